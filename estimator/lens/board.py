"""The calibration board: a ChArUco board (OpenCV's ``cv2.aruco.CharucoBoard``) described by
``board.json``.

A ChArUco board is a chessboard whose white squares hold ArUco markers: the markers name the
chessboard corners, so a view that shows only part of the board still gives identified corners
(Garrido-Jurado et al. 2014, "Automatic generation and detection of highly reliable fiducial
markers under occlusion"; OpenCV's ``objdetect`` ChArUco tutorial). That matters at SCET's
working distance of 3-4 cm, where a tilted board leaves the frame on one side.

Board frame: origin at the board's top-left outer corner, x along a row of squares, y down
the columns, z into the board; the top-left square is black (OpenCV's layout since 4.6; the
"legacy" layout of older versions differs for an even number of rows and is refused).

Default size (:data:`DEFAULT_BOARD`): 11 x 8 squares of 2.5 mm with 1.8 mm markers
(27.5 x 20 mm, DICT_4X4_50). At 35 mm the stock lens (643 px at VGA,
HARDWARE.md Sec. 10) sees a field of 35 x 26 mm, so the board fills ~60 % of the frame's width
and can be tilted by 30-40 deg or moved into a corner while most of it stays in view; a square
spans 46 px, a marker 33 px, one marker bit 5.5 px: above OpenCV's default minimum marker
perimeter (3 % of 640 px) and enough pixels a bit to survive a 1-2 px defocus blur. With the
~7.3 mm lens (1300 px) a square spans 93 px and a view holds about half the board. The 1.8 mm
marker is 6 bits of 0.30 mm: 7 dots a bit on a 600 dpi laser printer.

That default is too large for the prototype scene (``scenes/prototype_ov5647.toml``): its camera
sits 23 mm from the corneal apex, where the 643 px lens sees a field of 22.9 x 17.2 mm, narrower
than the 27.5 mm board. :func:`board_for_setup` sizes a board to a scene's field instead, by the
rule the rendered board frames use (``scet render --board``): 11 x 8 squares spanning 60 % of
the field's width at the working distance (the corneal apex's depth), the side rounded to
0.1 mm, markers 0.75 of a square (OpenCV's tutorial board's ratio). For the prototype: squares of
1.3 mm (14.3 x 10.4 mm, 36 px a square, a marker bit of 0.16 mm = 4.5 px; 3.8 dots at 600 dpi,
so print it at 1200 dpi or on a photo printer and check the 10 mm bar). ``scet hardware board``
prints that board by default (``--scene``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import datetime, timezone

import numpy as np

from ..checks import Doc
from ..errors import InputError
from ..formats import atomic_write, check_format, read_json

__all__ = ["BOARD_FORMAT", "BOARD_VERSION", "BoardError", "BoardSpec", "DEFAULT_BOARD",
           "read_board", "write_board", "DICTIONARIES", "working_distance_m", "board_for_setup",
           "FIELD_SHARE"]

BOARD_FORMAT, BOARD_VERSION = "scet-board", 1
#: The ArUco dictionaries a board may use (OpenCV's predefined 4x4 to 6x6 ones).
DICTIONARIES = tuple(f"DICT_{n}X{n}_{k}" for n in (4, 5, 6) for k in (50, 100, 250, 1000))


class BoardError(InputError):
    """A board description (``board.json``, or CLI values meant for one) is malformed."""


@dataclass(frozen=True, slots=True)
class BoardSpec:
    """A ChArUco board.

    Attributes
    ----------
    squares_x, squares_y : int
        Squares along a row (x) and a column (y), each >= 3 (at least 4 inner corners).
    square_mm, marker_mm : float
        Side of a chessboard square and of a marker (marker < square).
    dictionary : str
        OpenCV predefined ArUco dictionary name (:data:`DICTIONARIES`); it must hold a marker
        for every white square.
    """

    squares_x: int
    squares_y: int
    square_mm: float
    marker_mm: float
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self):
        for name in ("squares_x", "squares_y"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 3 <= v <= 100:
                raise BoardError(f"{name} must be an integer in [3, 100], got {v!r}", key=name)
            object.__setattr__(self, name, int(v))
        for name in ("square_mm", "marker_mm"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and 0.1 <= v <= 1000.0):
                raise BoardError(f"{name} must be in [0.1, 1000] mm, got {v:g}", key=name)
            object.__setattr__(self, name, v)
        if not self.marker_mm < self.square_mm:
            raise BoardError(f"marker_mm ({self.marker_mm:g}) must be smaller than square_mm "
                             f"({self.square_mm:g})", key="marker_mm")
        if self.dictionary not in DICTIONARIES:
            raise BoardError(f"dictionary must be one of {list(DICTIONARIES)}, got "
                             f"{self.dictionary!r}", key="dictionary")
        if self.markers > int(self.dictionary.rsplit("_", 1)[1]):
            raise BoardError(f"{self.markers} markers do not fit {self.dictionary}; choose a "
                             "larger dictionary", key="dictionary")

    @property
    def markers(self) -> int:
        """Number of markers (one per white square)."""
        return (self.squares_x * self.squares_y) // 2

    @property
    def inner_corners(self) -> int:
        """Number of ChArUco corners (the chessboard's inner corners)."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the board."""
        return self.squares_x * self.square_mm, self.squares_y * self.square_mm

    def cv_dictionary(self):
        import cv2

        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def cv_board(self):
        """The ``cv2.aruco.CharucoBoard``, its object points in metres."""
        import cv2

        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm * 1e-3,
                                      self.marker_mm * 1e-3, self.cv_dictionary())

    def corners_m(self) -> np.ndarray:
        """(n, 3) the ChArUco corners in the board frame (metres), index = corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)

    def to_dict(self) -> dict:
        return {"format": BOARD_FORMAT, "version": BOARD_VERSION, "kind": "charuco",
                **asdict(self), "size_mm": list(self.size_mm), "legacy_pattern": False,
                "opencv_board": "cv2.aruco.CharucoBoard((squares_x, squares_y), square, marker, "
                                "dictionary)"}


#: The default board (module docstring: why this size).
DEFAULT_BOARD = BoardSpec(11, 8, 2.5, 1.8, "DICT_4X4_50")
#: Share of the field's width a board sized by :func:`board_for_setup` spans: room to tilt it
#: by 30-40 deg or hold it into a corner with most of it in view (module docstring).
FIELD_SHARE = 0.6


def working_distance_m(setup) -> float:
    """Depth of the corneal apex at primary gaze in ``setup``'s camera frame (m): where the eye
    is, so where the board is held."""
    return float(setup.camera.world_to_camera(setup.eye.apex())[2])


def board_for_setup(setup, squares=(11, 8), dictionary: str = "DICT_4X4_50") -> BoardSpec:
    """A board of ``squares`` that spans :data:`FIELD_SHARE` of ``setup``'s field width at its
    working distance: the side rounded to 0.1 mm (at least 0.1 mm), markers 0.75 of a square.

    Raises
    ------
    BoardError
        When the markers do not fit ``dictionary``.
    """
    cam = setup.camera
    width_m = working_distance_m(setup) * cam.width_px / cam.fx_px
    tenths_mm = max(1, round(FIELD_SHARE * width_m / squares[0] * 1e4))
    return BoardSpec(int(squares[0]), int(squares[1]), tenths_mm / 10, 0.75 * tenths_mm / 10,
                     dictionary)


def write_board(spec: BoardSpec, path) -> None:
    """Write ``spec`` as ``board.json`` (atomically; the date of writing recorded)."""
    import json

    doc = spec.to_dict()
    doc["date"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    atomic_write(path, json.dumps(doc, indent=2) + "\n")


def board_from_doc(doc: Doc) -> BoardSpec:
    """A :class:`BoardSpec` from the object ``doc`` (a ``board.json`` or a camera file's
    ``board``); errors name the file and the key."""
    doc.string("kind", choices=("charuco",))
    if doc.boolean("legacy_pattern", required=False, default=False):
        raise doc.error("legacy_pattern", "the legacy ChArUco layout (OpenCV < 4.6) is not "
                                          "supported; print a board with scet hardware board")
    values = dict(squares_x=doc.integer("squares_x", lo=3, hi=100),
                  squares_y=doc.integer("squares_y", lo=3, hi=100),
                  square_mm=doc.number("square_mm", lo=0.1, hi=1000.0),
                  marker_mm=doc.number("marker_mm", lo=0.1, hi=1000.0),
                  dictionary=doc.string("dictionary", choices=DICTIONARIES))
    try:
        return BoardSpec(**values)
    except BoardError as exc:
        raise doc.error(exc.key, str(exc).split(": ", 1)[-1]) from None


#: The ``board.json`` that ``scet render --board`` writes beside its frames
#: (:mod:`scet_render.render.board`): its ``board`` object is read as the board.
RENDERED_FORMAT, RENDERED_VERSION = "scet-board-frames", 1


def _rendered_board(doc: Doc) -> BoardSpec:
    b = doc.obj("board")
    b.string("type", choices=("charuco",))
    sx, sy = b.integers("squares", 2, lo=3, hi=100)
    values = dict(squares_x=sx, squares_y=sy,
                  square_mm=1e3 * b.number("square_m", lo=1e-4, hi=1.0),
                  marker_mm=1e3 * b.number("marker_m", lo=1e-4, hi=1.0),
                  dictionary=b.string("dictionary", choices=DICTIONARIES))
    try:
        return BoardSpec(**values)
    except BoardError as exc:
        raise b.error(exc.key, str(exc).split(": ", 1)[-1]) from None


def read_board(path) -> BoardSpec:
    """Read a ``board.json``: a printed board's (:func:`write_board`, ``scet-board``) or that
    of rendered board frames (``scet-board-frames``, :data:`RENDERED_FORMAT`);
    :class:`BoardError` naming the file and the key for anything malformed."""
    data = read_json(path, BoardError)
    if isinstance(data, dict) and data.get("format") == RENDERED_FORMAT:
        check_format(data, path, RENDERED_FORMAT, RENDERED_VERSION, BoardError)
        return _rendered_board(Doc(data, path, "", BoardError))
    check_format(data, path, BOARD_FORMAT, BOARD_VERSION, BoardError)
    return board_from_doc(Doc(data, path, "", BoardError))
