"""Every tutorial notebook runs top to bottom in its small mode."""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[2] / "tutorials").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    assert all(not cell.get("outputs") for cell in nb.cells if cell.cell_type == "code"), \
        "notebooks are stored without outputs"
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute(
        # one intra-op thread, like the test process beside it: two threads on a core another
        # job also uses made a 30 s notebook take over 600 s (pytest-timeout)
        env={**os.environ, "OMP_NUM_THREADS": "1"})


def test_notebooks_match_their_source():
    import subprocess
    import sys
    import tempfile
    here = NOTEBOOKS[0].parent
    with tempfile.TemporaryDirectory() as out:
        script = (here / "make_notebooks.py").read_text()
        code = script.replace('here = Path(__file__).parent', f'here = Path({out!r})')
        subprocess.run([sys.executable, "-c", code], check=True)
        for path in NOTEBOOKS:
            fresh = nbformat.read(Path(out) / path.name, as_version=4)
            stored = nbformat.read(path, as_version=4)
            assert [c.source for c in fresh.cells] == [c.source for c in stored.cells], path.name
