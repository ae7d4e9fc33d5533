"""Scene files: one versioned TOML format, loaded into an immutable :class:`~estimator.setup.Setup`.

The format is documented key by key in ``docs/formats/scene.md``; ``scenes/paper_sim.toml`` is the
commented reference. Quantities carry their unit in the key name (``exposure_ms``,
``position_m``, ``span_deg``); each quantity accepts the units listed in :data:`UNITS` and
must be given exactly once. Every problem raises :class:`~estimator.errors.SceneError` naming
the file, the key and what was expected; nothing else escapes :func:`load_scene`.
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SceneError
from .eye import (
    ASPHERICITY_MAX,
    ASPHERICITY_MIN,
    BOHME_CORNEA_OFFSET_M,
    BOHME_CORNEA_RADIUS_M,
    BOHME_LIMBUS_DEPTH_M,
    PUPIL_DIAMETER_M,
    Eye,
)
from .eyelids import read_eyelids
from .geometry import Camera, RigidPose, look_at_rotation, rotation_from_vector, rotation_matrix
from .lens_keys import read_lens
from .scene_checks import check_geometry
from .scene_wire import read_arc_frame, read_wire_mirror
from .setup import DistanceSensor, LightGroup, LightRig, Screen, Sensor, Setup, Strobe

FORMAT = "scet-scene"
VERSION = 1
DEFAULT_SCENE = "paper_sim"

#: Accepted unit suffixes and their factor to SI.
UNITS = {
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3},
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0},
}

# Sanity ranges in SI units: values outside are almost always a unit mistake.
#: No number in a scene may exceed this in magnitude: squares of larger values (vector
#: lengths) overflow, and nothing in an eye-tracking scene is within orders of magnitude of it.
_MAX_ABS = 1e100
#: Positions must lie within this distance of the origin (m): an eye tracker fits on a desk.
_MAX_POSITION_M = 100.0


class _Table:
    """A TOML table being read: tracks which keys were used and reports the rest as unknown."""

    def __init__(self, data: Any, key: str, path: str):
        if not isinstance(data, dict):
            raise SceneError(f"expected a table, got {type(data).__name__}", path=path, key=key or None)
        self.data, self.key, self.path, self.used = data, key, path, set()

    def _full(self, name: str) -> str:
        return f"{self.key}.{name}" if self.key else name

    def error(self, name: str, message: str) -> SceneError:
        return SceneError(message, path=self.path, key=self._full(name))

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, default=None, required=True):
        if name not in self.data:
            if required:
                raise self.error(name, "missing required key")
            return default
        self.used.add(name)
        return self.data[name]

    def table(self, name: str, required=True) -> "_Table | None":
        value = self.raw(name, required=required)
        if value is None:
            return None
        return _Table(value, self._full(name), self.path)

    def string(self, name: str, default=None, required=True, choices=None) -> str:
        value = self.raw(name, default, required)
        if not isinstance(value, str):
            raise self.error(name, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(name, f"expected one of {sorted(choices)}, got {value!r}")
        return value

    def integer(self, name: str, default=None, required=True, minimum=None, maximum=None) -> int:
        value = self.raw(name, default, required)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(name, f"expected an integer >= {minimum}, got {value}")
        if maximum is not None and value > maximum:
            raise self.error(name, f"expected an integer <= {maximum}, got {value}")
        return value

    def number(self, name: str, default=None, required=True, lo=None, hi=None) -> float:
        value = self.raw(name, default, required)
        return self._check_number(name, value, lo, hi)

    def _check_number(self, name, value, lo=None, hi=None, unit_note="") -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(name, f"expected a number, got {value!r}")
        try:
            value = float(value)
        except OverflowError:
            raise self.error(name, "expected a finite number, got an integer too large for a float") from None
        if not math.isfinite(value) or abs(value) > _MAX_ABS:
            raise self.error(name, f"expected a finite number of magnitude below {_MAX_ABS:g}, got {value}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.error(name, f"expected a value in [{lo}, {hi}]{unit_note}, got {value}")
        return value

    def vector(self, name: str, length: int = 3, default=None, required=True) -> np.ndarray:
        value = self.raw(name, default, required)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise self.error(name, f"expected an array of {length} numbers, got {value!r}")
        return np.array([self._check_number(name, v) for v in value])

    def quantity(self, base: str, kind: str, *, shape=None, default=None, required=True,
                 lo=None, hi=None):
        """Read ``base_<unit>`` in SI units; exactly one accepted unit suffix must be present."""
        units = UNITS[kind]
        present = [u for u in units if f"{base}_{u}" in self.data]
        if len(present) > 1:
            keys = ", ".join(f"{base}_{u}" for u in present)
            raise self.error(base, f"given more than once ({keys}); keep one")
        if not present:
            wrong = [k for k in self.data if k.startswith(base + "_") and k not in self.used
                     and k[len(base) + 1:].isalpha()]
            accepted = ", ".join(f"{base}_{u}" for u in units)
            if wrong:
                raise self.error(wrong[0], f"unit '{wrong[0][len(base) + 1:]}' is not a {kind} "
                                           f"unit; write {accepted}")
            if base in self.data:
                raise self.error(base, f"needs a unit in its name: write {accepted}")
            if required:
                raise self.error(base, f"missing required key (one of {accepted})")
            return default
        key, factor = f"{base}_{present[0]}", units[present[0]]
        value = self.raw(key)
        note = f" {kind} in SI (after converting {key})"
        if shape is None:
            return self._ranged(key, value, factor, lo, hi, note)
        if not isinstance(value, (list, tuple)) or len(value) != shape:
            raise self.error(key, f"expected an array of {shape} numbers, got {value!r}")
        si = np.array([self._check_number(key, v) for v in value]) * factor
        if kind == "length" and np.abs(si).max() > _MAX_POSITION_M:
            raise self.error(key, f"expected coordinates within {_MAX_POSITION_M:g} m of the eye, got "
                                  f"{si.tolist()} m; check the unit in the key name")
        return si

    def _ranged(self, key, value, factor, lo, hi, note):
        si = self._check_number(key, value) * factor
        if (lo is not None and si < lo) or (hi is not None and si > hi):
            raise self.error(key, f"expected a value in [{lo}, {hi}]{note}, got {si:g}; "
                                  "check the unit in the key name")
        return si

    def finish(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise self.error(unknown[0], "unknown key" + (
                f" (also unknown: {', '.join(unknown[1:])})" if len(unknown) > 1 else ""))


def builtin_scenes() -> list[str]:
    """Names of the scene files shipped with the package."""
    return sorted(p.name[:-5] for p in resources.files("scet_scenes").iterdir()
                  if p.name.endswith(".toml"))


def resolve_scene(name_or_path: str | Path | None) -> Path:
    """A scene file path from a path or a built-in scene name (``None``: the default scene)."""
    if name_or_path is None:
        name_or_path = DEFAULT_SCENE
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    candidate = resources.files("scet_scenes") / f"{name_or_path}.toml"
    if candidate.is_file():
        return Path(str(candidate))
    raise SceneError(f"no such scene file, and not a built-in scene ({', '.join(builtin_scenes())})",
                     path=str(name_or_path))


def load_scene(name_or_path: str | Path | None = None) -> Setup:
    """Load a scene file (or a built-in scene by name) into a :class:`Setup`."""
    path = resolve_scene(name_or_path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"cannot read file: {exc.strerror or exc}", path=str(path)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"not UTF-8 text ({exc.reason} at byte {exc.start})", path=str(path)) from None
    return parse_scene(text, source=str(path))


def parse_scene(text: str, source: str = "<string>") -> Setup:
    """Parse scene TOML text into a :class:`Setup` (``source`` names it in errors)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise SceneError(f"not valid Unicode text ({exc.reason} at character {exc.start})", path=source) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"not valid TOML: {exc}", path=source) from None
    except (ValueError, RecursionError) as exc:  # deeply nested input, invalid characters
        raise SceneError(f"not valid TOML: {exc}", path=source) from None
    top = _Table(data, "", source)
    fmt = top.string("format")
    if fmt != FORMAT:
        raise top.error("format", f"expected '{FORMAT}', got {fmt!r}")
    version = top.integer("version")
    if version != VERSION:
        raise top.error("version", f"this SCET reads version {VERSION}, the file says {version}")
    name = top.string("name")
    description = top.string("description", "", required=False)
    eye = _read_eye(top.table("eye"))
    camera = _read_camera(top.table("camera"), eye)
    sensor = _read_sensor(top.table("sensor"), camera)
    strobe = _read_strobe(top.table("strobe"))
    screen = _read_screen(top.table("screen"))
    ds_table = top.table("distance_sensor", required=False)
    distance = _read_distance(ds_table) if ds_table is not None else None
    lights = _read_lights(top, eye)
    lid_table = top.table("eyelids", required=False)
    eyelids = read_eyelids(lid_table, eye, screen) if lid_table is not None else None
    appearance = _read_appearance(top)
    top.finish()
    setup = Setup(name=name, camera=camera, sensor=sensor, eye=eye, lights=lights, strobe=strobe,
                  screen=screen, distance_sensor=distance, description=description, source=source,
                  eyelids=eyelids, appearance=appearance,
                  source_sha256=hashlib.sha256(text.encode("utf-8")).hexdigest())
    check_geometry(setup, top)
    return setup


