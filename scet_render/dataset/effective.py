"""The effective scene: the scene TOML a setup was rendered with, after every override made in
code (a scaled-down camera, a planned strobe, single-pulse calibration timing, lids left out).

A dataset records it in ``manifest.json`` (``scene.toml``) and a folder of calibration frames
in ``scene.toml`` (:data:`SCENE_NAME`), so that ``scet calibrate``, ``scet track``,
``scet compare`` and ``scet score`` can take the scene from the folder itself
(:mod:`scet_render.cli_scene`).

The text is the scene file's own text with the overridden keys rewritten in place (each marked
``# overridden``), comments and all other keys kept, and a header comment naming the tables
that changed. Values are written in SI units with Python's shortest round-trip ``repr``, so
the text parses back to a setup equal to the rendered one field for field, bit for bit; that is
checked on every call (:func:`effective_scene_text`). What a scene file cannot say this way
(lights or a camera pose changed in code, as the foreign captures of the tests do on purpose)
stays as the file has it, and the fields that still differ are returned (and recorded by the
manifest as ``scene.differs``, so that readers can warn).
"""

from __future__ import annotations

import logging
import math
import numbers
import re
from dataclasses import fields, is_dataclass
from enum import Enum
from pathlib import Path
from typing import NamedTuple

import numpy as np

from estimator.errors import SceneError
from estimator.scene import parse_scene
from estimator.setup import Setup

__all__ = ["SCENE_NAME", "DIFFERS_MARK", "EffectiveScene", "effective_scene_text",
           "setup_differences", "plain_value"]

log = logging.getLogger(__name__)

#: A folder's effective scene beside its frames (calibration frames carry no manifest).
SCENE_NAME = "scene.toml"
#: First line of a ``scene.toml`` that differs from its frames: the fields follow.
DIFFERS_MARK = "# scet: this scene differs from the frames in"

#: Setup fields that describe where the setup came from, not what it is.
_PROVENANCE = ("source", "source_sha256")

class EffectiveScene(NamedTuple):
    """The result of :func:`effective_scene_text`.

    Attributes
    ----------
    text : str
        The scene TOML.
    overridden : list of str
        Setup fields whose keys were rewritten (``camera``, ``sensor``, ``strobe``, ``eye``,
        ``eyelids``, ``appearance``); empty where the text was already exact.
    differs : list of str
        Setup fields in which ``text`` still differs from the setup (empty: exact).
    """

    text: str
    overridden: list
    differs: list


#: Setup fields added after datasets were first written, with the value that reproduces the
#: older setups: a field at that value is left out of the fingerprint, so that datasets
#: rendered before it existed (byte-identical frames) still resume and compare equal.
_LATER_FIELDS = {("Eye", "cornea_asphericity"): 0.0, ("Setup", "eyelids"): None,
                 ("Eye", "pupil_diameter_m"): 4.0e-3,
                 ("Camera", "distortion"): (), ("Camera", "f_number"): None,
                 ("Camera", "focus_distance_m"): None, ("Camera", "pixel_pitch_m"): None,
                 ("Setup", "appearance"): None, ("LightGroup", "emitter"): None}


def _at_older_value(obj, name: str) -> bool:
    key = (type(obj).__name__, name)
    if key not in _LATER_FIELDS:
        return False
    value = getattr(obj, name)
    if isinstance(value, np.ndarray):  # the pinhole's empty distortion
        return value.size == 0 and _LATER_FIELDS[key] == ()
    return value == _LATER_FIELDS[key]


def plain_value(x):
    """A JSON-able exact image of a setup value (dataclasses field by field, arrays and floats
    as hex), for fingerprints and exact comparisons; ``source`` fields and fields at their
    older value (:data:`_LATER_FIELDS`) are left out."""
    if is_dataclass(x):
        return {f.name: plain_value(getattr(x, f.name)) for f in fields(x) if f.name != "source"
                and not _at_older_value(x, f.name)}
    if isinstance(x, np.ndarray):
        return {"shape": list(x.shape), "data": [float(v).hex() for v in x.ravel()]}
    if isinstance(x, (tuple, list)):
        return [plain_value(v) for v in x]
    if isinstance(x, Enum):
        return x.name
    if isinstance(x, (bool, str, type(None))):
        return x
    if isinstance(x, numbers.Integral):
        return int(x)
    if isinstance(x, numbers.Real):
        return float(x).hex()
    raise TypeError(f"cannot fingerprint a {type(x).__name__} in the setup")


