"""H.264 mp4 writing that browsers play, through ``imageio-ffmpeg``'s ``write_frames`` (its ffmpeg binary).

OpenCV's pip wheels carry no H.264 encoder (only MPEG-4 Part 2, ``mp4v``, which browsers and most notebook
viewers refuse), so the evaluation videos and the world demo send raw RGB frames to ffmpeg with ``libx264``,
``yuv420p``, even sides (odd ones padded white rather than rescaled) and the index at the front of the file
(``+faststart``): the files play in browsers, VS Code, Jupyter, VLC and QuickTime. What this module adds to
``write_frames``: a file is moved into place only once ffmpeg has finished it and it holds every frame
written (``write_frames`` does not report ffmpeg's exit status), so a crashed or killed encoder never
leaves a broken video behind.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Generator
from pathlib import Path
from types import ModuleType

import numpy as np

from navformer_rl.utils.durable import atomic_path

CRF = 23
"""libx264's constant rate factor (lower = better quality, larger files; 23 is x264's default)."""
PRESET = "veryfast"
"""libx264's speed preset: the frames are flat drawings, so a fast preset loses little."""


class VideoEncoderError(OSError):
    """The ffmpeg encoder is missing, or failed while writing a video."""


class _Abort(BaseException):
    """Thrown into ``write_frames`` to make it kill ffmpeg (a ``BaseException``: it does not wait)."""


def _imageio_ffmpeg() -> ModuleType:
    """The ``imageio_ffmpeg`` module, imported on first use so that training and collection run where it is
    not installed (a GPU machine); :class:`VideoEncoderError` naming the fix when it is missing."""
    try:
        import imageio_ffmpeg
    except ImportError as error:
        raise VideoEncoderError(
            f"no ffmpeg binary for the mp4 videos ({error}); reinstall imageio-ffmpeg for this platform"
        ) from None
    return imageio_ffmpeg


def ffmpeg_executable() -> str:
    """Path of the ffmpeg binary of ``imageio-ffmpeg`` (:class:`VideoEncoderError` naming the fix when it is
    missing)."""
    imageio_ffmpeg = _imageio_ffmpeg()
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as error:
        raise VideoEncoderError(
            f"no ffmpeg binary for the mp4 videos ({error}); reinstall imageio-ffmpeg for this platform, or "
            "set IMAGEIO_FFMPEG_EXE to an ffmpeg with libx264"
        ) from None


def video_codec(path: str | os.PathLike) -> str:
    """The codec of the video stream of ``path`` (``"h264"``, ``"mpeg4"`` for OpenCV's ``mp4v``, ...)."""
    reader = _imageio_ffmpeg().read_frames(str(path))
    try:
        return str(next(reader)["codec"])
    finally:
        reader.close()


