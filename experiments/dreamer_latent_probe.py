"""What does a pixel Dreamer's latent know of the state? (not a speed benchmark)

Filters episodes of uniform random actions (images and the privileged state of every
step, dm_control's own scene unless ``--dr``) through a saved Dreamer agent's encoder and
RSSM, as its policy does when it acts, and fits a ridge regression from the posterior
features ``[belief, stoch]`` to each state dimension on half of the episodes (ridge 0.1
on standardised features; a linear probe, so a lower bound on what the latent carries);
prints the R^2 on the other half. The same agent with its weights re-drawn (``untrained``) is the
floor: what an untrained recurrent filter of these images carries by chance.

It also asks whether the model knows what an action does (``action_response``): from the
task's initial states, ``--horizon`` steps of a constant action of -1, 0 or +1 earn a
summed reward in the simulator and, from the posterior of the same first image, in the
Dreamer's imagination; an actor learns only from the second, so a model whose imagined
rewards do not fall where the true ones do gives it nothing to learn from.

``--agent`` is a saved agent (``dreamer_agent.pt``, self-describing) or, with
``--training``, the checkpoint an online run keeps beside its episodes (``training.pt``;
``agent.pt`` in folders made before: the weights only, rebuilt as the recipe's pixel
Dreamer of ``--preset`` with the given actor form and ``--encoder``), so a run stopped
before its end can be probed.

With ``--fit-random N`` there is no agent to read: the recipe's pixel Dreamer of
``--preset`` (with ``--encoder``) is built fresh and only its world model trains, on
``N`` episodes of uniform random actions (the preset's episode length, slices and batch),
and the probe and action response are measured after each of ``--updates``: how many
updates the world model needs before its latent reads the state and its imagination
prices actions, with no actor drifting the data. ``--model`` chooses what trains: the pixel
Dreamer's world model (default), Dreamer State Recon.'s (its decoder reconstructs the
state, standardised per dimension as in the recipe, or raw with ``state_recon_raw``), or
``frame_cnn``: the same CNN with an MLP head, supervised to regress the standardised state
from one image (no RSSM; its ``r2_frame`` is a linear read of the head's outputs), which
says what a single 64 px frame shows at this encoder's capacity, or ``state``: the state
Dreamer's (the TWIST teacher's world model, which reads the state itself: a control).

With ``--actor-updates`` the fitted world model is then frozen and only the actor and
critic train, in imagination from the posterior states of the same random episodes
(``DreamerAgent.update_behaviour``), evaluated on the task's own scene after each count:
can an actor learn to act from this model at all, with no online loop, no exploration and
no model drifting under it? The ``state`` model says what such an actor reaches when the
latent is read from the state.

Usage:
    python experiments/dreamer_latent_probe.py --agent RUN/.../dreamer_agent.pt
    python experiments/dreamer_latent_probe.py --training --agent STAGE/training.pt \
        --actor-distribution trunc_normal
    python experiments/dreamer_latent_probe.py --agent A.pt --episodes 32 --steps 250 --json out.json
    python experiments/dreamer_latent_probe.py --fit-random 10 --updates 250 500 1000 \
        --encoder keypoints --json fit.json       # the world model alone, on random data
    python experiments/dreamer_latent_probe.py --fit-random 10 --updates 500 1000 \
        --model state_recon                       # State Recon.'s (state_recon_raw: raw target)
    python experiments/dreamer_latent_probe.py --fit-random 10 --updates 500 1000 \
        --model frame_cnn                         # the CNN supervised on one frame
    python experiments/dreamer_latent_probe.py --fit-random 10 --updates 1500 \
        --model state_recon --actor-updates 500 1000 2000   # then an actor on the frozen model
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch
from tqdm import tqdm

from simdist.agents import DreamerAgent
from simdist.agents.checkpoint import load_agent
from simdist.envs import VisualRandomisation
from simdist.modules.encoders import PixelEncoder
from simdist.modules.rssm import RSSMState
from simdist.objectives import TargetStandardiser
from simdist.pipelines.control import EpisodeReplay, control_env, dreamer_keys, evaluate_returns
from simdist.pipelines.locomotion import rollout
from simdist.pipelines.resumable import stage_seed
from simdist.pipelines import twist as recipe
from simdist.utils import load_checkpoint


def collect(task: str, seed: int, episodes: int, steps: int, camera_id, dr: bool) -> list:
    """Episodes of uniform random actions with ``pixels``, ``state`` and ``action``."""
    env = control_env(task, seed, pixels=True, max_episode_steps=steps, camera_id=camera_id,
                      visual=VisualRandomisation.training() if dr else None)
    out = []
    for i in range(episodes):
        env.set_seed(seed + i)
        td = env.rollout(steps, break_when_any_done=False)
        out.append(td.select("pixels", "state", "action"))
    env.close()
    return out


@torch.no_grad()
def features(agent: DreamerAgent, episode) -> torch.Tensor:
    """``[T, feature]`` posterior features: the RSSM filters the episode from its start,
    each step conditioned on the action that led to its image (zero at the first)."""
    wm = agent.world_model
    obs = episode[agent.obs_key][None]  # the image, or the state for a state Dreamer
    action = episode["action"][None].float()
    prev_action = torch.cat([torch.zeros_like(action[:, :1]), action[:, :-1]], 1)
    is_first = torch.zeros(action.shape[:2], dtype=torch.bool)
    is_first[:, 0] = True
    post = wm.rssm.observe(wm.encoder(obs), prev_action, is_first)
    return torch.cat([post["belief"], post["stoch"]], -1)[0]


def ridge_r2(x_fit, y_fit, x_test, y_test, ridge: float = 0.1) -> list[float]:
    """Per output dimension, 1 - MSE / variance on the test rows of a ridge fit.

    Examples:
        >>> _ = torch.manual_seed(0)
        >>> x = torch.randn(200, 3)
        >>> y = torch.stack([x[:, 0] * 2, torch.randn(200)], -1)
        >>> r2 = ridge_r2(x[:100], y[:100], x[100:], y[100:], ridge=1e-3)
        >>> r2[0] > 0.99, r2[1] < 0.1
        (True, True)
    """
    mean_x, std_x = x_fit.mean(0), x_fit.std(0).clamp_min(1e-6)
    mean_y = y_fit.mean(0)
    a = torch.cat([(x_fit - mean_x) / std_x, torch.ones(len(x_fit), 1)], -1).double()
    b = (y_fit - mean_y).double()
    w = torch.linalg.solve(a.T @ a + ridge * len(a) * torch.eye(a.shape[1], dtype=a.dtype),
                           a.T @ b)
    test = torch.cat([(x_test - mean_x) / std_x, torch.ones(len(x_test), 1)], -1).double()
    error = (test @ w + mean_y - y_test).pow(2).mean(0)
    return [round(float(v), 3) for v in 1 - error / y_test.double().var(0)]


def probe(agent: DreamerAgent, episodes: list) -> list[float]:
    half = len(episodes) // 2
    feats = [features(agent, e) for e in episodes]
    states = [e["state"].float() for e in episodes]
    return ridge_r2(torch.cat(feats[:half]), torch.cat(states[:half]),
                    torch.cat(feats[half:]), torch.cat(states[half:]))


def action_response(agent: DreamerAgent, task: str, seed: int, episodes: int, horizon: int,
                    camera_id, dr: bool, actions=(-1.0, 0.0, 1.0)) -> dict:
    """What ``horizon`` steps of one constant action earn, in the simulator and imagined.

    From the task's own initial states (seeds ``seed .. seed + episodes - 1``), each
    constant action is held for ``horizon`` steps in the env (summed reward: the truth)
    and, from the posterior of the same first image, in the Dreamer's imagination (summed
    predicted reward): how much of the action's consequence the model has learnt, the
    only thing its actor learns from. Returns ``{action: {"true": ..., "imagined": ...}}``
    (means over the episodes).
    """
    wm = agent.world_model
    env = control_env(task, seed, pixels=True, max_episode_steps=horizon, camera_id=camera_id,
                      visual=VisualRandomisation.training() if dr else None)
    out = {}
    for value in actions:
        true, imagined = [], []
        for i in range(episodes):
            env.set_seed(seed + i)
            held = torch.full(env.action_spec.shape, value, dtype=env.action_spec.dtype)
            td = env.rollout(horizon, actions=[held] * horizon, break_when_any_done=False)
            true.append(float(td["next", "reward"].sum()))
            with torch.no_grad():
                first = td[agent.obs_key][None, :1]
                post = wm.rssm.observe(wm.encoder(first),
                                       torch.zeros(1, 1, *env.action_spec.shape),
                                       torch.ones(1, 1, dtype=torch.bool))
                dream = wm.imagine(RSSMState(post["belief"][:, 0], post["stoch"][:, 0]),
                                   held.expand(1, horizon, *held.shape))
                imagined.append(float(wm.reward(wm.features(dream)).sum()))
        out[f"{value:+g}"] = {"true": round(sum(true) / episodes, 3),
                              "imagined": round(sum(imagined) / episodes, 3)}
    env.close()
    return out


FIT_MODELS = ("dreamer", "state_recon", "state_recon_raw", "frame_cnn", "state")


def fit_model(cfg, task: str, model: str) -> DreamerAgent:
    """A fresh agent for ``--fit-random --model``: the recipe's pixel Dreamer, its State
    Recon. (state target standardised, as the recipe's, or ``_raw``), or for
    ``frame_cnn`` the pixel Dreamer whose encoder alone will be trained, or for
    ``state`` the recipe's state Dreamer (the teacher's)."""
    n_state, n_action = recipe.state_dim(task)
    if model == "state":
        return DreamerAgent.for_state(n_state, n_action, cfg.dreamer())
    if model.startswith("state_recon"):
        config = dataclasses.replace(cfg.pixel_dreamer(),
                                     standardise_reconstruction=model == "state_recon")
        return DreamerAgent.for_pixels_state_recon(n_action, n_state, config)
    return DreamerAgent.for_pixels(n_action, cfg.pixel_dreamer())


class FrameRegressor(torch.nn.Module):
    """``frame_cnn``: the Dreamer's CNN and an MLP regress the standardised state from
    one image, supervised: what one 64 px frame shows of the state, at the encoder's
    capacity and learning rate, with no RSSM, KL or decoder in the way."""

    def __init__(self, agent: DreamerAgent, n_state: int, lr: float):
        super().__init__()
        self.encoder = agent.world_model.encoder
        width = self.encoder(torch.zeros(1, 64, 64, 3, dtype=torch.uint8)).shape[-1]
        self.head = torch.nn.Sequential(torch.nn.Linear(width, 256), torch.nn.ELU(),
                                        torch.nn.Linear(256, n_state))
        self.standardise = TargetStandardiser(n_state)
        self.optim = torch.optim.Adam(self.parameters(), lr=lr)

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(pixels))

    def update(self, batch) -> dict:
        target = self.standardise(batch["next", "state"])
        error = (self(batch["next", "pixels"]) - target).pow(2)
        loss = error.mean()
        self.optim.zero_grad(set_to_none=True)
        loss.backward()
        self.optim.step()
        return {"loss_frame": loss.detach(), **{f"mse_{i}": v for i, v in
                                                 enumerate(error.detach().flatten(0, -2).mean(0))}}

    @torch.no_grad()
    def r2(self, episodes: list) -> list[float]:
        """Held-out R^2 per state dimension of a linear read of the head's outputs."""
        half = len(episodes) // 2
        outputs = [self(e["pixels"]) for e in episodes]
        states = [e["state"].float() for e in episodes]
        return ridge_r2(torch.cat(outputs[:half]), torch.cat(states[:half]),
                        torch.cat(outputs[half:]), torch.cat(states[half:]), ridge=1e-3)


