"""The documentation site builds from the docstrings with no warnings, and covers the API.

``mkdocs build --strict`` (mkdocs + mkdocstrings, the ``dev`` extra) turns every warning
into a failure: a broken link, a docstring section griffe cannot parse, an argument
documented under a name the signature does not have.
"""

from __future__ import annotations

import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import yaml

import simdist

ROOT = Path(__file__).resolve().parents[1]


def _subpackages() -> list[str]:
    return sorted(info.name for info in pkgutil.iter_modules(simdist.__path__) if info.ispkg)


def test_every_subpackage_has_an_api_page_in_the_nav():
    nav = (ROOT / "mkdocs.yml").read_text()
    missing = []
    for name in _subpackages():
        page = ROOT / "docs" / "api" / f"{name}.md"
        if not page.exists() or f"::: simdist.{name}" not in page.read_text() \
                or f"api/{name}.md" not in nav:
            missing.append(name)
    assert _subpackages(), "no subpackages found"
    assert not missing, f"subpackages without an API page listed in mkdocs.yml: {missing}"


def test_sources_cite_only_files_in_this_repository():
    # The method notes live in docs/methods.md; nothing may point outside the repo.
    offenders = []
    for path in [*(ROOT / "src").rglob("*.py"), *(ROOT / "docs").rglob("*.md"),
                 ROOT / "README.md"]:
        text = path.read_text()
        if re.search(r"METHODS\.md|\.\./shared|shared/seeds", text):
            offenders.append(str(path.relative_to(ROOT)))
    assert not offenders, f"files citing documents outside the repository: {offenders}"


def test_mkdocs_build_is_strict_and_clean(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    log = result.stdout + result.stderr
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{log}"
    assert "WARNING" not in log, log
    # The reference pages really hold the API (not an empty page per package).
    modules = (tmp_path / "api" / "modules" / "index.html").read_text()
    for name in ("simdist.modules.LatentMPPIPlanner", "simdist.modules.SimDistWorldModel"):
        assert f'id="{name}"' in modules, name
    assert "arithmatex" in (tmp_path / "methods" / "index.html").read_text()


def test_mkdocs_config_parses():
    # mkdocs.yml uses no custom YAML tags, so a plain loader reads it.
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    assert config["strict"] is True
    assert "mkdocstrings" in str(config["plugins"])


def test_robot_task_page_runs(tmp_path, monkeypatch):
    # docs/robot_tasks.md's worked example registers a task: every block runs, in order.
    from simdist.envs import TASKS
    from tests.test_readme import python_blocks

    page = ROOT / "docs" / "robot_tasks.md"
    blocks = python_blocks(page.read_text())
    assert len(blocks) >= 3
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(TASKS, "cheetah-commanded", None)  # restored (removed) afterwards
    namespace: dict = {"__name__": "__docs__"}
    for line, source in blocks:
        exec(compile(source, f"docs/robot_tasks.md:{line}", "exec"), namespace)
    assert TASKS["cheetah-commanded"].is_robot
