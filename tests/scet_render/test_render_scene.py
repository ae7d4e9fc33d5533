"""The Mitsuba scene of a Setup: camera conversion, eye parts and poses, eyelids, export.

Tests that need Mitsuba skip themselves without it; they run on whatever variant
:func:`scet_render.render.backend.activate` picks (``SCET_MITSUBA_VARIANT=scalar_rgb`` forces scalar).
"""

import dataclasses
import math
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from estimator.eye import gaze_direction
from estimator.geometry import Camera, look_at_rotation
from estimator.scene import load_scene
from scet_render.render import (
    SCENE_UNITS_PER_M,
    EyeScene,
    SceneOptions,
    cornea_mesh,
    describe_scene,
    export_mitsuba,
    eye_layout,
    sclera_opacity,
    sensor_dict,
)


@dataclass(frozen=True)
class Tol:
    #: Camera conversion round trip (px): Mitsuba builds rays in float32; 1e-3 px is 60x the
    #: float32 direction rounding at 1300 px focal length and 1000x below the glint tolerance.
    pixel_px: float = 1e-3
    #: Eye part placement (m): float32 transforms of ~1 cm values (1e-7 relative).
    placement_m: float = 1e-8
    #: Radial mesh normals (unit vector components): float64 construction.
    normal: float = 1e-9


TOL = Tol()


@pytest.fixture(scope="module")
def mi():
    pytest.importorskip("mitsuba")
    from scet_render.render import activate

    return activate()


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


def _reproject(mi, camera: Camera, pixels) -> np.ndarray:
    """Pixels of points on the rays Mitsuba's sensor casts through OpenCV pixels ``pixels``."""
    d = sensor_dict(camera)
    d["to_world"] = mi.ScalarTransform4f(d["to_world"])
    sensor = mi.load_dict(d)
    out = []
    for u, v in pixels:
        film = mi.Point2f(float((u + 0.5) / camera.width_px), float((v + 0.5) / camera.height_px))
        ray, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
        o = np.array(ray.o, dtype=np.float64).ravel() / SCENE_UNITS_PER_M
        dvec = np.array(ray.d, dtype=np.float64).ravel()
        out.append(camera.project(o + 0.05 * dvec)[0])
    return np.array(out)


def test_sensor_puts_opencv_pixel_centres_where_the_camera_does(mi, setup):
    """The one conversion (film position = OpenCV pixel + 0.5; x, y negated) is exact."""
    pixels = np.array([[0.0, 0.0], [639.0, 479.0], [320.3, 100.7], [10.0, 400.0]])
    assert np.abs(_reproject(mi, setup.camera, pixels) - pixels).max() < TOL.pixel_px
    # A shifted principal point, a non-square image and another pose keep it exact.
    cam = Camera(np.array([0.02, 0.01, -0.04]),
                 look_at_rotation([0.02, 0.01, -0.04], [0.0, 0.002, -0.012], [0.1, 1.0, 0.0]),
                 900.0, 900.0, 141.25, 37.5, 200, 100)
    pixels = np.array([[0.0, 0.0], [199.0, 99.0], [141.25, 37.5], [12.5, 80.25]])
    assert np.abs(_reproject(mi, cam, pixels) - pixels).max() < TOL.pixel_px


def test_sensor_rejects_non_square_pixels(setup):
    cam = dataclasses.replace(setup.camera, fy_px=setup.camera.fx_px * 1.01)
    with pytest.raises(ValueError, match="square pixels"):
        sensor_dict(cam)


