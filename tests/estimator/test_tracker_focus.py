"""Focused detection with its fallback (issue 31): the tracker that searches each frame only
around the glints it expects gives the whole-frame tracker's accepted samples, on a stream with
clutter and a saccade that leaves the focused window."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.glints import GlintDetector
from estimator.scene import load_scene
from estimator.tracking import Tracker
from tests.estimator.simulated import ground_truth_calibration, ground_truth_glints
from tests.estimator.test_tracker import FOCUS_SAME_SCREEN_M, draw_frame

#: The saccade: the eye jumps by this much in yaw (deg) between two frames, from fixating the
#: screen's centre: within the plausibility check's reach one frame later (16 deg), so the
#: whole-frame tracker follows it, and beyond a window of :data:`TIGHT_MARGIN_PX` (paper_sim's
#: glints move 3.6 px/deg: 22 px).
SACCADE_DEG = 6.0
#: A focused window's margin too small for the saccade (px; the tracker's own is how far a
#: glint moves over one frame period of the fastest eye, 66 px here): a window that does not
#: hold the next frame's glints, as a failed prediction gives.
TIGHT_MARGIN_PX = 8


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def stream(setup):
    """Ten frames: the eye fixates the screen's centre, jumps at frame 4 and stays; every frame
    has two blobs in its corners, one in the glints' rows 200 px to their side and, from the
    saccade on, one amid where the glints were (the focused window is not empty then)."""
    rng = np.random.default_rng(11)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    g, vis, _ = ground_truth_glints(setup, float(yaw[0]), float(pitch[0]))
    u0, v0 = np.rint(g[vis].mean(axis=0)).astype(int)
    imgs = []
    for f in range(10):
        y = float(yaw[0]) + (np.radians(SACCADE_DEG) if f >= 4 else 0.0)
        img = draw_frame(setup, f, y, float(pitch[0]), rng)
        for v, u in ((440, 600), (10, 10), (230, 30)) + (((v0 - 3, u0 - 3),) if f >= 4 else ()):
            img[v:v + 7, u:u + 7] += 400
        imgs.append(img)
    return imgs


def track(setup, imgs, focus: bool, fallback: bool = True):
    tr = Tracker(setup, ground_truth_calibration(setup), "geometric", focus_detection=focus)
    tr.focus_fallback = fallback
    tr.detector.roi_margin_px = TIGHT_MARGIN_PX
    return [s for f, img in enumerate(imgs) for s in tr.process(img, f)], tr


def test_focused_detection_with_the_fallback_gives_the_whole_frames_accepted_samples(
        setup, stream):
    """Every band the whole-frame tracker accepts, the focused one accepts with the same lights
    and the same screen point (to FOCUS_SAME_SCREEN_M), and no other: after the saccade
    glints lie outside the (too tight) window; the last sample expecting glints beyond the
    window's edge, those bands take their rows' detections across the whole width (the
    fallback). Without the fallback the focused tracker loses two bands of the saccade's
    frame and accepts another prior-assisted from the 2 of its 5 glints left in the window."""
    whole, _ = track(setup, stream, focus=False)
    focused, tr = track(setup, stream, focus=True)
    bare, _ = track(setup, stream, focus=True, fallback=False)
    ok = [s.ok for s in whole]
    at = [s.frame_index == 4 for s in whole]
    assert sum(ok[:at.index(True)]) > 0 and sum(o for o, a in zip(ok, at) if a) > 0
    assert [s.ok for s in focused] == ok
    for a, b in zip(whole, focused):
        if a.ok:
            assert np.array_equal(a.light_index, b.light_index)
            assert np.abs(a.screen_xy_m - b.screen_xy_m).max() < FOCUS_SAME_SCREEN_M
    assert tr.refocused > 0 and tr.detector.strips == tr.refocused
    assert tr.detector.windowed >= len(stream) - 2  # the first frame and at most one more whole
    assert sum(s.ok for s in bare if s.frame_index == 4) < sum(o for o, a in zip(ok, at) if a)
    assert any(a.ok and b.ok and b.light_index.size < a.light_index.size
               for a, b in zip(whole, bare))  # a band the window cut, accepted from the rest


def test_the_fallbacks_strip_is_the_whole_frames_band(setup, stream):
    """GlintDetector.rows_of: a band's rows searched again across the whole width give the
    whole frame's detections of that band (the blob at its side included) with the same noise
    model, to 1e-9 px (centroids computed in the strip's coordinates)."""
    tr = Tracker(setup, ground_truth_calibration(setup), "geometric", focus_detection=True)
    tr.process(stream[0], 0)
    tr.process(stream[1], 1)
    assert tr.detector.window is not None
    strip = tr.detector.rows_of(200, 260)
    plain = GlintDetector(tr.detector.setup, track_roi=False)  # the frame 0's noise model
    plain(stream[0], 0)
    whole = plain(stream[1], 1)
    for det in (strip, whole):
        assert ((det.u_px < 40) & (det.v_px > 225) & (det.v_px < 240)).sum() == 1  # the blob
    rows = (strip.v_px >= 205) & (strip.v_px <= 255)
    near = (whole.v_px >= 205) & (whole.v_px <= 255)
    assert rows.sum() == near.sum() > 1
    a = np.stack([strip.u_px[rows], strip.v_px[rows]], axis=1)
    b = np.stack([whole.u_px[near], whole.v_px[near]], axis=1)
    assert np.abs(a[np.lexsort(a.T)] - b[np.lexsort(b.T)]).max() < 1e-9


def test_focused_detection_through_a_distorting_lens(setup):
    """The window is placed in the frame's own pixels: with a strong barrel lens (glints drawn
    where it puts them, tracked with it) the focused tracker windows every frame after the
    first and its accepted samples are the whole-frame tracker's."""
    from tests.estimator.test_camera_file_tracker import DIST, _frames
    from dataclasses import replace
    from estimator.lens import ideal_setup
    lens = replace(setup, camera=replace(setup.camera, distortion=DIST))
    frames, _ = _frames(setup, lens.camera, n=4)
    cal = ground_truth_calibration(ideal_setup(lens))
    out = {}
    for focus in (False, True):
        tr = Tracker(lens, cal, "polynomial", focus_detection=focus)
        out[focus] = [s for f, img in enumerate(frames) for s in tr.process(img, f)]
    assert tr.detector.windowed == len(frames) - 1
    assert [s.ok for s in out[True]] == [s.ok for s in out[False]] and any(s.ok for s in out[True])
    for a, b in zip(out[False], out[True]):
        if a.ok:
            assert np.array_equal(a.light_index, b.light_index)
            assert np.abs(a.screen_xy_m - b.screen_xy_m).max() < FOCUS_SAME_SCREEN_M
