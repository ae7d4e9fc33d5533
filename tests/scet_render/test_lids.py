"""Lids that follow the eye, blinks, lashes, and the labels of the glints they hide or cut.

Geometry, scene keys and blink kinematics are tested without Mitsuba; the renders (160x120 and
640x480 at 2-8 spp, conductor cornea: exact glints at low spp) skip without it.
"""

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from estimator.errors import SceneError
from estimator.eyelids import (
    MAX_BLINK_RATE_PER_MIN,
    always_closed,
    cornea_angular_radius,
    screen_pitch_range,
)
from estimator.scene import parse_scene
from scet_render.motion import (
    BLINK_DURATION_RANGE_S,
    BlinkModel,
    Blinks,
    blink_schedule,
    with_blinks,
)
from scet_render.render import (
    BandedRenderer,
    LidOccluder,
    describe_scene,
    eye_layout,
    lash_mesh,
    lid_transforms_m,
    moving_lid_meshes,
)
from scet_render.simulate import ground_truth_glints
from tests.scet_render.test_rolling_shutter import (
    _saccade,
    _saccade_frame,
    _small,
    assert_frame_compiles_nothing,
)


@dataclass(frozen=True)
class Tol:
    #: Margin elevation against upper_margin + gain x pitch (rad): a rigid rotation of float64
    #: vertices, exact to rounding (1e-16 relative of angles below 2 rad).
    margin_rad: float = 1e-12
    #: Rendered glint peak radiance (W sr^-1 m^-2, light radiance 1000, conductor F0 = 0.025):
    #: an unblocked glint's brightest pixel reads ~25 (measured 25.0 at 640x480, 4 spp); lid
    #: skin under the strobe reads 1-4. A glint counts as seen above 10 and as hidden below 6.
    glint_seen_radiance: float = 10.0
    glint_hidden_radiance: float = 6.0


TOL = Tol()
LIDS = "\n[eyelids]\nlash_count = 40\n"


@pytest.fixture(scope="module")
def paper_text():
    return (Path(__file__).resolve().parents[2] / "scenes" / "paper_sim.toml").read_text()


@pytest.fixture(scope="module")
def lidded(paper_text):
    return parse_scene(paper_text + LIDS, "lids.toml")


# --------------------------------------------------------------------------- scene keys


def test_scenes_without_an_eyelids_table_keep_the_static_lids(paper_text):
    setup = parse_scene(paper_text, "paper_sim.toml")
    assert setup.eyelids is None
    objects = describe_scene(setup).objects
    assert objects["lid_upper"]["type"] == "ply" and "lid_upper_shape" not in objects


def test_default_margins_clear_the_cornea_at_every_screen_gaze(lidded):
    lids, eye = lidded.eyelids, lidded.eye
    cap = cornea_angular_radius(eye)
    p = np.linspace(*screen_pitch_range(eye, lidded.screen), 50)
    upper, lower = lids.margins_rad(p)
    assert np.all(upper >= p + cap + math.radians(5.0) - 1e-12)
    assert np.all(lower <= p - cap - math.radians(5.0) + 1e-12)
    assert not always_closed(lids, eye, lidded.screen)


@pytest.mark.parametrize("lines, key", [
    ("blink_rate_per_min = 80", "eyelids.blink_rate_per_min"),
    ("upper_margin_deg = -40", "eyelids.upper_margin_deg"),
    ("lower_margin_deg = 60", "eyelids.lower_margin_deg"),
    ("upper_margin_deg = 10\nlower_margin_deg = 20", "eyelids.upper_margin_deg"),
    ("upper_gain = 3.0", "eyelids.upper_gain"),
    ("lash_count = -1", "eyelids.lash_count"),
    ("lash_length_mm = 50", "eyelids.lash_length_mm"),
    ("upper_margin_m = 0.1", "eyelids.upper_margin_m"),
    ("blinks = 3", "eyelids.blinks"),
])
def test_bad_eyelid_keys_raise_scene_error_naming_the_key(paper_text, lines, key):
    with pytest.raises(SceneError) as info:
        parse_scene(paper_text + f"\n[eyelids]\n{lines}\n", "bad.toml")
    assert f"'{key}'" in str(info.value) and "bad.toml" in str(info.value)


