"""Writing what people would rather look at than read: videos and PNG strips of episodes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

__all__ = ["VideoWriter", "side_by_side", "write_strip"]


def side_by_side(*images: np.ndarray, height: int | None = None) -> np.ndarray:
    """Images scaled to one height and placed left to right (uint8 RGB)."""
    height = height or max(im.shape[0] for im in images)
    parts = []
    for im in images:
        if im.shape[0] != height:
            w = round(im.shape[1] * height / im.shape[0])
            im = np.asarray(Image.fromarray(im).resize((w, height), Image.Resampling.BILINEAR))
        parts.append(im)
    return np.concatenate(parts, axis=1)


def write_strip(frames: list[np.ndarray], path: str | Path, labels: list[str] | None = None,
                columns: int = 6, width: int = 320) -> Path:
    """A PNG contact sheet of ``frames`` (scaled to ``width`` px) in rows of ``columns``, optionally captioned."""
    from PIL import ImageDraw

    if not frames:
        raise ValueError("write_strip needs at least one frame")
    frames = [side_by_side(f, height=round(f.shape[0] * width / f.shape[1])) for f in frames]
    h, w = frames[0].shape[:2]
    rows = (len(frames) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * w, rows * h), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for k, f in enumerate(frames):
        x, y = (k % columns) * w, (k // columns) * h
        sheet.paste(Image.fromarray(f), (x, y))
        if labels:
            draw.rectangle((x, y, x + 8 * len(labels[k]) + 6, y + 14), fill=(0, 0, 0))
            draw.text((x + 3, y + 1), labels[k], fill=(255, 255, 255))
    path = Path(path)
    sheet.save(path)
    return path


class VideoWriter:
    """MP4 (H.264 via imageio-ffmpeg) writer; frames are RGB uint8 of one size."""

    def __init__(self, path: str | Path, fps: float):
        import imageio.v2 as imageio

        self.path = Path(path)
        self._w = imageio.get_writer(self.path, fps=fps, codec="libx264", quality=5, macro_block_size=8,
                                     ffmpeg_log_level="error")

    def append(self, frame: np.ndarray) -> None:
        """Add a frame, padded with black to a multiple of 8 pixels (the codec's blocks): imageio would resize it
        and warn on stderr, in the middle of a command's progress lines."""
        h, w = frame.shape[:2]
        pad = ((0, -h % 8), (0, -w % 8)) + ((0, 0),) * (frame.ndim - 2)
        if pad[0][1] or pad[1][1]:
            frame = np.pad(frame, pad)
        self._w.append_data(np.ascontiguousarray(frame))

    def close(self) -> None:
        self._w.close()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
