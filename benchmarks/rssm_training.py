"""RSSM training throughput: our LossModule path vs a plain-PyTorch loop, same networks.

One update = filter a batch of slices (observe), compute the Dreamer world-model loss
(reconstruction + reward + balanced KL), backward, Adam step. "simdist" goes through
``DreamerWorldModelLoss`` on a TensorDict (key reads, input finiteness checks, loss-term
checks); "plain" calls the same ``nn.Module`` parts on raw tensors with the same math.
The ratio is the TensorDict/TorchRL overhead. ``--compile`` also times ``torch.compile``
of the plain update (compile time reported separately).

Usage:
    python benchmarks/rssm_training.py                 # batch 16 x 50, "small" RSSM
    python benchmarks/rssm_training.py --quick
    python benchmarks/rssm_training.py --device cuda --size paper --batch 16 --length 64
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

import simdist  # noqa: F401
from simdist.modules import DreamerWorldModel
from simdist.objectives import DreamerWorldModelLoss
from simdist.objectives.dreamer import balanced_kl


def make_batch(B, T, state_dim, action_dim, device="cpu"):
    from tensordict import TensorDict
    return TensorDict({
        "action": torch.rand(B, T, action_dim) * 2 - 1,
        "is_init": torch.zeros(B, T, 1, dtype=torch.bool),
        "next": {"state": torch.randn(B, T, state_dim), "reward": torch.randn(B, T, 1)},
    }, [B, T]).to(device)


def plain_update(wm, opt, state, action, reward, is_init):
    out = wm.observe(state, action, is_init)
    feats = torch.cat([out["belief"], out["stoch"]], -1)
    recon = 0.5 * (wm.decoder(feats) - state).pow(2).sum(-1).mean()
    rew = 0.5 * (wm.reward_head(feats) - reward).pow(2).mean()
    kl = balanced_kl(wm.rssm, out["posterior_logits"], out["prior_logits"], 0.8, 1.0).mean()
    loss = recon + rew + kl
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return loss.detach()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--compile", action="store_true")
    parser.add_argument("--size", default="small")
    parser.add_argument("--batch", type=int, default=16, help="slices per update")
    parser.add_argument("--length", type=int, default=50, help="steps per slice")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    B, T, S, A = args.batch, args.length, 5, 1
    updates, repeats = (3, 2) if args.quick else (10, 7)
    device = torch.device(args.device)
    # CUDA work is asynchronous: wait for it before reading the clock
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    torch.manual_seed(0)
    wm = DreamerWorldModel.teacher(S, A, size=args.size).to(device)
    opt = torch.optim.Adam(wm.parameters(), lr=1e-4)
    td = make_batch(B, T, S, A, device)
    loss_checked = DreamerWorldModelLoss(wm)
    loss_unchecked = DreamerWorldModelLoss(wm, check_inputs=False)
    raw = (td["next", "state"], td["action"], td["next", "reward"], td["is_init"].squeeze(-1))

    def ours(loss_module):
        def run():
            out = loss_module(td)
            total = out["loss_reconstruction"] + out["loss_reward"] + out["loss_kl"]
            opt.zero_grad(set_to_none=True)
            total.backward()
            opt.step()
        return run

    contenders = {"plain PyTorch loop": lambda: plain_update(wm, opt, *raw),
                  "simdist DreamerWorldModelLoss": ours(loss_checked),
                  "simdist, check_inputs=False": ours(loss_unchecked)}
    if args.compile:
        compiled = torch.compile(plain_update)
        start = time.perf_counter()
        compiled(wm, opt, *raw)
        print(f"torch.compile warm-up: {time.perf_counter() - start:.1f} s")
        contenders["plain PyTorch, torch.compile"] = lambda: compiled(wm, opt, *raw)

    rates = {k: [] for k in contenders}
    for run in contenders.values():
        run()
    for _ in range(repeats):
        for name, run in contenders.items():
            sync()
            start = time.perf_counter()
            for _ in range(updates):
                run()
            sync()
            rates[name].append(updates / (time.perf_counter() - start))
    ref = rates["plain PyTorch loop"]
    print(f"\nRSSM '{args.size}' (deter {wm.rssm.deter_dim}, {wm.rssm.stoch}x{wm.rssm.classes} "
          f"latents), batch {B} x {T}, device {device}, torch threads {torch.get_num_threads()}")
    print(f"{'contender':34s} {'updates/s':>10s} {'x plain':>8s} {'overhead':>9s}")
    for name, r in rates.items():
        ratio = statistics.median(a / b for a, b in zip(r, ref))
        print(f"{name:34s} {statistics.median(r):10.2f} {ratio:8.3f} {100 * (1 / ratio - 1):8.1f}%")


if __name__ == "__main__":
    main()
