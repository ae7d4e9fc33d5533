"""Focused glint detection against whole-frame detection on rendered frames with clutter: what
the window misses, which bands' samples differ, and what it saves (issue 31).

Three trackers on the same decoded frames of each dataset, both gaze methods:

- ``whole``: the tracker as it is by default (:class:`estimator.glints.GlintDetector`'s
  window on every detection since the last whole-frame search: on cluttered frames, nearly
  the whole frame; its detections are the whole frame's);
- ``focus``: ``Tracker(focus_detection=True)`` without the fallback
  (``tracker.focus_fallback = False``): each frame searched only around the glints the last
  frame's accepted samples used and those predicted at the last eye rotation;
- ``fallback``: ``Tracker(focus_detection=True)`` as it runs: a band where the last sample
  expects glints beyond the window's edge takes its rows' detections across the whole width
  (:meth:`estimator.tracking.Tracker.focused_bands`).

Printed per dataset and method:

- **misses**: labelled glints (the dataset's ``labels.jsonl``, visible ones of each band's
  strobe) that whole detection finds within 1 px (a detection of the same strobe) and the
  focused window does not (the focused tracker's own window detections of that frame);
- **bands that differ** from ``whole``'s samples: the reason, the lights, or the estimate
  (screen point beyond 1e-6 m; the largest difference and how many are the same to the
  last bit are printed too); among them the accepted samples (reason ok in either) that
  differ, each listed as frame/pulse with both reasons and lights;
- **frames/s** of each tracker (tracking alone, frames decoded beforehand, the process's CPU
  time), the three alternated over ``--rounds`` rounds, the range of the rounds and the ratio
  to ``whole`` per round; the bands the fallback gave their strip's detections ("redone").

With ``--declines`` it prints instead, per method, every dense band the default tracker's
cheap path declines: which of the follow step's tests declined it (from the prior, and on the
second try from the last rotation; :func:`follow_decision`), what followed (left unsearched as
``band_out_of_reach``, or the search's reason, and where it accepted whether with the cheap
try's lights), and the searches' CPU time by decision (issue 31, sixth pass).

Usage::

    python benchmarks/bench_focus.py DATASET[:PULSES] [...] [--frames N] [--rounds 3]
                                     [--calibration FILE] [--declines]

A dataset is a rendered folder (``frames/``, ``manifest.json``, ``labels.jsonl``), tracked
with the scene its manifest records (scaled to its width), ``PULSES`` pulses a frame where
given (the quick validation's ``test_p8``: 8). Its calibration: ``--calibration``, else
``calibration.json`` beside the folder, else calibrated from the ``calibration`` or ``calib``
folder beside it (:func:`estimator.folders.calibrate_from_folder`); nothing is written into
the dataset.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections import Counter
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from estimator.banding import scaled_setup, strobe_setup  # noqa: E402
from estimator.folders import calibrate_from_folder, iter_folder, load_calibration  # noqa: E402
from estimator.matching import follow_kernel  # noqa: E402
from estimator.matching.kernels import rival_margin  # noqa: E402
from estimator.scene import load_scene, parse_scene  # noqa: E402
from estimator.tracking import Tracker  # noqa: E402

MODES = ("whole", "focus", "fallback")
#: Two accepted samples with the same lights are the same where their screen points agree to
#: this (m): the window's centroids are the whole frame's to ~1e-9 px (computed in window
#: coordinates, tests/estimator/test_glints.py), which moves an estimate by far less; 1 um on
#: a screen at 70 cm is 1e-4 deg (tests/estimator/test_tracker.py FOCUS_SAME_SCREEN_M).
SAME_SCREEN_M = 1e-6
#: A labelled glint is found by a detection within this distance (px): the brief's 1 px.
FOUND_PX = 1.0


def load(spec: str, frames: int, calibration: Path | None):
    """(setup, calibration, [(frame, t0, image)], labels {(frame, strobe): (k, 2) glints})."""
    folder, _, pulses = spec.partition(":")
    folder = Path(folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    setup = parse_scene(manifest["scene"]["toml"], f"{folder / 'manifest.json'} (scene.toml)")
    width = int(manifest["image"]["width_px"])
    if setup.camera.width_px != width:
        setup = scaled_setup(setup, setup.camera.width_px // width)
    if pulses:
        setup = strobe_setup(setup, int(pulses))
    if calibration is None and (folder.parent / "calibration.json").is_file():
        calibration = folder.parent / "calibration.json"
    if calibration is not None:
        cal = load_calibration(calibration)
    else:
        cal_dir = next(d for d in (folder.parent / "calibration", folder.parent / "calib")
                       if d.is_dir())
        toml = cal_dir / "scene.toml"  # the calibration's own strobe (single pulse)
        cal = calibrate_from_folder(cal_dir, load_scene(toml) if toml.is_file() else setup)
    imgs = [(f, t0, img) for f, t0, img, err in iter_folder(folder, setup) if err is None]
    imgs = imgs[:frames]
    keep = {f for f, _, _ in imgs}
    labels = {}
    for line in (folder / "labels.jsonl").read_text().splitlines():
        row = json.loads(line)
        if row["frame"] in keep and row["strobe"] >= 0:
            g = np.array(row["glints_px"], dtype=np.float64).reshape(-1, 2)
            seen = np.array(row["glints_visible"], dtype=bool)
            labels[(row["frame"], row["strobe"])] = g[seen & np.isfinite(g).all(axis=1)]
    return setup, cal, imgs, labels


def tracker(setup, cal, method, mode) -> Tracker:
    tr = Tracker(setup, cal, method, focus_detection=mode != "whole")
    tr.focus_fallback = mode == "fallback"
    return tr


def recorded(setup, cal, method, mode, imgs):
    """The samples of ``mode``'s tracker and each frame's detections {frame: (u, v, strobe)}
    of its detector (the window's where it searched one)."""
    tr = tracker(setup, cal, method, mode)
    dets, detect = {}, tr.detector

    class Recorded:  # the detector, keeping each frame's detections
        def __call__(self, img, f):
            d = detect(img, f)
            dets[f] = (d.u_px, d.v_px, d.strobe_index)
            return d

        def __getattr__(self, name):
            return getattr(detect, name)

    tr.detector = Recorded()
    samples = [s for f, t0, img in imgs for s in tr.process(img, f, t0)]
    return samples, dets, tr


def found(dets, f, j, g) -> np.ndarray:
    """(k,) whether each labelled glint g (k, 2) of frame f, strobe j has a detection of
    strobe j within FOUND_PX."""
    u, v, s = dets[f]
    pick = s == j
    if not pick.any() or g.shape[0] == 0:
        return np.zeros(g.shape[0], dtype=bool)
    d = np.hypot(g[:, :1] - u[pick][None], g[:, 1:] - v[pick][None])
    return d.min(axis=1) <= FOUND_PX


def differs(a, b) -> bool:
    """Whether two samples of a band differ: reason, lights, or (accepted) the screen point by
    more than SAME_SCREEN_M."""
    if a.reason != b.reason or not np.array_equal(a.light_index, b.light_index):
        return True
    return bool(a.ok and np.abs(a.screen_xy_m - b.screen_xy_m).max() > SAME_SCREEN_M)


def compare(setup, cal, method, imgs, labels) -> None:
    out = {m: recorded(setup, cal, method, m, imgs) for m in MODES}
    whole, wdets, _ = out["whole"]
    for mode in ("focus", "fallback"):
        samples, dets, tr = out[mode]
        have = missed = 0
        for (f, j), g in labels.items():
            w = found(wdets, f, j, g)
            have += int(w.sum())
            missed += int((w & ~found(dets, f, j, g)).sum())
        diff = [(a, b) for a, b in zip(whole, samples) if differs(a, b)]
        both = [np.abs(a.screen_xy_m - b.screen_xy_m).max() for a, b in zip(whole, samples)
                if a.ok and b.ok]
        bits = sum(a.ok and b.ok and np.array_equal(a.screen_xy_m, b.screen_xy_m)
                   and np.array_equal(a.cornea_center_m, b.cornea_center_m)
                   for a, b in zip(whole, samples))
        acc = [(a, b) for a, b in diff if a.ok or b.ok]
        print(f"  {method}, {mode}: labelled glints whole detection finds {have}, the window "
              f"misses {missed} ({100 * missed / max(have, 1):.2f} %); bands {len(whole)}, "
              f"estimated {sum(s.ok for s in whole)} -> {sum(s.ok for s in samples)}; bands "
              f"that differ {len(diff)}, of them accepted in either {len(acc)}; frames "
              f"windowed {tr.detector.windowed} of {tr.detector.frames}, bands redone "
              f"{tr.refocused}; accepted in both {len(both)}, bit for bit {bits}, largest screen "
              f"difference {max(both, default=0.0):.1e} m")
        reasons = {}
        for a, b in diff:
            if not (a.ok or b.ok):
                reasons[(a.reason, b.reason)] = reasons.get((a.reason, b.reason), 0) + 1
        for (ra, rb), n in sorted(reasons.items(), key=lambda kv: -kv[1]):
            print(f"    failed in both, {n} bands: {ra} -> {rb}")
        for a, b in acc:
            print(f"    frame {a.frame_index} pulse {a.strobe_index}: {a.reason} "
                  f"{a.light_index.tolist()} -> {b.reason} {b.light_index.tolist()}")


def follow_decision(context, g, rows, prior, weight) -> tuple[str, list]:
    """Which of the compiled follow step's tests (``estimator.matching.follow_kernel
    .follow_band``) decides band ``g`` (k, 2) from ``prior`` (2,): its steps run one by one
    with the kernel's own compiled helpers; (decision, the lights of its last assignment).
    Decisions: few_detections, fallback, few_in_prior_gate (fewer than 5 detections within
    the prior's gate), fit_failed, not_settled, few_matched, crowded (more unmatched than
    matched and a detection within two gates of an identified glint), shift, rival (a shifted
    chain within the rival margin), match_min, accepted."""
    fk = follow_kernel
    fixed = context.kernel.fixed
    R, O, intr, size, rc, offset, radius, lights, cap, ce, rco, fit_radius, xtol, group, \
        shifted = fixed[:15]
    prior_gate, gate, margin_px, noise, unmatched, missing_cost, sigma, max_shift, rival_min, \
        min_margin = fixed[15]
    min_matches, match_min, rounds, max_nodes = (int(v) for v in fixed[16])
    cam, (lo, hi), k, n = (R, O, intr, size), (float(rows[0]), float(rows[1])), len(g), len(lights)
    if k < min_matches:
        return "few_detections", []
    pred, jac, x, JtJ = np.empty((n, 2)), np.empty((n, 2, 3)), np.empty(2), np.zeros((2, 2))
    vis, cand, inside = (np.empty(n, dtype=np.bool_) for _ in range(3))
    center, axis = np.empty(3), np.empty(3)
    assign, dist = np.empty(k, dtype=np.int64), np.empty(k)
    fk._candidates(cam, prior, rc, offset, radius, lights, cap, lo, hi, margin_px, pred, vis,
                   cand, inside, center, axis, np.empty((0, 2, 3)), False)
    if not fk._assign(g, pred, cand, prior_gate, assign, dist, max_nodes):
        return "fallback", []
    x0 = np.array(prior, dtype=np.float64)
    for _ in range(rounds):
        if (assign >= 0).sum() < min_matches:
            return "few_in_prior_gate", []
        ok = fk._fit(cam, g, lights, assign, x0, ce, rco, fit_radius, xtol, np.zeros(2),
                     np.zeros((2, 2)), x, JtJ)[0]
        if not ok:
            return "fit_failed", []
        x0[:], prev = x, assign.copy()
        if not fk._final(cam, g, x, rc, offset, radius, lights, cap, lo, hi, margin_px, gate,
                         group, max_nodes, pred, vis, cand, inside, center, axis, jac, True,
                         assign, dist):
            return "fallback", []
        if np.array_equal(assign, prev):
            break
    else:
        return "not_settled", []
    used = assign >= 0
    m, got = int(used.sum()), sorted(assign[used].tolist())
    if m < min_matches:
        return "few_matched", got
    if m < 0.5 * k and fk.crowded(g, assign, pred, cand, fk.CROWD_GATES * gate):
        return "crowded", got
    if np.abs(x - prior).max() > max_shift:
        return "shift", got
    detected = np.zeros(n, dtype=bool)
    detected[assign[used]] = True
    d = (x - prior) / sigma
    score = (float((dist[used] ** 2).sum()) / noise ** 2 + (k - m) * unmatched
             + missing_cost * int((inside & ~detected).sum()) + weight * float(d @ d))
    cp, sp, cy, sy = math.cos(x[1]), math.sin(x[1]), math.cos(x[0]), math.sin(x[0])
    da = offset * np.array([[cp * cy, -sp * sy], [0.0, cp], [cp * sy, sp * cy]])
    J = np.ascontiguousarray(np.einsum("nac,cb->nab", jac, da))
    margin = rival_margin(g, assign, pred, J, vis, shifted, x, np.asarray(prior, float), lo,
                          hi, gate, margin_px, noise, unmatched, missing_cost, sigma, weight,
                          score)
    if not margin >= rival_min:
        return "rival", got
    if m < match_min or margin < min_margin:
        return "match_min", got
    return "accepted", got


def declines(setup, cal, method, imgs) -> None:
    """Every dense band the cheap path declines: the follow step's decision (from the prior,
    then the second try from the last rotation), and what the tracker then did (left
    unsearched, or the search's reason, "ok" with the cheap try's lights or with others), and
    the searches' CPU time by decision."""
    import estimator.tracking.bands as bands
    table, ms, cur = Counter(), Counter(), {}
    cheap, search, dense = bands.cheap_sample, bands.searched_sample, bands.dense_sample

    def cheap_sample(context, state, f, j, time_s, g, rows):
        got = cheap(context, state, f, j, time_s, g, rows)
        cur.clear()
        if got is not None or context.kernel is None:
            return got
        fresh = state.fresh_prior()
        prior = state.prior_angles_rad if fresh else state.carried_prior(time_s)
        g = np.ascontiguousarray(g, dtype=np.float64)
        if prior is None:
            cur.update(key=(f, j), why=("no prior" if state.last is None else "prior too old",
                                        ""), lights=[])
            return None
        why, lights = follow_decision(context, g, rows, prior, 1.0 if fresh else 0.0)
        again = ""
        if why != "accepted" and not fresh and state.velocity_rad_s is not None:
            again, got2 = follow_decision(context, g, rows, state.last.angles_rad, 0.0)
            lights = got2 if again == "accepted" else lights
        cur.update(key=(f, j), why=(why, again), lights=lights)
        return None

    def searched_sample(context, state, f, j, time_s, g, rows):
        t = time.process_time()
        s, after = search(context, state, f, j, time_s, g, rows)
        if cur.get("key") == (f, j):
            out = str(s.reason)
            if s.ok:
                same = sorted(s.light_index.tolist()) == cur["lights"]
                out = "ok, the same lights" if same else "ok, other lights"
            table[(*cur["why"], out)] += 1
            ms[cur["why"][0]] += 1e3 * (time.process_time() - t)
        return s, after

    def dense_sample(context, state, f, j, time_s, g, rows, counts):
        before = counts["unfillable"]
        got = dense(context, state, f, j, time_s, g, rows, counts)
        if counts["unfillable"] != before and cur.get("key") == (f, j):
            table[(*cur["why"], "unsearched (band_out_of_reach)")] += 1
        return got

    bands.cheap_sample, bands.searched_sample, bands.dense_sample = (
        cheap_sample, searched_sample, dense_sample)
    try:
        tr = tracker(setup, cal, method, "whole")
        samples = [s for f, t0, img in imgs for s in tr.process(img, f, t0)]
    finally:
        bands.cheap_sample, bands.searched_sample, bands.dense_sample = cheap, search, dense
    print(f"  {method}: {len(samples)} bands, estimated {sum(s.ok for s in samples)}; dense "
          f"bands by route {dict(tr.counts)}")
    print("    declined bands | decision (prior) | second try | then")
    for (why, again, out), n in sorted(table.items(), key=lambda kv: -kv[1]):
        print(f"    {n:6d} | {why} | {again or '-'} | {out}")
    for why, t in sorted(ms.items(), key=lambda kv: -kv[1]):
        print(f"    searches after '{why}': {t:.0f} ms CPU")


def timing(setup, cal, method, imgs, rounds: int) -> None:
    for mode in MODES:  # load the compiled kernels
        tr = tracker(setup, cal, method, mode)
        for f, t0, img in imgs[:3]:
            tr.process(img, f, t0)
    rates = {m: [] for m in MODES}
    for _ in range(rounds):
        for mode in MODES:
            tr = tracker(setup, cal, method, mode)
            t = time.process_time()
            for f, t0, img in imgs:
                tr.process(img, f, t0)
            rates[mode].append(len(imgs) / (time.process_time() - t))
    base = np.array(rates["whole"])
    for mode in MODES:
        r = np.array(rates[mode])
        ratio = r / base
        print(f"  {method}, {mode}: {np.median(r):.0f} frames/s (rounds {r.min():.0f}-"
              f"{r.max():.0f}), {np.median(ratio):.2f}x whole (rounds {ratio.min():.2f}-"
              f"{ratio.max():.2f})")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("datasets", nargs="+", help="rendered dataset folders, DIR[:PULSES]")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--calibration", type=Path, default=None)
    ap.add_argument("--no-timing", action="store_true", help="compare the samples only")
    ap.add_argument("--declines", action="store_true",
                    help="only the default tracker's declined bands: why, and what followed")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    for spec in args.datasets:
        try:
            setup, cal, imgs, labels = load(spec, args.frames, args.calibration)
        except (OSError, ValueError, KeyError, StopIteration) as exc:
            ap.error(f"{spec}: not a rendered dataset with a calibration: {exc}")
        print(f"{spec}: {len(imgs)} frames {setup.camera.width_px}x{setup.camera.height_px}, "
              f"{setup.strobe.pulses_per_frame} pulses/frame")
        if args.declines:
            for method in ("polynomial", "geometric"):
                declines(setup, cal, method, imgs)
            continue
        for method in ("polynomial", "geometric"):
            compare(setup, cal, method, imgs, labels)
        if not args.no_timing:
            for method in ("polynomial", "geometric"):
                timing(setup, cal, method, imgs, args.rounds)


if __name__ == "__main__":
    main()
