"""Glint detection frames per second and glint matching samples per second, one core.

Detection: 640x480 10-bit banded frames of the paper_sim glints (Gaussian spots at their
closed-form positions, every pulse's row weights, an eye-like background, shot and read noise).
Two figures. Per frame, cold: :func:`estimator.glints.detect_glints` on frames at random eye
rotations (every frame measures its own noise model and is searched whole), with the centroid
error against the closed-form glints. Streaming: :class:`estimator.glints.GlintDetector` over
120 frames of an eye making main-sequence saccades between random screen targets (each
pulse's glints at the eye's pose at that pulse), searching every frame whole against
searching a window around the glints, and the window with the detector's numpy path (what
runs without Numba), timed as whole passes over the sequence (a noise model and a whole-frame
search every 30 frames included), alternated; the detections are checked against each other. Matching: bands as the tests build them (48 rows,
0.3-0.5 px noise, 5-10 % dropped glints, 1-3 spurious blobs), through
:meth:`estimator.matching.GlintMatcher.match` with a previous-sample prior and cold, on
paper_sim and paper_sim_doubled, with the identity rates measured on them. Usage:

    python benchmarks/bench_glints.py [--seconds 2] [--frames 8] [--stream-frames 120] [--bands 200]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from scipy.special import erf  # noqa: E402

from estimator.banding import row_pulse_weights
from estimator.glints import BLENDED, CUT_BY_BAND_EDGE, IMAGE_EDGE, GlintDetector, detect_glints
from estimator.glints import kernels as glint_kernels
from estimator.matching import GlintMatcher
from estimator.scene import load_scene  # noqa: E402
from scet_render.motion import saccade_sequence
from scet_render.simulate import ground_truth_glints, simulate_glints  # noqa: E402


def eye_background(h: int, w: int) -> np.ndarray:
    """Skin, an almond eye opening, an iris and a pupil (DN before the row weights)."""
    y, x = np.mgrid[0:h, 0:w].astype(float)
    r = np.hypot(x - 300, y - 230)
    soft = lambda d, s: 1 / (1 + np.exp(np.clip(d / s, -50, 50)))  # noqa: E731
    opening = soft(np.hypot((x - 300) / 230, (y - 230) / 140) * 140 - 140, 2.0)
    return 115 + 70 * opening - 110 * soft(r - 105, 1.5) * opening - 40 * soft(r - 40, 1.0)


def add_spots(img, glints_px, sigma_px, peak_dn) -> None:
    """Pixel-integrated Gaussian spots added to ``img`` (those too near the border left out)."""
    h, w = img.shape
    for (u, v), s, p in zip(glints_px, sigma_px, peak_dn):
        x0, y0 = int(u) - 6, int(v) - 6
        if x0 < 0 or y0 < 0 or x0 + 14 > w or y0 + 14 > h:
            continue
        gx = np.diff(0.5 * erf((np.arange(x0, x0 + 15) - 0.5 - u) / (np.sqrt(2) * s)))
        gy = np.diff(0.5 * erf((np.arange(y0, y0 + 15) - 0.5 - v) / (np.sqrt(2) * s)))
        img[y0:y0 + 14, x0:x0 + 14] += p * 2 * np.pi * s * s * gy[:, None] * gx[None, :]


def expose(setup, img, rng) -> np.ndarray:
    """uint16 10-bit DN of a signal image: shot and read noise, the black level, clipping."""
    img = img + np.sqrt(4.0 + img / 4.0) * rng.normal(size=img.shape) + setup.sensor.black_level_dn
    return np.clip(np.rint(img), 0, 1023).astype(np.uint16)


def banded_frame(setup, glints_px, sigma_px, peak_dn, rng, frame_index=0):
    """uint16 10-bit frame: pixel-integrated Gaussian spots and an eye-like background, each row
    weighted by the light Σ_j w_j(y) it collects from the strobe, shot and read noise."""
    img = eye_background(setup.camera.height_px, setup.camera.width_px)
    add_spots(img, glints_px, sigma_px, peak_dn)
    _, _, wts = row_pulse_weights(setup.sensor, setup.strobe, frame_index)
    img *= wts.sum(axis=1)[:, None]
    return expose(setup, img, rng)


def best_times(fns, seconds: float) -> list[float]:
    """Fastest call of each function over ``seconds``, calls alternated (other load on the
    machine then disturbs them alike)."""
    for fn in fns:
        fn()
    best, calls, end = [float("inf")] * len(fns), 0, time.perf_counter() + seconds
    while time.perf_counter() < end or calls < 3:
        for i, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t)
        calls += 1
    return best


def centroid_errors(det, g):
    """Distances of the true glints to their nearest detections, for the spots neither on the
    image edge nor blended, and which of those are cut by a band edge."""
    d = np.linalg.norm(det.glints_px[None] - g[:, None], axis=-1)
    i = d.argmin(axis=1)
    plain = (det.flags[i] & (IMAGE_EDGE | BLENDED)) == 0
    return d[np.arange(len(g)), i][plain], (det.flags[i][plain] & CUT_BY_BAND_EDGE) != 0


def print_accuracy(label, results, n_frames):
    err = np.concatenate([e for e, *_ in results])
    cut = np.concatenate([c for _, c, *_ in results])
    found = sum(n for *_, n, _ in results)
    truth = sum(t for *_, t in results)
    print(f"  {label}: {found} detections for {truth} glints; centroid error median "
          f"{np.median(err[~cut]):.3f} px, max {err[~cut].max():.3f} px ({(~cut).sum()} clean), "
          f"band-cut median {np.median(err[cut]):.3f} px, max {err[cut].max():.3f} px "
          f"({cut.sum()})")


def bench_detection(seconds: float, n_frames: int) -> None:
    """Per frame, cold: every frame measures its own noise model and is searched whole."""
    setup = load_scene("paper_sim")
    rng = np.random.default_rng(1)
    frames, truths, cold = [], [], []
    for f in range(n_frames):
        g, vis, _ = ground_truth_glints(setup, rng.uniform(-0.3, 0.3), rng.uniform(-0.25, 0.15))
        g = g[vis]
        frame = banded_frame(setup, g, rng.uniform(0.6, 1.2, len(g)), rng.uniform(200, 500, len(g)),
                             rng, f)
        frames.append((f, frame))
        truths.append(g)
        det = detect_glints(frame, setup, f)
        cold.append((*centroid_errors(det, g), len(det), len(g)))
    per_frame = np.array([best_times([lambda fr=fr, f=f: detect_glints(fr, setup, f)],
                                     seconds / n_frames)[0] for f, fr in frames])
    print(f"detection, paper_sim 640x480 10-bit banded frames ({sum(map(len, truths)) // n_frames} "
          "glints each), one core:")
    print(f"  per frame (cold: every frame measures its noise model, whole frame): "
          f"{1 / np.median(per_frame):6.0f} frames/s (median of per-frame best "
          f"{np.median(per_frame) * 1e3:.3f} ms)")
    print_accuracy("cold", cold, n_frames)


def moving_sequence(setup, n_frames: int, rng):
    """Frames of an eye making saccades between random screen targets (fixations 0.15-0.4 s,
    main-sequence saccades), each pulse's glints at the eye's pose at that pulse's centre and
    weighted by its own row weights, as the rolling shutter records them."""
    sc, eye = setup.screen, setup.eye
    n_targets = max(2, int(n_frames * setup.sensor.frame_period_s / 0.15) + 2)
    targets = np.stack([rng.uniform(*sc.x_range_m, n_targets),
                        rng.uniform(*sc.y_range_m, n_targets), np.full(n_targets, sc.z_m)], axis=1)
    traj = saccade_sequence(eye, targets, rng)
    background = eye_background(setup.camera.height_px, setup.camera.width_px)
    frames, peak_speed = [], 0.0
    for f in range(n_frames):
        _, start, wts = row_pulse_weights(setup.sensor, setup.strobe, f)
        yaw, pitch = traj.angles_at(start + 0.5 * setup.strobe.pulse_s)
        img = background * wts.sum(axis=1)[:, None]
        for j in np.flatnonzero(wts.max(axis=0) > 0):
            g, vis, _ = ground_truth_glints(setup, yaw[j], pitch[j])
            spots = np.zeros_like(img)
            add_spots(spots, g[vis], np.full(vis.sum(), 0.9), np.full(vis.sum(), 350.0))
            img += spots * wts[:, j:j + 1]
        frames.append((f, expose(setup, img, rng)))
        speed = np.hypot(np.diff(yaw), np.diff(pitch)) / np.diff(start)
        peak_speed = max(peak_speed, float(np.degrees(speed.max())))
    return frames, peak_speed


def numpy_path(fn):
    """``fn`` run with the detector's numpy path (no compiled kernels), as without Numba."""
    def run():
        enabled, glint_kernels.ENABLED = glint_kernels.ENABLED, False
        try:
            return fn()
        finally:
            glint_kernels.ENABLED = enabled
    return run


