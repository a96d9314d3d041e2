"""Which target data would make dynamics-only finetuning work? (not a speed benchmark)

Works on a finished `recipes/simdist_quadruped.py` run (``--run``). Two steps:

``collect``: target episodes from the run's planner (pretrained or ``--weights``) with
Gaussian noise of std ``--noise`` added to every executed action (0: the recipe's own
collection), written as a memmap folder the recipe's finetuning reads.

``finetune``: the pretrained world model's dynamics finetuned (the recipe's loss, lr and
batch) on the union of ``--train`` folders (recipe round data, ``collect`` output, or
``simulator_dynamics_planner.py --save-rollouts`` output) for ``--updates`` updates; prints
the latent prediction error relative to the latent's variance (steps 1..5) on each
``--probe`` folder before and after, evaluates the finetuned planner on the recipe's
evaluation seeds and saves the weights (``--save``) for ``simulator_dynamics_planner.py
--ranking``.

    python experiments/finetune_data.py collect --run RUN --weights RUN/stages/round_4/simdist.pt \\
        --noise 0.3 --episodes 96 --out /tmp/noisy
    python experiments/finetune_data.py finetune --run RUN --train /tmp/noisy --updates 4000 \\
        --probe /tmp/climbing --save /tmp/noisy.pt
    # the planner after 2000, 8000 and 16000 updates of one run, per-episode fractions to JSON
    python experiments/finetune_data.py finetune --run RUN --train RUN/stages/round_1/data \\
        RUN/stages/round_2/data --updates 16000 --eval-at 2000 8000 16000 --json ft.json
    # the same 2000 updates with slices drawn by the model's own error (prioritised replay)
    python experiments/finetune_data.py finetune --run RUN --train RUN/stages/round_1/data \\
        RUN/stages/round_2/data --updates 2000 --priority-alpha 0.6 --json ft_prio.json
    # the same with the consistency loss over 10 predicted steps instead of the run's 5
    python experiments/finetune_data.py finetune --run RUN --train RUN/stages/round_1/data \\
        RUN/stages/round_2/data --updates 2000 --horizon 10 --json ft_h10.json
    # the same without what follows a rollover (25 steps of it kept)
    python experiments/finetune_data.py finetune --run RUN --train RUN/stages/round_1/data \\
        RUN/stages/round_2/data --updates 2000 --keep-after-rollover 25 --json ft_cut.json
    # the same, also planning with exponential moving averages of the dynamics' weights
    python experiments/finetune_data.py finetune --run RUN --train RUN/stages/round_1/data \\
        RUN/stages/round_2/data --updates 2000 --ema-decay 0.99 0.999 --json ft_ema.json
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch
from torchrl.data import SliceSampler, TensorDictReplayBuffer, TensorStorage

from simdist.data import PrioritisedSlices, prioritised_update
from simdist.envs import get_target
from simdist.objectives.simdist_pretrain import latent_prediction_error
from simdist.pipelines import as_slices, locomotion_env, rollout
from simdist.pipelines import simdist as recipe
from simdist.utils import load_memmap, save_memmap


class NoisyPolicy(torch.nn.Module):
    """A policy's action plus Gaussian noise, clamped to the action bounds."""

    def __init__(self, policy, std: float, low, high, generator):
        super().__init__()
        self.policy, self.std, self.low, self.high = policy, std, low, high
        self.generator = generator

    def forward(self, td):
        td = self.policy(td)
        action = td["action"] + self.std * torch.randn(td["action"].shape,
                                                       generator=self.generator)
        # (through the policy, so an encoder reading previous actions sees the noisy one)
        return self.policy.replace_action(
            td, torch.maximum(torch.minimum(action, self.high), self.low))


def collect(args) -> None:
    cfg, pretrained = recipe.load_finished_run(Path(args.run))
    agent = recipe.load_agent(cfg, pretrained, args.weights)
    generator = torch.Generator().manual_seed(args.noise_seed)
    batches = []
    for start in range(0, args.episodes, 32):  # 32 worlds stepped at once
        n = min(32, args.episodes - start)
        env = locomotion_env(get_target(cfg.target), n, cfg.episode_steps, args.seed + start,
                             task=cfg.task, primers=[agent.make_primer(0)])
        low, high = env.action_spec.space.low[0], env.action_spec.space.high[0]
        planner = agent.policy(low, high, cfg.planner(), seed=start)

        noisy = NoisyPolicy(planner, args.noise, low, high, generator)
        td = rollout(env, noisy, cfg.episode_steps, desc=f"collect {start}..{start + n}")
        env.close()
        print(f"episodes {start}..{start + n}: forward progress "
              f"{td['next', 'forward_progress'][:, -1].mean():.2f} m", flush=True)
        batches.append(td.select(*recipe.TARGET_KEYS))
    save_memmap(torch.cat(batches, 0), Path(args.out))


