"""Writing frames: H.264 mp4 (imageio-ffmpeg, yuv420p), GIF (imageio) or a directory of PNG frames.

Every file is written to a temporary name in its target directory and moved into place with ``os.replace``, so a
failed or interrupted run never leaves a half-written output under the final name. Frames are (H, W, 3) uint8 RGB;
mp4 frames are cropped to even sizes.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from torchhand.errors import InputValueError

from .backend import RenderBackendError
from .overlay import even_size

__all__ = ["FORMATS", "infer_format", "check_writer", "FrameWriter", "publish"]

FORMATS = ("mp4", "gif", "png")


def publish(tmp: str | os.PathLike, target: str | os.PathLike) -> None:
    """Move the finished temporary file ``tmp`` onto ``target`` atomically, with the usual permissions
    (``0o666`` less the umask; temporary files are created private)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    os.replace(tmp, target)


def infer_format(out: str | os.PathLike, fmt: str | None) -> str:
    """The output format: ``fmt`` if given, else from ``out``'s suffix (.mp4, .gif; anything else = PNG frames)."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise InputValueError(f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
        return fmt
    suffix = Path(out).suffix.lower()
    return {".mp4": "mp4", ".gif": "gif"}.get(suffix, "png")


def ffmpeg_exe() -> str:
    """Path of the ffmpeg executable imageio-ffmpeg uses; :class:`RenderBackendError` if there is none."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise RenderBackendError("writing mp4 needs ffmpeg: pip install imageio-ffmpeg "
                                 "(or use --format gif / png)") from None
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except (RuntimeError, OSError) as err:
        raise RenderBackendError(f"writing mp4 needs ffmpeg, which was not found ({err}): pip install "
                                 f"imageio-ffmpeg or apt-get install ffmpeg (or use --format gif / png)") from None


def check_writer(fmt: str) -> None:
    """Fail early, before any rendering, if ``fmt`` cannot be written here."""
    if fmt == "mp4":
        ffmpeg_exe()
    elif fmt == "gif":
        try:
            import imageio  # noqa: F401
            import PIL  # noqa: F401
        except ImportError as err:
            raise RenderBackendError(f"writing GIF needs imageio and Pillow: pip install imageio pillow ({err})") \
                from None


def _one_image(out: Path, frames: int) -> str:
    return (f"--out {out}: a .png name holds one image, but {frames if frames > 1 else 'no'} frame(s) are drawn: "
            f"choose one with --frames A:A+1, or give a directory for PNG frames")


class FrameWriter:
    """Streams frames to ``out`` in ``fmt`` at ``fps``; use as a context manager (the file appears on exit)."""

    def __init__(self, out: str | os.PathLike, fmt: str, fps: float, *, quality: int = 8, frames: int | None = None):
        """frames: how many frames will be written, when known: with PNG output to a name ending in ``.png`` (one
        image, not a directory of frames) more than one is refused here, before any rendering."""
        self.out = Path(out)
        self.fmt = fmt
        self.fps = float(fps)
        self.quality = quality
        self.count = 0
        self._tmp: Path | None = None
        self._writer = None
        self._gif: list = []
        self.single = fmt == "png" and self.out.suffix.lower() == ".png" and not self.out.is_dir()
        if self.single:                                 # one image: --out still.png with one frame
            if frames is not None and frames != 1:
                raise InputValueError(_one_image(self.out, frames))
            self.out.parent.mkdir(parents=True, exist_ok=True)
        elif fmt == "png":
            if self.out.exists() and not self.out.is_dir():
                raise InputValueError(f"--out {self.out}: PNG frames go into a directory, but this is a file")
            self.out.mkdir(parents=True, exist_ok=True)
        else:
            parent = self.out.parent
            if not parent.exists():
                parent.mkdir(parents=True, exist_ok=True)
            if self.out.is_dir():
                raise InputValueError(f"--out {self.out}: is a directory; give a file name ending in .{fmt}")
            fd, name = tempfile.mkstemp(prefix=f".{self.out.name}.", suffix=f".{fmt}", dir=parent)
            os.close(fd)
            self._tmp = Path(name)

    def __enter__(self) -> "FrameWriter":
        return self

    def write(self, frame: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 frame."""
        if self.fmt == "png":
            import imageio.v3 as iio

            if self.single and self.count:
                raise InputValueError(_one_image(self.out, self.count + 1))
            target = self.out if self.single else self.out / f"frame_{self.count:05d}.png"
            tmp = target.with_name(f".{target.name}.tmp.png")
            iio.imwrite(tmp, frame)
            publish(tmp, target)
        elif self.fmt == "gif":
            self._gif.append(frame)
        else:
            frame = even_size(frame)
            if self._writer is None:
                import imageio.v2 as iio2

                ffmpeg_exe()
                self._writer = iio2.get_writer(str(self._tmp), format="FFMPEG", mode="I", fps=self.fps,
                                               codec="libx264", pixelformat="yuv420p", quality=self.quality,
                                               macro_block_size=2, ffmpeg_log_level="error")
            self._writer.append_data(frame)
        self.count += 1

    def close(self, ok: bool = True) -> None:
        try:
            if self.fmt == "mp4" and self._writer is not None:
                self._writer.close()
                self._writer = None
            elif self.fmt == "gif" and ok and self._gif:
                import imageio.v3 as iio

                iio.imwrite(self._tmp, np.stack(self._gif), extension=".gif", duration=1000.0 / self.fps, loop=0)
            if ok and self._tmp is not None:
                if self.count == 0:
                    raise InputValueError(f"--out {self.out}: no frames to write")
                publish(self._tmp, self.out)
                self._tmp = None
        finally:
            if self._tmp is not None and self._tmp.exists():
                self._tmp.unlink()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)
