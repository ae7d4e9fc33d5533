"""Near-IR appearance (scet_render.render.textures): the textures' means, their seeds, the
scene file's ``[appearance]`` table, and what the textures do to a render.

The physics held: a textured part must read, under the same light, what an untextured part of
the same mean albedo reads (the texture moves light around, it does not add or remove it);
rendered radiance is linear in albedo; the strobe light that MNEE carries through the cornea
meets the same texture the path tracer's rays see.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from estimator.errors import SceneError
from estimator.geometry import Camera
from estimator.scene import load_scene, parse_scene
from scet_render.render.textures import (
    Appearance,
    iris_texture,
    read_appearance,
    sclera_texture,
    skin_texture,
)

POSE = (0.1, -0.05)
#: Standard errors a Monte Carlo mean may miss by: 4 SE fails a correct test once in ~16,000.
N_SE = 4.0


def _with(setup, **table):
    return dataclasses.replace(setup, appearance=tuple(sorted(table.items())))


@pytest.fixture(scope="module")
def paper():
    return load_scene("paper_sim")


# --------------------------------------------------------------------------- textures


@pytest.mark.parametrize("mean", [0.1, 0.3, 0.55])
def test_iris_texture_mean_is_the_configured_albedo_on_every_circle(mean):
    """Every column (a circle about the iris centre) averages to the configured albedo (float32
    rounding), so the area mean over any annulus is it too, whatever the pupil's size."""
    tex = iris_texture(Appearance(), mean, 6e-3)
    assert tex.dtype == np.float32 and tex.shape == (1024, 256)
    assert np.abs(tex.mean(axis=0, dtype=np.float64) - mean).max() < 1e-6
    assert 0.0 <= tex.min() and tex.max() <= 1.0
    # A texture, not a constant: the fibres' relative SD is the configured contrast (the
    # collarette and crypts add to it), per circle.
    sd = tex[:, 40:240].std(axis=0).mean() / mean
    assert 0.15 < sd < 0.4


def test_texture_means_as_mitsuba_samples_them():
    """Mitsuba's bilinear lookup of each texture, at points uniform by area over the iris
    annulus (pupil edge to limbus), the skin tile, and a band of sclera, averages to the
    configured albedo within the Monte Carlo error of the sample."""
    from scet_render.render.backend import activate

    mi = activate()
    rng = np.random.default_rng(7)
    n = 20000
    app = Appearance(seed=3)
    cases = []
    # Iris: u = r / R uniform by area between 0.33 and 1, v uniform.
    r = np.sqrt(rng.uniform(0.33**2, 1.0, n))
    cases.append((iris_texture(app, 0.3, 6e-3), r, rng.uniform(0, 1, n), 0.3))
    cases.append((skin_texture(app, 0.6), rng.uniform(0, 1, n), rng.uniform(0, 1, n), 0.6))
    # Sclera: a band of polar angle (rows) 40-90 degrees, uniform by area (cos theta uniform).
    theta = np.arccos(rng.uniform(0.0, math.cos(math.radians(40.0)), n))
    cases.append((sclera_texture(app, 0.7, 12e-3, 0.6), rng.uniform(0, 1, n), theta / np.pi,
                  0.7))
    for tex, u, v, mean in cases:
        bitmap = mi.load_dict({"type": "bitmap", "data": mi.TensorXf(tex[..., None]),
                               "raw": True, "filter_type": "bilinear", "wrap_mode": "repeat"})
        import drjit as dr

        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.uv = mi.Point2f(mi.Float(u.astype(np.float32)), mi.Float(v.astype(np.float32)))
        values = np.asarray(bitmap.eval_1(si), dtype=np.float64)
        se = values.std() / math.sqrt(n)
        assert abs(values.mean() - mean) < N_SE * se, (mean, values.mean(), se)