_HEADER = re.compile(r"^\s*\[\[?\s*([A-Za-z_][A-Za-z0-9_.\-]*)\s*\]\]?\s*(#.*)?$")


def setup_differences(a: Setup, b: Setup) -> list[str]:
    """The top-level fields (``camera``, ``sensor``, ``strobe``, ...) in which two setups differ,
    compared exactly (arrays and floats bit for bit); ``source`` and ``source_sha256`` are
    not compared."""
    return [name for name in type(a).__dataclass_fields__ if name not in _PROVENANCE
            and plain_value(getattr(a, name)) != plain_value(getattr(b, name))]


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # shortest text that reads back to the same float
    return "[" + ", ".join(_toml_value(x.item() if hasattr(x, "item") else x) for x in v) + "]"


def _sections(lines: list[str], table: str) -> list[tuple[int, int]]:
    """[start, stop) line ranges of ``[table]`` and its sub-tables (the header line included)."""
    out, start = [], None
    for i, line in enumerate(lines):
        m = _HEADER.match(line)
        if m is None:
            continue
        if start is not None:
            out.append((start, i))
            start = None
        name = m.group(1)
        if name == table or name.startswith(table + "."):
            start = i
    if start is not None:
        out.append((start, len(lines)))
    return out


def _changed(old, new, keys: dict[str, tuple[str, ...]]) -> tuple[dict, tuple[str, ...]]:
    """The keys to write (name -> value) for the fields of ``new`` that differ from ``old``,
    and the key bases they replace. ``keys``: field -> (key written, bases replaced...)."""
    values, replaced = {}, ()
    for name, (key, *bases) in keys.items():
        if plain_value(getattr(old, name)) != plain_value(getattr(new, name)):
            values[key] = getattr(new, name)
            replaced += tuple(bases)
    return values, replaced


def _rewrite(lines: list[str], table: str, values: dict[str, object],
             replaced: tuple[str, ...]) -> list[str]:
    """Drop the keys of ``[table]`` named in ``replaced`` (any unit suffix) and write
    ``values`` in their place (or under the header)."""
    spans = [s for s in _sections(lines, table) if _HEADER.match(lines[s[0]]).group(1) == table]
    if len(spans) != 1:
        raise ValueError(f"the scene text has {len(spans)} [{table}] tables, expected one")
    start, stop = spans[0]
    pattern = re.compile(r"^\s*(" + "|".join(re.escape(k) for k in replaced)
                         + r")(_[a-z]+)?\s*=")
    body = lines[start + 1:stop]
    hits = [i for i, line in enumerate(body) if pattern.match(line)]
    at = hits[0] if hits else 0
    kept = [line for i, line in enumerate(body) if i not in set(hits)]
    at -= sum(1 for i in hits if i < at)
    new = [f"{key} = {_toml_value(v)}  # overridden" for key, v in values.items()]
    if not new and (not replaced or not hits):  # nothing to write, nothing to drop
        return lines
    return lines[:start + 1] + kept[:at] + new + kept[at:] + lines[stop:]


def _lens_values(cam) -> dict:
    """The ``[camera]`` lens keys that load into exactly ``cam``'s lens."""
    values = {}
    if cam.has_distortion:
        values["distortion"] = [float(v) for v in cam.distortion]
    if cam.f_number is not None:
        values["f_number"] = cam.f_number
        values["focus_distance_m"] = cam.focus_distance_m
    if cam.pixel_pitch_m is not None:
        um = cam.pixel_pitch_m * 1e6  # the loader multiplies by 1e-6: find the float it maps back
        for _ in range(8):
            if um * 1e-6 == cam.pixel_pitch_m:
                break
            um = math.nextafter(um, math.inf if um * 1e-6 < cam.pixel_pitch_m else -math.inf)
        values["pixel_pitch_um"] = um
    return values


def _drop_table(lines: list[str], table: str) -> list[str]:
    for start, stop in reversed(_sections(lines, table)):
        del lines[start:stop]
    return lines


