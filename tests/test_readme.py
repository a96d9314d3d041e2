"""Every ```python block in README.md runs, in order, as one session.

Blocks share a namespace (a later block may use an earlier block's names) and run in a
temporary directory, so nothing they write lands in the checkout. Budgets are cut by
exact textual substitutions listed in ``TINY_BUDGETS``; each one must still match the
README, so a stale substitution fails here instead of silently running the full budget.
No block is skipped: a block that cannot run as written must be made runnable.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"

# README text -> what the test runs instead (same code, smaller numbers).
TINY_BUDGETS = {
    "env.rollout(100)": "env.rollout(5)",
}


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line number, source)`` of every fenced block whose info string is ``python``."""
    blocks = []
    for match in re.finditer(r"^```python[ \t]*\n(.*?)^```[ \t]*$", text, re.S | re.M):
        blocks.append((text.count("\n", 0, match.start()) + 1, match.group(1)))
    return blocks


def test_readme_has_python_blocks():
    # Guards the test below against passing on an empty list (e.g. a changed fence style).
    assert len(python_blocks(README.read_text())) >= 2


def test_tiny_budget_substitutions_still_match():
    sources = "".join(source for _, source in python_blocks(README.read_text()))
    stale = [old for old in TINY_BUDGETS if old not in sources]
    assert not stale, f"TINY_BUDGETS entries no longer in README.md: {stale}"


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    for line, source in python_blocks(README.read_text()):
        for old, new in TINY_BUDGETS.items():
            source = source.replace(old, new)
        code = compile(source, f"README.md:{line}", "exec")
        try:
            exec(code, namespace)
        except Exception as err:  # pragma: no cover - the message is the point
            pytest.fail(f"README.md code block at line {line} failed: "
                        f"{type(err).__name__}: {err}")