@pytest.mark.parametrize("kwargs, match", [
    ({"cornea": "glass"}, "cornea must be one of"),
    ({"eyelid_openness": 1.5}, "eyelid_openness"),
    ({"ambient_radiance": -1.0}, "ambient_radiance"),
    ({"channels": "rgb"}, "channels"),
    ({"iris_albedo": 2.0}, "iris_albedo"),
])
def test_options_are_validated(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SceneOptions(**kwargs)


def test_layout_fits_the_eye_together(setup):
    lay = eye_layout(setup)
    eye = setup.eye
    # The sclera sphere passes through the limbus circle and the cornea protrudes from it.
    apex = eye.cornea_offset_m + eye.cornea_radius_m
    assert math.isclose(lay.sclera_radius_m, math.hypot(lay.limbus_plane_m, lay.limbus_radius_m))
    assert lay.limbus_plane_m < lay.sclera_radius_m < apex < lay.lid_radius_m < lay.skin_radius_m
    # Open lids leave the cornea's angular extent plus the margin for every screen gaze.
    _, pitch = eye.angles_toward(setup.screen.grid(9, 9, margin=0.0))
    assert lay.lid_upper_rad >= pitch.max() + lay.cap_angle_rad
    assert lay.lid_lower_rad <= pitch.min() - lay.cap_angle_rad
    closed = eye_layout(setup, SceneOptions(eyelid_openness=0.0))
    assert closed.lid_upper_rad == closed.lid_lower_rad


def test_sclera_mask_opens_exactly_the_cornea(setup):
    lay = eye_layout(setup)
    mask = sclera_opacity(lay)[:, 0]
    theta = (np.arange(mask.size) + 0.5) * np.pi / mask.size
    assert np.all(mask[theta < lay.cap_angle_rad - 2 * np.pi / mask.size] == 0)
    assert np.all(mask[theta > lay.cap_angle_rad] == 1)


def test_cornea_mesh_is_the_cap_with_radial_normals(setup):
    mesh = cornea_mesh(setup, edge_m=0.3e-3)
    eye = setup.eye
    center = eye.cornea_center(0.0, 0.0)
    radial = (mesh.vertices - center) / eye.cornea_radius_m
    assert np.allclose(np.linalg.norm(mesh.vertices - center, axis=1), eye.cornea_radius_m)
    assert np.abs(mesh.vertex_normals - radial).max() < TOL.normal
    axis = gaze_direction(0.0, 0.0)
    cos = radial @ axis
    assert math.isclose(cos.min(), eye.cap_cos_min, abs_tol=1e-12)  # the rim is the limbus
    # Faces wind outward, like the normals.
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals, radial[mesh.faces].mean(1)) > 0)


def test_description_holds_every_part(setup):
    desc = describe_scene(setup, SceneOptions(eyelid_openness=None))
    assert {"cornea", "sclera", "iris", "pupil", "face", "skin", "ambient"} <= set(desc.objects)
    assert "lid_upper" not in desc.objects
    assert sum(k.startswith("light_") for k in desc.objects) == setup.lights.count
    light = desc.objects["light_000"]
    assert math.isclose(light["radius"], setup.lights.groups[0].source_radius_m * SCENE_UNITS_PER_M)
    assert np.allclose(light["center"], setup.lights_world_m[0] * SCENE_UNITS_PER_M)
    # Split channels: strobe light in R, ambient in G; grey: both white.
    assert light["emitter"]["radiance"]["value"][1:] == [0.0, 0.0]
    assert desc.objects["ambient"]["radiance"]["value"][0::2] == [0.0, 0.0]
    grey = describe_scene(setup, SceneOptions(channels="grey"))
    assert len(set(grey.objects["light_000"]["emitter"]["radiance"]["value"])) == 1


@pytest.mark.parametrize("yaw, pitch", [(0.0, 0.0), (0.3, -0.2), (-0.25, 0.15)])
def test_moving_the_eye_moves_every_part(mi, setup, yaw, pitch):
    scene = EyeScene(setup, SceneOptions(cornea="conductor"), mi=mi)
    assert scene.set_pose(yaw, pitch) == ((yaw, pitch) != (0.0, 0.0))
    assert not scene.set_pose(yaw, pitch)  # unchanged pose: no update
    params = mi.traverse(scene.scene)
    u = SCENE_UNITS_PER_M

    def matrix(key):
        return np.array(params[key].matrix, dtype=np.float64).reshape(4, 4)

    cornea = matrix("cornea.to_world")
    assert np.abs(cornea[:3, 3] / u - setup.eye.cornea_center(yaw, pitch)).max() < TOL.placement_m
    lay = scene.layout
    gaze = gaze_direction(yaw, pitch)
    iris = matrix("iris.to_world")
    assert np.abs(iris[:3, 3] / u - lay.limbus_plane_m * gaze).max() < TOL.placement_m
    assert np.allclose(iris[:3, 2] / np.linalg.norm(iris[:3, 2]), gaze, atol=1e-6)  # faces out
    sclera = matrix("sclera.to_world")
    assert np.allclose(sclera[:3, 2] / (lay.sclera_radius_m * u), gaze, atol=1e-6)
    with pytest.raises(ValueError, match="finite"):
        scene.set_pose(float("nan"), 0.0)


