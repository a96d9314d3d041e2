"""What the frozen value head says about a quadruped that tips over, and a value head fitted
to the returns the pretraining data actually paid (issue 21; not a speed benchmark).

The pretraining dataset's value labels are the expert critic's values of each recorded
state (``value_target``). The critic was trained on the expert's own experience; the
perturbed dataset also holds states the expert never reached, a robot on its back among
them, and the labels there are whatever the critic extrapolates.

``audit`` prints, for a finished recipe run:

- the pretraining dataset's episodes that ended on their back, the critic's labels on
  those steps against the reward paid there, and the discounted return to the episode's
  end (bootstrapped by the critic at its last step);
- for each target-data folder (a round's ``data``), the pretrained value head on the
  frozen encoder's latents of the recorded steps, grouped by how many steps later the
  episode tips over (body-frame gravity z below 0.5), against episodes that never tip.

``foresee`` asks whether the world model sees a tip-over coming when it is given the
actions the robot actually took: from ``--steps-before`` steps before each recorded tip, it
rolls the dynamics open-loop on the recorded actions and prints, in 10-step bins, the
predicted reward and the value head on the predicted latents beside the real reward and
body-frame gravity z (pretrained dynamics and each ``--weights``).

``bias`` asks how far off the predicted reward is where the robot stays up: from every
10th step of each recorded episode that never tips over, for ``--horizon`` steps, it
rolls the dynamics open-loop on the recorded actions and prints, per commanded speed, the
real reward summed over the window, each model's prediction of it, the mean error (bias)
and the correlation (pretrained dynamics and each ``--weights``).

``refit`` fits the value head (from its pretrained weights) to those returns on the
pretrained dynamics' latents ``z^_{t+i}``, ``i = 0..H`` (as the pretraining loss does),
then once more with each episode's bootstrap read from the fitted head instead of the
critic; and writes world-model weights (``--base``'s, default the pretrained ones, with
the new value head) for ``experiments/planner_variants.py --weights``.

    python experiments/value_labels.py audit --run RUN --data RUN/stages/round_2/data
    python experiments/value_labels.py foresee --run RUN --data RUN/stages/round_2/data \\
        --weights RUN/stages/round_2/simdist.pt --steps-before 80
    python experiments/value_labels.py bias --run RUN --data RUN/stages/round_2/data \\
        --weights RUN/stages/round_2/simdist.pt
    python experiments/value_labels.py refit --run RUN --base RUN/stages/round_2/simdist.pt \\
        --out refit.pt
    python experiments/planner_variants.py --run RUN --weights refit.pt --domains slippery_slope

``heads`` asks whether one model's planner gains from a mean of value heads, as two
pretrained models planned together do from their mean terminal value
(docs/findings.md, "Which part of two members carries the gain"): it fits
``--heads`` more value heads on the same labels (the critic's) and latents as pretraining
(``z^_{t+i}``, ``i = 0..H``, every other part frozen), each from a fresh initialisation and
on its own bootstrap resample of the dataset's episodes, prints their held-out R^2 and
how far they disagree with the pretrained head on the dataset and on ``--data`` (target
steps, where the planner needs them), then plans in ``--target`` with ``--weights`` (e.g.
a round's finetuned model) scoring by the heads' mean, on the run's evaluation worlds,
and saves per-episode fractions as ``planner_variants.py --save-json`` does (pair them
with ``planner_variants.py --pool FILE=RUN/stages/round_2.json``):

    python experiments/value_labels.py heads --run RUN --weights RUN/stages/round_2/simdist.pt \
        --data RUN/stages/round_2/data --heads 2 --save-json heads_s0.json
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import numpy as np
import torch
from torchrl.objectives.value.functional import reward2go

from simdist.data.dataset import read_dataset_meta
from simdist.pipelines.locomotion import TIPPED, UPSIDE_DOWN
from simdist.pipelines import simdist as recipe
from simdist.utils import load_checkpoint, load_memmap
from simdist.utils.stages import read_stage_record

STEPS_BEFORE_TIP = ((0, 10), (10, 20), (20, 40), (40, 80), (80, 160))


def discounted_returns(reward: torch.Tensor, bootstrap: torch.Tensor, gamma: float
                       ) -> torch.Tensor:
    """``G_t = r_t + gamma r_{t+1} + ... + gamma^(T-t) bootstrap`` over ``[B, T]`` rows
    that are one episode each, ``bootstrap [B]`` standing for the value after the last
    step.

    Examples:
        >>> discounted_returns(torch.tensor([[1.0, 0.0, 2.0]]), torch.tensor([4.0]), 0.5)
        tensor([[2., 2., 4.]])
    """
    done = torch.zeros(reward.shape, dtype=torch.bool, device=reward.device)
    done[:, -1] = True
    steps_left = torch.arange(reward.shape[1], 0, -1, device=reward.device)  # T - t
    return (reward2go(reward, done, gamma, time_dim=-1)
            + gamma ** steps_left * bootstrap.to(reward.dtype)[:, None])


def steps_until_tip(gravity_z: np.ndarray, is_init: np.ndarray) -> np.ndarray:
    """``[B, T]``: steps from each step to its episode's first tipped reading (0 at that
    step), -1 after it, ``inf`` in an episode that never tips. Rows may hold several
    episodes (``is_init`` starts each)."""
    out = np.full(gravity_z.shape, np.inf)
    for row, (z, init) in enumerate(zip(gravity_z, is_init)):
        starts = list(np.flatnonzero(init)) + [len(z)]
        if starts[0] != 0:
            starts = [0, *starts]
        for a, b in zip(starts[:-1], starts[1:]):
            tipped = np.flatnonzero(z[a:b] < TIPPED)
            if len(tipped):
                t = tipped[0]
                out[row, a:a + t + 1] = t - np.arange(t + 1)
                out[row, a + t + 1:b] = -1
    return out


def windows_before_tip(until: np.ndarray, steps_before: int, length: int, first: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, starts)`` of the windows of ``length`` steps that start ``steps_before``
    steps before a tip (``until`` from :func:`steps_until_tip`), no earlier than step
    ``first`` (the encoder's window filled) and ending inside the row."""
    rows, starts = np.nonzero(until == steps_before)
    keep = (starts >= first) & (starts + length <= until.shape[1])
    return rows[keep], starts[keep]


