"""Cheap structural checks of PNG and JPEG frames, without decoding pixels.

PNG: signature, IHDR (width, height, bit depth, colour type), then every chunk is walked and its CRC-32
verified up to IEND — this catches truncated and bit-flipped files at the cost of one read and a CRC
(hundreds of MB/s), far cheaper than inflating the image. JPEG: markers are walked to the first SOF
segment (precision, height, width, components) and the file must end with an EOI marker (a truncated
upload loses it). A few frames per folder are additionally decoded with OpenCV (see ``decode_check``).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

from service.errors import InvalidSession

PNG_SIG = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}  # colour type -> channels after decoding
_PNG_KIND = {0: "grayscale", 2: "RGB", 3: "palette", 4: "grayscale+alpha", 6: "RGBA"}
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


@dataclass(frozen=True)
class ImageInfo:
    fmt: str  # "png" | "jpeg"
    width: int
    height: int
    bit_depth: int  # bits per sample
    channels: int
    kind: str  # e.g. "grayscale", "RGB", "YCbCr"


def sniff(data: bytes) -> str | None:
    if data.startswith(PNG_SIG):
        return "png"
    if data.startswith(b"\xff\xd8"):
        return "jpeg"
    return None


def png_info(path: Path, rel: str, *, verify: bool = True) -> ImageInfo:
    """Header of a PNG; with ``verify`` the whole chunk chain and CRCs are checked."""
    with open(path, "rb") as f:
        data = f.read() if verify else f.read(33)
    if not data.startswith(PNG_SIG):
        raise InvalidSession(rel, "not a PNG file (bad signature)")
    if len(data) < 33 or data[12:16] != b"IHDR":
        raise InvalidSession(rel, "corrupt PNG: missing IHDR header")
    w, h, depth, ctype = struct.unpack(">IIBB", data[16:26])
    if ctype not in _PNG_CHANNELS or w == 0 or h == 0:
        raise InvalidSession(rel, "corrupt PNG: invalid IHDR header")
    if verify:
        pos = 8
        n = len(data)
        while True:
            if pos + 12 > n:
                raise InvalidSession(rel, "truncated PNG (no IEND chunk)")
            (length,) = struct.unpack(">I", data[pos : pos + 4])
            ctype_b = data[pos + 4 : pos + 8]
            end = pos + 12 + length
            if end > n:
                raise InvalidSession(rel, f"truncated PNG (chunk {ctype_b!r} cut off)")
            (crc,) = struct.unpack(">I", data[end - 4 : end])
            if zlib.crc32(data[pos + 4 : end - 4]) != crc:
                raise InvalidSession(rel, f"corrupt PNG (CRC mismatch in chunk {ctype_b.decode('latin-1')})")
            pos = end
            if ctype_b == b"IEND":
                break
    return ImageInfo("png", w, h, depth, _PNG_CHANNELS[ctype], _PNG_KIND[ctype])


def jpeg_info(path: Path, rel: str, *, verify: bool = True) -> ImageInfo:
    """Header of a JPEG (first SOF segment); with ``verify`` the file must end with EOI."""
    with open(path, "rb") as f:
        data = f.read()
    n = len(data)
    if not data.startswith(b"\xff\xd8"):
        raise InvalidSession(rel, "not a JPEG file (bad signature)")
    pos = 2
    info = None
    while pos + 4 <= n:
        if data[pos] != 0xFF:
            raise InvalidSession(rel, "corrupt JPEG (bad marker)")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            pos += 2
            continue
        if marker == 0xD9 or marker == 0xDA:
            break
        (seglen,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        if marker in _SOF:
            if pos + 10 > n:
                break
            prec, h, w, comps = struct.unpack(">BHHB", data[pos + 4 : pos + 10])
            kind = {1: "grayscale", 3: "YCbCr", 4: "CMYK"}.get(comps, f"{comps}-component")
            info = ImageInfo("jpeg", w, h, prec, comps, kind)
            break
        pos += 2 + seglen
    if info is None or info.width == 0 or info.height == 0:
        raise InvalidSession(rel, "corrupt or truncated JPEG (no frame header)")
    if verify and b"\xff\xd9" not in data[-1024:]:
        raise InvalidSession(rel, "truncated JPEG (no end-of-image marker)")
    return info


def image_info(path: Path, rel: str, *, verify: bool = True) -> ImageInfo:
    with open(path, "rb") as f:
        head = f.read(8)
    kind = sniff(head)
    if kind == "png":
        return png_info(path, rel, verify=verify)
    if kind == "jpeg":
        return jpeg_info(path, rel, verify=verify)
    raise InvalidSession(rel, "not a PNG or JPEG image (unrecognised file header)")


def check_rgb(info: ImageInfo, rel: str) -> None:
    """Colour frame: 8-bit, 3 colour channels (PNG RGB/RGBA/palette, JPEG YCbCr). Grayscale is refused."""
    if info.bit_depth != 8:
        raise InvalidSession(rel, f"{info.bit_depth}-bit image, expected 8-bit colour")
    if info.fmt == "png" and info.kind in ("grayscale", "grayscale+alpha"):
        raise InvalidSession(rel, f"{info.kind} PNG, expected a colour (3-channel) image")
    if info.fmt == "jpeg" and info.channels != 3:
        raise InvalidSession(rel, f"{info.kind} JPEG, expected a colour (3-channel) image")


def _check_single_channel_png(info: ImageInfo, rel: str, what: str, bits: int) -> None:
    if info.fmt != "png":
        raise InvalidSession(rel, f"JPEG {what}, expected a single-channel {bits}-bit PNG")
    if info.channels != 1:
        raise InvalidSession(rel, f"{info.kind} image with {info.channels} channels, expected single-channel {bits}-bit")
    if info.bit_depth != bits:
        raise InvalidSession(rel, f"{info.bit_depth}-bit image, expected {bits}-bit")


def check_depth(info: ImageInfo, rel: str) -> None:
    """Depth frame: single-channel 16-bit PNG."""
    _check_single_channel_png(info, rel, "depth frame", 16)


def check_mask(info: ImageInfo, rel: str) -> None:
    """Mask: single-channel 8-bit PNG."""
    _check_single_channel_png(info, rel, "mask", 8)


def decode_check(path: Path, rel: str, info: ImageInfo, kind: str):
    """Decode with OpenCV and confirm it agrees with the header (catches broken compressed data).

    Returns the decoded image."""
    import cv2

    flag = cv2.IMREAD_COLOR if kind == "rgb" else cv2.IMREAD_UNCHANGED
    img = cv2.imread(str(path), flag)
    if img is None:
        raise InvalidSession(rel, "image cannot be decoded (corrupt file)")
    if img.shape[:2] != (info.height, info.width):
        raise InvalidSession(rel, "image cannot be decoded consistently with its header (corrupt file)")
    if kind == "depth" and (img.ndim != 2 or img.dtype.itemsize != 2):
        raise InvalidSession(rel, "decoded depth is not single-channel 16-bit")
    if kind == "mask" and (img.ndim != 2 or img.dtype.itemsize != 1):
        raise InvalidSession(rel, "decoded mask is not single-channel 8-bit")
    return img


def any_nonzero(path: Path) -> bool:
    """True when the decoded image has a non-zero pixel."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return img is not None and bool(img.any())
