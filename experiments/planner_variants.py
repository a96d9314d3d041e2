"""Which planner settings turn a pretrained SimDist world model into a good controller?

Loads the pretrained world model of a finished `recipes/simdist_quadruped.py` run
(``--run`` is its output folder) and evaluates, on the recipe's own evaluation seeds, the
policy prior alone (``prior``: the BC head, no planning) and latent MPPI under planner
variants given as ``name:field=value,field=value`` (fields of ``PlannerConfig``). Prints
% of the commanded distance, mean [bootstrap 95% CI] (IQM) per variant and domain.

    python experiments/planner_variants.py --run outputs/simdist_quadruped
    python experiments/planner_variants.py --run RUN --domains sim slippery_slope \\
        --variant "recipe:" --variant "pi50:policy_fraction=0.5" --variant "std05:init_std=0.5"

The recipe's planner (``recipe:``) is every variant's base; a variant overrides fields.
With an ensemble (several ``--weights``), the pseudo-field ``member0_parts`` (a JSON list
of ``reward``, ``value``, ``prior``) takes those parts from member 0 alone, on member 0's
latent, instead of the members' mean: which averaged part carries an ensemble's gain
(``--variant 'meanvalue:member0_parts=["reward","prior"]'``).

``--against RUN/stages/round_2.json`` pairs each variant, episode by episode, with the
recipe's own evaluation of SimDist in that round (same worlds: evaluate the round's
weights, ``--weights RUN/stages/round_2/simdist.pt``, on the round's target), and
``--against RUN/stages/zero_shot.json`` with the pretrained model's zero-shot evaluation in
each domain; ``--pool`` pools saved comparisons of several seeds without evaluating anything:

    python experiments/planner_variants.py --run RUN --domains slippery_slope \
        --weights RUN/stages/round_2/simdist.pt --variant "H60p20:horizon=60,policy_noise_steps=20" \
        --against RUN/stages/round_2.json --save-json h60p20_s0.json
    python experiments/planner_variants.py --pool h60p20_s0.json=RUN0/stages/round_2.json \
        h60p20_s1.json=RUN1/stages/round_2.json --domains slippery_slope

Several ``--weights`` files plan together as one ensemble (``WorldModelEnsemble``, e.g. two
finetunings of the same pretrained model), paired with the round that evaluated the first:

    python experiments/planner_variants.py --run RUN --domains slippery_slope \
        --weights RUN/stages/round_2/simdist.pt OTHER/stages/round_2/simdist.pt \
        --against RUN/stages/round_2.json --save-json ensemble_s0.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import time
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.envs import get_target
from simdist.modules import WorldModelEnsemble
from simdist.pipelines import simdist as recipe
from simdist.pipelines import episode_stats, locomotion_env, rollout
from simdist.pipelines.statistics import summarise, summarise_groups
from simdist.utils.stages import read_stage_file

def parse_variant(text: str) -> tuple[str, dict]:
    name, _, fields = text.partition(":")
    overrides = {}
    # commas inside a JSON list ("proposal_commands=[0.25,0.5]") do not split fields
    for item in filter(None, re.split(r",(?![^\[]*\])", fields)):
        key, _, value = item.partition("=")
        overrides[key.strip()] = json.loads(value)
    return name, overrides


def reward_calibration(td) -> dict:
    """Is the planner's model optimistic where it acts? For every step ``t`` with ``H``
    steps after it, the mean reward the planner predicted along the plan it chose
    (``("planner", "rewards")``, ``[B, T, H]``) against the mean reward the env paid over
    steps ``t .. t+H-1``; averaged over envs and steps, and their correlation."""
    predicted = td["planner", "rewards"]
    paid = td["next", "reward"].reshape(predicted.shape[:2])
    horizon, steps = predicted.shape[-1], predicted.shape[1]
    windows = paid.unfold(1, horizon, 1).mean(-1)[:, :steps - horizon]  # [B, T-H]
    planned = predicted[:, :steps - horizon].mean(-1)
    both = torch.stack([planned.flatten(), windows.flatten()])
    return {"predicted": planned.mean().item(), "paid": windows.mean().item(),
            "correlation": torch.corrcoef(both)[0, 1].item()}


class PriorPolicy(torch.nn.Module):
    """The world model's BC policy head on the encoded history (no planning)."""

    def __init__(self, planning_policy):
        super().__init__()
        self.inner = planning_policy

    def forward(self, td):
        td = self.inner(td)  # keeps the history bookkeeping identical to the planner's
        latent = td.get(("planner", "latent"))
        action = self.inner.world_model.policy(latent)
        low, high = self.inner.planner.action_low, self.inner.planner.action_high
        # what was sent, also as the next step's previous action / newest action in flight
        return self.inner.replace_action(td, torch.maximum(torch.minimum(action, high), low))


