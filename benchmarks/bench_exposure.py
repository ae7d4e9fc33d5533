"""The sensor's exposure: what clipping the brightest glints costs the detector, against a
dimmer exposure that clips none.

The default exposure (:data:`scet_render.render.sensor.DEFAULT_ELECTRONS_PER_RADIANCE`, 99.6 e-
per unit of radiance) puts a glint seen at normal incidence at 70 % of saturation; the Fresnel
reflectance grows with the incidence, so paper_sim's oblique glints clip. The same rendered
radiance (paper_sim, default dielectric cornea, saccades over the screen) is read out by the
OV5647 model at several exposure scales, each frame with the same noise seed, and fed to
:func:`estimator.glints.detect_glints`. Each labelled visible glint (the closed form, the
labels of :func:`scet_render.dataset.frame_labels`) is matched to the nearest detection of its
strobe within :data:`MATCH_PX` (the glints of each band's fully lit rows, :data:`EDGE_PX`
from its edges). Printed per scale: the share of labelled glints detected, the
share of those with a saturated pixel, and the centroid error (median, p90, max, px) of the
glints that clip at the default exposure and of those that do not. Usage:

    python benchmarks/bench_exposure.py [--spp 16] [--frames 12] [--scales 0.2,0.4,1,2]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator.glints import SATURATED, detect_glints
from estimator.scene import load_scene
from scet_render.dataset import dataset_trajectory, frame_labels
from scet_render.render import BandedRenderer, SensorModel

#: Glints closer than this to the edge of their band's fully lit rows are left out (px).
EDGE_PX = 2.0
#: A detection further than this from a labelled glint is not that glint's (px): well above
#: the 0.1-0.5 px centroid errors measured here, below the ~3 px between neighbouring glints
#: at the cornea's edge.
MATCH_PX = 1.5


def render(spp: int, frames: int, seed: int):
    """(setup, [(frame, radiance, labels)]) of paper_sim's saccades."""
    setup = load_scene("paper_sim")
    traj = dataset_trajectory(setup, "saccades", frames, seed)
    r = BandedRenderer(setup, spp=spp, seed=seed)
    out = []
    for f in range(frames):
        t = time.perf_counter()
        out.append((f, r.render_frame(traj, f).radiance, frame_labels(setup, traj, f)))
        print(f"frame {f + 1}/{frames} rendered in {time.perf_counter() - t:.1f} s", flush=True)
    return setup, out


def readout(setup, frames, sensor: SensorModel, seed: int):
    """{(frame, strobe, light): (error px, saturated)} of the labelled glints detected, and the
    number of labelled visible glints."""
    found, labelled = {}, 0
    for f, radiance, labels in frames:
        img = sensor.apply(radiance, np.random.SeedSequence([seed, f])).astype(np.float64)
        det = detect_glints(img, setup, f)
        for lab in labels:
            j = int(lab["strobe"])
            mine = det.strobe_index == j
            u, v, sat = det.u_px[mine], det.v_px[mine], det.has(SATURATED)[mine]
            lo, hi = lab["full_rows"]
            for i, (p, vis) in enumerate(zip(lab["glints_px"], lab["glints_visible"])):
                # Glints of the band's fully lit rows, a spot's radius from its edges (a spot
                # the band's edge cuts is another matter: the detector's band-edge correction).
                if p is None or not vis or not lo + EDGE_PX <= p[1] <= hi - EDGE_PX:
                    continue
                labelled += 1
                if not u.size:
                    continue
                d = np.hypot(u - p[0], v - p[1])
                k = int(np.argmin(d))
                if d[k] <= MATCH_PX:
                    found[(f, j, i)] = (float(d[k]), bool(sat[k]))
    return found, labelled


def _stats(e) -> str:
    if not len(e):
        return f"{'-':>6s} {'-':>6s} {'-':>6s} {0:5d}"
    e = np.asarray(e)
    return f"{np.median(e):6.3f} {np.percentile(e, 90):6.3f} {e.max():6.3f} {e.size:5d}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--scales", default="0.2,0.4,1,2",
                    help="exposure scales, comma-separated, relative to the default")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    scales = sorted({float(s) for s in args.scales.split(",")} | {1.0})
    if any(not (np.isfinite(s) and s > 0) for s in scales):
        raise SystemExit(f"--scales: positive numbers expected, got {args.scales!r}")
    setup, frames = render(args.spp, args.frames, args.seed)
    base = SensorModel.from_sensor(setup.sensor)
    results = {s: readout(setup, frames, replace(
        base, electrons_per_radiance=s * base.electrons_per_radiance), args.seed) for s in scales}
    clips = {key for key, (_, sat) in results[1.0][0].items() if sat}
    print(f"\n{Path(__file__).name}: paper_sim 640x480, {args.spp} spp dielectric, "
          f"{args.frames} frames of saccades; default {base.electrons_per_radiance:.1f} e- per "
          f"radiance unit; {len(clips)} glints clip at the default exposure")
    print(f"{'scale':>6s} {'e-/unit':>8s} {'found':>7s} {'saturated':>9s} | clipping at the "
          f"default: med    p90    max     n | not clipping: med    p90    max     n")
    for s in scales:
        found, labelled = results[s]
        sat = sum(v[1] for v in found.values())
        a = [e for key, (e, _) in found.items() if key in clips]
        b = [e for key, (e, _) in found.items() if key not in clips]
        print(f"{s:6.2f} {s * base.electrons_per_radiance:8.1f} {len(found) / labelled:7.3f} "
              f"{sat / max(len(found), 1):9.3f} | {'':18s}{_stats(a)} | {'':13s}{_stats(b)}")


if __name__ == "__main__":
    main()
