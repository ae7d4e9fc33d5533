"""The tracker on images: stream contract, folder readers, bad input (no rendering here).

Frames are drawn analytically: a dark eye-like background with Gaussian glints at the
closed-form glint positions, each row scaled by the pulse weights of its band, so the banding,
detection, matching and gaze code all run for real.
"""

import json

import cv2
import numpy as np
import pytest

from estimator.banding import band_layout, row_pulse_weights
from estimator.calibration import Calibration
from estimator.scene import load_scene
from estimator.folders import (load_calibration, read_samples_csv, read_timing,
                               save_calibration, timing_document, track_folder)
from estimator.tracker import (INTERNAL_ERROR, SATURATED_FRAME, UNREADABLE_FRAME,
                               WRONG_FRAME_SIZE, BandPrior, Tracker, TrackerInputError)
from tests.estimator.simulated import ground_truth_calibration, ground_truth_glints

DT = None


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def calibration(setup):
    return ground_truth_calibration(setup)


def draw_frame(setup, frame, yaw, pitch, rng, hide=()):
    """A 10-bit banded frame of the eye at fixed (yaw, pitch), without the glints of the
    lights in ``hide``."""
    H, W = setup.camera.height_px, setup.camera.width_px
    j, _, w = row_pulse_weights(setup.sensor, setup.strobe, frame)
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    vis = vis.copy()
    vis[list(hide)] = False
    yy, xx = np.mgrid[0:H, 0:W]
    img = np.zeros((H, W))
    for (u, v), ok in zip(g, vis):
        if ok:
            img += 600.0 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 1.2 ** 2))
    img = img * w.sum(axis=1)[:, None] + 60.0 * w.sum(axis=1)[:, None] + 16.0
    img += rng.normal(0.0, 2.0, img.shape)
    return np.clip(np.rint(img), 0, 1023).astype(np.uint16)


@pytest.fixture(scope="module")
def frames(setup):
    rng = np.random.default_rng(1)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    return [draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng) for f in range(3)], \
        setup.screen.grid(1, 1)[0]


def test_one_sample_per_visible_band_stamped_with_the_strobe_instant(setup, calibration, frames):
    tr = Tracker(setup, calibration, "polynomial")
    imgs, target = frames
    for f, img in enumerate(imgs):
        out = tr.process(img, f)
        bands = [b for b in band_layout(setup.sensor, setup.strobe, f) if b.visible]
        assert [s.strobe_index for s in out] == [b.pulse_index for b in bands]
        # s_j + Δs / 2 from the banding model, not the frame time f Δt.
        want = [b.strobe_time_s + 0.5 * setup.strobe.pulse_s for b in bands]
        assert np.allclose([s.time_s for s in out], want, atol=1e-12)
        for s in out:
            assert s.ok or (np.isnan(s.screen_xy_m).all() and s.reason != "ok")
        ok = [s for s in out if s.ok]
        assert ok, "a band crossing the glint arc gives a sample"
        err_m = np.linalg.norm(np.array([s.screen_xy_m for s in ok]) - target[:2], axis=1)
        # 1 cm at 70 cm is 0.8 deg: noiseless glints, the Eq. (1) mapping is exact to ~1 mm.
        assert err_m.max() < 0.01


def test_an_impossible_jump_between_bands_is_nan(setup, calibration):
    """The eye at one target, then 20 deg away in the next frame (1 ms between the last band
    of one and the first of the next; 600 deg/s per axis allows 2.8 deg with the slack): the
    far frame's own identifications are NaN with IMPLAUSIBLE_JUMP while the previous sample
    is under JUMP_AGE_S old, and accepted again once it is older."""
    from estimator.tracker import IMPLAUSIBLE_JUMP, JUMP_AGE_S
    rng = np.random.default_rng(4)
    targets = setup.screen.grid(2, 1)
    yaw, pitch = setup.eye.angles_toward(targets)
    assert np.degrees(abs(yaw[1] - yaw[0])) > 15
    near = [draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng) for f in range(2)]
    far = draw_frame(setup, 2, float(yaw[1]), float(pitch[1]), rng)
    tr = Tracker(setup, calibration, "geometric")
    before = tr.process(near[0], 0) + tr.process(near[1], 1)
    last_ok = max(s.time_s for s in before if s.ok)
    out = tr.process(far, 2)
    jumped = [s for s in out if s.reason == IMPLAUSIBLE_JUMP]
    assert jumped and not any(s.ok and s.time_s - last_ok <= JUMP_AGE_S for s in out)
    assert all(np.isnan(s.screen_xy_m).all() for s in jumped)
    # The same frame with no recent sample before it: identified and accepted.
    fresh = Tracker(setup, calibration, "geometric").process(far, 2)
    assert any(s.ok for s in fresh) and not any(s.reason == IMPLAUSIBLE_JUMP for s in fresh)


