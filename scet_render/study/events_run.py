"""``scet study events``: what the band rate buys over 60 Hz, on rendered sequences.

For each lighting (a scene file) the study renders, with Mitsuba, one sequence of the
"saccades" trajectory (:func:`scet_render.dataset.dataset_trajectory`: main-sequence saccades
between random screen points, fixations of 0.1-0.3 s with drift and tremor) per strobe setting
(4, 8 and 16 pulses per frame, :func:`estimator.banding.strobe_setup`) and once more with
one pulse per frame that every row collects (:func:`estimator.banding.calibration_setup`):
the 60 Hz, one-sample-per-frame tracker of the same camera. Every sequence is calibrated (one
5x5 single-pulse calibration per lighting), tracked with the prototype's tracker
(geometric gaze) and cut into events by pymovements' I-VT and I-DT
(:mod:`scet_render.study.events`), which are scored against the trajectory's own saccades.

Quick mode renders like ``scet validate --quick`` (320 x 240, 4 spp, conductor cornea) and
120 frames (2 s, about 8 saccades) per sequence. Full mode (no ``--quick``) is the study of
issue 34 (:mod:`.events_full`): the feature-level simulation of hundreds of saccades at every
setting and one rendered full-size sub-sequence; :data:`FULL` keeps the render-everything
configuration for callers that pass it as ``config``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from estimator.eye import fick_angles
from estimator.scene import load_scene

from .events import DETECTORS, detect_saccades, score_saccades, true_saccades, uniform_series
from .events_report import RATE_60, Condition, write_events_report


@dataclass(frozen=True, slots=True)
class EventConfig:
    scale: int
    spp: int
    cornea: str
    frames: int
    pulses_per_frame: tuple = (4, 8, 16)


QUICK = EventConfig(scale=2, spp=4, cornea="conductor", frames=120)
FULL = EventConfig(scale=1, spp=16, cornea="dielectric", frames=600)
def _gaze_deg(setup, rows) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (s) and Fick angles (deg) of the gaze points of ``samples.csv`` rows."""
    t = np.array([float(r["time_s"]) for r in rows])
    xy = np.array([[float(r["screen_x_m"]), float(r["screen_y_m"])] for r in rows])
    p = np.column_stack([xy, np.full(len(rows), setup.screen.z_m)])
    yaw, pitch = fick_angles(p - setup.eye.rotation_center_m)
    return t, np.degrees(np.column_stack([yaw, pitch]))


def run_event_study(lightings: dict, *, quick: bool, out_dir, report_dir, seed: int = 0,
                    progress: Callable[[str, int, int], None] | None = None,
                    config: EventConfig | None = None, render: bool = True):
    """Render, calibrate, track, detect and score (module docstring); write ``events.md``.

    Parameters
    ----------
    lightings : dict
        Label -> scene (name or file), e.g. {"current": "paper_sim", "designed": path}.
    render : bool
        Full mode: render the sub-sequence's missing frames (False: score only those
        already rendered under ``out_dir``).
    """
    from estimator.folders import calibrate_from_folder, read_samples_csv, track_folder
    from estimator.banding import calibration_setup, scaled_setup, strobe_setup
    from scet_render.dataset import dataset_trajectory, render_calibration, render_dataset

    if not quick and config is None:  # issue 34: the full study is the simulation at scale
        from .events_full import cli_conditions, run_full_event_study

        rows, path = run_full_event_study(lightings, out_dir=out_dir, report_dir=report_dir,
                                          seed=seed, progress=progress, render=render)
        return cli_conditions(rows), path
    cfg = config or (QUICK if quick else FULL)
    if not lightings:
        raise ValueError("lightings: at least one scene is needed")
    out = Path(out_dir)
    timings = {"render": 0.0, "calibrate": 0.0, "track": 0.0, "events": 0.0}
    stage = (lambda name: (lambda d, t: progress(name, d, t))) if progress else (lambda n: None)
    conditions, traces = [], {}
    for label, scene in lightings.items():
        setup = scaled_setup(load_scene(scene), cfg.scale)
        work = out / label
        t = time.perf_counter()
        cal_dir = render_calibration(setup, work / "calibration", spp=cfg.spp, cornea=cfg.cornea,
                                     seed=seed, progress=stage(f"{label} calibration"))
        runs = {p: strobe_setup(setup, p) for p in cfg.pulses_per_frame}
        runs[RATE_60] = calibration_setup(setup)
        for p, sset in runs.items():
            render_dataset(sset, work / f"seq_p{p}", frames=cfg.frames, spp=cfg.spp,
                           trajectory="saccades", seed=seed, cornea=cfg.cornea,
                           progress=stage(f"{label} render {p or '60 Hz'}"))
        timings["render"] += time.perf_counter() - t
        t = time.perf_counter()
        calibration = calibrate_from_folder(cal_dir, setup)
        timings["calibrate"] += time.perf_counter() - t
        for p, sset in runs.items():
            t = time.perf_counter()
            csv = work / f"samples_p{p}.csv"
            track_folder(work / f"seq_p{p}", sset, calibration, csv, method="geometric",
                         progress=stage(f"{label} track {p or '60 Hz'}"))
            rows = read_samples_csv(csv)
            timings["track"] += time.perf_counter() - t
            t = time.perf_counter()
            ts, pos = _gaze_deg(sset, rows)
            period = sset.strobe.period_s if p else sset.sensor.frame_period_s
            series = uniform_series(ts, pos, period, origin_s=float(ts.min()))
            traj = dataset_trajectory(sset, "saccades", cfg.frames, seed)
            truth = true_saccades(traj, float(ts.min()), float(ts.max()))
            span = float(ts.max() - ts.min()) + period
            ok = np.isfinite(pos).all(axis=1)
            for det in DETECTORS:
                found = detect_saccades(series, det)
                conditions.append(Condition(label, p, det, ok.sum() / span, float(ok.mean()),
                                            score_saccades(found, truth, period)))
            traces[(label, p)] = (series, traj)
            timings["events"] += time.perf_counter() - t
    path = write_events_report(Path(report_dir), conditions, traces, cfg, lightings, timings)
    return conditions, path