def bench_stream(seconds: float, n_frames: int) -> None:
    """Streaming, on a moving eye: :class:`GlintDetector` searching every frame whole against
    searching a window around the glints (``track_roi``), and the window with the numpy path
    (what runs without Numba), timed as whole passes over the sequence, alternated; the
    window's detections checked against the whole frame's, and the numpy path's against the
    compiled one's."""
    setup = load_scene("paper_sim")
    frames, peak_speed = moving_sequence(setup, n_frames, np.random.default_rng(7))
    whole, window, plain = (GlintDetector(setup, track_roi=False), GlintDetector(setup),
                            GlintDetector(setup))
    passes = [lambda: [whole(fr, f) for f, fr in frames], lambda: [window(fr, f) for f, fr in frames],
              numpy_path(lambda: [plain(fr, f) for f, fr in frames])]
    dets = [p() for p in passes]
    windowed, retried = window.windowed, window.retried

    def compare(a_dets, b_dets):
        gap = max((np.abs(a.glints_px - b.glints_px).max() if len(a) else 0.0)
                  for a, b in zip(a_dets, b_dets) if len(a) == len(b))
        same = all(len(a) == len(b) and np.array_equal(a.strobe_index, b.strobe_index)
                   and np.array_equal(a.flags, b.flags) for a, b in zip(a_dets, b_dets))
        return f"detections {'the same' if same else 'DIFFERENT'}, centroids within {gap:.1e} px"

    t_whole, t_window, t_plain = best_times(passes, 3 * seconds)
    compiled = "Numba kernels" if glint_kernels.ENABLED else "numpy (Numba not installed)"
    print(f"  streaming, {n_frames} frames of an eye making saccades (peak {peak_speed:.0f} "
          f"deg/s), {sum(map(len, dets[0])) / n_frames:.1f} glints per frame, a noise model and "
          f"a whole-frame search every {window.refresh_frames} frames; steps 2-6 by {compiled}:")
    print(f"    whole frames:                    {n_frames / t_whole:6.0f} frames/s "
          f"({t_whole / n_frames * 1e3:.3f} ms per frame)")
    print(f"    window around the glints (+{window.roi_margin_px} px): "
          f"{n_frames / t_window:6.0f} frames/s "
          f"({t_window / n_frames * 1e3:.3f} ms per frame; {t_whole / t_window:.2f}x); "
          f"{windowed} of {n_frames} frames in the window alone, {retried} searched again whole; "
          f"{compare(dets[0], dets[1])}")
    print(f"    window, numpy path:              {n_frames / t_plain:6.0f} frames/s "
          f"({t_plain / n_frames * 1e3:.3f} ms per frame; compiled {t_plain / t_window:.2f}x "
          f"faster); {compare(dets[1], dets[2])}")


