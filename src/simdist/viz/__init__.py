"""Visualisation: rerun recordings of plans and rollouts."""

from simdist.viz.episode import QUADRUPED_BODIES, record_planning_episode
from simdist.viz.kinematics import BodyPositions, decode_plans
from simdist.viz.rerun_log import PlanningRecorder, entity_paths, spawn_viewer
from simdist.viz.video import video_backend_available, write_mp4

__all__ = ["BodyPositions", "decode_plans", "PlanningRecorder", "entity_paths",
           "QUADRUPED_BODIES", "record_planning_episode", "spawn_viewer",
           "write_mp4", "video_backend_available"]
