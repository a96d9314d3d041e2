"""How much does a pretrained SimDist dynamics model know beyond "nothing changes"? (not a
speed benchmark)

Works on a finished `recipes/simdist_quadruped.py` run (``--run``). On fresh-seed
perturbed-expert episodes (the recipe's held-out diagnostic data: seeds the dataset never
used), and optionally on target-domain data (``--target-data``: a round's memmap folder),
it prints per predicted step ``i``, relative to the latent's total variance
(``simdist.objectives.simdist_pretrain.latent_prediction_skill``; the recipe's pretrain
stage records the same on its held-out episodes):

- ``model``: the dynamics rolled out with the recorded actions;
- ``copy``: ``z_{t+i} = z_t`` (the residual dynamics' starting point);
- ``shuffled``: the dynamics rolled out with another window's actions (the batch permuted),
  i.e. what the model predicts when the actions are wrong;
- ``skill``: ``1 - model / copy``, the share of the latent's change the model explains;
- ``action share``: ``(shuffled - model) / (copy - model)``, the part of the model's gain
  over ``copy`` that comes from reading the actions. The planner ranks candidates only
  through what the model does with actions.

Then, per data set, how the predicted SimNorm groups (5 steps out) sit against the encoded
ones: the share of groups whose top entry holds > 0.9 / 0.99, the share *confidently
wrong* (top entry > 0.9 on another entry than the encoded group's top), and the share of
each finetuning loss's gradient on the logits (summed L2 norms over groups,
``consistency_error``'s "squared" and "kl") that falls on those confidently wrong groups.

    python experiments/latent_skill.py --run RUN [--weights RUN/stages/round_2/simdist.pt]
        [--target-data RUN/stages/round_2/data] [--episodes 32] [--horizon 5]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.data import generate_shard
from simdist.objectives.simdist_pretrain import (consistency_error, latent_prediction_skill,
                                                rollout_windows)
from simdist.pipelines import simdist as recipe
from simdist.experts import resolve_expert
from simdist.utils import load_memmap
from simdist.utils.stages import read_stage_record


def report(name: str, table: dict[str, list[float]]) -> None:
    print(f"\n{name}")
    print(f"{'step':>4} {'model':>7} {'copy':>7} {'shuffled':>9} {'skill':>6} {'action share':>13}")
    for i, (m, c, s) in enumerate(zip(table["model"], table["copy"], table["shuffled"])):
        share = (s - m) / (c - m) if c > m else float("nan")
        print(f"{i + 1:4d} {m:7.3f} {c:7.3f} {s:9.3f} {1 - m / c:6.2f} {share:13.2f}")


def group_saturation(world_model, td, horizon: int) -> dict[str, float]:
    """How confident the predicted SimNorm groups are, how often confidently wrong, and
    which share of each consistency loss's logit gradient those wrong groups receive."""
    groups = world_model.encoder.simnorm_groups
    B, T = td.batch_size[:2]
    is_init = td.get("is_init").reshape(B, T).bool()
    with torch.no_grad():
        latents = world_model.encode_sequence(td.get("observation"), is_init, td.get("action"))
        predicted, targets, mask = rollout_windows(world_model, latents, td.get("action"),
                                                   is_init, horizon)
    keep = mask[..., -1].bool()                                    # complete windows only
    p = predicted[..., -1, :][keep].float().unflatten(-1, (groups, -1))
    q = targets[..., -1, :][keep].float().unflatten(-1, (groups, -1))
    top = p.max(-1)
    wrong = (top.values > 0.9) & (top.indices != q.argmax(-1))
    out = {"median top": top.values.median().item(),
           "top > 0.5": (top.values > 0.5).float().mean().item(),
           "top > 0.9": (top.values > 0.9).float().mean().item(),
           "top > 0.99": (top.values > 0.99).float().mean().item(),
           "confidently wrong": wrong.float().mean().item()}
    for kind in ("squared", "kl"):
        logits = p.clamp_min(1e-30).log().requires_grad_(True)
        error = consistency_error(torch.softmax(logits, -1).flatten(-2), q.flatten(-2),
                                  groups, kind)
        (grad,) = torch.autograd.grad(error.sum(), logits)
        norms = grad.norm(dim=-1)
        out[f"{kind} gradient on them"] = (norms[wrong].sum() / norms.sum()).item()
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="a finished recipe run folder")
    parser.add_argument("--weights", nargs="*", default=[],
                        help="world-model files to compare (default: the pretrained one)")
    parser.add_argument("--target-data", nargs="*", default=[],
                        help="memmap folders of target episodes (a round's data)")
    parser.add_argument("--episodes", type=int, default=32, help="fresh-seed sim episodes")
    parser.add_argument("--horizon", type=int, default=5)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(0)
    cfg, pretrained = recipe.load_finished_run(Path(args.run))
    expert = read_expert(args.run)
    data_cfg = dataclasses.replace(recipe.dataset_config(cfg), episodes=args.episodes,
                                   shard_episodes=args.episodes, num_workers=1)
    sim = generate_shard(data_cfg, recipe.dataset_config(cfg).shards + 1,
                         *recipe.load_experts(expert))
    sets = {"held-out sim episodes": sim}
    sets.update({f"target data {p}": load_memmap(Path(p))[:, :] for p in args.target_data})
    for weights in args.weights or [None]:
        agent = recipe.load_agent(cfg, pretrained, weights)
        for name, td in sets.items():  # the data go where the model lives (--device cuda)
            report(f"{weights or 'pretrained'} on {name}",
                   latent_prediction_skill(agent.world_model, td.to(agent.device), args.horizon))
            print("SimNorm groups at step", args.horizon, ": " + ", ".join(
                f"{k} {100 * v:.1f}%" for k, v in group_saturation(
                    agent.world_model, td.to(agent.device), args.horizon).items()))


def read_expert(run: str) -> str:
    # a results/ record names the shipped expert relative to the repository root
    return str(resolve_expert(
        read_stage_record(run, "expert")["result"]["path"]))


if __name__ == "__main__":
    main()
