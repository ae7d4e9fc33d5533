"""``scet track --events``: the events CSV written beside the samples, end to end on a small
rendered sequence (render, calibrate, track through ``scet``'s own ``main``), checked against
the trajectory's own saccades."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.events import read_events_csv
from estimator.scene import load_scene
from scet_render.cli import main

pytest.importorskip("mitsuba")

#: Onset tolerance (s) of a rendered saccade at 16 pulses per frame (S = 393 at 320 x 240,
#: 10 bands a frame, 6.2 ms blanking): the study measures ~2 ms mean at S = 786 full size;
#: 7 ms bounds each of a few (a blanking gap's width).
ONSET_TOL_S = 7e-3

from tests.scet_render.test_workflow import _small_scene  # noqa: E402  (paper_sim at 320x240)


@pytest.mark.slow
def test_track_writes_events_beside_the_samples(tmp_path, capsys):
    scene = _small_scene(tmp_path / "small.toml")
    common = ["--spp", "4", "--cornea", "conductor"]
    assert main(["render", str(scene), "--calibration", "5x5", "--out", str(tmp_path / "cal"),
                 *common]) == 0
    assert main(["calibrate", str(tmp_path / "cal"), "--scene", str(scene), "--out",
                 str(tmp_path / "cal.json")]) == 0
    assert main(["render", str(scene), "--frames", "40", "--trajectory", "saccades", "--seed", "1",
                 "--out", str(tmp_path / "seq"), *common]) == 0
    events = tmp_path / "events.csv"
    assert main(["track", str(tmp_path / "seq"), "--scene", str(scene), "--calibration",
                 str(tmp_path / "cal.json"), "--method", "geometric", "--out",
                 str(tmp_path / "samples.csv"), "--events", str(events)]) == 0
    assert f"written to {events}" in capsys.readouterr().out
    assert events.read_text().startswith("# scet-events 1\n")
    ev = read_events_csv(events)
    from scet_render.dataset import dataset_trajectory
    from scet_render.study.events_score import truth_events

    setup = load_scene(scene)
    traj = dataset_trajectory(setup, "saccades", 40, 1)
    truth = truth_events(traj, 0.0, 40 * setup.sensor.frame_period_s)
    assert truth.onset_s.size >= 1
    for on, amp in zip(truth.onset_s, truth.amplitude_deg):
        near = np.abs(ev.onset_s - on)
        assert near.min() < ONSET_TOL_S, (on, ev.onset_s)
        assert ev.amplitude_deg[np.argmin(near)] == pytest.approx(amp, rel=0.1, abs=0.3)