def test_frame_start_shifts_sample_times(setup, calibration, frames):
    tr = Tracker(setup, calibration)
    a = tr.process(frames[0][0], 0)
    b = Tracker(setup, calibration).process(frames[0][0], 0, frame_start_s=0.5)
    assert np.allclose([s.time_s + 0.5 for s in a], [s.time_s for s in b])


@pytest.mark.parametrize("frame, reason", [
    (None, UNREADABLE_FRAME),
    (np.zeros((10, 10), np.uint16), WRONG_FRAME_SIZE),
    ("saturated", SATURATED_FRAME),
])
def test_bad_frames_give_nan_samples_with_a_reason(setup, calibration, frame, reason):
    if isinstance(frame, str):
        frame = np.full((setup.camera.height_px, setup.camera.width_px), 1023, np.uint16)
    out = Tracker(setup, calibration).process(frame, 0)
    assert out and all(s.reason == reason and np.isnan(s.screen_xy_m).all() for s in out)


def test_no_glints_gives_nan_samples(setup, calibration):
    img = np.full((setup.camera.height_px, setup.camera.width_px), 40, np.uint16)
    out = Tracker(setup, calibration).process(img, 0)
    assert out and all(not s.ok and s.reason.endswith("too_few_glints") for s in out)


def test_an_exception_inside_a_frame_does_not_stop_the_stream(setup, calibration, frames,
                                                             monkeypatch, caplog):
    tr = Tracker(setup, calibration)

    class Boom:
        def __call__(self, *a, **k):
            raise RuntimeError("detector exploded")

        def reset(self):
            pass

    monkeypatch.setattr(tr, "detector", Boom())
    out = tr.process(frames[0][0], 0)
    assert out and all(s.reason == f"{INTERNAL_ERROR}:RuntimeError" for s in out)
    assert "detector exploded" in caplog.text
    monkeypatch.undo()
    assert any(s.ok for s in tr.process(frames[0][1], 1))


# --------------------------------------------------------------------------- folders


def write_folder(path, setup, imgs, timing=True):
    (path / "frames").mkdir(parents=True)
    for f, img in enumerate(imgs):
        cv2.imwrite(str(path / "frames" / f"{f:06d}.png"), img)
    if timing:
        dt = setup.sensor.frame_period_s
        (path / "timing.json").write_text(timing_document({f: f * dt for f in range(len(imgs))}))
    return path


def test_track_folder_writes_a_versioned_csv(tmp_path, setup, calibration, frames):
    folder = write_folder(tmp_path / "run", setup, frames[0])
    out = tmp_path / "samples.csv"
    summary = track_folder(folder, setup, calibration, out)
    rows = read_samples_csv(out)
    assert len(rows) == len(summary.samples) and summary.n_ok > 0
    assert {r["reason"] for r in rows} >= {"ok"}
    assert not (tmp_path / "samples.csv.partial").exists()


def test_corrupt_and_truncated_frames_become_nan_samples(tmp_path, setup, calibration, frames):
    folder = write_folder(tmp_path / "run", setup, frames[0])
    p1 = folder / "frames" / "000001.png"
    p1.write_bytes(p1.read_bytes()[:200])  # truncated
    (folder / "frames" / "000002.png").write_bytes(b"not a png at all")
    summary = track_folder(folder, setup, calibration, tmp_path / "s.csv")
    by_frame = {}
    for s in summary.samples:
        by_frame.setdefault(s.frame_index, set()).add(s.reason)
    assert by_frame[1] == {UNREADABLE_FRAME} and by_frame[2] == {UNREADABLE_FRAME}
    assert "ok" in by_frame[0]


