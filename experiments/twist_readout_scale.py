"""How many rendered images does a TWIST pixel readout need to be precise? (issue 19; not a
speed benchmark)

The TWIST diagnosis (docs/findings.md, "Where the student must see well, and how well")
found that a student keeps 70% of the Oracle only if it reads the cart position and the
pole's sine to ~0.01-0.02, and that the best readout of the recipe's images reaches ~.043
on held-out scenes from ~4000 distinct balancing states. This script measures the curve
behind that figure without a teacher run: cartpole states drawn uniformly from the
balancing region (pole within ``--max-angle`` of upright, cart within ``--max-cart``),
each rendered once under TWIST's training randomisation (``--camera train`` adds a camera
pose draw per image, 1.5x the evaluation's widths), a fresh copy of the student's CNN
(``PixelEncoder``, LayerNorm, per-image standardisation, random shift 4) fitted to
``(x, cos, sin)`` for ``--updates`` updates per training-set size, and the RMSE in state
units measured on fresh states rendered three ways: the training randomisation, the
evaluation's held-out textures without and with its camera jitter (drawn per image).
``--save-readouts DIR`` keeps each fitted readout as a :class:`StateReadout` file (weights
and a ``.json`` with its domain, command and precision): the committed
``src/simdist/checkpoints/twist_readout/cartpole-balance.pt`` that ``recipes/twist_dmc.py``
uses is the 64000-image readout of the second command below.

Rendering runs in ``--workers`` processes (one MuJoCo context each); training runs on
``--device``. Every finished probe is appended to ``--json`` at once.

    # the curve on a GPU machine (~6 min on one H200 with 14 render workers)
    python experiments/twist_readout_scale.py --device cuda --workers 14 \\
        --train-images 4000 16000 64000 --camera none train --updates 6000 --json scale.json
    # the committed readout (~6 min on one H200; copy RO/readout_train_64000.{pt,json} to
    # src/simdist/checkpoints/twist_readout/cartpole-balance.{pt,json})
    python experiments/twist_readout_scale.py --device cuda --workers 15 \\
        --train-images 16000 64000 --camera train --updates 24000 --test-images 4000 \\
        --save-readouts RO
    # widen a fitted readout's domain on the CPU (~35 min on 2 cores): go on from its
    # weights and units on poses with the cart up to 1.6 m from the centre
    python experiments/twist_readout_scale.py --workers 2 --train-images 32000 \
        --camera train --updates 8000 --batch 128 --lr 3e-4 --max-cart 1.6 \
        --init-readout src/simdist/checkpoints/twist_readout/cartpole-balance.pt \
        --save-readouts RO
    # a quick look on the CPU
    python experiments/twist_readout_scale.py --train-images 2000 --updates 300 --test-images 500
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import multiprocessing as mp
import sys
import time
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.envs import VisualRandomisation
from simdist.modules import PixelEncoder, RandomShift, StateReadout
from simdist.pipelines.twist import TRAIN_CAMERA_JITTER

TASK = "cartpole-balance"
TARGETS = ("x", "cos", "sin")


def draw_states(n: int, seed: int, max_angle: float, max_cart: float) -> torch.Tensor:
    """``[n, 2]`` cart positions and pole angles, uniform in the balancing region."""
    g = torch.Generator().manual_seed(seed)
    x = (torch.rand(n, generator=g) * 2 - 1) * max_cart
    angle = (torch.rand(n, generator=g) * 2 - 1) * max_angle
    return torch.stack([x, angle], -1)


def recorded_states(path: Path, renders: int, seed: int) -> torch.Tensor:
    """``[N * renders, 2]`` cart positions and pole angles of the recorded cartpole states in
    ``path`` (a ``[N, 5]`` tensor of ``(x, cos, sin, v, omega)``, e.g. a TWIST run's D),
    each repeated ``renders`` times (one texture draw per copy), in a seeded random order
    so that any prefix is a sample of the whole."""
    states = torch.load(path, weights_only=True)
    if states.ndim != 2 or states.shape[-1] != 5 or not torch.isfinite(states).all():
        raise ValueError(f"{path}: expected finite cartpole states [N, 5] (x, cos, sin, v, "
                         f"omega), got {tuple(states.shape)}")
    qpos = torch.stack([states[:, 0], torch.atan2(states[:, 2], states[:, 1])], -1)
    qpos = qpos.repeat(renders, 1)
    return qpos[torch.randperm(len(qpos), generator=torch.Generator().manual_seed(seed))]


def _render_chunk(args) -> torch.Tensor:
    """One worker: ``qpos`` rows rendered once each under a fresh draw of ``visual``."""
    qpos, visual, seed = args
    from simdist.pipelines import control_env  # in the worker: its own GL context
    env = control_env(TASK, seed, pixels=True, visual=visual)
    sim = env.base_env.sims[0]
    out = torch.empty(len(qpos), 64, 64, 3, dtype=torch.uint8)
    try:
        for i, q in enumerate(qpos.numpy()):
            out[i] = torch.from_numpy(sim.render_configuration(q))
    finally:
        env.close()
    return out


def render(qpos: torch.Tensor, visual: VisualRandomisation, seed: int, workers: int) -> torch.Tensor:
    """``[N, 64, 64, 3]`` uint8 images of ``qpos`` (cart position, pole angle)."""
    chunks = torch.tensor_split(qpos, max(1, min(workers, len(qpos))))
    jobs = [(c, visual, seed * 1000 + i) for i, c in enumerate(chunks)]
    if workers <= 1:
        return torch.cat([_render_chunk(j) for j in jobs])
    with mp.get_context("spawn").Pool(len(jobs)) as pool:
        return torch.cat(pool.map(_render_chunk, jobs))


def targets(qpos: torch.Tensor) -> torch.Tensor:
    """``(x, cos, sin)`` of ``qpos`` rows, the positions a TWIST student must read."""
    return torch.stack([qpos[:, 0], qpos[:, 1].cos(), qpos[:, 1].sin()], -1)


def fit_probe(images: torch.Tensor, y: torch.Tensor, tests: dict, args,
              device) -> tuple[list[dict], StateReadout]:
    """Fits the student's CNN + a linear head to standardised ``y``; RMSE per test set
    at each quarter of ``args.updates``, and the fitted readout, frozen on the CPU
    (:func:`fitted_readout`)."""
    torch.manual_seed(args.seed)
    if args.init_readout:  # go on from a fitted readout, in its units
        start_from = StateReadout.load(args.init_readout)
        if start_from.dims.tolist() != list(range(y.shape[-1])):
            raise ValueError(f"--init-readout {args.init_readout} reads dimensions "
                             f"{start_from.dims.tolist()}, not (x, cos, sin)")
        encoder = copy.deepcopy(start_from.encoder).requires_grad_(True).train().to(device)
        head = torch.nn.Linear(encoder.embed_dim, y.shape[-1])
        with torch.no_grad():
            head.weight.copy_(start_from.head.weight[:y.shape[-1]])
            head.bias.copy_(start_from.head.bias[:y.shape[-1]])
        head = head.to(device)
        mean, std = start_from.mean.clone(), start_from.std.clone()
    else:
        encoder = PixelEncoder(args.depth, norm="layer", input_norm="image").to(device)
        head = torch.nn.Linear(encoder.embed_dim, y.shape[-1]).to(device)
        mean, std = y.mean(0), y.std(0)
    shift = RandomShift(args.shift, "frame")
    params = [*encoder.parameters(), *head.parameters()]
    optim = torch.optim.Adam(params, lr=args.lr)
    # cosine decay to 1% of the rate: a readout is judged on its final precision
    sched = torch.optim.lr_scheduler.LambdaLR(
        optim, lambda s: 0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(s, args.updates) / args.updates)))
    images, y = images.to(device), y.to(device)
    mean, std = mean.to(device), std.to(device)

    def rmse(x_img: torch.Tensor, x_y: torch.Tensor) -> list[float]:
        encoder.eval()
        with torch.no_grad():
            out = torch.cat([head(encoder(x_img[i:i + 1000].to(device)))
                             for i in range(0, len(x_img), 1000)]) * std + mean
        encoder.train()
        return [round(v, 4) for v in (out - x_y.to(device)).pow(2).mean(0).sqrt().tolist()]

    rows, start = [], time.perf_counter()
    checkpoints = {max(1, args.updates * k // 4) for k in (1, 2, 3, 4)}
    for step in range(1, args.updates + 1):
        index = torch.randint(len(images), (args.batch,), device=device)
        batch = shift(images[index])
        loss = (head(encoder(batch)) - (y[index] - mean) / std).pow(2).mean()
        optim.zero_grad(set_to_none=True)
        loss.backward()
        optim.step()
        sched.step()
        if step in checkpoints:
            row = {"updates": step, "loss": round(loss.item(), 5),
                   "seconds": round(time.perf_counter() - start, 1)}
            for name, (x_img, x_y) in tests.items():
                row[f"rmse_{name}"] = rmse(x_img, x_y)
            rows.append(row)
    domain = None if args.states_file else balancing_domain(args.max_angle, args.max_cart)
    return rows, fitted_readout(encoder, head, mean, std, domain)


#: cartpole's state dimensions (x, cos, sin, v, omega): a readout predicts the first three
STATE_DIM = 5


def balancing_domain(max_angle: float, max_cart: float) -> tuple[list[float], list[float]]:
    """The box of ``(x, cos, sin)`` that poses drawn by :func:`draw_states` fill (any
    ``max_angle`` up to pi, the whole circle).

    Examples:
        >>> balancing_domain(math.pi, 1.8)
        ([-1.8, -1.0, -1.0], [1.8, 1.0, 1.0])
    """
    if not 0 < max_angle <= math.pi:
        raise ValueError(f"max_angle must be in (0, pi], got {max_angle}")
    sin = 1.0 if max_angle >= math.pi / 2 else math.sin(max_angle)
    cos = -1.0 if max_angle >= math.pi - 1e-9 else math.cos(max_angle)
    return ([-max_cart, cos, -sin], [max_cart, 1.0, sin])


def fitted_readout(encoder: PixelEncoder, head: torch.nn.Linear, mean: torch.Tensor,
                   std: torch.Tensor, domain=None) -> StateReadout:
    """The fitted ``(x, cos, sin)`` probe as a frozen CPU :class:`StateReadout` over
    cartpole's five state dimensions, of which it reads the first three (the velocity rows
    of its head are zero: a single image does not show them)."""
    readout = StateReadout(copy.deepcopy(encoder).cpu(), STATE_DIM, list(range(len(TARGETS))),
                           mean.cpu(), std.cpu(), domain)
    with torch.no_grad():
        readout.head.weight.zero_()
        readout.head.bias.zero_()
        readout.head.weight[:len(TARGETS)] = head.weight.detach().cpu()
        readout.head.bias[:len(TARGETS)] = head.bias.detach().cpu()
    return readout


def save_composed(args, fallback: StateReadout, path: Path) -> Path:
    """``args.fallback_for`` with ``fallback`` attached (answering outside the gates), saved
    to ``path`` with the precise readout's description and meta, and the fallback's."""
    composed = StateReadout.load(args.fallback_for).with_fallback(
        fallback, gate=(args.gate_low, args.gate_high),
        fallback_gate=None if args.fallback_gate_low is None else (
            args.fallback_gate_low, args.fallback_gate_high))
    meta = json.loads(args.fallback_for.with_suffix(".json").read_text())
    meta.pop("readout", None)
    fallback_meta = json.loads(path.with_name(path.name.replace("composed_", "readout_"))
                               .with_suffix(".json").read_text())
    fallback_meta.pop("readout", None)
    return composed.save(path, meta={**meta, "fallback": fallback_meta})


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--train-images", type=int, nargs="+", default=[4000, 16000])
    p.add_argument("--camera", nargs="+", choices=["none", "train"], default=["none"],
                   help="training images without / with a camera pose draw per image")
    p.add_argument("--test-images", type=int, default=2000)
    p.add_argument("--updates", type=int, default=3000)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--depth", type=int, default=32)
    p.add_argument("--shift", type=int, default=4)
    p.add_argument("--max-angle", type=float, default=0.3,
                   help="radians from upright (pi: every pose, e.g. a fallback readout)")
    p.add_argument("--max-cart", type=float, default=1.0, help="metres from the centre")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--states-file", type=Path, default=None,
                   help="train on these recorded cartpole states ([N, 5] tensor, e.g. a TWIST "
                        "run's D) instead of uniform draws in the balancing region; the test "
                        "sets stay uniform in the balancing region")
    p.add_argument("--renders-per-state", type=int, default=1,
                   help="--states-file: renders of each recorded state, one draw each")
    p.add_argument("--init-readout", type=Path, default=None,
                   help="a StateReadout file of (x, cos, sin) to go on fitting (its weights "
                        "and units) instead of a fresh CNN, e.g. to widen its domain")
    p.add_argument("--save-readouts", type=Path, default=None,
                   help="folder: each fitted readout as readout_<camera>_<images>.pt, for "
                        "`twist_diagnosis.py readout --readout-file`")
    p.add_argument("--fallback-for", type=Path, default=None,
                   help="a StateReadout file: each fitted readout is also saved (with "
                        "--save-readouts) as that readout's fallback, composed_<camera>_"
                        "<images>.pt, answering where the precise one's reading leaves "
                        "--gate-low/--gate-high or its own leaves --fallback-gate-low/-high")
    p.add_argument("--gate-low", type=float, nargs="+", default=None,
                   help="--fallback-for: low (x, cos, sin) of the precise reading's gate")
    p.add_argument("--gate-high", type=float, nargs="+", default=None)
    p.add_argument("--fallback-gate-low", type=float, nargs="+", default=None,
                   help="--fallback-for: low (x, cos, sin) of the fallback reading's gate "
                        "(default: none)")
    p.add_argument("--fallback-gate-high", type=float, nargs="+", default=None)
    args = p.parse_args(argv)
    if args.fallback_for and not (args.save_readouts and args.gate_low and args.gate_high):
        p.error("--fallback-for needs --save-readouts, --gate-low and --gate-high")
    if (args.fallback_gate_low is None) != (args.fallback_gate_high is None):
        p.error("--fallback-gate-low and --fallback-gate-high go together")
    args.max_angle = min(args.max_angle, math.pi)  # 3.1416 means the whole circle
    if args.updates < 4 or min(args.train_images) < 1 or args.renders_per_state < 1:
        p.error("--updates must be >= 4, --train-images and --renders-per-state >= 1")
    device = torch.device(args.device)

    start = time.perf_counter()
    test_q = draw_states(args.test_images, args.seed + 1, args.max_angle, args.max_cart)
    tests = {}
    for name, visual in (("train_dr", VisualRandomisation.training()),
                         ("heldout_nocam", VisualRandomisation.heldout_evaluation(camera=False)),
                         ("heldout", VisualRandomisation.heldout_evaluation())):
        tests[name] = (render(test_q, visual, args.seed + 10 + len(tests), args.workers),
                       targets(test_q))
    print(f"rendered {3 * len(test_q)} test images in {time.perf_counter() - start:.0f} s",
          flush=True)
    inner = test_q[:, 1].abs() < args.max_angle / 3  # the pole near upright
    for name in list(tests):
        tests[f"{name}_inner"] = (tests[name][0][inner], tests[name][1][inner])
    spread = targets(test_q).std(0).tolist()
    print(f"test spread (x, cos, sin): {[round(s, 4) for s in spread]}", flush=True)

    largest = max(args.train_images)
    for camera in args.camera:
        visual = (VisualRandomisation.training() if camera == "none"
                  else VisualRandomisation.training(camera=True, **TRAIN_CAMERA_JITTER))
        t = time.perf_counter()
        if args.states_file:  # recorded states (any pole angle), K renders each
            train_q = recorded_states(args.states_file, args.renders_per_state, args.seed + 100)
            if largest > len(train_q):
                p.error(f"--train-images {largest} > {len(train_q)} recorded renders")
            train_q = train_q[:largest]
        else:
            train_q = draw_states(largest, args.seed + 100, args.max_angle, args.max_cart)
        images = render(train_q, visual, args.seed + 200 + (camera == "train"), args.workers)
        fps = largest / (time.perf_counter() - t)
        print(f"camera={camera}: rendered {largest} training images at {fps:.0f} images/s",
              flush=True)
        for n in sorted(args.train_images):
            rows, readout = fit_probe(images[:n], targets(train_q[:n]), tests, args, device)
            if args.save_readouts:  # what recipes/twist_dmc.py's student_readout reads
                readout.save(args.save_readouts / f"readout_{camera}_{n}.pt", meta={
                    "task": TASK, "camera_id": None, "train_images": n,
                    "updates": args.updates, "camera_draws": camera == "train",
                    "command": "python experiments/twist_readout_scale.py " + " ".join(
                        sys.argv[1:] if argv is None else argv),
                    "rmse_x_cos_sin": {k: v for k, v in rows[-1].items()
                                       if k.startswith("rmse_")},
                    "test_spread_x_cos_sin": spread})
                if args.fallback_for:
                    save_composed(args, readout, args.save_readouts / f"composed_{camera}_{n}.pt")
            for row in rows:
                row.update({"camera": camera, "train_images": n, "device": str(device),
                            "render_fps": round(fps), "test_spread": spread})
                print(json.dumps(row), flush=True)
            if args.json:
                with args.json.open("a") as f:
                    for row in rows:
                        f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
