"""Does a pixel baseline learn with more updates? (not a speed benchmark)

Trains one of the TWIST recipe's pixel-Dreamer baselines (``recipes/twist_dmc.py``'s
``pixel_dreamer_stage``: the same agent, online loop, seeding and evaluation) with one
update per ``--train-every`` agent steps instead of the recipe's 20, for ``--steps`` agent
steps, or with ``--agent sac`` its Asymmetric SAC baseline (``asymmetric_sac_stage``; the
recipe: one update of 128 transitions per 4 steps, three stacked images, 3-step returns,
Polyak rate 0.02) with ``--frames`` stacked images, ``--batch`` transitions per update
and the critic's ``--n-step`` and ``--tau`` (each defaults to the preset's), then
evaluates it twice: on the recipe's held-out scenes (held-out textures and camera
jitter, as in the recipe's table) and on dm_control's own scene (no visual randomisation:
the training scene of a no-DR run). The recipe's two blind references (zero and uniform
random actions) say what a return is worth: on cartpole-balance doing nothing scores ~750
and random actions ~320, so a baseline below them has not learned to balance.

The run resumes: rerunning with a larger ``--steps`` into the same ``--out`` continues
from the stored episodes and checkpoint (one result file per budget).

Usage:
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000          # no DR
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000 --dr     # + DR
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000 \
        --actor-distribution trunc_normal --exploration sample     # DreamerV2's actor
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000 \
        --return-normalisation percentile                           # DreamerV3's returns
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000 \
        --actor-gradient reinforce                                  # DreamerV3's estimator
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000 \
        --reward-scale 100                     # the reward weighs more in the world model
    python experiments/pixel_dreamer_budget.py --train-every 4 --steps 10000 \
        --encoder keypoints                    # spatial-softmax keypoints read the image
    python experiments/pixel_dreamer_budget.py --agent state_recon --steps 6000  # State Recon., no DR
    python experiments/pixel_dreamer_budget.py --agent state_recon --raw-state-target --steps 6000
    python experiments/pixel_dreamer_budget.py --agent sac --steps 12000   # the recipe's SAC
    python experiments/pixel_dreamer_budget.py --agent sac --n-step 1 --tau 0.005 --steps 12000
    python experiments/pixel_dreamer_budget.py --preset tiny --steps 40 --train-every 10  # the test
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from simdist.agents.checkpoint import load_agent
from simdist.agents.dreamer import RETURN_NORMALISATIONS
from simdist.objectives.dreamer import ACTOR_GRADIENTS
from simdist.envs import VisualRandomisation
from simdist.modules.encoders import PixelEncoder
from simdist.pipelines import evaluate_returns
from simdist.pipelines import twist as recipe


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=10000, help="agent steps of the online run")
    parser.add_argument("--train-every", type=int, default=4,
                        help="one update per this many agent steps (the recipe's default: 20)")
    parser.add_argument("--dr", action="store_true",
                        help="train on the recipe's visually randomised scenes (+ DR)")
    parser.add_argument("--agent", choices=["dreamer", "state_recon", "sac"], default="dreamer",
                        help="a pixel Dreamer, the pixel Dreamer whose decoder reconstructs "
                             "the privileged state (TWIST's Dreamer State Recon.), or the "
                             "Asymmetric SAC baseline")
    parser.add_argument("--frames", type=int,
                        help="SAC: stacked images the actor reads (default: the preset's "
                             "sac_frames)")
    parser.add_argument("--batch", type=int,
                        help="SAC: transitions per update (default: the preset's sac_batch)")
    parser.add_argument("--n-step", type=int,
                        help="SAC: the critic's n-step return (default: the preset's "
                             "sac_n_step)")
    parser.add_argument("--tau", type=float,
                        help="SAC: the critic targets' Polyak rate (default: the preset's "
                             "sac_tau)")
    parser.add_argument("--slices", type=int,
                        help="Dreamer: slices per update (default: the preset's slices)")
    parser.add_argument("--actor-distribution", choices=["tanh_normal", "trunc_normal"],
                        help="Dreamer: the actor's distribution (default: the preset's "
                             "pixel_actor_distribution)")
    parser.add_argument("--exploration", choices=["noise", "sample"],
                        help="Dreamer: explore with the mode plus noise or by sampling the "
                             "actor (default: the preset's pixel_exploration)")
    parser.add_argument("--return-normalisation", choices=RETURN_NORMALISATIONS,
                        help="Dreamer: the actor's returns as they come or divided by their "
                             "running percentile range, DreamerV3's (default: the preset's)")
    parser.add_argument("--actor-gradient", choices=ACTOR_GRADIENTS,
                        help="Dreamer: the actor's gradient, backpropagated through the world "
                             "model (dynamics) or the score function with the critic as "
                             "baseline (reinforce, DreamerV3's) (default: the preset's "
                             "pixel_actor_gradient)")
    parser.add_argument("--reward-scale", type=float,
                        help="Dreamer: weight of the reward term in the world model's loss "
                             "(default: the preset's pixel_reward_scale, 1)")
    parser.add_argument("--encoder", choices=list(PixelEncoder.ARCHS),
                        help="how the Dreamer reads its image (default: the preset's "
                             "pixel_encoder, the CNN)")
    parser.add_argument("--raw-state-target", action="store_true",
                        help="State Recon.: reconstruct the raw state (before 2026-12-07) "
                             "instead of the preset's standardised one")
    parser.add_argument("--actor-lr", type=float,
                        help="Dreamer: actor and critic learning rate (default: the preset's)")
    parser.add_argument("--camera-id", type=int,
                        help="render from this camera of the task's model (default: the "
                             "preset's, camera 0)")
    parser.add_argument("--device", default="cpu",
                        help="where the agent trains and acts (cpu, cuda); replay stays on "
                             "the CPU")
    parser.add_argument("--out", default="outputs/pixel_dreamer_budget")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--preset", default="default", choices=sorted(recipe.PRESETS),
                        help="the recipe preset whose Dreamer settings to use")
    args = parser.parse_args(argv)
    sac_options = {"frames": "sac_frames", "batch": "sac_batch", "n_step": "sac_n_step",
                   "tau": "sac_tau"}
    if args.agent != "sac" and any(getattr(args, o) is not None for o in sac_options):
        parser.error("--frames, --batch, --n-step and --tau are the SAC's (--agent sac)")
    dreamer_options = ("slices", "actor_distribution", "exploration", "actor_lr",
                       "return_normalisation", "actor_gradient", "reward_scale", "encoder")
    if args.raw_state_target and args.agent != "state_recon":
        parser.error("--raw-state-target is State Recon.'s (--agent state_recon)")
    if args.agent == "sac" and any(getattr(args, o) is not None for o in dreamer_options):
        parser.error("--slices, --actor-distribution, --exploration, --actor-lr, "
                     "--return-normalisation, --actor-gradient, --reward-scale and --encoder "
                     "are the Dreamer's (--agent dreamer or state_recon)")
    preset = recipe.Config(**recipe.PRESETS[args.preset])
    # a Dreamer actor option that is set names the run's folder and overrides its config
    # fields; unset, the preset's applies
    suffix, actor = "", {}
    for option, tag, fields in (("actor_distribution", "actor_", ["pixel_actor_distribution"]),
                                ("exploration", "explore_", ["pixel_exploration"]),
                                ("actor_lr", "lr", ["actor_lr", "critic_lr"]),
                                ("return_normalisation", "return_", ["return_normalisation"]),
                                ("actor_gradient", "grad_", ["pixel_actor_gradient"]),
                                ("reward_scale", "reward", ["pixel_reward_scale"]),
                                ("encoder", "encoder_", ["pixel_encoder"])):
        value = getattr(args, option)
        if value is not None:
            suffix += f"_{tag}{value:g}" if isinstance(value, float) else f"_{tag}{value}"
            actor.update(dict.fromkeys(fields, value))
    if args.raw_state_target:
        suffix += "_raw_state"
        actor["state_recon_standardise"] = False
    for option, field in sac_options.items():  # unset: the preset's own setting
        if getattr(args, option) is None:
            setattr(args, option, getattr(preset, field))
    args.slices = preset.slices if args.slices is None else args.slices
    if min(args.train_every, args.steps, args.frames, args.batch, args.n_step, args.slices) < 1:
        parser.error("need --train-every, --steps, --frames, --batch, --n-step and --slices "
                     ">= 1")
    torch.set_num_threads(args.threads)
    sac = {"sac_train_every": args.train_every, "sac_frames": args.frames,
           "sac_batch": args.batch, "sac_n_step": args.n_step,
           "sac_tau": args.tau} if args.agent == "sac" else {}
    cfg = recipe.Config(**{**recipe.PRESETS[args.preset], "tasks": [args.task],
                           "seeds": [args.seed], "env_steps": args.steps,
                           "pixel_train_every": args.train_every, "output_dir": args.out,
                           "slices": args.slices, "camera_id": args.camera_id,
                           "device": args.device,
                           "teacher_snapshots": 0, **sac, **actor})  # no teacher here: any --steps
    camera = "" if args.camera_id is None else f"_camera{args.camera_id}"
    start = time.perf_counter()
    if args.agent == "sac":
        name = "asymmetric_sac" if args.dr else "asymmetric_sac_no_dr"
        method = f"Asymmetric SAC{' + DR' if args.dr else ', no DR'}, {args.frames} frame(s)"
        stage_dir = Path(args.out) / (f"{args.task}_s{args.seed}_{name}_every{args.train_every}"
                                      f"_frames{args.frames}_batch{args.batch}"
                                      f"_n{args.n_step}_tau{args.tau:g}{camera}")
        result = recipe.asymmetric_sac_stage(
            cfg, args.task, args.seed, stage_dir,
            visual=VisualRandomisation.training() if args.dr else None)
    else:
        state_recon = args.agent == "state_recon"
        if state_recon:  # the recipe's stage trains it with DR; --dr chooses here
            name = "dreamer_state_recon" if args.dr else "dreamer_state_recon_no_dr"
            method = "Dreamer State Recon." + (" + DR" if args.dr else ", no DR")
        else:
            name = "dreamer_dr" if args.dr else "dreamer_no_dr"
            method = recipe.PIXEL_DREAMERS[name][0]
        stage_dir = Path(args.out) / (f"{args.task}_s{args.seed}_{name}_every{args.train_every}"
                                      + (f"_slices{args.slices}"
                                         if args.slices != preset.slices else "")
                                      + suffix + camera)
        visual = VisualRandomisation.training() if args.dr else None
        result = recipe.pixel_dreamer_stage(cfg, args.task, args.seed, visual, stage_dir,
                                            state_recon=state_recon)
    own_scene = result.get("own_scene")
    if own_scene is None:  # trained with DR: how does it do on dm_control's plain scene?
        agent = load_agent(result["agent"], map_location=args.device)
        own_scene = evaluate_returns(args.task, agent.policy(explore=False),
                                     agent.make_primer(), args.seed + 10_000,
                                     cfg.eval_episodes, cfg.eval_steps, pixels=True,
                                     visual=None, camera_id=cfg.camera_id)
    references = recipe.references_stage(cfg, args.task, args.seed)
    summary = {"method": method, "steps": args.steps, "frames": args.frames,
               "slices": args.slices if args.agent != "sac" else None,
               "camera_id": args.camera_id, "device": args.device,
               "actor_distribution": cfg.pixel_actor_distribution,
               "exploration": cfg.pixel_exploration, "actor_lr": cfg.actor_lr,
               "return_normalisation": cfg.return_normalisation,
               "actor_gradient": cfg.pixel_actor_gradient,
               "reward_scale": cfg.pixel_reward_scale, "encoder": cfg.pixel_encoder,
               "standardised_state_target": (cfg.state_recon_standardise
                                             if args.agent == "state_recon" else None),
               "batch": args.batch if args.agent == "sac" else None,
               "n_step": args.n_step, "tau": args.tau,
               "train_every": args.train_every, "updates": result["updates"],
               "heldout_scenes": {k: result[k] for k in ("mean", "std", "returns")},
               "own_scene": own_scene,
               "references": {kind: r["mean"] for kind, r in references.items()},
               "training_returns": result["episode_returns"], "last": result["last"],
               "seconds": time.perf_counter() - start}
    (stage_dir / f"result_{args.steps}.json").write_text(json.dumps(summary, indent=1))
    print(f"{method}, {summary['updates']} updates: held-out scenes "
          f"{result['mean']:.0f} +- {result['std']:.0f}, dm_control's scene "
          f"{own_scene['mean']:.0f} +- {own_scene['std']:.0f}; zero action "
          f"{summary['references']['zero']:.0f}, random {summary['references']['uniform']:.0f}")


if __name__ == "__main__":
    main()
