"""Does SAC learn cartpole-balance from the state at the Asymmetric SAC's budget?

A control for the TWIST recipe's Asymmetric SAC baseline (``experiments/pixel_dreamer_budget.py
--agent sac``): the same TorchRL ``SACLoss`` settings (two Q-nets, learned temperature from
0.1, Adam 3e-4, 256-wide MLPs, batch 128, 1000 random steps first) but the actor reads the
5-d state as the critic does, so no perception is involved. If this does not learn at a
budget, the pixel baseline cannot be expected to either. Not a speed benchmark.

Usage:
    python experiments/state_sac_budget.py --steps 12000 --train-every 4               # 3000 updates
    python experiments/state_sac_budget.py --steps 12000 --train-every 1               # 11000
    python experiments/state_sac_budget.py --steps 12000 --n-step 3 --tau 0.02
"""

from __future__ import annotations

import argparse
import json
import time

import torch
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from torchrl.objectives import SACLoss, SoftUpdate

from simdist.experts.networks import make_actor, make_critic
from simdist.pipelines import control_env

TASK = "cartpole-balance"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=12000, help="agent steps")
    parser.add_argument("--train-every", type=int, default=4)
    parser.add_argument("--tau", type=float, default=0.005)
    parser.add_argument("--n-step", type=int, default=1)
    parser.add_argument("--prefill", type=int, default=1000, help="random-action steps first")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--layer-norm", action="store_true",
                        help="LayerNorm on the state input of actor and critic (the expert's)")
    args = parser.parse_args(argv)
    if min(args.steps, args.train_every, args.n_step, args.eval_episodes) < 1:
        parser.error("need --steps, --train-every, --n-step and --eval-episodes >= 1")
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    env = control_env(TASK, args.seed, pixels=False, max_episode_steps=500)
    actor = make_actor(5, env.action_spec, 256, obs_key="state", layer_norm=args.layer_norm)
    critic = make_critic(5, 1, 256, obs_key="state", layer_norm=args.layer_norm)
    loss = SACLoss(actor, critic, num_qvalue_nets=2,
                   loss_function="l2", alpha_init=0.1)
    loss.make_value_estimator(gamma=0.99)
    target = SoftUpdate(loss, tau=args.tau)
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)
    replay = TensorDictReplayBuffer(storage=LazyTensorStorage(args.steps), batch_size=128)
    td, episode_return, returns, recent, updates = env.reset(), 0.0, [], [], 0
    start, out = time.perf_counter(), None
    for t in range(args.steps):
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            if t < args.prefill:
                td["action"] = env.action_spec.rand()
            else:
                actor(td)
        td = env.step(td)
        episode_return += float(td["next", "reward"])
        recent.append(td.select("state", "action", ("next", "state"), ("next", "reward"),
                                ("next", "terminated"), ("next", "done")).clone())
        if len(recent) >= args.n_step:  # cartpole never terminates: n full steps
            step = recent[-args.n_step].clone()
            step["next", "reward"] = sum(0.99 ** i * recent[-args.n_step + i]["next", "reward"]
                                         for i in range(args.n_step))
            step["next", "state"] = recent[-1]["next", "state"]
            step["steps_to_next_obs"] = torch.tensor([float(args.n_step)])
            replay.add(step)
        done = bool(td["next", "done"])
        td = step_mdp(td)
        if done:
            returns.append(round(episode_return))
            episode_return, td, recent = 0.0, env.reset(), []
        if t >= args.prefill and t % args.train_every == 0:
            out = loss(replay.sample())
            total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
            optim.zero_grad()
            total.backward()
            optim.step()
            target.step()
            updates += 1
    evaluation = {}
    # the mean action (tanh of the Gaussian's mean) and a sampled one, on the same worlds:
    # a gap between them says where the balancing lives
    for kind, exploration in (("mean_action", ExplorationType.DETERMINISTIC),
                              ("sampled_action", ExplorationType.RANDOM)):
        evaluation[kind] = []
        with torch.no_grad(), set_exploration_type(exploration):
            for episode in range(args.eval_episodes):
                eval_env = control_env(TASK, args.seed + 10_000 + episode, pixels=False,
                                       max_episode_steps=500)
                rollout = eval_env.rollout(500, actor)
                evaluation[kind].append(round(float(rollout["next", "reward"].sum())))
                evaluation[f"{kind}_abs"] = float(rollout["action"].abs().mean())
                eval_env.close()
    result = {**vars(args), "updates": updates, "training_returns": returns,
              "q_end": -float(out["loss_actor"].detach()) if out is not None else None,
              "eval_returns": evaluation["mean_action"],
              "eval_mean": sum(evaluation["mean_action"]) / args.eval_episodes,
              "eval_sampled_returns": evaluation["sampled_action"],
              "eval_sampled_mean": sum(evaluation["sampled_action"]) / args.eval_episodes,
              "last_episode_mean_abs_action": {k: evaluation[f"{k}_abs"]
                                               for k in ("mean_action", "sampled_action")},
              "seconds": round(time.perf_counter() - start)}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