def _run(run: Path):
    cfg, pretrained = recipe.load_finished_run(run)
    agent = recipe.load_agent(cfg, pretrained)
    dataset = Path(read_stage_record(run, "dataset")["result"]["path"])
    data = load_memmap(dataset / "data", manifest=read_dataset_meta(dataset)["files"])
    return cfg, agent, data


def _encode(world_model, td, chunk: int = 64) -> torch.Tensor:
    obs, init, act = td["observation"].float(), td["is_init"].reshape(td.shape), td["action"].float()
    with torch.no_grad():
        return torch.cat([world_model.encode_sequence(obs[i:i + chunk], init[i:i + chunk],
                                                      act[i:i + chunk])
                          for i in range(0, td.shape[0], chunk)])


def _pretraining_latents(world_model, z: torch.Tensor, actions: torch.Tensor,
                         horizon: int) -> torch.Tensor:
    """The latents the pretraining loss trains V on, ``z^_{t+i}``, ``i = 0..H``: every
    encoded ``z_t`` (``[B, T, L]``) with ``H`` steps after it, rolled along the recorded
    ``actions`` (``[B, T, A]``); ``[B, T - H, H + 1, L]``."""
    T = z.shape[1]
    with torch.no_grad():
        start = z[:, :T - horizon]
        windows = actions.unfold(1, horizon, 1)[:, :T - horizon].transpose(-1, -2)  # [B, S, H, A]
        return torch.cat([start.unsqueeze(2), world_model.rollout(start, windows)], 2)