def fit_random(cfg, task: str, seed: int, episodes: int, updates: list[int], report,
               model: str = "dreamer") -> tuple[DreamerAgent, EpisodeReplay]:
    """Trains a fresh ``model`` (:data:`FIT_MODELS`) alone on ``episodes`` random-action
    episodes and calls ``report(agent, n, losses, regressor)`` after each of ``updates``
    updates (``regressor``: the :class:`FrameRegressor` of ``frame_cnn``, else None).
    Returns the agent and the replay of the random episodes."""
    agent = fit_model(cfg, task, model)
    regressor = (FrameRegressor(agent, recipe.state_dim(task)[0], cfg.pixel_dreamer().model_lr)
                 if model == "frame_cnn" else None)
    env = control_env(task, seed, pixels=True, max_episode_steps=cfg.episode_steps,
                      camera_id=cfg.camera_id)
    replay = EpisodeReplay(episodes * cfg.episode_steps, cfg.slice_len, cfg.slices)
    keys = {"dreamer": dreamer_keys("pixels"),
            "state": dreamer_keys("state")}.get(model, dreamer_keys("pixels", "state"))
    for i in tqdm(range(episodes), desc="random episodes"):
        env.set_seed(stage_seed(seed, f"fit_random/{i}"))
        with torch.no_grad():
            episode = rollout(env, None, cfg.episode_steps)
        replay.add(episode.select(*keys).to_tensordict())
    env.close()
    for n in tqdm(range(1, max(updates) + 1), desc=f"{model} updates"):
        batch = replay.sample().to(agent.device)
        out = regressor.update(batch) if regressor else agent.update_world_model(batch)
        if n in updates:
            report(agent, n, {k: round(v.item(), 4) for k, v in out.items()}, regressor)
    return agent, replay


