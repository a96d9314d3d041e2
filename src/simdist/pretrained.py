"""Pretrained agents shipped with the package, loadable by name.

Each is a weights-only file under ``simdist/checkpoints/`` with the record of how it was
trained beside it (command, machine, wall time, curves), so it can be tried at once and
retrained by anyone::

    from simdist.agents import load_agent
    agent = load_agent("simdist/quadruped")      # a name here, or any agent file's path

and from the shell: ``simdist-evaluate --checkpoint simdist/quadruped --target foam
--video foam.mp4``; ``simdist-evaluate --list`` prints this table.

Examples:
    >>> sorted(PRETRAINED)[:3]
    ['expert/quadruped', 'expert/quadruped-flat', 'simdist/quadruped']
    >>> pretrained_path("expert/quadruped").name
    'expert.pt'
    >>> pretrained_path("simdist/humanoid")
    Traceback (most recent call last):
    ...
    KeyError: "no pretrained agent named 'simdist/humanoid'; shipped: ['expert/quadruped', 'expert/quadruped-flat', 'simdist/quadruped', 'twist/cartpole-balance', 'twist/cartpole-balance-teacher']"
"""

from __future__ import annotations

import dataclasses
import os
from importlib import resources
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class Pretrained:
    """One shipped agent.

    Attributes:
        file: its file, relative to the package's ``checkpoints/`` folder.
        kind: the class :func:`simdist.agents.load_agent` returns.
        task: the task it was trained for (``simdist.envs.TASKS``).
        summary: what it is, in a line.
        record: the file (beside it) that says how it was trained.
    """

    file: str
    kind: str
    task: str
    summary: str
    record: str


#: Name -> shipped agent. Names read ``<method>/<robot or task>``.
PRETRAINED: dict[str, Pretrained] = {
    "simdist/quadruped": Pretrained(
        "simdist_quadruped/agent.pt", "SimDistAgent", "quadruped-flat",
        "SimDist world model of the recipe's default run, pretrained on the perturbed-expert "
        "dataset; plans with latent MPPI (no target data seen)",
        "simdist_quadruped/training_record.json"),
    "twist/cartpole-balance-teacher": Pretrained(
        "twist_cartpole-balance/teacher.pt", "DreamerAgent", "cartpole-balance",
        "TWIST's state teacher (the Oracle): a state Dreamer on privileged state",
        "twist_cartpole-balance/training_record.json"),
    "twist/cartpole-balance": Pretrained(
        "twist_cartpole-balance/student.pt", "TwistStudent", "cartpole-balance",
        "TWIST's faithful image student (a CNN by Eq. 3 + 4 alone); weak: below zero and "
        "random actions on held-out scenes (docs/results.md)",
        "twist_cartpole-balance/training_record.json"),
    "expert/quadruped": Pretrained(
        "quadruped_expert/expert.pt", "Expert", "quadruped-terrain",
        "state SAC expert on mixed slopes under dynamics randomisation (the recipes' "
        "data-collecting expert)", "quadruped_expert/training_curve.json"),
    "expert/quadruped-flat": Pretrained(
        "quadruped_expert_flat/expert.pt", "Expert", "quadruped-flat",
        "state SAC expert on flat ground (the one the terrain expert continues)",
        "quadruped_expert_flat/training_curve.json"),
}


def checkpoints_folder() -> Path:
    """The package's ``checkpoints/`` folder (the repository's ``checkpoints`` links to it)."""
    return Path(str(resources.files("simdist") / "checkpoints"))


def pretrained_path(name: str) -> Path:
    """The file of the shipped agent ``name``.

    Raises:
        KeyError: no agent of that name (the message lists the shipped ones).
        FileNotFoundError: the package was installed without its data files.
    """
    if name not in PRETRAINED:
        raise KeyError(f"no pretrained agent named {name!r}; shipped: {sorted(PRETRAINED)}")
    path = checkpoints_folder() / PRETRAINED[name].file
    if not path.is_file():
        raise FileNotFoundError(f"pretrained agent {name!r}: {path} is missing; reinstall "
                                "simdist-rl with its package data (pip install -e .)")
    return path


def resolve_agent_file(name_or_path: str | os.PathLike) -> Path:
    """An existing path as given, else the shipped agent of that name, else the path
    unchanged (the reader then reports it missing, naming it).

    Examples:
        >>> resolve_agent_file("expert/quadruped") == pretrained_path("expert/quadruped")
        True
        >>> resolve_agent_file("runs/a/agent.pt")
        PosixPath('runs/a/agent.pt')
    """
    path = Path(name_or_path)
    if path.exists() or str(name_or_path) not in PRETRAINED:
        return path
    return pretrained_path(str(name_or_path))


def describe_pretrained() -> str:
    """The shipped agents as a table (``simdist-evaluate --list``)."""
    width = max(map(len, PRETRAINED))
    lines = [f"{'name':<{width}}  {'class':<12}  {'task':<17}  what it is"]
    for name, entry in sorted(PRETRAINED.items()):
        shipped = (checkpoints_folder() / entry.file).is_file()
        lines.append(f"{name:<{width}}  {entry.kind:<12}  {entry.task:<17}  {entry.summary}"
                     + ("" if shipped else " [missing from this install]"))
    lines.append(f"files and training records: {checkpoints_folder()}")
    return "\n".join(lines)
