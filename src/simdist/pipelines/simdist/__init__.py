"""SimDist on the quadruped, stage by stage: the parts ``recipes/simdist_quadruped.py`` runs.

One module per concern, in pipeline order:

- :mod:`~simdist.pipelines.simdist.config`: the typed config (one field per flag) and presets.
- :mod:`~simdist.pipelines.simdist.expert_data`: the expert and the perturbed-expert dataset.
- :mod:`~simdist.pipelines.simdist.models`: building, saving and loading the world models.
- :mod:`~simdist.pipelines.simdist.pretraining`: the world model on the dataset.
- :mod:`~simdist.pipelines.simdist.evaluation`: the expert and the planner in a domain.
- :mod:`~simdist.pipelines.simdist.frozen_parts`: the prior alone and the planner with the
  simulator as its dynamics: what the frozen parts allow.
- :mod:`~simdist.pipelines.simdist.collection`: target data collected by the planner.
- :mod:`~simdist.pipelines.simdist.rounds`: dynamics-only finetuning, the whole-model
  ablation and the continued-SAC baseline on each round's data.
- :mod:`~simdist.pipelines.simdist.recording`: the probe and the rerun recordings.
- :mod:`~simdist.pipelines.simdist.jobs`: how independent calls share the cores.
- :mod:`~simdist.pipelines.simdist.shipping`: a run's pretrained model as a shipped agent.

Each stage is a function of the config and the earlier stages' results (plain dicts, the
stage records), so a Python user can run, replace or reorder them.

Examples:
    >>> from simdist.pipelines import simdist as pipeline
    >>> cfg = pipeline.Config(**pipeline.PRESETS["tiny"])
    >>> cfg.planner().horizon, cfg.budgets_min
    (3, [0.02, 0.04])
"""

from simdist.pipelines.simdist.collection import (collect_batch, collect_batch_job,
                                                  collect_round_data, collect_target_data,
                                                  collection_batches)
from simdist.pipelines.simdist.config import (DEFAULT_EXPERT, FINETUNE_KEYS, PRESETS, SIMDIST,
                                              SIMNORM_GROUP, STEPS_PER_MINUTE, TARGET_KEYS,
                                              Config, dataset_config, observation_layout)
from simdist.pipelines.simdist.evaluation import (collect_results, evaluate, evaluate_planner,
                                                  expert_zero_shot_stage, zero_shot_job)
from simdist.pipelines.simdist.expert_data import dataset_stage, expert_stage, load_experts
from simdist.pipelines.simdist.jobs import log_trained, member_jobs, stage_jobs, updates_done
from simdist.pipelines.simdist.models import (ignored_inputs, load_agent, load_finished_run,
                                              member_paths, new_agent, planning_agent,
                                              pretrained_latent_dim, save_agent)
from simdist.pipelines.simdist.frozen_parts import (frozen_parts_stage, prior_alone_job,
                                                    prior_only, simulator_ceiling_job)
from simdist.pipelines.simdist.pretraining import (heldout_prediction_skill, member_dir,
                                                   pretrain_member, pretrain_member_job,
                                                   pretrain_stage, pretraining_buffer,
                                                   term_shares)
from simdist.pipelines.simdist.recording import (FirstMemberProbe, probe_stage,
                                                 recording_job, recording_stage)
from simdist.pipelines.simdist.rounds import (finetune_and_evaluate, finetune_member,
                                              finetune_member_job, load_round_data,
                                              member_tag, method_job, method_results,
                                              previous_members, round_data, round_stage,
                                              sac_job, sac_round)

__all__ = [
    "Config", "PRESETS", "DEFAULT_EXPERT", "FINETUNE_KEYS", "SIMDIST", "SIMNORM_GROUP",
    "STEPS_PER_MINUTE", "TARGET_KEYS", "dataset_config", "observation_layout",
    "expert_stage", "load_experts", "dataset_stage", "evaluate", "expert_zero_shot_stage",
    "evaluate_planner", "zero_shot_job", "collect_results", "ignored_inputs", "new_agent",
    "save_agent", "load_finished_run", "load_agent", "member_paths", "planning_agent",
    "pretrained_latent_dim", "heldout_prediction_skill", "term_shares", "member_dir",
    "pretrain_member", "pretrain_member_job", "pretraining_buffer", "pretrain_stage",
    "collect_target_data", "collection_batches", "collect_batch", "collect_batch_job",
    "collect_round_data", "member_tag", "finetune_member", "finetune_member_job",
    "finetune_and_evaluate", "method_results", "method_job", "previous_members",
    "load_round_data", "round_data", "round_stage", "sac_round", "sac_job", "probe_stage",
    "FirstMemberProbe", "recording_stage", "recording_job", "member_jobs", "stage_jobs",
    "updates_done", "log_trained", "frozen_parts_stage", "prior_alone_job", "prior_only",
    "simulator_ceiling_job",
]
