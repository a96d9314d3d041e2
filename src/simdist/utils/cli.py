"""Recipe command lines from their config dataclasses: every field a flag, presets kept.

We use `tyro <https://brentyi.github.io/tyro/>`_ rather than argparse by hand or Hydra:
it builds the parser from the dataclass a recipe already has (types, defaults, and the
field's comment as its help), so a new field is on the command line the moment it
exists, with no YAML layer to keep in sync. Presets stay plain dicts of overrides: the
preset named by ``--preset`` becomes the parser's defaults, so ``--help`` after a preset
shows that preset's values and any flag still overrides it.

Validation is the dataclass's own (``__post_init__``): a bad value stops the parse with
an ``error:`` line naming the field, before a recipe writes or computes anything.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import sys
import typing
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence, TypeVar

# imported here, not lazily: tyro's import hashes every builtin, and a doctest's `_` can
# hold an unhashable tuple by then
import tyro

from simdist.utils.sealed import EditedRecordError, check_seal
from simdist.utils.stages import FolderInUseError, RunFolderError, field_defaults

T = TypeVar("T")


class ConfigError(ValueError):
    """A recipe config value that cannot work (the message names the field)."""


def check(condition: bool, field: str, message: str) -> None:
    """Raises :class:`ConfigError` ``"<field>: <message>"`` unless ``condition`` holds.

    Examples:
        >>> check(3 > 0, "episodes", "must be positive")
        >>> check(0 > 0, "episodes", "must be positive, got 0")
        Traceback (most recent call last):
        ...
        simdist.utils.cli.ConfigError: episodes: must be positive, got 0
    """
    if not condition:
        raise ConfigError(f"{field}: {message}")


def check_builds(field: str, build, *args) -> None:
    """Calls ``build(*args)`` (a constructor or validator with its own messages) and turns
    its ``ValueError``/``TypeError`` into a :class:`ConfigError` naming ``field``.

    Examples:
        >>> check_builds("device", int, "3")
        >>> check_builds("device", int, "tpu")
        Traceback (most recent call last):
        ...
        simdist.utils.cli.ConfigError: device: invalid literal for int() with base 10: 'tpu'
    """
    try:
        build(*args)
    except (ValueError, TypeError) as error:
        raise ConfigError(f"{field}: {error}") from error


def check_positive(config: Any, *fields: str, allow_zero: bool = False) -> None:
    """Each named field of ``config`` is a finite number > 0 (or >= 0 with
    ``allow_zero``)."""
    for name in fields:
        value = getattr(config, name)
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        ok = number and math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
        check(ok, name, f"must be {'>= 0' if allow_zero else '> 0'} and finite, got {value!r}")


def parse_config(config_type: type[T], presets: Mapping[str, Mapping[str, Any]],
                 argv: Sequence[str] | None = None, description: str | None = None,
                 prog: str | None = None) -> tuple[T, str]:
    """Parses ``argv`` into a ``config_type`` instance, starting from ``--preset``'s values.

    Every field of the dataclass is a ``--kebab-case`` flag with its default and help;
    ``--preset NAME`` (listed in the description) picks the defaults, and ``--config
    PATH`` (a run's saved ``config.json``) replaces them with that run's values, so a
    run can be repeated, or repeated with one flag changed. A value the dataclass's
    ``__post_init__`` rejects, or a config file that cannot be read, ends the program
    with exit status 2 and an ``error:`` line, as argparse does, before any work.

    Args:
        config_type: the recipe's config dataclass.
        presets: preset name -> field overrides (must contain ``"default"``).
        argv: the arguments (``sys.argv[1:]`` when None).
        description: the parser's description (e.g. the recipe docstring's first line).
        prog: the program name shown in usage lines.

    Returns:
        ``(config, preset_name)``.

    Examples:
        >>> @dataclasses.dataclass
        ... class Demo:
        ...     episodes: int = 8  # evaluation episodes
        ...     def __post_init__(self):
        ...         check_positive(self, "episodes")
        >>> parse_config(Demo, {"default": {}, "tiny": {"episodes": 2}}, ["--preset", "tiny"])
        (Demo(episodes=2), 'tiny')
        >>> parse_config(Demo, {"default": {}}, ["--episodes", "5"])[0].episodes
        5
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    names = sorted(presets)
    pre = argparse.ArgumentParser(add_help=False, prog=prog)
    pre.add_argument("--preset", choices=names, default="default")
    pre.add_argument("--config", default=None)
    known, rest = pre.parse_known_args(argv)
    starts = (f"--preset {{{','.join(names)}}}: start from that preset's values (default: "
              "default). --config PATH: start from a run's saved config.json instead (after "
              "the preset)." if len(names) > 1 else
              "--config PATH: start from a run's saved config.json.")
    text = (f"{description or ''}\n\n{starts} Every other flag overrides those values; "
            "each flag below shows the value it starts from as its default.").strip()
    try:
        default = dataclasses.replace(config_type(), **presets[known.preset])
        if known.config is not None:
            default = dataclasses.replace(default, **config_file(config_type, known.config))
        config = tyro.cli(config_type, default=default, args=rest, description=text, prog=prog)
    except ConfigError as error:
        usage = prog or sys.argv[0]
        print(f"usage: {usage} [-h] [--preset {{{','.join(names)}}}] [OPTIONS]\n"
              f"{usage}: error: {error}", file=sys.stderr)
        raise SystemExit(2) from error
    return config, known.preset


