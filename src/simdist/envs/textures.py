"""Procedural texture and colour banks with disjoint train / validation / held-out splits.

Nothing can be downloaded at run time, so backgrounds and floors come from seeded
procedural generators (checkers, stripes, smooth noise, blobs, gradients). Each item of a
bank is drawn from its own ``numpy`` seed sequence keyed by ``(bank seed, split, index)``;
the splits use different split keys, so no held-out item is ever generated for training
(a test also checks that no two items coincide pixel-wise).

The three splits have three jobs: ``train`` is what training randomises over;
``validation`` holds unseen items of the training distribution, on which defaults, gates
and candidates may be chosen; ``heldout`` is the reporting bank, only ever evaluated on.
"""

from __future__ import annotations

import functools

import numpy as np

SPLITS = ("train", "validation", "heldout")
# train and heldout keep the keys they always had: adding validation changes no item of them
_SPLIT_KEYS = {"train": 0, "heldout": 1, "validation": 2}


def check_split(split: str) -> str:
    """Returns ``split`` or raises a ``ValueError`` listing the valid splits."""
    if split not in _SPLIT_KEYS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")
    return split


def _rng(seed: int, split: str, index: int, stream: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), _SPLIT_KEYS[check_split(split)], int(index), stream])


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(0.0, 1.0, size=(n, 3))


def _checker(rng, h, w):
    c = _palette(rng, 2)
    cells = int(rng.integers(2, 12))
    yy, xx = np.mgrid[0:h, 0:w]
    mask = ((yy * cells // h) + (xx * cells // w)) % 2
    return c[mask]


def _stripes(rng, h, w):
    c = _palette(rng, 2)
    angle = rng.uniform(0, np.pi)
    freq = rng.uniform(2, 16)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    phase = np.sin(2 * np.pi * freq * (xx * np.cos(angle) + yy * np.sin(angle)))
    t = (phase > rng.uniform(-0.5, 0.5))[..., None]
    return np.where(t, c[0], c[1])


def _smooth_noise(rng, h, w):
    c = _palette(rng, 3)
    grid = int(rng.integers(3, 10))
    coarse = rng.uniform(0, 1, size=(grid, grid, 3))
    # Bilinear upsampling of a coarse random grid gives cloud-like textures.
    ys = np.linspace(0, grid - 1, h)
    xs = np.linspace(0, grid - 1, w)
    y0 = np.floor(ys).astype(int).clip(0, grid - 2)
    x0 = np.floor(xs).astype(int).clip(0, grid - 2)
    fy = (ys - y0)[:, None, None]
    fx = (xs - x0)[None, :, None]
    a = coarse[y0][:, x0]
    b = coarse[y0][:, x0 + 1]
    cc = coarse[y0 + 1][:, x0]
    d = coarse[y0 + 1][:, x0 + 1]
    weights = (1 - fy) * (1 - fx) * a + (1 - fy) * fx * b + fy * (1 - fx) * cc + fy * fx * d
    total = weights.sum(-1, keepdims=True).clip(1e-3)
    return (weights[..., :1] * c[0] + weights[..., 1:2] * c[1] + weights[..., 2:] * c[2]) / total


def _blobs(rng, h, w):
    c = _palette(rng, 4)
    img = np.broadcast_to(c[0], (h, w, 3)).copy()
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(int(rng.integers(3, 12))):
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        r = rng.uniform(0.05, 0.3) * max(h, w)
        inside = (yy - cy) ** 2 + (xx - cx) ** 2 < r**2
        img[inside] = c[int(rng.integers(1, 4))]
    return img


def _gradient(rng, h, w):
    c = _palette(rng, 2)
    angle = rng.uniform(0, 2 * np.pi)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    t = (xx * np.cos(angle) + yy * np.sin(angle))
    t = ((t - t.min()) / max(np.ptp(t), 1e-6))[..., None]
    return (1 - t) * c[0] + t * c[1]


_GENERATORS = (_checker, _stripes, _smooth_noise, _blobs, _gradient)


@functools.lru_cache(maxsize=512)
def _texture(seed: int, split: str, index: int, height: int, width: int) -> np.ndarray:
    rng = _rng(seed, split, index, stream=0)
    generator = _GENERATORS[int(rng.integers(len(_GENERATORS)))]
    img = generator(rng, height, width)
    img = np.clip(img * 255.0, 0, 255).astype(np.uint8)
    img.setflags(write=False)
    return img


class TextureBank:
    """A finite, seeded bank of procedural RGB textures for one split.

    Args:
        split: ``"train"`` or ``"heldout"``; the two splits never share an item.
        size: number of distinct textures in the bank.
        seed: bank seed; the same ``(seed, split, index)`` always gives the same texture.

    Examples:
        >>> bank = TextureBank("train", size=8, seed=0)
        >>> bank.texture(3, height=32, width=32).shape
        (32, 32, 3)
        >>> heldout = TextureBank("heldout", size=8, seed=0)
        >>> bool((bank.texture(0, 32, 32) != heldout.texture(0, 32, 32)).any())
        True
    """

    def __init__(self, split: str, size: int = 64, seed: int = 0):
        self.split = check_split(split)
        if size < 1:
            raise ValueError(f"TextureBank size must be >= 1, got {size}")
        self.size = int(size)
        self.seed = int(seed)

    def texture(self, index: int, height: int, width: int) -> np.ndarray:
        """Returns texture ``index`` (uint8, ``(height, width, 3)``, read-only)."""
        if not 0 <= index < self.size:
            raise IndexError(f"texture index {index} outside bank of size {self.size}")
        return _texture(self.seed, self.split, int(index), int(height), int(width))

    def sample(self, rng: np.random.Generator, height: int, width: int) -> np.ndarray:
        """Returns a texture drawn uniformly from the bank with ``rng``."""
        return self.texture(int(rng.integers(self.size)), height, width)


class ColourBank:
    """A finite, seeded palette of RGB colours for one split.

    Args:
        split: ``"train"`` or ``"heldout"``.
        size: number of colours.
        seed: bank seed.

    Examples:
        >>> ColourBank("train", size=16, seed=0).colours.shape
        (16, 3)
    """

    def __init__(self, split: str, size: int = 64, seed: int = 0):
        self.split = check_split(split)
        if size < 1:
            raise ValueError(f"ColourBank size must be >= 1, got {size}")
        self.colours = _rng(seed, split, 0, stream=1).uniform(0.05, 0.95, size=(size, 3))
        self.colours.setflags(write=False)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Returns ``n`` colours drawn with replacement, shape ``(n, 3)``."""
        return self.colours[rng.integers(len(self.colours), size=n)]
