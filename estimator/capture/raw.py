"""Raw Bayer frames as picamera2 returns them on a Raspberry Pi 4 or earlier: 10-bit CSI-2
packed (``S????10_CSI2P``: 4 pixels in 5 bytes) or unpacked (``S????10``: one little-endian
16-bit word per pixel, zero above bit 9), rows ``stride`` bytes apart (HARDWARE.md Sec. 3).

CSI-2 packing (V4L2 pixfmt-srggb10p): bytes 0-3 hold bits 9:2 of pixels 0-3, byte 4 holds
their bits 1:0, pixel i at bits 2i+1:2i. Unpacking and packing are whole-array numpy
operations (no Python loop over pixels).

Bayer handling. A NoIR OV5647 under near-IR light sees R ~ G ~ B (the dyes are nearly clear
above 800 nm), so the mosaic is a grey image with, at most, a small gain and black-level
difference per CFA site. We weight the channels rather than bin 2x2: each site's black level
(``SensorBlackLevels``) is subtracted, its gain applied and the frame keeps the sensor's full
640 x 480 grid. The detector and the calibration work in the scene camera's full-resolution
pixel coordinates (pixel (0, 0) is the centre of the top-left pixel, f = 643 px at VGA); a
2x2 bin would halve the focal length in pixels, move every pixel centre by half an input
pixel and average away the 2-4 px glints' sub-pixel shape, and the VGA mode already bins the
sensor 4x4 (Sec. 1a). The frame the tracker gets is the corrected mosaic, same size, same
pixel centres, in DN with the scene's black level.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

__all__ = ["BAYER_ORDERS", "CHANNELS", "RawFormat", "parse_raw_format", "row_bytes",
           "min_stride", "unpack_csi2p10", "pack_csi2p10", "decode_raw", "encode_raw",
           "cfa_channel_map", "to_tracker_frame", "mosaic_from_grey"]

#: The four 2x2 CFA orders (top-left block read row by row).
BAYER_ORDERS = ("RGGB", "GRBG", "GBRG", "BGGR")
#: Channel order of ``SensorBlackLevels`` and of SCET's per-channel gains.
CHANNELS = ("R", "Gr", "Gb", "B")
_FORMAT = re.compile(r"^S(RGGB|GRBG|GBRG|BGGR)10(_CSI2P)?$")


@dataclass(frozen=True, slots=True)
class RawFormat:
    """A raw stream format: picamera2's name, Bayer order, packing, bit depth."""

    name: str
    bayer_order: str
    packed: bool
    bit_depth: int = 10


def parse_raw_format(name) -> RawFormat:
    """The :class:`RawFormat` of a picamera2 raw format name; ``ValueError`` if SCET does not
    read it (8/12-bit modes, Pi 5 ``PISP_COMP1`` compressed frames)."""
    m = _FORMAT.match(str(name)) if isinstance(name, str) else None
    if m is None:
        raise ValueError(f"unknown raw format {name!r}: SCET reads 10-bit Bayer "
                         f"S<order>10_CSI2P (packed) or S<order>10 (unpacked), order one of "
                         f"{', '.join(BAYER_ORDERS)}")
    return RawFormat(str(name), m.group(1), m.group(2) is not None)


def row_bytes(fmt: RawFormat, width: int) -> int:
    """Bytes of pixel data in one row (the stride may add padding)."""
    if fmt.packed:
        if width % 4:
            raise ValueError(f"{fmt.name}: width {width} is not a multiple of 4")
        return width * 5 // 4
    return width * 2


