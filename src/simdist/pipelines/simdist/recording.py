"""The probe (latent -> state, for pictures only) and the rerun recordings and videos of one
target episode before and after finetuning.
"""

from __future__ import annotations

from pathlib import Path

import torch

import simdist  # noqa: F401  (headless GL set-up before dm_control)
from simdist.data import load_dataset
from simdist.envs import get_target
from simdist.modules import StateDecoder
from simdist.objectives import ProbeLoss
from simdist.pipelines import locomotion_env, mean_metrics, stage_seed, train_resumable
from simdist.pipelines.simdist.config import Config
from simdist.pipelines.simdist.jobs import stage_jobs
from simdist.pipelines.simdist.models import load_agent, planning_agent, pretrained_latent_dim
from simdist.pipelines.simdist.rounds import previous_members
from simdist.utils import load_checkpoint, run_jobs, save_atomic
from simdist.viz import record_planning_episode
from simdist.viz.video import video_backend_available


def probe_stage(cfg: Config, dataset: str, pretrained: dict, stage_dir: Path,
                logger=None) -> dict:
    """A decoder latent -> privileged state on frozen pretrained latents (for pictures).

    Dynamics-only finetuning leaves the encoder unchanged, so the probe stays valid for
    every SimDist round.
    """
    agent = load_agent(cfg, pretrained)
    buffer = load_dataset(dataset, cfg.slice_len, cfg.slice_len * cfg.batch_slices)
    state_dim = buffer[:]["state"].shape[-1]
    probe = StateDecoder(agent.world_model.latent_dim, state_dim, hidden=256,
                         layers=2).to(cfg.device)
    loss = ProbeLoss(agent.world_model.encode_sequence, probe,
                     with_actions=bool(agent.world_model.encoder.action_dim))
    optim = torch.optim.Adam(loss.trainable_parameters(), lr=1e-3)

    def update(batch):
        out = loss(batch.to(cfg.device))
        optim.zero_grad(set_to_none=True)
        out["loss_probe"].backward()
        optim.step()
        return {"loss_probe": out["loss_probe"].item()}

    history = train_resumable(update, lambda: buffer.sample().reshape(-1, cfg.slice_len),
                              cfg.probe_updates, {"probe": probe, "optim": optim},
                              stage_dir / "training.pt", desc="probe decoder",
                              seed=stage_seed(cfg.seed, "probe"), logger=logger,
                              log_prefix="probe")
    save_atomic(probe.state_dict(), stage_dir / "probe.pt")
    return {"path": str(stage_dir / "probe.pt"), "state_dim": state_dim,
            "loss": mean_metrics(history)}


class FirstMemberProbe(torch.nn.Module):
    """A latent -> state probe trained on member 0, applied to an (ensemble) latent."""

    def __init__(self, probe: torch.nn.Module, latent_dim: int):
        super().__init__()
        self.probe, self.latent_dim = probe, latent_dim

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return self.probe(latent[..., :self.latent_dim])


def recording_stage(cfg: Config, pretrained: dict, probe: dict, final: dict, out: Path) -> dict:
    """rerun recordings of one target episode before and after dynamics finetuning (side
    by side, :func:`stage_jobs`)."""
    labels = (("before", None), ("after", previous_members(final, "simdist")))
    jobs, threads = stage_jobs(cfg, len(labels))
    paths = {}
    for recorded in run_jobs([(recording_job, (cfg, pretrained, probe, weights, label, out))
                              for label, weights in labels], jobs, threads=threads):
        paths.update(recorded)
    return paths


def recording_job(cfg: Config, pretrained: dict, probe: dict, weights: list[str] | None,
                  label: str, out: Path) -> dict:
    """One recording of :func:`recording_stage`: the planner on ``weights`` (None: the
    pretrained model) for one target episode, to ``rerun_{label}.rrd`` and an MP4."""
    agent = planning_agent(cfg, pretrained, weights)
    # the probe reads member 0's latent (the first slice of an ensemble's)
    probe_net = StateDecoder(pretrained_latent_dim(agent), probe["state_dim"], hidden=256,
                             layers=2)
    probe_net.load_state_dict(load_checkpoint(probe["path"]))
    probe_net = FirstMemberProbe(probe_net, pretrained_latent_dim(agent)).to(cfg.device)
    env = locomotion_env(get_target(cfg.target), 1, cfg.episode_steps, cfg.seed + 10_000,
                         task=cfg.task, upright_power=cfg.reward_upright_power,
                         primers=[agent.make_primer(cfg.planner().latency_compensation)])
    spec = env.action_spec
    policy = agent.policy(spec.space.low[0], spec.space.high[0], cfg.planner(), seed=cfg.seed)
    # the same episode also as a video, for readers without a rerun viewer (when an MP4
    # encoder is installed: run() warned before any work otherwise)
    video = out / f"planner_{label}_finetuning.mp4" if video_backend_available() else None
    path = record_planning_episode(env, policy, probe_net, str(out / f"rerun_{label}.rrd"),
                                   cfg.episode_steps, application_id=f"simdist_{label}_finetuning",
                                   video_path=video)
    env.close()
    return {label: path, **({f"video_{label}": str(video)} if video else {})}