def _read_appearance(top: _Table) -> tuple | None:
    """The ``[appearance]`` table as sorted (key, value) pairs, its values checked to be numbers
    or booleans only; the renderer reads the keys (:mod:`scet_render.render.textures`)."""
    t = top.table("appearance", required=False)
    if t is None:
        return None
    for key, value in t.data.items():
        if not isinstance(value, (bool, int, float)):
            raise t.error(key, f"expected a number or a boolean, got {value!r}")
    return tuple(sorted(t.data.items()))


def _read_eye(t: _Table) -> Eye:
    center = t.quantity("rotation_center", "length", shape=3)
    r_c = t.quantity("cornea_radius", "length", lo=5e-3, hi=11e-3)
    s = r_c / BOHME_CORNEA_RADIUS_M
    offset = t.quantity("cornea_offset", "length", default=BOHME_CORNEA_OFFSET_M * s,
                        required=False, lo=0.0, hi=15e-3)
    limbus = t.quantity("limbus_depth", "length", default=BOHME_LIMBUS_DEPTH_M * s,
                        required=False, lo=0.5e-3, hi=r_c * 1.5)
    n = t.number("refractive_index", 1.376, required=False, lo=1.0, hi=2.0)
    q = t.number("cornea_asphericity", 0.0, required=False)
    if not ASPHERICITY_MIN < q <= ASPHERICITY_MAX:
        raise t.error("cornea_asphericity", f"expected a conic constant {ASPHERICITY_MIN:g} < Q <= "
                      f"{ASPHERICITY_MAX:g} (Q <= -1 is a paraboloid or hyperboloid, not a closed "
                      f"cornea; Q > 1 is flatter than any measured one), got {q:g}")
    if q != 0 and limbus >= r_c / (1.0 + q):
        raise t.error("cornea_asphericity", f"the limbus ({limbus * 1e3:.3f} mm behind the apex) "
                      f"must lie in front of the conic's equator ({r_c / (1 + q) * 1e3:.3f} mm)")
    pupil = _read_pupil(t, Eye(center, r_c, offset, limbus, n, q).limbus_radius_m)
    t.finish()
    return Eye(center, r_c, offset, limbus, n, q, pupil)