def finetune(args) -> None:
    overrides = {"finetune_lr": args.lr} if args.lr else {}
    cfg, pretrained = recipe.load_finished_run(Path(args.run), **overrides)
    torch.manual_seed(args.seed)
    agent = recipe.load_agent(cfg, pretrained, args.weights)

    def report(tag):
        with torch.no_grad():
            for path in args.probe:
                error = latent_prediction_error(agent.world_model, load_memmap(Path(path))[:, :],
                                                cfg.model_horizon)
                print(f"{tag}: relative latent prediction error on {path}: "
                      + " ".join(f"{e:.3f}" for e in error), flush=True)

    if args.horizon is not None:
        if not 1 <= args.horizon < cfg.slice_len:
            raise SystemExit(f"--horizon must lie in [1, slice_len={cfg.slice_len}), "
                             f"got {args.horizon}")
        for loss in agent.finetune_losses:  # the finetuning loss only; pretraining is done
            loss.horizon = args.horizon
    report("before")
    data = torch.cat([load_memmap(Path(p))[:, :].select(*recipe.TARGET_KEYS)
                      for p in args.train], 0)
    step = agent.finetune_update
    if args.priority_alpha < 0 or (args.priority_alpha == 0 and args.priority_beta is not None):
        raise SystemExit("--priority-alpha must be > 0 to prioritise (0: uniform slices, "
                         "where --priority-beta means nothing)")
    if args.priority_alpha > 0:
        if args.keep_after_rollover is not None:
            raise SystemExit("--priority-alpha and --keep-after-rollover do not combine")
        beta = 0.4 if args.priority_beta is None else args.priority_beta
        slices = PrioritisedSlices(data, cfg.slice_len, cfg.batch_slices, args.priority_alpha,
                                   beta)
        slices.measure_all(agent.finetune_slice_errors)
        describe_priorities(slices, data, cfg, "before finetuning")
        sample, step = slices.sample, prioritised_update(agent.finetune_update, slices)
    else:
        if args.keep_after_rollover is None:
            buffer = as_slices(data, cfg.slice_len, cfg.batch_slices)
        else:
            buffer = slices_until_rollover(data, cfg, args.keep_after_rollover)
        sample = lambda: buffer.sample().reshape(-1, cfg.slice_len)  # noqa: E731
    eval_at = set(args.eval_at or [args.updates])
    if max(eval_at) > args.updates or min(eval_at) < 0:
        raise SystemExit(f"--eval-at must lie in [0, --updates={args.updates}], got {eval_at}")
    evaluations = {}

    def evaluate(done, label=None):
        stats, _ = recipe.evaluate_planner(cfg, agent, cfg.target)
        low, high = stats["ci_fraction"]
        label = label or str(done)
        print(f"after {label} updates, planner in {cfg.target}: "
              f"{100 * stats['mean_fraction']:.0f}% [{100 * low:.0f}, {100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}) of the "
              "commanded distance", flush=True)
        evaluations[label] = {"mean_fraction": stats["mean_fraction"],
                              "fraction": [float(f) for f in stats["fraction"]]}

    # Exponential moving averages of the finetuned weights (Polyak averaging): each one
    # plans beside the raw weights at every evaluation, on the same worlds.
    if not all(0.0 < d < 1.0 for d in args.ema_decay):
        raise SystemExit(f"--ema-decay values must lie in (0, 1), got {args.ema_decay}")
    params = [p for loss in agent.finetune_losses for p in loss.trainable_parameters()]
    current = [p.detach() for p in params]  # views of the live weights, made once
    averages = {decay: [p.detach().clone() for p in params] for decay in args.ema_decay}

    def evaluate_all(done):
        evaluate(done)
        for decay, average in averages.items():
            with swapped_in(params, average):
                evaluate(done, f"{done} (weights averaged at decay {decay})")

    start = time.perf_counter()
    for i in range(args.updates):
        if i in eval_at:
            evaluate_all(i)
        metrics = step(sample())
        for decay, average in averages.items():
            torch._foreach_lerp_(average, current, 1.0 - decay)
        if i % 1000 == 0 or i == args.updates - 1:
            print(f"update {i}: consistency {metrics['loss_consistency']:.4f}", flush=True)
    if args.updates in eval_at:
        evaluate_all(args.updates)
    print(f"{args.updates} updates on {data.numel()} steps and {len(eval_at)} evaluations in "
          f"{time.perf_counter() - start:.0f} s")
    report("after")
    if args.priority_alpha > 0:
        describe_priorities(slices, data, cfg, "after finetuning")
    if args.save:
        torch.save(agent.world_model.state_dict(), args.save)
    if args.json:
        Path(args.json).write_text(json.dumps({"lr": cfg.finetune_lr, "train": args.train,
                                               "evaluations": evaluations}, indent=1))


@contextlib.contextmanager
def swapped_in(params: list[torch.Tensor], values: list[torch.Tensor]):
    """``params`` hold ``values`` inside the block and their own values again after it."""
    saved = [p.detach().clone() for p in params]
    with torch.no_grad():
        for p, v in zip(params, values):
            p.copy_(v)
    try:
        yield
    finally:
        with torch.no_grad():
            for p, v in zip(params, saved):
                p.copy_(v)


