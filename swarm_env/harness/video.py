"""Writing rendered frames to video files and pictures.

``.mp4`` goes through imageio-ffmpeg (H.264 ``libx264``, ``yuv420p`` so that
every player opens it); ``.gif`` through imageio's pillow plugin. imageio is
imported lazily, so ``import swarm_env`` does not need it.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from swarm_env.outputs import OutputError, check_target, open_atomic, temp_path, write_error

VIDEO_SUFFIXES = (".mp4", ".gif")


def _as_rgb(frame: np.ndarray) -> np.ndarray:
    """Check ``frame`` and return it as ``(H, W, 3)`` uint8 (gray is repeated, alpha dropped)."""
    a = np.asarray(frame)
    if a.dtype != np.uint8:
        raise TypeError(f"frames must be uint8 arrays, got dtype {a.dtype}")
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"frames must have shape (H, W, 3), (H, W, 4) or (H, W), got {a.shape}")
    return a[:, :, :3]


def _pad_even(a: np.ndarray) -> np.ndarray:
    """Pad the bottom/right edge by one replicated pixel where a side is odd (yuv420p needs even sides)."""
    ph, pw = a.shape[0] % 2, a.shape[1] % 2
    if ph or pw:
        a = np.pad(a, ((0, ph), (0, pw), (0, 0)), mode="edge")
    return a


def _check_mp4(path: Path, target: Path) -> None:
    """Raise :class:`~swarm_env.outputs.OutputError` unless ``path`` is a whole MP4 file: its top-level boxes
    tile the file exactly and one of them is ``moov`` (the index ffmpeg writes last). imageio does not report
    ffmpeg's exit status, so a full disk or a killed encoder would otherwise leave a truncated video; this reads
    only the boxes' 8-16-byte headers."""
    size = path.stat().st_size
    seen, pos = set(), 0
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(8)
            if len(head) < 8:
                break
            length, kind = int.from_bytes(head[:4], "big"), head[4:]
            if length == 1:  # a 64-bit size follows the type
                wide = f.read(8)
                length = int.from_bytes(wide, "big") if len(wide) == 8 else 0
            elif length == 0:  # the last box runs to the end of the file
                length = size - pos
            if length < 8:
                break
            seen.add(kind)
            pos += length
    if pos != size or b"moov" not in seen:
        raise OutputError(f"{target}: the video encoder did not finish the file (a full disk, a file-size limit, or "
                          "ffmpeg stopped); nothing was written there")


