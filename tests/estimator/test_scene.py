"""Tests of the scene loader (:mod:`estimator.scene`): the shipped scenes and bad scene files.

The shipped scenes must load into a :class:`~estimator.setup.Setup` with the numbers the SCET
paper gives (Fig. 3, Secs. 3, 3.1, 3.4, 4.2). A bad scene file must raise
:class:`~estimator.errors.SceneError` whose message names the file, the dotted key and what was
expected, and no input at all may raise anything else (fuzzed with hypothesis at the text, byte
and structure level).
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator.errors import SceneError
from estimator.scene import builtin_scenes, load_scene, parse_scene
from estimator.setup import Setup
from tests.estimator.hostile_json import parent_of, tree_nodes

SCENES_DIR = Path(__file__).resolve().parents[2] / "scenes"
PAPER_SIM = (SCENES_DIR / "paper_sim.toml").read_text(encoding="utf-8")
PAPER_SIM_DICT = tomllib.loads(PAPER_SIM)
SOURCE = "bad_scene.toml"

# --------------------------------------------------------------------------- tolerances
#: Positions typed in the file in metres come out after at most a multiplication by a unit
#: factor: 1e-15 m is ~1e2 ulp of 0.7 m (the screen distance).
TYPED_LENGTH_TOL_M = 1e-15
#: Light positions computed through a rotation about a pivot (and, for the checks, an SVD and a
#: circle fit) on values of ~0.05 m: float64 rounding is ~1e-17 m per step; 1e-12 m is the
#: issue's coplanarity bound and a millionth of the 0.4 mm source radius.
COMPUTED_LENGTH_TOL_M = 1e-12
#: Angles derived from those positions (rad): 1e-12 m over a 33 mm radius is 3e-11 rad.
ANGLE_TOL_RAD = 1e-9
#: Times given in ms or us in the file, converted to seconds by one multiplication: 1 ulp.
TIME_REL_TOL = 1e-12


# --------------------------------------------------------------------------- helpers
def toml_key(key: str) -> str:
    if re.fullmatch(r"[A-Za-z0-9_-]+", key):
        return key
    return toml_value(key)


def toml_value(value) -> str:
    """A tiny TOML writer: scalars, arrays and (inline) tables, enough for any parsed scene."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)  # '1e+308', '5e-324', '-0.0': all valid TOML floats
    if isinstance(value, str):
        out = []
        for ch in value:
            if ch in '"\\':
                out.append("\\" + ch)
            elif ord(ch) < 0x20 or ord(ch) == 0x7F:
                out.append(f"\\u{ord(ch):04x}")
            else:
                out.append(ch)
        return '"' + "".join(out) + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


def to_toml(document: dict) -> str:
    """A whole document, one top-level key per line (tables inline)."""
    return "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in document.items())


def scene_dict() -> dict:
    """A fresh, mutable copy of paper_sim.toml as parsed by tomllib."""
    return tomllib.loads(PAPER_SIM)


def edited(old: str, new: str, count: int = 1) -> str:
    """paper_sim.toml with ``old`` replaced by ``new`` (``old`` must occur ``count`` times)."""
    assert PAPER_SIM.count(old) == count, f"{old!r} occurs {PAPER_SIM.count(old)} times in paper_sim.toml"
    return PAPER_SIM.replace(old, new)


def expect_scene_error(text: str, key: str | None, *words: str, source: str = SOURCE) -> SceneError:
    """Parse ``text`` and check the SceneError names the source, ``key`` and every word."""
    with pytest.raises(SceneError) as info:
        parse_scene(text, source=source)
    err, msg = info.value, str(info.value)
    assert err.path == source and source in msg, msg
    if key is not None:
        assert err.key == key, msg
        assert f"key '{key}'" in msg, msg
    for word in words:
        assert word.lower() in msg.lower(), f"{word!r} not in {msg!r}"
    return err


