"""experiments/twist_readout_scale.py: state draws, targets, renders and the probe's rows."""

import json
import math

import pytest
import torch

from tests.in_process import benchmark_module

scale = benchmark_module("twist_readout_scale")


def test_states_stay_in_the_balancing_region_and_are_seeded():
    q = scale.draw_states(500, 3, max_angle=0.2, max_cart=0.5)
    assert q.shape == (500, 2)
    assert q[:, 0].abs().max() <= 0.5 and q[:, 1].abs().max() <= 0.2
    assert q[:, 1].abs().max() > 0.15  # uniform: the edges are reached
    assert torch.equal(q, scale.draw_states(500, 3, max_angle=0.2, max_cart=0.5))


def test_targets_are_cart_position_cosine_and_sine():
    q = torch.tensor([[0.3, 0.0], [-0.2, math.pi / 6]])
    expected = torch.tensor([[0.3, 1.0, 0.0], [-0.2, math.sqrt(3) / 2, 0.5]])
    assert torch.allclose(scale.targets(q), expected, atol=1e-6)


def test_renders_follow_the_state(tmp_path):
    q = torch.tensor([[0.0, 0.0], [0.0, 0.0], [0.8, 0.25]])
    visual = scale.VisualRandomisation.training(textures=None, colours=None, lighting=False)
    images = scale.render(q, visual, seed=0, workers=1)
    assert images.shape == (3, 64, 64, 3) and images.dtype == torch.uint8
    assert torch.equal(images[0], images[1])  # same state, nothing randomised
    assert not torch.equal(images[0], images[2])  # the cart moved, the pole leans


def test_probe_rows_and_json(tmp_path):
    out = tmp_path / "scale.json"
    scale.main(["--train-images", "6", "12", "--updates", "4", "--batch", "4",
                "--test-images", "6", "--depth", "4", "--json", str(out)])
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [(r["train_images"], r["updates"]) for r in rows] == [
        (6, 1), (6, 2), (6, 3), (6, 4), (12, 1), (12, 2), (12, 3), (12, 4)]
    for row in rows:
        for name in ("train_dr", "heldout_nocam", "heldout"):
            assert len(row[f"rmse_{name}"]) == 3
            assert all(math.isfinite(v) and v >= 0 for v in row[f"rmse_{name}"])
        assert row["camera"] == "none" and row["device"] == "cpu"


def _diagnosis():
    return benchmark_module("twist_diagnosis")


def test_fitted_readout_reads_what_the_probe_read_and_is_frozen():
    torch.manual_seed(0)
    encoder = scale.PixelEncoder(4, norm="layer", input_norm="image").eval()
    head = torch.nn.Linear(encoder.embed_dim, 3)
    mean, std = torch.tensor([0.1, 0.9, 0.0]), torch.tensor([0.5, 0.02, 0.2])
    readout = scale.fitted_readout(encoder, head, mean, std, scale.balancing_domain(0.3, 1.0))
    assert readout.head.weight.shape == (5, encoder.embed_dim)
    assert torch.equal(readout.head.weight[3:], torch.zeros(2, encoder.embed_dim))
    images = torch.randint(0, 256, (3, 64, 64, 3), dtype=torch.uint8)
    with torch.no_grad():
        expected = head(encoder(images)) * std + mean
        assert torch.allclose(readout(images), expected, atol=1e-5)
    assert not any(p.requires_grad for p in readout.parameters())
    assert encoder.net[0].weight.requires_grad is True  # the probe's own encoder untouched
    # the domain is the box the poses were drawn in: upright in, 0.4 rad over out
    states = torch.tensor([[0.9, 1.0, 0.0, 0, 0], [0.0, 0.921, 0.389, 0, 0]])
    assert readout.covers(states).tolist() == [True, False]


def test_main_saves_one_readout_per_camera_and_size_that_the_recipe_loads(tmp_path):
    scale.main(["--train-images", "6", "--updates", "4", "--batch", "4", "--test-images",
                "6", "--depth", "4", "--save-readouts", str(tmp_path / "ro")])
    readout = scale.StateReadout.load(tmp_path / "ro" / "readout_none_6.pt")
    assert readout.dims.tolist() == [0, 1, 2] and readout.domain is not None
    meta = json.loads((tmp_path / "ro" / "readout_none_6.json").read_text())
    assert meta["task"] == "cartpole-balance" and "--save-readouts" in meta["command"]
    assert len(meta["rmse_x_cos_sin"]["rmse_heldout"]) == 3
    from simdist.pipelines import twist as twist_dmc
    cfg = twist_dmc.Config(student_readout=str(tmp_path / "ro" / "readout_none_6.pt"))
    assert twist_dmc.readout_file(cfg, "cartpole-balance").name == "readout_none_6.pt"


def test_recorded_states_become_poses_repeated_per_render(tmp_path):
    angles = torch.tensor([0.0, 0.5, -2.0])
    states = torch.stack([torch.tensor([0.1, -0.3, 1.2]), angles.cos(), angles.sin(),
                          torch.zeros(3), torch.zeros(3)], -1)
    torch.save(states, tmp_path / "d.pt")
    q = scale.recorded_states(tmp_path / "d.pt", renders=2, seed=0)
    assert q.shape == (6, 2)
    expected = sorted([(0.1, 0.0), (-0.3, 0.5), (1.2, -2.0)] * 2)
    assert sorted((round(a, 5), round(b, 5)) for a, b in q.tolist()) == expected
    torch.save(states[:, :3], tmp_path / "bad.pt")
    try:
        scale.recorded_states(tmp_path / "bad.pt", 1, 0)
    except ValueError as err:
        assert "[N, 5]" in str(err)
    else:
        raise AssertionError("a [N, 3] tensor must be refused")