class Mp4Writer:
    """Streams uint8 RGB frames ``[H, W, 3]`` into an H.264 mp4; the file appears atomically on :meth:`close`.

    Frames with an odd height or width are padded by one white row or column (``yuv420p`` needs even
    sides). Every frame must have the first frame's size. Usable as a context manager: leaving the block
    with an exception calls :meth:`abort`, otherwise :meth:`close`.

    Args:
        path: output ``.mp4``; its folder is created.
        fps: frames per second (> 0).
        threads: encoder threads (0 = as many as ffmpeg chooses); give 1 when several processes encode.

    Raises:
        VideoEncoderError: from :meth:`write` or :meth:`close` when ffmpeg fails (it prints its message on
            stderr); the partial file is deleted and ``path`` left untouched. A writer dropped without
            ``close`` or ``abort`` has its encoder killed when it is garbage-collected.
    """

    def __init__(self, path: str | os.PathLike, fps: float, threads: int = 0) -> None:
        if not (isinstance(fps, int | float) and np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps={fps!r}: expected a number of frames per second > 0")
        if not (isinstance(threads, int) and threads >= 0):
            raise ValueError(f"threads={threads!r}: expected an integer >= 0 (0: ffmpeg chooses)")
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise ValueError(f"{self.path}: expected a file name ending in .mp4")
        self.fps = float(fps)
        self.threads = int(threads)
        ffmpeg_executable()  # a missing encoder is named now, not at the first frame
        self._context = atomic_path(self.path)  # the temporary file keeps the .mp4 suffix ffmpeg reads
        self._tmp = self._context.__enter__()
        self._encoder: Generator[None, object, None] | None = None  # write_frames, started at the first frame
        self._finalizer: weakref.finalize | None = None
        self._finished = False
        self._size: tuple[int, int] | None = None  # (height, width) of the incoming frames
        self.frames = 0

    def __enter__(self) -> Mp4Writer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write(self, frame: np.ndarray) -> None:
        """Append one uint8 RGB frame ``[H, W, 3]``."""
        if self._finished:
            raise ValueError(f"{self.path}: the video is already closed")
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(
                f"{self.path}: expected a uint8 RGB frame [H, W, 3], got {frame.dtype} {tuple(frame.shape)}"
            )
        if self._size is None:
            self._size = frame.shape[:2]
            self._start_encoder()
        elif frame.shape[:2] != self._size:
            raise ValueError(
                f"{self.path}: frame {self.frames} is {frame.shape[1]}x{frame.shape[0]} px, "
                f"the video's first frame {self._size[1]}x{self._size[0]} px"
            )
        try:
            self._encoder.send(np.ascontiguousarray(_pad_to_even(frame)).data)  # no copy to bytes
        except (OSError, StopIteration):  # write_frames reports a broken pipe as an IOError
            self._fail(f"ffmpeg stopped after {self.frames} frames")
        self.frames += 1

    def close(self) -> Path:
        """Finish the file and move it into place (ValueError if no frame was written)."""
        if self._finished:
            return self.path
        if self.frames == 0:
            self.abort()
            raise ValueError(f"no frames were written to {self.path}")
        try:
            try:
                self._encoder.close()  # ffmpeg finishes the file
            except OSError:
                self._fail("ffmpeg failed while finishing the file")
            self._check_finished_file()
        except BaseException:  # Ctrl-C while ffmpeg finishes, a vanished file, ...
            self.abort()
            raise
        self._finished = True
        self._finalizer.detach()
        self._context.__exit__(None, None, None)
        return self.path

    def abort(self) -> None:
        """Stop the encoder and drop the partial file; ``path`` is left untouched (no-op once finished)."""
        if self._finished:
            return
        self._finished = True
        if self._finalizer is not None:
            self._finalizer()  # kills ffmpeg
        self._context.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def _fail(self, what: str) -> None:
        """Abort and raise :class:`VideoEncoderError`."""
        self.abort()
        raise VideoEncoderError(f"{self.path}: {what} (its message, if any, is on stderr)")

    def _check_finished_file(self) -> None:
        """:class:`VideoEncoderError` unless ffmpeg left a readable file with every frame written."""
        if not self._tmp.is_file() or self._tmp.stat().st_size == 0:
            self._fail("ffmpeg wrote no file")
        try:
            frames, _ = _imageio_ffmpeg().count_frames_and_secs(str(self._tmp))
        except (RuntimeError, OSError) as error:
            self._fail(f"ffmpeg wrote an unreadable file ({error})")
        if frames != self.frames:
            self._fail(f"ffmpeg wrote {frames} of the {self.frames} frames")

    def _start_encoder(self) -> None:
        height, width = self._size
        self._encoder = _imageio_ffmpeg().write_frames(
            str(self._tmp),
            (width + width % 2, height + height % 2),  # _pad_to_even
            fps=self.fps,
            codec="libx264",
            quality=None,  # the rate factor below
            macro_block_size=1,  # even sides are enough for yuv420p; no rescaling
            ffmpeg_log_level="error",
            output_params=[
                *("-crf", str(CRF), "-preset", PRESET, "-threads", str(self.threads)),
                *("-movflags", "+faststart"),
            ],
        )
        try:
            self._encoder.send(None)  # starts ffmpeg
        except OSError as error:
            self._encoder = None
            self.abort()
            raise VideoEncoderError(f"{self.path}: cannot start ffmpeg ({error})") from None
        self._finalizer = weakref.finalize(self, _stop_encoder, self._encoder)


def _stop_encoder(encoder: Generator[None, object, None]) -> None:
    """Kill an unfinished ffmpeg (so it never writes its file later): ``write_frames`` kills it on a
    ``BaseException`` that is not an ``Exception``."""
    try:
        encoder.throw(_Abort())
    except (_Abort, StopIteration, OSError):
        pass


def _pad_to_even(frame: np.ndarray) -> np.ndarray:
    """Pad an odd height or width with one white row / column (``yuv420p`` needs even sides)."""
    height, width = frame.shape[:2]
    if height % 2 == 0 and width % 2 == 0:
        return frame
    return np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)), constant_values=255)


def read_mp4_frames(path: str | os.PathLike) -> tuple[float, list[np.ndarray]]:
    """``(fps, frames)`` of a video: every frame as uint8 RGB ``[H, W, 3]`` (decoded by the ffmpeg binary of
    ``imageio-ffmpeg``). FileNotFoundError when ``path`` is missing; ValueError when ffmpeg cannot read it."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no video at {str(path)!r}")
    imageio_ffmpeg = _imageio_ffmpeg()
    try:
        reader = imageio_ffmpeg.read_frames(str(path))
        meta = next(reader)
        width, height = meta["size"]
        frames = [np.frombuffer(raw, np.uint8).reshape(height, width, 3).copy() for raw in reader]
    except (RuntimeError, OSError, StopIteration) as error:
        raise ValueError(f"{path} is not a readable video ({type(error).__name__}: {error})") from None
    return float(meta["fps"]), frames
