"""The README's third Quickstart block (custom target, reload, evaluate with a video) runs.

The block's shell lines run as written, in order, in a temporary directory (the console
scripts work from any directory), and what they promise is checked: the run wrote its
results and agent files, and the evaluation wrote a non-empty MP4.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def quickstart_blocks() -> list[str]:
    """The ```bash blocks of the README's Quickstart section."""
    text = README.read_text()
    section = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^```bash[ \t]*\n(.*?)^```[ \t]*$", section, re.S | re.M)


def test_quickstart_has_three_commands_blocks():
    blocks = quickstart_blocks()
    assert len(blocks) == 2, "Quickstart: the two set-up lines, then the reload block"
    assert len(blocks[0].strip().splitlines()) == 2


def test_custom_target_and_reload_block_runs(tmp_path):
    lines = [line for line in quickstart_blocks()[1].strip().splitlines() if line.strip()]
    assert "--preset tiny" in lines[0]  # the test must stay tiny
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    for line in lines:
        done = subprocess.run(shlex.split(line), cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=600)
        assert done.returncode == 0, f"{line}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
    run = tmp_path / "runs" / "icy"
    assert (run / "results.json").exists()
    assert "icy_slope" in (run / "results.json").read_text()
    assert (run / "stages" / "round_2" / "simdist_agent.pt").exists()
    video = run / "foam.mp4"
    assert video.exists() and video.stat().st_size > 1000
