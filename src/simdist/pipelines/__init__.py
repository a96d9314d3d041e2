"""Pipeline steps shared by the recipes (evaluate, collect, train on slices)."""

from simdist.pipelines.locomotion import (as_slices, locomotion_env, progress_stats, rollout,
                                          train)

__all__ = ["as_slices", "locomotion_env", "progress_stats", "rollout", "train"]
