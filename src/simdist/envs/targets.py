"""Target domains: parameterised stand-ins for "the real world".

A :class:`TargetDomain` is a fixed shift applied to every episode of an environment:
dynamics multipliers (friction, contact softness, motor strength), an added payload,
action latency, slope geometry, and optionally a visual setting. Named presets lie
**outside** the default training randomisation (:class:`DynamicsRandomisation`), which
:func:`describe_ranges` prints side by side and a test checks.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
from pathlib import Path
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from simdist.envs.randomisation import DynamicsParams, DynamicsRandomisation, VisualRandomisation


#: field -> (lowest, highest) value a target domain may take: physically meaningful shifts
#: the simulator can step (a friction of 1e308 or a 1e30 kg payload fails inside MuJoCo;
#: a latency of 100000 steps would hold that many actions per world)
TARGET_BOUNDS = {"friction": (0.01, 10.0), "contact_softness": (0.05, 50.0),
                 "motor_strength": (0.05, 5.0), "payload_kg": (0.0, 200.0),
                 "action_latency": (0, 50), "slope_deg": (-30.0, 30.0)}


@dataclass(frozen=True)
class TargetDomain:
    """A named, fixed domain shift.

    Args:
        name: label used in logs and results.
        friction: scale on sliding friction (``< 1`` is slippery).
        contact_softness: scale on the contact time constant (``> 1`` is softer ground).
        motor_strength: scale on actuator force.
        payload_kg: mass added to the robot's root body.
        action_latency: extra control steps of action delay.
        slope_deg: ground incline along the direction of travel (quadruped tasks only).
        visual: visual randomisation in force in this domain, or ``None``.

    Every number must be a real number (an integer for ``action_latency``; never a bool or
    a string) inside its physical bounds (:data:`TARGET_BOUNDS`): friction 0.01-10,
    contact softness 0.05-50, motor strength 0.05-5, payload 0-200 kg, latency 0-50
    steps, slope -30 to 30 degrees. A value outside them is refused here, naming the
    field, before any environment is built.

    Examples:
        >>> target = TargetDomain(name="icy", friction=0.2)
        >>> target.dynamics().friction
        0.2
        >>> get_target("slippery_slope").slope_deg > 0
        True
    """

    name: str = "custom"
    friction: float = 1.0
    contact_softness: float = 1.0
    motor_strength: float = 1.0
    payload_kg: float = 0.0
    action_latency: int = 0
    slope_deg: float = 0.0
    visual: VisualRandomisation | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"TargetDomain.name must be a non-empty string, got {self.name!r}")
        for field, (low, high) in TARGET_BOUNDS.items():
            value = getattr(self, field)
            kind = numbers.Integral if field == "action_latency" else numbers.Real
            if isinstance(value, bool) or not isinstance(value, kind):
                raise TypeError(f"TargetDomain.{field} must be "
                                f"{'an integer' if kind is numbers.Integral else 'a number'}, "
                                f"got {value!r} ({type(value).__name__})")
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(f"TargetDomain.{field} must lie in [{low}, {high}], got {value}")
        if self.visual is not None and not isinstance(self.visual, VisualRandomisation):
            raise TypeError(f"TargetDomain.visual must be a VisualRandomisation or None, got "
                            f"{type(self.visual).__name__}")
        self.dynamics()  # the dynamics fields' own checks

    def dynamics(self) -> DynamicsParams:
        """The dynamics part of the shift."""
        return DynamicsParams(
            friction=self.friction,
            contact_softness=self.contact_softness,
            motor_strength=self.motor_strength,
            payload_kg=self.payload_kg,
            action_latency=self.action_latency,
        )

    def replace(self, **changes) -> TargetDomain:
        """A copy with some fields changed (e.g. a milder slope)."""
        return dataclasses.replace(self, **changes)


SIM = TargetDomain(name="sim")

PRESETS: dict[str, TargetDomain] = {
    "sim": SIM,
    # Low friction on an incline: feet slip downhill (the SimDist quadruped benchmark).
    "slippery_slope": TargetDomain(name="slippery_slope", friction=0.3, slope_deg=12.0),
    # Soft, compliant ground: contacts sink and rebound slowly.
    "foam": TargetDomain(name="foam", contact_softness=8.0, friction=0.5),
    # A 30 kg load (~28% of the quadruped's 107 kg) strapped to the torso.
    "payload": TargetDomain(name="payload", payload_kg=30.0),
    # Motors deliver 45% of their nominal force.
    "weak_motors": TargetDomain(name="weak_motors", motor_strength=0.45),
    # Three control steps (60 ms at 50 Hz) between command and actuation.
    "laggy": TargetDomain(name="laggy", action_latency=3),
    # Held-out textures and camera jitter, nominal dynamics (TWIST-style evaluation).
    "unseen_scenes": TargetDomain(name="unseen_scenes",
                                  visual=VisualRandomisation.heldout_evaluation()),
}


def register_target(target: TargetDomain, overwrite: bool = False) -> TargetDomain:
    """Adds ``target`` to the named targets (``--target NAME`` in the recipes).

    Examples:
        >>> register_target(TargetDomain(name="icy_ramp", friction=0.4, slope_deg=6.0)).name
        'icy_ramp'
        >>> get_target("icy_ramp").friction
        0.4
        >>> register_target(TargetDomain(name="icy_ramp"))
        Traceback (most recent call last):
        ...
        ValueError: target 'icy_ramp' is already registered; pass overwrite=True to replace it
        >>> _ = PRESETS.pop("icy_ramp")
    """
    if not isinstance(target, TargetDomain):
        raise TypeError(f"register_target takes a TargetDomain, got {type(target).__name__}")
    if target.name in PRESETS and not overwrite:
        raise ValueError(f"target {target.name!r} is already registered; pass overwrite=True "
                         "to replace it")
    PRESETS[target.name] = target
    return target


def get_target(target: str | TargetDomain | Mapping[str, Any] | None) -> TargetDomain:
    """Resolves a preset name, a dict of :class:`TargetDomain` fields, or a ``TargetDomain``.

    A string may also be a JSON object of fields or the path of a ``.json`` file holding
    one: that is how a custom target is given on a recipe's command line
    (``--target '{"name": "icy", "friction": 0.4}'``).

    Examples:
        >>> target = get_target({"friction": 0.3, "slope_deg": 5.0})
        >>> target.name, target.friction, target.slope_deg
        ('custom', 0.3, 5.0)
        >>> get_target('{"name": "icy", "friction": 0.4}').friction
        0.4
    """
    if target is None:
        return SIM
    if isinstance(target, TargetDomain):
        return target
    if isinstance(target, Mapping):
        fields = {f.name for f in dataclasses.fields(TargetDomain)}
        unknown = sorted(map(str, set(target) - fields))
        if unknown:
            raise ValueError(f"unknown TargetDomain field(s) {unknown} in target dict; valid: "
                             f"{sorted(fields)}")
        return TargetDomain(**target)
    if isinstance(target, str) and (target.lstrip().startswith("{") or target.endswith(".json")):
        return get_target(_read_target_json(target))
    if not isinstance(target, str):
        raise TypeError(f"target must be a preset name, a dict of TargetDomain fields or a "
                        f"TargetDomain, got {type(target).__name__}")
    if target not in PRESETS:
        raise ValueError(f"unknown target domain {target!r}; valid presets: "
                         f"{', '.join(sorted(PRESETS))} (or pass a TargetDomain)")
    return PRESETS[target]


def _read_target_json(text: str) -> dict:
    source = "target JSON"
    if not text.lstrip().startswith("{"):
        path = Path(text)
        if not path.is_file():
            raise ValueError(f"target file {text!r} does not exist")
        source, text = f"target file {str(path)!r}", path.read_text()
    try:
        fields = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{source} is not valid JSON: {error}") from error
    if not isinstance(fields, dict):
        raise ValueError(f"{source} must be a JSON object of TargetDomain fields")
    return fields


def describe_ranges(training: DynamicsRandomisation | None = None) -> str:
    """A markdown table of the training ranges beside every preset's value."""
    training = training or DynamicsRandomisation()
    fields = ("friction", "contact_softness", "motor_strength", "action_latency")
    head = "| parameter | training range | " + " | ".join(PRESETS) + " |"
    rows = [head, "|" + " --- |" * (len(PRESETS) + 2)]
    for f in fields:
        lo, hi = getattr(training, f)
        vals = " | ".join(f"{getattr(t, f):g}" for t in PRESETS.values())
        rows.append(f"| {f} | {lo:g} - {hi:g} | {vals} |")
    lo, hi = training.mass
    rows.append(f"| payload_kg | mass x {lo:g} - {hi:g} | "
                + " | ".join(f"{t.payload_kg:g}" for t in PRESETS.values()) + " |")
    rows.append("| slope_deg | task's own (flat: 0) | "
                + " | ".join(f"{t.slope_deg:g}" for t in PRESETS.values()) + " |")
    return "\n".join(rows)