def circle_fit(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre, radius and unit plane normal of (n, 3) points lying on a circle (Kasa fit)."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid)
    e1, e2, normal = vt
    x, y = (points - centroid) @ e1, (points - centroid) @ e2
    A = np.stack([2 * x, 2 * y, np.ones_like(x)], axis=1)
    (a, b, c), *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    return centroid + a * e1 + b * e2, math.sqrt(c + a * a + b * b), normal


def angle_to_xz_plane_deg(normal: np.ndarray) -> float:
    """Dihedral angle between a plane with unit ``normal`` and the horizontal x-z plane."""
    return math.degrees(math.acos(min(1.0, abs(float(normal[1])))))


def check_arc(points: np.ndarray, radius_m: float, span_deg: float, tilt_deg: float) -> None:
    """Points on one circular arc: common centre, equal steps, total span, plane tilt."""
    center, fitted_radius, normal = circle_fit(points)
    # Coplanar: every point on the fitted plane.
    assert np.abs((points - center) @ normal).max() < COMPUTED_LENGTH_TOL_M
    r = np.linalg.norm(points - center, axis=1)
    assert np.abs(r - radius_m).max() < COMPUTED_LENGTH_TOL_M
    assert abs(fitted_radius - radius_m) < COMPUTED_LENGTH_TOL_M
    spokes = points - center
    cross = np.cross(spokes[:-1], spokes[1:])
    steps = np.arctan2(np.linalg.norm(cross, axis=1), np.einsum("ij,ij->i", spokes[:-1], spokes[1:]))
    # One sense of rotation (an arc, not a zig-zag), equal steps, 90 degrees in all.
    turn = cross @ normal
    assert np.all(turn > 0) or np.all(turn < 0)
    expected_step = math.radians(span_deg) / (len(points) - 1)
    assert np.abs(steps - expected_step).max() < ANGLE_TOL_RAD
    assert abs(steps.sum() - math.radians(span_deg)) < ANGLE_TOL_RAD
    assert abs(angle_to_xz_plane_deg(normal) - tilt_deg) < math.degrees(ANGLE_TOL_RAD)


# --------------------------------------------------------------------------- shipped scenes
@pytest.fixture(scope="module")
def paper_sim() -> Setup:
    return load_scene("paper_sim")


def test_builtin_scenes_listed():
    assert {"paper_sim", "paper_sim_doubled", "lighting_grid", "prototype_ov5647"} <= set(builtin_scenes())


@pytest.mark.parametrize("name", ["paper_sim", "paper_sim_doubled", "lighting_grid", "prototype_ov5647"])
def test_shipped_scene_loads_by_name_and_path(name):
    by_name = load_scene(name)
    by_path = load_scene(SCENES_DIR / f"{name}.toml")
    assert isinstance(by_name, Setup) and by_name.name == name
    assert by_name.source_sha256 == by_path.source_sha256
    assert np.all(np.isfinite(by_name.lights_world_m))


def test_default_scene_is_paper_sim():
    assert load_scene(None).name == "paper_sim"


def test_paper_sim_camera(paper_sim):
    cam = paper_sim.camera
    assert np.allclose(cam.position_m, [0.012, -0.008, -0.030], rtol=0, atol=TYPED_LENGTH_TOL_M)
    assert cam.fx_px == cam.fy_px == 1300.0
    assert (cam.width_px, cam.height_px) == (640, 480)
    assert (cam.cx_px, cam.cy_px) == (319.5, 239.5)  # image centre, pixel-centre convention
    # "pointing to the eye apex": the apex projects to the principal point.
    apex_px, depth = cam.project(paper_sim.eye.apex())
    assert depth > 0 and np.allclose(apex_px, [319.5, 239.5], rtol=0, atol=1e-9)


def test_paper_sim_eye_and_screen(paper_sim):
    assert paper_sim.eye.cornea_radius_m == pytest.approx(7.8e-3, rel=0, abs=TYPED_LENGTH_TOL_M)
    assert np.array_equal(paper_sim.eye.rotation_center_m, [0.0, 0.0, 0.0])
    screen = paper_sim.screen
    assert screen.x_range_m == pytest.approx((-0.24, 0.24), rel=0, abs=TYPED_LENGTH_TOL_M)
    assert screen.y_range_m == pytest.approx((-0.20, 0.10), rel=0, abs=TYPED_LENGTH_TOL_M)
    assert screen.z_m == pytest.approx(-0.70, rel=0, abs=TYPED_LENGTH_TOL_M)


def test_paper_sim_lights_on_a_45_degree_arc(paper_sim):
    lights = paper_sim.lights_world_m
    assert lights.shape == (40, 3)
    assert np.allclose(lights[0], [-0.010, 0.020, -0.015], rtol=0, atol=COMPUTED_LENGTH_TOL_M)
    check_arc(lights, radius_m=33e-3, span_deg=90.0, tilt_deg=45.0)
    assert paper_sim.lights.groups[0].source_radius_m == pytest.approx(0.2e-3, rel=TIME_REL_TOL)


def test_paper_sim_doubled_second_arc_at_64_degrees():
    setup = load_scene("paper_sim_doubled")
    lights, group = setup.lights_world_m, setup.lights.group_index
    assert lights.shape == (80, 3) and np.bincount(group).tolist() == [40, 40]
    check_arc(lights[group == 0], radius_m=33e-3, span_deg=90.0, tilt_deg=45.0)
    check_arc(lights[group == 1], radius_m=33e-3, span_deg=90.0, tilt_deg=64.0)
    # Both copies start at G.
    assert np.allclose(lights[group == 1][0], [-0.010, 0.020, -0.015], rtol=0, atol=COMPUTED_LENGTH_TOL_M)


def test_lighting_grid_is_a_planar_6x6_grid_of_33_mm():
    setup = load_scene("lighting_grid")
    points = setup.lights_world_m
    assert points.shape == (36, 3)
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid)
    normal = vt[2]
    assert np.abs((points - centroid) @ normal).max() < COMPUTED_LENGTH_TOL_M  # coplanar
    # In-plane axes: columns run along world x projected onto the plane (the file's u_axis).
    u = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    for coords in ((points - centroid) @ u, (points - centroid) @ v):
        levels = np.sort(coords)
        # Six rows (columns) of six lights, each at one coordinate.
        rows = levels.reshape(6, 6)
        assert np.ptp(rows, axis=1).max() < COMPUTED_LENGTH_TOL_M
        values = rows.mean(axis=1)
        assert values[-1] - values[0] == pytest.approx(33e-3, rel=0, abs=COMPUTED_LENGTH_TOL_M)
        assert np.allclose(np.diff(values), 6.6e-3, rtol=0, atol=COMPUTED_LENGTH_TOL_M)
    assert np.allclose(centroid, [-0.008, 0.004, -0.035], rtol=0, atol=COMPUTED_LENGTH_TOL_M)


