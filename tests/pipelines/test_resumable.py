"""Resumable training: a killed job continues from its checkpoint; NaN stops it loudly."""

import pytest
import torch

from simdist.pipelines import mean_metrics, train_resumable, weights


def _problem(seed=0):
    torch.manual_seed(seed)
    model = torch.nn.Linear(3, 1)
    optim = torch.optim.Adam(model.parameters(), lr=1e-2)
    data = torch.Generator().manual_seed(seed)

    def sample():
        x = torch.randn(16, 3, generator=data)
        return x, x.sum(-1, keepdim=True)

    def update(batch):
        x, y = batch
        loss = (model(x) - y).pow(2).mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
        return {"loss": loss.item()}

    return model, optim, sample, update


def test_killed_run_resumes_from_checkpoint_and_matches_uninterrupted(tmp_path):
    model, optim, sample, update = _problem()
    full = train_resumable(update, sample, 40, {"m": model, "o": optim}, tmp_path / "a.pt",
                           every=10, progress=False)
    reference = weights(model)

    model, optim, sample, update = _problem()
    calls = {"n": 0}

    def crashing_update(batch):
        calls["n"] += 1
        if calls["n"] == 26:
            raise KeyboardInterrupt  # killed after 25 updates; checkpoint holds 20
        return update(batch)

    with pytest.raises(KeyboardInterrupt):
        train_resumable(crashing_update, sample, 40, {"m": model, "o": optim},
                        tmp_path / "b.pt", every=10, progress=False)
    # A fresh process: new objects, same command.
    model2, optim2, _, update2 = _problem(seed=1)
    _, _, sample_resumed, _ = _problem()
    for _ in range(20):
        sample_resumed()  # the data stream continues where the checkpoint was taken
    resumed = train_resumable(update2, sample_resumed, 40, {"m": model2, "o": optim2},
                              tmp_path / "b.pt", every=10, progress=False)
    assert len(resumed) == 40
    assert [h["loss"] for h in resumed[:20]] == [h["loss"] for h in full[:20]]
    for k, v in weights(model2).items():
        torch.testing.assert_close(v, reference[k])
    assert mean_metrics(resumed, 5)["loss"] < mean_metrics(resumed[:5], 5)["loss"]


def test_non_finite_loss_raises_naming_the_step(tmp_path):
    model, optim, sample, _ = _problem()
    with pytest.raises(FloatingPointError, match="non-finite \\['loss'\\] at update 0"):
        train_resumable(lambda b: {"loss": float("nan")}, sample, 5, {"m": model},
                        tmp_path / "c.pt", progress=False)


def test_global_rng_draws_resume_exactly_and_a_seed_isolates_the_stage(tmp_path):
    """Samples and updates drawing from torch's global generator (as replay buffers and
    stochastic losses do) continue after a crash exactly as the uninterrupted run did."""

    def problem():
        torch.manual_seed(0)  # the same initial weights in both runs
        model = torch.nn.Linear(3, 1)
        optim = torch.optim.SGD(model.parameters(), lr=1e-2)

        def sample():
            x = torch.randn(16, 3)  # global generator
            return x, x.sum(-1, keepdim=True) + 0.1 * torch.randn(16, 1)

        def update(batch):
            if crash["at"] is not None and len(crash["seen"]) == crash["at"]:
                raise KeyboardInterrupt
            crash["seen"].append(1)
            x, y = batch
            loss = (model(x) - y).pow(2).mean()
            optim.zero_grad()
            loss.backward()
            optim.step()
            return {"loss": loss.item()}

        return model, optim, sample, update

    crash = {"at": None, "seen": []}
    model, optim, sample, update = problem()
    torch.manual_seed(11)  # whatever the process drew before this stage...
    full = train_resumable(update, sample, 30, {"m": model, "o": optim}, tmp_path / "a.pt",
                           every=10, progress=False, seed=5)
    full_weights = weights(model)

    crash.update(at=17, seen=[])
    model, optim, sample, update = problem()
    torch.manual_seed(99)  # ...does not change a seeded stage
    with pytest.raises(KeyboardInterrupt):
        train_resumable(update, sample, 30, {"m": model, "o": optim}, tmp_path / "b.pt",
                        every=10, progress=False, seed=5)
    crash.update(at=None, seen=[])
    model, optim, sample, update = problem()
    torch.rand(500)  # a new process draws other things before resuming
    resumed = train_resumable(update, sample, 30, {"m": model, "o": optim}, tmp_path / "b.pt",
                              every=10, progress=False, seed=5)
    assert resumed == full
    assert all(torch.equal(v, full_weights[k]) for k, v in weights(model).items())
