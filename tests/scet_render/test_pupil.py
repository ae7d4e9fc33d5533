"""The pupil: its scene key, its size over time, and its image through the cornea (the
dataset's ``pupil_center_px`` / ``pupil_ellipse_px`` labels), checked against Snell's law, a
forward ray trace, the n -> 1 limit and Gaussian optics. No rendering here
(``test_masks.py`` checks the labels on rendered frames)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest

from estimator.errors import SceneError
from estimator.eye import gaze_direction
from estimator.geometry import (
    Camera,
    look_at_rotation,
    refraction_points,
    snell_residual_rad,
)
from estimator.scene import load_scene, parse_scene
from scet_render.motion import (
    PupilModel,
    PupilTrace,
    fixation_sequence,
    pupil_diameters,
    pupil_schedule,
    with_pupil,
)
from scet_render.render import PUPIL_OFFSET_M, eye_layout, pupil_image, pupil_points


@dataclass(frozen=True)
class Tol:
    #: Snell's law at a refraction point (rad): Newton stops at steps of 1e-14 R (float64
    #: rounding); 1e-12 rad leaves three orders of magnitude (measured: <= 1e-15 rad).
    snell_rad: float = 1e-12
    #: A forward trace from the camera through the labelled pixel to the pupil plane lands
    #: this close to the pupil's centre (m): float64 rounding of a 50 mm path, ~1e-15 m,
    #: through a projection and its inverse; 1e-10 m is 1e-6 px at 1300 px and 60 mm.
    forward_trace_m: float = 1e-10
    #: n = 1 against the plain projection (px): the same point, projected (rounding).
    index_one_px: float = 1e-9
    #: Entrance-pupil magnification against Gaussian optics (relative): a 0.4 mm pupil seen
    #: on the axis from 0.5 m is paraxial to ~(0.2 / 7.8)^2 ~ 7e-4 (spherical aberration of
    #: the marginal ray); 3e-3 allows it and nothing like a wrong index (1.376 vs 1.336 moves
    #: the magnification by 2 %).
    magnification: float = 3e-3
    #: Hippus RMS over 10 min against the model's (relative): 6 sinusoids of periods <= 20 s
    #: average to their RMS within a few per cent over 600 s.
    hippus_rms: float = 0.05


TOL = Tol()


@pytest.fixture(scope="module")
def paper():
    return load_scene("paper_sim")


def _scene_text(extra: str) -> str:
    """paper_sim's text with a line added to [eye] (replacing a key it sets already)."""
    with open(load_scene("paper_sim").source, encoding="utf-8") as f:
        lines = f.read().splitlines()
    key = extra.split("=")[0].strip()
    lines = [ln for ln in lines if ln.split("=")[0].strip() != key]
    return "\n".join(lines).replace("[eye]", "[eye]\n" + extra, 1) + "\n"


# --------------------------------------------------------------------------- scene key


def test_pupil_diameter_is_a_scene_key_defaulting_to_the_old_renders(paper):
    assert paper.eye.pupil_diameter_m == 4e-3  # the renders' 2 mm radius before the key
    setup = parse_scene(_scene_text("pupil_diameter_mm = 3.0"))
    assert setup.eye.pupil_diameter_m == pytest.approx(3e-3, rel=0, abs=1e-15)


@pytest.mark.parametrize("line, key, words", [
    ("pupil_diameter_mm = 13.5", "eye.pupil_diameter_mm", "smaller than the iris"),
    ("pupil_diameter_mm = 0.0", "eye.pupil_diameter_mm", "> 0"),
    ("pupil_diameter_mm = -2.0", "eye.pupil_diameter_mm", "> 0"),
    ("pupil_diameter_mm = nan", "eye.pupil_diameter_mm", "finite"),
    ("pupil_diameter_mm = inf", "eye.pupil_diameter_mm", "finite"),
    ("pupil_diameter = 4.0", "eye.pupil_diameter", "unit"),
    ("refractive_index = 0.9", "eye.refractive_index", "[1.0"),
])
def test_bad_pupil_or_index_names_the_key(line, key, words):
    with pytest.raises(SceneError) as err:
        parse_scene(_scene_text(line), source="bad.toml")
    message = str(err.value)
    assert "bad.toml" in message and f"'{key}'" in message and words in message