def test_prototype_ov5647_timing_and_wire():
    setup = load_scene("prototype_ov5647")
    sensor, strobe = setup.sensor, setup.strobe
    assert (sensor.total_lines, sensor.visible_lines) == (786, 480)
    assert sensor.frame_period_s == pytest.approx(16.636e-3, rel=TIME_REL_TOL)
    assert sensor.exposure_s == pytest.approx(1e-3, rel=TIME_REL_TOL)
    assert strobe.pulses_per_frame == 16
    assert strobe.pulse_s == pytest.approx(100e-6, rel=TIME_REL_TOL)
    assert strobe.period_s == pytest.approx(1039.75e-6, rel=TIME_REL_TOL)
    # 16 pulse periods fill one frame (16,636 ticks of the 16 MHz timer).
    assert 16 * strobe.period_s == pytest.approx(sensor.frame_period_s, rel=TIME_REL_TOL)
    assert setup.lights.count == 35
    assert setup.lights.groups[0].source_radius_m == pytest.approx(0.4e-3, rel=TIME_REL_TOL)
    # The turns of `scet hardware mirror`: on the wire's axis, half a wire (0.4 mm) inside the
    # mirror's 33 mm radius.
    check_arc(setup.lights_world_m, radius_m=33e-3 - 0.4e-3, span_deg=90.0, tilt_deg=45.0)


# --------------------------------------------------------------------------- bad scene files
def _drop(section: str, key: str) -> str:
    doc = scene_dict()
    target = doc["lights"][0] if section == "lights" else (doc if section == "" else doc[section])
    del target[key]
    return to_toml(doc)


