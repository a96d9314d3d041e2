"""Where does a TWIST student lose return? Experiments on a finished ``twist_dmc`` run.

Reads the teacher stage a ``recipes/twist_dmc.py`` run left in ``--outputs`` (its
checkpoint and the recorded data D = {(s, o, a, r)}) and runs one of:

- ``state``: the same distillation (Eq. 3 + Eq. 4, same budget) but the student RSSM
  reads the privileged *state* instead of pixels, evaluated on state: what distillation
  gives with perfect perception.
- ``positions``: as ``state``, but the student reads only some state dimensions
  (``--positions``, default the cartpole's x, cos, sin: what one image can show), exactly:
  a student with perfect perception of positions, which must infer the velocities itself.
  ``--init-rssm`` starts its RSSM as the teacher's; ``--slices`` and ``--lr`` change the
  student's batch and learning rate.
- ``pixels``: the recipe's student again, at other update budgets.
- ``init``: the pixel student with its RSSM (all but the encoder-facing layers whose
  shapes differ) initialised from the teacher's weights.
- ``warm``: the pixel student with a warm-started encoder: first trained alone, on
  single images of D, to regress the frozen teacher's *state embedding* of the same step
  (``--warm-updates`` updates of ``--batch`` images, an MLP head mapping the encoder's
  output to the teacher's embedding), then that encoder + head feed a student RSSM
  initialised from the teacher's (same shapes), then the usual Eq. 3 + Eq. 4 updates;
  prints the return and latent R^2 after the warm start (0 updates) and each budget.
- ``noisy``: no student: the teacher itself on state with Gaussian noise added to the
  state it reads, ``--noise`` times each dimension's standard deviation in D (all
  dimensions, then the pole's sine alone, then the pole's angular velocity alone): how
  precise must a student's perception be to keep the Oracle's return?
- ``readout``: a two-part student: the probe's CNN and a linear head trained supervised
  (``--warm-updates`` updates of ``--batch`` images, ``--shift``, ``--lr``) to regress the
  state from one image, then frozen, and a ``positions`` student RSSM that reads the
  readout's ``--positions`` instead of the exact ones (``--extra-renders K``: the readout
  also sees each training state under K more draws); prints the readout's error on
  D's balancing states (D's images and the same states under the held-out scenes).
  ``--readout-file F`` freezes a readout fitted elsewhere instead (a ``StateReadout``
  file, ``.pt`` and ``.json``: e.g. the committed
  ``src/simdist/checkpoints/twist_readout/cartpole-balance.pt``, or one written by
  ``experiments/twist_readout_scale.py --save-readouts``).
- ``delayed``: no student: the Oracle reading the state ``--delays`` control steps late
  (a student whose latent lags the scene keeps at most this).
- ``probe``: the student's CNN trained *supervised* to regress the state from one
  randomised image (5/6 of D's images to train, 1/6 held out); prints R^2 per state
  dimension: can the encoder see what the teacher's latent needs? Options: the encoder
  (``--depth``, ``--norm layer``, ``--input-norm image``), augmentation (``--shift``,
  ``--rotate``), ``--extra-renders K`` (D's training states rendered K more times under
  other training randomisations) and ``--heldout-renders`` (the test states re-rendered
  under the recipe's evaluation scenes, with and without the camera jitter) and
  ``--train-camera`` (the training images are D's states re-rendered under the recipe's
  ``train_camera`` randomisation: a camera-pose draw per image, so one teacher serves both
  arms). ``--frames 2`` reads each recorded image together with the one a control step
  earlier (the shared encoder's features and their change, one shift for both): can two
  frames give the velocities one image cannot? For cartpole, one frame, it prints the RMSE per
  state dimension on the *balancing* test states (pole within 0.3 rad of upright, cart in
  view; ``balancing_rmse_*`` next to their ``balancing_std``): most of D is a fallen pole
  or a cart out of view, so R^2 over all of D hides the precision a balancing policy needs.

Which data the probe and the students train on: ``--train-states balancing`` keeps
only D's balancing states (the pixel students: only runs of such steps at least a
slice long, each replayed as an episode), ``--train-states in_view`` those with the cart
in the camera's view, ``--recent-episodes N`` only the last N episodes, and
``--teacher-episodes K`` adds K episodes of the *final* teacher acting on state (with its
collection noise, under the training randomisation, recorded like D) after D: with
``--recent-episodes K`` the student trains on them alone. The test sets and the latent
R^2 slices stay D's.

``pixels`` prints, after each budget, the held-out return and the student's latent R^2
(and, with ``--eval-scenes heldout_nocam training``, the return on held-out textures
without the camera jitter and on training scenes):
the teacher's decoder applied to the student's posterior features on 128 slices of D's
recorded images, per state dimension (``latent_r2``; ``teacher_r2``: the same with the
teacher's own posterior, the ceiling). ``--train-camera`` trains the student on D with
every image re-rendered under the ``train_camera`` randomisation (same states, actions
and rewards: what a teacher stage with ``train_camera=True`` would record, on the same
teacher); ``--standardise-belief`` turns on ``TwistConfig.standardise_belief`` and
``--action-weight W`` ``TwistConfig.action_weight`` (the teacher's actor on the student's
latent is trained to act as on the teacher's: the latent error that moves the policy).

Every figure in the README's TWIST "honest reading" comes from this script or from
``experiments/twist_dagger.py`` (a student-specific actor by DAgger).

Usage:
    python recipes/twist_dmc.py                                  # first, the recipe
    python experiments/twist_diagnosis.py state --updates 300,900
    python experiments/twist_diagnosis.py positions --updates 300,900 --episodes 10 \
        [--lr 1e-3 --slices 16] [--init-rssm]
    python experiments/twist_diagnosis.py pixels --updates 300,900 [--lr 1e-3]
    python experiments/twist_diagnosis.py pixels --updates 300,900 --render-camera 0 \
        --outputs RUN_WITH_CAMERA_1 --name cam0   # same teacher and D, the other camera
    python experiments/twist_diagnosis.py init --updates 300,600
    python experiments/twist_diagnosis.py probe --updates 1500 --batch 400
    python experiments/twist_diagnosis.py probe --updates 300,600,900 --batch 128 \
        --heldout-renders --norm layer --input-norm image --shift 4
    python experiments/twist_diagnosis.py probe ... --train-camera   # H1, camera in training
    python experiments/twist_diagnosis.py probe --updates 600 --batch 128 --heldout-renders \
        --norm layer --input-norm image --shift 4 --arch keypoints --lr 1e-3
    python experiments/twist_diagnosis.py probe --updates 600,1500 --batch 128 --norm layer \
        --input-norm image --shift 4 --arch keypoints --lr 1e-3 --frames 2   # image pairs
    python experiments/twist_diagnosis.py noisy --noise 0,0.1,0.3,0.5 --episodes 10
    python experiments/twist_diagnosis.py warm --warm-updates 1200 --updates 0,300 \
        --arch keypoints --episodes 10
    python experiments/twist_diagnosis.py pixels --updates 300 --episodes 10 \
        --train-camera | --standardise-belief | --action-weight 10 --name ARM
    python experiments/twist_diagnosis.py delayed --delays 0,1,2,3,4 --episodes 10
    python experiments/twist_diagnosis.py probe --updates 1500 --batch 128 --heldout-renders \
        --norm layer --input-norm image --shift 4 --lr 1e-3 --depth 32 --train-states balancing
    python experiments/twist_diagnosis.py pixels --updates 300,900 --lr 1e-3 --slices 16 \
        --init-rssm --episodes 10 --teacher-episodes 16 --recent-episodes 16 --name final16
    python experiments/twist_diagnosis.py readout --updates 300,900 --lr 1e-3 --slices 16 \
        --init-rssm --episodes 10 --warm-updates 1500 --batch 128 --shift 4 --norm layer \
        --input-norm image --depth 32 [--train-states balancing] [--teacher-episodes 16 \
        --recent-episodes 16] --name ARM
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import time
from pathlib import Path

import torch

from simdist.pipelines import twist as recipe  # (config and stage helpers)
from simdist.agents import DreamerPolicy, TwistStudent
from simdist.envs import VisualRandomisation
from simdist.modules import (RSSM_SIZES, DreamerWorldModel, PixelEncoder, RandomRotate,
                             RandomShift, StateReadout)
from simdist.pipelines import (EpisodeReplay, control_env, evaluate_returns,
                               load_episodes, mean_metrics, train_resumable)
from simdist.pipelines.locomotion import rollout
from simdist.utils.memmap import load_memmap, save_memmap
from simdist.utils.stages import read_stage_record


def teacher_stage(outputs: Path, task: str, seed: int) -> dict:
    path = outputs / "stages" / f"{task}_s{seed}_teacher.json"
    if not path.exists():
        raise FileNotFoundError(f"no finished teacher stage at {path}: run "
                                f"`python recipes/twist_dmc.py --output-dir {outputs}` first")
    return read_stage_record(outputs, path.stem)["result"]


class SelectDims(torch.nn.Module):
    """Keeps the given dimensions of the last axis (a student that sees part of the state)."""

    def __init__(self, dims: list[int]):
        super().__init__()
        self.register_buffer("dims", torch.tensor(dims))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.index_select(-1, self.dims)


def train_readout(args, cfg, episodes: list) -> StateReadout:
    """The probe's CNN and head trained on the images and states of ``episodes``
    (``--warm-updates`` updates of ``--batch`` images, ``--shift`` per image, Adam at
    ``--lr``), then frozen to read the ``--positions`` dimensions."""
    pixels = torch.cat([recipe.recorded_images(e) for e in episodes])
    states = torch.cat([e["next", "state"] for e in episodes])
    if args.extra_renders:  # each training state rendered K more times, other draws
        path = args.work / "probe_renders" / f"readout_extra{args.extra_renders}_{args.name}.pt"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            torch.save(render_states(args.task, states, recipe.training_visual(cfg),
                                     args.seed + 70_000, args.extra_renders,
                                     camera_id=cfg.camera_id).flatten(0, 1), path)
        pixels = torch.cat([pixels, torch.load(path, weights_only=True)])
        states = states.repeat(1 + args.extra_renders, 1)
    mean, std = states.mean(0), states.std(0).clamp_min(1e-3)
    encoder = probe_encoder(args, cfg)
    head = torch.nn.Linear(encoder.embed_dim, states.shape[-1])
    optim = torch.optim.Adam([*encoder.parameters(), *head.parameters()], lr=args.lr or 1e-3)
    shift = RandomShift(args.shift, "frame")
    start = time.perf_counter()
    for step in range(1, args.warm_updates + 1):
        index = torch.randint(len(pixels), (args.batch,))
        loss = (head(encoder(shift(pixels[index]))) - (states[index] - mean) / std).pow(2)
        loss = loss.mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
        if step % 300 == 0 or step == args.warm_updates:
            print(json.dumps({"variant": "readout", "readout_updates": step,
                              "loss": round(loss.item(), 3), "images": len(pixels),
                              "seconds": round(time.perf_counter() - start, 1)}), flush=True)
    readout = StateReadout(encoder, states.shape[-1], args.positions,
                           mean[args.positions], std[args.positions])
    readout.head.load_state_dict(head.state_dict())
    return readout


def readout_precision(args, cfg, readout: StateReadout, recorded: list) -> dict:
    """The readout's RMSE per dimension, in units of the dimension's spread there, on D's
    balancing states (up to 1000, cartpole): D's own images (training randomisation) and
    the same states re-rendered under the evaluation's held-out scenes."""
    states = torch.cat([e["next", "state"] for e in recorded])
    pixels = torch.cat([recipe.recorded_images(e) for e in recorded])
    index = balancing(states).nonzero().flatten()
    index = index[torch.randperm(len(index), generator=torch.Generator().manual_seed(0))[:1000]]
    if not len(index):
        return {"variant": "readout", "readout_balancing_states": 0}
    camera = "" if cfg.camera_id is None else f"_camera{cfg.camera_id}"
    heldout = cached_renders(args, states[index], VisualRandomisation.heldout_evaluation(),
                             cfg.camera_id, f"heldout_balancing{camera}", 60_000)
    target = states[index][:, readout.dims]
    spread = target.std(0).clamp_min(1e-6)
    out = {"variant": "readout", "readout_balancing_states": len(index),
           "readout_dims": readout.dims.tolist()}
    with torch.no_grad():
        for name, images in (("recorded", pixels[index]), ("heldout", heldout)):
            error = torch.cat([readout(images[i:i + 250]) for i in range(0, len(images), 250)])
            rmse = (error - target).pow(2).mean(0).sqrt() / spread
            out[f"readout_rmse_x_std_{name}"] = [round(v, 3) for v in rmse.tolist()]
    return out