def _read_pupil(t: _Table, limbus_radius_m: float) -> float:
    """``pupil_diameter_mm`` (any length unit): > 0 and smaller than the iris, whose edge is the
    limbus circle."""
    d = t.quantity("pupil_diameter", "length", default=PUPIL_DIAMETER_M, required=False)
    key = next((f"pupil_diameter_{u}" for u in UNITS["length"] if t.has(f"pupil_diameter_{u}")),
               "pupil_diameter_mm")
    if d <= 0:
        raise t.error(key, f"expected a pupil diameter > 0, got {d * 1e3:g} mm")
    if d >= 2 * limbus_radius_m:
        raise t.error(key, f"the pupil ({d * 1e3:.3f} mm across) must be smaller than the iris "
                           f"(the limbus circle, {2 * limbus_radius_m * 1e3:.3f} mm across)")
    return d


def _read_camera(t: _Table, eye: Eye) -> Camera:
    position = t.quantity("position", "length", shape=3)
    res = t.vector("resolution_px", 2)
    if np.any(res != np.round(res)) or np.any(res < 1) or np.any(res > 20000):
        raise t.error("resolution_px", f"expected two positive integers (width, height), got {res}")
    width, height = int(res[0]), int(res[1])
    if t.has("focal_px") and (t.has("fx_px") or t.has("fy_px")):
        raise t.error("focal_px", "give either focal_px or fx_px and fy_px, not both")
    if t.has("fx_px") or t.has("fy_px"):
        fx = t.number("fx_px", lo=1.0, hi=1e6)
        fy = t.number("fy_px", lo=1.0, hi=1e6)
    else:
        fx = fy = t.number("focal_px", lo=1.0, hi=1e6)
    pp = t.vector("principal_point_px", 2, default=[(width - 1) / 2, (height - 1) / 2], required=False)
    if not (-0.5 <= pp[0] <= width - 0.5 and -0.5 <= pp[1] <= height - 0.5):
        raise t.error("principal_point_px", f"expected a point inside the {width}x{height} image, got {pp}")
    up = t.vector("up", 3, default=[0.0, 1.0, 0.0], required=False)
    ways = [k for k in ("look_at", "look_at_m", "rotation_deg", "rotation_rad") if t.has(k)]
    if len(ways) != 1:
        raise t.error("look_at", "give exactly one of look_at = \"cornea_apex\", look_at_m = [x, y, z] "
                                 "or rotation_deg = [rx, ry, rz] (world-to-camera rotation vector)"
                      + (f"; found {', '.join(ways)}" if ways else ""))
    try:
        if ways[0] == "look_at":
            t.string("look_at", choices={"cornea_apex"})
            R = look_at_rotation(position, eye.apex(), up)
        elif ways[0] == "look_at_m":
            R = look_at_rotation(position, t.quantity("look_at", "length", shape=3), up)
        else:
            R = rotation_from_vector(t.quantity("rotation", "angle", shape=3))
    except ValueError as exc:
        raise t.error(ways[0], str(exc)) from None
    lens = read_lens(t, fx)
    t.finish()
    try:
        camera = Camera(position, R, fx, fy, pp[0], pp[1], width, height)
    except ValueError as exc:
        raise t.error(ways[0], str(exc)) from None
    if lens is None:
        return camera
    try:
        return Camera(position, R, fx, fy, pp[0], pp[1], width, height, *lens)
    except ValueError as exc:  # the one lens check left to Camera: a folding distortion
        raise t.error("distortion", str(exc)) from None


