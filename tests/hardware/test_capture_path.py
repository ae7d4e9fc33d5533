"""The capture path end to end without a Pi: a dataset folder of banded 10-bit frames (drawn
analytically, as tests/estimator/test_tracker.py does) replayed into a capture folder (packed
CSI-2 or 16-bit rows, a Bayer mosaic of unequal channel responses) and tracked through the one
capture reader; the samples agree with tracking the dataset itself."""

import json

import cv2
import numpy as np
import pytest

from tests.estimator.simulated import ground_truth_calibration

from estimator.capture import CaptureFolder
from estimator.folders import track_folder
from estimator.scene import load_scene
from scet_hardware.capture import replay_dataset
from scet_render.cli import main
from tests.estimator.test_tracker import draw_frame

FRAMES = 4


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, setup):
    folder = tmp_path_factory.mktemp("dataset")
    (folder / "frames").mkdir()
    rng = np.random.default_rng(7)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    for f in range(FRAMES):
        img = draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng)
        cv2.imwrite(str(folder / "frames" / f"{f:06d}.png"), img)
    text = open(setup.source, encoding="utf-8").read()
    manifest = {"format": "scet-dataset", "version": 1, "frames": FRAMES,
                "scene": {"name": setup.name, "toml": text},
                "image": {"width_px": 640, "height_px": 480, "png_bit_depth": 16}}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    (folder / "labels.jsonl").write_text("".join(json.dumps({"frame": f, "target_m": [0, 0, -0.7]}) + "\n"
                                                 for f in range(FRAMES)))
    return folder


@pytest.fixture(scope="module")
def calibration(setup):
    return ground_truth_calibration(setup)


