"""The renders' own gaze errors in the events study's simulation.

The feature-level simulation gives every valid band Gaussian noise of one SD per axis. The
rendered sub-sequence (:mod:`.events_render`) shows errors that are not so: heavier-tailed
(an RMS above the median-based SD: one band in fifty a poor fit a tenth of a degree off) and
larger at saccadic speeds, where the glint moves during the pulse. Here each valid sample takes
instead an error drawn (with replacement) from the valid rendered samples' errors at the same
true eye speed (:data:`RESIDUAL_SPEEDS_DEG_S`): that keeps their distribution and its growth
with speed, not their order in time. :func:`residuals_by_speed` puts them on the renders' own
bands (the rendered comparison's third twin); :func:`goal_with_rendered_errors` on the goal
setting's simulated trajectories, so that the study's goals are also measured with the errors
the renders make. The renders' poor fits (:mod:`estimator.events.quality`) are drawn as often
as they occur at each speed, and the event gate runs on the drawn stream as on the renders.
"""

from __future__ import annotations

import math

import numpy as np

#: Eye speed bands (deg/s) within which errors are drawn from the renders' own.
RESIDUAL_SPEEDS_DEG_S = (0.0, 30.0, 100.0, 300.0, math.inf)
#: Trajectory seeds of the goal setting measured with the renders' errors: the study's own
#: and the four held-out ones (:data:`scet_render.study.events_full.HELD_OUT_SEEDS`).
GOAL_ERROR_SEEDS = (0, 1, 2, 3, 4)


def eye_speed_deg_s(traj, t) -> np.ndarray:
    """(n,) the trajectory's true eye speed (deg/s) at instants ``t`` (s), by central
    difference over 0.2 ms."""
    h = 1e-4
    y0, p0 = traj.angles_at(np.asarray(t) - h)
    y1, p1 = traj.angles_at(np.asarray(t) + h)
    return np.degrees(np.hypot(y1 - y0, p1 - p0)) / (2 * h)


def draw_errors(speed, valid, pool_speed, pool_err, rng, pool_poor=None):
    """(n, 2) deg: for each ``valid`` sample an error drawn from ``pool_err`` (m, 2) among
    those whose ``pool_speed`` (m,) lies in the same band of :data:`RESIDUAL_SPEEDS_DEG_S`
    as its ``speed``; NaN elsewhere (and where that band holds no error). With ``pool_poor``
    (m,) bool (the renders' poor fits, :func:`estimator.events.quality.poor_fits`), also the
    (n,) bool of the draws that were poor fits: (errors, poor)."""
    out = np.full((np.asarray(speed).size, 2), np.nan)
    poor = np.zeros(out.shape[0], dtype=bool)
    for lo, hi in zip(RESIDUAL_SPEEDS_DEG_S[:-1], RESIDUAL_SPEEDS_DEG_S[1:]):
        m = valid & (speed >= lo) & (speed < hi)
        src = np.flatnonzero((pool_speed >= lo) & (pool_speed < hi))
        if m.any() and src.size:
            pick = rng.choice(src, int(m.sum()))
            out[m] = pool_err[pick]
            if pool_poor is not None:
                poor[m] = np.asarray(pool_poor)[pick]
    return out if pool_poor is None else (out, poor)


def rendered_errors(traj, t, pos, truth_pos, ok) -> tuple[np.ndarray, np.ndarray]:
    """The valid rendered samples' true eye speeds (m,) and errors (m, 2) deg, less their
    median (a calibration bias moves no event)."""
    err = pos[ok] - truth_pos[ok]
    return eye_speed_deg_s(traj, t[ok]), err - np.median(err, axis=0)


def residuals_by_speed(traj, t, pos, truth_pos, ok, rng) -> np.ndarray:
    """(n, 2) deg: the truth at the renders' valid instants plus an error drawn from the
    renders' own at the same eye speed (module docstring); NaN where the render has no
    sample."""
    pool_speed, pool_err = rendered_errors(traj, t, pos, truth_pos, ok)
    return truth_pos + draw_errors(eye_speed_deg_s(traj, t), ok, pool_speed, pool_err, rng)