def _open_loop(world_model, z: torch.Tensor, at, actions: torch.Tensor) -> torch.Tensor:
    """The latents a step's reward is read from along ``actions`` (``[windows, steps,
    action]``), rolled open-loop from the encoded latent ``z[row, start]`` of each
    ``(row, start)`` in ``at``: the start's own latent, then the predicted ones."""
    z0 = torch.stack([z[r, t] for r, t in at])
    return torch.cat([z0[:, None], world_model.rollout(z0, actions)[:, :-1]], 1)


def audit(run: Path, folders: list[Path]) -> None:
    cfg, agent, data = _run(run)
    wm, gamma = agent.world_model, cfg.planner().gamma
    grav = recipe.observation_layout(cfg.data_task)["gravity"]
    z_up = data["observation"][..., grav.start + 2].numpy()
    reward = data["next", "reward"].reshape(data.shape).double()
    critic = data["value_target"].reshape(data.shape).double()
    returns = discounted_returns(reward, critic[:, -1], gamma).numpy()
    back = z_up < UPSIDE_DOWN
    print(f"pretraining data: {data.shape[0]} episodes, {int(back.any(1).sum())} on their back "
          f"at some step ({100 * back.mean():.1f}% of the steps)")
    print(f"  on their back: critic label {critic.numpy()[back].mean():.1f}, reward per step "
          f"{reward.numpy()[back].mean():.3f}, discounted return to the end "
          f"{returns[back].mean():.1f}")
    print(f"  upright: critic label {critic.numpy()[~back].mean():.1f}, discounted return "
          f"{returns[~back].mean():.1f}")
    grav = recipe.observation_layout(cfg.task)["gravity"]
    for folder in folders:
        td = load_memmap(folder)[:, :]
        with torch.no_grad():
            value = wm.value(_encode(wm, td)).squeeze(-1).numpy()
        until = steps_until_tip(td["next", "observation"][..., grav.start + 2].numpy(),
                                td["is_init"].reshape(td.shape).numpy())
        command = td["observation"][..., recipe.observation_layout(cfg.task)["command"].start]
        command = np.round(command.double().numpy(), 6)
        speeds = sorted(set(command[:, 0].tolist()))
        never = np.isinf(until)
        never[:, :cfg.model_history or 4] = False  # the encoder's window still filling
        groups = [(f"{low}-{high}", (until >= low) & (until < high))
                  for low, high in STEPS_BEFORE_TIP]
        groups += [("never tips", never), ("after tipping", until < 0)]
        print(f"\n{folder}: the pretrained value head on the encoded target steps, by "
              "commanded speed (V, steps)")
        print("| steps before the episode tips over |" + "".join(f" {v:g} m/s |" for v in speeds))
        print("| --- |" + " --- |" * len(speeds))
        for name, chosen in groups:
            cells = []
            for v in speeds:
                m = chosen & (command == v)
                cells.append(f" {value[m].mean():.1f} ({int(m.sum())}) |" if m.any() else " - |")
            print(f"| {name} |" + "".join(cells))