def min_stride(fmt: RawFormat, width: int, align: int = 32) -> int:
    """The stride the Pi's Unicam driver uses: the row bytes rounded up to 32 (800 B packed,
    1280 B unpacked at 640 px)."""
    n = row_bytes(fmt, width)
    return -(-n // align) * align


def unpack_csi2p10(rows: np.ndarray, width: int) -> np.ndarray:
    """(H, stride) uint8 CSI-2 packed rows -> (H, width) uint16 pixels 0..1023."""
    rows = np.asarray(rows, dtype=np.uint8)
    h = rows.shape[0]
    groups = rows[:, : width * 5 // 4].reshape(h, width // 4, 5)
    low = groups[:, :, 4]
    out = np.empty((h, width // 4, 4), dtype=np.uint16)
    # Four strided passes, one per pixel of a group (1.3 ms a VGA frame here, against 2.7 ms
    # for one broadcast expression: fewer temporaries).
    for i in range(4):
        o = out[:, :, i]
        np.left_shift(groups[:, :, i], 2, out=o, dtype=np.uint16)
        o |= (low >> (2 * i)) & 3
    return out.reshape(h, width)


def pack_csi2p10(pixels: np.ndarray, stride: int | None = None) -> np.ndarray:
    """(H, W) integer pixels 0..1023 -> (H, stride) uint8 CSI-2 packed rows (zero padding)."""
    px = np.asarray(pixels)
    if px.ndim != 2 or px.shape[1] % 4:
        raise ValueError(f"expected (H, W) pixels with W a multiple of 4, got shape {px.shape}")
    if px.size and (px.min() < 0 or px.max() > 1023):
        raise ValueError("pixels must be 10-bit (0..1023)")
    h, w = px.shape
    n = w * 5 // 4
    stride = n if stride is None else int(stride)
    if stride < n:
        raise ValueError(f"stride {stride} is shorter than a packed row ({n} bytes)")
    g = px.astype(np.uint16).reshape(h, w // 4, 4)
    out = np.zeros((h, stride), dtype=np.uint8)
    body = out[:, :n].reshape(h, w // 4, 5)
    body[:, :, :4] = (g >> 2).astype(np.uint8)
    body[:, :, 4] = ((g & 3) << np.array([0, 2, 4, 6], dtype=np.uint16)).sum(axis=2).astype(np.uint8)
    return out


def decode_raw(rows: np.ndarray, fmt: RawFormat, width: int) -> np.ndarray:
    """(H, stride) uint8 rows of ``fmt`` -> (H, width) uint16 mosaic. Unpacked frames are a
    view of ``rows`` (no copy)."""
    if fmt.packed:
        return unpack_csi2p10(rows, width)
    return np.ascontiguousarray(rows[:, : 2 * width]).view("<u2").reshape(rows.shape[0], width)


def encode_raw(mosaic: np.ndarray, fmt: RawFormat, stride: int) -> np.ndarray:
    """(H, W) mosaic 0..1023 -> (H, stride) uint8 rows of ``fmt``."""
    m = np.asarray(mosaic)
    if fmt.packed:
        return pack_csi2p10(m, stride)
    h, w = m.shape
    if stride < 2 * w:
        raise ValueError(f"stride {stride} is shorter than an unpacked row ({2 * w} bytes)")
    out = np.zeros((h, stride), dtype=np.uint8)
    out[:, : 2 * w] = m.astype("<u2").view(np.uint8).reshape(h, 2 * w)
    return out


def cfa_channel_map(bayer_order: str) -> np.ndarray:
    """(2, 2) index into :data:`CHANNELS` of each site of the top-left 2x2 block. Gr is the
    green on red rows, Gb the green on blue rows."""
    if bayer_order not in BAYER_ORDERS:
        raise ValueError(f"unknown Bayer order {bayer_order!r}, expected one of {BAYER_ORDERS}")
    sites = np.array(list(bayer_order)).reshape(2, 2)
    out = np.empty((2, 2), dtype=np.int64)
    for r in range(2):
        red_row = "R" in sites[r]
        for c in range(2):
            s = sites[r, c]
            out[r, c] = {"R": 0, "B": 3}.get(s, 1 if red_row else 2)
    return out


def _site_values(values, bayer_order: str, shape) -> np.ndarray:
    """(H, W) per-pixel value of the per-channel ``values`` (R, Gr, Gb, B)."""
    v = np.asarray(values, dtype=np.float64)
    block = v[cfa_channel_map(bayer_order)]
    h, w = shape
    return np.tile(block, (-(-h // 2), -(-w // 2)))[:h, :w]


def to_tracker_frame(mosaic: np.ndarray, bayer_order: str, black_levels_dn, gains,
                     black_level_out_dn: float, bit_depth: int = 10) -> np.ndarray:
    """The mosaic as the tracker's grey frame: per CFA site, (raw - black) * gain + the
    output black level, rounded and clipped to the bit depth (uint16).

    Where every site already has the output black level and unit gain this is the mosaic
    itself (no copy): the common case of a NoIR sensor under NIR.
    """
    black = np.asarray(black_levels_dn, dtype=np.float64).reshape(4)
    gain = np.asarray(gains, dtype=np.float64).reshape(4)
    if np.all(black == black_level_out_dn) and np.all(gain == 1.0):
        return mosaic
    b = _site_values(black, bayer_order, mosaic.shape)
    g = _site_values(gain, bayer_order, mosaic.shape)
    out = (mosaic.astype(np.float32) - b.astype(np.float32)) * g.astype(np.float32) + np.float32(black_level_out_dn)
    return np.clip(np.rint(out), 0, 2 ** bit_depth - 1).astype(np.uint16)


def mosaic_from_grey(grey_dn: np.ndarray, bayer_order: str, black_levels_dn, gains,
                     black_level_in_dn: float, bit_depth: int = 10) -> np.ndarray:
    """The inverse of :func:`to_tracker_frame`: the mosaic a sensor with these per-channel
    black levels and relative responses (1 / gain) reads from a grey frame (uint16)."""
    grey = np.asarray(grey_dn, dtype=np.float64)
    b = _site_values(black_levels_dn, bayer_order, grey.shape)
    g = _site_values(gains, bayer_order, grey.shape)
    out = (grey - black_level_in_dn) / g + b
    return np.clip(np.rint(out), 0, 2 ** bit_depth - 1).astype(np.uint16)
