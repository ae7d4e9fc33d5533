"""Glint detection frames per second and glint matching samples per second, one core.

Detection: 640x480 10-bit banded frames of the paper_sim glints (Gaussian spots at their
closed-form positions, every pulse's row weights, an eye-like background, shot and read noise),
timed through :func:`estimator.glints.detect_glints`; the centroid error against the
closed-form glints is printed alongside. Two figures: per frame (cold: every frame measures
its own noise model) and streaming (:class:`estimator.glints.GlintDetector` over the frames as
one sequence, measuring the model every ``refresh_frames`` frames; timed over whole refresh
cycles, so the measurement's cost is included once per cycle). Matching: bands as the tests build them (48 rows,
0.3-0.5 px noise, 5-10 % dropped glints, 1-3 spurious blobs), through
:meth:`estimator.matching.GlintMatcher.match` with a previous-sample prior and cold, on
paper_sim and paper_sim_doubled, with the identity rates measured on them. Usage:

    python benchmarks/bench_glints.py [--seconds 2] [--frames 8] [--bands 200]
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

from estimator.banding import row_pulse_weights  # noqa: E402
from estimator.glints import (  # noqa: E402
    BLENDED,
    CUT_BY_BAND_EDGE,
    IMAGE_EDGE,
    GlintDetector,
    detect_glints,
)
from estimator.matching import GlintMatcher  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from scet_render.simulate import ground_truth_glints, simulate_glints  # noqa: E402


def banded_frame(setup, glints_px, sigma_px, peak_dn, rng, frame_index=0):
    """uint16 10-bit frame: pixel-integrated Gaussian spots and an eye-like background, each row
    weighted by the light Σ_j w_j(y) it collects from the strobe, shot and read noise."""
    h, w = setup.camera.height_px, setup.camera.width_px
    y, x = np.mgrid[0:h, 0:w].astype(float)
    r = np.hypot(x - 300, y - 230)
    soft = lambda d, s: 1 / (1 + np.exp(np.clip(d / s, -50, 50)))  # noqa: E731
    opening = soft(np.hypot((x - 300) / 230, (y - 230) / 140) * 140 - 140, 2.0)
    img = 115 + 70 * opening - 110 * soft(r - 105, 1.5) * opening - 40 * soft(r - 40, 1.0)
    for (u, v), s, p in zip(glints_px, sigma_px, peak_dn):
        x0, y0 = int(u) - 6, int(v) - 6
        if x0 < 0 or y0 < 0 or x0 + 14 > w or y0 + 14 > h:
            continue
        gx = np.diff(0.5 * erf((np.arange(x0, x0 + 15) - 0.5 - u) / (np.sqrt(2) * s)))
        gy = np.diff(0.5 * erf((np.arange(y0, y0 + 15) - 0.5 - v) / (np.sqrt(2) * s)))
        img[y0:y0 + 14, x0:x0 + 14] += p * 2 * np.pi * s * s * gy[:, None] * gx[None, :]
    _, _, wts = row_pulse_weights(setup.sensor, setup.strobe, frame_index)
    img *= wts.sum(axis=1)[:, None]
    img += np.sqrt(4.0 + img / 4.0) * rng.normal(size=img.shape) + setup.sensor.black_level_dn
    return np.clip(np.rint(img), 0, 1023).astype(np.uint16)


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
    setup = load_scene("paper_sim")
    rng = np.random.default_rng(1)
    frames, truths, cold, stream = [], [], [], []
    detector = GlintDetector(setup)
    for f in range(n_frames):
        g, vis, _ = ground_truth_glints(setup, rng.uniform(-0.3, 0.3), rng.uniform(-0.25, 0.15))
        g = g[vis]
        frame = banded_frame(setup, g, rng.uniform(0.6, 1.2, len(g)), rng.uniform(200, 500, len(g)),
                             rng, f)
        frames.append((f, frame))
        truths.append(g)
        for results, det in ((cold, detect_glints(frame, setup, f)), (stream, detector(frame, f))):
            results.append((*centroid_errors(det, g), len(det), len(g)))
    # Streaming: the per-frame best with the model reused, plus 1/refresh_frames of the cost
    # of measuring it (the cold time less the reused one) for the frames that measure it.
    n = detector.refresh_frames
    reused = GlintDetector(setup, refresh_frames=2 ** 62)
    reused(*frames[0][::-1])
    per_frame, per_frame_reused = np.array([
        best_times([lambda fr=fr, f=f: detect_glints(fr, setup, f),
                    lambda fr=fr, f=f: reused(fr, f)], 2 * seconds / n_frames)
        for f, fr in frames]).T
    assert reused.measurements == 1  # no level drift between the bench frames
    t_reused = np.median(per_frame_reused)
    t_stream = t_reused + (np.median(per_frame) - t_reused) / n
    print(f"detection, paper_sim 640x480 10-bit banded frames ({sum(map(len, truths)) // n_frames} "
          "glints each), one core:")
    print(f"  per frame (cold: every frame measures its noise model): "
          f"{1 / np.median(per_frame):6.0f} frames/s (median of per-frame best "
          f"{np.median(per_frame) * 1e3:.3f} ms)")
    print(f"  streaming (GlintDetector, a noise model every {n} frames): {1 / t_stream:6.0f} "
          f"frames/s ({t_stream * 1e3:.3f} ms per frame: {t_reused * 1e3:.3f} ms with the model "
          f"reused, the median of per-frame best, and 1/{n} of the measurement)")
    print_accuracy("cold", cold, n_frames)
    print_accuracy("streaming", stream, n_frames)


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
    ap.add_argument("--bands", type=int, default=200, help="bands per scene to match (0: none)")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"numpy {np.__version__}, OpenCV {cv2.__version__}, one core")
    bench_detection(args.seconds, args.frames)
    if args.bands > 0:
        bench_matching(args.bands)


if __name__ == "__main__":
    main()
