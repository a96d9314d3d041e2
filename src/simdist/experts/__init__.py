"""State-based experts (TorchRL SAC) whose critics label SimDist datasets."""

from simdist.experts.sac import Expert, SACExpertConfig, evaluate, train_sac_expert

__all__ = ["Expert", "SACExpertConfig", "evaluate", "train_sac_expert"]
