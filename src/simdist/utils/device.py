"""Where models live: the device of a module, and a user's ``--device`` choice checked."""

from __future__ import annotations

import argparse
import itertools

import torch


def module_device(module: torch.nn.Module) -> torch.device:
    """The device of ``module``'s first parameter (or buffer); CPU if it has neither.

    Examples:
        >>> module_device(torch.nn.Linear(2, 3))
        device(type='cpu')
        >>> module_device(torch.nn.Linear(2, 3, device="meta"))
        device(type='meta')
    """
    # Called per policy step and per update: look at the first tensor only.
    first = next(itertools.chain(module.parameters(), module.buffers()), None)
    return torch.device("cpu") if first is None else first.device


def resolve_device(name: str | torch.device) -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; any other name is checked to exist.

    Raises:
        ValueError: for a name torch does not know, or a CUDA device this machine lacks
            (instead of a failure deep inside the first training step).

    Examples:
        >>> resolve_device("cpu")
        device(type='cpu')
        >>> resolve_device("auto") in (torch.device("cpu"), torch.device("cuda"))
        True
    """
    if str(name) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError as err:
        raise ValueError(f"unknown device {name!r} (e.g. 'cpu', 'cuda', 'cuda:1', 'auto')") \
            from err
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0 or (device.index or 0) >= count:
            raise ValueError(f"device {name!r} asked for, but this machine has {count} CUDA "
                             f"device(s) (torch {torch.__version__}); use --device cpu")
    return device


def device_argument(name: str) -> str:
    """``argparse`` ``type=`` for a ``--device`` option: the resolved name, or a usage
    error carrying :func:`resolve_device`'s message (exit status 2, before any work).

    Examples:
        >>> device_argument("cpu")
        'cpu'
    """
    try:
        return str(resolve_device(name))
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def move_to_device(modules, optimisers, device: str | torch.device) -> None:
    """Moves ``modules`` to ``device`` and keeps ``optimisers`` training those parameters.

    ``Module.to`` moves CPU<->CUDA parameters in place, but for some conversions (e.g. to
    the ``meta`` device) it creates new ``Parameter`` objects, which would leave an
    optimiser updating the old ones. Any replaced parameter is swapped in the optimisers'
    groups and their state (moved along), so the result is right either way.

    Examples:
        >>> net = torch.nn.Linear(2, 3)
        >>> optim = torch.optim.Adam(net.parameters())
        >>> move_to_device([net], [optim], "meta")
        >>> optim.param_groups[0]["params"][0] is net.weight, net.weight.device.type
        (True, 'meta')
    """
    before = [(module, dict(module.named_parameters())) for module in modules]
    for module in modules:
        module.to(device)
    replaced = {}
    for module, old in before:
        for name, param in module.named_parameters():
            if old.get(name) is not None and old[name] is not param:
                replaced[id(old[name])] = param
    for optimiser in optimisers:
        for group in optimiser.param_groups:
            group["params"] = [replaced.get(id(p), p) for p in group["params"]]
        state = {}
        for param, values in optimiser.state.items():
            values = {k: v.to(device) if torch.is_tensor(v) and v.dim() else v
                      for k, v in values.items()}
            state[replaced.get(id(param), param)] = values
        optimiser.state.clear()
        optimiser.state.update(state)