class SensorNoise(torch.nn.Module):
    """Adds white Gaussian noise of ``std`` (the input's units) in training and acting
    alike: a stand-in for a readout of that precision."""

    def __init__(self, std: float):
        super().__init__()
        self.std = std

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.std * torch.randn_like(x)


def start_from_teacher_rssm(twist: TwistStudent) -> TwistStudent:
    copied = twist.start_from_teacher_rssm()
    print(f"copied {copied}/{len(twist.student.rssm.state_dict())} RSSM tensors from the "
          f"teacher", flush=True)
    return twist


#: variants whose student reads the privileged state vector (evaluated on state, no images)
STATE_VARIANTS = ("state", "positions")


def make_student(variant: str, cfg, task: str, teacher, lr: float | None,
                 standardise_belief: bool = False, positions: list[int] | None = None,
                 init_rssm: bool = False, action_weight: float = 0.0,
                 readout: torch.nn.Module | None = None, noise: float = 0.0) -> TwistStudent:
    overrides = {} if lr is None else {"lr": lr}
    if standardise_belief:
        overrides["standardise_belief"] = True
    if action_weight:
        overrides["action_weight"] = action_weight
    if variant in STATE_VARIANTS or variant == "readout":
        state_dim, action_dim = recipe.state_dim(task)
        dims = list(range(state_dim)) if variant == "state" else positions
        if variant == "readout":
            dims = positions
        student = DreamerWorldModel.teacher(len(dims), action_dim, cfg.model_size)
        student.decoder = student.reward_head = None  # a student learns neither
        if variant == "positions":  # reads only these dimensions of the state
            student.encoder = torch.nn.Sequential(SelectDims(dims), SensorNoise(noise),
                                                  student.encoder)
        if variant == "readout":  # reads them from one image through a frozen readout
            student.encoder = torch.nn.Sequential(readout, student.encoder)
        overrides["shift_pad"] = 0  # a state vector is not an image (nor a readout's)
        twist = TwistStudent(teacher, student, recipe.twist_config(cfg, overrides),
                             pixels_key=("next", "pixels" if readout else "state"))
        return start_from_teacher_rssm(twist) if init_rssm else twist
    twist = recipe.new_student(cfg, task, teacher, overrides)
    if variant == "warm":  # encoder + head -> the teacher's embedding; the teacher's RSSM
        encoder = twist.student.encoder
        head = torch.nn.Sequential(torch.nn.Linear(encoder.embed_dim, 256), torch.nn.ELU(),
                                   torch.nn.Linear(256, teacher.world_model.rssm.embed_dim))
        twist.student.encoder = torch.nn.Sequential(encoder, head)
        # the head emits the teacher's embedding, so the student's RSSM is the teacher's
        twist.student.rssm = copy.deepcopy(teacher.world_model.rssm)
        twist.optim = torch.optim.Adam(twist.student.parameters(), lr=twist.config.lr)
    if variant == "init" or (init_rssm and variant != "warm"):
        start_from_teacher_rssm(twist)
    return twist


