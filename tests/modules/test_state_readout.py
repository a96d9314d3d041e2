"""StateReadout / ReadoutEncoder: frozen, shape-checked, saved without pickle, and a readout
student that trains, saves and reloads like any TWIST student."""

import json
import math

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import DreamerAgent, DreamerConfig, TwistConfig, TwistStudent
from simdist.modules import (DreamerWorldModel, PixelEncoder, ReadoutEncoder, StateEncoder,
                             StateReadout)

DOMAIN = ([-1.0, math.cos(0.3), -math.sin(0.3)], [1.0, 1.0, math.sin(0.3)])


def _readout(**kwargs) -> StateReadout:
    torch.manual_seed(0)
    return StateReadout(PixelEncoder(4, norm="layer", input_norm="image"), 5, [0, 1, 2],
                        **kwargs)


def _images(*batch) -> torch.Tensor:
    return torch.randint(0, 256, (*batch, 64, 64, 3), dtype=torch.uint8)


def test_readout_reads_images_in_state_units_and_passes_readings_through():
    readout = _readout(mean=torch.tensor([0.5, 1.0, 0.0]), std=torch.tensor([2.0, 1.0, 3.0]))
    images = _images(2, 3)
    out = readout(images)
    assert out.shape == (2, 3, 3)
    # by hand: the head's standardised output of the kept dims, then * std + mean
    raw = readout.head(readout.encoder(images.reshape(-1, 64, 64, 3)))[:, :3]
    assert torch.allclose(out.reshape(-1, 3), raw * readout.std + readout.mean)
    readings = readout.read(images.reshape(-1, 64, 64, 3), chunk=4)
    assert torch.allclose(readings, out.reshape(-1, 3))
    assert readout(readings) is readings  # a precomputed reading is returned as it is


@pytest.mark.parametrize("bad, match", [
    (torch.zeros(2, 32, 32, 3, dtype=torch.uint8), r"must end with shape \(64, 64, 3\)"),
    (torch.zeros(2, 5), "precomputed readings"),
    (torch.zeros(2, 3, dtype=torch.long), "precomputed readings")])
def test_readout_refuses_what_it_cannot_read(bad, match):
    with pytest.raises(ValueError, match=match):
        _readout()(bad)


@pytest.mark.parametrize("kwargs, match", [
    ({"dims": [0, 0]}, "distinct"), ({"dims": [5]}, "distinct"),
    ({"domain": ([0.0], [1.0])}, "domain must be"),
    ({"domain": ([1.0, 0, 0], [0.0, 1, 1])}, "low < high")])
def test_readout_refuses_bad_construction(kwargs, match):
    args = {"dims": [0, 1, 2], **kwargs}
    with pytest.raises(ValueError, match=match):
        StateReadout(PixelEncoder(4), 5, **args)


def test_readout_is_frozen_and_stays_in_evaluation_mode():
    readout = _readout()
    readout.train()
    assert not readout.training and not readout.encoder.training
    assert not any(p.requires_grad for p in readout.parameters())


def test_covers_is_the_fitted_box_of_the_read_dimensions():
    readout = _readout(domain=DOMAIN)
    # x, cos, sin, v, omega: upright; pole 0.4 rad over; cart at 1.2 m; fast (v unread)
    states = torch.tensor([[0.0, 1.0, 0.0, 0.0, 0.0],
                           [0.0, math.cos(0.4), math.sin(0.4), 0.0, 0.0],
                           [1.2, 1.0, 0.0, 0.0, 0.0],
                           [0.5, math.cos(0.2), -math.sin(0.2), 9.0, -9.0]])
    assert readout.covers(states).tolist() == [True, False, False, True]
    assert _readout().covers(states).all()  # no domain: everything
    with pytest.raises(ValueError, match="'state' must end with shape"):
        readout.covers(torch.zeros(3, 4))


def test_save_load_round_trip_without_pickle(tmp_path):
    readout = _readout(mean=torch.tensor([0.1, 0.9, 0.0]), domain=DOMAIN)
    path = readout.save(tmp_path / "r.pt", meta={"task": "cartpole-balance"})
    desc = json.loads(path.with_suffix(".json").read_text())
    assert desc["task"] == "cartpole-balance" and desc["readout"]["depth"] == 4
    loaded = StateReadout.load(path)
    images = _images(3)
    assert torch.equal(loaded(images), readout(images))
    assert loaded.domain == readout.domain


