"""Agents: own the optimisers and loops around the world models and losses."""

from simdist.agents.dreamer import DreamerAgent, DreamerConfig, DreamerPolicy
from simdist.agents.simdist import SimDistAgent, SimDistConfig, SimDistPolicy
from simdist.agents.twist import TwistConfig, TwistStudent
from simdist.agents.checkpoint import load_agent
from simdist.agents.action_spec import action_bounds
from simdist.agents.asymmetric_sac import AsymmetricSACAgent, AsymmetricSACConfig

__all__ = ["DreamerAgent", "DreamerConfig", "DreamerPolicy", "TwistConfig", "TwistStudent",
           "SimDistAgent", "SimDistConfig", "SimDistPolicy", "load_agent", "action_bounds",
           "AsymmetricSACAgent", "AsymmetricSACConfig"]