def _set(section: str, key: str, value) -> str:
    doc = scene_dict()
    target = doc["lights"][0] if section == "lights" else (doc if section == "" else doc[section])
    target[key] = value
    return to_toml(doc)


def _light_list(positions_mm) -> str:
    doc = scene_dict()
    doc["lights"] = [{"name": "dots", "kind": "list", "positions_mm": positions_mm}]
    return to_toml(doc)


CAMERA_AT = "position_m = [0.012, -0.008, -0.030]"
AIM = 'look_at = "cornea_apex"'

BAD_SCENES = [
    # Unknown keys, at the top level, in a table and in a [[lights]] group.
    ("unknown top-level key", _set("", "colour", "red"), "colour", ["unknown key"]),
    ("unknown sensor key", edited("exposure_ms = 1.0", "exposure_ms = 1.0\ngain = 2.0"),
     "sensor.gain", ["unknown key"]),
    ("unknown light key", _set("lights", "colour", "red"), "lights[0].colour", ["unknown key"]),
    ("unknown pose key", edited("rotation_deg = -45.0", "rotation_deg = -45.0\nscale = 2.0"),
     "lights[0].pose.scale", ["unknown key"]),
    # Missing keys.
    ("missing focal", _drop("camera", "focal_px"), "camera.focal_px", ["missing"]),
    ("missing total_lines", _drop("sensor", "total_lines"), "sensor.total_lines", ["missing"]),
    ("missing count", _drop("lights", "count"), "lights[0].count", ["missing"]),
    ("missing exposure", _drop("sensor", "exposure_ms"), "sensor.exposure", ["missing", "exposure_ms"]),
    ("missing screen table", _drop("", "screen"), "screen", ["missing"]),
    ("missing lights", _drop("", "lights"), "lights", ["missing"]),
    ("missing format", _drop("", "format"), "format", ["missing"]),
    # Wrong types.
    ("string for a number", edited("exposure_ms = 1.0", 'exposure_ms = "1.0"'),
     "sensor.exposure_ms", ["expected a number"]),
    ("bool for a number", edited("exposure_ms = 1.0", "exposure_ms = true"),
     "sensor.exposure_ms", ["expected a number"]),
    ("float for an integer", edited("count = 40", "count = 40.0"), "lights[0].count", ["integer"]),
    ("bool for an integer", edited("total_lines = 786", "total_lines = true"),
     "sensor.total_lines", ["integer"]),
    ("string for a vector", edited(CAMERA_AT, 'position_m = "here"'), "camera.position_m", ["array of 3"]),
    ("short vector", edited(CAMERA_AT, "position_m = [0.012, -0.008]"), "camera.position_m", ["array of 3"]),
    ("bool in a vector", edited(CAMERA_AT, "position_m = [0.012, true, -0.03]"),
     "camera.position_m", ["expected a number"]),
    ("number for a string", edited('name = "paper_sim"', "name = 3"), "name", ["string"]),
    ("number for a table", _set("", "eye", 3), "eye", ["table"]),
    ("table for lights", _set("", "lights", {"kind": "arc"}), "lights", ["[[lights]]"]),
    ("unknown light kind", edited('kind = "arc"', 'kind = "spiral"'), "lights[0].kind", ["one of"]),
    ("fractional resolution", edited("resolution_px = [640, 480]", "resolution_px = [640.5, 480]"),
     "camera.resolution_px", ["integers"]),
    # Wrong or missing unit suffixes.
    ("time in ns", edited("exposure_ms = 1.0", "exposure_ns = 1.0"), "sensor.exposure_ns",
     ["unit 'ns'", "exposure_ms"]),
    ("time without unit", edited("exposure_ms = 1.0", "exposure = 1.0"), "sensor.exposure",
     ["unit", "exposure_ms"]),
    ("angle in mm", edited("span_deg = 90.0", "span_mm = 90.0"), "lights[0].span_mm",
     ["not a angle unit", "span_deg"]),
    ("length in inches", edited("radius_mm = 33.0", "radius_in = 1.3"), "lights[0].radius_in",
     ["length unit", "radius_mm"]),
    ("length without unit", edited("z_m = -0.700", "z = -0.700"), "screen.z", ["unit", "z_m"]),
    # The same quantity twice.
    ("exposure twice", edited("exposure_ms = 1.0", "exposure_ms = 1.0\nexposure_us = 1000.0"),
     "sensor.exposure", ["more than once", "exposure_ms", "exposure_us"]),
    ("radius twice", edited("radius_mm = 33.0", "radius_mm = 33.0\nradius_m = 0.033"),
     "lights[0].radius", ["more than once"]),
    ("focal twice", edited("focal_px = 1300.0", "focal_px = 1300.0\nfx_px = 1300.0\nfy_px = 1300.0"),
     "camera.focal_px", ["not both"]),
    # Non-finite numbers.
    ("nan exposure", edited("exposure_ms = 1.0", "exposure_ms = nan"), "sensor.exposure_ms", ["finite"]),
    ("inf exposure", edited("exposure_ms = 1.0", "exposure_ms = inf"), "sensor.exposure_ms", ["finite"]),
    ("-inf radius", edited("radius_mm = 33.0", "radius_mm = -inf"), "lights[0].radius_mm", ["finite"]),
    ("nan in position", edited(CAMERA_AT, "position_m = [0.012, nan, -0.030]"),
     "camera.position_m", ["finite"]),
    ("inf focal", edited("focal_px = 1300.0", "focal_px = inf"), "camera.focal_px", ["finite"]),
    ("nan refractive index", edited("refractive_index = 1.376", "refractive_index = nan"),
     "eye.refractive_index", ["finite"]),
    # Out of range: usually a unit mistake.
    ("cornea radius in metres under _mm", edited("cornea_radius_mm = 7.8", "cornea_radius_mm = 0.0078"),
     "eye.cornea_radius_mm", ["check the unit"]),
    ("frame period in us under _ms", edited("frame_period_ms = 16.636", "frame_period_ms = 16636.0"),
     "sensor.frame_period_ms", ["check the unit"]),
    ("arc radius in mm under _m", edited("radius_mm = 33.0", "radius_m = 33.0"),
     "lights[0].radius_m", ["check the unit"]),
    ("negative exposure", edited("exposure_ms = 1.0", "exposure_ms = -1.0"),
     "sensor.exposure_ms", ["expected a value in"]),
    ("zero lights in the arc", edited("count = 40", "count = 0"), "lights[0].count", [">= 1"]),
    ("screen behind the eye", edited("z_m = -0.700", "z_m = 0.700"), "screen.z", ["z < 0"]),
    ("empty screen range", edited("x_range_m = [-0.240, 0.240]", "x_range_m = [0.240, -0.240]"),
     "screen.x_range", ["low < high"]),
    # Impossible geometry.
    ("camera inside the eye", edited(CAMERA_AT, "position_m = [0.0, 0.0, -0.010]"),
     "camera.position_m", ["inside the eye"]),
    ("camera at the eye's centre", edited(CAMERA_AT, "position_m = [0.0, 0.0, 0.0]"),
     "camera.position_m", ["inside the eye"]),
    ("light inside the eye (list)", _light_list([[20.0, 20.0, -20.0], [0.0, 0.0, -12.0]]),
     "lights[0]", ["light 1", "inside the eye"]),
    ("light inside the eye (arc at G moved)",
     edited("[-0.010, 0.020, -0.015]", "[-0.005, 0.005, -0.008]", count=2),
     "lights[0]", ["inside the eye"]),
    ("camera looking away (look_at_m)", edited(AIM, "look_at_m = [0.012, -0.008, -0.5]"),
     "camera", ["cannot see the cornea"]),
    ("camera looking sideways (look_at_m)", edited(AIM, "look_at_m = [0.5, -0.008, -0.030]"),
     "camera", ["cannot see the cornea"]),
    ("camera looking along +z (rotation_deg)", edited(AIM, "rotation_deg = [0.0, 0.0, 0.0]"),
     "camera", ["cannot see the cornea"]),
    ("camera looking at itself", edited(AIM, "look_at_m = [0.012, -0.008, -0.030]"),
     "camera.look_at_m", ["coincides"]),
    ("two ways to aim the camera", edited(AIM, AIM + "\nrotation_deg = [0.0, 0.0, 0.0]"),
     "camera.look_at", ["exactly one", "rotation_deg"]),
    ("pulse longer than its period", edited("pulse_us = 100.0", "pulse_us = 2000.0"),
     "strobe.pulse", ["longer than its period"]),
    ("exposure longer than the frame", edited("exposure_ms = 1.0", "exposure_ms = 20.0"),
     "sensor.exposure", ["longer than the frame period"]),
    ("visible lines beyond total lines", edited("total_lines = 786", "total_lines = 400"),
     "sensor.visible_lines", ["at most total_lines"]),
    ("visible lines not the image height", edited("visible_lines = 480", "visible_lines = 470"),
     "sensor.visible_lines", ["image height"]),
    ("principal point outside the image",
     edited("focal_px = 1300.0", "focal_px = 1300.0\nprincipal_point_px = [700.0, 240.0]"),
     "camera.principal_point_px", ["inside the 640x480 image"]),
    ("zero arc normal", edited("normal = [0.0, 1.0, 0.0]", "normal = [0.0, 0.0, 0.0]"),
     "lights[0].normal", ["non-zero"]),
    ("arc normal not perpendicular", edited("normal = [0.0, 1.0, 0.0]", "normal = [0.0, 1.0, 1.0]"),
     "lights[0].normal", ["perpendicular"]),
    ("zero pose axis", edited("rotation_axis = [1.0, 0.0, 0.0]", "rotation_axis = [0.0, 0.0, 0.0]"),
     "lights[0].pose.rotation_axis", ["non-zero"]),
    # Format and version.
    ("wrong format", edited('format = "scet-scene"', 'format = "scet-scenes"'), "format", ["scet-scene"]),
    ("future version", edited("version = 1", "version = 2"), "version", ["version 1"]),
    ("version as a string", edited("version = 1", 'version = "1"'), "version", ["integer"]),
    # Not TOML at all: no key, but the file and the reason.
    ("unclosed table header", edited("[camera]", "[camera"), None, ["not valid TOML"]),
    ("duplicate key", edited("exposure_ms = 1.0", "exposure_ms = 1.0\nexposure_ms = 2.0"), None,
     ["not valid TOML"]),
    ("empty file", "", "format", ["missing"]),
]