# --------------------------------------------------------------------------- refraction


def _pupil_plane_points(setup, yaw, pitch, rng, count=8):
    """Random points of the pupil plane (within 2 mm of its centre) at poses (n,)."""
    center, edge = pupil_points(setup, yaw, pitch, 4e-3, count)
    w = rng.uniform(0.0, 1.0, edge.shape[:-1] + (1,))
    return center[..., None, :] + w * (edge - center[..., None, :])


@pytest.mark.parametrize("q", [0.0, -0.25, -0.454, 0.5])
def test_the_refraction_obeys_snell_and_a_forward_trace_lands_on_the_point(paper, q):
    rng = np.random.default_rng(29)
    eye = dataclasses.replace(paper.eye, cornea_asphericity=q)
    setup = dataclasses.replace(paper, eye=eye)
    yaw, pitch = rng.uniform(-0.35, 0.35, 40), rng.uniform(-0.25, 0.25, 40)
    X = _pupil_plane_points(setup, yaw, pitch, rng)
    g = gaze_direction(yaw, pitch)
    apex = eye.rotation_center_m + (eye.cornea_offset_m + eye.cornea_radius_m) * g
    O = setup.camera.position_m
    P, N, ok = refraction_points(O, apex, g, eye.cornea_radius_m, q, eye.refractive_index, X,
                                 limbus_depth_m=eye.limbus_depth_m)
    assert ok.mean() > 0.9  # the pupil seen through the cap at these poses
    assert np.max(snell_residual_rad(X, P, N, O, eye.refractive_index)[ok]) < TOL.snell_rad
    # Forward: from the camera through P, refract by Snell's law (vector form), meet the plane
    # of X: the point itself. Independent of the Fermat solve (it only supplies P and N).
    d = P - O
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cos_i = -np.einsum("...i,...i->...", d, N)
    eta = 1.0 / eye.refractive_index
    cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
    t_dir = eta * d + (eta * cos_i - cos_t)[..., None] * N
    gg = np.broadcast_to(g[:, None, :], X.shape)
    s = np.einsum("...i,...i->...", X - P, gg) / np.einsum("...i,...i->...", t_dir, gg)
    hit = P + s[..., None] * t_dir
    assert np.max(np.linalg.norm(hit - X, axis=-1)[ok]) < TOL.forward_trace_m


def test_with_index_one_the_label_is_the_plain_projection(paper):
    yaw, pitch = np.array([0.0, 0.25, -0.2]), np.array([0.0, -0.1, 0.15])
    im = pupil_image(paper, yaw, pitch, refractive_index=1.0)
    center, _ = pupil_points(paper, yaw, pitch, paper.eye.pupil_diameter_m)
    plain, _ = paper.camera.project(center)
    assert np.all(im.center_visible)
    assert np.max(np.abs(im.center_px - plain)) < TOL.index_one_px
    # ... and the cornea's index moves it by pixels: the label is not the plain projection.
    refracted = pupil_image(paper, yaw, pitch)
    assert np.min(np.linalg.norm(refracted.center_px - plain, axis=-1)) > 1.0


