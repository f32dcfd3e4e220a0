"""H.264 mp4 writing that browsers play: frames are piped to the ffmpeg binary shipped by ``imageio-ffmpeg``.

OpenCV's pip wheels carry no H.264 encoder (only MPEG-4 Part 2, ``mp4v``, which browsers and most notebook
viewers refuse), so the evaluation videos and the world demo write through ``imageio_ffmpeg.write_frames``
with ``libx264``, ``yuv420p`` and the index at the front of the file (``+faststart``): the files play in
browsers, VS Code, Jupyter, VLC and QuickTime.
"""

from __future__ import annotations

import os
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from navformer_rl.durable import atomic_path

CRF = 23
"""libx264's constant rate factor (lower = better quality, larger files; 23 is x264's default)."""
PRESET = "veryfast"
"""libx264's speed preset: the frames are flat drawings, so a fast preset loses little."""


class Mp4Writer:
    """Streams uint8 RGB frames ``[H, W, 3]`` into an H.264 mp4; the file appears atomically on :meth:`close`.

    Frames with an odd height or width are padded by one white row or column (``yuv420p`` needs even
    sides). Every frame must have the first frame's size. Usable as a context manager: leaving the block
    with an exception calls :meth:`abort`, otherwise :meth:`close`.

    Args:
        path: output ``.mp4``; its folder is created.
        fps: frames per second (> 0).
        threads: encoder threads (0 = as many as ffmpeg chooses); give 1 when several processes encode.
    """

    def __init__(self, path: str | os.PathLike, fps: float, threads: int = 0) -> None:
        if not (isinstance(fps, int | float) and np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps={fps!r}: expected a number of frames per second > 0")
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise ValueError(f"{self.path}: expected a file name ending in .mp4")
        self.fps = float(fps)
        self.threads = int(threads)
        self._context = atomic_path(self.path)  # the temporary file keeps the .mp4 suffix ffmpeg reads
        self._tmp = self._context.__enter__()
        self._encoder = None
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
            self._encoder = self._start_encoder()
        elif frame.shape[:2] != self._size:
            raise ValueError(
                f"{self.path}: frame {self.frames} is {frame.shape[1]}x{frame.shape[0]} px, "
                f"the video's first frame {self._size[1]}x{self._size[0]} px"
            )
        self._encoder.send(np.ascontiguousarray(_pad_to_even(frame)))
        self.frames += 1

    def close(self) -> Path:
        """Finish the file and move it into place (ValueError if no frame was written)."""
        if self._finished:
            return self.path
        if self.frames == 0:
            self.abort()
            raise ValueError(f"no frames were written to {self.path}")
        try:
            self._encoder.close()
        except BaseException as error:
            self._encoder = None
            self._finished = True
            self._context.__exit__(type(error), error, None)
            raise
        self._encoder = None
        self._finished = True
        self._context.__exit__(None, None, None)
        return self.path

    def abort(self) -> None:
        """Stop the encoder and drop the partial file; ``path`` is left untouched (no-op once finished)."""
        if self._finished:
            return
        self._finished = True
        if self._encoder is not None:
            try:
                self._encoder.close()
            except Exception:  # the partial file is deleted either way
                pass
            self._encoder = None
        self._context.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def _start_encoder(self):
        height, width = self._size
        encoder = imageio_ffmpeg.write_frames(
            str(self._tmp),
            (width + width % 2, height + height % 2),
            fps=self.fps,
            codec="libx264",
            pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p",
            quality=None,
            macro_block_size=1,
            ffmpeg_log_level="error",
            output_params=[
                *("-crf", str(CRF), "-preset", PRESET, "-threads", str(self.threads)),
                *("-movflags", "+faststart"),
            ],
        )
        encoder.send(None)  # starts ffmpeg
        return encoder


def _pad_to_even(frame: np.ndarray) -> np.ndarray:
    """Pad an odd height or width with one white row / column (``yuv420p`` needs even sides)."""
    height, width = frame.shape[:2]
    if height % 2 == 0 and width % 2 == 0:
        return frame
    return np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)), constant_values=255)
