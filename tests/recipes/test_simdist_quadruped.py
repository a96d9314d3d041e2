import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
RECIPE = [sys.executable, str(ROOT / "recipes" / "simdist_quadruped.py")]


@pytest.fixture(scope="module")
def tiny_expert(tmp_path_factory):
    from simdist.experts import Expert, SACExpertConfig
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("expert") / "expert.pt"
    return Expert.untrained(89, 12, hidden=16).save(path, 89, SACExpertConfig(hidden=16))


def _run(*args, timeout=300):
    return subprocess.run([*RECIPE, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def test_recipe_runs_end_to_end_on_tiny_preset_and_resumes(tmp_path, tiny_expert):
    proc = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path)
    assert proc.returncode == 0, proc.stderr
    results = json.loads((tmp_path / "results.json").read_text())
    zero_shot = results["expert_zero_shot"]
    assert set(zero_shot) == {"sim", "slippery_slope"}
    assert len(zero_shot["sim"]["progress_m"]) == 2 and "mean_fraction" in zero_shot["sim"]
    assert (tmp_path / "forward_progress.png").stat().st_size > 0
    assert (tmp_path / "stages" / "expert_zero_shot.json").exists()
    assert "of commanded distance" in proc.stdout
    again = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path)
    assert again.returncode == 0 and "already done" in again.stdout
    assert json.loads((tmp_path / "results.json").read_text())["expert_zero_shot"] == zero_shot
    changed = _run("--preset", "tiny", "--episodes", 3, "--expert", tiny_expert,
                   "--output-dir", tmp_path)
    assert changed.returncode != 0 and "different config" in changed.stderr


def test_recipe_rejects_unknown_target_and_missing_expert(tmp_path):
    proc = _run("--targets", "moon", "--output-dir", tmp_path / "a")
    assert proc.returncode != 0 and "unknown targets ['moon']" in proc.stderr
    proc = _run("--preset", "tiny", "--expert", tmp_path / "none.pt", "--output-dir", tmp_path / "b")
    assert proc.returncode != 0 and "recipes/train_expert.py" in proc.stderr