def test_load_refuses_missing_or_mismatched_or_poisoned_files(tmp_path):
    readout = _readout()
    with pytest.raises(FileNotFoundError, match="no readout file"):
        StateReadout.load(tmp_path / "absent.pt")
    path = readout.save(tmp_path / "r.pt")
    desc = json.loads(path.with_suffix(".json").read_text())
    desc["readout"]["depth"] = 8  # the weights are depth 4
    path.with_suffix(".json").write_text(json.dumps(desc))
    with pytest.raises(ValueError, match="does not match its description"):
        StateReadout.load(path)
    path = readout.save(tmp_path / "r.pt")
    state = torch.load(path, weights_only=True)
    state["mean"][0] = float("nan")
    torch.save(state, path)
    with pytest.raises(ValueError, match="NaN or inf"):
        StateReadout.load(path)


def _readout_student(readout: StateReadout | None = None) -> TwistStudent:
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    readout = _readout(domain=DOMAIN) if readout is None else readout
    model = DreamerWorldModel.readout_student(readout, 1, "tiny")
    return TwistStudent(teacher, model, TwistConfig(horizon=3, lr=1e-2))


def _batch(pixels: torch.Tensor) -> TensorDict:
    slices, steps = pixels.shape[:2]
    return TensorDict({"action": torch.rand(slices, steps, 1) * 2 - 1,
                       "is_init": torch.zeros(slices, steps, 1, dtype=torch.bool),
                       "next": {"state": torch.randn(slices, steps, 5), "pixels": pixels}},
                      [slices, steps])


def test_readout_student_trains_its_rssm_and_state_encoder_never_the_readout():
    twist = _readout_student()
    assert twist.start_from_teacher_rssm() == len(twist.student.rssm.state_dict())
    teacher_rssm = twist.teacher.world_model.rssm.state_dict()
    assert all(torch.equal(v, teacher_rssm[k]) for k, v in twist.student.rssm.state_dict().items())
    readout = twist.student.encoder.readout
    before = {k: v.clone() for k, v in readout.state_dict().items()}
    encoder_before = [p.clone() for p in twist.student.encoder.encoder.parameters()]
    images = _images(2, 4)
    for pixels in (images, readout(images)):  # from images, then from readings read once
        twist.update(_batch(pixels))
    assert all(torch.equal(v, before[k]) for k, v in readout.state_dict().items())
    assert all(p.grad is None for p in readout.parameters())
    assert any(not torch.equal(a, b) for a, b in
               zip(encoder_before, twist.student.encoder.encoder.parameters()))


@pytest.mark.parametrize("gated", [False, True])
def test_readout_student_saves_and_reloads_and_acts_the_same(tmp_path, gated):
    twist = _readout_student(_gated()[0] if gated else None)
    twist.update(_batch(_images(2, 4)))
    loaded = TwistStudent.load(twist.save(tmp_path / "student.pt"))
    assert isinstance(loaded.student.encoder, ReadoutEncoder)
    assert loaded.student.encoder.readout.domain == twist.student.encoder.readout.domain
    assert loaded.student.encoder.readout.gate == twist.student.encoder.readout.gate
    assert (loaded.student.encoder.readout.fallback is None) == (not gated)
    images = _images(3)
    assert torch.equal(loaded.student.encoder(images), twist.student.encoder(images))


@pytest.mark.parametrize("saved_gated", [False, True])
def test_a_student_saved_with_the_other_kind_of_readout_is_refused_clearly(saved_gated):
    saved = _readout_student(_gated()[0] if saved_gated else None).state_dict()
    other = _readout_student(None if saved_gated else _gated()[0])
    before = {k: v.clone() for k, v in other.student.state_dict().items()}
    has = "has" if saved_gated else "has no"
    with pytest.raises(ValueError, match=f"readout {has} fallback.*twist_redeploy_readout"):
        other.load_state_dict(saved)
    assert all(torch.equal(v, before[k]) for k, v in other.student.state_dict().items())


def test_readout_encoder_refuses_a_state_encoder_of_another_width():
    with pytest.raises(ValueError, match="reads 5 values, the readout gives 3"):
        ReadoutEncoder(_readout(), StateEncoder(5, 8, 8))


def test_describe_refuses_an_encoder_it_could_not_rebuild():
    readout = StateReadout(PixelEncoder(4, arch="keypoints", keypoints=4), 5, [0, 1, 2])
    with pytest.raises(ValueError, match="only a PixelEncoder of arch 'dreamer'"):
        readout.describe()


