"""Image sizes read before anything is decoded, and the pixel bound ``sources.max_image_px``.

A 1 MB PNG or JPEG may declare 30000 x 30000 pixels: ``cv2.imdecode`` allocates the declared
size first (2.7 GB for colour) and every per-frame array after it scales with it (~100 bytes a
pixel through the maps, README "Limits"). So the size is read from the header (PNG IHDR, JPEG
SOFn; a raw ``sensor_msgs/Image`` declares width and height) and checked against the bound
before any allocation. An oversized frame is a ``FrameTooLarge`` decode error: the reader skips
that frame with one counted warning, the run goes on.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import Any, cast

import numpy as np

from slzcli.errors import DecodeError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOI = b"\xff\xd8"
# A file's header is read up to here (TUM folders); real JPEG headers (EXIF, ICC) fit well inside.
HEADER_READ_BYTES = 1 << 20


class FrameTooLarge(DecodeError):
    """A frame whose declared size is over ``sources.max_image_px``: skipped, not decoded."""


def compressed_size(data: bytes | memoryview | np.ndarray) -> tuple[int, int, str]:
    """(width, height, 'png' | 'jpeg') from a compressed image's header; DecodeError if there is none.

    Pillow's PNG and JPEG readers parse the header only (~0.1 ms a frame, benchmarks/read.py's frames
    take ~100 ms). Their plugin classes are used directly: ``Image.open`` refuses images over its own
    pixel limit (``DecompressionBombError``) before telling the size, and the bound here is slz's own.
    """
    from PIL import ImageFile, JpegImagePlugin, PngImagePlugin

    view = _bytes_view(data)
    head = bytes(view[:8])
    reader: type[ImageFile.ImageFile]
    if head == PNG_SIGNATURE:
        kind, reader = "png", PngImagePlugin.PngImageFile
    elif head[:2] == JPEG_SOI:
        kind, reader = "jpeg", JpegImagePlugin.JpegImageFile
    else:
        raise DecodeError("not a decodable jpeg/png (no PNG or JPEG signature)")
    try:
        with reader(io.BytesIO(view)) as image:
            width, height = image.size
    except (OSError, SyntaxError, ValueError, struct.error, IndexError) as err:
        raise DecodeError(f"not a decodable jpeg/png ({kind} header: {err})") from None
    if width == 0 or height == 0:  # height 0 = size given later (DNL): libjpeg cannot decode it
        raise DecodeError(f"not a decodable jpeg/png ({kind} header says {width}x{height} px)")
    return width, height, kind


def _bytes_view(data: bytes | memoryview | np.ndarray) -> memoryview:
    """A flat byte view (indexing gives Python ints: numpy uint8 arithmetic would wrap at 256)."""
    view = memoryview(cast(Any, data))   # numpy arrays are buffers; the stubs do not say so
    return view if view.format == "B" and view.ndim == 1 else view.cast("B")


def check_pixels(width: int, height: int, max_px: int, what: str) -> None:
    """``FrameTooLarge`` when width x height is over ``max_px`` (0 = no bound); names the size and the key."""
    if max_px > 0 and width * height > max_px:
        raise FrameTooLarge(f"{what} of {width}x{height} px ({width * height / 1e6:.1f} MP) is over "
                            f"sources.max_image_px {max_px} ({max_px / 1e6:.1f} MP)")


def check_compressed(data: bytes | memoryview | np.ndarray, max_px: int, what: str) -> str:
    """Check a compressed image's declared size against the bound before decoding; returns its kind."""
    width, height, kind = compressed_size(data)
    check_pixels(width, height, max_px, f"{what} ({kind})")
    return kind


def check_file(path: Path, max_px: int, what: str) -> None:
    """The same for an image file (TUM folders), reading only its header."""
    with open(path, "rb") as fh:
        head = fh.read(HEADER_READ_BYTES)
    check_compressed(head, max_px, what)
