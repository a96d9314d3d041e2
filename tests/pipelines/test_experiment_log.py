"""Scalar logs through TorchRL's loggers: what training writes, resumes and plots."""

import pytest
import torch

from simdist.pipelines import train_resumable
from simdist.pipelines.experiment_log import (make_logger, plot_curves, read_csv_scalars)


def _problem():
    torch.manual_seed(0)
    model = torch.nn.Linear(2, 1)
    optim = torch.optim.SGD(model.parameters(), lr=0.1)

    def update(x):
        loss = (model(x) - x.sum(-1, keepdim=True)).pow(2).mean()
        optim.zero_grad()
        loss.backward()
        optim.step()
        return {"loss": loss.item(), "note": "not a number"}

    return model, optim, update


def test_training_logs_every_update_and_a_resumed_run_keeps_one_value_per_step(tmp_path):
    model, optim, update = _problem()
    logger = make_logger("csv", tmp_path)
    history = train_resumable(update, lambda: torch.randn(8, 2), 12, {"m": model, "o": optim},
                              tmp_path / "ckpt.pt", every=5, progress=False, logger=logger,
                              log_prefix="stage")
    scalars = read_csv_scalars(tmp_path / "logs")
    assert list(scalars) == ["stage/loss"]  # strings are not logged
    steps, values = scalars["stage/loss"]
    assert steps == list(range(1, 13)) and values == [h["loss"] for h in history]
    # A crashed run re-logs the updates after its last checkpoint: appended to the same
    # file, read back once per step (the last value).
    path = tmp_path / "logs" / "scalars" / "stage" / "loss.csv"
    path.write_text(path.read_text() + "11,123.0\n")
    assert read_csv_scalars(tmp_path / "logs")["stage/loss"][1][10] == 123.0
    assert len(read_csv_scalars(tmp_path / "logs")["stage/loss"][0]) == 12
    assert plot_curves(tmp_path / "logs", tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 0


def test_unknown_logger_is_refused_and_none_logs_nothing(tmp_path):
    with pytest.raises(ValueError, match="unknown logger 'mlflowx'"):
        make_logger("mlflowx", tmp_path)
    assert make_logger("none", tmp_path) is None
    assert not plot_curves(tmp_path / "logs", tmp_path / "curves.png")  # nothing logged


def test_tensorboard_logger_writes_event_files_when_installed(tmp_path):
    pytest.importorskip("tensorboard")
    model, optim, update = _problem()
    logger = make_logger("tensorboard", tmp_path)
    train_resumable(update, lambda: torch.randn(8, 2), 3, {"m": model, "o": optim},
                    tmp_path / "ckpt.pt", progress=False, logger=logger, log_prefix="stage")
    logger.experiment.flush()
    assert list((tmp_path / "logs").rglob("events.out.tfevents.*"))


def test_training_curves_keep_losses_and_returns_apart_with_legends_beside_the_lines():
    """A return in the hundreds on the loss's axis would flatten the loss: each stage's
    losses and other metrics get their own axes; legends sit outside the axes; the update
    axis has integer ticks (no 0.5 of an update)."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    from simdist.pipelines.experiment_log import curves_figure
    fig = curves_figure({"teacher/loss_reconstruction": ([1, 2, 3], [3.0, 2.0, 1.0]),
                         "teacher/episode_return": ([1, 2, 3], [100.0, 400.0, 900.0]),
                         "student/loss_distillation": ([1, 2], [1.0, 0.5])})
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in visible] == [
        "student: losses", "teacher: losses", "teacher: other metrics"]
    for ax in visible:
        names = [line.get_label() for line in ax.get_lines()]
        assert all(n.startswith("loss") for n in names) or not any(
            n.startswith("loss") for n in names)
        anchor = ax.get_legend().get_bbox_to_anchor().transformed(ax.transAxes.inverted())
        assert anchor.x0 > 1.0  # beside the axes, right of the lines
        assert isinstance(ax.xaxis.get_major_locator(), MaxNLocator)
        ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
        assert all(float(t).is_integer() for t in ticks)
    plt.close(fig)