def foresee(run: Path, folders: list[Path], weights: list[str], steps_before: int,
            after: int = 30, width: int = 10) -> None:
    cfg, agent, _ = _run(run)
    _, pretrained = recipe.load_finished_run(run)
    grav = recipe.observation_layout(cfg.task)["gravity"]
    length = steps_before + after
    bins = range(0, length, width)
    for folder in folders:
        td = load_memmap(folder)[:, :]
        gravity_z = td["next", "observation"][..., grav.start + 2].numpy()
        until = steps_until_tip(gravity_z, td["is_init"].reshape(td.shape).numpy())
        rows, starts = windows_before_tip(until, steps_before, length, cfg.model_history or 4)
        if not len(rows):
            print(f"\n{folder}: no tip-over {steps_before} steps into a full window")
            continue
        # controls: the same start steps in episodes of the same commanded speed that never tip
        speed = np.round(td["observation"][:, 0, recipe.observation_layout(cfg.task)["command"]
                                           .start].double().numpy(), 6)
        never = np.flatnonzero(np.isinf(until).all(1))
        rng = np.random.default_rng(0)
        pairs = [(rng.choice(never[speed[never] == speed[r]]), t) for r, t in zip(rows, starts)
                 if (speed[never] == speed[r]).any()]
        take = lambda x, at: torch.stack([torch.as_tensor(x[r, t:t + length])  # noqa: E731
                                          for r, t in at])
        tips = list(zip(rows, starts))
        reward = td["next", "reward"].reshape(td.shape).float()
        lines = [("gravity z, real", take(gravity_z, tips).double(), ".2f"),
                 ("reward, real", take(reward, tips), ".2f")]
        if pairs:
            lines.append(("reward, real, controls", take(reward, pairs), ".2f"))
        encoder = None
        for name in ["pretrained", *weights]:
            wm = (agent if name == "pretrained"
                  else recipe.load_agent(cfg, pretrained, name)).world_model
            z = _encode(wm, td)
            with torch.no_grad():
                for label, at in [("", tips), (", controls", pairs)][:1 + bool(pairs)]:
                    actions = take(td["action"].float(), at)
                    path = _open_loop(wm, z, at, actions)
                    lines += [(f"{name}: reward predicted{label}",
                               wm.reward(path, actions).squeeze(-1), ".2f"),
                              (f"{name}: V on the predicted latents{label}",
                               wm.value(path).squeeze(-1), ".1f")]
                state = [p.detach().clone() for p in wm.encoder.parameters()]
                if encoder is None or any(not torch.equal(a, b) for a, b in zip(state, encoder)):
                    # dynamics-only finetuning keeps the encoder: the row would repeat
                    lines.append((f"{name}: V on the encoded real steps",
                                  wm.value(take(z, tips)).squeeze(-1), ".1f"))
                encoder = state
        print(f"\n{folder}: {len(rows)} tip-overs, the dynamics rolled open-loop on the "
              f"recorded actions from {steps_before} steps before each; controls: the same "
              f"steps of {len(pairs)} episodes at the same commanded speed that never tip "
              f"(means per {width}-step bin)")
        print("| steps from the tip |" + "".join(f" {b - steps_before:+d} |" for b in bins))
        print("| --- |" + " --- |" * len(bins))
        for name, values, fmt in lines:
            print(f"| {name} |" + "".join(f" {values[:, b:b + width].mean():{fmt}} |" for b in bins))


def upright_windows(until: np.ndarray, is_init: np.ndarray, horizon: int, every: int = 10,
                    first: int = 10) -> list[tuple[int, int]]:
    """``(row, start)`` of windows of ``horizon`` steps, every ``every`` steps from ``first``,
    in episodes that never tip over (``until`` infinite, from :func:`steps_until_tip`: not
    only up over the window, which would let in the rearing before a fall), with no new
    episode starting between the row's first step and the window's end (the encoder's
    history is the episode's own).

    Examples:
        >>> until = np.full((2, 40), np.inf)
        >>> is_init = np.zeros((2, 40), bool)
        >>> is_init[1, 20] = True  # row 1 holds a second episode from step 20
        >>> upright_windows(until, is_init, horizon=10, every=10, first=0)
        [(0, 0), (0, 10), (0, 20), (0, 30), (1, 0), (1, 10)]
    """
    rows, steps = until.shape
    return [(r, t) for r in range(rows) for t in range(first, steps - horizon + 1, every)
            if np.isinf(until[r, t:t + horizon]).all() and not is_init[r, 1:t + horizon].any()]