def test_skin_and_sclera_means():
    app = Appearance(seed=11)
    assert skin_texture(app, 0.45).mean(dtype=np.float64) == pytest.approx(0.45, abs=1e-6)
    sclera = sclera_texture(app, 0.7, 12e-3, 0.6)
    assert np.abs(sclera.mean(axis=1, dtype=np.float64) - 0.7).max() < 1e-6
    assert sclera.min() < 0.7 * (1 - 0.5 * app.sclera_vessel_contrast)  # vessels are there


def test_same_seed_same_bytes_other_seed_differs():
    for make in (lambda a: iris_texture(a, 0.3, 6e-3), lambda a: skin_texture(a, 0.6),
                 lambda a: sclera_texture(a, 0.7, 12e-3, 0.6)):
        a, b, c = make(Appearance(seed=5)), make(Appearance(seed=5)), make(Appearance(seed=6))
        assert a.tobytes() == b.tobytes()
        assert a.tobytes() != c.tobytes()
        # Not a shifted copy either: the two seeds' patterns are uncorrelated.
        corr = np.corrcoef(a.ravel(), c.ravel())[0, 1]
        assert abs(corr) < 0.2


def test_parameters_change_what_they_name():
    base = Appearance(seed=2)
    none = iris_texture(dataclasses.replace(base, iris_crypts_per_mm2=0.0,
                                            collarette_radius_mm=0.0), 0.3, 6e-3)
    crypts = iris_texture(dataclasses.replace(base, iris_crypts_per_mm2=1.0,
                                              collarette_radius_mm=0.0), 0.3, 6e-3)
    # Crypts are dark pits: more very dark texels (below half the mean).
    assert (crypts < 0.15).mean() > (none < 0.15).mean() + 0.01
    flat = iris_texture(dataclasses.replace(base, iris_contrast=0.0, iris_crypts_per_mm2=0.0,
                                            collarette_radius_mm=0.0), 0.3, 6e-3)
    assert np.abs(flat - 0.3).max() < 1e-6
    no_pores = skin_texture(dataclasses.replace(base, skin_contrast=0.0,
                                                skin_pores_per_mm2=0.0), 0.6)
    assert np.abs(no_pores - 0.6).max() < 1e-6


# --------------------------------------------------------------------------- scene file


def _scene_text(extra: str) -> str:
    from importlib import resources

    text = resources.files("scenes").joinpath("paper_sim.toml").read_text()
    return text + "\n[appearance]\n" + extra + "\n"


def test_appearance_table_is_read():
    setup = parse_scene(_scene_text("iris_albedo = 0.25\nseed = 9\ntextured = false"),
                        source="s.toml")
    app = read_appearance(setup)
    assert (app.iris_albedo, app.seed, app.textured) == (0.25, 9, False)
    assert read_appearance(load_scene("paper_sim")) == Appearance()


@pytest.mark.parametrize("line, key", [
    ("iris_albedo = 1.2", "appearance.iris_albedo"),
    ("skin_albedo = -0.1", "appearance.skin_albedo"),
    ("sclera_albedo = 2", "appearance.sclera_albedo"),
    ("iris_crypts_per_mm2 = -1.0", "appearance.iris_crypts_per_mm2"),
    ("skin_pores_per_mm2 = -0.5", "appearance.skin_pores_per_mm2"),
    ("sclera_vessels = -3", "appearance.sclera_vessels"),
    ("iris_fibres = 2.5", "appearance.iris_fibres"),
    ("textured = 1", "appearance.textured"),
    ("iris_albdo = 0.3", "appearance.iris_albdo"),
    ("iris_albedo = nan", "appearance.iris_albedo"),
    ('iris_albedo = "grey"', "appearance.iris_albedo"),
])
def test_bad_appearance_names_the_key(line, key):
    with pytest.raises(SceneError) as err:
        read_appearance(parse_scene(_scene_text(line), source="bad.toml"))
    assert err.value.key == key and "bad.toml" in str(err.value)


