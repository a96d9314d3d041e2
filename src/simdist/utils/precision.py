"""The arithmetic precisions a world model may train or plan in, by name.

``SimDistConfig.mixed_precision`` (training updates) and ``PlannerConfig.precision``
(the planner's candidate rollouts) take the same names (:data:`PRECISIONS`):

- ``"none"``: float32 throughout, no autocast;
- ``"bfloat16"``: the models run under ``torch.autocast`` with bfloat16 matmuls;
- ``"auto"``: ``"bfloat16"`` where the device runs bfloat16 matmuls natively
  (:func:`native_bfloat16`), ``"none"`` elsewhere.

Why ``"auto"`` exists: on a CPU without AVX512 (AVX2 only), PyTorch has no fast bfloat16
matmul kernel and falls back to a reference loop; one SimDist pretraining update of the
wide model then takes 16-25x the float32 time (docs/findings.md, "bfloat16 on a CPU
without AVX512"), where CPUs with AVX512-BF16 run it 2.3-2.6x faster than float32.

Examples:
    >>> autocast_dtype("none", "cpu") is None
    True
    >>> autocast_dtype("bfloat16", "cpu")
    torch.bfloat16
    >>> autocast_dtype("auto", "cpu") in (torch.bfloat16, None)
    True
    >>> resolve_precision("auto", "cpu") in ("bfloat16", "none")
    True
"""

from __future__ import annotations

import functools

import torch

#: the valid precision names
PRECISIONS = ("none", "bfloat16", "auto")

_DTYPES = {"none": None, "bfloat16": torch.bfloat16}


@functools.cache
def _cpu_bfloat16() -> bool:
    # The test PyTorch's own CPU bfloat16 paths use (oneDNN: AVX512BW/VL/DQ, AMX or Arm
    # BF16); without it a bfloat16 matmul runs a scalar reference kernel. Private API, so
    # a PyTorch without it counts as "no native bfloat16" (float32 is never wrong, only
    # sometimes slower).
    check = getattr(getattr(torch.ops, "mkldnn", None), "_is_mkldnn_bf16_supported", None)
    try:
        return bool(check()) if check is not None else False
    except (RuntimeError, AttributeError):
        return False


def native_bfloat16(device: str | torch.device) -> bool:
    """Whether ``device`` runs bfloat16 matmuls with native kernels (a CUDA device that
    supports bfloat16; a CPU whose oneDNN has bfloat16 kernels, i.e. AVX512 or Arm BF16)."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device.type == "cpu":
        return _cpu_bfloat16()
    return False


def check_precision(name: str, what: str = "precision") -> None:
    """Raises ``ValueError`` naming ``what`` unless ``name`` is one of :data:`PRECISIONS`."""
    if name not in PRECISIONS:
        raise ValueError(f"unknown {what} {name!r}; valid: {', '.join(PRECISIONS)}")


def resolve_precision(name: str, device: str | torch.device) -> str:
    """``name`` with ``"auto"`` replaced by what it means on ``device``: ``"bfloat16"`` or
    ``"none"``."""
    check_precision(name)
    if name == "auto":
        return "bfloat16" if native_bfloat16(device) else "none"
    return name


def autocast_dtype(name: str, device: str | torch.device) -> torch.dtype | None:
    """The dtype ``torch.autocast`` runs matmuls in for precision ``name`` on ``device``
    (``None``: no autocast, float32)."""
    return _DTYPES[resolve_precision(name, device)]
