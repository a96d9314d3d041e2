"""MP4 files from rendered frames (evaluation videos).

TorchRL's ``VideoRecorder`` + ``CSVLogger(video_format="mp4")`` encodes with torchcodec,
which needs the system's FFmpeg shared libraries (absent on our CPU machines and CI, and
not installable from PyPI). We encode with ``imageio-ffmpeg`` instead (a core
dependency): its wheel ships an ``ffmpeg`` executable, so ``pip install`` is the whole set-up.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from simdist.utils.atomic import atomic_path

INSTALL_HINT = ("writing MP4 videos needs imageio-ffmpeg (it ships an ffmpeg binary): "
                "pip install 'imageio-ffmpeg>=0.5' (a dependency of simdist-rl that this "
                "environment lacks)")


def video_backend_available() -> bool:
    """Whether :func:`write_mp4` can encode here (``imageio_ffmpeg`` importable).

    Examples:
        >>> isinstance(video_backend_available(), bool)
        True
    """
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def write_mp4(frames, path: str | os.PathLike, fps: float = 30.0) -> Path:
    """Encodes ``frames`` (uint8 ``[T, H, W, 3]``, array or tensor) as an H.264 MP4,
    written atomically (a reader never sees half a video); returns ``path``.

    ``H`` and ``W`` must be even (yuv420p); 16-multiples (e.g. 256) avoid ffmpeg padding.

    Raises:
        ModuleNotFoundError: no encoder installed (the message says what to install).
        ValueError: frames of the wrong shape or type.

    Examples:
        >>> import tempfile
        >>> frames = np.zeros((5, 32, 32, 3), dtype=np.uint8)
        >>> path = write_mp4(frames, Path(tempfile.mkdtemp()) / "clip.mp4", fps=10)
        >>> path.stat().st_size > 0
        True
    """
    frames = frames.cpu().numpy() if isinstance(frames, torch.Tensor) else np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or not len(frames):
        raise ValueError(f"frames must be uint8 [T, H, W, 3] with T >= 1, got "
                         f"{frames.dtype} {frames.shape}")
    height, width = frames.shape[1:3]
    if height % 2 or width % 2:
        raise ValueError(f"frame height and width must be even for H.264, got {height}x{width}")
    try:
        import imageio_ffmpeg
    except ImportError as err:
        raise ModuleNotFoundError(INSTALL_HINT) from err
    path = Path(path)
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(str(tmp), (width, height), fps=fps,
                                             codec="libx264", macro_block_size=2,
                                             ffmpeg_log_level="error")
        writer.send(None)  # start the encoder
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
        writer.close()
    return path