def test_effective_scene_carries_an_appearance_set_in_code(paper):
    from importlib import resources

    from scet_render.dataset.effective import effective_scene_text

    text = resources.files("scenes").joinpath("paper_sim.toml").read_text()
    setup = _with(paper, iris_albedo=0.2, seed=4)
    eff = effective_scene_text(setup, text)
    assert eff.overridden == ["appearance"] and eff.differs == []
    back = parse_scene(eff.text)
    assert read_appearance(back) == Appearance(iris_albedo=0.2, seed=4)


# --------------------------------------------------------------------------- renders


@pytest.fixture(scope="module")
def mi():
    pytest.importorskip("mitsuba")
    from scet_render.render.backend import activate

    mi = activate()
    if mi.variant().startswith("scalar"):
        pytest.skip("MNEE runs in the JIT variants only (scalar_rgb was chosen: no libLLVM)")
    return mi


def _small(setup, k=8):
    cam = setup.camera
    W, H = cam.width_px // k, cam.height_px // k
    return dataclasses.replace(setup, camera=Camera(
        cam.position_m, cam.rotation, cam.fx_px / k, cam.fy_px / k, (W - 1) / 2, (H - 1) / 2,
        W, H))


def _renderer(setup, spp=16, seed=3, max_depth=16):
    from scet_render.render import BandedRenderer, SceneOptions

    return BandedRenderer(setup, spp=spp, ambient=0.0, seed=seed, eyelid_openness=None,
                          options=SceneOptions(eyelid_openness=None, max_depth=max_depth))


def _masks(renderer):
    """(iris, sclera, skin) bool masks of pixel centres (region_labels), eroded by a pixel and
    kept 3 px away from every glint."""
    from estimator.geometry import project_glints
    from scet_render.render.regions import REGIONS, region_labels

    labels = region_labels(renderer, *POSE)
    setup = renderer.setup
    g, vis = project_glints(setup.camera, setup.eye.cornea_center(*POSE),
                            setup.eye.cornea_radius_m, setup.lights_world_m)
    vv, uu = np.mgrid[: labels.shape[0], : labels.shape[1]]
    near = np.zeros(labels.shape, bool)
    for u, v in g[vis]:
        near |= (uu - u) ** 2 + (vv - v) ** 2 < 9.0
    out = []
    for name in ("iris", "sclera", "skin"):
        m = labels == REGIONS.index(name)
        e = m.copy()
        e[1:] &= m[:-1]
        e[:-1] &= m[1:]
        e[:, 1:] &= m[:, :-1]
        e[:, :-1] &= m[:, 1:]
        out.append(e & ~near)
    return out


def _region_stats(img, mask):
    """Mean and standard error of a region's mean (pixels as independent samples: the
    texture's pattern and the Monte Carlo noise both count as scatter)."""
    v = img[mask].astype(np.float64)
    return v.mean(), v.std() / math.sqrt(v.size)


@pytest.fixture(scope="module")
def renders(mi, paper):
    """The strobe image of paper_sim at 80 x 60 (MNEE on) at one pose: textured and untextured
    at the default albedos; and direct light only (``max_depth`` 2), textured at the default
    albedos and at half of them."""
    small = _small(paper)
    half = {"iris_albedo": 0.15, "sclera_albedo": 0.35, "skin_albedo": 0.3}
    out = {}
    for name, setup, depth in (("textured", small, 16), ("plain", _with(small, textured=False), 16),
                               ("direct", small, 2), ("half", _with(small, **half), 2)):
        r = _renderer(setup, max_depth=depth)
        out[name] = r.render_rows(*POSE, seed=5)[0]
        if name == "textured":
            out["masks"] = _masks(r)
    return out


def test_textured_regions_read_the_untextured_means(renders):
    """Under the same light a textured part reads what an untextured part of the same mean
    albedo reads: iris (lit through the cornea by MNEE), sclera, skin."""
    for name, mask in zip(("iris", "sclera", "skin"), renders["masks"]):
        assert mask.sum() > 30, name
        m_t, se_t = _region_stats(renders["textured"], mask)
        m_p, se_p = _region_stats(renders["plain"], mask)
        assert abs(m_t - m_p) < N_SE * math.hypot(se_t, se_p), (name, m_t, m_p)


