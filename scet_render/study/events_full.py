"""``scet study events`` (full mode): event timing at the band rate on hundreds of saccades.

Feature-level simulation (:mod:`.events_sim`) of 200 saccades of 0.5-20 deg and 100
microsaccades of 0.1-1 deg per lighting, at 4 / 8 / 16 pulses per frame and S = 524 and 786,
against the 60 Hz tracker of the same camera and an ideal 1 kHz uniform tracker with the goal
setting's per-sample noise. Three detectors on the same samples: the estimator's band-sample
detector (:mod:`estimator.events`) and pymovements' I-VT and I-DT (:mod:`.events`). The error
budget of the goal setting (designed lighting, 16 pulses, S = 524) switches the blanking gap,
the per-sample noise and the invalid bands off one at a time. The rendered sub-sequence
(:mod:`.events_render`), tracked with the prototype's tracker, is scored beside the simulation
of the same trajectory and setting.

Per-sample noise (deg per axis): the geometric gaze's mean error over the full-size rendered
validation (``reports/full/validation.md``, ``reports/design/paper_sim_designed_validation_full``;
640 x 480, 16 spp, dielectric, S = 786), divided by sqrt(pi / 2) (the mean of a 2-D Gaussian
error's length is sigma sqrt(pi / 2)).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from dataclasses import replace

from estimator.events import EventParams, EventStream, detect_events
from estimator.events.detect import FIRST_ROUND
from estimator.scene import load_scene

from .events_score import TWIN_RESIDUALS, match_events, pool, summarise, truth_events
from .events_sim import (StreamSetting, band_setting, on_screen_mask, simulate_stream,
                         study_trajectory)

N_SACCADES, N_MICRO = 200, 100
PULSES = (4, 8, 16)
TOTAL_LINES = (524, 786)
#: Geometric gaze mean error (deg) of the full-size rendered validation by scene and pulses.
RENDERED_MEAN_ERROR_DEG = {
    "paper_sim": {4: 0.007, 8: 0.010, 16: 0.012},
    "paper_sim_designed": {4: 0.012, 8: 0.015, 16: 0.018},
}
GOAL = ("designed", 16, 524)
DETECTORS = ("scet", "ivt", "idt")
#: The band detector's changes of issue 34's second round, added one at a time to the first
#: full-size study's detector (the last is today's EventParams()): each measured on the same
#: samples of the goal setting.
CHANGES = (
    ("first round", FIRST_ROUND),
    ("+ crossings at the fits' mean instants", replace(FIRST_ROUND, centroid_timing=True)),
    ("+ speeds in their own fits' noise", replace(FIRST_ROUND, centroid_timing=True,
                                                  local_noise=True)),
    ("+ 20 ms minimum intersaccadic interval", replace(EventParams(), edge_fit=False,
                                                       bounded_gap_reach=False,
                                                       glitches_before_merge=False)),
    ("+ edge fit", replace(EventParams(), bounded_gap_reach=False, glitches_before_merge=False)),
    ("+ bounds at most 12.5 ms into long gaps", replace(EventParams(), glitches_before_merge=False)),
    ("+ glitches rejected before merging (today's detector)", EventParams()),
)
#: Further trajectories of the goal setting the changes are measured on (seeds of
#: :func:`study_trajectory` and the noise, added to the study's): first simulated after the
#: changes were built on the study's own trajectory; nothing was tuned on them (variants tried
#: on them, edge-fit powers 2, 3 or 2-3 alone and a 0.7 speed fraction, did no better and
#: were not adopted).
HELD_OUT_SEEDS = (1, 2, 3, 4)
#: Trajectories first simulated in issue 34's third round, after the simulator's trajectories
#: were kept on the screen (:func:`study_trajectory`): today's detector, unchanged in that
#: round, on trajectories nothing was ever tried on.
FRESH_SEEDS = (5, 6, 7, 8)


def noise_sd_deg(scene_name: str, pulses: int) -> float:
    table = RENDERED_MEAN_ERROR_DEG.get(scene_name, RENDERED_MEAN_ERROR_DEG["paper_sim_designed"])
    return table[pulses] / math.sqrt(math.pi / 2)


def _period(setting: StreamSetting) -> float:
    s = setting.setup
    if setting.kind == "uniform":
        return 1.0 / setting.rate_hz
    if setting.kind == "frame":
        return s.sensor.frame_period_s
    return s.strobe.period_s


def detect(detector: str, t, pos, period_s: float, params: EventParams = EventParams()):
    """(onset, offset, amplitude, peak) arrays of one detector on the samples (``params``:
    the band detector's)."""
    if detector == "scet":
        ev = detect_events(t, pos, params)
        return ev.onset_s, ev.offset_s, ev.amplitude_deg, ev.peak_velocity_deg_s
    from .events import detect_saccades, uniform_series

    sac = detect_saccades(uniform_series(t, pos, period_s, origin_s=float(t[0])), detector)
    return sac.onset_s, sac.offset_s, sac.amplitude_deg, sac.peak_velocity_deg_s


def score(setting, traj, t, pos, detector, params: EventParams = EventParams()):
    truth = truth_events(traj, float(t[0]), float(t[-1]))
    on, off, amp, peak = detect(detector, t, pos, _period(setting), params)
    pad = 0.5 * float(np.median(np.diff(t)))
    m = match_events(on, off, amp, peak, truth, pad, float(t[0]), float(t[-1]))
    return m, summarise(m)


def detector_changes(setup, goal, traj, t, pos, seed: int, n_saccades: int, n_micro: int,
                     held_out=HELD_OUT_SEEDS, fresh=FRESH_SEEDS) -> tuple:
    """Each of :data:`CHANGES` on the goal setting's samples (``t``, ``pos`` of ``traj``) and
    on the pooled streams of the :data:`HELD_OUT_SEEDS` trajectories: dicts of the change's
    name and the two summaries (:func:`summarise`), with the held-out saccade counts; then
    :func:`bracketed_onsets` of today's detector over the study's, the held-out and the
    :data:`FRESH_SEEDS` trajectories, with the pooled summaries of the held-out and fresh
    ones and of the held-out seeds' trajectories by the earlier rule that let them leave the
    screen (``keep_on_screen`` False); and :func:`nan_band_onsets`."""
    def stream(s, on_screen=True):
        tr = study_trajectory(setup, n_saccades, n_micro, seed + s, keep_on_screen=on_screen)
        ts, ps = simulate_stream(goal, tr, tr.duration_s, seed + s)
        return tr, ts, ps

    streams = [(traj, t, pos)] + [stream(s) for s in held_out]
    out = []
    for name, params in CHANGES:
        ms = [score(goal, tr, ts, ps, "scet", params)[0] for tr, ts, ps in streams]
        held = pool(ms[1:]) if len(ms) > 1 else None
        out.append({"name": name, "study": summarise(ms[0]),
                    "held_out": None if held is None else summarise(held),
                    "n_held_out": 0 if held is None else int((held.truth.amplitude_deg >= 1).sum())})
    new = [stream(s) for s in fresh]
    earlier = [stream(s, on_screen=False) for s in held_out]
    pooled = {}
    for key, group in (("held out", streams[1:]), ("fresh", new), ("earlier", earlier)):
        if group:
            m = pool([score(goal, tr, ts, ps, "scet")[0] for tr, ts, ps in group])
            pooled[key] = (summarise(m), int((m.truth.amplitude_deg >= 1).sum()))
    bracketed = {**bracketed_onsets(streams + new, setup),
                 "seeds": (seed,) + tuple(seed + k for k in (*held_out, *fresh)),
                 "held_out_seeds": tuple(seed + k for k in held_out),
                 "fresh_seeds": tuple(seed + k for k in fresh), "pooled": pooled,
                 "earlier": bracketed_onsets(earlier, setup)["per_stream"]}
    return out, bracketed, nan_band_onsets(goal, traj, t, pos, seed)


#: NaN bands within this of a true onset (s) count as beside it (:func:`nan_band_onsets`).
NEAR_ONSET_S = 4e-3


def nan_band_onsets(goal, traj, t, pos, seed: int) -> dict:
    """Where the first round's onset error and false saccades came from, on the goal stream:
    the onset mean abs error (ms) of saccades >= 1 deg grouped by the NaN bands within
    :data:`NEAR_ONSET_S` of their onset (0, 1, 2, 3 or more), for the first-round detector,
    for it on the same samples with every band valid (the same noise draws: the stream's
    label seeds them), and for today's; and how many of the first round's false events overlap
    a true microsaccade (a microsaccade split in two)."""
    from .events_score import mean_ci

    _, twin = simulate_stream(replace(goal, invalid_bands=False), traj, traj.duration_s, seed)
    truth = truth_events(traj, float(t[0]), float(t[-1]))
    nan = ~np.isfinite(pos).all(axis=1)
    near = np.array([nan[np.abs(t - o) < NEAR_ONSET_S].sum() for o in truth.onset_s])
    groups = {"0": near == 0, "1": near == 1, "2": near == 2, "3 or more": near >= 3}
    out = {"groups": {}, "split_micro": 0, "false": 0}
    for label, params, p in (("first round", FIRST_ROUND, pos), ("every band valid", FIRST_ROUND, twin),
                             ("today's", EventParams(), pos)):
        m = score(goal, traj, t, p, "scet", params)[0]
        err = np.full(truth.onset_s.size, np.nan)
        hit = m.match >= 0
        err[hit] = 1e3 * np.abs(m.onset_s[m.match[hit]] - truth.onset_s[hit])
        big = truth.amplitude_deg >= 1.0
        out["groups"][label] = {g: (int((sel & big).sum()), mean_ci(err[sel & big]))
                                for g, sel in groups.items()}
        if label == "first round":
            used = np.zeros(m.onset_s.size, dtype=bool)
            used[m.match[hit]] = True
            micro = truth.amplitude_deg < 1.0
            for j in np.flatnonzero(~used):
                out["false"] += 1
                out["split_micro"] += bool(np.any(micro & (truth.onset_s < m.offset_s[j])
                                                  & (truth.offset_s > m.onset_s[j])))
    return out


#: An onset is bracketed when its stated uncertainty is at most this (s): the two samples
#: around it are neighbouring bands (1.04 ms apart at 16 pulses, S = 524), no NaN band between.
BRACKETED_S = 0.6e-3


def bracketed_onsets(streams, setup=None) -> dict:
    """Today's detector over the streams [(trajectory, t, pos)]: the onset mean abs error
    (ms, with its interval) of the matched saccades >= 1 deg whose onset is bracketed
    (:data:`BRACKETED_S`) and of the rest (NaN bands or the blanking beside it), and how many
    of each; per stream the valid share, with ``setup`` the share of bands whose gaze meets
    the screen and the valid share on and off it, the saccades >= 1 deg, those missed, missed
    in the dark (fewer than 20 % of the bands within 10 ms of it valid) and missed off the
    screen (a band within 10 ms of it off the screen)."""
    from .events_score import mean_ci

    err, unc, per = [], [], []
    for tr, t, pos in streams:
        ev = detect_events(t, pos)
        truth = truth_events(tr, float(t[0]), float(t[-1]))
        m = match_events(ev.onset_s, ev.offset_s, ev.amplitude_deg, ev.peak_velocity_deg_s,
                         truth, 0.5 * float(np.median(np.diff(t))), float(t[0]), float(t[-1]))
        big = truth.amplitude_deg >= 1.0
        hit = np.flatnonzero((m.match >= 0) & big)
        err.append(1e3 * np.abs(ev.onset_s[m.match[hit]] - truth.onset_s[hit]))
        unc.append(ev.onset_uncertainty_s[m.match[hit]])
        ok = np.isfinite(pos).all(axis=1)
        missed = np.flatnonzero(big & (m.match < 0))
        near = [(t >= truth.onset_s[i] - 0.01) & (t <= truth.offset_s[i] + 0.01) for i in missed]
        row = {"valid": float(ok.mean()), "n": int(big.sum()), "missed": int(missed.size),
               "missed_dark": int(sum(ok[w].mean() < 0.2 for w in near)),
               "onset_mae_ms": float(err[-1].mean()) if err[-1].size else math.nan}
        if setup is not None:
            on = on_screen_mask(setup, tr, t)
            row.update(on_screen=float(on.mean()), valid_on=float(ok[on].mean()) if on.any() else math.nan,
                       valid_off=float(ok[~on].mean()) if (~on).any() else math.nan,
                       missed_off=int(sum(not on[w].all() for w in near)))
        per.append(row)
    err, unc = np.concatenate(err), np.concatenate(unc)
    inside = unc <= BRACKETED_S
    return {"streams": len(streams), "per_stream": per,
            "bracketed": (int(inside.sum()), mean_ci(err[inside])),
            "gap": (int((~inside).sum()), mean_ci(err[~inside])),
            "gap_share_of_error": float(err[~inside].sum() / err.sum()) if err.sum() > 0 else math.nan}


def stream_latency(t, pos, traj, frame_s: float, early: bool = False) -> dict:
    """Latency of :class:`EventStream` (reported minus true onset, ms) over the matched
    saccades >= 1 deg, samples pushed a frame at a time (``early``: the stream's early
    reports), with the summary (:func:`summarise`) of the streamed events."""
    stream = EventStream(early=early)
    got = []
    edges = np.arange(t[0], t[-1] + frame_s, frame_s)
    idx = np.searchsorted(t, edges)
    for a, b in zip(idx[:-1], idx[1:]):
        if b > a:
            ev = stream.push(t[a:b], pos[a:b])
            got.append((ev.onset_s, ev.offset_s, ev.amplitude_deg, ev.peak_velocity_deg_s))
    on, off, amp, peak = (np.concatenate([g[k] for g in got]) for k in range(4))
    rep = np.array(stream.reported_at_s)
    truth = truth_events(traj, float(t[0]), float(t[-1]))
    m = match_events(on, off, amp, peak, truth, 0.5 * float(np.median(np.diff(t))),
                     float(t[0]), float(t[-1]))
    hit = (m.match >= 0) & (truth.amplitude_deg >= 1.0)
    lat = 1e3 * (rep[m.match[hit]] - truth.onset_s[hit])
    after_off = 1e3 * (rep[m.match[hit]] - truth.offset_s[hit])
    return {"n": int(hit.sum()), "median_ms": float(np.median(lat)),
            "p95_ms": float(np.percentile(lat, 95)), "after_offset_median_ms": float(np.median(after_off)),
            "settle_ms": 1e3 * stream.wait_s, "summary": summarise(m), "early": early}


def run_full_event_study(lightings: dict, *, out_dir, report_dir, seed: int = 0, progress=None,
                         render: bool = True, n_saccades: int = N_SACCADES,
                         n_micro: int = N_MICRO):
    """Simulate, detect and score every setting; score the rendered sub-sequence (rendering
    what is missing when ``render``); write ``events.md``. Returns (rows, report path)."""
    from .events_full_report import write_full_report

    timings = {"simulate": 0.0, "detect": 0.0, "stream": 0.0, "changes": 0.0, "rendered": 0.0}
    rows = []  # dicts: lighting, setting, detector, samples/s, valid share, summary
    traces = {}
    labels = dict(lightings)
    if "designed" not in labels:
        labels["designed"] = "scenes/paper_sim_designed.toml"
    steps = [(lab, p, S) for lab in labels for p in PULSES for S in TOTAL_LINES]
    done = 0
    total = len(steps) + 2 * len(labels) + 6
    latency = None
    changes = None
    for lab, scene in labels.items():
        setup = load_scene(scene)
        traj = study_trajectory(setup, n_saccades, n_micro, seed)
        dur = traj.duration_s
        settings = [(f"{p} pulses, S = {S}", band_setting(f"{lab} {p} {S}", setup, p, S,
                                                           noise_sd_deg(setup.name, p)))
                    for p in PULSES for S in TOTAL_LINES]
        settings.append(("60 Hz", StreamSetting(f"{lab} 60", "frame", setup,
                                                noise_sd_deg(setup.name, 4))))
        if lab == GOAL[0]:
            goal_sd = noise_sd_deg(setup.name, 16)
            settings.append(("1 kHz reference", StreamSetting("1k", "uniform", setup, goal_sd)))
            base = dict(noise_sd_deg=goal_sd)
            for name, sw in (("no blanking", dict(blanking=False)),
                             ("no noise", dict(noise_sd_deg=0.0)),
                             ("no invalid bands", dict(invalid_bands=False)),
                             ("none of the three", dict(blanking=False, noise_sd_deg=0.0,
                                                        invalid_bands=False))):
                kw = {**base, **sw}
                sd = kw.pop("noise_sd_deg")
                settings.append((f"16 pulses, S = 524, {name}",
                                 band_setting(f"{lab} goal {name}", setup, 16, 524, sd, **kw)))
        for name, st in settings:
            t0 = time.perf_counter()
            t, pos = simulate_stream(st, traj, dur, seed)
            timings["simulate"] += time.perf_counter() - t0
            ok = np.isfinite(pos).all(axis=1)
            span = float(t[-1] - t[0])
            for det in DETECTORS:
                t0 = time.perf_counter()
                m, summ = score(st, traj, t, pos, det)
                timings["detect"] += time.perf_counter() - t0
                rows.append({"lighting": lab, "setting": name, "detector": det,
                             "samples_per_s": ok.sum() / span, "valid": float(ok.mean()),
                             "noise_sd_deg": st.noise_sd_deg, "n_saccades": int((m.truth.amplitude_deg >= 1).sum()),
                             "n_micro": int(((m.truth.amplitude_deg >= 0.3) & (m.truth.amplitude_deg < 1)).sum()),
                             "summary": summ, "matched": m})
            if lab == GOAL[0] and name == "16 pulses, S = 524":
                t0 = time.perf_counter()
                latency = [stream_latency(t, pos, traj, setup.sensor.frame_period_s, early)
                           for early in (False, True)]
                timings["stream"] += time.perf_counter() - t0
                traces["goal"] = (t, pos, traj)
                t0 = time.perf_counter()
                changes = detector_changes(setup, st, traj, t, pos, seed, n_saccades, n_micro)
                timings["changes"] += time.perf_counter() - t0
            if lab == GOAL[0] and name == "60 Hz":
                traces["60"] = (t, pos, traj)
            if lab == GOAL[0] and name == "16 pulses, S = 786":
                traces["786"] = (t, pos, traj)
            done += 1
            if progress:
                progress("simulated settings", done, total)
    blanking = blanking_table(load_scene(labels[GOAL[0]]))
    t0 = time.perf_counter()
    rendered = rendered_comparison(labels[GOAL[0]], Path(out_dir), seed, render=render)
    timings["rendered"] = time.perf_counter() - t0
    path = write_full_report(Path(report_dir), rows, latency, rendered, traces, timings, labels,
                             (n_saccades, n_micro), RENDERED_MEAN_ERROR_DEG, blanking, changes)
    return rows, path


def blanking_table(setup) -> list:
    """Per pulse count and S: band instants a frame and the longest time without one (s),
    from the band layout over 20 frames."""
    from .events_sim import band_instants

    out = []
    for p in PULSES:
        for S in TOTAL_LINES:
            st = band_setting("b", setup, p, S, 0.0).setup
            t, _, _ = band_instants(st, 20 * st.sensor.frame_period_s)
            out.append((p, S, t.size / 20.0, float(np.diff(t).max())))
    return out


def cli_conditions(rows) -> list:
    """The 16-pulse, S = 524 and 60 Hz rows as the quick study's :class:`Condition` objects
    (what ``scet study events`` prints), every detector."""
    from .events import EventScores
    from .events_report import RATE_60, Condition

    out = []
    for r in rows:
        if r["setting"] not in ("16 pulses, S = 524", "60 Hz"):
            continue
        m = r["matched"]
        hit = m.match >= 0
        j = m.match[hit]
        tr = m.truth
        scores = EventScores(int(tr.onset_s.size), m.n_detected, int(hit.sum()),
                             1e3 * (m.onset_s[j] - tr.onset_s[hit]),
                             1e3 * (m.offset_s[j] - tr.offset_s[hit]),
                             1e3 * ((m.offset_s[j] - m.onset_s[j]) - (tr.offset_s[hit] - tr.onset_s[hit])),
                             m.peak_velocity_deg_s[j] - tr.peak_velocity_deg_s[hit],
                             m.amplitude_deg[j] - tr.amplitude_deg[hit])
        out.append(Condition(r["lighting"], RATE_60 if r["setting"] == "60 Hz" else 16,
                             r["detector"], r["samples_per_s"], r["valid"], scores))
    return out


def sample_reasons(folder: Path, frames: int, t, pos) -> tuple[list, np.ndarray, np.ndarray]:
    """The ``reason`` column of the tracked rendered samples CSV, in its row order (the order
    of :func:`estimator.events.gaze_from_samples_csv`'s samples, times ``t`` (n,) and gaze
    ``pos`` (n, 2)), which samples the event gate's first step flags as poor fits, and which
    it leaves out (:mod:`estimator.events.quality`)."""
    from estimator.events import SampleGate
    from estimator.events.files import samples_left_out
    from estimator.events.quality import disagree_with_neighbours
    from estimator.tracking import read_samples_csv

    path = Path(folder) / f"samples_{frames}.csv"
    rows = read_samples_csv(path)
    if len(rows) != np.asarray(t).size:
        raise ValueError(f"{path}: {len(rows)} rows for {np.asarray(t).size} samples")
    flagged = samples_left_out(rows, t, pos, replace(SampleGate(), neighbour_check=False), path)
    return [r["reason"] for r in rows], flagged, disagree_with_neighbours(t, pos, flagged)


def invalid_reasons(reasons) -> list:
    """(reason, count) of the samples' ``reasons`` (:func:`sample_reasons`) that are not
    ``ok``, most first."""
    from collections import Counter

    return Counter(r for r in reasons if r != "ok").most_common()


def band_agreement(t, ok_rendered, ts, ok_simulated, reasons) -> dict:
    """Band by band, the rendered samples' validity (``ok_rendered`` at instants ``t``, with
    the tracker's ``reasons``) against the simulator's at the same instants (``ts``,
    ``ok_simulated``; an instant is the same within 1 us): the counts of the four cases and,
    for the bands valid only in the simulation, the tracker's reasons, most first."""
    from collections import Counter

    t, ts = np.asarray(t, dtype=float), np.asarray(ts, dtype=float)
    j = np.clip(np.searchsorted(ts, t), 1, max(ts.size - 1, 1))
    j = np.where(np.abs(ts[j - 1] - t) < np.abs(ts[j] - t), j - 1, j) if ts.size > 1 else \
        np.zeros(t.size, dtype=int)
    same = np.abs(ts[j] - t) < 1e-6
    sim = np.zeros(t.size, dtype=bool)
    sim[same] = np.asarray(ok_simulated, dtype=bool)[j[same]]
    ren = np.asarray(ok_rendered, dtype=bool)
    only_sim = same & sim & ~ren
    return {"bands": int(same.sum()), "both": int((same & sim & ren).sum()),
            "rendered only": int((same & ren & ~sim).sum()), "simulated only": int(only_sim.sum()),
            "neither": int((same & ~sim & ~ren).sum()),
            "simulated only, reasons": Counter(reasons[i] for i in np.flatnonzero(only_sim)).most_common()}


#: A rendered sample further than this many noise SDs from the truth is an outlier (a
#: misidentified band): counted in the report; the detectors see the samples less the event
#: gate's poor fits (:mod:`estimator.events.quality`), which hold most of them.
OUTLIER_SDS = 5.0


def rendered_comparison(scene, out_dir: Path, seed: int, *, render: bool):
    """Score the tracked rendered sub-sequence (the frames rendered so far, from frame 0) and
    the simulation of the same trajectory and setting; None when nothing is rendered."""
    from .events_errors import goal_with_rendered_errors, residuals_by_speed
    from .events_render import rendered_samples

    got = rendered_samples(scene, out_dir / "designed", seed=seed, render=render)
    if got is None:
        return None
    setup, traj, t, pos, truth_pos, frames, planned = got
    ok = np.isfinite(pos).all(axis=1)
    # per-sample noise of the renders: the tracked gaze minus the truth at the strobe instant,
    # less its median (a calibration bias moves no event), over the valid samples; its SD from
    # the median absolute deviation (1.4826 MAD, the SD of a Gaussian), as the detector's own
    # median-based noise estimate: a few misidentified bands (errors of degrees) would make an
    # RMS ten times the noise of the rest, and a twin with that much Gaussian noise everywhere
    d = pos[ok] - truth_pos[ok]
    d -= np.median(d, axis=0)
    sd_rendered = float(np.mean(1.4826 * np.median(np.abs(d), axis=0)))
    rms = float(np.sqrt(np.mean(d ** 2)))
    far = np.hypot(d[:, 0], d[:, 1]) > OUTLIER_SDS * sd_rendered
    reasons, poor, gone = sample_reasons(out_dir / "designed", frames, t, pos)
    # what the detectors see: the gate's choice left out, as scet track --events does
    pos_used = np.where(gone[:, None], np.nan, pos)
    used = ok & ~gone
    sim_setting = band_setting("rendered twin", setup, 16, 524, sd_rendered)
    ts, ps = simulate_stream(sim_setting, traj, float(t[-1]) + 1e-3, seed)
    keep = ts >= t[0]
    ts, ps = ts[keep], ps[keep]
    # the second twin: the renders' own instants and used bands, the simulated noise
    rng = np.random.default_rng(np.random.SeedSequence([seed, 342]))
    pm = truth_pos + rng.normal(0.0, sd_rendered, truth_pos.shape)
    pm[~used] = np.nan
    # the third twin: the renders' used bands with their own errors, each drawn from the
    # used samples whose true eye speed falls in the same band of RESIDUAL_SPEEDS_DEG_S
    pr = residuals_by_speed(traj, t, pos, truth_pos, used, rng)
    study_setup = load_scene(scene)
    goal_errors = goal_with_rendered_errors(study_setup, traj, t, pos, truth_pos, ok, seed,
                                            score=score,
                                            noise_sd_deg=noise_sd_deg(study_setup.name, 16),
                                            counts=(N_SACCADES, N_MICRO), poor=poor)
    # (the draws carry the first step's flags; the neighbour check runs on each drawn stream)
    out = {"frames": frames, "planned": planned, "noise_sd_deg": sd_rendered, "rms_deg": rms,
           "reasons": invalid_reasons(reasons),
           "agreement": band_agreement(t, ok, ts, np.isfinite(ps).all(axis=1), reasons),
           "outliers": float(np.mean(far)), "poor fits": float(poor[ok].mean()),
           "left out": float(gone[ok].mean()),
           "outliers of the left out": float(np.mean(far[gone[ok]])) if gone.any() else 0.0,
           "outliers left": float(np.mean(far[~gone[ok]])),
           "goal with rendered errors": goal_errors,
           "valid_rendered": float(ok.mean()), "valid_simulated": float(np.isfinite(ps).all(axis=1).mean())}
    for det in DETECTORS:
        mr, sr = score(sim_setting, traj, t, pos_used, det)
        ms, ss = score(sim_setting, traj, ts, ps, det)
        sm = score(sim_setting, traj, t, pm, det)[1]
        out[det] = {"rendered": sr, "simulated": ss, "simulated, the renders' valid bands": sm,
                    TWIN_RESIDUALS: score(sim_setting, traj, t, pr, det)[1],
                    "n": int((mr.truth.amplitude_deg >= 1).sum()),
                    "n_all": int(mr.truth.onset_s.size)}
    return out
