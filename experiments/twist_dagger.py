"""Is the deployed actor what limits a TWIST student? A student-specific actor by DAgger.

TWIST deploys the teacher's actor on the student's latent. This script keeps a finished
student's world model frozen and trains a copy of the teacher's actor to act, on the
*student's* posterior features, as the teacher's actor acts on the teacher's features of
the same steps (deterministic actions, squared error): the best actor a student latent
supports. Iteration 0 fits it on the recorded data D; each further iteration (DAgger,
Ross et al. 2011) lets the student act with that actor for ``--episodes-per-iter``
episodes in training scenes, labels every visited step with the teacher (its RSSM filters
the privileged states and the executed actions), adds them to the data and refits. After
each iteration the actor is evaluated like the recipe's student (held-out scenes, the
recipe's seeds). If a better actor cannot lift the return, the latent is the limit.

Reads a ``recipes/twist_dmc.py`` output folder (its teacher stage and a student stage).

Usage:
    python recipes/twist_dmc.py --no-baselines                     # first, the recipe
    python experiments/twist_dagger.py --outputs outputs/twist_dmc --iterations 3 \
        --episodes-per-iter 8 --episodes 10

The run's own settings (its ``config.json``: episode length, camera, randomisation) are
used throughout.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import time
from pathlib import Path

import torch

from simdist.agents import TwistStudent
from simdist.agents.twist import action_error
from simdist.modules import DreamerWorldModel
from simdist.pipelines import control_env, load_episodes
from simdist.pipelines.locomotion import rollout
from simdist.pipelines import twist as recipe
from simdist.utils.stages import read_stage_record


def labelled(twist: TwistStudent, episodes: list) -> tuple[torch.Tensor, torch.Tensor]:
    """(student posterior features, the teacher's action on its own features) of every
    step of ``episodes`` (TensorDicts of one episode each, filtered one at a time so a
    long D fits in memory)."""
    features, targets = [], []
    with torch.no_grad():
        for episode in episodes:
            recipe.recorded_images(episode)  # a clear error where D holds no images
            teacher, student = twist.distillation.filter_both(episode.unsqueeze(0))
            features.append(DreamerWorldModel.features(student)[0])
            targets.append(twist.teacher.actor(DreamerWorldModel.features(teacher))[0])
    return torch.cat(features), torch.cat(targets)


def fit(actor, data: list, updates: int, batch: int, lr: float, teacher_actor) -> dict:
    """``updates`` Adam steps of squared action error on all of ``data`` so far; reports
    the fitted actor's error and, on the same steps, the teacher's actor's (TWIST's)."""
    x, y = (torch.cat(part) for part in zip(*data))
    optim = torch.optim.Adam(actor.parameters(), lr=lr)
    for _ in range(updates):
        index = torch.randint(len(x), (batch,))
        loss = action_error(actor(x[index]), y[index])
        optim.zero_grad()
        loss.backward()
        optim.step()
    with torch.no_grad():
        return {"steps": len(x), "mse": action_error(actor(x), y).item(),
                "mse_teacher_actor": action_error(teacher_actor(x), y).item()}


def run_config(outputs: Path, episodes: int) -> recipe.Config:
    """The recipe's config of the run in ``outputs`` (its config.json), with the
    evaluation's episode count."""
    path = outputs / "config.json"
    if not path.exists():
        raise FileNotFoundError(f"no recipe run at {outputs}: run `python recipes/twist_dmc.py "
                                f"--output-dir {outputs}` first")
    return dataclasses.replace(recipe.saved_config(outputs), eval_episodes=episodes)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--outputs", type=Path, default=Path("outputs/twist_dmc"))
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--student", default="twist", help="the student stage's suffix")
    parser.add_argument("--iterations", type=int, default=3, help="DAgger iterations after D")
    parser.add_argument("--episodes-per-iter", type=int, default=8)
    parser.add_argument("--updates", type=int, default=2000, help="actor updates per fit")
    parser.add_argument("--batch", type=int, default=512)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--episodes", type=int, default=10, help="held-out evaluation episodes")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    cfg = run_config(args.outputs, args.episodes)  # the run's own settings and camera
    stages = args.outputs / "stages"
    name = f"{args.task}_s{args.seed}"
    teacher_result = read_stage_record(args.outputs, f"{name}_teacher")["result"]
    twist = TwistStudent.load(stages / f"{name}_{args.student}" / "student_agent.pt")
    actor = copy.deepcopy(twist.teacher.actor)  # starts as TWIST's deployed actor

    def evaluate(a) -> dict:
        result = recipe.evaluate(cfg, args.task, args.seed, twist.policy(actor=a),
                                 twist.make_primer(), pixels=True)
        return {"mean": result["mean"], "std": result["std"], "returns": result["returns"]}

    start = time.perf_counter()
    print(json.dumps({"iteration": None, "actor": "teacher", **evaluate(twist.teacher.actor)}),
          flush=True)
    data = [labelled(twist, [e.to_tensordict() for e in load_episodes(teacher_result["data"])])]
    for iteration in range(args.iterations + 1):
        collected = None
        if iteration:  # the student acts with the current actor; the teacher labels
            env = control_env(args.task, args.seed + 100 * iteration, pixels=True,
                              visual=recipe.training_visual(cfg),
                              num_envs=args.episodes_per_iter,
                              max_episode_steps=cfg.episode_steps,
                              primer=twist.make_primer(), camera_id=cfg.camera_id)
            episodes = rollout(env, twist.policy(actor=actor), cfg.episode_steps)
            env.close()
            collected = episodes["next", "reward"].sum(1).mean().item()
            data.append(labelled(twist, list(episodes.unbind(0))))
        fitted = fit(actor, data, args.updates, args.batch, args.lr, twist.teacher.actor)
        print(json.dumps({"iteration": iteration, "actor": "dagger", **fitted,
                          "collected_return": collected, **evaluate(actor),
                          "seconds": round(time.perf_counter() - start)}), flush=True)


if __name__ == "__main__":
    main()
