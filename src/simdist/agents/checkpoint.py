"""Self-describing agent checkpoints: weights and the config that rebuilds them, one file.

One ``.pt`` file per agent, written atomically (:func:`~simdist.utils.save_atomic`) and read
with ``torch.load(..., weights_only=True)`` only (:func:`~simdist.utils.load_checkpoint`):
it holds tensors and plain containers of numbers and strings, never pickled objects. Its
top level::

    {"format": "simdist-agent", "version": 1, "class": "SimDistAgent" | "DreamerAgent" |
     "TwistStudent" | "AsymmetricSACAgent", "config": {...sizes, config dataclass fields...},
     "weights": {...state dicts...}, "optimisers": {...} (optional), "meta": {...}}

``meta`` is free-form plain data from whoever saved the file (a recipe records the task
it trained on, so ``recipes/evaluate.py`` can default to it).
"""

from __future__ import annotations

import dataclasses
import numbers
import os
from pathlib import Path
from typing import Any

from simdist.utils.checkpoint import CorruptCheckpointError, load_checkpoint, recovery_hint, save_atomic

FORMAT = "simdist-agent"
#: The newest format version this code reads and the one it writes.
VERSION = 1
CLASSES = ("SimDistAgent", "DreamerAgent", "TwistStudent", "AsymmetricSACAgent")


def check_plain(value: Any, where: str = "config") -> None:
    """Raises ``TypeError`` unless ``value`` is plain data (what a weights-only load reads
    back without unpickling): ``None``, bools, numbers, strings, and lists, tuples and
    dicts with string keys of those.

    Examples:
        >>> check_plain({"size": "tiny", "dims": [3, 4], "lr": 1e-3, "noise": None})
        >>> check_plain({"path": Path("x")})
        Traceback (most recent call last):
        ...
        TypeError: config['path'] is a PosixPath; a checkpoint's config holds only plain data (numbers, strings, lists, dicts)
    """
    if value is None or isinstance(value, (bool, str, numbers.Real)) and \
            type(value).__module__ == "builtins":
        return
    if isinstance(value, (list, tuple)) and type(value) in (list, tuple):
        for i, item in enumerate(value):
            check_plain(item, f"{where}[{i}]")
        return
    if type(value) is dict:
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"{where} has a non-string key {key!r}")
            check_plain(item, f"{where}[{key!r}]")
        return
    raise TypeError(f"{where} is a {type(value).__name__}; a checkpoint's config holds only "
                    "plain data (numbers, strings, lists, dicts)")


def write_agent_checkpoint(path: str | os.PathLike, agent_class: str, config: dict,
                           weights: dict, optimisers: dict | None = None,
                           meta: dict | None = None) -> Path:
    """Writes one self-describing agent file atomically; returns ``path``.

    ``config`` and ``meta`` are checked to be plain data first, so an object that a
    weights-only load would refuse fails here, before anything is written.
    """
    if agent_class not in CLASSES:
        raise ValueError(f"unknown agent class {agent_class!r}; known: {CLASSES}")
    check_plain(config, "config")
    meta = dict(meta or {})
    check_plain(meta, "meta")
    payload = {"format": FORMAT, "version": VERSION, "class": agent_class, "config": config,
               "weights": weights, "meta": meta}
    if optimisers is not None:
        payload["optimisers"] = optimisers
    save_atomic(payload, path)
    return Path(path)


class NotAnAgentFileError(ValueError):
    """A valid file that is not an agent file (e.g. a training checkpoint): nothing to
    recover, only another file to load."""


def incompatible(path: str | os.PathLike, why: str) -> CorruptCheckpointError:
    """The error for a readable file that is not a usable agent checkpoint."""
    return CorruptCheckpointError(f"agent checkpoint {str(path)!r} is corrupt or incompatible: "
                                  f"{why}. To recover, {recovery_hint(path)}")