def distil(args, cfg, teacher_result: dict) -> None:
    torch.manual_seed(args.seed)
    teacher = recipe.load_teacher(cfg, args.task, teacher_result)
    recorded = [e.to_tensordict() for e in load_episodes(teacher_result["data"])]
    states = torch.cat([e["next", "state"] for e in recorded])
    if args.render_camera is not None:  # D's states seen from another camera, same DR
        recorded = with_pixels(recorded, camera_renders(args, cfg, states, "D_all"))
    episodes = recorded
    if args.train_camera:  # D's states re-rendered under the recipe's train_camera DR
        episodes = with_pixels(recorded, train_camera_renders(args, cfg, states, "D_all"))
    if args.teacher_episodes:  # the final teacher's own episodes after D (training DR)
        episodes = episodes + teacher_episodes(args, cfg, teacher, recorded[0])
    replay = EpisodeReplay(cfg.env_steps + cfg.episode_steps, cfg.student_slice_len,
                           args.slices or cfg.student_slices)
    train_episodes = []  # what the student trains on (and a warm start's encoder)
    for episode in episodes[-args.recent_episodes if args.recent_episodes else 0:]:
        if args.train_states == "all":
            train_episodes.append(episode)
            continue
        # only the runs of consecutive kept steps at least a slice long, each as an episode
        states_here = episode["next", "state"]
        keep = (balancing(states_here) if args.train_states == "balancing"
                else states_here[:, 0].abs() < BALANCING_CART)
        train_episodes += [episode[start:end]
                           for start, end in recipe.mask_runs(keep, cfg.student_slice_len)]
    if not any(len(e) >= cfg.student_slice_len for e in train_episodes):
        raise SystemExit(f"no run of --train-states {args.train_states} steps is a slice "
                         f"({cfg.student_slice_len} steps) long: nothing to train on")
    stage = args.work / (f"{args.variant}_lr{args.lr}" if args.name == "base"
                         else f"{args.variant}_{args.name}")
    readout = None
    if args.variant == "readout":  # trained once, kept beside the student's checkpoint
        path = args.readout_file or stage / "readout.pt"
        if args.readout_file and not path.exists():
            raise FileNotFoundError(f"--readout-file {path} does not exist")
        if args.readout_file:  # a readout saved by StateReadout.save (.pt and .json)
            readout = StateReadout.load(path)
        elif path.exists():
            n_state = recorded[0]["next", "state"].shape[-1]
            readout = StateReadout(probe_encoder(args, cfg), n_state, args.positions)
            readout.load_state_dict(torch.load(path, weights_only=True))
        else:
            readout = train_readout(args, cfg, train_episodes)
            stage.mkdir(parents=True, exist_ok=True)
            torch.save(readout.state_dict(), path)
        if args.task.startswith("cartpole"):
            print(json.dumps(readout_precision(args, cfg, readout, recorded)), flush=True)
    replay_episodes = train_episodes
    if readout is not None and args.cache_readout:
        start = time.perf_counter()
        # the readings pass through the frozen readout as they are
        replay_episodes = [recipe.with_readings(e, readout) for e in train_episodes]
        print(f"read {sum(len(e) for e in train_episodes)} training images once in "
              f"{time.perf_counter() - start:.0f} s", flush=True)
    for episode in replay_episodes:
        replay.add(episode)
    print(f"training slices from {replay.episodes} runs, {len(replay)} steps", flush=True)
    twist = make_student(args.variant, cfg, args.task, teacher, args.lr,
                         args.standardise_belief, args.positions, args.init_rssm,
                         args.action_weight, readout, args.positions_noise)
    probe_replay = EpisodeReplay(cfg.env_steps + cfg.episode_steps, cfg.student_slice_len, 128)
    for episode in recorded:  # latent R^2 on the recorded images for every arm
        probe_replay.add(episode)
    generator_state = torch.get_rng_state()
    torch.manual_seed(12345)  # the same 128 slices for every arm and budget
    probe_batch = probe_replay.sample()
    torch.set_rng_state(generator_state)
    if args.variant == "warm" and not (stage / "student.pt").exists():
        warm_start(args, twist, train_episodes)
    for updates in args.updates:  # cumulative: resumes from the previous budget
        start = time.perf_counter()
        history = train_resumable(twist.update, replay.sample, updates, {"twist": twist},
                                  stage / "student.pt", every=100,
                                  desc=args.variant) if updates else []
        seconds = time.perf_counter() - start
        if args.variant in STATE_VARIANTS:
            policy = DreamerPolicy(twist.student, teacher.actor, "state", explore=False)
            result = evaluate_returns(args.task, policy, twist.make_primer(),
                                      args.seed + 10_000, args.episodes, cfg.eval_steps,
                                      False, None)
        else:
            cfg_eval = dataclasses.replace(cfg, eval_episodes=args.episodes)
            result = recipe.evaluate(cfg_eval, args.task, args.seed, twist.policy(),
                                     twist.make_primer(), pixels=True)
        scenes = {}  # the same student on other scenes: which part of the shift costs return
        for name in args.eval_scenes if args.variant not in STATE_VARIANTS else []:
            scene = evaluate_returns(args.task, twist.policy(), twist.make_primer(),
                                     args.seed + 10_000, args.episodes, cfg.eval_steps, True,
                                     EVAL_SCENES[name], camera_id=cfg.camera_id)
            scenes[name] = {"mean": scene["mean"], "std": scene["std"]}
        extra = {"scenes": scenes} if scenes else {}
        if args.variant not in STATE_VARIANTS:
            extra.update(latent_r2(twist, probe_batch))
        print(json.dumps({"variant": args.variant, "name": args.name, "updates": updates,
                          "lr": args.lr, "slices": args.slices or cfg.student_slices,
                          "init_rssm": args.init_rssm or args.variant == "init",
                          "action_weight": args.action_weight, "positions_noise": args.positions_noise,
                          "mean": result["mean"], "std": result["std"],
                          "returns": [round(r, 1) for r in result["returns"]], **extra,
                          "train_s": round(seconds, 1),
                          "last": mean_metrics(history, 50) if history else None}),
              flush=True)