def test_missing_timing_names_the_folder(tmp_path, setup, calibration, frames):
    folder = write_folder(tmp_path / "run", setup, frames[0], timing=False)
    with pytest.raises(TrackerInputError, match="timing.json"):
        track_folder(folder, setup, calibration, tmp_path / "s.csv")


@pytest.mark.parametrize("text, key", [
    ("{", "cannot read JSON"),
    (json.dumps({"format": "other", "version": 1, "frames": {"0": 0.0}}), "format"),
    (json.dumps({"format": "scet-timing", "version": 99, "frames": {"0": 0.0}}), "version"),
    (json.dumps({"format": "scet-timing", "version": 1, "frames": {"x": 0.0}}), "'frames.x'"),
    (json.dumps({"format": "scet-timing", "version": 1, "frames": {}}), "'frames'"),
])
def test_malformed_timing_names_file_and_key(tmp_path, setup, text, key):
    (tmp_path / "timing.json").write_text(text)
    with pytest.raises(TrackerInputError, match=key) as info:
        read_timing(tmp_path, setup)
    assert "timing.json" in str(info.value)


def test_calibration_file_round_trip_and_bad_files(tmp_path, calibration):
    path = save_calibration(calibration, tmp_path / "cal.json")
    back = load_calibration(path)
    assert back.to_json() == calibration.to_json()
    (tmp_path / "bad.json").write_text('{"format": "scet-calibration", "version": 7}')
    with pytest.raises(TrackerInputError, match="bad.json"):
        load_calibration(tmp_path / "bad.json")
    with pytest.raises(TrackerInputError, match="missing.json"):
        load_calibration(tmp_path / "missing.json")


def test_a_failed_run_keeps_the_previous_csv(tmp_path, setup, calibration, frames):
    folder = write_folder(tmp_path / "run", setup, frames[0])
    out = tmp_path / "samples.csv"
    track_folder(folder, setup, calibration, out)
    before = out.read_bytes()
    (folder / "timing.json").write_text("{broken")
    with pytest.raises(TrackerInputError):
        track_folder(folder, setup, calibration, out)
    assert out.read_bytes() == before


# --------------------------------------------------------------------------- calibrated geometry


def test_the_matcher_predicts_from_the_calibrated_lighting_and_eye(setup, calibration):
    from dataclasses import replace

    from estimator.calibration import pose_correction

    corr = pose_correction([0.0, 0.02, 0.0], [3e-3, 0.0, -1e-3], setup.lights_world_m.mean(axis=0))
    cal = replace(calibration, lighting_correction=corr, cornea_radius_m=7.7e-3,
                  orbit_radius_m=4.2e-3)
    m = Tracker(setup, cal).matcher
    assert np.allclose(m.lights_world_m, cal.lights_world_m(setup.lights_world_m))
    assert m.eye.cornea_radius_m == 7.7e-3 and m.eye.cornea_offset_m == 4.2e-3
    assert np.allclose(m.problem.lights_world_m, m.lights_world_m)


# --------------------------------------------------------------------------- band prior


def sparse_band_frame(setup, keep=2, seed=3):
    """Frame 0 at the screen centre with one band cut down to ``keep`` glints, right after a
    band with enough of its own: (frame, band position among the samples, kept lights)."""
    yaw, pitch = (float(a[0]) for a in setup.eye.angles_toward(setup.screen.grid(1, 1)))
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    bands = [b for b in band_layout(setup.sensor, setup.strobe, 0) if b.visible]
    lights = [np.flatnonzero(vis & (g[:, 1] >= b.first_row) & (g[:, 1] <= b.last_row))
              for b in bands]
    k = next(i for i in range(1, len(bands)) if lights[i - 1].size >= 6 and lights[i].size > keep)
    hide = lights[k][keep:]
    img = draw_frame(setup, 0, yaw, pitch, np.random.default_rng(seed), hide=hide)
    return img, k, lights[k][:keep]


