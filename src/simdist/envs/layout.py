"""Named slices of a flat observation vector."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Layout:
    """The per-field layout of a flat float vector (e.g. the privileged ``"state"``).

    Examples:
        >>> layout = Layout.from_sizes({"qpos": 2, "qvel": 3})
        >>> layout.size, layout["qvel"]
        (5, slice(2, 5, None))
        >>> layout.split(np.arange(5.0))["qpos"].tolist()
        [0.0, 1.0]
    """

    fields: tuple[tuple[str, slice], ...]

    @classmethod
    def from_sizes(cls, sizes) -> Layout:
        out, start = [], 0
        for name, size in sizes.items():
            out.append((name, slice(start, start + int(size))))
            start += int(size)
        return cls(tuple(out))

    @property
    def size(self) -> int:
        return self.fields[-1][1].stop if self.fields else 0

    def __getitem__(self, name: str) -> slice:
        for key, sl in self.fields:
            if key == name:
                return sl
        raise KeyError(f"no field {name!r} in layout; fields: {[k for k, _ in self.fields]}")

    def names(self) -> list[str]:
        return [k for k, _ in self.fields]

    def split(self, flat) -> OrderedDict:
        """Splits a ``(..., size)`` array/tensor into named views."""
        return OrderedDict((k, flat[..., sl]) for k, sl in self.fields)