class VideoWriter:
    """Writes RGB frames to ``path`` (``.mp4`` or ``.gif``) at ``fps`` frames per second.

    Every frame must have the size of the first one. A context manager::

        with VideoWriter("run.mp4", fps=10) as video:
            for ...:
                video.append(env.render())

    ``.mp4`` frames are streamed to ffmpeg as they come (odd sides are padded
    by one pixel); ``.gif`` frames are kept in memory and written by
    :meth:`close`. ``quality`` is imageio-ffmpeg's 0-10 scale (mp4 only).

    The file is encoded under a temporary name in ``path``'s directory and renamed to ``path`` by
    :meth:`close` (:mod:`swarm_env.outputs`): a writer that fails (an exception in the ``with``
    block, or :meth:`abort`) or is killed never leaves a truncated video under ``path``. A symlink
    at ``path`` is refused, an existing file is replaced only with ``overwrite``, and with ``root``
    a path resolving outside that directory is refused (``OutputError``, a ``ValueError``).
    """

    def __init__(self, path: str | os.PathLike[str], fps: float, *, quality: float = 8.0, overwrite: bool = True,
                 root: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in VIDEO_SUFFIXES:
            raise ValueError(f"{self.path}: unsupported video format {suffix!r}; use one of {VIDEO_SUFFIXES}")
        if not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps!r}")
        self._overwrite, self._root = overwrite, root
        check_target(self.path, root=root, overwrite=overwrite)  # refuse before any frame is rendered
        self._tmp: Path | None = None
        self.fps = float(fps)
        self.quality = quality
        self.n_frames = 0
        self._format = suffix[1:]
        self._shape: tuple[int, ...] | None = None
        self._writer: Any = None
        self._gif_frames: list[np.ndarray] = []
        self._closed = False

    def append(self, frame: np.ndarray) -> None:
        """Add one ``(H, W, 3)`` uint8 frame (``(H, W, 4)`` and ``(H, W)`` are accepted too)."""
        if self._closed:
            raise RuntimeError(f"{self.path}: the VideoWriter is closed")
        a = _as_rgb(frame)
        if self._shape is None:
            self._shape = a.shape
        elif a.shape != self._shape:
            raise ValueError(f"{self.path}: frame shape {a.shape} differs from the first frame's {self._shape}")
        if self._format == "gif":
            self._gif_frames.append(a.copy())
        else:
            if self._writer is None:
                import imageio.v2 as iio  # noqa: PLC0415 - lazy: optional dependency

                self._writer = iio.get_writer(
                    self._temp_path(),
                    format="FFMPEG",
                    mode="I",
                    fps=self.fps,
                    codec="libx264",
                    pixelformat="yuv420p",
                    quality=self.quality,
                    macro_block_size=1,  # we pad to even sides ourselves; no rescaling to multiples of 16
                )
            try:
                self._writer.append_data(np.ascontiguousarray(_pad_even(a)))
            except OSError as exc:  # ffmpeg's pipe closed under it (a full disk killed it): one line
                self.abort()
                raise write_error(self.path, exc if exc.strerror else OSError(exc.errno, "the video encoder stopped"),
                                  "nothing was written there") from None
        self.n_frames += 1

    def _temp_path(self) -> Path:
        """The hidden file the encoder writes (same directory and suffix as :attr:`path`)."""
        if self._tmp is None:
            self._tmp = temp_path(self.path)
        return self._tmp

    def close(self) -> None:
        """Finish the file and rename it to :attr:`path` (no file when no frame was appended). Safe to call
        more than once; if finishing fails, the temporary file is removed and nothing is left at :attr:`path`."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._writer is not None:
                self._writer.close()
                self._writer = None
                _check_mp4(self._temp_path(), self.path)
            if self._format == "gif" and self._gif_frames:
                import imageio.v3 as iio3  # noqa: PLC0415

                # pillow's GIF duration is per frame in milliseconds; loop=0 repeats forever.
                # encoded in memory (the frames are there already), then written by us: a failed write is ours to report
                data = iio3.imwrite("<bytes>", np.stack(self._gif_frames), extension=".gif", plugin="pillow",
                                    duration=1000.0 / self.fps, loop=0)
                with open(self._temp_path(), "wb") as f:
                    f.write(data)
                    f.flush()
                    os.fsync(f.fileno())
                self._gif_frames = []
            if self._tmp is not None:
                check_target(self.path, root=self._root, overwrite=self._overwrite)
                os.replace(self._tmp, self.path)
        except OSError as exc:  # pillow or the rename on a full disk
            raise write_error(self.path, exc, "nothing was written there") from None
        finally:
            if self._tmp is not None:
                self._tmp.unlink(missing_ok=True)
                self._tmp = None

    def abort(self) -> None:
        """Stop without writing :attr:`path`: the encoder is stopped and its temporary file removed."""
        if self._closed:
            return
        self._closed = True
        self._gif_frames = []
        try:
            if self._writer is not None:
                self._writer.close()
        except Exception:  # noqa: BLE001 - an encoder failing to stop must not hide the error that aborted it
            pass
        finally:
            self._writer = None
            if self._tmp is not None:
                self._tmp.unlink(missing_ok=True)
                self._tmp = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def save_frame_png(path: str | os.PathLike[str], frame: np.ndarray, *, overwrite: bool = True) -> None:
    """Write one ``(H, W, 3)`` uint8 frame as a PNG file (atomically, :func:`swarm_env.outputs.open_atomic`)."""
    import imageio.v3 as iio3  # noqa: PLC0415


    with open_atomic(path, overwrite=overwrite) as tmp:
        iio3.imwrite(tmp, _as_rgb(frame), extension=".png")
