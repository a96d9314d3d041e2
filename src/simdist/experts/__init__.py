"""State-based experts (TorchRL SAC) whose critics label SimDist datasets."""

from simdist.experts.committed import COMMITTED_EXPERTS, committed_expert, resolve_expert
from simdist.experts.sac import Expert, SACExpertConfig, evaluate, train_sac_expert

__all__ = ["Expert", "SACExpertConfig", "evaluate", "train_sac_expert", "COMMITTED_EXPERTS",
           "committed_expert", "resolve_expert"]
