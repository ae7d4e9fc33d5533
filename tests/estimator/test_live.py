"""``scet track --follow``: a folder tracked while a writer thread adds its frames gives the
samples the whole folder gives, and stops on the end marker or on the timeout."""

import threading
import time

import cv2
import numpy as np

from estimator.folders import frame_path, timing_document, track_folder
from estimator.live import END_NAME, follow_frames, track_following
from tests.estimator.test_tracker import calibration, draw_frame, setup  # noqa: F401 fixtures


def frames_of(setup, n=4):
    rng = np.random.default_rng(3)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    return [draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng) for f in range(n)]


def write_frame(folder, f, img):
    path = frame_path(folder, f)
    tmp = path.with_suffix(".tmp")
    cv2.imwrite(str(tmp.with_suffix(".tmp.png")), img)
    tmp.with_suffix(".tmp.png").replace(path)


def test_following_a_folder_being_written_gives_the_folder_samples(tmp_path, setup,  # noqa: F811
                                                                   calibration):  # noqa: F811
    imgs = frames_of(setup)
    dt = setup.sensor.frame_period_s
    whole = tmp_path / "whole"
    (whole / "frames").mkdir(parents=True)
    (whole / "timing.json").write_text(timing_document({f: f * dt for f in range(len(imgs))}))
    for f, img in enumerate(imgs):
        write_frame(whole, f, img)
    ref = track_folder(whole, setup, calibration, tmp_path / "ref.csv")

    live = tmp_path / "live"
    (live / "frames").mkdir(parents=True)

    def writer():
        for f, img in enumerate(imgs):
            time.sleep(0.05)
            write_frame(live, f, img)
        (live / END_NAME).touch()

    th = threading.Thread(target=writer)
    th.start()
    got = track_following(live, setup, calibration, tmp_path / "live.csv", timeout_s=10.0)
    th.join()
    assert got.frames == len(imgs)
    assert [(s.frame_index, s.strobe_index, s.reason) for s in got.samples] == \
        [(s.frame_index, s.strobe_index, s.reason) for s in ref.samples]
    for a, b in zip(got.samples, ref.samples):
        assert np.array_equal(a.light_index, b.light_index)
        assert np.allclose(a.screen_xy_m, b.screen_xy_m, equal_nan=True, atol=0, rtol=0)
    assert (tmp_path / "live.csv").read_text() == (tmp_path / "ref.csv").read_text()
    assert got.seconds > 0 and got.samples_per_s > 0


def test_a_gap_is_a_missing_frame_and_silence_ends_the_follow(tmp_path, setup):  # noqa: F811
    imgs = frames_of(setup, 1)
    (tmp_path / "frames").mkdir()
    write_frame(tmp_path, 0, imgs[0])
    write_frame(tmp_path, 2, imgs[0])
    now = [0.0]

    def sleep(s):
        now[0] += s

    got = list(follow_frames(tmp_path, setup, timeout_s=1.0, clock=lambda: now[0], sleep=sleep))
    assert [(f, err is None) for f, _, _, err in got] == [(0, True), (1, False), (2, True)]
    assert got[1][3].endswith(": missing")
    assert now[0] > 1.0, "stopped by the timeout, not before"
