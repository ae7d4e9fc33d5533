"""`scet hardware board`: the printable ChArUco board is OpenCV's board at true scale (SVG and
PDF), its board.json reads back, and OpenCV's detector finds every corner in a rasterised
print."""

import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from estimator.lens import DEFAULT_BOARD, BoardSpec, read_board
from scet_hardware.board import board_rects_mm, write_printable_board
from scet_render.cli import main

#: Rasterisation scale (px per mm) at which the drawing must equal OpenCV's generateImage
#: pixel for pixel where every marker cell spans whole pixels (0.3 mm: 6 px; generateImage
#: resamples markers whose cells do not).
PX_PER_MM = 20


def _raster(rects, size_mm, ppm=PX_PER_MM, origin=(0.0, 0.0)):
    w, h = int(round(size_mm[0] * ppm)), int(round(size_mm[1] * ppm))
    img = np.full((h, w), 255, np.uint8)
    for x, y, rw, rh in rects:
        x, y = x - origin[0], y - origin[1]
        img[int(round(y * ppm)):int(round((y + rh) * ppm)),
            int(round(x * ppm)):int(round((x + rw) * ppm))] = 0
    return img


@pytest.mark.parametrize("spec", [DEFAULT_BOARD, BoardSpec(5, 4, 10.0, 7.2, "DICT_4X4_50"),
                                  BoardSpec(6, 6, 5.0, 3.5, "DICT_5X5_100")])
def test_the_drawing_is_opencvs_board(spec):
    img = _raster(board_rects_mm(spec), spec.size_mm)
    ref = spec.cv_board().generateImage((img.shape[1], img.shape[0]), marginSize=0, borderBits=1)
    assert np.array_equal(img, ref)


def test_svg_and_pdf_are_true_scale_and_detectable(tmp_path):
    import cv2

    out = write_printable_board(tmp_path, DEFAULT_BOARD)
    root = ET.parse(out["svg"]).getroot()
    assert root.get("width") == "210.000mm" and root.get("viewBox") == "0 0 210.000 297.000"
    ns = "{http://www.w3.org/2000/svg}"
    rects = [tuple(float(r.get(k)) for k in ("x", "y", "width", "height"))
             for r in root.iter(ns + "rect") if r.get("width") not in ("210.000",)]
    board = rects[:-1]  # the last is the 10 mm bar
    assert rects[-1][2:] == (10.0, 1.0)
    ox, oy = min(r[0] for r in board), min(r[1] for r in board)
    assert (ox, oy) == pytest.approx(((210 - 27.5) / 2, 10.0))
    # The printed board, rasterised with a white margin, seen by OpenCV's own detector.
    img = _raster(board, (47.5, 40.0), origin=(ox - 10, oy - 10))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(DEFAULT_BOARD.cv_board()).detectBoard(img)
    assert ids is not None and sorted(ids.ravel()) == list(range(DEFAULT_BOARD.inner_corners))
    # Corner 0 sits one square from the board's top-left corner (pixel-centre convention).
    assert corners[list(ids.ravel()).index(0)].ravel() == pytest.approx(
        [(10 + 2.5) * PX_PER_MM - 0.5, (10 + 2.5) * PX_PER_MM - 0.5], abs=0.2)

    pdf = out["pdf"].read_bytes()
    assert pdf.startswith(b"%PDF-1.4") and pdf.rstrip().endswith(b"%%EOF")
    # The cross-reference table points at every object (a reader relies on it).
    xref = int(re.search(rb"startxref\n(\d+)", pdf).group(1))
    assert pdf[xref:xref + 4] == b"xref"
    offsets = [int(m) for m in re.findall(rb"(\d{10}) 00000 n", pdf)]
    for k, off in enumerate(offsets, 1):
        assert pdf[off:].startswith(b"%d 0 obj" % k)
    stream = re.search(rb"stream\n(.*?)\nendstream", pdf, re.S).group(1)
    assert int(re.search(rb"/Length (\d+)", pdf).group(1)) == len(stream)
    mm = 25.4 / 72
    media = [float(v) for v in re.search(rb"/MediaBox \[([^\]]+)\]", pdf).group(1).split()]
    assert media[2] * mm == pytest.approx(210, abs=1e-3) and media[3] * mm == pytest.approx(297, abs=1e-3)
    prect = [[float(v) * mm for v in m.split()] for m in re.findall(rb"([\d. ]+) re", stream)]
    assert len(prect) == len(rects)
    # Same rectangles in the PDF (y up from the page's bottom) as in the SVG (y down).
    for (x, y, w, h), (px, py, pw, ph) in zip(rects, prect):
        assert (px, 297 - py - ph, pw, ph) == pytest.approx((x, y, w, h), abs=2e-3)
    assert read_board(out["json"]) == DEFAULT_BOARD


def test_a_board_larger_than_a4_gets_its_own_page(tmp_path):
    spec = BoardSpec(9, 7, 30.0, 22.0, "DICT_4X4_50")
    out = write_printable_board(tmp_path, spec)
    assert out["page_mm"][0] == pytest.approx(270 + 20)


def test_cli_writes_the_board_and_refuses_bad_values(tmp_path, capsys):
    assert main(["hardware", "board", "--out", str(tmp_path / "b"), "--square-mm", "2.5",
                 "--marker-mm", "1.8"]) == 0
    assert "11x8 squares of 2.5 mm" in capsys.readouterr().out
    assert read_board(tmp_path / "b" / "board.json") == DEFAULT_BOARD
    for flags, text in ((["--marker-mm", "3"], "marker_mm"), (["--squares", "12x10"], "60 markers"),
                        (["--squares", "eleven"], "--squares")):
        assert main(["hardware", "board", "--out", str(tmp_path / "c"), *flags]) == 2
        err = capsys.readouterr().err
        assert text in err and len(err.strip().splitlines()) == 1


def test_the_default_board_fits_the_prototypes_field(tmp_path, capsys):
    # Issue 30: the 27.5 mm default board is wider than the prototype's 22.9 mm field at its
    # 23 mm working distance. The printed default spans 60 % of that field (1.3 mm squares),
    # so it can be tilted or held into a corner and stay mostly in view; another scene gets
    # its own size.
    from estimator.lens import working_distance_m
    from estimator.scene import load_scene

    assert main(["hardware", "board", "--out", str(tmp_path / "p")]) == 0
    assert "sized to prototype_ov5647's field" in capsys.readouterr().out
    spec = read_board(tmp_path / "p" / "board.json")
    assert (spec.square_mm, spec.marker_mm) == (1.3, 0.975)
    setup = load_scene("prototype_ov5647")
    field_mm = 1e3 * working_distance_m(setup) * setup.camera.width_px / setup.camera.fx_px
    assert DEFAULT_BOARD.size_mm[0] > field_mm  # the issue: the old default did not fit
    assert spec.size_mm[0] == pytest.approx(0.6 * field_mm, abs=11 * 0.05)
    assert main(["hardware", "board", "--out", str(tmp_path / "q"), "--scene", "paper_sim"]) == 0
    assert read_board(tmp_path / "q" / "board.json").square_mm == 0.6  # 1300 px: half the field
    capsys.readouterr()
    assert main(["hardware", "board", "--out", str(tmp_path / "r"), "--scene", "nowhere"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
