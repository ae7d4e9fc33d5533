"""A printable ChArUco board at true scale: ``board.svg`` and ``board.pdf`` (vector), and the
``board.json`` that ``scet camera calibrate`` reads (:mod:`estimator.lens.board`).

The drawing is OpenCV's board, not a copy of it: the black squares are the squares
``cv2.aruco.CharucoBoard`` leaves without a marker, each marker is placed at the corners
``getObjPoints`` gives it and filled with the bit matrix of ``Dictionary.generateImageMarker``
(black border included), so a rasterised drawing equals ``CharucoBoard.generateImage`` at the
same scale (tests/hardware/test_board.py). Every shape is a rectangle in millimetres: an SVG
whose ``width``/``height`` are in mm and a one-page PDF (1 mm = 72 / 25.4 pt) print at true
scale when printed at 100 % ("actual size", not "fit to page"). A 10 mm bar beside the board
lets the print be checked with a ruler; ``square_mm`` in ``board.json`` must then be what the
print measures (measure ten squares with calipers and edit it, if the printer scales).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.lens.board import BoardSpec, write_board

__all__ = ["board_rects_mm", "write_printable_board", "MARGIN_MM", "A4_MM"]

#: White margin around the board (the quiet zone ArUco detection needs beyond the outer
#: squares) and room for the caption.
MARGIN_MM = 10.0
A4_MM = (210.0, 297.0)


def _runs(row) -> list[tuple[int, int]]:
    """(start, end) of the runs of True in a 1-D bool array."""
    d = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def board_rects_mm(spec: BoardSpec) -> list[tuple[float, float, float, float]]:
    """The board's black regions as rectangles (x, y, width, height) in mm, board frame (origin
    at the top-left outer corner, y down)."""
    board = spec.cv_board()
    dictionary = spec.cv_dictionary()
    bits = dictionary.markerSize + 2  # the code and its one-bit black border
    s = spec.square_mm
    centres = set()
    rects = []
    for mid, corners in zip(np.asarray(board.getIds()).ravel(), board.getObjPoints()):
        c = np.asarray(corners, dtype=np.float64).reshape(4, 3)[:, :2] * 1e3  # m -> mm
        x0, y0 = c[:, 0].min(), c[:, 1].min()
        side = (c[:, 0].max() - x0)
        centres.add((int((x0 + side / 2) // s), int((y0 + side / 2) // s)))
        img = dictionary.generateImageMarker(int(mid), bits, borderBits=1)
        cell = side / bits
        for r in range(bits):
            for a, b in _runs(img[r] == 0):
                rects.append((x0 + a * cell, y0 + r * cell, (b - a) * cell, cell))
    for j in range(spec.squares_y):
        for i in range(spec.squares_x):
            if (i, j) not in centres:
                rects.append((i * s, j * s, s, s))
    return rects


def _svg(spec: BoardSpec, rects, page_mm, origin_mm, caption: str) -> str:
    w, h = page_mm
    ox, oy = origin_mm
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.3f}mm" height="{h:.3f}mm" '
           f'viewBox="0 0 {w:.3f} {h:.3f}">',
           f'<title>{caption}</title>',
           f'<rect x="0" y="0" width="{w:.3f}" height="{h:.3f}" fill="#fff"/>',
           '<g fill="#000" shape-rendering="crispEdges">']
    out += [f'<rect x="{ox + x:.4f}" y="{oy + y:.4f}" width="{rw:.4f}" height="{rh:.4f}"/>'
            for x, y, rw, rh in rects]
    bw, bh = spec.size_mm
    out.append(f'<rect x="{ox:.4f}" y="{oy + bh + 4:.4f}" width="10" height="1"/>')
    out.append("</g>")
    out.append(f'<text x="{ox + 12:.3f}" y="{oy + bh + 5:.3f}" font-family="Helvetica, Arial" '
               f'font-size="2.5">{caption}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def _pdf(spec: BoardSpec, rects, page_mm, origin_mm, caption: str) -> bytes:
    """A one-page PDF 1.4 (ISO 32000-1 Sec. 7: objects, cross-reference table, trailer):
    filled rectangles (``re f``) and one line of Helvetica, a standard font every reader has."""
    pt = 72.0 / 25.4
    w, h = page_mm
    ox, oy = origin_mm
    bw, bh = spec.size_mm

    def rect(x, y, rw, rh):  # board frame (mm, y down) -> page (pt, y up)
        return f"{(ox + x) * pt:.3f} {(h - oy - y - rh) * pt:.3f} {rw * pt:.3f} {rh * pt:.3f} re"

    text = caption.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)")
    body = ["0 g"] + [rect(*r) for r in rects] + [rect(0.0, bh + 4.0, 10.0, 1.0), "f",
            f"BT /F1 7 Tf {(ox + 12) * pt:.3f} {(h - oy - bh - 5) * pt:.3f} Td ({text}) Tj ET"]
    stream = "\n".join(body).encode("ascii")
    objs = [b"<< /Type /Catalog /Pages 2 0 R >>",
            b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
            (f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {w * pt:.3f} {h * pt:.3f}] "
             f"/Contents 4 0 R /Resources << /Font << /F1 5 0 R >> >> >>").encode("ascii"),
            b"<< /Length %d >>\nstream\n" % len(stream) + stream + b"\nendstream",
            b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>"]
    out = bytearray(b"%PDF-1.4\n")
    offsets = []
    for k, o in enumerate(objs, 1):
        offsets.append(len(out))
        out += b"%d 0 obj\n" % k + o + b"\nendobj\n"
    xref = len(out)
    out += b"xref\n0 %d\n0000000000 65535 f \n" % (len(objs) + 1)
    out += b"".join(b"%010d 00000 n \n" % off for off in offsets)
    out += b"trailer\n<< /Size %d /Root 1 0 R >>\nstartxref\n%d\n%%%%EOF\n" % (len(objs) + 1, xref)
    return bytes(out)


def write_printable_board(out_dir, spec: BoardSpec) -> dict:
    """Write ``board.svg``, ``board.pdf`` and ``board.json`` into ``out_dir``.

    The page is A4 portrait when the board and its margins fit, else the board's size plus
    :data:`MARGIN_MM` on every side (and room for the caption).

    Returns
    -------
    dict
        Paths (``svg``, ``pdf``, ``json``) and the page size in mm (``page_mm``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bw, bh = spec.size_mm
    need = (bw + 2 * MARGIN_MM, bh + 2 * MARGIN_MM + 8.0)
    page = A4_MM if need[0] <= A4_MM[0] and need[1] <= A4_MM[1] else need
    origin = ((page[0] - bw) / 2, MARGIN_MM)
    rects = board_rects_mm(spec)
    caption = (f"SCET ChArUco {spec.squares_x}x{spec.squares_y}, square {spec.square_mm:g} mm, "
               f"marker {spec.marker_mm:g} mm, {spec.dictionary}. Print at 100 %: the bar is "
               f"10 mm.")
    paths = {"svg": out / "board.svg", "pdf": out / "board.pdf", "json": out / "board.json"}
    atomic_write(paths["svg"], _svg(spec, rects, page, origin, caption))
    atomic_write(paths["pdf"], _pdf(spec, rects, page, origin, caption))
    write_board(spec, paths["json"])
    return {**paths, "page_mm": page, "rects": len(rects)}