@pytest.mark.parametrize("method", ["polynomial", "geometric"])
def test_a_sparse_band_borrows_the_previous_band(setup, calibration, method):
    img, k, kept = sparse_band_frame(setup)
    target = setup.screen.grid(1, 1)[0]
    s = Tracker(setup, calibration, method).process(img, 0)[k]
    assert s.ok and s.prior_assisted and sorted(s.light_index) == sorted(kept)
    # Noiseless glints and the ground-truth calibration: exact to ~1 mm on the screen.
    assert np.linalg.norm(s.screen_xy_m - target[:2]) < 2e-3
    off = Tracker(setup, calibration, method, prior=None).process(img, 0)[k]
    assert not off.ok and off.reason == "match_too_few_glints" and not off.prior_assisted


def test_a_band_without_glints_stays_nan_despite_a_prior(setup, calibration):
    img, k, _ = sparse_band_frame(setup, keep=0)
    out = Tracker(setup, calibration).process(img, 0)
    assert out[k - 1].ok
    assert not out[k].ok and np.isnan(out[k].screen_xy_m).all() and not out[k].prior_assisted


def test_the_prior_grows_with_its_age_and_expires():
    p = BandPrior(eye_speed_max_deg_s=600.0, max_sd_deg=0.75)
    c0 = np.eye(2) * np.radians(0.05) ** 2
    one = p.predict(c0, 1.04e-3)  # one band period at 16 pulses per frame
    assert np.allclose(np.sqrt(np.diag(one)), np.hypot(np.radians(0.05), np.radians(0.624)))
    assert p.predict(c0, 2.08e-3) is None  # one band period at 8 pulses: too wide
    assert p.predict(c0, -1e-3) is None
    with pytest.raises(ValueError, match="eye_speed_max_deg_s"):
        BandPrior(eye_speed_max_deg_s=0.0)


