"""Raw Bayer frames: CSI-2 packing to the V4L2 bit layout, unpacked words, CFA channels and the
black-level/gain correction (numpy only; no renderer)."""

import numpy as np
import pytest

from estimator.capture import (cfa_channel_map, decode_raw, encode_raw, min_stride,
                               mosaic_from_grey, pack_csi2p10, parse_raw_format,
                               to_tracker_frame, unpack_csi2p10)


def test_packing_follows_the_v4l2_layout():
    # Pixels 0..3 = 0x3FF, 0x001, 0x2AA, 0x155: bytes 0-3 are bits 9:2, byte 4 the pairs of
    # bits 1:0 with pixel i at bits 2i+1:2i (docs.kernel.org pixfmt-srggb10p).
    px = np.array([[0x3FF, 0x001, 0x2AA, 0x155]])
    packed = pack_csi2p10(px)
    assert packed.tolist() == [[0xFF, 0x00, 0xAA, 0x55, 0b01_10_01_11]]
    assert unpack_csi2p10(packed, 4).tolist() == px.tolist()


@pytest.mark.parametrize("name", ["SGBRG10_CSI2P", "SGBRG10", "SRGGB10_CSI2P", "SBGGR10"])
def test_round_trip_with_padding(name, rng):
    fmt = parse_raw_format(name)
    px = rng.integers(0, 1024, (480, 640))
    stride = min_stride(fmt, 640)
    assert stride == (800 if fmt.packed else 1280)
    rows = encode_raw(px, fmt, stride + 64)
    assert rows.shape == (480, stride + 64)
    assert np.array_equal(decode_raw(rows, fmt, 640), px)


def test_unpacked_frames_are_a_view(rng):
    fmt = parse_raw_format("SGBRG10")
    rows = encode_raw(rng.integers(0, 1024, (8, 16)), fmt, 32)
    assert np.shares_memory(decode_raw(rows, fmt, 16), rows)


@pytest.mark.parametrize("name", ["SGBRG12", "PISP_COMP1", "SGBRG10_CSI2", "", None, 10])
def test_unknown_formats(name):
    with pytest.raises(ValueError, match="unknown raw format"):
        parse_raw_format(name)


def test_cfa_channels_gbrg():
    # GBRG: row 0 is G B (a blue row: Gb), row 1 is R G (a red row: Gr).
    assert cfa_channel_map("GBRG").tolist() == [[2, 3], [0, 1]]
    assert cfa_channel_map("RGGB").tolist() == [[0, 1], [2, 3]]


def test_weighting_keeps_the_grid_and_undoes_the_mosaic(rng):
    grey = rng.integers(16, 1000, (480, 640)).astype(np.uint16)
    black = [16, 17, 15, 18]
    response = np.array([0.9, 1.0, 1.02, 0.85])        # relative NIR response per channel
    mosaic = mosaic_from_grey(grey, "GBRG", black, 1 / response, 16)
    back = to_tracker_frame(mosaic, "GBRG", black, 1 / response, 16)
    assert back.shape == grey.shape
    # Rounding the mosaic to whole DN costs at most 0.5 DN / response: < 0.6 DN + 0.5 rounding.
    assert np.abs(back.astype(int) - grey.astype(int)).max() <= 1


def test_unit_gains_and_matching_black_return_the_mosaic_itself(rng):
    mosaic = rng.integers(0, 1024, (4, 4)).astype(np.uint16)
    assert to_tracker_frame(mosaic, "GBRG", [16] * 4, [1] * 4, 16) is mosaic