def realistic_bands(setup, n, rng, rows=48, prior_deg=0.5):
    """Detections of one band each: (detections, label sets, (first, last) row, prior)."""
    sc = setup.screen
    obs = simulate_glints(setup, np.stack([rng.uniform(*sc.x_range_m, n),
                                           rng.uniform(*sc.y_range_m, n), np.full(n, sc.z_m)], 1))
    out = []
    for b in range(n):
        vis, g = obs.visible[b], obs.glints_true_px[b]
        lo = rng.uniform(g[vis, 1].min() - rows + 8, g[vis, 1].max() - 8)
        kept = np.flatnonzero(vis & (g[:, 1] >= lo) & (g[:, 1] < lo + rows))
        kept = kept[rng.random(kept.size) >= rng.uniform(0.05, 0.10)]
        groups, free = [], np.ones(kept.size, bool)
        for a in range(kept.size):  # glints closer than 3 px are one blob
            if free[a]:
                m = np.flatnonzero(free & (np.linalg.norm(g[kept] - g[kept[a]], axis=1) < 3.0))
                free[m] = False
                groups.append(kept[m])
        det = np.array([g[m].mean(0) for m in groups]).reshape(-1, 2)
        det = det + rng.normal(0, rng.uniform(0.3, 0.5), det.shape)
        labels = [set(np.flatnonzero(vis & (np.linalg.norm(g[:, None] - g[m][None], axis=-1) < 3.0)
                                     .any(1)).tolist()) for m in groups]
        ns = int(rng.integers(1, 4))
        det = np.vstack([det, np.stack([rng.uniform(g[vis, 0].min() - 20, g[vis, 0].max() + 20, ns),
                                        rng.uniform(lo, lo + rows, ns)], 1)])
        labels += [{-1}] * ns
        a = rng.uniform(0, 2 * np.pi)
        prior = np.array([obs.yaw_rad[b], obs.pitch_rad[b]]) + np.radians(prior_deg) * np.sqrt(
            rng.random()) * np.array([np.cos(a), np.sin(a)])
        out.append((det, labels, (lo, lo + rows - 1), prior))
    return out


