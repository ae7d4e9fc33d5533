"""Events beside the samples: reading a samples CSV into gaze angles, and the events CSV.

The events CSV (format ``scet-events``, version :data:`EVENTS_VERSION`): a first line
``# scet-events 1``, a header, one row per event in onset order::

    onset_s,offset_s,amplitude_deg,peak_velocity_deg_s,kind,onset_uncertainty_s,offset_uncertainty_s

times on the samples' clock (the strobe instants, s), the amplitude and peak velocity of the
gaze's Fick angles, ``kind`` ``saccade`` or ``microsaccade`` (below 1 deg), and each
uncertainty half the time between the two valid samples that bracket the onset or offset
(:mod:`estimator.events.detect`).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..errors import TrackerInputError
from ..formats import atomic_write
from .detect import EventParams, Events, detect_events, gaze_angles_deg
from .quality import SampleGate, left_out

EVENTS_FORMAT = "scet-events"
EVENTS_VERSION = 1
EVENT_COLUMNS = ("onset_s", "offset_s", "amplitude_deg", "peak_velocity_deg_s", "kind",
                 "onset_uncertainty_s", "offset_uncertainty_s")


def gaze_from_samples_csv(path, setup, *, gate: SampleGate | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(n,) sample times (s) and (n, 2) gaze Fick angles (deg, NaN for failed samples) of a
    samples CSV (:func:`estimator.tracking.read_samples_csv`), the gaze from the setup's eye
    rotation centre to the screen point. With a ``gate`` the samples it leaves out
    (:func:`estimator.events.quality.left_out`, from the ``n_glints``, ``prior`` and
    ``residual_px`` columns and the gaze) are NaN too.

    Raises
    ------
    TrackerInputError
        Naming the file and row: no ``time_s`` column, a time that is not a finite number,
        times out of order or repeated, no valid sample at all, or (with a ``gate``) a
        ``n_glints`` or ``residual_px`` that is not a number.
    """
    t, pos, rows = _gaze_and_rows(path, setup)
    if gate is not None:
        pos[samples_left_out(rows, t, pos, gate, path)] = np.nan
    return t, pos


def _gaze_and_rows(path, setup):
    """:func:`gaze_from_samples_csv` without a gate, and the CSV's rows."""
    from ..tracking import read_samples_csv

    path = Path(path)
    rows = read_samples_csv(path)
    if not rows:
        raise TrackerInputError("no samples: events need at least one", path=path)
    for col in ("time_s", "screen_x_m", "screen_y_m"):
        if col not in rows[0]:
            raise TrackerInputError(f"no column '{col}': events need time-stamped gaze samples",
                                    path=path, key=col)
    t = np.empty(len(rows))
    xy = np.empty((len(rows), 2))
    for i, r in enumerate(rows):
        line = i + 3  # the format line and the header come first
        try:
            t[i] = float(r["time_s"])
            xy[i] = float(r["screen_x_m"]), float(r["screen_y_m"])
        except (TypeError, ValueError):
            raise TrackerInputError(f"line {line}: time_s / screen_x_m / screen_y_m must be "
                                    f"numbers, got {r.get('time_s')!r}, {r.get('screen_x_m')!r},"
                                    f" {r.get('screen_y_m')!r}", path=path) from None
        if not math.isfinite(t[i]):
            raise TrackerInputError(f"line {line}: time_s must be finite, got {r['time_s']!r}",
                                    path=path, key="time_s")
        if i and t[i] <= t[i - 1]:
            what = "repeats" if t[i] == t[i - 1] else "is before"
            raise TrackerInputError(f"line {line}: time_s {float(t[i])!r} {what} the previous "
                                    f"sample's ({float(t[i - 1])!r}): samples must be in strictly "
                                    "increasing time order", path=path, key="time_s")
    ok = np.isfinite(xy).all(axis=1)
    if not ok.any():
        raise TrackerInputError(f"all {len(rows)} samples are NaN (lines 3-{len(rows) + 2}): no "
                                "gaze to find events in", path=path)
    pos = np.full((len(rows), 2), np.nan)
    pos[ok] = gaze_angles_deg(xy[ok], setup.eye.rotation_center_m, setup.screen.z_m)
    return t, pos, rows


