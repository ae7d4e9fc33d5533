"""Single-pulse calibration frames (Sec. 2.4): the eye fixating the calibration grid,
every visible row lit by the same pulse, with a timing sidecar.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from estimator.banding import calibration_setup, strobe_instant
from estimator.folders import timing_document
from estimator.formats import FRAMES_DIR, LABELS_NAME, TIMING_NAME, atomic_write, frame_name
from estimator.setup import Setup

from ..motion import fixation_sequence
from .effective import DIFFERS_MARK, SCENE_NAME, effective_scene_text
from .format import counts_png
from .labels import frame_labels
from .manifest import _scene_text

#: Calibration fixation per target (s); one frame is rendered in its middle.
CALIB_FIXATION_S = 0.1


def render_calibration(setup: Setup, out_dir, *, spp: int, cornea: str, seed: int = 0,
                       grid=(5, 5), progress=None,
                       eyelid_openness: float | None = 1.0,
                       scene_text: str | None = None) -> Path:
    """Render single-pulse calibration frames of the eye fixating the calib grid.

    Writes ``frames/NNNNNN.png`` (frames in the middle of each fixation), ``labels.jsonl``
    (:func:`scet_render.dataset.frame_labels`), ``timing.json`` (with the calibration
    exposure and strobe) and ``scene.toml`` (the effective scene of ``setup``, the one to
    calibrate with: :func:`scet_render.dataset.effective.effective_scene_text`; the timing
    sidecar carries the single-pulse timing), each atomically. Returns the folder.
    ``eyelid_openness`` as :func:`scet_render.dataset.render_dataset` (the frames carry no
    manifest: a folder is reused as it is, so give each eyelid setting its own);
    ``scene_text`` is the scene TOML ``setup`` was loaded from (default: read from
    ``setup.source``).
    """
    from ..render import BandedRenderer, SensorModel

    out = Path(out_dir)
    effective = effective_scene_text(setup, _scene_text(setup, scene_text))
    text = effective.text
    if effective.differs:  # what the text could not carry, in a line readers look for
        text = f"{DIFFERS_MARK} {', '.join(effective.differs)}\n" + text
    cal = calibration_setup(setup)
    targets = setup.screen.grid(grid[0], grid[1], margin=0.0)
    traj = fixation_sequence(setup.eye, targets, CALIB_FIXATION_S)
    dt = cal.sensor.frame_period_s
    ends = np.cumsum(traj.segment_duration_s)
    starts = ends - traj.segment_duration_s
    fix = np.flatnonzero(np.asarray(traj.kind) == 0)
    mid = 0.5 * (starts[fix] + ends[fix])
    instant = strobe_instant(cal.strobe.phase_s, cal.strobe.pulse_s)  # pulse centre relative to t0_f
    frames = [int(round((t - instant) / dt)) for t in mid]
    renderer = BandedRenderer(cal, spp=spp, cornea=cornea, seed=seed,
                              eyelid_openness=eyelid_openness)
    sensor = SensorModel.from_sensor(cal.sensor)
    labels = []
    for i, f in enumerate(frames):
        path = out / FRAMES_DIR / frame_name(f, "png")
        if not path.is_file():
            radiance = renderer.render_frame(traj, f).radiance
            dn = sensor.apply(radiance, np.random.SeedSequence([seed, 3, f]))
            atomic_write(path, counts_png(dn, sensor.bit_depth))
        labels.extend(frame_labels(cal, traj, f))
        if progress is not None:
            progress(i + 1, len(frames))
    atomic_write(out / LABELS_NAME, "".join(json.dumps(x) + "\n" for x in labels))
    atomic_write(out / TIMING_NAME, timing_document({f: f * dt for f in frames},
                                                   exposure_s=cal.sensor.exposure_s,
                                                   strobe=cal.strobe))
    atomic_write(out / SCENE_NAME, text)
    return out
