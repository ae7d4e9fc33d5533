"""The feature-level simulator and its file format."""

import json

import numpy as np
import pytest

from estimator.scene import load_scene
from scet_render.simulate import (
    glint_statistics,
    load_observations,
    parse_targets,
    save_observations,
    simulate_glints,
)


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


def test_noise_is_bohme_uniform_and_seeded(setup):
    targets = parse_targets("grid:24x15", setup)
    a = simulate_glints(setup, targets, noise_px=0.5, rng=3)
    b = simulate_glints(setup, targets, noise_px=0.5, rng=3)
    c = simulate_glints(setup, targets, noise_px=0.5, rng=4)
    assert np.array_equal(a.glints_px, b.glints_px, equal_nan=True)
    assert not np.array_equal(a.glints_px, c.glints_px, equal_nan=True)
    err = (a.glints_px - a.glints_true_px)[a.visible]
    # Uniform in [-e_f, e_f] on each axis: bounded, mean ~0, SD e_f / sqrt(3).
    assert np.abs(err).max() <= 0.5
    assert np.abs(err.mean(axis=0)).max() < 0.02  # 14,000+ samples: 4 SE of the mean is 0.01 px
    assert np.allclose(err.std(axis=0), 0.5 / np.sqrt(3), rtol=0.05)
    g = simulate_glints(setup, targets, noise_px=0.5, noise_model="gaussian", rng=3)
    assert np.allclose((g.glints_px - g.glints_true_px)[g.visible].std(axis=0), 0.5, rtol=0.05)


def test_glints_cover_the_cornea_over_the_whole_screen(setup):
    """The scene's arc choice (see paper_sim.toml): many glints for every target."""
    obs = simulate_glints(setup, parse_targets("grid:24x15", setup))
    stats = glint_statistics(obs)
    assert stats["targets"] == 360 and stats["lights"] == 40
    assert stats["visible_min"] >= 36
    assert stats["spread_u_px_mean"] > 150 and stats["spread_v_px_mean"] > 150
    # The eye looks at each target.
    d = obs.cornea_center_m - setup.eye.rotation_center_m
    t = obs.targets_m - setup.eye.rotation_center_m
    cos = np.sum(d * t, 1) / np.linalg.norm(d, axis=1) / np.linalg.norm(t, axis=1)
    assert np.allclose(cos, 1.0, atol=1e-14)


def test_estimator_tests_simulate_the_same_glints(setup):
    """tests/estimator simulates its glints without this package
    (:mod:`tests.estimator.simulated`); the simulator gives the same numbers, noise draw for
    noise draw, so those tests check what they checked with it."""
    from tests.estimator import simulated

    for spec in ("grid:24x15", "grid:6x4", "calib:3x3", "calib:5x5"):
        assert np.array_equal(simulated.screen_targets(spec, setup), parse_targets(spec, setup))
    targets = parse_targets("grid:6x4", setup)
    for kwargs in (dict(), dict(noise_px=0.5, rng=5),
                   dict(noise_px=0.5, noise_model="gaussian", rng=9),
                   dict(lights_world_m=setup.lights_world_m + [0.002, 0.0, -0.001],
                        cornea_radius_m=7.5e-3)):
        ours = simulate_glints(setup, targets, **kwargs)
        theirs = simulated.simulate_glints(setup, targets, **kwargs)
        for name in ("targets_m", "yaw_rad", "pitch_rad", "cornea_center_m", "glints_true_px",
                     "glints_px", "visible"):
            assert np.array_equal(getattr(ours, name), getattr(theirs, name), equal_nan=True), name
    a = simulate_glints(setup, targets, noise_px=0.5, rng=np.random.default_rng(2))
    b = simulated.simulate_glints(setup, targets, noise_px=0.5, rng=np.random.default_rng(2))
    assert np.array_equal(a.glints_px, b.glints_px, equal_nan=True)


