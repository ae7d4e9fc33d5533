"""The band diagram (Fig. 2 of the SCET paper) and the band table."""

from __future__ import annotations

import struct

import pytest

from estimator.banding import band_layout
from estimator.setup import Sensor, Strobe
from scet_render.band_diagram import band_table, draw_band_diagram

pytest.importorskip("matplotlib")

PROTO_SENSOR = Sensor(786, 480, 16.636e-3, 1e-3)
PROTO_STROBE = Strobe(16, 100e-6, 1039.75e-6, 0.3e-3)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


@pytest.mark.parametrize("frames", [1, 2])
def test_diagram_is_a_png(tmp_path, frames):
    out = draw_band_diagram(PROTO_SENSOR, PROTO_STROBE, tmp_path / "bands.png", frames=frames)
    assert out == tmp_path / "bands.png"
    width, height = png_size(out)
    assert (width, height) == (1100, 660)  # 10 x 6 inches at 110 dpi
    assert out.stat().st_size > 10_000  # a drawing, not an empty canvas


def test_diagram_rejects_bad_frames(tmp_path):
    with pytest.raises(ValueError):
        draw_band_diagram(PROTO_SENSOR, PROTO_STROBE, tmp_path / "x.png", frames=0)
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("frame_index", [0, 3])
def test_table_has_one_row_per_pulse_touching_the_frame(frame_index):
    table = band_table(PROTO_SENSOR, PROTO_STROBE, frame_index)
    layout = band_layout(PROTO_SENSOR, PROTO_STROBE, frame_index)
    assert [row["strobe"] for row in table] == [b.pulse_index for b in layout]
    assert len({row["strobe"] for row in table}) == len(table) >= 16
    for row in table:
        assert 0 <= row["first_row"] <= row["last_row"] <= 785
        assert row["time_us"] == pytest.approx((0.3e-3 + row["strobe"] * 1039.75e-6) * 1e6)
        assert row["partial_rows"] <= 12  # two ramps of 4.72 rows, each spanning <= 6 rows
    # Pulses lighting only invisible lines are listed too, marked invisible.
    assert any(not row["visible"] for row in table)