def train_actor(cfg, agent: DreamerAgent, replay: EpisodeReplay, task: str, seed: int,
                updates: list[int], eval_episodes: int, report) -> None:
    """Trains ``agent``'s actor and critic alone, in imagination from the posterior states
    of ``replay``'s slices, on its world model frozen as it is; after each of ``updates``
    evaluates the deterministic policy on the task's own scene (``eval_episodes``
    episodes of the preset's length, seeds ``seed + 10_000 ..``) and calls
    ``report(n, losses, evaluation)``."""
    for n in tqdm(range(1, max(updates) + 1), desc="actor-critic updates"):
        batch = replay.sample().to(agent.device)
        with torch.no_grad():
            agent.model_loss(batch)  # writes the posteriors; no step on the model
        out = agent.update_behaviour(batch)
        if n in updates:
            stats = evaluate_returns(task, agent.policy(explore=False), agent.make_primer(),
                                     seed + 10_000, eval_episodes, cfg.eval_steps,
                                     pixels=agent.obs_key == "pixels", visual=None,
                                     camera_id=cfg.camera_id)
            report(n, {k: round(v.item(), 4) for k, v in out.items()},
                   {k: stats[k] for k in ("mean", "std", "returns")})


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", help="a saved pixel DreamerAgent (.pt)")
    parser.add_argument("--fit-random", type=int, metavar="N",
                        help="no --agent: train a fresh pixel Dreamer's world model alone on N "
                             "random-action episodes and probe it after each of --updates")
    parser.add_argument("--model", choices=FIT_MODELS, default="dreamer",
                        help="--fit-random: what trains: the pixel Dreamer's world model, "
                             "State Recon.'s (standardised state target, or raw), or the "
                             "Dreamer's CNN supervised to regress the state from one frame")
    parser.add_argument("--updates", type=int, nargs="+", default=[250, 500, 1000],
                        help="--fit-random: world-model updates at which to probe")
    parser.add_argument("--actor-updates", type=int, nargs="+",
                        help="--fit-random: then freeze the world model and train the actor "
                             "and critic alone, evaluating on the own scene after each count")
    parser.add_argument("--eval-episodes", type=int,
                        help="--actor-updates: evaluation episodes (default: the preset's)")
    parser.add_argument("--encoder", choices=list(PixelEncoder.ARCHS),
                        help="--training / --fit-random: the Dreamer's image encoder "
                             "(default: the preset's)")
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--episodes", type=int, default=16, help="half fit, half test")
    parser.add_argument("--steps", type=int, default=200, help="steps per episode")
    parser.add_argument("--camera-id", type=int, help="as the agent trained (default: task's)")
    parser.add_argument("--dr", action="store_true", help="the recipe's training DR scenes")
    parser.add_argument("--training", action="store_true",
                        help="--agent is an online run's training checkpoint (training.pt)")
    parser.add_argument("--preset", default="default", choices=sorted(recipe.PRESETS),
                        help="--training: the recipe preset whose pixel Dreamer it is")
    parser.add_argument("--actor-distribution", default="tanh_normal",
                        choices=["tanh_normal", "trunc_normal"],
                        help="--training: the run's actor form")
    parser.add_argument("--horizon", type=int, default=15,
                        help="steps of each constant action in the action-response check "
                             "(the Dreamer's imagination horizon)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", help="also write the result here")
    args = parser.parse_args(argv)
    if args.episodes < 2 or args.steps < 2 or args.horizon < 1:
        parser.error("need --episodes >= 2, --steps >= 2 and --horizon >= 1")
    if (args.agent is None) == (args.fit_random is None):
        parser.error("give one of --agent and --fit-random")
    if args.model != "dreamer" and args.fit_random is None:
        parser.error("--model chooses what --fit-random trains")
    if args.actor_updates and (args.fit_random is None or args.model == "frame_cnn"
                               or min(args.actor_updates) < 1):
        parser.error("--actor-updates (>= 1) trains an actor on a --fit-random world model "
                     "(not frame_cnn, which has none)")
    if args.eval_episodes is not None and (args.eval_episodes < 1 or not args.actor_updates):
        parser.error("--eval-episodes (>= 1) evaluates the actor of --actor-updates")
    if args.fit_random is not None and (args.fit_random < 1 or min(args.updates) < 1
                                        or args.training or args.dr):
        parser.error("--fit-random needs N >= 1 and --updates >= 1, and trains on dm_control's "
                     "own scene from scratch (no --training, no --dr)")
    torch.set_num_threads(args.threads)
    cfg = recipe.Config(**{**recipe.PRESETS[args.preset], "camera_id": args.camera_id,
                           "pixel_actor_distribution": args.actor_distribution,
                           **({} if args.encoder is None else {"pixel_encoder": args.encoder})})
    torch.manual_seed(args.seed)
    episodes = collect(args.task, args.seed, args.episodes, args.steps, args.camera_id, args.dr)
    result = {"agent": args.agent and str(args.agent), "task": args.task,
              "episodes": args.episodes, "steps": args.steps, "dr": args.dr,
              "camera_id": args.camera_id,
              "state_std": [round(float(v), 3)
                            for v in torch.cat([e["state"] for e in episodes]).std(0)],
              "horizon": args.horizon}

    def measure(agent) -> dict:
        return {"r2_trained": probe(agent, episodes),
                "action_response": action_response(agent, args.task, args.seed, args.episodes,
                                                   args.horizon, args.camera_id, args.dr)}

    def write() -> None:
        print(json.dumps(result))
        if args.json:
            Path(args.json).write_text(json.dumps(result, indent=1))

    if args.fit_random is not None:
        result.update(fit_random=args.fit_random, model=args.model, encoder=cfg.pixel_encoder,
                      fits=[])
        untrained = fit_model(cfg, args.task, args.model)
        result["r2_untrained"] = (FrameRegressor(untrained, recipe.state_dim(args.task)[0],
                                                 1e-3).r2(episodes)
                                  if args.model == "frame_cnn" else probe(untrained, episodes))

        def report(agent, updates, losses, regressor):
            measured = {"r2_frame": regressor.r2(episodes)} if regressor else measure(agent)
            result["fits"].append({"updates": updates, "losses": losses, **measured})
            write()

        agent, replay = fit_random(cfg, args.task, args.seed, args.fit_random,
                                   sorted(set(args.updates)), report, model=args.model)
        if args.actor_updates:
            result["actor"] = []

            def report_actor(updates, losses, evaluation):
                result["actor"].append({"updates": updates, "losses": losses,
                                        "own_scene": evaluation})
                write()

            train_actor(cfg, agent, replay, args.task, args.seed, sorted(set(args.actor_updates)),
                        args.eval_episodes or cfg.eval_episodes, report_actor)
        return
    if args.training:
        agent = DreamerAgent.for_pixels(recipe.state_dim(args.task)[1], cfg.pixel_dreamer())
        agent.load_state_dict(load_checkpoint(args.agent)["agent"])
    else:
        agent = load_agent(args.agent)
    if not isinstance(agent, DreamerAgent) or agent.obs_key != "pixels":
        parser.error(f"{args.agent} is not a pixel Dreamer agent")
    result.update(measure(agent))
    result["r2_untrained"] = probe(DreamerAgent.from_config(agent.describe()), episodes)
    write()


if __name__ == "__main__":
    main()