def bias(run: Path, folders: list[Path], weights: list[str], horizon: int) -> None:
    cfg, agent, _ = _run(run)
    _, pretrained = recipe.load_finished_run(run)
    layout = recipe.observation_layout(cfg.task)
    models = {"pretrained": agent.world_model}
    models.update({w: recipe.load_agent(cfg, pretrained, w).world_model for w in weights})
    for folder in folders:
        td = load_memmap(folder)[:, :]
        is_init = td["is_init"].reshape(td.shape).numpy()
        until = steps_until_tip(td["next", "observation"][..., layout["gravity"].start + 2]
                                .numpy(), is_init)
        at = upright_windows(until, is_init, horizon)
        if not at:
            print(f"\n{folder}: no upright window of {horizon} steps")
            continue
        window = lambda x: torch.stack([x[r, t:t + horizon] for r, t in at])  # noqa: E731
        real = window(td["next", "reward"].reshape(td.shape).float()).sum(1)
        actions = window(td["action"].float())
        speed = np.array([round(float(td["observation"][r, 0, layout["command"].start]), 6)
                          for r, _ in at])
        predicted = {}
        for name, wm in models.items():
            z = _encode(wm, td)
            with torch.no_grad():
                path = _open_loop(wm, z, at, actions)
                predicted[name] = wm.reward(path, actions).squeeze(-1).sum(1)
        print(f"\n{folder}: {len(at)} windows of {horizon} steps in episodes that never tip; "
              "reward summed over the window, real and predicted open-loop on the recorded "
              "actions: mean (bias = predicted - real, correlation)")
        print("| commanded speed | windows | real |" + "".join(f" {n} |" for n in predicted))
        print("| --- | --- | --- |" + " --- |" * len(predicted))
        for v in sorted(set(speed.tolist())):
            m = torch.as_tensor(speed == v)
            cells = "".join(
                f" {p[m].mean():.2f} ({(p[m] - real[m]).mean():+.2f}, "
                f"{np.corrcoef(p[m].numpy(), real[m].numpy())[0, 1]:.2f}) |"
                for p in predicted.values())
            print(f"| {v:g} m/s | {int(m.sum())} | {real[m].mean():.2f} |{cells}")


