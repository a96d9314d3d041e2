import numpy as np
import pytest

from simdist.envs import ColourBank, TextureBank


def test_train_and_heldout_textures_never_coincide():
    train = [TextureBank("train", 48, seed=3).texture(i, 24, 24) for i in range(48)]
    heldout = [TextureBank("heldout", 48, seed=3).texture(i, 24, 24) for i in range(48)]
    for a in train:
        for b in heldout:
            assert np.abs(a.astype(int) - b).mean() > 1.0


def test_texture_bank_is_deterministic_and_varied():
    bank = TextureBank("train", 16, seed=7)
    again = TextureBank("train", 16, seed=7)
    assert all((bank.texture(i, 16, 16) == again.texture(i, 16, 16)).all() for i in range(16))
    distinct = {bank.texture(i, 16, 16).tobytes() for i in range(16)}
    assert len(distinct) == 16
    other_seed = TextureBank("train", 16, seed=8)
    assert (bank.texture(0, 16, 16) != other_seed.texture(0, 16, 16)).any()


def test_colour_banks_are_disjoint():
    train = ColourBank("train", 64, seed=0).colours
    heldout = ColourBank("heldout", 64, seed=0).colours
    gaps = np.abs(train[:, None] - heldout[None]).sum(-1)
    assert gaps.min() > 1e-6


def test_bad_split_and_index_are_clear_errors():
    with pytest.raises(ValueError, match="valid splits: train, heldout"):
        TextureBank("validation")
    with pytest.raises(IndexError, match="outside bank of size 4"):
        TextureBank("train", 4).texture(4, 8, 8)
    with pytest.raises(ValueError, match="size must be >= 1"):
        ColourBank("train", 0)
