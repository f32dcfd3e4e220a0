"""Mp4Writer: H.264 files with the frames written, atomic appearance, clear errors."""

from __future__ import annotations

import cv2
import imageio_ffmpeg
import numpy as np
import pytest

from navformer_rl.utils.mp4 import Mp4Writer, video_codec


def _frames(count: int, height: int, width: int) -> list[np.ndarray]:
    frames = []
    for i in range(count):
        frame = np.full((height, width, 3), 255, dtype=np.uint8)
        frame[10:40, 10 + 3 * i : 40 + 3 * i] = (200, 30, 30)  # a red square moving right
        frames.append(frame)
    return frames


def _ffmpeg(video: Mp4Writer):
    """The ffmpeg process behind a started writer (``write_frames``' ``Popen``, read from its frame)."""
    return video._encoder.gi_frame.f_locals["p"]


def _decode(path) -> tuple[dict, list[np.ndarray]]:
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    frames = [np.frombuffer(raw, np.uint8).reshape(height, width, 3) for raw in reader]
    return meta, frames


def test_writes_h264_with_every_frame_and_odd_sides_padded(tmp_path):
    path = tmp_path / "clip.mp4"
    written = _frames(12, 101, 151)
    with Mp4Writer(path, fps=10, threads=1) as video:
        for frame in written:
            video.write(frame)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]  # no temporary file left
    meta, frames = _decode(path)
    assert meta["codec"] == "h264" and meta["fps"] == 10.0
    assert meta["size"] == (152, 102)  # padded to even sides
    assert len(frames) == 12
    for got, want in zip(frames, written):
        # lossy, but the square is where it was drawn and the padding is white
        assert np.abs(got[:101, :151].astype(int) - want).mean() < 4
        assert got[101:, :].min() > 200 and got[:, 151:].min() > 200
    # OpenCV (what most users read videos with) decodes it too
    capture = cv2.VideoCapture(str(path))
    assert capture.read()[0]


def test_nothing_appears_on_error_and_an_existing_file_is_kept(tmp_path):
    path = tmp_path / "clip.mp4"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="boom"):
        with Mp4Writer(path, fps=5) as video:
            video.write(_frames(1, 20, 20)[0])
            raise RuntimeError("boom")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]


def test_bad_input_is_named(tmp_path):
    with pytest.raises(ValueError, match="fps=0"):
        Mp4Writer(tmp_path / "a.mp4", fps=0)
    with pytest.raises(ValueError, match="ending in .mp4"):
        Mp4Writer(tmp_path / "a.avi", fps=5)
    video = Mp4Writer(tmp_path / "b.mp4", fps=5)
    with pytest.raises(ValueError, match="uint8 RGB frame"):
        video.write(np.zeros((20, 20), dtype=np.uint8))
    video.write(np.zeros((20, 20, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="20x20 px"):
        video.write(np.zeros((22, 20, 3), dtype=np.uint8))
    video.abort()
    assert not (tmp_path / "b.mp4").exists()
    empty = Mp4Writer(tmp_path / "c.mp4", fps=5)
    with pytest.raises(ValueError, match="no frames"):
        empty.close()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("when", ["write", "close"])
def test_a_failed_encoder_leaves_no_file(tmp_path, when):
    path = tmp_path / "clip.mp4"
    video = Mp4Writer(path, fps=5, threads=1)
    frames = _frames(3, 40, 60)
    video.write(frames[0])
    _ffmpeg(video).kill()  # ffmpeg dies (disk full, OOM killer, ...)
    _ffmpeg(video).wait()
    with pytest.raises(OSError, match="ffmpeg"):
        if when == "write":
            for _ in range(200):  # until the pipe's buffer is full and the broken pipe shows
                video.write(frames[1])
        else:
            video.close()
    assert list(tmp_path.iterdir()) == []


def test_video_codec_reads_the_stream(tmp_path):
    path = tmp_path / "clip.mp4"
    with Mp4Writer(path, fps=5) as video:
        video.write(_frames(1, 20, 20)[0])
    assert video_codec(path) == "h264"


def test_a_dropped_writer_stops_its_encoder_and_leaves_no_file(tmp_path):
    import gc

    video = Mp4Writer(tmp_path / "clip.mp4", fps=5, threads=1)
    video.write(_frames(1, 20, 20)[0])
    process = _ffmpeg(video)
    del video
    gc.collect()
    assert process.wait(timeout=30) < 0  # killed, not left to finish its file (it would write later)
    assert list(tmp_path.iterdir()) == []


def test_a_missing_encoder_is_a_named_error(tmp_path, monkeypatch):
    import imageio_ffmpeg

    from navformer_rl.utils.mp4 import VideoEncoderError

    def missing():
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", missing)
    with pytest.raises(VideoEncoderError, match="no ffmpeg binary .* IMAGEIO_FFMPEG_EXE"):
        Mp4Writer(tmp_path / "clip.mp4", fps=5)
    assert list(tmp_path.iterdir()) == []


def test_a_file_without_every_frame_is_refused(tmp_path, monkeypatch):
    """``write_frames`` does not report ffmpeg's exit status: the finished file's frames are counted."""
    from navformer_rl.utils.mp4 import VideoEncoderError

    monkeypatch.setattr(imageio_ffmpeg, "count_frames_and_secs", lambda path: (2, 0.4))
    video = Mp4Writer(tmp_path / "clip.mp4", fps=5, threads=1)
    for frame in _frames(3, 20, 20):
        video.write(frame)
    with pytest.raises(VideoEncoderError, match="2 of the 3 frames"):
        video.close()
    assert list(tmp_path.iterdir()) == []