def _first_hits(mi, scene, origin, targets):
    """(n,) distances of the first intersection along rays from origin toward targets."""
    d = targets - origin
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    if mi.variant().startswith("scalar"):
        t = [scene.ray_intersect(mi.Ray3f(mi.Point3f(*map(float, origin)),
                                          mi.Vector3f(*map(float, di)))).t for di in d]
        return np.array(t, dtype=np.float64), dist
    o = mi.Point3f(*[mi.Float(np.full(len(d), c, np.float32)) for c in origin])
    si = scene.ray_intersect(mi.Ray3f(o, mi.Vector3f(*[mi.Float(d[:, i].astype(np.float32))
                                                       for i in range(3)])))
    return np.array(si.t, dtype=np.float64), dist


def _visible_cornea_points(setup, yaw, pitch, n=400, seed=0):
    """Cap points (m) facing the camera, up to 1 deg inside the limbus."""
    rng = np.random.default_rng(seed)
    eye = setup.eye
    axis = gaze_direction(yaw, pitch)
    v = rng.normal(size=(n * 4, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = v[v @ axis > eye.cap_cos_min + 0.02]
    p = eye.cornea_center(yaw, pitch) + eye.cornea_radius_m * v
    view = setup.camera.position_m - p
    # Facing the camera, and not grazing (beyond 78 deg, float32 intersection distances
    # along the ray lose more than the 1 µm the test allows).
    facing = np.einsum("ij,ij->i", v, view) > 0.2 * np.linalg.norm(view, axis=1)
    return p[facing][:n]


def test_open_eyelids_never_cover_the_cornea(mi, setup):
    """For gazes over the whole screen, every cap point facing the camera is seen directly."""
    u = SCENE_UNITS_PER_M
    scene = EyeScene(setup, SceneOptions(eyelid_openness=1.0), mi=mi)
    closing = EyeScene(setup, SceneOptions(eyelid_openness=0.3), mi=mi)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(5, 5, margin=0.0))
    covered_when_closing = 0
    for a, b in zip(yaw, pitch):
        pts = _visible_cornea_points(setup, a, b) * u
        for s in (scene, closing):
            s.set_pose(a, b)
        t, dist = _first_hits(mi, scene.scene, setup.camera.position_m * u, pts)
        # float32 intersection distances at ~3 cm, not grazing: 1 µm slack.
        slack = 1e-6 * u
        assert np.all(np.abs(t - dist) < slack), f"cornea covered at yaw {a:.3f}, pitch {b:.3f}"
        t, dist = _first_hits(mi, closing.scene, setup.camera.position_m * u, pts)
        covered_when_closing += int(np.sum(t < dist - slack))
    assert covered_when_closing > 0  # the check can fail: nearly closed lids do cover it


def test_export_renders_with_mitsubas_own_loader(mi, setup, tmp_path):
    path = export_mitsuba(setup, tmp_path / "scene", yaw_rad=0.1, pitch_rad=-0.05, spp=4)
    assert path.name == "scene.xml"
    assert sorted(p.name for p in (path.parent / "meshes").iterdir()) == [
        "face.ply", "lid_lower.ply", "lid_upper.ply", "skin.ply"]
    scene = mi.load_file(str(path))
    # (Mitsuba merges the skin, lid and face meshes, which share one BSDF, into one unnamed
    # mesh.)
    ids = {s.id() for s in scene.shapes()}
    assert {"cornea", "sclera", "iris", "pupil", "light_039"} <= ids
    # The exported camera is the Setup's camera.
    sensor = scene.sensors()[0]
    film = mi.Point2f(float(100.5 / 640), float(50.5 / 480))
    ray, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
    o = np.array(ray.o, dtype=np.float64).ravel() / SCENE_UNITS_PER_M
    px = setup.camera.project(o + 0.05 * np.array(ray.d, dtype=np.float64).ravel())[0]
    assert np.abs(px - [100.0, 50.0]).max() < TOL.pixel_px
    # It renders like the same scene built in memory (grey channels, same pose).
    exported = np.asarray(mi.render(scene, spp=4, seed=1))
    memory = EyeScene(setup, SceneOptions(channels="grey"), mi=mi)
    memory.set_pose(0.1, -0.05)
    direct = np.asarray(mi.render(memory.scene, spp=4, seed=1))
    assert exported.shape == direct.shape == (480, 640, 3)
    # 1.2M samples each: the frame means agree to 2 % (their MC error is well below 1 %).
    assert math.isclose(exported.mean(), direct.mean(), rel_tol=0.02)


def test_export_writes_the_lens_mitsuba_can_carry(mi, tmp_path):
    # The prototype's lens (issue 30): its thin lens as Mitsuba's thinlens sensor (the same
    # pupil and focus plane: every ray through a pixel meets the focus plane where the pinhole
    # ray does), its distortion in camera.json beside the XML (no Mitsuba sensor has one).
    from estimator.lens import read_camera_file

    proto = load_scene("prototype_ov5647")
    cam = proto.camera
    path = export_mitsuba(proto, tmp_path / "scene", spp=1)
    text = path.read_text()
    assert 'type="thinlens"' in text and "distortion" in text and "camera.json" in text
    lens = read_camera_file(path.parent / "camera.json")
    assert lens.K.tolist() == cam.K.tolist() and lens.distortion.tolist() == [-0.05, 0, 0, 0, 0]
    sensor = mi.load_file(str(path)).sensors()[0]
    pinhole = dataclasses.replace(cam, distortion=(), f_number=None, focus_distance_m=None)
    d_f = cam.focus_distance_m
    for u, v in ((100.0, 50.0), (319.5, 239.5), (600.0, 400.0)):
        film = mi.Point2f(float((u + 0.5) / cam.width_px), float((v + 0.5) / cam.height_px))
        hits, origins = [], []
        for a in ((0.1, 0.2), (0.9, 0.5), (0.5, 0.95)):
            ray, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(*a))
            o = np.array(ray.o, dtype=np.float64).ravel() / SCENE_UNITS_PER_M
            dv = np.array(ray.d, dtype=np.float64).ravel()
            oc, dc = cam.world_to_camera(o), dv @ cam.rotation.T
            origins.append(oc)
            hits.append(oc + (d_f - oc[2]) / dc[2] * dc)  # camera frame, on the focus plane
        hits, origins = np.array(hits), np.array(origins)
        # the rays leave points of the pupil of radius f / (2 N), far apart ...
        r = np.hypot(origins[:, 0], origins[:, 1])
        assert 0.3 * cam.aperture_radius_m < r.max() <= cam.aperture_radius_m * (1 + 1e-5)
        # ... and meet on the focus plane (float32 rays: 1e-7 of 27 mm)
        assert np.linalg.norm(np.diff(hits, axis=0), axis=1).max() < 1e-8
        px = pinhole.project(hits[0] @ cam.rotation + cam.position_m)[0]
        assert np.abs(px - [u, v]).max() < 10 * TOL.pixel_px


@pytest.mark.slow
def test_export_renders_with_the_mitsuba_command(setup, tmp_path):
    exe = shutil.which("mitsuba") or shutil.which("mitsuba", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("the mitsuba command is not installed")
    from scet_render.render import LLVM_ENV, choose_variant

    choice = choose_variant()
    env = dict(os.environ)
    if choice.llvm_path is not None:
        env[LLVM_ENV] = str(choice.llvm_path)
    path = export_mitsuba(setup, tmp_path / "scene", spp=1)
    out = tmp_path / "scene.exr"
    run = subprocess.run([exe, "-m", choice.variant, "-o", str(out), str(path)], env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr + run.stdout
    assert out.exists() and out.stat().st_size > 0
