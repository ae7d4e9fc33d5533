"""Tracker throughput on one core: glint detection frames/s and end-to-end samples/s, the cheap
path against the hypothesis search on every band, in one run on the same frames.

Frames: 640x480 10-bit banded frames of paper_sim (Gaussian glints at their closed-form
positions for an eye making saccades, each pulse's glints at the eye's pose then, every pulse's
row weights, an eye-like background, shot and read noise; :func:`bench_glints.moving_sequence`),
or with ``--dataset DIR`` the PNG frames of a rendered dataset (tracked with the scene its
manifest records and that scene's ground-truth calibration). Detection is timed through
:class:`estimator.glints.GlintDetector` (one pass over the frames as a stream, after a warm-up
pass that loads its compiled kernels). End to end, :meth:`estimator.tracker.Tracker.process`
(detect, group by strobe, predict, assign, fit, map), both gaze methods, ``cheap=False`` (the
hypothesis search on every band: the path before issue 15), ``cheap=True`` with its band step
in Python (the compiled step of :mod:`estimator.tracking.kernel` off: the path before issue 31's
kernel, whose samples must be the compiled step's bit for bit), ``cheap=True`` with the matcher's
numpy steps (:mod:`estimator.matching.kernels` off, and with it the search's compiled refits
and predictions: as on an install without Numba) and
``cheap=True`` alternated over ``--rounds`` rounds on the same frames (the machine's speed
drifts: ratios are per round):
samples/s (every lit band is a sample, NaN or not; and the estimates/s of the estimated
ones), per-frame latency p50/p99 (frame in, its samples out, wall time), whether both give the same
samples (reasons; identities and estimates to 1e-6 m where estimated), where each band's
microseconds go on the cheap path, and the estimated Raspberry Pi 3B+ figure.
With ``--conic Q`` it measures instead what the estimator's conic cornea option costs: the
same synthetic frames of an eye whose cornea has conic constant Q, tracked with the cheap path
by the spherical tracker and by the conic-aware one (``cornea_model = "conic"``, Q known; both
calibrations exact: nominal lighting, the eye's own c_e and r_co, Eq. (1) fitted to the model's
own noise-free centres of the 5x5 pattern), alternated over the rounds: samples/s of each, their
ratio per round, and the samples each estimates.
Usage:

    python benchmarks/bench_tracker.py [--frames 60] [--rounds 3] [--dataset DIR [--pulses N]]
                                       [--calibration FILE] [--conic Q] [--clock cpu] [--focus]

Each band step's latency (:meth:`Tracker.band`, from the band's detections to its sample; with
``--clock cpu`` the thread's CPU time where that clock ticks finely) is printed as p50/p99
beside the frame's, with the rest of the frame's time (detection, grouping)
per band. ``--clock cpu`` times by the process's CPU time instead of the wall clock: on a
machine shared with other work it is what the tracker costs one core. On a Raspberry Pi (an
ARM machine) the last line of each method compares the measured samples/s with what the
planning rule expects from :data:`REFERENCE_X86` (hardware/README.md, "Real time on a
Raspberry Pi").

With ``--focus`` it also runs the cheap path with focused detection
(``Tracker(focus_detection=True)``: each frame searched around the glints the last frame's
samples used, :class:`estimator.glints.GlintDetector` ``focus``) in the same alternation, and
prints its samples/s against the whole-frame detection's and whether the samples agree (as
above; on rendered frames with clutter they may not where a glint appears outside the window).

With ``--calibration FILE`` (a calibration with ``glint_flux``: ``scet calibrate`` of the
dataset's calibration frames) it also times the cut-glint check
(``Tracker(flag_cut_glints=True)``): microseconds per checked band, per refit, and the pass
against the same tracker without it (``flag_cut_glints=False``). The other passes run the
tracker as it is by default: they check for cut glints where the calibration has
``glint_flux``.

60 frames are one second of video: a stream's first cold search and the searches after
saccades that cross a frame gap weigh in as in a longer run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The tests' ground-truth calibration (tests/estimator/simulated.py).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_glints import moving_sequence  # noqa: E402

import estimator.matching.follow as follow_module  # noqa: E402
import estimator.matching.kernels as match_kernels  # noqa: E402
import estimator.tracking.context as context_module  # noqa: E402
import estimator.tracking.estimates as estimates_module  # noqa: E402
import estimator.tracking.tracker as tracker_module  # noqa: E402
from estimator.folders import iter_folder, load_calibration  # noqa: E402
from estimator.glints import GlintDetector  # noqa: E402
from estimator.reasons import Reason  # noqa: E402
from estimator.scene import load_scene, parse_scene  # noqa: E402
from estimator.tracking import Tracker  # noqa: E402
from tests.estimator.simulated import ground_truth_calibration  # noqa: E402

#: A Raspberry Pi 3B+ core against this kind of x86 core: 15x slower, 10-30x the range
#: (../shared/HARDWARE.md Sec. 12: Quake/Doom single-thread times of a Pi 2 and a Core
#: i3-3220, Pi 3B+ / Pi 2 ratios, desktop / Ivy Bridge ratios; SIMD-bound numpy 15-30x).
PI_FACTOR, PI_RANGE = 15.0, (10.0, 30.0)
PI_SOURCE = "shared/HARDWARE.md Sec. 12 (planning rule: x86 single-thread time x 15, 10-30)"
#: What a Raspberry Pi must sustain: a 60 Hz camera with 16 pulses a frame gives 960 bands
#: (samples) a second, and 60 frames a second.
PI_NEEDED_SAMPLES_S, PI_NEEDED_FRAMES_S = 960.0, 60.0
#: The cheap path's samples/s on the synthetic frames (60 frames, 3 rounds, --clock cpu, the
#: median) of a desktop x86 core, measured at this version (hardware/README.md, "Real time on a Raspberry Pi"): the
#: figures an ARM run is compared with, through the planning rule.
REFERENCE_X86 = {"polynomial": 3337.0, "geometric": 3903.0}
#: The clock of every timing: wall time (default), or the process's CPU time (``--clock
#: cpu``: on a machine shared with other work, what the tracker itself costs one core).
clock = time.perf_counter
#: The clock of a band step's latency: the wall clock, or with ``--clock cpu`` the thread's CPU
#: time where it ticks finely (CLOCK_THREAD_CPUTIME_ID; 1 ns here): on a loaded machine the
#: wall clock's p99 is the scheduler's, not the tracker's.
band_clock = time.perf_counter
#: Whether the matcher's compiled steps run (Numba installed, JIT on).
KERNELS = match_kernels.ENABLED
#: follow: the cheap path's prediction, assignment, fit and checks as one compiled call
#: (estimator.tracking.kernel: with polynomial gaze's centre fit and the map in it); with the
#: Python form they count as predict, assign, fit.
STAGES = ("detect", "group", "follow", "predict", "assign", "fit", "map", "search", "prior",
          "other")


def synthetic_frames(setup, n: int, rng):
    """Frames of an eye making saccades between random screen targets
    (:func:`bench_glints.moving_sequence`: each pulse's glints at the eye's pose then)."""
    return moving_sequence(setup, n, rng)[0]


def run(tracker, frames, band_s=None, wall_s=None):
    """Samples and per-frame seconds (:data:`clock`) of one pass; with lists ``band_s`` and
    ``wall_s``, the seconds of every band step (:meth:`Tracker.band`: from the band's
    detections to its sample; :data:`band_clock`) and the wall seconds of every frame appended
    (the process's CPU clock ticks too coarsely on some kernels, 4 ms on one measured, to time
    one band; the thread's, where it ticks finely, times it)."""
    if band_s is not None:
        step = tracker.band

        def timed_band(*a, **k):
            t = band_clock()
            try:
                return step(*a, **k)
            finally:
                band_s.append(band_clock() - t)

        tracker.band = timed_band
    samples, lat = [], []
    for f, t0, img in frames:
        t, w = clock(), time.perf_counter()
        samples.extend(tracker.process(img, f, t0))
        lat.append(clock() - t)
        if wall_s is not None:
            wall_s.append(time.perf_counter() - w)
    return samples, np.array(lat)


def focus_misses(setup, cal, method, frames, whole) -> dict:
    """What focused detection loses against the whole frame's: the glints the whole-frame
    tracker's accepted samples used (``whole``, its samples of ``frames``) that the focused
    tracker's detector did not detect in the same frame (the window's detections are exactly
    the whole frame's, to 1e-9 px), the estimated samples of each, and the largest screen
    difference (m) of a band both estimated."""
    tr = Tracker(setup, cal, method, focus_detection=True)
    dets = {}

    class Recorded:  # the detector, keeping each frame's detections
        def __call__(self, img, f, detect=tr.detector):
            dets[f] = detect(img, f)
            return dets[f]

        def __getattr__(self, name, detect=tr.detector):
            return getattr(detect, name)

    tr.detector = Recorded()
    focused, _ = run(tr, frames)
    missed = total = 0
    for s in whole:
        if not s.ok:
            continue
        have = dets[s.frame_index].glints_px
        for g in s.glints_px:
            total += 1
            missed += have.shape[0] == 0 or np.abs(have - g).max(axis=1).min() > 1e-6
    both = [np.abs(x.screen_xy_m - y.screen_xy_m).max() for x, y in zip(whole, focused)
            if x.ok and y.ok]
    return {"missed": missed, "glints": total, "whole_ok": sum(x.ok for x in whole),
            "focused_ok": sum(y.ok for y in focused), "dscreen_m": max(both, default=0.0)}


def same(a, b) -> bool:
    """Whether samples ``b`` (the cheap path) are ``a``: reasons, and the identities and
    estimates (to 1e-6 m) of the estimated ones. A NaN band of ``b`` the cheap path left
    unsearched (``band_out_of_reach``) may name another reason in ``a``, a NaN there too
    (:func:`estimator.tracking.dense_sample`); a NaN sample's glints and lights are diagnostics of the
    route that failed (a sparse band's prior-assisted retry keeps those of the failure before
    it, a search's or ``band_out_of_reach``'s), not answers."""
    return len(a) == len(b) and all(
        (y.reason == Reason.OUT_OF_REACH and not x.ok) or (
            x.reason == y.reason and (not x.ok or (
                np.array_equal(x.light_index, y.light_index)
                and np.abs(x.cornea_center_m - y.cornea_center_m).max() < 1e-6)))
        for x, y in zip(a, b))


def bit_identical(a, b) -> bool:
    """Whether samples ``a`` and ``b`` are the same to the last bit: every field, arrays by
    their bytes (the compiled band step against the Python one)."""
    def bits(v):
        v = np.atleast_1d(np.asarray(v))
        return v.dtype.str, v.shape, v.tobytes()

    return len(a) == len(b) and all(
        all(bits(getattr(x, n)) == bits(getattr(y, n)) for n in x.__dataclass_fields__)
        for x, y in zip(a, b))


class _Timed:
    """Wraps a callable, adding its seconds to ``totals[stage]`` (not inside a search or a
    sparse band's identification from the prior, whose predictions and assignments count as
    theirs)."""

    def __init__(self, fn, totals, stage):
        self.fn, self.totals, self.stage = fn, totals, stage

    def __call__(self, *a, **k):
        if self.totals["_searching"]:
            return self.fn(*a, **k)
        self.totals["_searching"] = self.stage in ("search", "prior")
        t = clock()
        try:
            return self.fn(*a, **k)
        finally:
            self.totals[self.stage] += clock() - t
            self.totals["_searching"] = False

    def __getattr__(self, name):  # the wrapped object's other methods (a detector's reset)
        return getattr(self.fn, name)


class _TimedMapping:
    def __init__(self, mapping, totals):
        self.mapping, self.n_features = mapping, mapping.n_features
        self.predict = _Timed(mapping.predict, totals, "map")
        self.predict_one = _Timed(mapping.predict_one, totals, "map")


def breakdown(setup, cal, method, frames, compiled=True) -> dict:
    """Seconds per stage of one cheap-path pass (the stages wrapped where they are called;
    nested stages are subtracted from their callers); ``compiled`` False runs the Python
    forms of the band steps (the cheap path's follow, whose predict, assign and fit are timed
    apart, and the prior's)."""
    totals = defaultdict(float)
    tr = Tracker(setup, cal, method)
    tr.follower.compiled = compiled and tr.follower.compiled
    # The compiled band steps (estimator.tracking.kernel, prior_kernel) count as follow and
    # prior: each identifies, fits and maps in one call; the Python forms run without them.
    ctx = tr.context
    tr.context = replace(
        ctx, kernel=_Timed(ctx.kernel, totals, "follow") if compiled and ctx.kernel else None,
        prior_kernel=_Timed(ctx.prior_kernel, totals, "prior")
        if compiled and ctx.prior_kernel else None)
    tr.follower._follow_compiled = _Timed(tr.follower._follow_compiled, totals, "follow")
    tr.detector = _Timed(tr.detector, totals, "detect")
    tr.follower.predict = _Timed(tr.follower.predict, totals, "predict")
    m = tr.matcher
    m._assign = _Timed(m._assign, totals, "assign")
    m._final_assign = _Timed(m._final_assign, totals, "assign")
    saved = (follow_module.fit_small, context_module.BandContext.gaze_point)
    follow_module.fit_small = estimates_module.fit_small = _Timed(saved[0], totals, "fit")
    if method == "geometric":  # polynomial gaze's map is its mapping's (timed below)
        timed_point = _Timed(saved[1], totals, "map")
        context_module.BandContext.gaze_point = lambda self, c, a: timed_point(self, c, a)
    tr.group = _Timed(tr.group, totals, "group")
    m.match = _Timed(m.match, totals, "search")
    m.match_near = _Timed(m.match_near, totals, "prior")
    if tr.context.gaze_map is not None:
        tr.context = replace(tr.context, gaze_map=_TimedMapping(tr.context.gaze_map, totals))
    try:
        t = clock()
        samples, _ = run(tr, frames)
        wall = clock() - t
    finally:
        follow_module.fit_small, context_module.BandContext.gaze_point = saved
        estimates_module.fit_small = saved[0]
    totals["other"] = wall - sum(totals[s] for s in STAGES if s != "other")
    return {"samples": len(samples), "wall": wall, **totals}


def flux_cost(setup, cal, method, frames) -> dict:
    """The cut-glint check's cost (``flag_cut_glints=True``, :mod:`estimator.tracking.cut_glints`):
    seconds and calls of the check of accepted bands and of the refits without flagged glints,
    and the pass's wall time against the same tracker without the check."""
    totals, calls = defaultdict(float), defaultdict(int)
    saved = (tracker_module.flagged, Tracker.without)

    def timed(fn, stage):
        def call(*a, **k):
            t = clock()
            try:
                return fn(*a, **k)
            finally:
                totals[stage] += clock() - t
                calls[stage] += 1
        return call

    tracker_module.flagged, Tracker.without = timed(saved[0], "check"), timed(saved[1], "refit")
    try:
        run(Tracker(setup, cal, method, flag_cut_glints=True), frames[:3])  # warm-up
        totals.clear(), calls.clear()
        samples, lat = run(Tracker(setup, cal, method, flag_cut_glints=True), frames)
    finally:
        tracker_module.flagged, Tracker.without = saved
    off, lat_off = run(Tracker(setup, cal, method, flag_cut_glints=False), frames)
    return {"samples": len(samples), "wall": lat.sum(), "wall_off": lat_off.sum(),
            "flagged": sum(s.flux_flagged.size for s in samples), **{f"{k}_s": v for k, v in
                                                                      totals.items()},
            **{f"{k}_n": v for k, v in calls.items()}}


def conic_calibration(setup):
    """The exact calibration of ``setup``'s conic eye for the conic-aware tracker: as
    :func:`ground_truth_calibration`, with ``cornea_model = "conic"`` and the eye's Q, its
    Eq. (1) mapping fitted to the conic fits' centres."""
    from estimator.calibration import fit_gaze_mapping
    from estimator.gaze import fit_cornea_centers

    cal = replace(ground_truth_calibration(setup), mappings={}, cornea_model="conic",
                  cornea_asphericity=setup.eye.cornea_asphericity)
    targets = setup.screen.grid(5, 5, margin=0.0)
    yaw, pitch = setup.eye.angles_toward(targets)
    g, vis, _ = setup.eye.glints(setup.camera, setup.lights_world_m, yaw, pitch)
    c = fit_cornea_centers(setup, cal, np.where(vis[..., None], g, np.nan)).center_m
    return cal.with_mappings(eq1_25=fit_gaze_mapping(c, targets, "eq1", degenerate="min_norm"))


def compare_cornea_models(setup, frames, rounds: int) -> None:
    """Spherical against conic-aware tracker, cheap path, alternated on the same frames."""
    cals = {"sphere": ground_truth_calibration(setup), "conic": conic_calibration(setup)}
    for method in ("polynomial", "geometric"):
        for cal in cals.values():
            run(Tracker(setup, cal, method), frames[:3])
        rates = {k: [] for k in cals}
        oks = {}
        for _ in range(rounds):
            for name, cal in cals.items():
                samples, lat = run(Tracker(setup, cal, method), frames)
                rates[name].append(len(samples) / lat.sum())
                oks[name] = (sum(x.ok for x in samples), len(samples))
        ratio = np.array(rates["sphere"]) / np.array(rates["conic"])
        for name in cals:
            r = np.array(rates[name])
            print(f"tracker {method}, {name} cornea: {np.median(r):.0f} samples/s (rounds "
                  f"{r.min():.0f}-{r.max():.0f}), {oks[name][0]}/{oks[name][1]} samples estimated")
        print(f"  sphere / conic: {np.median(ratio):.2f}x (rounds {ratio.min():.2f}-{ratio.max():.2f})")


def compare_distortion(setup, frames, rounds: int, coefficients) -> None:
    """samples/s of the tracker with the scene's camera given a lens distortion (detections
    undistorted, :meth:`GlintDetections.undistorted`) against the pinhole, alternated over the
    rounds on the same frames, and the undistortion's own cost per frame. The frames are the
    pinhole's, so the given lens moves the glints off the model and may change the bands' path
    (counts printed); a lens of k1 = 1e-12 takes the pinhole's path with the undistortion step:
    its ratio is the step's cost alone."""
    from estimator.lens import ideal_setup

    lenses = {"pinhole": setup,
              "undistort only (k1 = 1e-12)": replace(setup, camera=replace(
                  setup.camera, distortion=[1e-12, 0.0, 0.0, 0.0])),
              "lens": replace(setup, camera=replace(setup.camera, distortion=coefficients))}
    cal = ground_truth_calibration(ideal_setup(setup))
    rates, ok, counts = {k: [] for k in lenses}, {}, {}
    for s in lenses.values():  # warm up (kernels, caches)
        run(Tracker(s, cal, "polynomial"), frames[:3])
    for _ in range(rounds):
        for name, s in lenses.items():
            tr = Tracker(s, cal, "polynomial")
            samples, lat = run(tr, frames)
            rates[name].append(len(samples) / lat.sum())
            ok[name], counts[name] = sum(x.ok for x in samples), dict(tr.counts)
    detector = GlintDetector(setup)
    dets = [detector(img, f) for f, _, img in frames]
    t = clock()
    for _ in range(rounds):
        for d in dets:
            d.undistorted(lenses["lens"].camera)
    per = (clock() - t) / (rounds * len(dets))
    base = np.array(rates["pinhole"])
    for name in lenses:
        r = np.array(rates[name])
        print(f"tracker polynomial, {name}: {np.median(r):.0f} samples/s (rounds {r.min():.0f}-"
              f"{r.max():.0f}; / pinhole {np.median(r / base):.3f}x, rounds "
              f"{(r / base).min():.3f}-{(r / base).max():.3f}), {ok[name]} estimated, bands "
              f"{counts[name]['cheap']} cheap, {counts[name]['search']} searched")
    print(f"  undistortion {1e6 * per:.1f} us per frame "
          f"({np.mean([len(d) for d in dets]):.1f} glints), distortion {list(coefficients)}")


def dataset_scene(ap, folder: Path):
    """The scene a rendered dataset was rendered with (its manifest's ``scene.toml``: a
    ``prototype_ov5647`` dataset is tracked with the prototype's camera and lights, not
    paper_sim's)."""
    manifest = folder / "manifest.json"
    try:
        toml = json.loads(manifest.read_text())["scene"]["toml"]
        return parse_scene(toml, f"{manifest} (its scene.toml)")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        ap.error(f"{manifest}: no readable scene (key scene.toml): {exc}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--dataset", type=Path, default=None)
    ap.add_argument("--calibration", type=Path, default=None,
                    help="calibration file with glint_flux (scet calibrate): also time the "
                         "cut-glint check (Tracker flag_cut_glints) with it")
    ap.add_argument("--pulses", type=int, default=None,
                    help="pulses per frame of --dataset (default: the scene's; the quick "
                         "validation's test_p8 needs 8)")
    ap.add_argument("--conic", type=float, default=None, metavar="Q",
                    help="compare the spherical and the conic-aware tracker on an eye of conic "
                         "constant Q (synthetic frames only)")
    ap.add_argument("--focus", action="store_true",
                    help="also time the cheap path with focused detection "
                         "(Tracker(focus_detection=True)) and compare its samples")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="time by the wall clock (default) or by the process's CPU time (a "
                         "machine shared with other work: what the tracker costs one core)")
    ap.add_argument("--distortion", nargs="?", const="-0.35,0.25,0.001,-0.0008,0",
                    default=None, metavar="K1,K2,P1,P2[,K3...]",
                    help="compare the tracker on the scene's camera with this OpenCV lens "
                         "distortion (detections undistorted) against the pinhole (synthetic "
                         "frames; default coefficients those of tests/estimator/"
                         "test_camera_file_tracker.py)")
    args = ap.parse_args(argv)
    global clock, band_clock
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    if args.clock == "cpu" and time.get_clock_info("thread_time").resolution <= 1e-6:
        band_clock = time.thread_time
    setup = load_scene("paper_sim") if args.dataset is None else dataset_scene(ap, args.dataset)
    if args.conic is not None:
        if args.dataset is not None:
            ap.error("--conic runs on synthetic frames; leave out --dataset")
        setup = replace(setup, eye=replace(setup.eye, cornea_asphericity=args.conic))
    if args.pulses is not None:
        from estimator.banding import strobe_setup

        setup = strobe_setup(setup, args.pulses)
    rng = np.random.default_rng(0)
    cv2.setNumThreads(1)
    if args.dataset is not None:
        from estimator.banding import scaled_setup

        width = json.loads((args.dataset / "manifest.json").read_text())["image"]["width_px"]
        if setup.camera.width_px != int(width):  # a quick render records the full-size scene
            setup = scaled_setup(setup, setup.camera.width_px // int(width))
        frames = [(f, t0, img) for f, t0, img, err in iter_folder(args.dataset, setup)
                  if err is None][: args.frames]
    else:
        frames = [(f, None, img) for f, img in synthetic_frames(setup, args.frames, rng)]
    print(f"{platform.processor() or platform.machine()}, {len(frames)} frames "
          f"{setup.camera.width_px}x{setup.camera.height_px}, "
          f"{setup.strobe.pulses_per_frame} pulses/frame, one core, {args.clock} clock, "
          f"Numba kernels {'on' if KERNELS else 'off'}")

    for _ in range(2):  # load (or compile) the detector's kernels, windowed ones included
        detector = GlintDetector(setup)
        t = clock()
        n_glints = sum(len(detector(img, f)) for f, _, img in frames)
        dt = clock() - t
    print(f"detection (GlintDetector, one pass): {len(frames) / dt:.1f} frames/s "
          f"({1e3 * dt / len(frames):.2f} ms/frame, {n_glints / len(frames):.1f} glints/frame, "
          f"{detector.windowed} of {detector.frames} frames in a window)")

    if args.conic is not None:
        compare_cornea_models(setup, frames, args.rounds)
        return
    if args.distortion is not None:
        compare_distortion(setup, frames, args.rounds,
                           [float(v) for v in args.distortion.split(",")])
        return
    cal = ground_truth_calibration(setup)
    for method in ("polynomial", "geometric"):
        for cheap in (False, True):  # compile the cheap path's kernels before timing
            run(Tracker(setup, cal, method, cheap=cheap), frames[:3])
        modes = (False, "python", True, "numpy") + (("focus",) if args.focus else ())
        rates = {m: [] for m in modes}
        bands = {m: [] for m in modes}
        walls = {m: [] for m in modes}
        spent = {m: 0.0 for m in modes}  # seconds of every round's frames (clock)
        agree, agree_numpy, agree_focus, counts = True, True, True, None
        identical = True
        for _ in range(args.rounds):
            out = {}
            for cheap in modes:
                # "numpy": the cheap path with the matcher's numpy steps (no matching kernels);
                # "python": the cheap path with its band step in Python (the compiled step of
                # estimator.tracking.kernel off: the path before it, in the same run);
                # "focus": the cheap path with focused detection.
                match_kernels.ENABLED = cheap != "numpy" and KERNELS
                try:
                    tr = Tracker(setup, cal, method, cheap=bool(cheap),
                                 focus_detection=cheap == "focus")
                    if cheap == "python":
                        tr.context = replace(tr.context, kernel=None, prior_kernel=None)
                    samples, lat = run(tr, frames, bands[cheap], walls[cheap])
                finally:
                    match_kernels.ENABLED = KERNELS
                rates[cheap].append(len(samples) / lat.sum())
                spent[cheap] += lat.sum()
                out[cheap] = samples
                if cheap is True:
                    counts = dict(tr.counts)
            agree &= same(out[False], out[True])
            agree_numpy &= same(out["numpy"], out[True])
            identical &= bit_identical(out["python"], out[True])
            if args.focus:
                agree_focus &= same(out[True], out["focus"])
            ok = sum(s.ok for s in out[True])
        ratio = np.array(rates[True]) / np.array(rates[False])
        ratio_numpy = np.array(rates[True]) / np.array(rates["numpy"])
        ratio_step = np.array(rates[True]) / np.array(rates["python"])
        for cheap, name in ((False, "search every band"), ("numpy", "cheap path, numpy matcher"),
                            ("python", "cheap path, Python band step"), (True, "cheap path"),
                            ("focus", "cheap path, focused detection")):
            if cheap not in rates:
                continue
            r, lat = np.array(rates[cheap]), np.array(walls[cheap]) * 1e3
            band = np.array(bands[cheap]) * 1e3
            # The rest of a frame's time (detection, grouping, the band layout) per band, on the
            # frames' clock (the band steps' is the same kind: wall, or CPU time of this one
            # thread).
            rest = (1e3 * spent[cheap] - band.sum()) / max(len(band), 1)
            print(f"tracker {method}, {name}: {np.median(r):.0f} samples/s "
                  f"(rounds {r.min():.0f}-{r.max():.0f}), latency p50 {np.percentile(lat, 50):.2f} ms, "
                  f"p99 {np.percentile(lat, 99):.2f} ms per frame (wall); band step "
                  f"({'thread CPU time' if band_clock is time.thread_time else 'wall'}) p50 "
                  f"{np.percentile(band, 50):.3f} ms, p99 {np.percentile(band, 99):.3f} ms "
                  f"(+ {rest:.3f} ms a band of detection and the frame's glue)")
        print(f"  cheap / search: {np.median(ratio):.1f}x (rounds {ratio.min():.1f}-{ratio.max():.1f}); "
              f"bands: {counts['cheap']} cheap, {counts['search']} searched, {counts['unfillable']} "
              f"left to the prior unsearched; {ok}/{len(out[True])} "
              f"samples estimated ({np.median(rates[True]) * ok / len(out[True]):.0f} "
              f"estimates/s); same samples: {'yes' if agree else 'NO'}")
        print(f"  compiled / Python band step: {np.median(ratio_step):.2f}x (rounds "
              f"{ratio_step.min():.2f}-{ratio_step.max():.2f}); samples identical bit for bit: "
              f"{'yes' if identical else 'NO'}")
        print(f"  matching kernels / numpy matcher: {np.median(ratio_numpy):.2f}x (rounds "
              f"{ratio_numpy.min():.2f}-{ratio_numpy.max():.2f}); same samples: "
              f"{'yes' if agree_numpy else 'NO'}"
              + ("" if KERNELS else " (Numba is not installed: both run numpy)"))
        if args.focus:
            ratio_focus = np.array(rates["focus"]) / np.array(rates[True])
            miss = focus_misses(setup, cal, method, frames, out[True])
            print(f"  focused / whole-frame detection: {np.median(ratio_focus):.2f}x (rounds "
                  f"{ratio_focus.min():.2f}-{ratio_focus.max():.2f}); same samples: "
                  f"{'yes' if agree_focus else 'NO'}; glints of the accepted samples not "
                  f"detected: {miss['missed']} of {miss['glints']} "
                  f"({100 * miss['missed'] / max(miss['glints'], 1):.2f} %); estimated "
                  f"{miss['whole_ok']} -> {miss['focused_ok']}; largest screen difference "
                  f"{1e3 * miss['dscreen_m']:.3g} mm")
        for compiled, name in ((True, "cheap path"), (False, "cheap path, Python band steps")):
            b = breakdown(setup, cal, method, frames, compiled)
            per = {s: 1e6 * b[s] / b["samples"] for s in STAGES}
            print(f"  us per band ({name}): " + ", ".join(f"{s} {per[s]:.0f}" for s in STAGES)
                  + f"; total {1e6 * b['wall'] / b['samples']:.0f}")
        if args.calibration is not None:
            c = flux_cost(setup, load_calibration(args.calibration), method, frames)
            print(f"  cut-glint check ({args.calibration.name}): "
                  f"{1e6 * c.get('check_s', 0) / max(c.get('check_n', 0), 1):.1f} us per "
                  f"checked band ({c.get('check_n', 0)} of {c['samples']}), refit "
                  f"{1e6 * c.get('refit_s', 0) / max(c.get('refit_n', 0), 1):.0f} us per band "
                  f"with a flag ({c.get('refit_n', 0)}, {c['flagged']} glints flagged); "
                  f"pass {1e6 * c['wall'] / c['samples']:.0f} against "
                  f"{1e6 * c['wall_off'] / c['samples']:.0f} us per band without the check")
        best = np.median(rates[True])
        if platform.machine() in ("aarch64", "arm64", "armv7l"):
            ref = REFERENCE_X86[method]
            print(f"  this ARM core: {best:.0f} samples/s (a 60 Hz camera at 16 pulses needs "
                  f"{PI_NEEDED_SAMPLES_S:.0f}); the planning rule expected "
                  f"{ref / PI_FACTOR:.0f} ({ref / PI_RANGE[1]:.0f}-{ref / PI_RANGE[0]:.0f}) on a "
                  f"Pi 3B+ core from the reference x86 figure {ref:.0f}: the x86 / this core "
                  f"factor is {ref / best:.1f} ({PI_SOURCE})")
        else:
            print(f"  Raspberry Pi 3B+ estimate: {best / PI_FACTOR:.0f} samples/s per core "
                  f"({best / PI_RANGE[1]:.0f}-{best / PI_RANGE[0]:.0f}; factor {PI_FACTOR:g}, "
                  f"range {PI_RANGE[0]:g}-{PI_RANGE[1]:g}, {PI_SOURCE}); a 60 Hz camera at 16 "
                  f"pulses needs {PI_NEEDED_SAMPLES_S:.0f}")


if __name__ == "__main__":
    main()
