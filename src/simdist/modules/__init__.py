"""World-model parts as composable modules (TensorDict adapters where keys matter)."""

from simdist.modules.augment import RandomRotate, RandomShift, ReadingNoise
from simdist.modules.encoders import (ChannelLayerNorm, HistoryEncoder, PixelEncoder,
                                      StateEncoder, simnorm)
from simdist.modules.ensemble import WorldModelEnsemble
from simdist.modules.heads import Actor, PixelDecoder, PolicyPrior, ScalarHead, StateDecoder
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig
from simdist.modules.rssm import RSSM, RSSMState
from simdist.modules.state_readout import ReadoutEncoder, StateReadout
from simdist.modules.simdist_model import SIMDIST_SIZES, MLPDynamics, SimDistWorldModel
from simdist.modules.world_model import RSSM_SIZES, DreamerWorldModel

__all__ = ["RandomShift", "RandomRotate", "ReadingNoise", "ChannelLayerNorm", "HistoryEncoder", "PixelEncoder", "StateEncoder",
           "simnorm", "Actor", "PixelDecoder",
           "PolicyPrior", "ScalarHead", "StateDecoder", "RSSM", "RSSMState", "SIMDIST_SIZES",
           "MLPDynamics", "SimDistWorldModel", "RSSM_SIZES", "DreamerWorldModel",
           "LatentMPPIPlanner", "PlannerConfig", "WorldModelEnsemble", "StateReadout",
           "ReadoutEncoder"]