def describe_priorities(slices: PrioritisedSlices, data, cfg, when: str) -> None:
    """Where the prioritised draws go: the share of the probability on the top tenth of
    slices, and on slices with a step upside down (the rollovers that decide the slow
    command) against their share of the slices."""
    from progress_by_command import upside_down_steps  # a sibling script (benchmarks/)

    probability = slices.probabilities()
    top = probability.sort(descending=True).values[:max(1, len(slices) // 10)].sum()
    upside_down = upside_down_steps(data["next", "observation"], cfg.task).float()  # [E, T]
    windows = upside_down.unfold(1, slices.slice_len, 1).amax(-1).reshape(-1).bool()
    print(f"priorities {when}: top 10% of slices draw {100 * top:.0f}%; slices with a step "
          f"upside down are {100 * windows.float().mean():.0f}% of the slices and draw "
          f"{100 * probability[windows].sum():.0f}%; median priority "
          f"{slices.priority.median():.4f}", flush=True)


def slices_until_rollover(data, cfg, keep_after: int) -> TensorDictReplayBuffer:
    """Like ``as_slices``, but each episode ends ``keep_after`` steps after the quadruped
    first rolls onto its back (body-frame gravity z < -0.5): the rest, sliding on its back,
    is data the planner never needs and the consistency loss would still fit."""
    from progress_by_command import upside_down_steps  # a sibling script (benchmarks/)

    episodes, steps = data.shape
    if data["is_init"][:, 1:].any():
        raise SystemExit("--keep-after-rollover needs one episode per row; these data were "
                         "collected with --collect-reset-upside-down (nothing follows a "
                         "rollover there)")
    upside_down = upside_down_steps(data["observation"], cfg.task)          # [episodes, steps]
    first = torch.where(upside_down.any(1), upside_down.float().argmax(1), steps)
    keep = torch.arange(steps)[None] < (first + keep_after).clamp(max=steps)[:, None]
    flat = data.clone()
    flat.set("episode", torch.arange(episodes)[:, None].expand(episodes, steps).clone())
    flat = flat[keep]
    print(f"until rollover + {keep_after}: {int(keep.sum())} of {episodes * steps} steps kept "
          f"({int((first < steps).sum())} of {episodes} episodes rolled over)", flush=True)
    sampler = SliceSampler(slice_len=cfg.slice_len, traj_key="episode", strict_length=True)
    return TensorDictReplayBuffer(storage=TensorStorage(flat), sampler=sampler,
                                  batch_size=cfg.slice_len * cfg.batch_slices)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="step", required=True)
    c = sub.add_parser("collect", help="target episodes from the planner + action noise")
    c.add_argument("--run", required=True)
    c.add_argument("--weights", default=None, help="world-model weights (default: pretrained)")
    c.add_argument("--noise", type=float, default=0.0)
    c.add_argument("--episodes", type=int, default=96)
    c.add_argument("--seed", type=int, default=7000, help="seed of the worlds")
    c.add_argument("--noise-seed", type=int, default=1)
    c.add_argument("--out", required=True)
    f = sub.add_parser("finetune", help="dynamics-only finetuning on given data, then evaluate")
    f.add_argument("--run", required=True)
    f.add_argument("--weights", default=None, help="start from these weights (default: pretrained)")
    f.add_argument("--train", nargs="+", required=True, help="memmap folders of target data")
    f.add_argument("--updates", type=int, default=4000)
    f.add_argument("--lr", type=float, default=None, help="default: the run's finetune_lr")
    f.add_argument("--probe", nargs="*", default=[], help="folders to measure prediction error on")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--save", default=None)
    f.add_argument("--eval-at", type=int, nargs="*", default=None,
                   help="evaluate the planner after these update counts (default: --updates)")
    f.add_argument("--json", default=None, help="write each evaluation's per-episode fractions here")
    f.add_argument("--keep-after-rollover", type=int, default=None, metavar="STEPS",
                   help="end each training episode this many steps after the quadruped first "
                        "rolls onto its back (default: keep whole episodes)")
    f.add_argument("--horizon", type=int, default=None,
                   help="predicted steps of the finetuning loss (default: the run's model_horizon)")
    f.add_argument("--priority-alpha", type=float, default=0.0,
                   help="draw slices by the model's own consistency error to this power "
                        "(data/prioritised_slices.py; default 0: uniform, the recipe's)")
    f.add_argument("--priority-beta", type=float, default=None,
                   help="importance-weight exponent of the prioritised draws (default 0.4)")
    f.add_argument("--ema-decay", type=float, nargs="*", default=[],
                   help="also plan with an exponential moving average of the finetuned "
                        "weights at each of these decays, on the same worlds")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    (collect if args.step == "collect" else finetune)(args)


if __name__ == "__main__":
    main()