@pytest.mark.parametrize("text, key, words", [pytest.param(t, k, w, id=i) for i, t, k, w in BAD_SCENES])
def test_bad_scene_raises_scene_error_naming_file_key_and_expectation(text, key, words):
    expect_scene_error(text, key, *words)


def test_the_edits_start_from_a_valid_scene():
    # Guards the table above: paper_sim.toml and its round trip through the test's TOML writer
    # load, so each error comes from the one edit.
    assert parse_scene(PAPER_SIM, SOURCE).lights.count == 40
    assert np.array_equal(parse_scene(to_toml(scene_dict()), SOURCE).lights_world_m,
                          load_scene("paper_sim").lights_world_m)


def test_camera_behind_the_eye_cannot_see_the_cornea():
    # Looking at the apex straight through the eyeball: the apex projects to the image centre,
    # but the cornea faces away from the camera (it looks along -z, the camera sits at +z).
    text = edited(CAMERA_AT, "position_m = [0.012, -0.008, 0.030]")
    expect_scene_error(text, "camera.position_m", "cannot see the cornea")


def test_camera_beside_the_eye_cannot_see_the_cornea():
    text = edited(CAMERA_AT, "position_m = [0.040, 0.0, 0.0]")
    expect_scene_error(text, "camera.position_m", "cannot see the cornea")