def test_the_entrance_pupil_is_magnified_as_gaussian_optics_says(paper):
    """On the axis, a single refracting sphere (R, n) images a pupil d behind its apex at
    v = 1 / ((n - 1) / R - n / d) (virtual, in front of the pupil) with magnification
    m = n v / d (Gaussian optics; the human cornea's ~1.13)."""
    eye = paper.eye
    R, n = eye.cornea_radius_m, eye.refractive_index
    lay = eye_layout(paper)
    d = eye.cornea_offset_m + R - (lay.limbus_plane_m + PUPIL_OFFSET_M)
    v = 1.0 / (n / d - (n - 1.0) / R)  # depth of the virtual image behind the apex
    m = n * v / d
    apex = eye.apex()
    position = apex + np.array([0.0, 0.0, -0.5])  # 0.5 m in front, on the axis
    f = 5000.0
    cam = Camera(position, look_at_rotation(position, apex, np.array([0.0, 1.0, 0.0])),
                 f, f, 319.5, 239.5, 640, 480)
    setup = dataclasses.replace(paper, camera=cam)
    D = 0.4e-3
    im = pupil_image(setup, 0.0, 0.0, D)
    seen_px = f * m * D / (0.5 + v)
    assert im.ellipse_px[2] == pytest.approx(seen_px, rel=TOL.magnification)
    assert im.ellipse_px[3] == pytest.approx(seen_px, rel=TOL.magnification)
    assert np.allclose(im.center_px, [319.5, 239.5], rtol=0, atol=1e-9)
    assert 1.10 < m < 1.16  # the eye's entrance pupil: ~13 % larger than the pupil


def test_the_conic_cornea_moves_the_label(paper):
    """The labels refract at the conic when the scene says so (not at the sphere)."""
    conic = dataclasses.replace(paper, eye=dataclasses.replace(paper.eye,
                                                               cornea_asphericity=-0.25))
    a, b = pupil_image(paper, 0.1, 0.05), pupil_image(conic, 0.1, 0.05)
    # The pupil's edge refracts 2 mm off the axis, where the conic departs from the sphere.
    assert np.all(np.isfinite(a.ellipse_px)) and np.all(np.isfinite(b.ellipse_px))
    assert np.max(np.abs(a.ellipse_px[:4] - b.ellipse_px[:4])) > 0.5


# --------------------------------------------------------------------------- over time


def test_light_reflex_waits_for_its_latency_then_settles():
    model = PupilModel(hippus_rms_mm=0.0)
    trace = PupilTrace(4e-3, [1.0, 5.0], [-1.5e-3, 1.0e-3], [], [], [], model)
    t = np.array([0.9, 1.0 + model.latency_s - 1e-6, 1.0 + model.latency_s + 0.1, 4.9, 12.0])
    d = trace.diameter_at(t)
    assert d[0] == d[1] == 4e-3  # nothing before the latency
    assert 2.5e-3 < d[2] < 4e-3  # constricting
    assert d[3] == pytest.approx(2.5e-3, abs=2e-6)  # settled: 5 s >> 5 tau_c
    assert d[4] == pytest.approx(3.5e-3, abs=2e-6)  # redilated by the second change
    # Constriction is faster than redilation (Ellis 1981): 90 % of each change taken.
    fine = np.linspace(0.0, 12.0, 120001)
    dd = trace.diameter_at(fine)
    c90 = fine[np.argmax(dd <= 4e-3 - 0.9 * 1.5e-3)] - 1.0 - model.latency_s
    r90 = fine[np.argmax((fine > 5.0) & (dd >= 2.5e-3 + 0.9 * 1.0e-3))] - 5.0 - model.latency_s
    assert c90 < r90
    assert np.all(np.abs(np.diff(dd)) < 1e-6)  # no jumps


def test_hippus_is_seeded_in_its_band_with_its_rms():
    model = PupilModel(hippus_rms_mm=0.2)
    a = pupil_schedule(600.0, 4e-3, 7, model)
    b = pupil_schedule(600.0, 4e-3, 7, model)
    t = np.arange(0.0, 600.0, 0.05)
    da, db = a.diameter_at(t), b.diameter_at(t)
    assert np.array_equal(da, db)  # same seed, same trace
    assert not np.array_equal(da, pupil_schedule(600.0, 4e-3, 8, model).diameter_at(t))
    assert np.std(da) * 1e3 == pytest.approx(0.2, rel=TOL.hippus_rms)
    assert np.all((a.hippus_frequency_hz >= 0.05) & (a.hippus_frequency_hz <= 0.3))
    spectrum = np.abs(np.fft.rfft(da - da.mean()))
    freq = np.fft.rfftfreq(t.size, 0.05)
    assert 0.05 <= freq[np.argmax(spectrum)] <= 0.3


