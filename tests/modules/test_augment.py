"""DrQ random shift: integer shifts with replicated edges, shared along a sequence or not."""

import pytest
import torch

from simdist.modules import RandomRotate, RandomShift


def _ramp(lead=(2, 3), size=8):
    """Images whose pixel value encodes (row, column): a shift is readable from them."""
    rows = torch.arange(size)[:, None].expand(size, size)
    cols = torch.arange(size)[None, :].expand(size, size)
    image = torch.stack([rows, cols, rows * 0], -1).to(torch.uint8)
    return image.expand(*lead, size, size, 3).clone()


def _shift_of(images):
    """(row, column) shift of each image, read at the centre pixel of a ramp."""
    c = images.shape[-2] // 2
    return images[..., c, c, :2].long() - c


def test_shift_is_an_integer_translation_with_replicated_edges():
    torch.manual_seed(0)
    images = _ramp((64,))
    out = RandomShift(pad=2, per="frame")(images)
    assert out.dtype == torch.uint8 and out.shape == images.shape
    shift = _shift_of(out)
    assert shift.abs().max() <= 2 and len(torch.unique(shift, dim=0)) > 5
    for image, (dy, dx) in zip(out, shift.tolist()):
        rows = (torch.arange(8) + dy).clamp(0, 7)
        cols = (torch.arange(8) + dx).clamp(0, 7)
        assert torch.equal(image[..., 0], rows[:, None].expand(8, 8).to(torch.uint8))
        assert torch.equal(image[..., 1], cols[None, :].expand(8, 8).to(torch.uint8))


def test_sequence_mode_shares_one_shift_along_time_frame_mode_does_not():
    torch.manual_seed(0)
    images = _ramp((16, 5))
    per_sequence = _shift_of(RandomShift(pad=3, per="sequence")(images))  # [16, 5, 2]
    assert (per_sequence == per_sequence[:, :1]).all()
    assert len(torch.unique(per_sequence[:, 0], dim=0)) > 1  # sequences differ
    per_frame = _shift_of(RandomShift(pad=3, per="frame")(images))
    assert not (per_frame == per_frame[:, :1]).all()


def test_eval_mode_and_zero_pad_are_identity_and_bad_arguments_raise():
    images = _ramp((2, 3))
    assert torch.equal(RandomShift(pad=4).eval()(images), images)
    assert torch.equal(RandomShift(pad=0)(images), images)
    with pytest.raises(ValueError, match="pad"):
        RandomShift(pad=-1)
    with pytest.raises(ValueError, match="per"):
        RandomShift(per="batch")
    with pytest.raises(ValueError, match="sequence"):
        RandomShift(pad=2, per="sequence")(torch.zeros(8, 8, 3))


def test_generator_makes_shifts_reproducible_and_float_images_work():
    images = _ramp((4, 2)).float()
    a = RandomShift(2, generator=torch.Generator().manual_seed(3))(images)
    b = RandomShift(2, generator=torch.Generator().manual_seed(3))(images)
    assert a.dtype == torch.float32 and torch.equal(a, b)


def test_rotation_turns_a_line_about_the_centre_and_shares_angles_per_sequence():
    torch.manual_seed(0)
    line = torch.zeros(8, 3, 33, 33, 1)
    line[..., 16, :, 0] = 200.0  # a horizontal line through the centre, 3 frames per sequence
    out = RandomRotate(max_deg=30, per="sequence")(line)
    assert (out[:, 1:] == out[:, :1]).all()  # one angle per sequence
    assert (out[..., 16, 16, 0] > 150).all()  # the centre stays on the line
    tilted = (out[:, 0, :, 0, 0] > 100).float().argmax(-1)  # row of the line at the left edge
    assert len(torch.unique(tilted)) > 1  # sequences turned by different angles
    frames = RandomRotate(max_deg=30, per="frame")(line)
    assert not (frames[:, 1:] == frames[:, :1]).all()
    uint8 = RandomRotate(10, per="frame")(line[:, 0].to(torch.uint8))
    assert uint8.dtype == torch.uint8 and uint8.shape == (8, 33, 33, 1)


def test_rotation_identity_cases_and_bad_arguments():
    images = _ramp((2, 3))
    assert torch.equal(RandomRotate(5).eval()(images), images)
    assert torch.equal(RandomRotate(0)(images), images)
    with pytest.raises(ValueError, match="max_deg"):
        RandomRotate(-1)
    with pytest.raises(ValueError, match="per"):
        RandomRotate(5, per="batch")
    with pytest.raises(ValueError, match="sequence"):
        RandomRotate(5, per="sequence")(torch.zeros(8, 8, 3))


def test_reading_noise_has_the_asked_std_per_dimension_and_is_off_in_eval():
    from simdist.modules import ReadingNoise
    std = torch.tensor([0.1, 0.0, 0.02])
    noise = ReadingNoise(std, generator=torch.Generator().manual_seed(0))
    readings = torch.full((200, 50, 3), 0.5)
    out = noise(readings)
    residual = (out - readings).reshape(-1, 3)
    assert torch.allclose(residual.std(0), std, rtol=0.02, atol=1e-6)
    assert residual.mean(0).abs().max() < 0.003  # unbiased
    assert torch.equal(out[..., 1], readings[..., 1])
    assert not torch.equal(noise(readings), out)  # fresh noise every call
    assert noise.eval()(readings) is readings


def test_reading_noise_refuses_images_wrong_widths_and_bad_stds():
    from simdist.modules import ReadingNoise
    noise = ReadingNoise(torch.tensor([0.1, 0.1, 0.1]))
    with pytest.raises(ValueError, match="float readings"):
        noise(torch.zeros(2, 64, 64, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match=r"\[\.\.\., 3\]"):
        noise(torch.zeros(2, 5))
    for bad in (torch.tensor([-0.1]), torch.tensor([float("nan")]), torch.zeros(2, 2)):
        with pytest.raises(ValueError, match="std must be"):
            ReadingNoise(bad)
