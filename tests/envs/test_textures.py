import numpy as np
import pytest

from simdist.envs import ColourBank, TextureBank

# a pixel sum of item 0 of each bank (seed 0, 4x4) before the validation split existed
TRAIN_ITEM_SUM, HELDOUT_ITEM_SUM = 5402, 6561


@pytest.mark.parametrize("first,second", [("train", "heldout"), ("train", "validation"),
                                          ("validation", "heldout")])
def test_no_two_splits_share_a_texture(first, second):
    a_bank = [TextureBank(first, 48, seed=3).texture(i, 24, 24) for i in range(48)]
    b_bank = [TextureBank(second, 48, seed=3).texture(i, 24, 24) for i in range(48)]
    for a in a_bank:
        for b in b_bank:
            assert np.abs(a.astype(int) - b).mean() > 1.0


def test_adding_the_validation_split_changed_no_train_or_heldout_item():
    """Pinned pixels of the banks every result so far was trained and reported on."""
    assert TextureBank("train", 8, seed=0).texture(0, 4, 4).sum() == TRAIN_ITEM_SUM
    assert TextureBank("heldout", 8, seed=0).texture(0, 4, 4).sum() == HELDOUT_ITEM_SUM


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
    with pytest.raises(ValueError, match="valid splits: train, validation, heldout"):
        TextureBank("test")
    with pytest.raises(IndexError, match="outside bank of size 4"):
        TextureBank("train", 4).texture(4, 8, 8)
    with pytest.raises(ValueError, match="size must be >= 1"):
        ColourBank("train", 0)