def test_huge_integer_for_a_number():
    # tomllib reads integers of any size; float() of 10**309 overflows.
    expect_scene_error(edited("exposure_ms = 1.0", f"exposure_ms = {10 ** 309}"), "sensor.exposure_ms")


def test_lone_surrogate_in_text():
    # A str that no UTF-8 file can hold, but parse_scene takes any str.
    expect_scene_error(PAPER_SIM + "# \ud800\n", None)


@pytest.mark.parametrize("old, new, key", [
    ("rotation_axis = [1.0, 0.0, 0.0]", "rotation_axis = [1e300, 0.0, 0.0]", "lights[0].pose.rotation_axis"),
    ("up = [0.0, 1.0, 0.0]", "up = [1e300, 1.0, 0.0]", "camera.up"),
    ("center_direction = [0.0, 0.0, -1.0]", "center_direction = [0.0, 0.0, -1e300]",
     "lights[0].center_direction"),
    ("normal = [0.0, 1.0, 0.0]", "normal = [0.0, 1e300, 0.0]", "lights[0].normal"),
    ("first_m = [-0.010, 0.020, -0.015]", "first_m = [-0.010, 0.020, 1e300]", "lights[0].first_m"),
], ids=["pose axis", "camera up", "arc centre direction", "arc normal", "arc first light"])
def test_huge_finite_vectors(old, new, key):
    # Finite but absurd: a 1e300 component overflows every norm (1e600). The loader must say
    # which key is wrong, not raise ValueError from geometry or Camera, warn about overflow, or
    # accept an arc collapsed onto one point or a line, or lights 1e299 m away.
    expect_scene_error(edited(old, new), key)