def teacher_episodes(args, cfg, teacher, like) -> list:
    """``--teacher-episodes`` episodes of the *final* teacher acting on state with its
    collection noise, recorded like D (the keys of ``like``) under the training
    randomisation, from ``cfg.camera_id``; cached in ``--work``/teacher_episodes (rendering
    takes minutes). The states a student deploying this policy will meet, which D (mostly
    the early, weaker teacher's experience) holds few of."""
    folder = (args.work / "teacher_episodes" /
              f"{args.task}_s{args.seed}_camera{cfg.camera_id}_{args.teacher_episodes}")
    if not folder.exists():
        start = time.perf_counter()
        torch.manual_seed(args.seed + 20_000)
        env = control_env(args.task, args.seed + 20_000, pixels=True,
                          visual=recipe.training_visual(cfg), num_envs=args.teacher_episodes,
                          max_episode_steps=cfg.episode_steps, primer=teacher.make_primer(),
                          camera_id=cfg.camera_id)
        data = rollout(env, teacher.policy(explore=True), cfg.episode_steps)
        env.close()
        keys = list(like.keys(True, True))
        for i, episode in enumerate(data.unbind(0)):
            save_memmap(episode.select(*keys), folder.with_name(folder.name + ".tmp") / f"{i:03d}")
        folder.with_name(folder.name + ".tmp").rename(folder)  # complete or absent
        print(f"recorded {args.teacher_episodes} episodes of the final teacher in "
              f"{time.perf_counter() - start:.0f} s, return "
              f"{data['next', 'reward'].sum(1).mean():.0f}", flush=True)
    return [load_memmap(p).to_tensordict() for p in sorted(folder.iterdir())]


