"""Data: perturbed-expert action schedules (dataset generation follows)."""

from simdist.data.perturbation import ActionPerturbation, PerturbationSchedule

__all__ = ["ActionPerturbation", "PerturbationSchedule"]