def _read_sensor(t: _Table, camera: Camera) -> Sensor:
    total = t.integer("total_lines", minimum=1, maximum=100000)
    visible = t.integer("visible_lines", minimum=1, maximum=100000)
    if visible > total:
        raise t.error("visible_lines", f"expected at most total_lines ({total}), got {visible}")
    if visible != camera.height_px:
        raise t.error("visible_lines", f"expected the image height of camera.resolution_px "
                                       f"({camera.height_px}), got {visible}")
    period = t.quantity("frame_period", "time", lo=1e-4, hi=10.0)
    exposure = t.quantity("exposure", "time", lo=1e-7, hi=10.0)
    if exposure > period:
        raise t.error("exposure", f"exposure ({exposure:g} s) longer than the frame period ({period:g} s)")
    bits = t.integer("bit_depth", 10, required=False, minimum=1, maximum=16)
    black = t.number("black_level_dn", 16.0, required=False, lo=0.0, hi=2.0 ** bits - 1)
    t.finish()
    return Sensor(total, visible, period, exposure, bits, black)


def _read_strobe(t: _Table) -> Strobe:
    pulses = t.integer("pulses_per_frame", minimum=1, maximum=10000)
    pulse = t.quantity("pulse", "time", lo=1e-8, hi=10.0)
    period = t.quantity("period", "time", lo=1e-7, hi=10.0)
    if pulse > period:
        raise t.error("pulse", f"pulse ({pulse:g} s) longer than its period ({period:g} s)")
    phase = t.quantity("phase", "time", default=0.0, required=False, lo=-10.0, hi=10.0)
    t.finish()
    return Strobe(pulses, pulse, period, phase)


def _read_screen(t: _Table) -> Screen:
    xr = t.quantity("x_range", "length", shape=2)
    yr = t.quantity("y_range", "length", shape=2)
    z = t.quantity("z", "length", lo=-100.0, hi=100.0)
    for key, r in (("x_range", xr), ("y_range", yr)):
        if not r[0] < r[1]:
            raise t.error(key, f"expected [low, high] with low < high, got {list(r)}")
    if z >= 0:
        raise t.error("z", f"the screen must lie in front of the eye (z < 0, the eye looks along -z), got {z}")
    t.finish()
    return Screen((float(xr[0]), float(xr[1])), (float(yr[0]), float(yr[1])), float(z))


