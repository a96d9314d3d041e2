"""MP4 writing: a real, decodable H.264 file, written atomically; bad frames refused."""

import subprocess

import imageio_ffmpeg
import numpy as np
import pytest

from simdist.viz import write_mp4


def test_write_mp4_encodes_every_frame(tmp_path):
    frames = np.zeros((7, 48, 64, 3), dtype=np.uint8)
    frames[:, :, :32, 0] = 255  # left half red
    path = write_mp4(frames, tmp_path / "clip.mp4", fps=10)
    assert path.read_bytes()[4:8] == b"ftyp"  # an MP4 container
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]  # no temp file left
    count, _ = imageio_ffmpeg.count_frames_and_secs(str(path))
    assert count == 7
    # decode the first frame with the same ffmpeg (imageio_ffmpeg.read_frames leaks pipes)
    raw = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path),
                          "-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                         capture_output=True, check=True).stdout
    first = np.frombuffer(raw, np.uint8).reshape(48, 64, 3)
    assert first[:, :20, 0].mean() > 200 and first[:, 44:, 0].mean() < 50


@pytest.mark.parametrize("frames", [np.zeros((3, 8, 8), np.uint8), np.zeros((3, 8, 8, 3)),
                                    np.zeros((0, 8, 8, 3), np.uint8),
                                    np.zeros((2, 9, 8, 3), np.uint8)])
def test_write_mp4_refuses_bad_frames_before_writing(tmp_path, frames):
    with pytest.raises(ValueError, match="frame"):
        write_mp4(frames, tmp_path / "bad.mp4")
    assert not list(tmp_path.iterdir())