class FirstMember(torch.nn.Module):
    """Member 0's part of an ensemble part (``WorldModelEnsemble.reward_head`` etc.) on
    member 0's slice of the ensemble latent; the other members' slices are ignored."""

    def __init__(self, per_member):
        super().__init__()
        self.part, self.member_dim = per_member.parts[0], per_member.member_dim
        self.latent_dim = per_member.latent_dim

    def forward(self, latent, *rest):
        return self.part(latent[..., :self.member_dim], *rest)


ENSEMBLE_PARTS = {"reward": "reward_head", "value": "value_head", "prior": "policy_head"}


def with_member0_parts(model, parts) -> dict:
    """Swaps ``parts`` of the ensemble ``model`` for member 0's (:class:`FirstMember`) and
    returns the swapped-out modules, so that :func:`restore_parts` puts them back."""
    unknown = set(parts) - set(ENSEMBLE_PARTS)
    if unknown:
        raise ValueError(f"member0_parts: unknown part(s) {sorted(unknown)}; "
                         f"choose from {sorted(ENSEMBLE_PARTS)}")
    if parts and not isinstance(model, WorldModelEnsemble):
        raise ValueError("member0_parts needs an ensemble: give several --weights")
    swapped = {}
    for part in parts:
        attribute = ENSEMBLE_PARTS[part]
        swapped[attribute] = getattr(model, attribute)
        setattr(model, attribute, FirstMember(swapped[attribute]))
    return swapped


def restore_parts(model, swapped: dict) -> None:
    for attribute, module in swapped.items():
        setattr(model, attribute, module)


def recipe_evaluation(record: str | Path, domain: str) -> dict:
    """The recipe's SimDist evaluation (per-episode ``fraction`` and ``command_mps``) kept
    in a stage record: a round's (``round_k.json``, its target) or the zero-shot stage's
    (``zero_shot.json``, one evaluation per domain, read for ``domain``)."""
    result = read_stage_file(record)["result"]
    if "simdist_eval" in result:
        return result["simdist_eval"]
    if domain in result and "fraction" in result[domain]:
        return result[domain]
    raise ValueError(f"{record} holds no SimDist evaluation in {domain!r}: give a round's "
                     "record (round_k.json) or the zero-shot stage's (zero_shot.json)")


def paired_rows(fractions: list[float], evaluation: dict) -> tuple[list[float], dict]:
    """Per-episode differences (points of the commanded distance) of a variant's
    ``fractions`` against the recipe's ``evaluation`` on the same worlds, and the means of
    both per commanded speed (``{speed: (variant, recipe, episodes)}``)."""
    ours, theirs = torch.tensor(fractions), torch.tensor(evaluation["fraction"])
    if ours.shape != theirs.shape:
        raise ValueError(f"{len(fractions)} episodes against the record's {len(theirs)}: "
                         "evaluate the same worlds (--episodes as the run's)")
    speed = torch.tensor(evaluation["command_mps"])
    by_speed = {round(v, 6): (100 * ours[speed == v].mean().item(),
                              100 * theirs[speed == v].mean().item(), int((speed == v).sum()))
                for v in sorted(set(speed.tolist()))}
    return (100 * (ours - theirs)).tolist(), by_speed


def _print_paired(name: str, groups: list[list[float]], speeds: list[dict]) -> None:
    stats = summarise_groups(groups) if len(groups) > 1 else summarise(groups[0])
    def pooled(v, i):  # episode-weighted mean over the runs at speed v
        return sum(s[v][i] * s[v][2] for s in speeds) / sum(s[v][2] for s in speeds)
    cells = "; ".join(f"{v:g} m/s {pooled(v, 0):.0f}% vs {pooled(v, 1):.0f}%" for v in speeds[0])
    print(f"  {name} minus the recipe's evaluation, paired by episode ({len(groups)} run(s), "
          f"{stats['n']} episodes): {stats['mean']:+.1f} [{stats['ci_low']:+.1f}, "
          f"{stats['ci_high']:+.1f}]; by speed (variant vs recipe): {cells}", flush=True)