def test_non_utf8_file(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes(PAPER_SIM.encode("utf-8").replace(b"paper_sim", "papér_sim".encode("latin-1"), 1))
    with pytest.raises(SceneError, match="UTF-8") as info:
        load_scene(path)
    assert info.value.path == str(path) and str(path) in str(info.value)


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere.toml"
    with pytest.raises(SceneError, match="cannot read") as info:
        load_scene(path)
    assert info.value.path == str(path) and "nowhere.toml" in str(info.value)


def test_unknown_builtin_name():
    with pytest.raises(SceneError, match="not a built-in scene") as info:
        load_scene("no_such_scene")
    assert "no_such_scene" in str(info.value) and "paper_sim" in str(info.value)


def test_directory_instead_of_file(tmp_path):
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path)


def test_error_names_the_source_given_to_parse_scene():
    err = expect_scene_error(edited("exposure_ms = 1.0", "exposure_ms = nan"), "sensor.exposure_ms",
                             source="/some/where/my_rig.toml")
    assert str(err).startswith("/some/where/my_rig.toml, key 'sensor.exposure_ms': ")


# --------------------------------------------------------------------------- fuzzing
def parse_only_scene_errors(text: str) -> Setup | None:
    """Parse ``text``; a Setup or a SceneError are the only acceptable outcomes."""
    try:
        setup = parse_scene(text, source="fuzz.toml")
    except SceneError as exc:
        assert exc.path == "fuzz.toml"
        return None
    assert isinstance(setup, Setup)
    assert np.all(np.isfinite(setup.lights_world_m))
    return setup


# Every character, surrogates included: parse_scene takes any str.
any_text = st.text(st.characters(blacklist_categories=()), max_size=400)


@given(text=any_text)
@settings(max_examples=300, deadline=None)
def test_fuzz_arbitrary_text(text):
    parse_only_scene_errors(text)


@given(data=st.data())
@settings(max_examples=300, deadline=None)
def test_fuzz_spliced_text(data):
    # Near-valid input: paper_sim.toml with a random piece cut out and random text put in.
    n = len(PAPER_SIM)
    start = data.draw(st.integers(0, n), label="start")
    stop = data.draw(st.integers(start, min(n, start + 40)), label="stop")
    insert = data.draw(st.text(st.characters(blacklist_categories=()), max_size=20)
                       | st.sampled_from(["\n", "=", "[", "]", "\"", "#", ".", ",", "nan", "inf", "1e999",
                                          "1" + "0" * 400, "\n[[lights]]\n", "\n[x]\n"]), label="insert")
    parse_only_scene_errors(PAPER_SIM[:start] + insert + PAPER_SIM[stop:])


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("scene_fuzz")


@given(raw=st.binary(max_size=400) | st.builds(
    lambda pos, b: PAPER_SIM.encode()[:pos] + b + PAPER_SIM.encode()[pos + len(b):],
    st.integers(0, len(PAPER_SIM.encode())), st.binary(min_size=1, max_size=4)))
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_fuzz_bytes_in_a_file(fuzz_dir, raw):
    path = fuzz_dir / "fuzz.toml"
    path.write_bytes(raw)
    try:
        load_scene(path)
    except SceneError as exc:
        assert exc.path == str(path)