GATE = ([-0.9, 0.9, -0.27], [0.9, 2.0, 0.27])
FALLBACK_GATE = ([-9.0, 0.3, -9.0], [9.0, 2.0, 9.0])


def _gated() -> tuple[StateReadout, StateReadout]:
    torch.manual_seed(1)
    wide = StateReadout(PixelEncoder(4, norm="layer", input_norm="image"), 5, [0, 1, 2],
                        mean=torch.tensor([0.0, 0.0, 0.0]), std=torch.tensor([1.0, 0.7, 0.7]))
    return _readout(domain=DOMAIN, fallback=wide, gate=GATE, fallback_gate=FALLBACK_GATE), wide


def _in(values: torch.Tensor, box) -> torch.Tensor:
    return ((values >= torch.tensor(box[0])) & (values <= torch.tensor(box[1]))).all(-1)


def test_fallback_answers_where_either_reading_leaves_its_gate():
    gated, wide = _gated()
    precise = _readout(domain=DOMAIN)  # the same weights, no fallback
    images = _images(4, 6)
    coarse, fine, out = wide(images), precise(images), gated(images)
    inside = _in(fine, GATE) & _in(coarse, FALLBACK_GATE)
    # by hand: the precise reading inside both gates, the fallback's everywhere else
    assert torch.equal(out, torch.where(inside[..., None], fine, coarse))
    assert torch.equal(gated.gated(fine, coarse), inside)
    assert torch.equal(gated.without_fallback()(images), fine)
    rebuilt = precise.with_fallback(wide, gate=GATE, fallback_gate=FALLBACK_GATE)
    assert torch.equal(rebuilt(images), out)  # the same weights, composed anew
    # each gate alone sends an image to the fallback: put every reading in, then out
    with torch.no_grad():
        for r in (precise, gated, wide):
            r.std.fill_(1e-6), r.mean.copy_(torch.tensor([0.0, 1.0, 0.0]))  # upright
    assert torch.equal(gated(images), precise(images))
    with torch.no_grad():
        wide.mean[1] = 0.0  # the fallback sees the pole horizontal: below its cos gate
    assert torch.equal(gated(images), wide(images))
    with torch.no_grad():
        wide.mean[1], gated.mean[0] = 1.0, 0.95  # the precise cart reading beyond 0.9 m
    assert torch.equal(gated(images), wide(images))
    # covers stays this readout's own fitted domain, frozen like the rest
    assert gated.covers(torch.tensor([[1.2, 1.0, 0.0, 0.0, 0.0]])).tolist() == [False]
    assert not any(p.requires_grad for p in gated.parameters())
    readings = gated.read(images.reshape(-1, 64, 64, 3))
    assert gated(readings) is readings  # precomputed readings pass through


def test_fallback_round_trips_and_refuses_mismatches(tmp_path):
    gated, _ = _gated()
    path = gated.save(tmp_path / "g.pt")
    desc = json.loads(path.with_suffix(".json").read_text())["readout"]
    assert desc["gate"] == [list(s) for s in GATE] and desc["fallback"]["depth"] == 4
    assert desc["fallback_gate"] == [list(s) for s in FALLBACK_GATE]
    loaded = StateReadout.load(path)
    images = _images(5)
    assert torch.equal(loaded(images), gated(images)) and loaded.gate == gated.gate
    assert loaded.fallback_gate == gated.fallback_gate
    with pytest.raises(ValueError, match="the fallback readout reads dims"):
        StateReadout(PixelEncoder(4), 5, [0, 1], fallback=_readout())
    for gate in ({"gate": GATE}, {"fallback_gate": FALLBACK_GATE}):
        with pytest.raises(ValueError, match="a gate needs a fallback"):
            _readout(**gate)
    with pytest.raises(ValueError, match="needs a gate"):
        _readout(fallback=_readout())
    with pytest.raises(ValueError, match="gate must be"):
        _readout(fallback=_readout(), gate=([0.0], [1.0]))
    with pytest.raises(ValueError, match="fallback_gate must be"):
        _readout(fallback=_readout(), gate=GATE, fallback_gate=([1.0] * 3, [0.0] * 3))
    with pytest.raises(ValueError, match="no fallback"):
        _readout().gated(torch.zeros(2, 3), torch.zeros(2, 3))