def _read_distance(t: _Table) -> DistanceSensor:
    gain = t.number("gain_per_m", 1e3, required=False, lo=1e-9, hi=1e12)
    sd = t.number("noise_sd", 8e-3, required=False, lo=0.0, hi=1e9)
    t.finish()
    return DistanceSensor(gain, sd)


def _read_pose(t: _Table | None, default_pivot) -> RigidPose:
    if t is None:
        return RigidPose()
    pivot = t.quantity("pivot", "length", shape=3, default=default_pivot, required=False)
    axis = t.vector("rotation_axis", 3, default=[0.0, 0.0, 1.0], required=False)
    angle = t.quantity("rotation", "angle", default=0.0, required=False, lo=-2 * math.pi, hi=2 * math.pi)
    shift = t.quantity("translation", "length", shape=3, default=np.zeros(3), required=False)
    if angle != 0.0 and np.linalg.norm(axis) == 0:
        raise t.error("rotation_axis", "expected a non-zero axis")
    t.finish()
    R = rotation_matrix(axis, angle) if angle != 0.0 else np.eye(3)
    return RigidPose(R, pivot - R @ pivot + shift)


def _unit(t: _Table, key: str, v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    if n == 0:
        raise t.error(key, "expected a non-zero direction")
    return v / n


def _read_lights(top: _Table, eye: Eye) -> LightRig:
    raw = top.raw("lights")
    if not isinstance(raw, list) or not raw:
        raise top.error("lights", "expected at least one [[lights]] group")
    groups = []
    for i, item in enumerate(raw):
        t = _Table(item, f"lights[{i}]", top.path)
        name = t.string("name", f"group{i}", required=False)
        kind = t.string("kind", choices={"arc", "grid", "list", "wire_mirror"})
        diameter = t.quantity("source_diameter", "length", default=None, required=False,
                              lo=1e-6, hi=10e-3)
        emitter = None
        if kind == "wire_mirror":
            emitter = read_wire_mirror(t)
            points, default_pivot = emitter.wire_axes_m, emitter.wire_axes_m[0]
            diameter = emitter.wire_diameter_m if diameter is None else diameter
        elif kind == "arc":
            count = t.integer("count", minimum=1, maximum=10000)
            radius, span, first, to_center, normal = read_arc_frame(t)
            center = first + radius * to_center
            u = -to_center  # from the centre to the first light
            v = np.cross(normal, u)
            a = span * np.arange(count) / max(count - 1, 1)
            points = center + radius * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
            default_pivot = first
        elif kind == "grid":
            rows = t.integer("rows", minimum=1, maximum=1000)
            cols = t.integer("cols", minimum=1, maximum=1000)
            side = t.quantity("side", "length", lo=1e-4, hi=1.0)
            center = t.quantity("center", "length", shape=3)
            normal = _unit(t, "normal", t.vector("normal"))
            u = t.vector("u_axis", 3, default=[1.0, 0.0, 0.0], required=False)
            u = u - (u @ normal) * normal
            if np.linalg.norm(u) < 1e-9:
                raise t.error("u_axis", "expected a direction not parallel to the normal")
            u = u / np.linalg.norm(u)
            v = np.cross(normal, u)
            xs = (np.arange(cols) - (cols - 1) / 2) * (side / max(cols - 1, 1))
            ys = (np.arange(rows) - (rows - 1) / 2) * (side / max(rows - 1, 1))
            X, Y = np.meshgrid(xs, ys)
            points = center + X.reshape(-1, 1) * u + Y.reshape(-1, 1) * v
            default_pivot = center
        else:
            pos = t.raw("positions_m") if t.has("positions_m") else None
            factor = 1.0
            if pos is None and t.has("positions_mm"):
                pos, factor = t.raw("positions_mm"), 1e-3
            if pos is None:
                raise t.error("positions_m", "missing required key (positions_m or positions_mm)")
            if not isinstance(pos, list) or not pos or not all(
                    isinstance(p, list) and len(p) == 3 for p in pos):
                raise t.error("positions_m", "expected a non-empty array of [x, y, z] arrays")
            points = np.array([[t._check_number("positions_m", v) for v in p] for p in pos]) * factor
            default_pivot = points[0]
        pose = _read_pose(t.table("pose", required=False), default_pivot)
        t.finish()
        diameter = 0.4e-3 if diameter is None else diameter
        groups.append(LightGroup(name, kind, points, pose, diameter / 2, emitter))
    return LightRig(tuple(groups))