hazards = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e300, 5e-324, 1e-300, 0, -0.0,
                            10 ** 400, -(10 ** 400), 2 ** 63, True, "1"])
# Values TOML can hold, biased toward the troublesome ones.
toml_scalars = (
    st.integers(-10, 100_000)
    | st.integers(-(2 ** 70), 2 ** 70)
    | st.sampled_from([0, -1, 2 ** 63, 10 ** 400, -(10 ** 400)])
    | st.floats()
    | st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, 1e-300, 0.0, -0.0])
    | st.text(max_size=12)
    | st.sampled_from(["cornea_apex", "arc", "grid", "list", "scet-scene"])
    | st.booleans()
)
toml_keys = st.sampled_from([
    "format", "version", "name", "kind", "count", "rows", "cols", "pose", "look_at", "up", "normal",
    "position_m", "position_mm", "exposure_ms", "exposure_us", "exposure_ns", "exposure",
    "pulse_us", "period_us", "phase_us", "radius_mm", "radius_m", "span_deg", "span_rad", "side_mm",
    "first_m", "center_m", "center_direction", "u_axis", "positions_m", "positions_mm",
    "pivot_m", "rotation_axis", "rotation_deg", "translation_m", "focal_px", "fx_px", "fy_px",
    "principal_point_px", "look_at_m", "rotation_rad", "cornea_offset_mm", "limbus_depth_mm",
    "bit_depth", "black_level_dn", "gain_per_m", "noise_sd", "distance_sensor",
]) | st.text(min_size=1, max_size=8)
toml_values = st.recursive(
    toml_scalars,
    lambda children: st.lists(children, max_size=4) | st.dictionaries(toml_keys, children, max_size=4),
    max_leaves=8,
)


def mutated_scene(data) -> dict:
    """paper_sim.toml as a dict, after one to four random edits drawn from ``data``."""
    doc = scene_dict()
    for _ in range(data.draw(st.integers(1, 4), label="mutations")):
        nodes = list(tree_nodes(doc))
        op = data.draw(st.sampled_from(["replace", "scale", "delete", "add", "poke", "poke"]), label="op")
        numbers = [(p, v) for p, v in nodes if type(v) in (int, float)]
        if op == "poke" and numbers:
            # The values that break arithmetic, put where a number is expected.
            path, _ = data.draw(st.sampled_from(numbers), label="number")
            parent_of(doc, path)[path[-1]] = data.draw(hazards, label="hazard")
            continue
        if not nodes:
            op = "add"
        if op == "add":
            containers = [doc] + [v for _, v in nodes if isinstance(v, dict)]
            target = data.draw(st.sampled_from(containers), label="table")
            target[data.draw(toml_keys, label="key")] = data.draw(toml_values, label="value")
            continue
        path, value = data.draw(st.sampled_from(nodes), label="node")
        parent = parent_of(doc, path)
        if op == "delete":
            del parent[path[-1]]
        elif op == "scale" and type(value) in (int, float) and abs(value) < 1e300:
            # Plausible-looking numbers: unit mistakes, sign flips, zero, small nudges.
            factor = data.draw(st.sampled_from([1e-3, 1e3, -1.0, 0.0, 1.01, 0.5, 2.0, 1e300]), label="factor")
            parent[path[-1]] = float(value) * factor
        else:
            parent[path[-1]] = data.draw(toml_values, label="value")
    return doc


@given(data=st.data())
@settings(max_examples=300, deadline=None)
def test_fuzz_mutated_scene_structure(data):
    parse_only_scene_errors(to_toml(mutated_scene(data)))


def test_fuzz_writer_round_trips():
    # The fuzzers' TOML writer must say what it means, or the structure fuzz tests nothing.
    doc = {"a": [1, 2.5, math.inf, -math.inf, "x\"\\\n\x7f"], "b": {"c d": True, "e": {}}, "f": 1e308,
           "g": 5e-324, "h": -0.0, "i": 10 ** 400}
    back = tomllib.loads(to_toml(doc))
    assert back == doc
    assert math.isnan(tomllib.loads(to_toml({"n": math.nan}))["n"])
