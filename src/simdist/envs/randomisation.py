"""Domain-randomisation configurations: dynamics (per episode) and visual (per step or episode).

Configs are frozen dataclasses validated on construction, so an invalid range fails where
it is written, not deep inside a rollout. Concrete draws are :class:`DynamicsParams`, which
is also how target domains (``targets.py``) describe their shifts: the physics only ever
sees one ``DynamicsParams``, composed from the randomisation draw and the target shift.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from simdist.envs.textures import check_split

Range = tuple[float, float]


def check_range(name: str, value: Range, *, minimum: float | None = None) -> Range:
    """Validates a ``(low, high)`` pair: finite, ordered, and ``>= minimum`` if given."""
    if not (isinstance(value, (tuple, list)) and len(value) == 2):
        raise ValueError(f"{name} must be a (low, high) pair, got {value!r}")
    low, high = float(value[0]), float(value[1])
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if low > high:
        raise ValueError(f"{name} range is inverted: low={low} > high={high}")
    if minimum is not None and low < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got low={low}")
    return (low, high)


@dataclass(frozen=True)
class DynamicsParams:
    """One concrete set of physics parameters, as multipliers on the nominal model.

    Attributes:
        friction: scale on every geom's sliding friction.
        mass: scale on every body's mass and inertia.
        damping: scale on every joint's damping.
        motor_strength: scale on actuator force (gain and position/velocity bias).
        contact_softness: scale on the contact time constant (``solref[0]``), the
            compliance ``1 - solimp[0:2]`` and the width ``solimp[2]``; > 1 is softer. MuJoCo clamps time
            constants below two timesteps, so values < 1 mostly act through solimp.
        action_latency: whole control steps between choosing and applying an action.
        payload_kg: mass added to the root body (inertia scaled with it).

    Examples:
        >>> DynamicsParams(friction=0.5).compose(DynamicsParams(friction=0.5)).friction
        0.25
    """

    friction: float = 1.0
    mass: float = 1.0
    damping: float = 1.0
    motor_strength: float = 1.0
    contact_softness: float = 1.0
    action_latency: int = 0
    payload_kg: float = 0.0

    def __post_init__(self):
        for field in ("friction", "mass", "damping", "motor_strength", "contact_softness"):
            value = getattr(self, field)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"DynamicsParams.{field} must be finite and > 0, got {value}")
        if int(self.action_latency) != self.action_latency or self.action_latency < 0:
            raise ValueError(f"action_latency must be an integer >= 0, got {self.action_latency}")
        if not (math.isfinite(self.payload_kg) and self.payload_kg >= 0):
            raise ValueError(f"payload_kg must be finite and >= 0, got {self.payload_kg}")

    def compose(self, other: DynamicsParams) -> DynamicsParams:
        """Applies ``other`` on top of ``self``: scales multiply, latency/payload add."""
        return DynamicsParams(
            friction=self.friction * other.friction,
            mass=self.mass * other.mass,
            damping=self.damping * other.damping,
            motor_strength=self.motor_strength * other.motor_strength,
            contact_softness=self.contact_softness * other.contact_softness,
            action_latency=self.action_latency + other.action_latency,
            payload_kg=self.payload_kg + other.payload_kg,
        )

    FIELDS = ("friction", "mass", "damping", "motor_strength", "contact_softness",
              "action_latency", "payload_kg")

    def as_array(self) -> np.ndarray:
        """The parameters as a float32 vector, in :attr:`FIELDS` order."""
        return np.array([getattr(self, f) for f in self.FIELDS], dtype=np.float32)


@dataclass(frozen=True)
class DynamicsRandomisation:
    """Per-episode dynamics randomisation ranges (multipliers on the nominal model).

    Each episode draws every scale uniformly from its range (log-uniform would favour
    neither side of 1 either, but uniform matches the SimDist reference's friction
    0.2-1.2 style of ranges). ``action_latency`` is drawn uniformly from the inclusive
    integer range.

    Examples:
        >>> dr = DynamicsRandomisation(friction=(0.5, 1.5))
        >>> p = dr.sample(np.random.default_rng(0))
        >>> 0.5 <= p.friction <= 1.5
        True
        >>> DynamicsRandomisation(friction=(1.5, 0.5))
        Traceback (most recent call last):
        ...
        ValueError: friction range is inverted: low=1.5 > high=0.5
    """

    friction: Range = (0.6, 1.4)
    mass: Range = (0.85, 1.15)
    damping: Range = (0.8, 1.2)
    motor_strength: Range = (0.8, 1.2)
    contact_softness: Range = (0.8, 1.5)
    action_latency: tuple[int, int] = (0, 1)

    def __post_init__(self):
        for field in ("friction", "mass", "damping", "motor_strength", "contact_softness"):
            low, _ = check_range(field, getattr(self, field), minimum=0.0)
            if low <= 0:
                raise ValueError(f"{field} scales must be > 0, got low={low}")
        low, high = check_range("action_latency", self.action_latency, minimum=0)
        if int(low) != low or int(high) != high:
            raise ValueError(f"action_latency must be integer steps, got {self.action_latency}")

    def sample(self, rng: np.random.Generator) -> DynamicsParams:
        """Draws one :class:`DynamicsParams`."""
        draw = {f: float(rng.uniform(*getattr(self, f)))
                for f in ("friction", "mass", "damping", "motor_strength", "contact_softness")}
        low, high = self.action_latency
        return DynamicsParams(**draw, action_latency=int(rng.integers(low, high + 1)))

    def contains(self, params: DynamicsParams) -> dict[str, bool]:
        """For each randomised field, whether ``params`` lies inside the training range."""
        out = {}
        for field in ("friction", "mass", "damping", "motor_strength", "contact_softness",
                      "action_latency"):
            low, high = getattr(self, field)
            out[field] = low <= getattr(params, field) <= high
        return out


@dataclass(frozen=True)
class VisualRandomisation:
    """Visual domain randomisation, MuJoCo-native (model edits + texture uploads).

    Args:
        textures: texture split for skybox and floor (``"train"``, ``"validation"`` or
            ``"heldout"``; see :mod:`simdist.envs.textures`), or ``None`` to keep the
            nominal textures.
        colours: colour split for robot/object materials, or ``None``.
        lighting: randomise light intensity, tint and position.
        camera: randomise the render camera's pose (TWIST: at evaluation).
        every_step: re-randomise every control step (training); ``False`` draws once
            per episode (evaluation).
        bank_size: distinct textures/colours per split.
        bank_seed: seed of the procedural banks (keep it fixed across train and eval).
        light_intensity: range of the diffuse light scale.
        camera_position_jitter: half-width (metres) of the uniform camera offset.
        camera_angle_jitter_deg: half-width of the uniform camera rotation (degrees).

    Examples:
        >>> VisualRandomisation.training().every_step
        True
        >>> VisualRandomisation.heldout_evaluation().textures
        'heldout'
    """

    textures: str | None = "train"
    colours: str | None = "train"
    lighting: bool = True
    camera: bool = False
    every_step: bool = True
    bank_size: int = 64
    bank_seed: int = 0
    light_intensity: Range = (0.3, 1.2)
    camera_position_jitter: float = 0.1
    camera_angle_jitter_deg: float = 5.0

    def __post_init__(self):
        for name in ("textures", "colours"):
            value = getattr(self, name)
            if value is not None:
                check_split(value)
        if self.bank_size < 1:
            raise ValueError(f"bank_size must be >= 1, got {self.bank_size}")
        check_range("light_intensity", self.light_intensity, minimum=0.0)
        if self.camera_position_jitter < 0 or self.camera_angle_jitter_deg < 0:
            raise ValueError("camera jitters must be >= 0")

    @classmethod
    def training(cls, **overrides) -> VisualRandomisation:
        """TWIST training: train textures and colours, re-drawn every step."""
        return dataclasses.replace(cls(), **overrides)

    @classmethod
    def validation(cls, **overrides) -> VisualRandomisation:
        """Scenes to choose on: unseen validation textures, train colours, camera jitter,
        drawn per episode, like :meth:`heldout_evaluation` but never its textures.

        Examples:
            >>> VisualRandomisation.validation().textures
            'validation'
        """
        base = cls(textures="validation", colours="train", camera=True, every_step=False)
        return dataclasses.replace(base, **overrides)

    @classmethod
    def heldout_evaluation(cls, **overrides) -> VisualRandomisation:
        """TWIST evaluation: held-out textures, train colours, camera jitter, per episode."""
        base = cls(textures="heldout", colours="train", camera=True, every_step=False)
        return dataclasses.replace(base, **overrides)