#: ``--eval-scenes``: besides the recipe's held-out scenes (textures never trained on and
#: camera jitter, drawn per episode), the same without the camera jitter, and the training
#: textures and colours drawn once per episode with no camera jitter.
EVAL_SCENES = {
    "heldout_nocam": VisualRandomisation.heldout_evaluation(camera=False),
    "training": VisualRandomisation.training(every_step=False),
}


def warm_start(args, twist: TwistStudent, episodes: list) -> None:
    """Trains the student's encoder (+ head) alone to map one image of D to the frozen
    teacher's embedding of the same step's state (standardised per dimension), with the
    student's augmentation applied per image; the RSSM is not touched."""
    pixels = torch.cat([recipe.recorded_images(e) for e in episodes])
    with torch.no_grad():
        target = twist.teacher.world_model.encoder(torch.cat([e["next", "state"]
                                                              for e in episodes]))
    scale = target.std(0).clamp_min(1e-3)
    encoder = twist.student.encoder
    optim = torch.optim.Adam(encoder.parameters(), lr=1e-3)  # the probe's best (README)
    shift = RandomShift(twist.config.shift_pad, "frame")
    start = time.perf_counter()
    for step in range(1, args.warm_updates + 1):
        index = torch.randint(len(pixels), (args.batch,))
        loss = ((encoder(shift(pixels[index])) - target[index]) / scale).pow(2).mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
        if step % 300 == 0 or step == args.warm_updates:
            print(json.dumps({"variant": "warm", "warm_updates": step,
                              "loss": round(loss.item(), 3),
                              "seconds": round(time.perf_counter() - start, 1)}), flush=True)


def latent_r2(twist: TwistStudent, batch) -> dict:
    """R^2 per state dimension of the teacher's decoder on the student's (and, for
    reference, the teacher's own) posterior features of ``batch``: what each latent
    carries of the true state."""
    state = batch["next", "state"]
    with torch.no_grad():
        teacher, student = twist.distillation.filter_both(batch.clone())
        decode = twist.teacher.world_model.decode
        out = {}
        for name, states in (("latent", student), ("teacher", teacher)):
            decoded = decode(DreamerWorldModel.features(states))
            error = (decoded - state).pow(2)
            r2 = 1 - error.flatten(0, 1).mean(0) / state.flatten(0, 1).var(0)
            out[f"{name}_r2"] = [round(v, 2) for v in r2.tolist()]
            # how many steps behind the scene the latent is: per dimension, the lag k in
            # 0..4 at which the decoded state at t best matches the true state at t - k
            lagged = [1 - (decoded[:, k:] - state[:, :state.shape[1] - k]).pow(2)
                      .flatten(0, 1).mean(0) / state.flatten(0, 1).var(0) for k in range(5)]
            out[f"{name}_lag"] = torch.stack(lagged).argmax(0).tolist()
            if state.shape[-1] == 5:  # cartpole: the error where a balancing policy looks
                keep = balancing(state)
                spread = state[keep].std(0)
                out[f"{name}_balancing_rmse_x_std"] = [
                    round(v, 2) for v in ((decoded - state)[keep].pow(2).mean(0).sqrt()
                                          / spread).tolist()]
        # what the deployed policy does with it: the teacher's actor (its deterministic
        # action) on the student's latent against the same actor on the teacher's
        actor = twist.teacher.actor
        on_student = actor(DreamerWorldModel.features(student)).flatten(0, -2)
        on_teacher = actor(DreamerWorldModel.features(teacher)).flatten(0, -2)
        pair = torch.stack([on_student.flatten(), on_teacher.flatten()])
        out["action_corr"] = round(float(torch.corrcoef(pair)[0, 1]), 2)
        out["action_rmse"] = round(float((on_student - on_teacher).pow(2).mean().sqrt()), 3)
        out["action_rms_teacher"] = round(float(on_teacher.pow(2).mean().sqrt()), 3)
    return out


def cached_renders(args, states: torch.Tensor, visual: VisualRandomisation, camera_id,
                   file: str, seed_offset: int) -> torch.Tensor:
    """``states`` rendered once each under ``visual`` from ``camera_id``, cached in
    ``--work``/probe_renders/``file``_s<seed>.pt (rendering D takes minutes)."""
    path = args.work / "probe_renders" / f"{file}_s{args.seed}.pt"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        torch.save(render_states(args.task, states, visual, args.seed + seed_offset,
                                 camera_id=camera_id)[0], path)
        print(f"rendered {len(states)} images under {visual} from camera {camera_id} in "
              f"{time.perf_counter() - start:.0f} s", flush=True)
    return torch.load(path)


def train_camera_renders(args, cfg, states: torch.Tensor, name: str) -> torch.Tensor:
    """``states`` under the recipe's ``train_camera`` randomisation (``--train-camera``)."""
    camera = "" if cfg.camera_id is None else f"_camera{cfg.camera_id}"
    visual = recipe.training_visual(dataclasses.replace(cfg, train_camera=True))
    return cached_renders(args, states, visual, cfg.camera_id, f"traincam_{name}{camera}",
                          40_000)


def camera_renders(args, cfg, states: torch.Tensor, name: str) -> torch.Tensor:
    """``states`` under the training randomisation from camera ``cfg.camera_id``
    (``--render-camera``)."""
    return cached_renders(args, states, recipe.training_visual(cfg), cfg.camera_id,
                          f"camera{cfg.camera_id}_{name}", 50_000)


def with_pixels(episodes: list, images: torch.Tensor) -> list:
    """Copies of ``episodes`` whose ("next", "pixels") are ``images`` (all steps, in order)."""
    out = [e.clone() for e in episodes]
    for e, x in zip(out, images.split([len(e) for e in episodes])):
        e.set(("next", "pixels"), x)
    return out