def read_agent_checkpoint(path: str | os.PathLike, expected: str | None = None) -> dict:
    """Reads and validates an agent file (weights-only, on the CPU); returns its dict.

    Args:
        path: the file :meth:`SimDistAgent.save` (or ``DreamerAgent``/``TwistStudent``)
            wrote.
        expected: the agent class the caller can build, or ``None`` for any.

    Raises:
        FileNotFoundError: naming the missing file.
        CorruptCheckpointError: naming the file: truncated or garbled, holds pickled
            objects, is not an agent checkpoint (e.g. a bare state dict), was written by a
            newer format version, or holds another agent class than ``expected``.
        NotAnAgentFileError: the file is a training checkpoint (it names the agent file
            to load instead).
    """
    ckpt = load_checkpoint(path, map_location="cpu")
    if not isinstance(ckpt, dict):
        raise incompatible(path, f"it holds a {type(ckpt).__name__}, not an agent's dict")
    if ckpt.get("format") != FORMAT and "history" in ckpt:
        # a valid file of another kind: say what it is, and never advise deleting it
        raise NotAnAgentFileError(
            f"{str(path)!r} is a training checkpoint (it resumes a training loop: keys "
            f"{sorted(map(str, ckpt))[:6]}), not an agent file. Load the agent file its stage "
            "saved beside it (agent.pt after pretraining, *_agent.pt elsewhere: "
            "teacher_agent.pt, student_agent.pt, dreamer_agent.pt, sac_agent.pt, "
            "simdist_agent.pt)")
    if ckpt.get("format") != FORMAT:
        raise incompatible(path, f"it is not a self-describing agent file (no 'format': "
                           f"{FORMAT!r}; top-level keys {sorted(map(str, ckpt))[:8]}): a bare "
                           "state dict or a training checkpoint needs the code that built the "
                           "model; save agents with agent.save(path)")
    version = ckpt.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise incompatible(path, f"its format version {version!r} is not a positive integer")
    if version > VERSION:
        raise incompatible(path, f"it has format version {version}, this simdist reads up to "
                           f"{VERSION}: upgrade simdist to load it")
    agent_class = ckpt.get("class")
    if agent_class not in CLASSES:
        raise incompatible(path, f"it names an unknown agent class {agent_class!r}")
    if expected is not None and agent_class != expected:
        raise incompatible(path, f"it holds a {agent_class}, not a {expected}: load it with "
                           f"{agent_class}.load or simdist.agents.load_agent")
    for key in ("config", "weights"):
        if not isinstance(ckpt.get(key), dict):
            raise incompatible(path, f"its {key!r} entry is missing or not a dict")
    ckpt.setdefault("meta", {})
    return ckpt


