"""The quadruped experts shipped inside the package, found from any working directory.

The SAC experts the recipes start from are package data (``simdist/checkpoints/...``);
the repository's ``checkpoints/`` folder points at the same files, so the recipes' default
``--expert checkpoints/quadruped_expert/expert.pt`` reads the shipped file from the
repository root and from anywhere else.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

#: Shipped experts: ``quadruped_expert`` (mixed slopes, the recipes' default) and
#: ``quadruped_expert_flat`` (flat ground, the one it was continued from).
COMMITTED_EXPERTS = ("quadruped_expert", "quadruped_expert_flat")


def committed_expert(name: str = "quadruped_expert") -> Path:
    """Path of a shipped expert's ``expert.pt`` (``Expert.load`` reads it).

    Args:
        name: one of :data:`COMMITTED_EXPERTS`.

    Raises:
        ValueError: ``name`` is not a shipped expert.
        FileNotFoundError: the package was installed without its data files.

    Examples:
        >>> from simdist.experts import Expert
        >>> path = committed_expert()
        >>> path.name, path.parent.name
        ('expert.pt', 'quadruped_expert')
        >>> Expert.load(path).actor is not None
        True
    """
    if name not in COMMITTED_EXPERTS:
        raise ValueError(f"unknown shipped expert {name!r}; valid: {list(COMMITTED_EXPERTS)}")
    path = Path(str(resources.files("simdist") / "checkpoints" / name / "expert.pt"))
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: reinstall simdist-rl with its package "
                                "data (pip install simdist-rl)")
    return path


def resolve_expert(path: str | os.PathLike) -> Path:
    """``path`` if it exists, else the shipped expert it names, else ``path`` unchanged.

    A relative ``checkpoints/<name>/expert.pt`` (the recipes' defaults, relative to the
    repository root) falls back to the shipped ``<name>`` when the working directory has
    no such file, so recipes run from any directory. Any other path is returned as given
    (the caller reports it missing).

    Args:
        path: an ``expert.pt`` path, absolute or relative to the working directory.

    Examples:
        >>> default = resolve_expert("checkpoints/quadruped_expert/expert.pt")
        >>> default.resolve() == committed_expert().resolve()  # from any directory
        True
        >>> resolve_expert("no/such/expert.pt")
        PosixPath('no/such/expert.pt')
    """
    path = Path(path)
    if path.exists():
        return path
    parts = path.parts
    if (not path.is_absolute() and len(parts) == 3 and parts[0] == "checkpoints"
            and parts[1] in COMMITTED_EXPERTS and parts[2] == "expert.pt"):
        return committed_expert(parts[1])
    return path