def effective_scene_text(setup: Setup, text: str) -> EffectiveScene:
    """The scene text that loads into exactly ``setup``, as far as a scene file can say it.

    Parameters
    ----------
    setup : Setup
        The setup rendered (possibly changed in code after loading).
    text : str
        The scene TOML it was loaded from.

    Returns
    -------
    EffectiveScene
        ``text`` itself where it already loads into ``setup``; otherwise ``text`` with the
        overridden keys rewritten (see the module docstring), and the fields a scene file
        cannot carry this way (``differs``, logged as a warning).

    Raises
    ------
    SceneError
        ``text`` is not a valid scene.
    """
    base = parse_scene(text, source="<scene text>")
    diffs = setup_differences(base, setup)
    if not diffs:
        return EffectiveScene(text, [], [])
    lines = text.splitlines()
    cam = setup.camera
    rewritable = [d for d in diffs if d in ("camera", "sensor", "strobe", "eye", "appearance")
                  or (d == "eyelids" and setup.eyelids is None)]
    if "camera" in rewritable:
        c0 = base.camera
        values = {}
        if (c0.width_px, c0.height_px) != (cam.width_px, cam.height_px):
            values["resolution_px"] = [cam.width_px, cam.height_px]
        if (c0.fx_px, c0.fy_px) != (cam.fx_px, cam.fy_px):
            values.update({"focal_px": cam.fx_px} if cam.fx_px == cam.fy_px
                          else {"fx_px": cam.fx_px, "fy_px": cam.fy_px})
        if (c0.cx_px, c0.cy_px) != (cam.cx_px, cam.cy_px):
            values["principal_point_px"] = [cam.cx_px, cam.cy_px]
        replaced = tuple(k for k in values if k != "focal_px") + (
            ("focal_px", "fx_px", "fy_px") if {"focal_px", "fx_px"} & set(values) else ())
        lens = [(c.distortion, c.f_number, c.focus_distance_m, c.pixel_pitch_m) for c in (c0, cam)]
        if plain_value(lens[0]) != plain_value(lens[1]):
            replaced += ("distortion", "f_number", "focus_distance", "pixel_pitch")
            values.update(_lens_values(cam))
        lines = _rewrite(lines, "camera", values, replaced)
    tables = {
        "sensor": {"total_lines": ("total_lines", "total_lines"),
                   "visible_lines": ("visible_lines", "visible_lines"),
                   "frame_period_s": ("frame_period_s", "frame_period"),
                   "exposure_s": ("exposure_s", "exposure"),
                   "bit_depth": ("bit_depth", "bit_depth"),
                   "black_level_dn": ("black_level_dn", "black_level_dn")},
        "strobe": {"pulses_per_frame": ("pulses_per_frame", "pulses_per_frame"),
                   "pulse_s": ("pulse_s", "pulse"), "period_s": ("period_s", "period"),
                   "phase_s": ("phase_s", "phase")},
        "eye": {"rotation_center_m": ("rotation_center_m", "rotation_center"),
                "cornea_radius_m": ("cornea_radius_m", "cornea_radius"),
                "cornea_offset_m": ("cornea_offset_m", "cornea_offset"),
                "limbus_depth_m": ("limbus_depth_m", "limbus_depth"),
                "refractive_index": ("refractive_index", "refractive_index"),
                "cornea_asphericity": ("cornea_asphericity", "cornea_asphericity"),
                "pupil_diameter_m": ("pupil_diameter_m", "pupil_diameter")},
    }
    for table, keys in tables.items():
        if table in rewritable:
            values, replaced = _changed(getattr(base, table), getattr(setup, table), keys)
            lines = _rewrite(lines, table, values, replaced)
    if "eyelids" in rewritable:
        lines = _drop_table(lines, "eyelids")
    if "appearance" in rewritable:  # the renderer's table, set in code: written whole
        lines = _drop_table(lines, "appearance")
        if setup.appearance is not None:
            lines += ["", "[appearance]  # overridden"] + [
                f"{k} = {_toml_value(v)}" for k, v in setup.appearance]
    out = "\n".join(lines) + "\n"
    try:
        left = setup_differences(parse_scene(out, source="<effective scene>"), setup)
    except SceneError as exc:  # e.g. a rewritten camera that no longer sees the cornea
        log.warning("setup %r: the rewritten scene text does not load (%s); recording the "
                    "scene file as it is", setup.name, exc)
        return EffectiveScene(text, [], diffs)
    overridden = [d for d in rewritable if d not in left]
    if left:
        log.warning("setup %r differs from its scene text in %s, which a scene file does not "
                    "carry as rewritten keys; recorded as scene.differs", setup.name, left)
    if not overridden:
        return EffectiveScene(text, [], diffs)
    note = [f"# The effective scene of these frames: {setup.name}"
            f"{' (' + Path(setup.source).name + ')' if setup.source else ''} with "
            f"{', '.join(overridden)} overridden in code;",
            "# the keys marked 'overridden' hold the values rendered."]
    return EffectiveScene("\n".join(note) + "\n" + out, overridden, left)