def config_from_dict(config_type: type, values: Any, path, what: str):
    """``config_type(**values)``, turning unknown fields or refused values into an error
    naming the file (fields missing from an older file take their defaults)."""
    if not isinstance(values, dict):
        raise incompatible(path, f"its {what} is not a dict")
    known = {f.name for f in dataclasses.fields(config_type)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise incompatible(path, f"its {what} has fields this simdist does not know: {unknown}")
    try:
        return config_type(**values)
    except (TypeError, ValueError) as err:
        raise incompatible(path, f"its {what} is refused: {err}") from None


def load_weights(module, state, path, what: str) -> None:
    """``module.load_state_dict(state)`` (strict), or an error naming the file and part."""
    try:
        module.load_state_dict(state)
    except (RuntimeError, KeyError, TypeError, ValueError, AttributeError) as err:
        raise incompatible(path, f"its {what} weights do not fit the model it describes "
                           f"({str(err).strip().splitlines()[0][:300]})") from None


def load_optimisers(owner, ckpt: dict, names, path) -> None:
    """Loads ``ckpt["optimisers"][name]`` into ``owner.<name>`` for each of ``names``, if
    the file has optimiser states at all (``save(..., optimisers=False)`` writes none)."""
    states = ckpt.get("optimisers")
    if states is None:
        return
    if not isinstance(states, dict) or set(states) != set(names):
        found = sorted(map(str, states)) if isinstance(states, dict) else type(states).__name__
        raise incompatible(path, f"its optimisers are {found}, expected {sorted(names)}")
    for name in names:
        load_weights(getattr(owner, name), states[name], path, f"optimiser {name!r}")


def part(ckpt: dict, path, *keys: str):
    """``ckpt[k1][k2]...``, or an error naming the file and the missing entry."""
    value = ckpt
    for i, key in enumerate(keys):
        if not isinstance(value, dict) or key not in value:
            raise incompatible(path, f"it lacks {'/'.join(keys[:i + 1])!r}")
        value = value[key]
    return value


def build(what: str, builder, desc, path):
    """``builder(desc)`` (a model from its description), or an error naming the file."""
    try:
        return builder(desc)
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise incompatible(path, f"its {what} description cannot be built ({err!r})") from None


def load_agent(path: str | os.PathLike, map_location=None):
    """Loads any self-describing agent file, or a shipped agent by name, into its class.

    Args:
        path: an agent file written by ``save``, or the name of a shipped agent
            (:data:`simdist.pretrained.PRETRAINED`, e.g. ``"simdist/quadruped"``).
        map_location: device to put the agent on (default: the CPU).

    Returns:
        a :class:`~simdist.agents.SimDistAgent`, :class:`~simdist.agents.DreamerAgent`,
        :class:`~simdist.agents.TwistStudent` or :class:`~simdist.agents.AsymmetricSACAgent`
        (or a :class:`~simdist.experts.Expert` for an ``expert.pt``), its ``meta`` dict in
        ``.checkpoint_meta``.

    Examples:
        >>> import tempfile
        >>> from simdist.agents import DreamerAgent, DreamerConfig
        >>> path = Path(tempfile.mkdtemp()) / "teacher.pt"
        >>> _ = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny")).save(
        ...     path, meta={"task": "cartpole-balance"})
        >>> agent = load_agent(path)
        >>> type(agent).__name__, agent.checkpoint_meta["task"]
        ('DreamerAgent', 'cartpole-balance')
    """
    from simdist import agents  # the classes import this module
    from simdist.pretrained import resolve_agent_file

    path = resolve_agent_file(path)
    if is_expert_file(path):
        from simdist.experts import Expert
        return Expert.load(path).to(map_location or "cpu")
    ckpt = read_agent_checkpoint(path)
    return getattr(agents, ckpt["class"]).from_checkpoint(ckpt, path, map_location)


def is_expert_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a SAC expert's ``expert.pt`` (:meth:`simdist.experts.Expert.save`)
    rather than an agent file: the experts keep their own format, older than agent files."""
    path = Path(path)
    if path.name != "expert.pt" or not path.is_file():
        return False
    ckpt = load_checkpoint(path)
    return isinstance(ckpt, dict) and "actor" in ckpt and "critic" in ckpt and "class" not in ckpt


def read_agent_meta(path: str | os.PathLike) -> dict:
    """The ``meta`` of an agent file or shipped agent (for an expert: its task), read and
    checked without building the agent.

    Raises:
        FileNotFoundError, CorruptCheckpointError: naming the file.
    """
    from simdist.pretrained import resolve_agent_file

    path = resolve_agent_file(path)
    if is_expert_file(path):
        config = load_checkpoint(path).get("config", {})
        return {"task": config.get("task", "")} if isinstance(config, dict) else {}
    return read_agent_checkpoint(path)["meta"]


class LoadableAgent:
    """Mixin: ``load(path)`` for an agent class whose ``save`` writes a self-describing file.

    The class provides ``from_checkpoint(ckpt, path, map_location)``; the file's stored
    class must be this class's name.
    """

    @classmethod
    def load(cls, path: str | os.PathLike, map_location=None):
        """Rebuilds an agent from a file its ``save`` wrote (weights-only load).

        Args:
            path: the file.
            map_location: device for the agent (default: the CPU).

        Raises:
            FileNotFoundError, CorruptCheckpointError: naming the file (see
                :func:`read_agent_checkpoint`).
        """
        ckpt = read_agent_checkpoint(path, expected=cls.__name__)
        return cls.from_checkpoint(ckpt, path, map_location)

