"""JPEG coding of camera frames, shared by the caller, the served node and the in-process runner.

AIDO sends every camera frame as a JPEG, so a remote agent never sees the rendered pixels, only their
decoded JPEG. For results to be comparable, in-process agents must see the same pixels: the runner passes
frames through :func:`roundtrip`, and a remote agent receives exactly the bytes that roundtrip decoded.

Codec: simplejpeg (libjpeg-turbo bundled in its manylinux wheels); measured fastest of Pillow, simplejpeg
and PyTurboJPEG (which needs a system libturbojpeg), see ``benchmarks/bench_protocol.py --codecs``.
Decoding uses the accurate DCT and "fancy" upsampling, libjpeg's defaults, so Pillow or OpenCV in a foreign
node decode the same bytes to the same pixels (checked in the tests).

Default quality 75 with 4:2:0 chroma subsampling: Pillow's default and what the AIDO simulator sent
(~11 KB per 640×480 frame there; proxybench's textured frames are ~16 KB at 640×480, ~2.6 KB at 160×120).
"""

from __future__ import annotations

from collections import deque

import numpy as np
import simplejpeg

__all__ = ["DEFAULT_QUALITY", "SUBSAMPLING", "decode", "decode_received", "encode", "jpeg_of", "roundtrip"]

DEFAULT_QUALITY = 75
SUBSAMPLING = "420"
# (decoded array, its JPEG) of the latest round trips, so a remote agent can be sent the very bytes an
# in-process agent's pixels came from instead of a second, lossier encoding of already-decoded pixels
_RECENT: deque[tuple[np.ndarray, bytes]] = deque(maxlen=8)


def encode(rgb: np.ndarray, quality: int = DEFAULT_QUALITY) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 RGB image."""
    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) RGB image, got shape {img.shape}")
    return simplejpeg.encode_jpeg(img, quality=int(quality), colorspace="RGB", colorsubsampling=SUBSAMPLING)


def decode(data: bytes) -> np.ndarray:
    """(H, W, 3) uint8 RGB pixels of a JPEG, decoded as libjpeg's defaults (and Pillow) do."""
    return simplejpeg.decode_jpeg(data, colorspace="RGB", fastdct=False, fastupsample=False)


def roundtrip(rgb: np.ndarray, quality: int = DEFAULT_QUALITY) -> np.ndarray:
    """The pixels an AIDO agent would see for ``rgb``: ``decode(encode(rgb))``, returned read-only.

    Read-only so that the array stays equal to its JPEG, which :func:`jpeg_of` hands out.
    """
    data = encode(rgb, quality)
    out = decode(data)
    out.flags.writeable = False
    _RECENT.append((out, data))
    return out


def decode_received(data: bytes) -> np.ndarray:
    """A received frame's pixels (e.g. from a robot node), read-only and remembered like :func:`roundtrip`'s,
    so that a remote agent is then sent these very bytes rather than a second encoding."""
    out = decode(data)
    out.flags.writeable = False
    _RECENT.append((out, bytes(data)))
    return out


def jpeg_of(image: np.ndarray) -> bytes | None:
    """The JPEG that a recent :func:`roundtrip` decoded into this very array object, if any."""
    for arr, data in reversed(_RECENT):
        if arr is image:
            return data
    return None
