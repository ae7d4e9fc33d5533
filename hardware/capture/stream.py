"""The capture loop: frames from a camera (picamera2 on the Pi, or a replayed dataset) written
to a capture folder as they arrive, with bounded memory, a timeout on every camera call, the
realised timing checked against the plan, dropped frames counted, and hooks for the phase
lock and the tracker.

Threads: the caller's thread takes each frame from the camera (``source.next_frame``, with a
timeout), checks and counts it, hands it to the writer thread through a queue of
``queue_frames`` slots and to ``on_frame`` (the phase lock and the live tracker, which must
return quickly: :class:`Worker` runs heavy work on its own thread, dropping frames it has no
time for). A full queue (the disk slower than the camera) loses the frame rather than
growing: memory stays at ``queue_frames`` buffers (384 kB each, packed VGA), where buffering a
whole run fills a 1 GB Pi 3B+ after ~1,500-2,000 frames. A frame lost to the queue leaves a
gap in the written time stamps, as a frame the camera dropped does; the summary counts both.

The camera drops frames when the loop is late: picamera2 keeps one completed request and
recycles older ones, so a late loop sees the next frame's ``SensorTimestamp`` more than one
frame period after the last. Such gaps are counted (``dropped_camera``) from the time stamps:
round(step / FrameDuration) - 1 per step.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

__all__ = ["CameraError", "CameraStall", "TimingMismatch", "CaptureReport", "Worker",
           "check_timing", "stream_capture"]


class CameraError(RuntimeError):
    """The camera cannot be used: not there, another sensor, another Bayer order, another
    raw stream (the message names the camera)."""


class CameraStall(CameraError):
    """No frame within the timeout."""


class TimingMismatch(CameraError):
    """The realised frame timing differs from the plan (the message gives the numbers)."""


@dataclass
class CaptureReport:
    """What a capture did. ``state``: complete, interrupted or failed; ``stopped``: why it
    stopped early. Latencies (s) are frame arrival (the loop got it) minus its
    SensorTimestamp, where the camera's clock is the host's (picamera2: CLOCK_MONOTONIC)."""

    state: str
    stopped: str
    frames_written: int
    dropped_camera: int
    lost_queue: int
    queue_high_water: int
    arrival_latency_s: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"state": self.state, "stopped": self.stopped, "frames_written": self.frames_written,
                "dropped_camera": self.dropped_camera, "lost_queue": self.lost_queue,
                "queue_high_water": self.queue_high_water}


def check_timing(metadata: list[dict], *, frame_duration_us: float, exposure_us: float,
                 line_us: float, camera: str) -> None:
    """The realised timing of the first frames against the plan.

    ``FrameDuration`` must be the planned frame to within one sensor line (the plan assumes a
    pixel rate; a kernel with another one gives another line time, and so another frame),
    ``ExposureTime`` the planned exposure to within one line, and the ``SensorTimestamp``
    steps the reported ``FrameDuration`` to within 1 % (libcamera's report against what the
    sensor delivers).

    Raises
    ------
    TimingMismatch
        With the planned and realised numbers.
    """
    fd = [float(m["FrameDuration"]) for m in metadata if "FrameDuration" in m]
    ex = [float(m["ExposureTime"]) for m in metadata if "ExposureTime" in m]
    ts = [int(m["SensorTimestamp"]) for m in metadata if "SensorTimestamp" in m]
    if not fd or not ex or len(ts) < 2:
        raise TimingMismatch(f"{camera}: the first frames carry no FrameDuration, ExposureTime "
                             "or SensorTimestamp metadata; cannot check the timing")
    fd_med, ex_med = sorted(fd)[len(fd) // 2], sorted(ex)[len(ex) // 2]
    if abs(fd_med - frame_duration_us) > line_us:
        raise TimingMismatch(f"{camera}: FrameDuration is {fd_med:.1f} us, the plan "
                             f"{frame_duration_us:.1f} us (more than one {line_us:.3f} us line "
                             "apart): another sensor mode or pixel rate; check the profile")
    if abs(ex_med - exposure_us) > line_us:
        raise TimingMismatch(f"{camera}: ExposureTime is {ex_med:.1f} us, the plan "
                             f"{exposure_us:.1f} us (more than one {line_us:.3f} us line apart)")
    steps = sorted((b - a) * 1e-3 for a, b in zip(ts, ts[1:]))
    step = steps[len(steps) // 2]
    if abs(step - fd_med) > 0.01 * fd_med:
        raise TimingMismatch(f"{camera}: SensorTimestamp steps {step:.1f} us, FrameDuration says "
                             f"{fd_med:.1f} us")


class Worker:
    """Run ``fn(item)`` on a thread of its own; :meth:`offer` hands it an item unless it is
    still busy (then the item is skipped and counted): the capture loop never waits for it."""

    def __init__(self, fn, name: str, slots: int = 1):
        self.fn, self.name = fn, name
        self.skipped = 0
        self.error: BaseException | None = None
        self._q: queue.Queue = queue.Queue(maxsize=slots)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self):
        while True:
            item = self._q.get()
            if item is None:
                return
            if self.error is not None:
                continue
            try:
                self.fn(item)
            except BaseException as exc:   # kept, re-raised to the caller by close()
                self.error = exc
                log.error("%s: %s", self.name, exc)

    def offer(self, item) -> bool:
        try:
            self._q.put_nowait(item)
            return True
        except queue.Full:
            self.skipped += 1
            return False

    def close(self, timeout_s: float = 30.0) -> None:
        self._q.put(None)
        self._thread.join(timeout_s)


def stream_capture(source, writer, *, frames: int, skip_frames: int = 4, timeout_s: float = 2.0,
                   queue_frames: int = 16, plan: dict | None = None, on_frame=None,
                   stop: threading.Event | None = None, labels_text: str | None = None,
                   clock=time.monotonic_ns) -> CaptureReport:
    """Capture ``frames`` frames from ``source`` into ``writer`` (module docstring).

    Parameters
    ----------
    source
        A started camera: ``next_frame(timeout_s) -> (rows (H, stride) uint8, metadata)``,
        raising :class:`CameraStall` on a timeout; ``name``.
    writer : estimator.capture.CaptureWriter
    skip_frames : int
        Frames dropped at the start (libcamera mistrusts the first two after a start and
        applies controls two frames late).
    plan : dict, optional
        ``frame_duration_us``, ``exposure_us``, ``line_us``: checked on the first frames
        after ``skip_frames`` (:func:`check_timing`); a mismatch stops the capture.
    on_frame : callable, optional
        ``on_frame(index, rows, metadata)`` for every frame written or queued; it must not
        block (hand work to a :class:`Worker`). Returning ``False`` stops the capture.
    stop : threading.Event, optional
        Set from elsewhere to end the capture early (state ``interrupted``).

    Returns
    -------
    CaptureReport
        Also written as ``capture.json``'s ``summary``. A SIGINT (KeyboardInterrupt) ends
        the run as ``interrupted``; a stall, a timing mismatch or a write error as
        ``failed``; the frames written before stay readable in every case.
    """
    q: queue.Queue = queue.Queue(maxsize=max(int(queue_frames), 1))
    write_error: list[BaseException] = []
    high = [0]

    def write_loop():
        while True:
            item = q.get()
            if item is None:
                return
            if write_error:
                continue                      # drain: memory back, nothing more written
            try:
                writer.write(*item)
            except BaseException as exc:
                write_error.append(exc)

    thread = threading.Thread(target=write_loop, name="capture-writer", daemon=True)
    thread.start()
    state, stopped = "complete", ""
    dropped = lost = 0
    last_ts = None
    period_ns = None
    checked: list[dict] = []
    latency: list[float] = []
    index = 0
    try:
        for n in range(skip_frames + frames):
            if stop is not None and stop.is_set():
                state, stopped = "interrupted", "stopped by request"
                break
            if write_error:
                exc = write_error[0]
                state, stopped = "failed", f"cannot write the capture: {exc}"
                break
            rows, md = source.next_frame(timeout_s)
            now = clock()
            if n < skip_frames:
                continue
            ts = int(md["SensorTimestamp"])
            latency.append((now - ts) * 1e-9)
            fd = md.get("FrameDuration")
            if fd:
                period_ns = float(fd) * 1e3
            if last_ts is not None and period_ns:
                gap = int(round((ts - last_ts) / period_ns)) - 1
                if gap > 0:
                    dropped += gap
                    log.warning("%s: %d frame(s) dropped before SensorTimestamp %d", source.name,
                                gap, ts)
            last_ts = ts
            if plan is not None and len(checked) < 3:
                checked.append(md)
                if len(checked) == 3:
                    check_timing(checked, camera=source.name, **plan)
            try:
                q.put_nowait((rows, md))
            except queue.Full:
                lost += 1
                log.warning("%s: the writer is behind (%d frames queued): frame lost", source.name,
                            q.qsize())
                continue
            high[0] = max(high[0], q.qsize())
            if on_frame is not None and on_frame(index, rows, md) is False:
                state, stopped = "interrupted", "stopped by the frame handler"
                break
            index += 1
    except KeyboardInterrupt:
        state, stopped = "interrupted", "interrupted (SIGINT)"
    except TimingMismatch as exc:
        state, stopped = "failed", str(exc)
    except CameraStall as exc:
        state, stopped = "failed", str(exc)
    finally:
        q.put(None)
        thread.join()
    if write_error and state == "complete":
        state, stopped = "failed", f"cannot write the capture: {write_error[0]}"
    report = CaptureReport(state, stopped, writer.frames, dropped, lost, high[0], latency)
    summary = report.to_dict()
    try:
        writer.finish(state, summary, labels_text)
    except OSError as exc:
        log.error("%s: cannot complete capture.json (%s); the frames listed stay readable",
                  writer.folder, exc)
        report.stopped = (report.stopped + "; " if report.stopped else "") + \
            f"capture.json not completed: {exc}"
        if report.state == "complete":
            report.state = "failed"
    return report
