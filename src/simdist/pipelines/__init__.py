"""Pipeline steps shared by the recipes (evaluate, collect, train on slices, baselines)."""

from simdist.pipelines.locomotion import (as_slices, locomotion_env, progress_stats, rollout,
                                          train)
from simdist.pipelines.policy_finetune import OfflineSAC, OfflineSACConfig
from simdist.pipelines.resumable import mean_metrics, train_resumable, weights

__all__ = ["as_slices", "locomotion_env", "progress_stats", "rollout", "train", "OfflineSAC",
           "OfflineSACConfig", "mean_metrics", "train_resumable", "weights"]