@pytest.mark.parametrize("fmt", ["SGBRG10_CSI2P", "SGBRG10"])
def test_replay_reads_back_the_dataset_frames(tmp_path, dataset, setup, fmt):
    cap_dir = replay_dataset(dataset, tmp_path / "cap", raw_format=fmt)
    cap = CaptureFolder(cap_dir, size_px=(640, 480))
    head = cap.header
    assert head["raw"] == {"format": fmt, "size": [640, 480], "stride": 800 if fmt.endswith("P") else 1280}
    assert head["controls"]["FrameDurationLimits"][0] == round(setup.sensor.frame_period_s * 1e6)
    assert head["strobe"]["period_ticks"] == round(setup.strobe.period_s * 16e6 - 0.5)
    got = list(cap.frames())
    assert len(got) == FRAMES and cap.problems == []
    for fr in got:
        png = cv2.imread(str(dataset / "frames" / f"{fr.index:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(fr.image, png)
        assert fr.start_s == pytest.approx(fr.index * setup.sensor.frame_period_s, abs=1e-9)
    raw = (cap_dir / "frames" / "000000.raw").stat().st_size
    assert raw == head["raw"]["stride"] * 480


def test_tracking_a_capture_matches_tracking_the_dataset(tmp_path, dataset, setup, calibration):
    # Channel responses 10 % apart: the reader's weighting undoes them to within a DN.
    cap_dir = replay_dataset(dataset, tmp_path / "cap", channel_response=(0.92, 1.0, 1.0, 0.9))
    a = track_folder(dataset, setup, calibration, tmp_path / "a.csv")
    b = track_folder(cap_dir, setup, calibration, tmp_path / "b.csv")
    assert a.n_ok > 0 and [s.reason for s in a.samples] == [s.reason for s in b.samples]
    ta = np.array([s.time_s for s in a.samples])
    tb = np.array([s.time_s for s in b.samples])
    np.testing.assert_allclose(tb, ta, atol=1e-9)     # ns timestamps
    ok = [s.ok for s in a.samples]
    xa = np.array([s.screen_xy_m for s, k in zip(a.samples, ok) if k])
    xb = np.array([s.screen_xy_m for s, k in zip(b.samples, ok) if k])
    # A DN of rounding moves a glint centroid by well under 0.01 px: sub-millimetre on screen.
    np.testing.assert_allclose(xb, xa, atol=1e-3)


def test_dropped_frames_are_nan_samples_and_the_stream_goes_on(tmp_path, dataset, setup, calibration):
    cap_dir = replay_dataset(dataset, tmp_path / "cap")
    lines = (cap_dir / "frames.jsonl").read_text().splitlines()
    del lines[1]
    (cap_dir / "frames.jsonl").write_text("\n".join(lines) + "\n")
    out = track_folder(cap_dir, setup, calibration, tmp_path / "s.csv")
    reasons = {}
    for s in out.samples:
        reasons.setdefault(s.frame_index, set()).add(s.reason)
    assert reasons[1] == {"missing_frame"}
    assert "ok" in reasons[0] and "ok" in reasons[2]


def test_cli_replay_and_track(tmp_path, dataset, setup, calibration, capsys):
    from estimator.folders import save_calibration

    save_calibration(calibration, tmp_path / "cal.json")
    assert main(["capture", "--replay", str(dataset), "--out", str(tmp_path / "cap")]) == 0
    assert main(["track", str(tmp_path / "cap"), "--scene", "paper_sim", "--calibration",
                 str(tmp_path / "cal.json"), "--out", str(tmp_path / "s.csv")]) == 0
    assert "gaze samples from 4 frames" in capsys.readouterr().out
    # The capture records the replayed dataset's scene: track needs no --scene.
    assert main(["track", str(tmp_path / "cap"), "--calibration", str(tmp_path / "cal.json"),
                 "--out", str(tmp_path / "s2.csv")]) == 0
    assert "capture.json (its scene.toml)" in capsys.readouterr().out
    assert (tmp_path / "s2.csv").read_bytes() == (tmp_path / "s.csv").read_bytes()
    (tmp_path / "cap" / "capture.json").write_text('{"format": "scet-capture", "version": 9}')
    assert main(["track", str(tmp_path / "cap"), "--scene", "paper_sim", "--calibration",
                 str(tmp_path / "cal.json"), "--out", str(tmp_path / "s.csv")]) == 2
    assert "capture.json: key 'version'" in capsys.readouterr().err


def test_scet_run_captures_and_tracks_live(tmp_path, dataset, setup, calibration, capsys):
    """Capture (the dataset replayed at the frame rate), track in the same process, samples
    written as they come; the frames it tracked give the samples the batch tracker gives."""
    from estimator.folders import save_calibration
    from estimator.tracking import read_samples_csv

    save_calibration(calibration, tmp_path / "cal.json")
    rc = main(["run", "--replay", str(dataset), "--realtime", "--frames", "12", "--out",
               str(tmp_path / "cap"), "--scene", "paper_sim", "--calibration",
               str(tmp_path / "cal.json"), "--samples", str(tmp_path / "live.csv")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "12 frames written" in out and "latency frame in -> samples out: p50" in out
    live = read_samples_csv(tmp_path / "live.csv")
    frames = sorted({int(r["frame"]) for r in live})
    assert frames and any(r["reason"] == "ok" for r in live)
    batch = track_folder(tmp_path / "cap", setup, calibration, tmp_path / "batch.csv")
    by_frame = {}
    for s in batch.samples:
        by_frame.setdefault(s.frame_index, []).append(s)
    # The live tracker skips frames it has no time for, and restarts its stream there; on the
    # first frame it tracked the samples are the batch tracker's of that frame.
    f0 = frames[0]
    first_live = [r for r in live if int(r["frame"]) == f0]
    assert [r["reason"] for r in first_live] == [s.reason for s in by_frame[f0]]


def test_track_follow_reads_a_capture_while_it_is_written(tmp_path, dataset, setup, calibration, capsys):
    import os
    import subprocess
    import sys
    from pathlib import Path

    from estimator.folders import save_calibration

    repo = Path(__file__).resolve().parents[2]
    save_calibration(calibration, tmp_path / "cal.json")
    proc = subprocess.Popen([sys.executable, "-m", "scet_render.cli", "capture", "--replay",
                             str(dataset), "--realtime", "--frames", "20", "--out",
                             str(tmp_path / "cap")], cwd=repo,
                            env=dict(os.environ, PYTHONPATH=str(repo)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        rc = main(["track", str(tmp_path / "cap"), "--follow", "--scene", "paper_sim",
                   "--calibration", str(tmp_path / "cal.json"), "--out", str(tmp_path / "s.csv")])
    finally:
        proc.communicate(timeout=60)
    assert proc.returncode == 0 and rc == 0
    written = json.loads((tmp_path / "cap" / "capture.json").read_text())["summary"]
    n_slots = written["frames_written"] + written["dropped_camera"]
    from estimator.tracking import read_samples_csv

    rows = read_samples_csv(tmp_path / "s.csv")
    assert sorted({int(r["frame"]) for r in rows}) == list(range(n_slots))
