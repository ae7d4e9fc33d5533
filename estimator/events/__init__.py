"""Eye-movement events from band samples, on the Pi (numpy only).

Saccades and microsaccades from gaze samples at their strobe instants, irregular, with the
blanking gap and NaN bands as they come: :func:`detect_events` (offline),
:class:`EventStream` (live, with the latency stated in :mod:`estimator.events.stream`), and
the events CSV ``scet track --events`` writes (:mod:`estimator.events.files`), leaving out the
tracker's poor fits (:mod:`estimator.events.quality`).
"""

from .detect import (
    MICROSACCADE,
    MICROSACCADE_MAX_DEG,
    SACCADE,
    EventParams,
    Events,
    check_samples,
    detect_events,
    empty_events,
    gaze_angles_deg,
)
from .files import (
    EVENT_COLUMNS,
    EVENTS_FORMAT,
    EVENTS_VERSION,
    events_csv,
    events_from_samples_csv,
    gaze_from_samples_csv,
    read_events_csv,
    write_events_csv,
)
from .quality import NO_GATE, SampleGate, left_out, poor_fits
from .stream import EventStream
from .velocity import local_velocity

__all__ = [
    "SACCADE", "MICROSACCADE", "MICROSACCADE_MAX_DEG", "EventParams", "Events", "check_samples",
    "detect_events", "empty_events", "gaze_angles_deg", "EVENT_COLUMNS", "EVENTS_FORMAT",
    "EVENTS_VERSION", "events_csv", "events_from_samples_csv", "gaze_from_samples_csv",
    "read_events_csv", "write_events_csv", "EventStream", "local_velocity", "NO_GATE",
    "SampleGate", "left_out", "poor_fits",
]