def samples_left_out(rows, time_s, position_deg, gate: SampleGate, path) -> np.ndarray:
    """(n,) bool: :func:`~estimator.events.quality.left_out` of a samples CSV's rows (as
    :func:`estimator.tracking.read_samples_csv` gives them), their times (n,) s and gaze
    (n, 2) deg (NaN where the tracker gave none).

    Raises
    ------
    TrackerInputError
        Naming the file, line and column of a ``n_glints``, ``prior`` or ``residual_px`` that
        is missing or not a number.
    """
    for col in ("n_glints", "prior", "residual_px"):
        if rows and col not in rows[0]:
            raise TrackerInputError(f"no column '{col}': the event gate needs the tracker's "
                                    "n_glints, prior and residual_px", path=path, key=col)
    n = np.empty(len(rows))
    prior = np.empty(len(rows), dtype=bool)
    res = np.empty(len(rows))
    for i, r in enumerate(rows):
        try:
            n[i] = float(r["n_glints"])
            res[i] = float(r["residual_px"])
            if r["prior"] not in ("0", "1"):
                raise ValueError
            prior[i] = r["prior"] == "1"
        except (TypeError, ValueError):
            raise TrackerInputError(f"line {i + 3}: n_glints and residual_px must be numbers and "
                                    f"prior 0 or 1, got {r.get('n_glints')!r}, "
                                    f"{r.get('residual_px')!r}, {r.get('prior')!r}",
                                    path=path) from None
    try:
        return left_out(time_s, position_deg, n, prior, res, gate, source=str(path))
    except ValueError as e:
        raise TrackerInputError(str(e), path=path, key="n_glints") from None


def events_csv(events: Events) -> str:
    """CSV text of ``events`` (module docstring)."""
    buf = io.StringIO()
    buf.write(f"# {EVENTS_FORMAT} {EVENTS_VERSION}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(EVENT_COLUMNS)
    for i in range(events.count):
        w.writerow([repr(float(events.onset_s[i])), repr(float(events.offset_s[i])),
                    f"{events.amplitude_deg[i]:.6g}", f"{events.peak_velocity_deg_s[i]:.6g}",
                    str(events.kind[i]), f"{events.onset_uncertainty_s[i]:.6g}",
                    f"{events.offset_uncertainty_s[i]:.6g}"])
    return buf.getvalue()


def read_events_csv(path) -> Events:
    """Read an events CSV written by :func:`write_events_csv`, checking its format line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackerInputError(f"cannot read the events ({exc})", path=path) from None
    first, _, rest = text.partition("\n")
    if first.strip() != f"# {EVENTS_FORMAT} {EVENTS_VERSION}":
        raise TrackerInputError(f"expected first line '# {EVENTS_FORMAT} {EVENTS_VERSION}', got "
                                f"{first[:60]!r}", path=path)
    rows = list(csv.DictReader(io.StringIO(rest)))
    cols = {c: [] for c in EVENT_COLUMNS}
    for i, r in enumerate(rows):
        for c in EVENT_COLUMNS:
            if r.get(c) is None:
                raise TrackerInputError(f"line {i + 3}: no value for '{c}'", path=path, key=c)
            cols[c].append(r[c])
    f = {c: np.array(cols[c], dtype=np.float64) for c in EVENT_COLUMNS if c != "kind"}
    return Events(f["onset_s"], f["offset_s"], f["onset_uncertainty_s"],
                  f["offset_uncertainty_s"], f["amplitude_deg"], f["peak_velocity_deg_s"],
                  np.array(cols["kind"], dtype="<U12"))


def write_events_csv(path, events: Events) -> Path:
    """Write :func:`events_csv` of ``events`` to ``path`` atomically; returns the path."""
    return atomic_write(Path(path), events_csv(events))


def events_from_samples_csv(samples_path, setup, events_path,
                            params: EventParams = EventParams(),
                            gate: SampleGate | None = SampleGate()) -> tuple[Events, int]:
    """``scet track --events``: detect the events of a samples CSV and write them beside it,
    leaving out the samples ``gate`` flags as poor fits (None: none). Returns the events and
    how many samples with a gaze estimate were left out."""
    t, pos, rows = _gaze_and_rows(samples_path, setup)
    left_out = 0
    if gate is not None:
        poor = samples_left_out(rows, t, pos, gate, samples_path)
        pos[poor] = np.nan
        left_out = int(poor.sum())
    events = detect_events(t, pos, params, source=str(samples_path))
    write_events_csv(events_path, events)
    return events, left_out