def render_states(task: str, states: torch.Tensor, visual: VisualRandomisation, seed: int,
                  renders: int = 1, camera_id: int | None = None) -> torch.Tensor:
    """Images ``[renders, N, 64, 64, 3]`` of recorded cartpole states, each under a fresh draw.

    Sets the physics to every stored state (cart position and the pole's angle from its
    cosine and sine) and renders it ``renders`` times, each render with a new draw of
    ``visual`` (textures, colours, light, and the camera if ``visual.camera``).
    """
    if not task.startswith("cartpole"):
        raise ValueError(f"render_states knows cartpole's state layout only, got {task}")
    env = control_env(task, seed, pixels=True, visual=visual, camera_id=camera_id)
    sim = env.base_env.sims[0]
    out = torch.zeros(renders, len(states), 64, 64, 3, dtype=torch.uint8)
    qpos = torch.stack([states[:, 0], torch.atan2(states[:, 2], states[:, 1])], -1).numpy()
    for i, q in enumerate(qpos):
        for r in range(renders):  # a fresh draw of ``visual`` for every render
            out[r, i] = torch.from_numpy(sim.render_configuration(q))
    env.close()
    return out


def noisy(args, cfg, teacher_result: dict) -> None:
    """The Oracle with noisy state: the perception precision its return needs."""
    teacher = recipe.load_teacher(cfg, args.task, teacher_result)
    states = torch.cat([e["next", "state"] for e in load_episodes(teacher_result["data"])])
    std, encoder = states.std(0), teacher.world_model.encoder
    clean = encoder.forward
    dims = states.shape[-1]
    groups = {"all": list(range(dims))}
    if args.task.startswith("cartpole"):  # (x, cos, sin, v, omega)
        groups.update({"sin(pole)": [2], "pole angular velocity": [4]})
    try:
        for name, index in groups.items():
            for level in args.noise:
                scale = torch.zeros(dims)
                scale[index] = level * std[index]
                encoder.forward = lambda s, scale=scale: clean(s + torch.randn_like(s) * scale)
                result = evaluate_returns(args.task, teacher.policy(explore=False),
                                          teacher.make_primer(), args.seed + 10_000,
                                          args.episodes, cfg.eval_steps, False, None)
                print(json.dumps({"variant": "noisy", "dimensions": name, "noise_x_std": level,
                                  "mean": round(result["mean"], 1),
                                  "std": round(result["std"], 1)}), flush=True)
    finally:
        encoder.forward = clean


def delayed(args, cfg, teacher_result: dict) -> None:
    """The Oracle reading the state ``k`` control steps late: what a student whose latent
    lags the scene by ``k`` steps can at best keep of the Oracle's return."""
    teacher = recipe.load_teacher(cfg, args.task, teacher_result)
    encoder = teacher.world_model.encoder
    clean = encoder.forward
    try:
        for delay in args.delays:
            seen = []  # the states of the last delay + 1 steps (every world steps together)

            def late(state, delay=delay, seen=seen):
                seen.append(state)
                del seen[:-delay - 1]
                return clean(seen[0])  # the first steps read the first state

            encoder.forward = late
            result = evaluate_returns(args.task, teacher.policy(explore=False),
                                      teacher.make_primer(), args.seed + 10_000,
                                      args.episodes, cfg.eval_steps, False, None)
            print(json.dumps({"variant": "delayed", "delay_steps": delay,
                              "mean": round(result["mean"], 1),
                              "std": round(result["std"], 1)}), flush=True)
    finally:
        encoder.forward = clean


#: cartpole states a balancing policy visits: pole within this angle (rad) of upright ...
BALANCING_ANGLE = 0.3
#: ... and the cart within this distance (m) of the centre (the fixed camera's view)
BALANCING_CART = 1.5


def balancing(states: torch.Tensor) -> torch.Tensor:
    """Mask of cartpole states ``(x, cos, sin, v, omega)`` with the pole near upright and
    the cart in view."""
    angle = torch.atan2(states[..., 2], states[..., 1])
    return (angle.abs() < BALANCING_ANGLE) & (states[..., 0].abs() < BALANCING_CART)