def test_a_prior_does_not_smooth_a_saccade_away(setup):
    """One glint, the eye 0.6° past the prior mean (600°/s for one band period): the fit
    follows the glint, not the prior."""
    from estimator.gaze import geometric_gaze

    cal = Calibration.ground_truth(setup)
    yaw, pitch = np.radians(5.0), np.radians(-3.0)
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    one = np.full_like(g, np.nan)
    i = np.flatnonzero(vis)[len(np.flatnonzero(vis)) // 2]
    one[i] = g[i] + np.random.default_rng(0).normal(0.0, 0.3, 2)
    prior = BandPrior()
    cov = prior.predict(np.eye(2) * np.radians(0.05) ** 2, 1.04e-3)
    mean = np.array([yaw - np.radians(0.6), pitch])
    est = geometric_gaze(setup, cal, one[None], prior_mean_rad=mean, prior_cov_rad2=cov,
                         noise_px=prior.noise_px)
    err_deg = np.degrees(np.abs(est.angles_rad[0] - [yaw, pitch]))
    # The glint's 0.3 px is ~0.1° of rotation; the prior pulls by less than that.
    assert est.ok[0] and err_deg.max() < 0.15, err_deg


def test_samples_csv_marks_prior_assisted_samples_and_reads_version_1(tmp_path, setup,
                                                                      calibration):
    from estimator.folders import samples_csv

    img, k, _ = sparse_band_frame(setup)
    out = Tracker(setup, calibration).process(img, 0)
    path = tmp_path / "s.csv"
    path.write_text(samples_csv(out))
    assert path.read_text().startswith("# scet-samples 3\n")
    rows = read_samples_csv(path)
    assert [r["prior"] for r in rows] == [str(int(s.prior_assisted)) for s in out]
    assert rows[k]["prior"] == "1"
    old = tmp_path / "v1.csv"
    old.write_text("# scet-samples 1\nframe,strobe,reason\n0,3,ok\n")
    assert read_samples_csv(old) == [{"frame": "0", "strobe": "3", "reason": "ok", "prior": "0",
                                      "flux_flagged": ""}]
    (tmp_path / "v9.csv").write_text("# scet-samples 9\nframe\n")
    with pytest.raises(TrackerInputError, match="v9.csv"):
        read_samples_csv(tmp_path / "v9.csv")


def test_a_late_dropped_or_out_of_order_frame_is_flagged_not_a_lost_stream(setup, calibration,
                                                                         frames):
    """Frames 0, 2 (1 dropped), 1 (late: out of order), 2 again, 3: the old ones are NaN with
    their reason, the stream goes on from the newest, and the gap costs no stall."""
    imgs = frames[0]
    tr = Tracker(setup, calibration)
    first = tr.process(imgs[0], 0)
    after_gap = tr.process(imgs[2], 2)
    state = tr.state
    late = tr.process(imgs[1], 1)
    again = tr.process(imgs[2], 2)
    assert tr.state is state  # the old frames changed nothing
    assert late and all(s.reason == "frame_out_of_order" and np.isnan(s.screen_xy_m).all()
                        for s in late + again)
    assert [s.frame_index for s in late] == [1] * len(late)
    assert any(s.ok for s in first) and any(s.ok for s in after_gap)
    yaw, pitch = setup.eye.angles_toward(frames[1][None])
    nxt = draw_frame(setup, 3, float(yaw[0]), float(pitch[0]), np.random.default_rng(2))
    assert any(s.ok for s in tr.process(nxt, 3))


#: Focused and whole-frame detection give the same glints up to the window's offset (the
#: centroid is computed in window coordinates, 1e-9 px; test_glints.SAME_SPOT_PX): estimates
#: then agree far below any accuracy figure (1 um on the screen at 70 cm is 1e-4 deg).
FOCUS_SAME_SCREEN_M = 1e-6


def test_focused_detection_skips_far_clutter_and_gives_the_same_samples(setup, calibration):
    """Tracker(focus_detection=True) searches each frame around the glints its last frame's
    samples used: blobs in the frame's corners are not detected after the first frame, and
    the samples are the whole-frame tracker's (reasons, lights; estimates to
    FOCUS_SAME_SCREEN_M)."""
    rng = np.random.default_rng(7)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    imgs = []
    for f in range(5):
        img = draw_frame(setup, f, float(yaw[0]) + 0.002 * f, float(pitch[0]), rng)
        img[440:447, 600:607] += 400
        img[10:17, 10:17] += 400
        imgs.append(img)
    plain, focused = Tracker(setup, calibration, "geometric"), \
        Tracker(setup, calibration, "geometric", focus_detection=True)
    for f, img in enumerate(imgs):
        a, b = plain.process(img, f), focused.process(img, f)
        assert [s.reason for s in a] == [s.reason for s in b]
        assert any(s.ok for s in a)
        for x, y in zip(a, b):
            assert np.array_equal(x.light_index, y.light_index)
            if x.ok:
                assert np.abs(x.screen_xy_m - y.screen_xy_m).max() < FOCUS_SAME_SCREEN_M
    assert focused.detector.windowed == len(imgs) - 1 and plain.detector.windowed == 0
    y0, y1, x0, x1 = focused.detector.window
    for v, u in ((440, 600), (10, 10)):  # the blobs (7 x 7 px) are outside
        assert not (y0 < v + 7 and v < y1 and x0 < u + 7 and u < x1)


def test_focused_detection_searches_the_whole_frame_after_a_dropped_frame(setup, calibration):
    """The focused window allows for one frame of eye motion: after frames were dropped (a
    gap in the indices) the next frame is searched whole, and the stream goes on."""
    rng = np.random.default_rng(8)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    tr = Tracker(setup, calibration, "geometric", focus_detection=True)
    windows = []
    for f in (0, 1, 2, 6, 7):
        out = tr.process(draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng), f)
        assert any(s.ok for s in out)
        windows.append(tr.detector.window)
    assert windows[0] is None and windows[1] is not None and windows[2] is not None
    assert windows[3] is None and windows[4] is not None
