"""A finished SimDist recipe run's forward progress split by commanded speed.

The recipe draws one of three commanded speeds per evaluation episode and reports the
mean over all episodes; this prints every point again per speed (mean, bootstrap 95% CI
over that speed's episodes, episode count), for one seed's folder or a multi-seed
folder's pooled table. Runs written before the recipe kept each episode's speed
(``command_mps``) get it back from their records: fraction = progress / (speed x
episode duration), so speed = progress / fraction / duration.

    python experiments/progress_by_command.py --run outputs/simdist_quadruped
    python experiments/progress_by_command.py --run MULTI_SEED_OUT    # after --seeds 0 1 2
    python experiments/progress_by_command.py --run RUN --data RUN/stages/round_2/data

``--data``: target episodes the recipe recorded (a round's memmap folder); prints per
commanded speed how many of them ended upside down at some step (the body-frame gravity
sensor's z below -0.5: the quadruped rolled onto its back), which way they went over
(the first step tipped 60 degrees from upright: body-frame gravity x below -|y|, nose up,
is over the tail), how many steps that took from a nose-up pitch of 27 degrees, and their
mean reward.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from simdist.envs.quadruped import CONTROL_TIMESTEP
from simdist.pipelines.locomotion import TIPPED, UPSIDE_DOWN
from simdist.pipelines.report import REFERENCES, format_by_command
from simdist.pipelines.simdist import observation_layout  # cached per task
from simdist.utils import load_memmap


def with_commands(point: dict, episode_s: float) -> dict:
    """``point`` with ``command_mps`` recovered from progress and fraction when absent."""
    if "command_mps" in point:
        return point
    progress = np.asarray(point["progress_m"], dtype=np.float64)
    fraction = np.asarray(point["fraction"], dtype=np.float64)
    if np.any(fraction == 0):  # 0 m of progress: the speed cannot be recovered
        raise ValueError("an episode with zero progress: its commanded speed cannot be "
                         "recovered; rerun the point with the current recipe")
    return {**point, "command_mps": np.round(progress / fraction / episode_s, 3).tolist()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, type=Path,
                        help="a finished recipe output folder (its results.json)")
    parser.add_argument("--data", nargs="*", default=[], type=Path,
                        help="memmap folders of recorded target episodes (a round's data)")
    args = parser.parse_args(argv)
    path = args.run / "results.json"
    if not path.exists():
        raise SystemExit(f"no results.json in {args.run}: is the run finished?")
    results = json.loads(path.read_text())
    episode_s = results["config"]["episode_steps"] * CONTROL_TIMESTEP
    curves = {name: (points if name == "minutes" else
                     with_commands(points, episode_s) if name in REFERENCES else
                     [with_commands(p, episode_s) for p in points])
              for name, points in results["curves"].items()}
    print(format_by_command(curves, results["config"]["target"]))
    for folder in args.data:
        print(f"\n{folder}")
        print(flips_by_command(load_memmap(folder)[:, :], results["config"]["task"]))


def upside_down_steps(observation, task: str):
    """``[episodes, steps]`` bool: the quadruped is on its back (gravity's body-frame z)."""
    return observation[..., observation_layout(task)["gravity"].start + 2] < UPSIDE_DOWN


# Nose up by 27 degrees from the horizontal (gravity x < -0.45; on a 12 degree slope a body
# parallel to the ground reads -0.21): where a tip over the tail is seen coming.
NOSE_UP = -0.45


def tip_overs(gravity: np.ndarray) -> tuple[int, int, list[int]]:
    """Of the episodes' body-frame gravity readings (a list of ``[steps, 3]`` arrays), how
    many tipped over, how many of those over the tail (x below -|y| at the first tipped
    step) and, for each of these, the steps from the first nose-up reading before it to
    the tipped one."""
    count, over_tail, lead = 0, 0, []
    for g in gravity:
        tipped = np.flatnonzero(g[:, 2] < TIPPED)
        if not len(tipped):
            continue
        count += 1
        t = tipped[0]
        if g[t, 0] < -abs(g[t, 1]):
            over_tail += 1
            nose_up = np.flatnonzero(g[:t + 1, 0] < NOSE_UP)
            lead.append(int(t - nose_up[0]) if len(nose_up) else 0)
    return count, over_tail, lead


def flips_by_command(td, task: str) -> str:
    """Per commanded speed: episodes, steps, how many episodes rolled onto their back, how
    many tipped over the tail and how long that took from a nose-up pitch (median steps),
    mean reward per step. A row that holds several episodes (collected with
    ``--collect-reset-upside-down``: a world on its back starts a new episode, with a newly
    drawn command) counts each of them."""
    obs = td["observation"]
    rows, steps = obs.shape[:2]
    starts = td["is_init"].reshape(rows, steps).clone()
    starts[:, 0] = True
    episode = (starts.reshape(-1).long().cumsum(0) - 1)  # one id per episode
    layout = observation_layout(task)
    command = obs.reshape(rows * steps, -1)[:, layout["command"].start].double()
    first = starts.reshape(-1).nonzero().squeeze(-1)
    episode_command = command[first].round(decimals=6)
    count = len(first)
    # step t's reading after it (next observation) belongs to step t's episode; the
    # observation of the step after a reset is already the new episode's upright start
    flipped = upside_down_steps(td["next", "observation"], task) | upside_down_steps(obs, task)
    rolled = torch.zeros(count, dtype=torch.bool).index_put_(
        (episode,), flipped.reshape(-1), accumulate=True)
    length = torch.bincount(episode, minlength=count)
    reward = torch.zeros(count, dtype=torch.float64).index_add_(
        0, episode, td["next", "reward"].reshape(-1).double())
    # the reading after each step, split into episodes at their starts
    gravity = td["next", "observation"][..., layout["gravity"]].reshape(rows * steps, 3)
    bounds = first.tolist() + [rows * steps]
    episodes = [gravity[a:b].double().numpy() for a, b in zip(bounds[:-1], bounds[1:])]
    lines = ["| speed (m/s) | episodes | steps | rolled onto their back | tipped over (over the tail) "
             "| steps from nose-up to tipped (median) | mean reward per step |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for speed in sorted(set(episode_command.tolist())):
        chosen = episode_command == speed
        tipped, over_tail, lead = tip_overs([e for e, c in zip(episodes, chosen.tolist()) if c])
        lines.append(f"| {speed:g} | {int(chosen.sum())} | {int(length[chosen].sum())} | "
                     f"{int(rolled[chosen].sum())} | {tipped} ({over_tail}) | "
                     f"{f'{np.median(lead):.0f}' if lead else '-'} | "
                     f"{float(reward[chosen].sum() / length[chosen].sum()):.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