def probe_encoder(args, cfg) -> torch.nn.Module:
    size = DreamerWorldModel.student(1, cfg.model_size).encoder
    depth = args.depth or size.net[0].out_channels
    keypoints = max(1, RSSM_SIZES[cfg.model_size]["embed"] // 2)
    return PixelEncoder(depth, norm=args.norm, input_norm=args.input_norm, arch=args.arch,
                        keypoints=keypoints)


def probe(args, cfg, teacher_result: dict) -> None:
    """Supervised probe: can the student's CNN read the state from one randomised image?

    Test sets: 1/6 of D's images (training randomisation, images the encoder never saw)
    and, with ``--heldout-renders``, the same test states re-rendered under the recipe's
    evaluation randomisation (held-out textures, camera jitter): the student's test.
    """
    torch.manual_seed(args.seed)
    frames = args.frames
    if frames == 2 and (args.heldout_renders or args.train_camera or args.extra_renders
                        or args.render_camera is not None):
        raise SystemExit("--frames 2 reads consecutive recorded images of D; it cannot be "
                         "combined with re-rendered images (--heldout-renders, "
                         "--train-camera, --extra-renders, --render-camera)")
    episodes = [e.to_tensordict() for e in load_episodes(teacher_result["data"])]
    pixels = torch.cat([recipe.recorded_images(e).flatten(0, -4) for e in episodes])
    states = torch.cat([e["next", "state"].flatten(0, -2) for e in episodes])
    if args.render_camera is not None:  # D's states seen from another camera
        pixels = camera_renders(args, cfg, states, "D_all")
    camera_tag = "" if cfg.camera_id is None else f"_camera{cfg.camera_id}"  # cache names
    lengths = [len(e["next", "state"].flatten(0, -2)) for e in episodes]
    first = torch.tensor([0, *lengths[:-1]]).cumsum(0)
    previous = torch.arange(len(pixels)) - 1  # the image one control step earlier
    previous[first] = first  # an episode's first image has no earlier one in D: itself

    def pairs(index):  # [N, 2, H, W, C]: each image and the one before it
        return torch.stack([pixels[index], pixels[previous[index]]], 1)

    order = torch.randperm(len(pixels))
    test, train = order[: len(order) // 6], order[len(order) // 6:]
    if args.train_states == "balancing":  # learn only where a balancing policy looks
        train = train[balancing(states[train])]
    if args.train_states == "in_view":  # every pole angle, the cart in the camera's view
        train = train[states[train, 0].abs() < BALANCING_CART]
    if args.recent_episodes:  # learn only on the last episodes of D (the final teacher's)
        train = train[train >= sum(lengths[:-args.recent_episodes])]
    if not len(train):
        raise SystemExit("no training image is left after --train-states/--recent-episodes")
    cache = args.work / "probe_renders"
    cache.mkdir(parents=True, exist_ok=True)
    heldout = {}  # name -> the test states rendered under the evaluation's randomisation
    if args.heldout_renders:  # and without its camera jitter: textures alone
        for name, camera in (("heldout", True), ("heldout_nocam", False)):
            path = cache / f"{name}{camera_tag}_s{args.seed}.pt"
            if not path.exists():
                torch.save(render_states(args.task, states[test],
                                         VisualRandomisation.heldout_evaluation(camera=camera),
                                         args.seed + 20_000, camera_id=cfg.camera_id)[0], path)
            heldout[name] = torch.load(path)
    images = pixels[train][None]  # [1 + extra renders, N_train, ...]
    if args.train_camera:  # the same training states, each with a camera-pose draw
        images = train_camera_renders(args, cfg, states[train], "probe_train")[None]
    if args.extra_renders:
        selection = ("" if args.train_states == "all" else f"_{args.train_states}") + (
            f"_last{args.recent_episodes}" if args.recent_episodes else "")
        path = cache / f"extra{args.extra_renders}{selection}{camera_tag}_s{args.seed}.pt"
        if not path.exists():
            torch.save(render_states(args.task, states[train], VisualRandomisation.training(),
                                     args.seed + 30_000, args.extra_renders,
                                     camera_id=cfg.camera_id), path)
        images = torch.cat([images, torch.load(path)])
    encoder = probe_encoder(args, cfg)
    shift = None  # one image per state: per frame; an image pair: one shift for both
    per = "frame" if frames == 1 else "sequence"
    if args.shift or args.rotate:
        shift = torch.nn.Sequential(RandomShift(args.shift, per),
                                    RandomRotate(args.rotate, per))
    features = encoder.embed_dim * frames
    head = torch.nn.Linear(features, states.shape[-1])
    if args.arch == "keypoints":  # coordinates -> state is not linear (angles of offsets)
        head = torch.nn.Sequential(torch.nn.Linear(features, 256), torch.nn.ELU(),
                                   torch.nn.Linear(256, states.shape[-1]))

    def encode(x):  # late fusion of a pair: the features now and their change in one step
        if frames == 1:
            return encoder(x)
        f = encoder(x)
        return torch.cat([f[:, 0], f[:, 0] - f[:, 1]], -1)
    params = [*encoder.parameters(), *head.parameters()]
    optim = torch.optim.Adam(params, lr=args.lr or 3e-4)
    mean, std = states[train].mean(0), states[train].std(0)

    def predict(x) -> torch.Tensor:  # the state read from images, in the state's units
        encoder.eval()
        with torch.no_grad():
            out = torch.cat([head(encode(x[i:i + 500])) for i in range(0, len(x), 500)])
        encoder.train()
        return out * std + mean

    def r2(x, y) -> list[float]:
        error = (predict(x) - y).pow(2).mean(0)
        return [round(v, 2) for v in (1 - error / y.var(0)).tolist()]

    # The test states where the pole is within BALANCING_ANGLE of upright and the cart in
    # the camera's view: the states a balancing policy visits (most of D is a fallen pole
    # or a cart out of view, where R^2 over all of D says little about the precision a
    # controller needs). Cartpole only; the same test states for every image set.
    keep = (balancing(states[test]) if args.task.startswith("cartpole") and frames == 1
            else None)

    def balancing_rmse(images) -> list[float]:
        """RMSE per state dimension of the state read from ``images`` of the test states,
        on the balancing ones (NaN where there are none, e.g. in tiny runs)."""
        if not keep.any():
            return [float("nan")] * states.shape[-1]
        error = predict(images[keep]) - states[test][keep]
        return [round(v, 4) for v in error.pow(2).mean(0).sqrt().tolist()]

    start = time.perf_counter()
    n = len(train)
    for step in range(1, args.updates[-1] + 1):
        index = torch.randint(n, (args.batch,))
        render = torch.randint(len(images), (args.batch,))
        batch = images[render, index] if frames == 1 else pairs(train[index])
        if shift is not None:
            batch = shift(batch)
        loss = (head(encode(batch)) - (states[train[index]] - mean) / std).pow(2).mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
        if step in args.updates or step % 300 == 0:
            record = {"variant": "probe", "probe": args.name, "updates": step,
                      "images_train": n * len(images), "images_test": len(test),
                      "frames": frames,
                      "r2_test": r2(pixels[test] if frames == 1 else pairs(test), states[test]),
                      "r2_train": r2(images[0, :len(test)] if frames == 1
                                     else pairs(train[:len(test)]), states[train[:len(test)]])}
            for name, images_heldout in heldout.items():
                record[f"r2_{name}"] = r2(images_heldout, states[test])
            if keep is not None:
                kept = states[test][keep]
                record["balancing_states"] = len(kept)
                record["balancing_std"] = ([round(v, 4) for v in kept.std(0).tolist()]
                                           if len(kept) > 1 else [float("nan")] * kept.shape[-1])
                record["balancing_rmse_test"] = balancing_rmse(pixels[test])
                for name, images_heldout in heldout.items():
                    record[f"balancing_rmse_{name}"] = balancing_rmse(images_heldout)
            record["seconds"] = round(time.perf_counter() - start, 1)
            print(json.dumps(record), flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variant", choices=["state", "positions", "readout", "pixels", "init",
                                            "warm", "noisy", "delayed", "probe"])
    parser.add_argument("--outputs", type=Path, default=Path("outputs/twist_dmc"))
    parser.add_argument("--preset", default="default", choices=sorted(recipe.PRESETS))
    parser.add_argument("--task", default="cartpole-balance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--updates", default="300,900",
                        type=lambda s: sorted(int(x) for x in s.split(",")))
    parser.add_argument("--lr", type=float, default=None, help="default: the recipe's")
    parser.add_argument("--slices", type=int, default=None,
                        help="student slices per update (default: the recipe's)")
    parser.add_argument("--init-rssm", action="store_true",
                        help="state/positions/pixels: the student RSSM's tensors of the "
                             "teacher's shapes start as the teacher's")
    parser.add_argument("--positions", default="0,1,2",
                        type=lambda s: [int(x) for x in s.split(",")],
                        help="positions: the state dimensions the student reads (cartpole: "
                             "x, cos, sin)")
    parser.add_argument("--positions-noise", type=float, default=0.0,
                        help="positions: white Gaussian noise of this std (state units) on "
                             "every dimension read, in training and evaluation")
    parser.add_argument("--episodes", type=int, default=6, help="held-out evaluation episodes")
    parser.add_argument("--batch", type=int, default=400, help="probe: images per update")
    parser.add_argument("--depth", type=int, default=None,
                        help="probe: CNN depth (default: the preset's)")
    parser.add_argument("--norm", default=None, choices=["layer"], help="probe: encoder norm")
    parser.add_argument("--input-norm", default="fixed", choices=["fixed", "image"])
    parser.add_argument("--shift", type=int, default=0, help="probe: random-shift pad")
    parser.add_argument("--rotate", type=float, default=0.0,
                        help="probe: random in-plane rotation, degrees")
    parser.add_argument("--extra-renders", type=int, default=0,
                        help="probe/readout: extra training renders of the training states")
    parser.add_argument("--heldout-renders", action="store_true",
                        help="probe: also test on the test states under held-out scenes")
    parser.add_argument("--train-camera", action="store_true",
                        help="probe/pixels: training images re-rendered under the recipe's "
                             "train_camera randomisation (camera-pose draw per image)")
    parser.add_argument("--standardise-belief", action="store_true",
                        help="pixels: TwistConfig.standardise_belief")
    parser.add_argument("--action-weight", type=float, default=0.0,
                        help="pixels: TwistConfig.action_weight (the teacher's actor on the "
                             "student's latent should act as on the teacher's)")
    parser.add_argument("--arch", default="dreamer", choices=["dreamer", "keypoints"],
                        help="probe/pixels/warm: the encoder (PixelEncoder.arch)")
    parser.add_argument("--noise", default="0,0.1,0.3,0.5",
                        type=lambda s: [float(x) for x in s.split(",")],
                        help="noisy: noise levels, in units of each state dimension's std")
    parser.add_argument("--delays", default="0,1,2,3", type=lambda s: [int(x) for x in s.split(",")],
                        help="delayed: how many control steps late the Oracle reads the state")
    parser.add_argument("--warm-updates", type=int, default=1200,
                        help="warm: encoder-only updates before distillation")
    parser.add_argument("--readout-file", type=Path, default=None,
                        help="readout: a fitted readout to freeze instead of fitting one on "
                             "D (e.g. from `twist_readout_scale.py --save-readouts`)")
    parser.add_argument("--cache-readout", action="store_true",
                        help="readout: read the training images once and train on the "
                             "readings (same batches, a fraction of the time)")
    parser.add_argument("--name", default="base",
                        help="a label for the log (pixels: also the checkpoint folder)")
    parser.add_argument("--work", type=Path, default=Path("outputs/twist_diagnosis"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--recent-episodes", type=int, default=0,
                        help="probe/pixels: train only on the last N episodes of D (of D "
                             "and the --teacher-episodes after it); 0: all of them")
    parser.add_argument("--teacher-episodes", type=int, default=0,
                        help="pixels: add this many episodes of the final teacher (on state, "
                             "with its collection noise, training DR) after D; with "
                             "--recent-episodes N <= this, train on them alone")
    parser.add_argument("--train-states", default="all", choices=["all", "balancing", "in_view"],
                        help="probe/pixels: train on all of D's training states or only the "
                             "balancing ones (pole within 0.3 rad, cart in view) or those with "
                             "the cart in view (any pole angle); pixels: runs of such steps at "
                             "least a slice long; the test sets and latent R^2 slices stay")
    parser.add_argument("--frames", type=int, default=1, choices=[1, 2],
                        help="probe: 2 reads each image with the one before it (late fusion)")
    parser.add_argument("--eval-scenes", nargs="*", default=[], choices=sorted(EVAL_SCENES),
                        help="pixels/init/warm: also evaluate on these scenes")
    parser.add_argument("--render-camera", type=int, default=None,
                        help="pixels/init/warm: re-render D's states from this camera of the "
                             "task's model (training DR) and evaluate from it: the same "
                             "teacher and states seen through another camera")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cfg = dataclasses.replace(recipe.Config(), **recipe.PRESETS[args.preset])
    # the camera is the run's: its D was rendered from it (recipe --camera-id)
    run_config = json.loads((args.outputs / "config.json").read_text()) \
        if (args.outputs / "config.json").exists() else {}
    cfg = dataclasses.replace(cfg, student_arch=args.arch,
                              camera_id=run_config.get("camera_id"))
    if args.render_camera is not None:
        if args.variant not in ("pixels", "init", "warm", "probe"):
            parser.error("--render-camera applies to the probe and the pixel students")
        cfg = dataclasses.replace(cfg, camera_id=args.render_camera)
    teacher_result = teacher_stage(args.outputs, args.task, args.seed)
    run = {"probe": probe, "noisy": noisy, "delayed": delayed}.get(args.variant, distil)
    run(args, cfg, teacher_result)


if __name__ == "__main__":
    main()
