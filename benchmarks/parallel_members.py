"""Pretraining K world models: in turn in one process, or side by side in K processes.

The recipe's ``--ensemble-size K`` pretrains K independent members. ``--ensemble-jobs 1``
trains them one after the other with all of the process's torch threads; the default
(``0``) gives each member its own worker process (``simdist.utils.run_jobs``) with
``threads // K`` threads. Small models scale poorly over threads, so K one-thread
processes can finish K members in far less than K times one member's time. This measures
both on the recipe's default model (``recipes/simdist_quadruped.py``'s ``new_agent``) and a
batch shaped like its own (32 slices of 16 steps, 89-D observations, 12-D actions), in the
same run, and prints seconds per member-update and the ratio.

Usage:
    python benchmarks/parallel_members.py                       # K = 2, 300 updates each
    python benchmarks/parallel_members.py --members 2 --updates 600 --threads 2

Times are wall-clock of the whole call, worker start-up (imports, ~5 s) included: what the
recipe pays. Run on quiet cores: anything else running skews both arms.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from simdist_pretrain_precision import make_batch  # noqa: E402

from simdist.pipelines.simdist import Config, new_agent  # noqa: E402
from simdist.utils import run_jobs  # noqa: E402


WARM_UP = 5


def train_member(member: int, updates: int) -> float:
    """Builds the recipe's model, runs ``updates`` pretraining updates after a few of
    warm-up; returns the seconds of those ``updates``."""
    torch.manual_seed(member)
    agent = new_agent(Config(), 89, 12)
    batch = make_batch(32, 16, 89, 12)
    for _ in range(WARM_UP):  # kernels and allocator; timed below, not here
        agent.pretrain_update(batch)
    start = time.perf_counter()
    for _ in range(updates):
        agent.pretrain_update(batch)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--members", type=int, default=2)
    parser.add_argument("--updates", type=int, default=300, help="per member")
    parser.add_argument("--threads", type=int, default=0,
                        help="torch threads in all (0: torch's default, one per core)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    threads = torch.get_num_threads()
    per_worker = max(1, threads // args.members)
    print(f"torch {torch.__version__}, cpu, {threads} threads; {args.members} members x "
          f"{args.updates} updates")
    start = time.perf_counter()
    in_turn = [train_member(m, args.updates) for m in range(args.members)]
    turn_wall = time.perf_counter() - start
    start = time.perf_counter()
    inner = run_jobs([(train_member, (m, args.updates)) for m in range(args.members)],
                     jobs=args.members, threads=per_worker)
    side_wall = time.perf_counter() - start
    work = args.members * args.updates
    print(f"{'arm':44s} {'wall s':>7s} {'ms / member-update':>18s}")
    print(f"{f'in turn, one process, {threads} threads':44s} {turn_wall:7.1f} "
          f"{1e3 * turn_wall / work:18.1f}")
    print(f"{f'side by side, {args.members} processes x {per_worker} threads':44s} "
          f"{side_wall:7.1f} {1e3 * side_wall / work:18.1f}")
    steady_turn = sum(in_turn) / work
    steady_side = max(inner) / work  # the workers overlap: the slower one sets the time
    print(f"steady state (updates only, no start-up or warm-up): in turn "
          f"{1e3 * steady_turn:.1f} ms / member-update, side by side "
          f"{1e3 * steady_side:.1f} (workers {', '.join(f'{s:.1f}' for s in inner)} s)")
    print(f"side by side / in turn: {side_wall / turn_wall:.2f}x the wall-clock, "
          f"{steady_side / steady_turn:.2f}x in the steady state")


if __name__ == "__main__":
    main()