def test_scet_scene_describes_the_lids_and_refuses_bad_ones(paper_text, tmp_path, capsys):
    from scet_render.cli import main

    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text(paper_text + LIDS + "blink_rate_per_min = 20\n")
    bad.write_text(paper_text + "\n[eyelids]\nblink_rate_per_min = 90\n")
    assert main(["scene", str(good)]) == 0
    assert "0.9 x pitch" in capsys.readouterr().out
    assert main(["scene", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'eyelids.blink_rate_per_min'" in err[0] and "bad.toml" in err[0]


def test_a_blink_rate_above_the_physiological_maximum_is_refused_by_the_model():
    with pytest.raises(ValueError, match="rate_per_min"):
        blink_schedule(10.0, MAX_BLINK_RATE_PER_MIN + 1, 0)


# --------------------------------------------------------------------------- lid geometry


def _margin_elevation(mesh, transform, center, lowest: bool):
    """Elevation (rad) of the margin vertex on the vertical meridian (x = 0) after a pose."""
    v = mesh.vertices
    on_meridian = np.abs(v[:, 0] - center[0]) < 1e-12
    rel = v[on_meridian] - center
    theta = np.arctan2(rel[:, 1], -rel[:, 2])
    margin = rel[np.argmin(theta) if lowest else np.argmax(theta)]
    posed = transform[:3, :3] @ margin
    return math.atan2(posed[1], -posed[2])


@pytest.mark.parametrize("pitch_deg", [-16.0, -5.0, 0.0, 8.0])
def test_lid_margins_follow_the_pitch_with_their_gains(lidded, pitch_deg):
    lids, c = lidded.eyelids, lidded.eye.rotation_center_m
    upper, lower = moving_lid_meshes(lidded, eye_layout(lidded), lids)
    p = math.radians(pitch_deg)
    T = lid_transforms_m(lidded, lids, p)
    got_up = _margin_elevation(upper, T["lid_upper"], c, lowest=True)
    got_low = _margin_elevation(lower, T["lid_lower"], c, lowest=False)
    assert abs(got_up - (lids.upper_margin_rad + lids.upper_gain * p)) < TOL.margin_rad
    assert abs(got_low - (lids.lower_margin_rad + lids.lower_gain * p)) < TOL.margin_rad


def test_a_shut_lid_passes_the_lower_margin_everywhere(lidded):
    """At closure 1 the upper margin lies below the lower one at every side angle (a rotation
    about x shifts a margin's rotation angle uniformly): no crack along the lids."""
    lids, c = lidded.eyelids, lidded.eye.rotation_center_m
    upper, lower = moving_lid_meshes(lidded, eye_layout(lidded), lids)
    T = lid_transforms_m(lidded, lids, 0.0, closure=1.0)
    rel_up = (upper.vertices - c) @ T["lid_upper"][:3, :3].T
    theta_up = np.arctan2(rel_up[:, 1], -rel_up[:, 2])
    rel_low = lower.vertices - c
    theta_low = np.arctan2(rel_low[:, 1], -rel_low[:, 2])
    front = (rel_up[:, 2] < 0)
    assert theta_up[front].min() < theta_low.max() - math.radians(1.0)


def test_lashes_are_seeded(lidded):
    layout = eye_layout(lidded)
    a, b = lash_mesh(lidded, layout, lidded.eyelids), lash_mesh(lidded, layout, lidded.eyelids)
    assert a.vertices.tobytes() == b.vertices.tobytes() and len(a.faces) > 40 * 10
    other = lash_mesh(lidded, layout, dataclasses.replace(lidded.eyelids, lash_seed=1))
    assert other.vertices.tobytes() != a.vertices.tobytes()


# --------------------------------------------------------------------------- blinks


def test_blink_durations_lie_in_the_reported_range():
    model = BlinkModel()
    amplitude = np.linspace(0.05, 1.0, 20)
    close, _, opening = model.phases_s(amplitude)
    total = model.duration_s(amplitude)
    assert np.all((total >= BLINK_DURATION_RANGE_S[0]) & (total <= BLINK_DURATION_RANGE_S[1]))
    assert np.all(opening > 2 * close)  # the up phase is the slower one
    peak = model.peak_closing_speed_per_s(amplitude)
    assert np.all(np.diff(peak) > 0)  # main sequence: larger blinks close faster


def test_blink_closure_rises_to_the_amplitude_and_reopens():
    model = BlinkModel()
    blinks = Blinks([0.1, 0.8], [1.0, 0.5], model)
    t = np.linspace(0.0, 1.5, 150001)  # 10 us steps
    c = blinks.closure_at(t)
    close, hold, opening = model.phases_s(1.0)
    assert c[t < 0.1].max() == 0.0 and c[(t > 0.1 + close) & (t < 0.1 + close + hold)].min() == 1.0
    assert c[(t > 0.8) & (t < 1.2)].max() == pytest.approx(0.5, abs=1e-9)
    assert c[t > blinks.end_s[-1]].max() == 0.0
    # Continuous: the fastest closing moves 2 A / D_c per second, 10 us at a time.
    assert np.abs(np.diff(c)).max() <= 1e-5 * model.peak_closing_speed_per_s(1.0) * 1.001


def test_blink_schedules_are_seeded_and_keep_the_mean_rate():
    a, b = blink_schedule(600.0, 17.0, 5), blink_schedule(600.0, 17.0, 5)
    assert a.start_s.tobytes() == b.start_s.tobytes()
    # 170 blinks expected in 10 min; the dead time makes the count less variable than a
    # Poisson count (SD 13): 4 SD is 52.
    assert abs(a.start_s.size - 170) < 52
    assert np.all(a.start_s[1:] >= a.end_s[:-1])


def test_a_trajectory_carries_its_blinks(lidded):
    traj = _saccade(lidded)
    assert np.all(traj.lid_closure_at(np.linspace(0, 0.5, 11)) == 0)
    blinked = with_blinks(traj, Blinks([0.1], [1.0]))
    assert blinked.lid_closure_at(0.2) == 1.0
    assert np.array_equal(blinked.angles_at(0.2)[0], traj.angles_at(0.2)[0])


# --------------------------------------------------------------------------- renders


@pytest.fixture(scope="module")
def mi():
    pytest.importorskip("mitsuba")
    from scet_render.render import activate

    return activate()


def test_moving_lids_and_blinks_compile_nothing(mi, lidded):
    if mi.variant().startswith("scalar"):
        pytest.skip("scalar_rgb compiles no kernels")
    small = _small(lidded)
    traj = _saccade(small)
    f = _saccade_frame(small, traj)
    # A complete blink from the start of frame f + 1: the lid moves through both frames.
    onset = (f + 1) * small.sensor.frame_period_s
    traj = with_blinks(traj, Blinks([onset], [1.0]))
    renderer = BandedRenderer(small, seed=7, spp=8, blur_step_px=0.5, cornea="conductor")
    assert_frame_compiles_nothing(renderer, traj, f)
    frame = renderer.render_frame(traj, f + 2)
    assert np.ptp(frame.lid_closure) > 0.1  # the lid moved within the frame


def _glint_peaks(img, glints_px, half_px=1):
    out = np.full(len(glints_px), np.nan)
    for i, (u, v) in enumerate(glints_px):
        x, y = int(round(u)), int(round(v))
        if half_px <= x < img.shape[1] - half_px and half_px <= y < img.shape[0] - half_px:
            out[i] = img[y - half_px:y + half_px + 1, x - half_px:x + half_px + 1].max()
    return out


@pytest.fixture(scope="module")
def glint_renderer(mi, lidded):
    return BandedRenderer(lidded, cornea="conductor", spp=2, ambient=0.0, seed=3)


@pytest.fixture(scope="module")
def occluder(mi, lidded):
    return LidOccluder(lidded, mi=mi)


@pytest.mark.parametrize("yaw, pitch, closure", [(0.0, 0.0, 1.0), (0.0, 0.0, 0.35),
                                                 (0.1, 0.05, 0.3)])
def test_labels_and_render_agree_on_the_glints_a_lid_hides(glint_renderer, occluder, lidded,
                                                           yaw, pitch, closure):
    img = glint_renderer.render_global(yaw, pitch, closure=closure)
    glints, visible, _ = ground_truth_glints(lidded, yaw, pitch)
    occ = occluder.glints(yaw, pitch, closure)
    hidden, clear = occ.hidden[0] & visible, (occ.blocked_fraction[0] == 0) & visible
    peaks = _glint_peaks(img, glints)
    if closure == 1.0:
        assert hidden.sum() == visible.sum() > 30  # a shut lid hides every glint
        assert img.max() < TOL.glint_hidden_radiance
    else:
        assert hidden.any() and clear.any()
    assert np.all(peaks[hidden] < TOL.glint_hidden_radiance)
    assert np.all(peaks[clear] > TOL.glint_seen_radiance)


def test_lashes_cut_glints_in_down_gaze(occluder):
    """Looking down lowers the upper lid and its lashes into the lights' paths: some glints
    are cut (part of the spot blocked) by a lash, none hidden by a lid."""
    occ = occluder.glints(0.0, -0.25, 0.0)
    assert occ.cut[0].sum() >= 3 and np.all(occ.occluder[0][occ.cut[0]] == 2)
    assert not (occ.occluder[0] == 1).any()


def test_dataset_labels_say_what_hides_each_glint(mi, paper_text, tmp_path):
    """A 160x120 dataset of a blinking, lashed eye: its labels carry the lid closure and each
    glint's occluder, and a glint a lid hides is not visible; a lidless run writes none."""
    from scet_render.dataset import dataset_trajectory, iter_labels, render_dataset

    text = paper_text + LIDS + "blink_rate_per_min = 60\n"
    setup = _small(parse_scene(text, "lids.toml"))
    traj = dataset_trajectory(setup, "fixations", 60, seed=2)
    assert traj.blinks is not None and traj.blinks.start_s.size >= 1
    onset = traj.blinks.start_s[0]
    frame = int(onset // setup.sensor.frame_period_s) + 3  # the lid well on its way down
    render_dataset(setup, tmp_path / "d", frames=frame + 1, spp=1, seed=2, cornea="conductor",
                   scene_text=text)
    labels = [lab for lab in iter_labels(tmp_path / "d") if lab.frame == frame]
    assert labels and all(lab.lid_closure > 0 for lab in labels)
    assert any(np.any(lab.glints_blocked_fraction >= 1.0) for lab in labels)
    for lab in labels:
        hidden = lab.glints_blocked_fraction >= 1.0
        assert len(lab.glints_occluder) == lab.glints_px.shape[0]
        assert not np.any(lab.glints_visible & hidden)
        assert lab.pupil_occluder in ("none", "lid", "lash")
        assert 0.0 <= lab.pupil_edge_visible_fraction <= 1.0
        # A pupil centre the lid covers leaves its edge less than whole.
        assert lab.pupil_occluder == "none" or lab.pupil_edge_visible_fraction < 1.0
    plain = render_dataset(setup, tmp_path / "e", frames=1, spp=1, seed=2, cornea="conductor",
                           scene_text=text, eyelid_openness=None)
    first = next(iter_labels(plain.path))
    assert first.glints_occluder is None and first.lid_closure == 0.0
    assert first.pupil_occluder is None and first.pupil_edge_visible_fraction is None


@pytest.mark.parametrize("closure", [0.0, 0.45, 0.5, 1.0])
def test_pupil_occlusion_labels_match_the_rendered_mask(glint_renderer, occluder, lidded,
                                                        closure):
    """The pupil labels' occlusion (:meth:`LidOccluder.toward_camera` on the refraction points
    of the pupil's centre and 64 edge points) against the renderer's own mask of the same
    pose: wherever a point's pixel and its 8 neighbours are all lid/lash or all not, the label
    says the same (a lid edge within a pixel of a point decides nothing at 1 px resolution).
    A blink's closing lid covers the pupil from none (0) through part of it (0.5: the
    centre and about half the edge; measured 33 % of the edge at 0.45, 53 % at 0.5) to all of
    it (1)."""
    from scet_render.render import MASK_CLASSES, pose_mask, pupil_image

    pupil = pupil_image(lidded, 0.0, 0.0)
    codes = occluder.toward_camera(0.0, closure, pupil.surface_m[None])[0]
    px, _ = lidded.camera.project(pupil.surface_m)
    x, y = np.rint(px[:, 0]).astype(int), np.rint(px[:, 1]).astype(int)
    rows = np.arange(y.min() - 1, y.max() + 2)
    mask = pose_mask(glint_renderer, 0.0, 0.0, closure=closure, rows=rows)
    covered = np.isin(mask, [MASK_CLASSES.index("lid"), MASK_CLASSES.index("lash")])
    decided = 0
    for i in range(len(codes)):
        block = covered[y[i] - rows[0] - 1:y[i] - rows[0] + 2, x[i] - 1:x[i] + 2]
        if block.all() or not block.any():
            decided += 1
            assert (codes[i] > 0) == block.all(), (i, codes[i])
    assert decided >= 50  # of 65 points, most are not within a pixel of a lid edge
    blocked = (codes[1:] > 0).mean()
    expected = {0.0: (0.0, 0.0), 0.45: (0.1, 0.5), 0.5: (0.35, 0.75), 1.0: (1.0, 1.0)}[closure]
    assert expected[0] <= blocked <= expected[1]
