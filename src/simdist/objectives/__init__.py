"""Losses, one method step each, as TorchRL ``LossModule``s that name what they train."""

from simdist.objectives.common import SimdistLoss
from simdist.objectives.distillation import TwistDistillationLoss
from simdist.objectives.dreamer import DreamerActorCriticLoss, DreamerWorldModelLoss, balanced_kl
from simdist.objectives.imagined_alignment import ImaginedAlignmentLoss
from simdist.objectives.probe import ProbeLoss
from simdist.objectives.return_scale import ReturnScale
from simdist.objectives.target_standardiser import TargetStandardiser
from simdist.objectives.simdist_pretrain import (DynamicsFinetuneLoss, SimDistPretrainLoss,
                                                latent_prediction_error, latent_prediction_skill)

__all__ = ["SimdistLoss", "TwistDistillationLoss", "DreamerActorCriticLoss",
           "DreamerWorldModelLoss", "balanced_kl", "ImaginedAlignmentLoss", "ProbeLoss",
           "ReturnScale", "TargetStandardiser",
           "DynamicsFinetuneLoss", "SimDistPretrainLoss", "latent_prediction_error",
           "latent_prediction_skill"]
