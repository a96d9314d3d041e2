"""The recipes run from any directory: console scripts, and the shipped expert as package data."""

import glob
import importlib
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from simdist.experts import COMMITTED_EXPERTS, Expert, committed_expert, resolve_expert

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
SCRIPTS = PYPROJECT["project"]["scripts"]


def test_every_console_script_names_a_function_of_a_recipe_module():
    assert {"simdist-quadruped", "simdist-evaluate", "simdist-dataset"} <= set(SCRIPTS)
    for name, target in SCRIPTS.items():
        module, function = target.split(":")
        assert module.startswith("simdist.recipes."), name
        assert callable(getattr(importlib.import_module(module), function)), name
        shim = ROOT / "recipes" / f"{module.rsplit('.', 1)[1]}.py"
        assert shim.exists(), f"{name}: no recipes/ shim for {module}"


@pytest.mark.parametrize("script", ["simdist-evaluate", "simdist-quadruped"])
def test_console_script_help_runs_from_another_directory(script, tmp_path):
    exe = shutil.which(script)
    assert exe, f"{script} is not installed: pip install -e '.[dev]' again"
    proc = subprocess.run([exe, "--help"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "--preset" in proc.stdout


def test_default_expert_resolves_outside_the_repository(tmp_path, monkeypatch):
    from simdist.pipelines.simdist import Config
    monkeypatch.chdir(tmp_path)
    path = resolve_expert(Config().expert)  # the default: checkpoints/quadruped_expert/...
    assert path.is_absolute() and path == committed_expert()
    assert Expert.load(path).actor is not None
    assert resolve_expert("checkpoints/other/expert.pt") == Path("checkpoints/other/expert.pt")
    with pytest.raises(ValueError, match="unknown shipped expert"):
        committed_expert("nope")


def test_shipped_experts_are_package_data():
    patterns = PYPROJECT["tool"]["setuptools"]["package-data"]["simdist"]
    shipped = {Path(f).relative_to(ROOT / "src" / "simdist").as_posix()
               for pattern in patterns for f in glob.glob(str(ROOT / "src" / "simdist" / pattern))}
    for name in COMMITTED_EXPERTS:
        assert f"checkpoints/{name}/expert.pt" in shipped, name
        assert committed_expert(name).is_file()


def test_repository_checkpoints_folder_is_the_package_data():
    # recipes' docs and old commands name checkpoints/...: it must be the same files
    if not (ROOT / "checkpoints").exists():
        pytest.skip("not a repository checkout")
    assert (ROOT / "checkpoints" / "quadruped_expert" / "expert.pt").resolve() \
        == committed_expert().resolve()


def test_shims_run_the_packaged_recipe(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "recipes" / "train_expert.py"), "--help"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "--init-from" in proc.stdout


@pytest.mark.parametrize("script,flags,message", [
    ("train_expert.py", ["--frames", "0"], "frames: must be > 0"),
    ("train_expert.py", ["--task", "moon"], "task: unknown task 'moon'"),
    ("train_expert.py", ["--target", '{"friction": true}'], "target: TargetDomain.friction"),
    ("train_expert.py", ["--init-from", "none.pt"], "init_from: no expert checkpoint"),
    ("generate_dataset.py", ["--episodes", "0"], "episodes: must be > 0"),
    ("generate_dataset.py", ["--backend", "spark"], "backend: must be 'local' or 'ray'"),
    ("generate_dataset.py", ["--expert", "none.pt"], "expert: no expert checkpoint"),
])
def test_expert_and_dataset_scripts_refuse_bad_values_before_any_work(
        tmp_path, capsys, script, flags, message):
    """The same typed, validated command line as the recipes: exit status 2, the field
    named, nothing written."""
    from tests.in_process import run_script
    proc = run_script(ROOT / "recipes" / script, *flags, "--out", tmp_path / "out",
                      capsys=capsys)
    assert proc.returncode == 2, proc.stderr
    assert message in " ".join(proc.stderr.replace("│", " ").split()), proc.stderr
    assert not (tmp_path / "out").exists()
