"""Videos (mks_sim.report.write_video): MP4 through imageio-ffmpeg, GIF only for ``.gif``."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest

from mks_sim.errors import DataError, MksError
from mks_sim.report import write_video


def _frames(n: int = 6) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(n)]


def test_mp4_is_an_mp4(tmp_path) -> None:
    path = write_video(_frames(), tmp_path / "ep.mp4", fps=10)
    assert path == tmp_path / "ep.mp4"
    assert path.read_bytes()[4:8] == b"ftyp"  # ISO base media file, not a renamed GIF
    back = iio.imread(path, index=None)
    assert back.shape[0] == 6 and back.shape[1:] == (48, 64, 3)


def test_gif_only_when_asked(tmp_path) -> None:
    path = write_video(_frames(3), tmp_path / "ep.gif")
    assert path.read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_without_ffmpeg_mp4_is_an_error(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr("mks_sim.report.has_ffmpeg", lambda: False)
    with pytest.raises(MksError, match=r"MP4 needs imageio-ffmpeg.*pip install"):
        write_video(_frames(2), tmp_path / "ep.mp4")
    assert not (tmp_path / "ep.gif").exists()  # no silent GIF beside it


def test_bad_frames(tmp_path) -> None:
    with pytest.raises(DataError, match="expected at least one frame"):
        write_video([], tmp_path / "x.mp4")