def pool(pairs: list[str], domains: list[str]) -> None:
    """Prints each saved variant's paired difference pooled over ``pairs`` of
    ``VARIANT_JSON=ROUND_JSON`` (one per seed; the interval stratified by seed)."""
    loaded = [(json.loads(Path(v).read_text()), r)
              for v, _, r in (p.partition("=") for p in pairs)]
    for name in loaded[0][0]:
        for domain in domains:
            rows = [paired_rows(saved[name][domain], recipe_evaluation(record, domain))
                    for saved, record in loaded if domain in saved.get(name, {})]
            if rows:
                _print_paired(f"{name} ({domain})", [d for d, _ in rows], [s for _, s in rows])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", help="a finished recipe output folder")
    parser.add_argument("--domains", nargs="+", default=["sim"])
    parser.add_argument("--against", default=None,
                        help="a round's stage record (or zero_shot.json for the pretrained "
                             "model): pair each evaluation with its SimDist one")
    parser.add_argument("--pool", nargs="+", default=None, metavar="VARIANT_JSON=ROUND_JSON",
                        help="pool saved --save-json files against their rounds; no evaluation")
    parser.add_argument("--variant", action="append", default=None,
                        help="name:field=value,... (PlannerConfig fields); repeatable")
    parser.add_argument("--prior", action="store_true", help="also evaluate the BC prior alone")
    parser.add_argument("--episodes", type=int, default=None, help="default: the run's")
    parser.add_argument("--weights", nargs="+", default=None,
                        help="world-model weights (default: pretrained); several plan as one "
                             "ensemble (WorldModelEnsemble, as the recipe's --ensemble-size)")
    parser.add_argument("--planner-seed", type=int, default=None,
                        help="seed of the planner's sampling (default: the run's, as the "
                             "recipe's evaluation); the worlds stay the run's")
    parser.add_argument("--calibration", action="store_true",
                        help="also print the planner's predicted reward along its chosen plan "
                             "against the reward the env then paid (see reward_calibration)")
    parser.add_argument("--save-json", default=None,
                        help="write every variant's per-episode fractions per domain here "
                             "(for paired comparisons on the same worlds)")
    args = parser.parse_args(argv)
    if args.pool:
        return pool(args.pool, args.domains)
    if not args.run:
        parser.error("--run is required unless --pool is given")
    torch.set_num_threads(1)
    run = Path(args.run)
    # read per domain up front, so that a wrong record fails before any evaluation
    against = ({d: recipe_evaluation(args.against, d) for d in args.domains}
               if args.against else None)
    cfg, pretrained = recipe.load_finished_run(
        run, **({"episodes": args.episodes} if args.episodes else {}))
    agent = recipe.planning_agent(cfg, pretrained, args.weights or [pretrained["path"]])
    variants = [parse_variant(v) for v in (args.variant or ["recipe:"])]
    if args.prior:
        variants = [("prior", None), *variants]
    print(f"run {run} (seed {cfg.seed}), {cfg.episodes} episodes of {cfg.episode_steps} steps")
    print("| variant | domain | % of commanded distance [95% CI] (IQM), on its back | s |")
    print("| --- | --- | --- | --- |")
    saved = {}
    for name, overrides in variants:
        overrides = dict(overrides) if overrides is not None else None
        swapped = with_member0_parts(agent.world_model,
                                     (overrides or {}).pop("member0_parts", []))
        planner = dataclasses.replace(cfg.planner(), **(overrides or {}))
        for domain in args.domains:
            start = time.perf_counter()
            env = locomotion_env(get_target(domain), cfg.episodes, cfg.episode_steps,
                                 cfg.seed + 10_000, task=cfg.task,
                                 primers=[agent.make_primer(planner.latency_compensation)])
            spec = env.action_spec
            policy = agent.policy(spec.space.low[0], spec.space.high[0], planner,
                                  seed=cfg.seed if args.planner_seed is None else args.planner_seed)
            if overrides is None:
                policy = PriorPolicy(policy)
            td = rollout(env, policy, cfg.episode_steps)
            stats = episode_stats(td, env.base_env.observation_layout)
            env.close()
            saved.setdefault(name, {})[domain] = [float(f) for f in stats["fraction"]]
            if args.save_json:  # rewritten after every evaluation: a killed run keeps its rows
                Path(args.save_json).write_text(json.dumps(saved, indent=1))
            low, high = stats["ci_fraction"]
            extra = ""
            if args.calibration and overrides is not None:
                c = reward_calibration(td)
                extra = (f" predicted {c['predicted']:.3f}, paid {c['paid']:.3f}, "
                         f"corr {c['correlation']:.2f} |")
            print(f"| {name} {overrides or ''} | {domain} | {100 * stats['mean_fraction']:.0f}% "
                  f"[{100 * low:.0f}, {100 * high:.0f}] ({100 * stats['iqm_fraction']:.0f}), "
                  f"{sum(stats['upside_down'])}/{len(stats['fraction'])} on its back | "
                  f"{time.perf_counter() - start:.0f} |{extra}", flush=True)
            if against is not None:
                diff, speeds = paired_rows(saved[name][domain], against[domain])
                _print_paired(name, [diff], [speeds])
        restore_parts(agent.world_model, swapped)


if __name__ == "__main__":
    main()
