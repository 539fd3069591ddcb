"""Image sizes read before anything is decoded, and the pixel bound ``sources.max_image_px``.

A 1 MB PNG or JPEG may declare 30000 x 30000 pixels: ``cv2.imdecode`` allocates the declared
size first (2.7 GB for colour) and every per-frame array after it scales with it (~100 bytes a
pixel through the maps, README "Limits"). So the size is read from the header (PNG IHDR, JPEG
SOFn; a raw ``sensor_msgs/Image`` declares width and height) and checked against the bound
before any allocation. An oversized frame is a ``FrameTooLarge`` decode error: the reader skips
that frame with one counted warning, the run goes on.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any, cast

import numpy as np

from slzcli.errors import DecodeError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOI = b"\xff\xd8"
# SOFn markers carrying the frame size (ITU T.81 B.1.1.3): not DHT (C4), JPG (C8) or DAC (CC).
_JPEG_SOF = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})
_JPEG_STANDALONE = frozenset({0x01, *range(0xD0, 0xD8)})   # TEM, RSTn: no length field
# A file's header is read up to here (TUM folders); real JPEG headers (EXIF, ICC) fit well inside.
HEADER_READ_BYTES = 1 << 20


class FrameTooLarge(DecodeError):
    """A frame whose declared size is over ``sources.max_image_px``: skipped, not decoded."""


def compressed_size(data: bytes | memoryview | np.ndarray) -> tuple[int, int, str]:
    """(width, height, 'png' | 'jpeg') from a compressed image's header; DecodeError if there is none."""
    data = _bytes_view(data)
    head = bytes(data[:8])
    if head == PNG_SIGNATURE:
        return (*_png_size(data), "png")
    if head[:2] == JPEG_SOI:
        return (*_jpeg_size(data), "jpeg")
    raise DecodeError("not a decodable jpeg/png (no PNG or JPEG signature)")


def _bytes_view(data: bytes | memoryview | np.ndarray) -> memoryview:
    """A flat byte view (indexing gives Python ints: numpy uint8 arithmetic would wrap at 256)."""
    view = memoryview(cast(Any, data))   # numpy arrays are buffers; the stubs do not say so
    return view if view.format == "B" and view.ndim == 1 else view.cast("B")


def _png_size(data: memoryview) -> tuple[int, int]:
    ihdr = bytes(data[8:24])
    if len(ihdr) < 16 or ihdr[4:8] != b"IHDR":
        raise DecodeError("not a decodable jpeg/png (PNG without an IHDR header)")
    return struct.unpack(">II", ihdr[8:16])


def _jpeg_size(data: memoryview) -> tuple[int, int]:
    """Walk the marker segments from SOI to the first SOFn (each segment: FF, marker, BE16 length)."""
    n, i = len(data), 2
    while i + 4 <= n:
        if data[i] != 0xFF:
            raise DecodeError(f"not a decodable jpeg/png (JPEG marker expected at byte {i})")
        marker = data[i + 1]
        if marker == 0xFF:               # fill byte before a marker
            i += 1
            continue
        if marker in _JPEG_STANDALONE:
            i += 2
            continue
        if marker in (0xD9, 0xDA):       # EOI or start of scan before any frame header
            break
        length = (data[i + 2] << 8) | data[i + 3]
        if marker in _JPEG_SOF:
            if i + 9 > n:
                break
            height = (data[i + 5] << 8) | data[i + 6]
            width = (data[i + 7] << 8) | data[i + 8]
            if width == 0 or height == 0:  # height 0 = size given later (DNL): libjpeg cannot decode it
                raise DecodeError(f"not a decodable jpeg/png (JPEG frame header says {width}x{height} px)")
            return width, height
        if length < 2:
            break
        i += 2 + length
    raise DecodeError("not a decodable jpeg/png (no JPEG frame header)")


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
