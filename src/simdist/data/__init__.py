"""Data: perturbed-expert action schedules, policy mixtures and on-disk datasets."""

from simdist.data.cotraining import CoTrainingSlices
from simdist.data.dataset import (DatasetConfig, collect_shards, generate_dataset, generate_shard,
                                  load_dataset, shard_seed)
from simdist.data.mixture import EpisodeMixture
from simdist.data.perturbation import ActionPerturbation, PerturbationSchedule
from simdist.data.prioritised_slices import PrioritisedSlices, prioritised_update

__all__ = ["ActionPerturbation", "PerturbationSchedule", "EpisodeMixture", "DatasetConfig",
           "collect_shards", "generate_dataset", "generate_shard", "load_dataset", "shard_seed",
           "PrioritisedSlices", "prioritised_update", "CoTrainingSlices"]
