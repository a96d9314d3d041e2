"""The paper's baselines: Dreamer from pixels (with and without visual DR, and with state
reconstruction) and Asymmetric SAC (pixel actor, privileged-state critic).
"""

from __future__ import annotations

from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.agents import AsymmetricSACAgent, AsymmetricSACConfig, DreamerAgent
from simdist.envs import VisualRandomisation
from simdist.modules import RSSM_SIZES
from simdist.pipelines import (control_env, dreamer_keys, mean_metrics, stage_seed,
                               train_dreamer_online)
from simdist.pipelines.experiment_log import make_logger
from simdist.pipelines.twist.config import Config, state_dim
from simdist.pipelines.twist.teacher import evaluate, saved_meta


def pixel_dreamer_stage(cfg: Config, task: str, seed: int, visual, stage_dir: Path,
                        state_recon: bool = False) -> dict:
    """A pixel-Dreamer baseline; ``state_recon``: its decoder reconstructs the state."""
    torch.manual_seed(seed)
    n_state, n_action = state_dim(task)
    agent = (DreamerAgent.for_pixels_state_recon(n_action, n_state, cfg.pixel_dreamer())
             if state_recon else DreamerAgent.for_pixels(n_action, cfg.pixel_dreamer())
             ).to(cfg.device)
    env = control_env(task, seed, pixels=True, visual=visual,
                      max_episode_steps=cfg.episode_steps, primer=agent.make_primer(),
                      camera_id=cfg.camera_id)
    keys = dreamer_keys("pixels", "state") if state_recon else dreamer_keys("pixels")
    out = train_dreamer_online(agent, env, cfg.online(pixels=True), stage_dir,
                               keys, desc=stage_dir.name,
                               seed=stage_seed(seed, stage_dir.name),
                               logger=make_logger(cfg.logger, cfg.output_dir))
    env.close()
    agent.save(stage_dir / "dreamer_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    policy = agent.policy(explore=False)
    result = evaluate(cfg, task, seed, policy, agent.make_primer(), pixels=True)
    if visual is None:  # also where it trained (dm_control's scene): did it learn at all?
        result["own_scene"] = evaluate(cfg, task, seed, policy, agent.make_primer(),
                                       pixels=True, own_scene=True)
    return {**result, "agent": str(stage_dir / "dreamer_agent.pt"),
            "episode_returns": out["episode_returns"], "updates": out["updates"],
            "last": mean_metrics(out["history"])}


def asymmetric_sac_stage(cfg: Config, task: str, seed: int, stage_dir: Path,
                         visual=VisualRandomisation.training()) -> dict:
    """TWIST's model-free baseline: SAC whose actor sees DR pixels (``visual``; ``None``:
    dm_control's own scene) and whose critic sees the privileged state, trained online for
    the pixel Dreamers' environment steps."""
    torch.manual_seed(seed)
    agent = AsymmetricSACAgent(*state_dim(task), AsymmetricSACConfig(
        depth=RSSM_SIZES[cfg.model_size]["depth"], lr=cfg.critic_lr, frames=cfg.sac_frames,
        n_step=cfg.sac_n_step, tau=cfg.sac_tau)).to(cfg.device)
    env = control_env(task, seed, pixels=True, visual=visual,
                      max_episode_steps=cfg.episode_steps, camera_id=cfg.camera_id,
                      primer=agent.make_primer())
    out = train_dreamer_online(agent, env, cfg.sac_online(), stage_dir,
                               dreamer_keys("pixels", "state"), desc=stage_dir.name,
                               seed=stage_seed(seed, stage_dir.name),
                               logger=make_logger(cfg.logger, cfg.output_dir))
    env.close()
    agent.save(stage_dir / "sac_agent.pt", optimisers=False, meta=saved_meta(cfg, task, seed))
    policy = agent.policy(explore=False)
    result = evaluate(cfg, task, seed, policy, agent.make_primer(), pixels=True)
    if visual is None:  # also where it trained (dm_control's scene): did it learn at all?
        result["own_scene"] = evaluate(cfg, task, seed, policy, agent.make_primer(),
                                       pixels=True, own_scene=True)
    return {**result, "agent": str(stage_dir / "sac_agent.pt"),
            "checkpoint": str(stage_dir / "training.pt"),
            "episode_returns": out["episode_returns"], "updates": out["updates"],
            "last": mean_metrics(out["history"])}