def test_region_means_scale_with_the_configured_albedo(renders):
    """Direct light is linear in albedo: half the albedo, half the radiance, in every region.

    Direct light only (``max_depth`` 2, and MNEE's single scattering on the iris): light passed
    between surfaces scales with the albedo's square and more (the skin shell is a bowl: at
    full depth halving its albedo measured a ratio of 0.33), so it is left out. Diffuse
    sampling does not depend on the albedo, so both renders take the same random decisions
    and the ratio is exact to float32 rounding: the same texture pattern scaled.
    """
    for name, mask in zip(("iris", "sclera", "skin"), renders["masks"]):
        full = renders["direct"][mask].astype(np.float64)
        half = renders["half"][mask].astype(np.float64)
        assert full.mean() > 0.05, name
        assert half.mean() / full.mean() == pytest.approx(0.5, abs=1e-4), name


def test_mnee_meets_the_texture_the_path_tracer_sees(mi, paper):
    """textures.iris_albedo at points of the iris equals the iris BSDF's reflectance at the
    same points found by Mitsuba's own ray intersection (its texture coordinates)."""
    import drjit as dr

    from scet_render.render.textures import iris_albedo

    r = _renderer(_small(paper), spp=1)
    es = r.eye_scene
    es.set_pose(*POSE)
    state, lights = es.mnee_state["pose"], es.mnee_lights
    rng = np.random.default_rng(2)
    n = 2000
    g = np.array(state["gaze"], dtype=np.float64).ravel()
    c = np.array(state["center"], dtype=np.float64).ravel()
    ex = np.array(state["iris_x"], dtype=np.float64).ravel()
    ey = np.array(state["iris_y"], dtype=np.float64).ravel()
    limbus = float(np.array(state["limbus"]).ravel()[0])
    rad = lights["iris_cm"] * np.sqrt(rng.uniform(0.2, 0.95, n))
    ang = rng.uniform(0, 2 * np.pi, n)
    x = (c + limbus * g)[None] + rad[:, None] * (np.cos(ang)[:, None] * ex + np.sin(ang)[:, None]
                                                 * ey)
    # Rays from just in front of the iris (inside the eye) straight back onto it.
    o = x + 1e-3 * g
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, k].astype(np.float32)) for k in range(3))),
                   mi.Vector3f(*(mi.Float(np.full(n, -v, np.float32)) for v in g)))
    si = es.scene.ray_intersect(ray)
    iris = next(s for s in es.scene.shapes() if s.id() == "iris")
    hit = np.asarray(si.shape == mi.ShapePtr(iris), bool)
    seen = np.asarray(iris.bsdf().eval_diffuse_reflectance(si).x, np.float64)
    V64 = dr.float64_array_t(mi.Vector3f)
    ours = np.asarray(iris_albedo(mi, state, lights,
                                  V64(*(dr.float64_array_t(mi.Float)(x[:, k]) for k in range(3)))),
                      np.float64)
    assert hit.mean() > 0.99
    # float32 intersection against the float64 point: ~1e-6 of a texel apart; bilinear values
    # differ by the texture's gradient times that.
    assert np.abs(ours[hit] - seen[hit]).max() < 2e-3
    assert np.std(ours) > 0.02  # a texture, not a constant


def test_scet_render_refuses_a_bad_appearance_in_one_line_before_any_work(tmp_path, capsys,
                                                                          monkeypatch):
    """``scet render`` with a scene whose [appearance] is out of range: exit 2, one line naming
    the file and the key, nothing written (the table is checked before the renderer opens)."""
    from scet_render.cli import main

    scene = tmp_path / "bad.toml"
    scene.write_text(_scene_text("sclera_vessels = -2"))
    monkeypatch.chdir(tmp_path)
    assert main(["render", str(scene), "--frames", "1", "--out", "d"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "bad.toml" in err and "appearance.sclera_vessels" in err
    assert not (tmp_path / "d").exists()
