"""Cost of the wire mirror's virtual-source option (``light_model = "wire_mirror"``, issue 35 c)
against the point-source rows, with its Numba kernel and without.

Feature level (noise-free two-bounce glints of ``prototype_ov5647_wire``, the paper's 24 x 15
grid cut to 4 glints a sample as a band holds): the geometric band step's samples/s for the
point-source ideal, (a), (b) and (c) (``scet_render.study.wire_track.band_cost``: every sample
in one call, and 40 samples one call each), over repeats, printed as ranges and as ratios to
(b). The run repeats itself in a child process with ``NUMBA_DISABLE_JIT=1`` for the numpy
fallback. This machine's speed swings ~2x: compare ratios within one run.

Usage::

    python benchmarks/bench_wire_option.py [--repeats 5] [--no-numpy]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def measure(repeats: int) -> dict:
    from estimator.scene import load_scene
    from scet_render.simulate import parse_targets
    from scet_render.study.wire import tracker_accuracy, wire_glints_for
    from scet_render.study.wire_track import MODELS, accuracy_table, band_cost

    setup = load_scene("prototype_ov5647_wire")

    def glints(t):
        g, v = wire_glints_for(setup, t)
        return np.where(v[..., None], g, np.nan)

    cal_t, targets = parse_targets("calib:5x5", setup), setup.screen.grid(24, 15)
    test_g = glints(targets)
    acc = accuracy_table(setup, glints(cal_t), cal_t, test_g, targets)
    ideal = tracker_accuracy(setup, "point")
    rows = {"ideal": (setup, ideal["calibration"], ideal["glints"]),
            **{k: (setup, acc[k]["calibration"], test_g) for k, _ in MODELS}}
    return band_cost(setup, rows, targets, repeats=repeats)


def show(cost: dict, title: str) -> None:
    mid = lambda x: 0.5 * (x[0] + x[1])  # noqa: E731
    ref = cost["calibrated"]
    print(title)
    print(f"{'row':<12} {'batched samples/s':>20} {'ratio':>6} {'one band a call':>18} {'ratio':>6}")
    for k, c in cost.items():
        print(f"{k:<12} {c['batched'][0]:>9.0f}..{c['batched'][1]:<9.0f} "
              f"{mid(c['batched']) / mid(ref['batched']):>6.2f} {c['per_band'][0]:>8.1f}..{c['per_band'][1]:<8.1f} "
              f"{mid(c['per_band']) / mid(ref['per_band']):>6.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-numpy", action="store_true", help="skip the NUMBA_DISABLE_JIT=1 run")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    from estimator.geometry import wire_kernel

    show(measure(args.repeats), "kernel: " + ("compiled (Numba)" if wire_kernel.ENABLED else "numpy (no Numba)"))
    if not (args.child or args.no_numpy) and wire_kernel.ENABLED:
        env = dict(os.environ, NUMBA_DISABLE_JIT="1")
        subprocess.run([sys.executable, __file__, "--repeats", str(args.repeats), "--child"], env=env, check=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