def bench_matching(n_bands: int) -> None:
    print(f"matching, {n_bands} bands of 48 rows per scene (0.3-0.5 px noise, 5-10 % dropped, "
          "1-3 spurious, prior <= 0.5 deg off):")
    for name in ("paper_sim", "paper_sim_doubled"):
        t = time.perf_counter()
        matcher = GlintMatcher(load_scene(name))
        build = time.perf_counter() - t
        bands = realistic_bands(matcher.setup, n_bands, np.random.default_rng(11))
        for mode in ("prior", "cold"):
            t = time.perf_counter()
            results = [matcher.match(d, rows, prior if mode == "prior" else None)
                       for d, _, rows, prior in bands]
            dt = time.perf_counter() - t
            right = total = claimed = claimed_right = refused = 0
            for r, (_, labels, _, _) in zip(results, bands):
                ok = np.array([light in s for light, s in zip(r.light_index, labels)])
                right += ok.sum()
                total += ok.size
                claimed += r.matched.sum()
                claimed_right += (ok & r.matched).sum()
                refused += not r.ok
            print(f"  {name:18s} {mode:5s} {n_bands / dt:7.1f} samples/s "
                  f"({dt / n_bands * 1e3:.1f} ms/band; grid built in {build:.2f} s); "
                  f"correct labels {right / total:.2%} of {total} detections, "
                  f"claimed identities right {claimed_right / claimed:.2%}, "
                  f"bands refused {refused / n_bands:.1%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="time per detection measurement")
    ap.add_argument("--frames", type=int, default=8, help="distinct frames to detect in")
    ap.add_argument("--stream-frames", type=int, default=120, help="frames of the moving-eye stream")
    ap.add_argument("--bands", type=int, default=200, help="bands per scene to match (0: none)")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"numpy {np.__version__}, OpenCV {cv2.__version__}, one core")
    bench_detection(args.seconds, args.frames)
    bench_stream(args.seconds, args.stream_frames)
    if args.bands > 0:
        bench_matching(args.bands)


if __name__ == "__main__":
    main()
