"""Imports deferred to first use, for heavy libraries only some code paths need.

Every recipe imports the whole library before it parses its flags, so a module that only
its last stage uses (rerun for recordings, ``scipy.stats`` for the results table) would
otherwise cost each start, ``--help`` included (~0.6 s and ~1 s on a 2-core machine;
measured with ``python -X importtime``).
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def lazy_import(name: str) -> ModuleType:
    """The module ``name``, executed on its first attribute access instead of now.

    The standard library's :class:`importlib.util.LazyLoader` recipe: the module object is
    registered in ``sys.modules`` at once (so every later ``import name`` shares it), and
    its code runs the first time an attribute is read. A missing module still fails here,
    at import time.

    Args:
        name: the absolute module name, e.g. ``"scipy.stats"``.

    Raises:
        ModuleNotFoundError: ``name`` is not installed.

    Examples:
        >>> colorsys = lazy_import("colorsys")  # not executed yet
        >>> colorsys.rgb_to_hsv(1.0, 0.0, 0.0)  # executed here
        (0.0, 1.0, 1.0)
    """
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None:
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)
    loader = importlib.util.LazyLoader(spec.loader)
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module
