"""Ground-truth labels of a dataset (one line per strobe sample) and its EXR frames:
computing, writing and reading them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from estimator.banding import band_layout, strobe_instant
from estimator.checks import Doc, iter_json_lines
from estimator.inputs import MAX_FRAMES, MAX_FRAME_PX
from estimator.setup import Setup

from ..motion import Trajectory
from ..motion.pupil import pupil_diameters
from ..render import OCCLUDER_NAMES, occluder_names, pupil_image
from ..simulate import ground_truth_glints
from .format import FORMAT, LABELS_NAME, VERSION, DatasetError, StrobeLabel, _floats
from .manifest import read_manifest

# --------------------------------------------------------------------------- labels


def visible_bands(setup: Setup, frame: int) -> list:
    """The bands of ``frame`` that light visible rows (:func:`estimator.banding.band_layout`)."""
    return [b for b in band_layout(setup.sensor, setup.strobe, frame) if b.visible]


def frame_labels(setup: Setup, trajectory: Trajectory, frame: int, bands=None) -> list[dict]:
    """Ground truth of every strobe that lights visible rows of ``frame``.

    Parameters
    ----------
    setup : Setup
    trajectory : Trajectory
    frame : int
    bands : list of Band, optional
        The frame's :func:`visible_bands`, when the caller has them already.

    Returns
    -------
    list of dict
        One JSON-ready dict per strobe (keys as in the module docstring), by pulse index.
    """
    sensor, strobe = setup.sensor, setup.strobe
    N = sensor.visible_lines
    if bands is None:
        bands = visible_bands(setup, frame)
    if not bands:
        return []
    start_s = np.array([b.strobe_time_s for b in bands])
    time_s = strobe_instant(start_s, strobe.pulse_s)
    yaw, pitch = trajectory.angles_at(time_s)
    target = trajectory.target_at(time_s)
    glints, visible, center = ground_truth_glints(setup, yaw, pitch)
    glints = setup.camera.distort_px(glints)  # through the lens, as Camera.project (pinhole: as is)
    pupil = pupil_image(setup, yaw, pitch,
                        pupil_diameters(trajectory, time_s, setup.eye.pupil_diameter_m))
    lids = None
    if setup.eyelids is not None:
        closure = trajectory.lid_closure_at(time_s)
        occluder = _occluder(setup)
        lids = occluder.glints(yaw, pitch, closure)
        visible = visible & ~lids.hidden
        pupil_blocked = occluder.toward_camera(pitch, closure, pupil.surface_m)  # (m, 1 + E)
        edge_seen = np.isfinite(pupil.surface_m[:, 1:, 0]) & (pupil_blocked[:, 1:] == 0)
    out = []
    for i, b in enumerate(bands):
        full_start, full_stop = min(b.full_rows[0], N), min(b.full_rows[1], N)
        out.append({
            "frame": int(frame),
            "strobe": int(b.pulse_index),
            "time_s": float(time_s[i]),
            "pulse_start_s": float(start_s[i]),
            "first_row": int(b.first_row),
            "last_row": int(min(b.last_row, N - 1)),
            "full_rows": [int(full_start), int(max(full_start, full_stop))],
            "target_m": _floats(target[i]),
            "yaw_rad": float(yaw[i]),
            "pitch_rad": float(pitch[i]),
            "cornea_center_m": _floats(center[i]),
            "glints_px": [_floats(g) if np.all(np.isfinite(g)) else None for g in glints[i]],
            "glints_visible": [bool(v) for v in visible[i]],
            "pupil_center_px": (_floats(pupil.center_px[i]) if pupil.center_visible[i]
                                else None),
            "pupil_ellipse_px": (_floats(pupil.ellipse_px[i])
                                 if np.all(np.isfinite(pupil.ellipse_px[i])) else None),
            "pupil_diameter_mm": float(pupil.diameter_m[i] * 1e3),
        })
        if lids is not None:
            out[-1].update({
                "lid_closure": float(closure[i]),
                "glints_occluder": occluder_names(lids.occluder[i]),
                "glints_blocked_fraction": [float(f) for f in lids.blocked_fraction[i]],
                "pupil_occluder": OCCLUDER_NAMES[int(pupil_blocked[i, 0])],
                "pupil_edge_visible_fraction": float(edge_seen[i].mean()),
            })
    return out


_OCCLUDERS: dict = {}


def _occluder(setup: Setup):
    """One :class:`~scet_render.render.occlusion.LidOccluder` per Setup (its Mitsuba scenes)."""
    from ..render import LidOccluder

    key = id(setup)
    if key not in _OCCLUDERS or _OCCLUDERS[key][0] is not setup:
        _OCCLUDERS.clear()
        _OCCLUDERS[key] = (setup, LidOccluder(setup))
    return _OCCLUDERS[key][1]


@dataclass(frozen=True, slots=True)
class ExrFrame:
    """One ``frames/NNNNNN.exr`` file.

    Attributes
    ----------
    radiance : (H, W) float32
        Pulse-weighted linear radiance, as rendered.
    frame : int
    pulse_indices : (P,) int64
        Pulses rendered into the frame.
    strobe_times_s : (P,) float
        Their instants (pulse centres).
    scene_sha256 : str
    """

    radiance: np.ndarray
    frame: int
    pulse_indices: np.ndarray
    strobe_times_s: np.ndarray
    scene_sha256: str


def read_exr(path, size_px: tuple[int, int] | None = None) -> ExrFrame:
    """Read a dataset frame's EXR file, checking its format and version attributes.

    The header's data window is checked before the pixels are read: it must be ``size_px``
    (W, H) when given, and at most :data:`estimator.inputs.MAX_FRAME_PX` pixels.

    Raises
    ------
    DatasetError
        Unreadable, not written by this module, another version, or no "Y" channel.
    """
    import OpenEXR

    path = Path(path)
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            (x0, y0), (x1, y1) = (np.asarray(c, dtype=np.int64) for c in exr.header()["dataWindow"])
        width, height = int(x1 - x0 + 1), int(y1 - y0 + 1)
        if size_px is not None and (width, height) != tuple(size_px):
            raise DatasetError(f"{path}: frame size {width}x{height} px in its EXR header, the "
                               f"dataset's is {size_px[0]}x{size_px[1]}")
        if not (0 < width and 0 < height and width * height <= MAX_FRAME_PX):
            raise DatasetError(f"{path}: frame size {width}x{height} px in its EXR header, more "
                               f"than SCET reads ({MAX_FRAME_PX} px)")
        with OpenEXR.File(str(path)) as exr:
            # The binding empties its header dict when the file closes: copy what we need.
            header, channels = dict(exr.header()), exr.channels()
            names = sorted(channels)
            radiance = np.array(channels["Y"].pixels, copy=True) if "Y" in channels else None
    except (OSError, RuntimeError, KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, DatasetError):
            raise
        raise DatasetError(f"{path}: cannot read the EXR file ({exc})") from None
    if header.get("scet_format") != FORMAT or header.get("scet_version") != VERSION:
        raise DatasetError(f"{path}: expected {FORMAT} version {VERSION} attributes, got "
                           f"{header.get('scet_format')!r} version {header.get('scet_version')!r}")
    if radiance is None or radiance.dtype != np.float32 or radiance.ndim != 2:
        raise DatasetError(f"{path}: expected one float32 channel 'Y', got {names}")
    try:
        pulses = np.array(json.loads(header["scet_pulse_indices"]), dtype=np.int64)
        times = np.array(json.loads(header["scet_strobe_times_s"]), dtype=np.float64)
        frame, sha = int(header["scet_frame"]), str(header["scet_scene_sha256"])
    except (KeyError, TypeError, ValueError, RecursionError) as exc:
        raise DatasetError(f"{path}: malformed SCET header attributes ({exc!r})") from None
    if pulses.shape != times.shape or pulses.ndim != 1:
        raise DatasetError(f"{path}: scet_pulse_indices and scet_strobe_times_s differ in length")
    return ExrFrame(radiance, frame, pulses, times, sha)


def iter_labels(path) -> Iterator[StrobeLabel]:
    """Iterate over the strobe labels of a finished dataset, in file order.

    Parameters
    ----------
    path : str or Path
        The dataset folder.

    Yields
    ------
    StrobeLabel

    Raises
    ------
    DatasetError
        Not a dataset of this format and version, unfinished (no labels file), or a malformed
        line (the message names the line).
    """
    path = Path(path)
    read_manifest(path)
    file = path / LABELS_NAME
    if not file.is_file():
        raise DatasetError(f"{file}: missing; the run that writes this dataset did not finish "
                           "(rerun render_dataset with the same arguments to complete it)")
    for where, data in iter_json_lines(file, DatasetError):
        yield _label(Doc(data, where, error=DatasetError))


#: Bounds of a label's fields: positions (m) as in scene files, times (s), pixels and rows.
_POSITION_M, _TIME_S, _PIXEL, _ROWS = 100.0, 1e9, 1e7, 10 ** 6


def _label(d: Doc) -> StrobeLabel:
    glints = d.array("glints_px", (None, 2), lo=-_PIXEL, hi=_PIXEL, allow_null=True)
    visible = np.array(d.booleans("glints_visible"), dtype=bool)
    if visible.shape != (glints.shape[0],):
        raise d.error("glints_visible", f"{visible.size} entries for {glints.shape[0]} glints_px")
    first, last = d.integer("first_row", lo=0, hi=_ROWS), d.integer("last_row", lo=0, hi=_ROWS)
    return StrobeLabel(
        frame=d.integer("frame", lo=0, hi=MAX_FRAMES), strobe=d.integer("strobe"),
        time_s=d.number("time_s", lo=-_TIME_S, hi=_TIME_S),
        pulse_start_s=d.number("pulse_start_s", lo=-_TIME_S, hi=_TIME_S), first_row=first,
        last_row=last, full_rows=tuple(d.integers("full_rows", 2, lo=0, hi=_ROWS)),
        target_m=d.array("target_m", (3,), lo=-_POSITION_M, hi=_POSITION_M),
        yaw_rad=d.number("yaw_rad", lo=-math.pi, hi=math.pi),
        pitch_rad=d.number("pitch_rad", lo=-math.pi, hi=math.pi),
        cornea_center_m=d.array("cornea_center_m", (3,), lo=-_POSITION_M, hi=_POSITION_M),
        glints_px=glints, glints_visible=visible, **_lid_fields(d, glints.shape[0]),
        **_pupil_fields(d))


def _pupil_fields(d: Doc) -> dict:
    """The pupil fields of a label (absent from datasets written before they existed)."""
    if not d.has("pupil_diameter_mm"):
        return {}
    out = {"pupil_diameter_mm": d.number("pupil_diameter_mm", lo=0.0, hi=100.0)}
    for name, n in (("pupil_center_px", 2), ("pupil_ellipse_px", 5)):
        # null: not seen (its ray misses the cap, or part of the edge is hidden).
        out[name] = (np.full(n, np.nan) if d.data.get(name, 0) is None
                     else d.array(name, (n,), lo=-_PIXEL, hi=_PIXEL))
    return out


def _lid_fields(d: Doc, n: int) -> dict:
    """The optional lid fields of a label (written for scenes with moving lids only)."""
    if not d.has("glints_occluder"):
        return {}
    names = d.data["glints_occluder"]
    if not (isinstance(names, list) and len(names) == n
            and all(isinstance(x, str) and x in OCCLUDER_NAMES for x in names)):
        raise d.error("glints_occluder", f"expected {n} names from {list(OCCLUDER_NAMES)}")
    fraction = d.array("glints_blocked_fraction", (n,), lo=0.0, hi=1.0)
    out = {"lid_closure": d.number("lid_closure", lo=0.0, hi=1.0),
           "glints_occluder": tuple(names), "glints_blocked_fraction": fraction}
    if d.has("pupil_occluder"):  # absent from datasets written before the pupil's occlusion
        pupil = d.data["pupil_occluder"]
        if not (isinstance(pupil, str) and pupil in OCCLUDER_NAMES):
            raise d.error("pupil_occluder", f"expected one of {list(OCCLUDER_NAMES)}")
        out["pupil_occluder"] = pupil
        out["pupil_edge_visible_fraction"] = d.number("pupil_edge_visible_fraction",
                                                      lo=0.0, hi=1.0)
    return out