def test_targets_specs(setup, tmp_path):
    assert parse_targets("grid:24x15", setup).shape == (360, 3)
    calib = parse_targets("calib:3x3", setup)
    assert calib.shape == (9, 3) and np.isclose(calib[:, 0].min(), -0.24)
    assert np.allclose(parse_targets("centre", setup), [[0.0, -0.05, -0.7]])
    f = tmp_path / "t.csv"
    f.write_text("x_m,y_m,z_m\n0.1,0.0,-0.7\n-0.1,0.05,-0.7\n")
    assert parse_targets(str(f), setup).shape == (2, 3)
    for bad in ("grid:0x3", "grid:3", "calib:axb", "nonsense"):
        with pytest.raises(ValueError):
            parse_targets(bad, setup)
    f.write_text("x_m,y_m\n0.1,0.0\n")
    with pytest.raises(ValueError, match="x_m, y_m, z_m"):
        parse_targets(str(f), setup)


def test_bad_input(setup):
    with pytest.raises(ValueError, match=r"\(m, 3\)"):
        simulate_glints(setup, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="finite"):
        simulate_glints(setup, np.array([[np.nan, 0, -0.7]]))
    with pytest.raises(ValueError, match="rng"):
        simulate_glints(setup, np.array([[0, 0, -0.7]]), noise_px=0.5)
    with pytest.raises(ValueError, match="e_f"):
        simulate_glints(setup, np.array([[0, 0, -0.7]]), noise_px=-1, rng=1)
    with pytest.raises(ValueError, match="noise model"):
        simulate_glints(setup, np.array([[0, 0, -0.7]]), noise_px=0.5, noise_model="laplace", rng=1)


def test_file_round_trip(setup, tmp_path):
    obs = simulate_glints(setup, parse_targets("calib:5x5", setup), noise_px=0.3, rng=9)
    path = save_observations(tmp_path / "sim.npz", obs, setup)
    back, meta = load_observations(path)
    assert meta["scene"] == "paper_sim" and meta["seed"] == 9 and meta["version"] == 1
    assert np.array_equal(back.glints_px, obs.glints_px, equal_nan=True)
    assert np.array_equal(back.visible, obs.visible)
    csv = save_observations(tmp_path / "sim.csv", obs, setup)
    lines = csv.read_text().splitlines()
    assert json.loads(lines[0][2:])["format"] == "scet-glints"
    assert len(lines) == 2 + 25 * 40
    data = np.genfromtxt(csv, delimiter=",", skip_header=2)
    assert np.allclose(data[:, 7:9], obs.glints_px.reshape(-1, 2), atol=1e-6, equal_nan=True)
    assert not list(tmp_path.glob("*.partial"))
    with pytest.raises(ValueError, match=".npz or .csv"):
        save_observations(tmp_path / "sim.txt", obs, setup)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a SCET simulation"):
        load_observations(tmp_path / "junk.npz")


def test_conic_eye_simulates_conic_glints():
    """A conic eye's simulated glints are the conic's (not the sphere's): the labels a study of
    the spherical tracker on aspheric eyes compares with."""
    import dataclasses

    from estimator.eye import gaze_direction
    from estimator.geometry import project_glints_conic

    paper = load_scene("paper_sim")
    conic = dataclasses.replace(paper, eye=dataclasses.replace(paper.eye, cornea_asphericity=-0.25))
    targets = parse_targets("grid:6x4", conic)
    obs = simulate_glints(conic, targets)
    yaw, pitch = conic.eye.angles_toward(targets)
    e = conic.eye
    g, vis = project_glints_conic(conic.camera, e.apex(yaw, pitch), gaze_direction(yaw, pitch),
                                  e.cornea_radius_m, -0.25, conic.lights_world_m,
                                  limbus_depth_m=e.limbus_depth_m)
    assert np.array_equal(obs.visible, vis)
    assert np.abs(obs.glints_true_px - g)[vis].max() < 1e-9  # float64 apex rounding only
    sphere = simulate_glints(paper, targets)
    both = vis & sphere.visible
    assert np.median(np.linalg.norm(obs.glints_true_px - sphere.glints_true_px, axis=-1)[both]) > 2.0
