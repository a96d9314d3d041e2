"""How closely a finished SimDist run's pretrained policy prior imitates the expert.

The prior is BC-trained on the final expert's unnoised steps of the pretraining dataset
(the ``expert_active`` mask). This reads every ``--every``-th dataset episode, encodes it
with the run's pretrained encoder and prints the mean |prior - expert| over those steps,
on every joint and on the joints whose upper bound exceeds 1 (the quadruped's lift
joints, [-1, 1.1]), and on the steps where the expert went above 1.0 there: a ``tanh``
prior in [-1, 1] (``--model-prior-bounds`` off) cannot follow it there, a bounded one can.

    python experiments/prior_fit.py --run RUN/seed_0 --run OTHER/seed_0

The steps are training steps, not held-out ones: this measures what the prior's output
box lets it fit, not how it generalises.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from simdist.agents import action_bounds
from simdist.envs import make_env
from value_labels import _encode, _run


def prior_fit(run: Path, every: int) -> dict:
    """The fit figures of ``run``'s pretrained prior (see the module docstring)."""
    cfg, agent, data = _run(run)
    td = data[::every]
    wm = agent.world_model
    z = _encode(wm, td)
    with torch.no_grad():
        prior = wm.policy(z.reshape(-1, z.shape[-1])).reshape(*z.shape[:2], -1)
    action = td["action"].float()
    mask = td["expert_active"].reshape(td.shape).clone()
    mask[:, :wm.encoder.history] = False  # the encoder's window is still filling there
    env = make_env(cfg.data_task)
    high = action_bounds(env.action_spec)[1]
    env.close()
    wide = torch.nonzero(high > 1.0).flatten()
    a, p = action[mask], prior[mask]
    err = (p - a).abs()
    above = a[:, wide] > 1.0
    return {"steps": int(mask.sum()), "all": float(err.mean()),
            "wide": float(err[:, wide].mean()), "above_share": float(above.float().mean()),
            "above_error": float(err[:, wide][above].mean()),
            "above_prior": float(p[:, wide][above].mean()),
            "above_expert": float(a[:, wide][above].mean()),
            "prior_max": p[:, wide].max(0).values.tolist()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, action="append", required=True,
                        help="a finished recipe run folder (one seed's); repeatable")
    parser.add_argument("--every", type=int, default=16, help="read every n-th episode")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    print("| run | steps | mean abs error, all joints / joints with bound > 1 | steps with the "
          "expert > 1.0 there | error there | prior / expert there | prior's max there |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for run in args.run:
        f = prior_fit(run, args.every)
        print(f"| {run} | {f['steps']} | {f['all']:.3f} / {f['wide']:.3f} | "
              f"{100 * f['above_share']:.1f}% | {f['above_error']:.3f} | "
              f"{f['above_prior']:.3f} / {f['above_expert']:.3f} | "
              f"{max(f['prior_max']):.3f} |")


if __name__ == "__main__":
    main()
