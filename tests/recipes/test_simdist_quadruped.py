import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_recipe_runs_end_to_end_on_tiny_preset(tmp_path):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "simdist_quadruped.py"), "--preset", "tiny",
         "--output-dir", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    results = json.loads((tmp_path / "results.json").read_text())
    assert set(results["results"]) == {"sim", "slippery_slope"}
    assert len(results["results"]["sim"]["forward_progress_m"]) == 1
    assert (tmp_path / "forward_progress.png").stat().st_size > 0
    assert "forward progress" in proc.stdout
    assert (tmp_path / "config.json").exists() and (tmp_path / "stages" / "environment.json").exists()
    again = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "simdist_quadruped.py"), "--preset", "tiny",
         "--output-dir", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "already done" in again.stdout
    assert json.loads((tmp_path / "results.json").read_text())["results"] == results["results"]
    changed = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "simdist_quadruped.py"), "--preset", "tiny",
         "--episodes", "2", "--output-dir", str(tmp_path)], capture_output=True, text=True,
        timeout=300)
    assert changed.returncode != 0 and "different config" in changed.stderr


def test_recipe_rejects_unknown_target(tmp_path):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "recipes" / "simdist_quadruped.py"), "--targets", "moon",
         "--output-dir", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "unknown targets ['moon']" in proc.stderr