def config_file(config_type: type, path: str | Path) -> dict[str, Any]:
    """The fields a saved config file (a run's ``config.json``) sets, typed for
    ``config_type``. A field the file predates reads as what such a run was made with
    (its ``ABSENT_MEANS``, see :func:`~simdist.utils.stages.field_defaults`).

    Raises:
        ConfigError: the file is missing, not JSON, not an object, or names a field
            ``config_type`` does not have.

    Examples:
        >>> import tempfile
        >>> @dataclasses.dataclass
        ... class Demo:
        ...     episodes: int = 8
        ...     commands: tuple[float, ...] = ()
        >>> path = Path(tempfile.mkdtemp()) / "config.json"
        >>> _ = path.write_text('{"episodes": 3, "commands": [0.5]}')
        >>> config_file(Demo, path)
        {'episodes': 3, 'commands': (0.5,)}
    """
    path = Path(path)
    try:
        stored = json.loads(path.read_text())
    except FileNotFoundError as error:
        raise ConfigError(f"config: no file at {path}") from error
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ConfigError(f"config: {path} is not a readable JSON file ({error})") from error
    try:  # a results.json is sealed: an edited one is refused
        stored = check_seal(stored, path)
    except EditedRecordError as error:
        raise ConfigError(f"config: {error}") from error
    if isinstance(stored, dict) and isinstance(stored.get("config"), dict):
        stored = stored["config"]  # a results.json holds its config under "config"
    if not isinstance(stored, dict):
        raise ConfigError(f"config: {path} must hold a JSON object of config fields")
    fields = {f.name for f in dataclasses.fields(config_type)}
    unknown = sorted(set(stored) - fields)
    if unknown:
        raise ConfigError(f"config: {path} names fields this program does not have: "
                          f"{unknown}")
    absent = field_defaults(config_type)
    values = {**{k: absent[k] for k in fields - set(stored) if k in absent}, **stored}
    hints = typing.get_type_hints(config_type)
    for name, value in values.items():  # JSON has lists only; a tuple field gets a tuple
        if isinstance(value, list) and typing.get_origin(hints.get(name)) is tuple:
            values[name] = tuple(value)
    return values


def usage_error(prog: str, message: str) -> typing.NoReturn:
    """Ends the program as argparse does for a bad flag: ``<prog>: error: <message>`` on
    stderr, exit status 2 (the user's input, not a failure of the program)."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


@contextlib.contextmanager
def exit_on_folder_errors(prog: str) -> Iterator[None]:
    """Ends the program with ``<prog>: error: <message>`` and exit status 2 (as argparse
    does for a bad flag) when the output folder cannot be used: it holds another config's
    results (:class:`~simdist.utils.stages.RunFolderError`) or another run holds it
    (:class:`~simdist.utils.stages.FolderInUseError`). Both are the user's choice of
    folder, not a failure of the program, so no traceback.

    Examples:
        >>> from simdist.utils.stages import RunFolderError
        >>> with exit_on_folder_errors("demo.py"):
        ...     raise RunFolderError("out holds results of a different config")
        Traceback (most recent call last):
        ...
        SystemExit: 2
    """
    try:
        yield
    except (RunFolderError, FolderInUseError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        raise SystemExit(2) from error