def test_readings_computed_once_equal_reading_at_every_update():
    from tensordict import TensorDict
    diagnosis = _diagnosis()  # the diagnosis's --cache-readout uses the recipe's helper
    torch.manual_seed(1)
    readout = scale.StateReadout(scale.PixelEncoder(4, norm="layer", input_norm="image"), 5,
                                 [0, 1, 2])
    pixels = torch.randint(0, 256, (7, 64, 64, 3), dtype=torch.uint8)
    episode = TensorDict({"next": {"pixels": pixels, "state": torch.zeros(7, 5)}}, [7])
    cached = diagnosis.recipe.with_readings(episode, readout)
    assert episode["next", "pixels"].dtype == torch.uint8  # the original is untouched
    with torch.no_grad():
        assert torch.allclose(cached["next", "pixels"], readout(pixels), atol=1e-6)
        # a student whose encoder starts with the readout trains on either the same way
        assert torch.equal(readout(cached["next", "pixels"]), cached["next", "pixels"])


def test_init_readout_goes_on_from_the_file_in_its_units(tmp_path):
    scale.main(["--train-images", "6", "--updates", "4", "--batch", "4", "--test-images",
                "6", "--depth", "4", "--save-readouts", str(tmp_path / "a")])
    start = scale.StateReadout.load(tmp_path / "a" / "readout_none_6.pt")
    # a vanishing rate: the refit must be the starting readout, with its mean and std
    scale.main(["--train-images", "6", "--updates", "4", "--batch", "4", "--test-images",
                "6", "--depth", "4", "--lr", "1e-12", "--max-cart", "1.5",
                "--init-readout", str(tmp_path / "a" / "readout_none_6.pt"),
                "--save-readouts", str(tmp_path / "b")])
    refit = scale.StateReadout.load(tmp_path / "b" / "readout_none_6.pt")
    assert torch.equal(refit.mean, start.mean) and torch.equal(refit.std, start.std)
    for a, b in zip(start.state_dict().values(), refit.state_dict().values()):
        assert torch.allclose(a.float(), b.float(), atol=1e-6)
    assert refit.domain[0][0] == -1.5 and refit.domain[1][0] == 1.5  # the new box
    meta = json.loads((tmp_path / "b" / "readout_none_6.json").read_text())
    assert "--init-readout" in meta["command"]
    # a readout of other dimensions is not a starting point for (x, cos, sin)
    other = scale.StateReadout(scale.PixelEncoder(4, norm="layer", input_norm="image"), 5,
                               [0, 2])
    other.save(tmp_path / "other.pt")
    try:
        scale.main(["--train-images", "6", "--updates", "4", "--batch", "4",
                    "--test-images", "6", "--depth", "4",
                    "--init-readout", str(tmp_path / "other.pt")])
    except ValueError as err:
        assert "not (x, cos, sin)" in str(err)
    else:
        raise AssertionError("a readout of dimensions [0, 2] must be refused")


def test_whole_circle_domain_and_a_composed_fallback(tmp_path):
    assert scale.balancing_domain(math.pi, 1.8) == ([-1.8, -1.0, -1.0], [1.8, 1.0, 1.0])
    assert scale.balancing_domain(math.pi / 2, 1.0)[1][2] == 1.0
    with pytest.raises(ValueError, match="max_angle"):
        scale.balancing_domain(0.0, 1.0)
    scale.main(["--train-images", "6", "--updates", "4", "--batch", "4", "--test-images",
                "6", "--depth", "4", "--save-readouts", str(tmp_path / "a")])
    precise_path = tmp_path / "a" / "readout_none_6.pt"
    scale.main(["--train-images", "6", "--updates", "4", "--batch", "4", "--test-images",
                "6", "--depth", "4", "--max-angle", "3.1416", "--max-cart", "1.8",
                "--save-readouts", str(tmp_path / "w"), "--fallback-for", str(precise_path),
                "--gate-low", "-0.9", "0.9", "-0.27", "--gate-high", "0.9", "2", "0.27",
                "--fallback-gate-low", "-9", "0.3", "-9", "--fallback-gate-high", "9", "2", "9"])
    wide = scale.StateReadout.load(tmp_path / "w" / "readout_none_6.pt")
    assert wide.domain == ([-1.8, -1.0, -1.0], [1.8, 1.0, 1.0])
    composed = scale.StateReadout.load(tmp_path / "w" / "composed_none_6.pt")
    precise = scale.StateReadout.load(precise_path)
    # the precise readout's weights, units and domain, the fresh fit as its fallback
    assert composed.domain == precise.domain
    assert composed.gate == ([-0.9, 0.9, -0.27], [0.9, 2, 0.27])
    assert composed.fallback_gate == ([-9, 0.3, -9], [9, 2, 9])
    images = torch.randint(0, 256, (8, 64, 64, 3), dtype=torch.uint8)
    inside = composed.gated(precise(images), wide(images))
    expected = torch.where(inside[:, None], precise(images), wide(images))
    assert torch.equal(composed(images), expected)
    meta = json.loads((tmp_path / "w" / "composed_none_6.json").read_text())
    assert meta["fallback"]["train_images"] == 6 and "readout" not in meta["fallback"]
    with pytest.raises(SystemExit):
        scale.main(["--fallback-for", str(precise_path), "--save-readouts", str(tmp_path)])