def test_pupil_stays_in_its_range_and_models_check_their_inputs():
    model = PupilModel(light_steps_per_min=60.0, light_step_range_mm=(-6.0, 6.0))
    trace = pupil_schedule(120.0, 4e-3, 3, model)
    d = trace.diameter_at(np.linspace(0.0, 120.0, 4001))
    assert d.min() >= 2e-3 and d.max() <= 8e-3 and trace.step_s.size > 60
    for bad in (dict(latency_s=-0.1), dict(constriction_tau_s=0.0),
                dict(hippus_band_hz=(0.3, 0.05)), dict(hippus_components=0),
                dict(min_diameter_mm=9.0)):
        with pytest.raises(ValueError):
            PupilModel(**bad)


def test_a_trajectory_without_a_pupil_trace_keeps_the_scene_size(paper):
    traj = fixation_sequence(paper.eye, paper.screen.grid(3, 3)[[4]], [1.0])
    t = np.linspace(0.0, 1.0, 5)
    assert np.all(pupil_diameters(traj, t, 4e-3) == 4e-3)
    assert np.all(pupil_diameters(object(), t, 5e-3) == 5e-3)  # no pupil_diameter_at at all
    traced = with_pupil(traj, pupil_schedule(1.0, 4e-3, 1, PupilModel(hippus_rms_mm=0.3)))
    d = pupil_diameters(traced, t, 4e-3)
    assert np.all(np.isfinite(d)) and np.ptp(d) > 0
    assert math.isclose(traced.pupil.base_diameter_m, 4e-3)


def test_scet_render_pupil_dynamic_labels_the_trace_it_renders(tmp_path, capsys):
    """``scet render --pupil dynamic``: the manifest records the dynamics, each strobe's
    ``pupil_diameter_mm`` is the seeded trace of the same trajectory at its instant (to float
    rounding of the JSON, 1e-9 mm), and the pupil moves (hippus: nonzero range over 2 frames).
    Without the flag the manifest has no ``pupil`` and every label is the scene's 4 mm."""
    import json

    pytest.importorskip("mitsuba")
    from scet_render.cli import main
    from scet_render.dataset import dataset_trajectory
    from scet_render.motion import PupilModel
    from tests.scet_render.test_workflow import _small_scene

    scene = _small_scene(tmp_path / "small.toml")
    common = ["--frames", "2", "--spp", "1", "--cornea", "conductor", "--no-masks"]
    assert main(["render", str(scene), *common, "--pupil", "dynamic", "--seed", "3",
                 "--out", str(tmp_path / "dyn")]) == 0
    assert main(["render", str(scene), *common, "--seed", "3", "--out", str(tmp_path / "fix")]) == 0
    capsys.readouterr()

    def labels(folder):
        lines = (tmp_path / folder / "labels.jsonl").read_text().splitlines()
        rows = [json.loads(line) for line in lines]
        return (np.array([r["time_s"] for r in rows]),
                np.array([r["pupil_diameter_mm"] for r in rows]))

    manifest = json.loads((tmp_path / "dyn" / "manifest.json").read_text())
    assert manifest["pupil"]["hippus_rms_mm"] == PupilModel().hippus_rms_mm
    t, d = labels("dyn")
    setup = load_scene(scene)
    traj = dataset_trajectory(setup, "fixations", 2, 3, PupilModel())
    np.testing.assert_allclose(d, 1e3 * pupil_diameters(traj, t, setup.eye.pupil_diameter_m),
                               atol=1e-9)
    assert np.ptp(d) > 0
    assert "pupil" not in json.loads((tmp_path / "fix" / "manifest.json").read_text())
    assert np.all(labels("fix")[1] == 4.0)


def test_scet_render_refuses_light_steps_without_dynamic_pupil(tmp_path, capsys):
    from scet_render.cli import main

    assert main(["render", "paper_sim", "--frames", "1", "--light-steps-per-min", "2",
                 "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--pupil dynamic" in err
    assert not (tmp_path / "d").exists()