def refit(run: Path, base: str | None, out: Path, iterations: int, updates: int,
          batch: int, lr: float, seed: int) -> None:
    cfg, agent, data = _run(run)
    torch.manual_seed(seed)
    wm, gamma, horizon = agent.world_model, cfg.planner().gamma, cfg.model_horizon
    B, T = data.shape
    if not (data["is_init"].reshape(B, T)[:, 0].all() and not data["is_init"].reshape(B, T)[:, 1:].any()):
        raise ValueError("refit reads one episode per dataset row")
    z = _encode(wm, data)
    path = _pretraining_latents(wm, z, data["action"].float(), horizon)
    reward = data["next", "reward"].reshape(B, T).double()
    bootstrap = data["value_target"].reshape(B, T)[:, -1].double()
    heldout = torch.zeros(B, dtype=torch.bool)
    heldout[torch.randperm(B)[:max(1, B // 10)]] = True
    train = (~heldout).nonzero().squeeze(-1)
    head = wm.value_head
    optim = torch.optim.Adam(head.parameters(), lr=lr)
    for it in range(iterations):
        labels = discounted_returns(reward, bootstrap, gamma).float()
        target = labels.unfold(1, horizon + 1, 1)[:, :T - horizon]
        for _ in range(updates):
            rows, steps = train[torch.randint(len(train), (batch,))], torch.randint(T - horizon, (batch,))
            loss = (head(path[rows, steps]).squeeze(-1) - target[rows, steps]).pow(2).mean()
            optim.zero_grad()
            loss.backward()
            optim.step()
        with torch.no_grad():
            value = head(path[heldout, :, 0]).squeeze(-1)
            truth = labels[heldout, :T - horizon]
            r2 = 1 - (value - truth).pow(2).mean() / truth.var()
            bootstrap = head(z[:, -1]).squeeze(-1).double()  # the next labels' bootstrap
        print(f"iteration {it + 1}: labels mean {labels.mean():.1f}; held-out episodes R^2 "
              f"{r2:.3f}")
    weights = load_checkpoint(base or recipe.member_paths(
        read_stage_record(run, "pretrain")["result"])[0])
    weights.update({f"value_head.{k}": v for k, v in head.state_dict().items()})
    torch.save(weights, out)
    print(f"wrote {out}")


class MeanOfHeads(torch.nn.Module):
    """The mean of several scalar heads' outputs (a value-head ensemble on one latent)."""

    def __init__(self, heads):
        super().__init__()
        self.heads = torch.nn.ModuleList(heads)

    def forward(self, *inputs):
        return torch.stack([h(*inputs) for h in self.heads]).mean(0)


def _fresh_copy(module: torch.nn.Module) -> torch.nn.Module:
    fresh = copy.deepcopy(module)
    for layer in fresh.modules():
        if hasattr(layer, "reset_parameters"):
            layer.reset_parameters()
    return fresh


def heads(run: Path, weights: str | None, folders: list[Path], count: int, episodes: int,
          updates: int, batch: int, lr: float, seed: int, target: str | None,
          save_json: Path | None) -> None:
    cfg, agent, data = _run(run)
    torch.manual_seed(seed)
    wm, horizon = agent.world_model, cfg.model_horizon
    rows = torch.randperm(data.shape[0])[:episodes].sort().values
    data = data[rows]
    B, T = data.shape
    path = _pretraining_latents(wm, _encode(wm, data), data["action"].float(), horizon)
    labels = data["value_target"].reshape(B, T).float().unfold(1, horizon + 1, 1)
    steps = path.shape[1]
    heldout = torch.zeros(B, dtype=torch.bool)
    heldout[torch.randperm(B)[:max(1, B // 10)]] = True
    train = (~heldout).nonzero().squeeze(-1)
    new = []
    for k in range(count):
        head = _fresh_copy(wm.value_head)
        last = [m for m in head.modules() if isinstance(m, torch.nn.Linear)][-1]
        with torch.no_grad():  # start at the labels' mean: they sit far from 0 (~80)
            last.bias.fill_(labels[train].mean())
        optim = torch.optim.Adam(head.parameters(), lr=lr)
        resample = train[torch.randint(len(train), (len(train),))]  # this head's bootstrap
        for _ in range(updates):
            r = resample[torch.randint(len(resample), (batch,))]
            t = torch.randint(steps, (batch,))
            loss = (head(path[r, t]).squeeze(-1) - labels[r, t]).pow(2).mean()
            optim.zero_grad()
            loss.backward()
            optim.step()
        new.append(head.requires_grad_(False))
    all_heads = [wm.value_head, *new]
    with torch.no_grad():
        x, y = path[heldout, :, 0], labels[heldout, :, 0]
        values = [h(x).squeeze(-1) for h in all_heads]
        for name, v in [*zip(["pretrained", *[f"new {k}" for k in range(count)]], values),
                        ("mean", torch.stack(values).mean(0))]:
            print(f"held-out episodes, {name} head: R^2 {1 - (v - y).pow(2).mean() / y.var():.3f}")
        residuals = [(v - y).flatten() for v in values]
        for k in range(count):
            c = torch.corrcoef(torch.stack([residuals[0], residuals[k + 1]]))[0, 1]
            print(f"  residual correlation, pretrained vs new {k}: {c:.2f}")
        for folder in folders:
            zt = _encode(wm, load_memmap(folder)[:, :])
            v = torch.stack([h(zt).squeeze(-1) for h in all_heads])
            print(f"{folder}: V per head {[round(x, 1) for x in v.mean((1, 2)).tolist()]}; "
                  f"mean |new - pretrained| {(v[1:] - v[0]).abs().mean():.2f}, "
                  f"spread over heads (std) {v.std(0).mean():.2f}")
    if not target:
        return
    agent = recipe.load_agent(cfg, recipe.load_finished_run(run)[1], weights)
    saved = {}
    for name, chosen in (("meanheads", [agent.world_model.value_head, *new]),
                         ("newheads", new)):
        original = agent.world_model.value_head
        agent.world_model.value_head = MeanOfHeads(chosen)
        stats, _ = recipe.evaluate_planner(cfg, agent, target)
        agent.world_model.value_head = original
        saved[name] = {target: [float(f) for f in stats["fraction"]]}
        low, high = stats["ci_fraction"]
        print(f"{name} ({len(chosen)} heads) in {target}: {100 * stats['mean_fraction']:.0f}% "
              f"[{100 * low:.0f}, {100 * high:.0f}], {sum(stats['upside_down'])} on its back",
              flush=True)
        if save_json:
            save_json.write_text(json.dumps(saved, indent=1))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    a = sub.add_parser("audit", help="value labels and the value head near tip-overs")
    a.add_argument("--run", required=True, type=Path, help="a finished recipe output folder")
    a.add_argument("--data", nargs="*", default=[], type=Path,
                   help="memmap folders of recorded target episodes (a round's data)")

    def rollout_parser(name: str, summary: str):  # the open-loop commands' shared arguments
        p = sub.add_parser(name, help=summary)
        p.add_argument("--run", required=True, type=Path)
        p.add_argument("--data", nargs="+", required=True, type=Path,
                       help="memmap folders of recorded target episodes (a round's data)")
        p.add_argument("--weights", nargs="*", default=[],
                       help="finetuned world-model weights to compare with the pretrained ones")
        return p

    rollout_parser("foresee", "does the model predict a tip-over from the actions taken"
                   ).add_argument("--steps-before", type=int, default=60)
    rollout_parser("bias", "predicted against real reward where the robot stays up"
                   ).add_argument("--horizon", type=int, default=20,
                                  help="window length (the plan's)")
    r = sub.add_parser("refit", help="fit the value head to the data's returns")
    r.add_argument("--run", required=True, type=Path)
    r.add_argument("--base", default=None,
                   help="world-model weights the new head goes into (default: pretrained)")
    r.add_argument("--out", required=True, type=Path)
    r.add_argument("--iterations", type=int, default=2)
    r.add_argument("--updates", type=int, default=3000, help="per iteration")
    r.add_argument("--batch", type=int, default=256)
    r.add_argument("--lr", type=float, default=3e-4)
    r.add_argument("--seed", type=int, default=0)
    h = sub.add_parser("heads", help="plan with the mean of several value heads")
    h.add_argument("--run", required=True, type=Path)
    h.add_argument("--weights", default=None, help="the planner's world model (default: "
                   "pretrained); the pretrained model's latents train the heads")
    h.add_argument("--data", nargs="*", default=[], type=Path,
                   help="target-data folders to measure the heads' disagreement on")
    h.add_argument("--heads", type=int, default=1, help="new heads beside the pretrained one")
    h.add_argument("--episodes", type=int, default=512, help="dataset episodes to fit on")
    h.add_argument("--updates", type=int, default=3000)
    h.add_argument("--batch", type=int, default=256)
    h.add_argument("--lr", type=float, default=3e-4)
    h.add_argument("--seed", type=int, default=0)
    h.add_argument("--target", default="slippery_slope",
                   help="plan there with the heads' mean (the run's evaluation worlds); \"\": do not plan")
    h.add_argument("--save-json", type=Path, default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.command == "audit":
        audit(args.run, args.data)
    elif args.command == "foresee":
        foresee(args.run, args.data, args.weights, args.steps_before)
    elif args.command == "bias":
        bias(args.run, args.data, args.weights, args.horizon)
    elif args.command == "heads":
        heads(args.run, args.weights, args.data, args.heads, args.episodes, args.updates,
              args.batch, args.lr, args.seed, args.target, args.save_json)
    else:
        refit(args.run, args.base, args.out, args.iterations, args.updates, args.batch,
              args.lr, args.seed)


if __name__ == "__main__":
    main()