def goal_with_rendered_errors(setup, traj, t, pos, truth_pos, ok, seed: int, *, score,
                              noise_sd_deg: float, counts: tuple, detectors=("scet", "ivt"),
                              seeds=GOAL_ERROR_SEEDS, poor=None) -> dict:
    """The goal setting (``setup``, the designed lighting, at 16 pulses and S = 524) of the
    study's trajectories
    ``seeds`` (:func:`~scet_render.study.events_sim.study_trajectory`, 200 saccades and 100
    microsaccades each), its valid bands as the simulator makes them, scored by each
    detector pooled over the seeds, with the simulator's Gaussian noise and with errors drawn
    from the rendered sub-sequence's (``traj``, ``t``, ``pos``, ``truth_pos``, ``ok``; with
    ``poor`` (n,) bool, the renders' poor fits, each drawn stream is gated as the event gate
    gates a stream: a drawn poor fit that disagrees with its neighbours is a NaN band):
    {detector: {"gaussian": summary, "rendered errors": summary}}."""
    from estimator.events.quality import disagree_with_neighbours

    from .events_score import pool, summarise
    from .events_sim import band_setting, simulate_stream, study_trajectory

    pool_speed, pool_err = rendered_errors(traj, t, pos, truth_pos, ok)
    pool_poor = None if poor is None else np.asarray(poor, dtype=bool)[ok]
    sd = noise_sd_deg
    got = {d: {"gaussian": [], "rendered errors": []} for d in detectors}
    for s in seeds:
        tr = study_trajectory(setup, *counts, s)
        st = band_setting("designed 16 524", setup, 16, 524, sd)
        tg, pg = simulate_stream(st, tr, tr.duration_s, s)
        t0, p0 = simulate_stream(band_setting("designed 16 524", setup, 16, 524, 0.0), tr,
                                 tr.duration_s, s)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 343, s]))
        valid = np.isfinite(p0).all(axis=1)
        if pool_poor is None:
            pr = p0 + draw_errors(eye_speed_deg_s(tr, t0), valid, pool_speed, pool_err, rng)
        else:  # the event gate on the drawn stream: the draws' flags, its own neighbours
            err, flagged = draw_errors(eye_speed_deg_s(tr, t0), valid, pool_speed, pool_err,
                                       rng, pool_poor)
            pr = p0 + err
            pr[disagree_with_neighbours(t0, pr, flagged)] = np.nan
        for d in detectors:
            got[d]["gaussian"].append(score(st, tr, tg, pg, d)[0])
            got[d]["rendered errors"].append(score(st, tr, t0, pr, d)[0])
    return {d: {k: summarise(pool(v)) for k, v in per.items()} for d, per in got.items()}


def rendered_errors_table(rendered, names: dict, met) -> str:
    """The goals with the simulator's Gaussian noise and with the renders' own errors
    (:func:`goal_with_rendered_errors`); ``names`` the detectors' names, ``met(key, value)``
    whether a value meets its goal (the goals table's words)."""
    g = None if rendered is None else rendered.get("goal with rendered errors")
    if not g:
        return ""
    from .events_changes import _fmt, _spec
    from .events_score import GOALS, MEASURES

    keys = [k for k in MEASURES if k in GOALS]
    out = ("The goal setting's trajectories (seeds " + ", ".join(map(str, GOAL_ERROR_SEEDS))
           + ", pooled) with each valid band's error drawn from the rendered sub-sequence's own "
           "errors at the same eye speed (the renders' poor fits drawn with them, and the event "
           "gate run on the drawn stream), beside the simulator's Gaussian noise of the same "
           "bands:\n\n| detector | errors | " + " | ".join(MEASURES[k] for k in keys)
           + " |\n|---|---|" + "---|" * len(keys) + "\n")
    for det, per in g.items():
        for name, summ in per.items():
            out += (f"| {names[det]} | {name} | "
                    + " | ".join(f"{_fmt(summ[k], _spec(k))} {met(k, summ[k])}".rstrip()
                                 for k in keys) + " |\n")
    return out + "\nEach value is followed by whether it meets the goal (as in the goals table).\n"
