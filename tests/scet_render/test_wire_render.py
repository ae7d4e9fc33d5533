"""The wire-wound mirror in the Mitsuba scene (scet_render.render.wire_mirror): what is drawn
instead of the point lights, the wire's geometry against the solver's, its material, and (slow)
rendered glints on the two-bounce labels."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from estimator.geometry.wire import setup_wire_mirrors
from estimator.geometry.wire_model import LedBeam, enamelled_copper_reflectance, fresnel_unpolarized
from estimator.scene import load_scene
from scet_render.render.layout import SCENE_UNITS_PER_M
from scet_render.render.scene import describe_scene
from scet_render.render.wire_mirror import strip_mesh, wire_mirror_objects, wire_reflectance_scale


@pytest.fixture(scope="module")
def setup():
    return load_scene("prototype_ov5647_wire")


@pytest.fixture(scope="module")
def mirror(setup):
    ((_, _, m),) = setup_wire_mirrors(setup)
    return m


def test_scene_draws_wire_strip_and_led_not_points(setup, mirror):
    desc = describe_scene(setup)
    objs = desc.objects
    assert not any(k.startswith("light_") for k in objs)
    turns = [k for k in objs if k.startswith("wire0_turn_")]
    assert len(turns) == mirror.turns
    assert objs["wire0_led"]["emitter"]["type"] == "area"
    assert "wire0_strip" in desc.meshes
    # The point-light scene of the same lights draws spheres instead.
    plain = describe_scene(load_scene("prototype_ov5647")).objects
    assert sum(k.startswith("light_") for k in plain) == mirror.turns


def test_cylinders_are_the_solvers_wire(setup, mirror):
    objs = describe_scene(setup).objects
    for i, axis in enumerate(mirror.wire_axes_m):
        c = objs[f"wire0_turn_{i:03d}"]
        p0, p1 = np.array(c["p0"]) / SCENE_UNITS_PER_M, np.array(c["p1"]) / SCENE_UNITS_PER_M
        np.testing.assert_allclose(0.5 * (p0 + p1), axis, atol=1e-15)
        np.testing.assert_allclose(p1 - p0, mirror.width_m * mirror.normal, atol=1e-15)
        assert c["radius"] == pytest.approx(mirror.wire_radius_m * SCENE_UNITS_PER_M)


def test_strip_mesh_carries_the_wire(mirror):
    m = strip_mesh(mirror)
    assert m.is_watertight
    # Every vertex lies on the band (inner face R, outer face R + t, within the width).
    rel = m.vertices - mirror.center_m
    z = rel @ mirror.normal
    r = np.hypot(rel @ mirror.u, rel @ mirror.v)
    assert np.all(np.abs(z) <= 0.5 * mirror.width_m + 1e-12)
    assert np.all((np.abs(r - mirror.radius_m) < 1e-12) | (np.abs(r - mirror.radius_m - mirror.thickness_m) < 1e-12))
    # The wire touches the inner face and does not cut into its chords (sag < 1 µm).
    assert mirror.radius_m * (1 - np.cos(np.pi / 720)) < 1e-6


def test_wire_material_tracks_the_enamelled_copper():
    """The conductor (Cu at 850 nm, scaled) against the layered model, 0-70 deg incidence."""
    c = np.cos(np.radians(np.arange(0, 71, 5)))
    from estimator.geometry.wire_model import COPPER_INDEX_850NM

    drawn = wire_reflectance_scale() * fresnel_unpolarized(c, 1.0, COPPER_INDEX_850NM)
    assert np.abs(drawn / enamelled_copper_reflectance(c) - 1).max() < 0.013


def test_non_lambertian_led_is_refused(mirror):
    narrow = replace(mirror, beam=LedBeam.cos_power(np.radians(20.0)))
    with pytest.raises(ValueError, match="cos\\^"):
        wire_mirror_objects(narrow, "w", radiance=1.0, split=True)


#: The rendered LED's diameter (m): the glint of a 0.5 mm LED through a 0.8 mm wire is a line
#: ~0.01 px wide, hit by ~1 % of a pixel's paths; at 2 mm (a 5 mm lensed LED's apparent
#: emitter) 1024 spp reach the labels. Its glints are compared with the solver's glints
#: averaged over the LED's disk (estimator.geometry.wire.led_disk_glints): 0.31 px median,
#: 0.87 px max from the centre's glints at this pose, where part of a disk's highlight leaves
#: the strip.
RENDER_LED_M = 2e-3
#: Rendered glint centroids against the disk-averaged labels (px): the issue's 0.1 px median;
#: measured 0.095 px median at 1024 spp (35 glints, one pose, 640 x 480; 0.222 / 0.125 px at
#: 64 / 256 spp, benchmarks/bench_wire_render.py).
RENDER_MEDIAN_PX = 0.1
#: The largest error, 0.358 px measured, is at the two glints whose LED image is 23-29 % off the
#: strip (the labels there 0.6-0.7 px from the centre's glints): the disk average, weighted
#: uniformly or by each point's glint flux (tried: 0.357 px), is the clipped glint's centroid to
#: ~0.3 px; glints whose disk lies on the strip are within 0.22 px.
RENDER_MAX_PX = 0.4


@pytest.fixture(scope="module")
def rendered(setup):
    """The prototype wire scene at full size, rows of the glints only, strobe light only,
    conductor cornea, at 256 and 1024 spp (the per-band frozen renderer's render_rows)."""
    pytest.importorskip("mitsuba")
    from estimator.geometry.wire import eye_wire_glints, led_disk_glints
    from estimator.setup import LightGroup
    from scet_render.render import BandedRenderer
    from tests.scet_render.centroids import glint_centroids

    g0 = setup.lights.groups[0]
    big = replace(g0.emitter, led_diameter_m=RENDER_LED_M)
    s = replace(setup, lights=replace(setup.lights, groups=(
        LightGroup(g0.name, g0.kind, g0.points_local_m, g0.pose, g0.source_radius_m, big),)))
    ((_, _, mirror),) = setup_wire_mirrors(s)
    yaw, pitch = -0.10, 0.05
    g = eye_wire_glints(s.eye, s.camera, mirror, yaw, pitch)
    disk, _ = led_disk_glints(s.eye, s.camera, mirror, yaw, pitch)
    vis = g.visible & np.isfinite(disk).all(-1)
    labels = disk[vis]
    rows = (int(labels[:, 1].min()) - 6, int(labels[:, 1].max()) + 7)
    r = BandedRenderer(s, spp=16, cornea="conductor", ambient=0.0, seed=1)
    out = {}
    for spp in (256, 1024):
        strobe, _ = r.render_rows(yaw, pitch, row_start=rows[0], row_stop=rows[1], seed=2, spp=spp)
        img = np.zeros((s.camera.height_px, s.camera.width_px), np.float32)
        img[rows[0]:rows[1]] = strobe
        c, _ = glint_centroids(img, labels, labels)
        out[spp] = np.linalg.norm(c - labels, axis=-1)
    return out


@pytest.mark.slow  # ~140 s on 2 cores
def test_rendered_wire_glints_land_on_the_labels(rendered):
    d = rendered[1024]
    assert np.isfinite(d).all() and d.size >= 20
    assert np.median(d) <= RENDER_MEDIAN_PX
    assert d.max() < RENDER_MAX_PX


@pytest.mark.slow
def test_rendered_wire_glints_converge(rendered):
    # Plain path tracing of the specular chain: more samples, closer centroids.
    assert np.median(rendered[1024]) < np.median(rendered[256])
