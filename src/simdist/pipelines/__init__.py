"""Pipeline steps shared by the recipes (evaluate, collect, train on slices, baselines)."""

from simdist.pipelines.control import (EpisodeReplay, control_env, dreamer_keys,
                                       evaluate_returns, returns_stats)
from simdist.pipelines.evaluate_agent import evaluate_agent, record_video
from simdist.pipelines.locomotion import (as_slices, episode_stats, locomotion_env,
                                          progress_stats, rollout)
from simdist.pipelines.online_dreamer import (OnlineConfig, load_episodes, snapshot_paths,
                                              train_dreamer_online)
from simdist.pipelines.policy_finetune import OfflineSAC, OfflineSACConfig
from simdist.pipelines.reference_policies import ReferencePolicy
from simdist.pipelines.simulator_dynamics import SimulatorDynamics, SimulatorPlanningPolicy
from simdist.pipelines.resumable import mean_metrics, stage_seed, train_resumable, weights

__all__ = ["EpisodeReplay", "control_env", "dreamer_keys", "evaluate_returns", "returns_stats",
           "OnlineConfig", "load_episodes", "snapshot_paths", "train_dreamer_online",
           "as_slices", "locomotion_env",
           "episode_stats", "progress_stats", "rollout", "OfflineSAC", "OfflineSACConfig", "mean_metrics", "stage_seed", "train_resumable", "weights",
           "evaluate_agent", "record_video", "SimulatorDynamics", "SimulatorPlanningPolicy",
           "ReferencePolicy"]
