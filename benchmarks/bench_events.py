"""Cost of the band-sample event detector (:mod:`estimator.events`): offline over a whole
stream and streaming a frame at a time, per sample, on a simulated stream of the study's
goal setting (designed lighting, 16 pulses per frame, S = 524: ~860 valid samples/s).

    python benchmarks/bench_events.py [--seconds 20] [--repeats 5]

Prints the median and range over repeats (this machine's speed swings by 2x), in us per
sample, and the ratio to the band period (1.04 ms): the share of one core that keeping up
costs. The stream is timed twice in each repeat: pushed without the samples' quality, and
with it (the event gate of :mod:`estimator.events.quality` run on every push; the quality
columns made up here: 5-8 glints, one band in twenty a prior-assisted one-glint band, gamma
residuals). The estimator's budget on a Raspberry Pi is not measured here.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages

import numpy as np  # noqa: E402

from estimator.events import EventStream, detect_events  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from scet_render.study.events_sim import band_setting, simulate_stream, study_trajectory  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    setup = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "paper_sim_designed.toml")
    traj = study_trajectory(setup, 80, 40, seed=0)
    st = band_setting("goal", setup, 16, 524, 0.018 / math.sqrt(math.pi / 2))
    t, pos = simulate_stream(st, traj, min(a.seconds, traj.duration_s), seed=0)
    n = t.size
    rng = np.random.default_rng(0)
    weak = rng.random(n) < 0.05
    quality = (np.where(weak, 1, rng.integers(5, 9, n)), weak, rng.gamma(9.0, 0.1 / 9.0, n))
    offline, stream, gated = [], [], []
    frame = setup.sensor.frame_period_s
    edges = np.searchsorted(t, np.arange(t[0], t[-1] + frame, frame))
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        ev = detect_events(t, pos)
        offline.append((time.perf_counter() - t0) / n * 1e6)
        s = EventStream()
        t0 = time.perf_counter()
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi > lo:
                s.push(t[lo:hi], pos[lo:hi])
        stream.append((time.perf_counter() - t0) / n * 1e6)
        s = EventStream()
        t0 = time.perf_counter()
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi > lo:
                s.push(t[lo:hi], pos[lo:hi], tuple(q[lo:hi] for q in quality))
        gated.append((time.perf_counter() - t0) / n * 1e6)
    period_us = 1e6 * st.setup.strobe.period_s
    print(f"{n} samples over {t[-1] - t[0]:.1f} s, {ev.count} events")
    for name, v in (("offline", offline), ("stream, a frame a push", stream),
                    ("stream with the samples' quality (the event gate)", gated)):
        v = np.array(v)
        print(f"{name}: {np.median(v):.1f} us/sample (range {v.min():.1f}-{v.max():.1f}), "
              f"{np.median(v) / period_us:.3f} of a core at one sample per band period")


if __name__ == "__main__":
    main()
