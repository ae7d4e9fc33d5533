"""``scet capture`` and ``scet run``: the capture loop with the strobe held and phase locked,
and live tracking on top of it; and what every prototype subcommand takes from its flags (the
strobe connection, the settings plan). :mod:`.cli` defines the flags and registers the
subcommands (heavy imports inside each command)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

__all__ = ["PORT_ENV", "SETTINGS_ENV", "settings_path", "strobe_link", "strobe_plan",
           "cmd_capture", "cmd_run"]

PORT_ENV = "SCET_STROBE_PORT"
SETTINGS_ENV = "SCET_STROBE_SETTINGS"


def settings_path(args) -> Path:
    """The strobe settings file: --settings, $SCET_STROBE_SETTINGS, or
    $XDG_CONFIG_HOME/scet/strobe-settings.json (~/.config by default)."""
    if getattr(args, "settings", None):
        return Path(args.settings)
    if os.environ.get(SETTINGS_ENV):
        return Path(os.environ[SETTINGS_ENV])
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "scet" / "strobe-settings.json"


def strobe_link(args, port=None):
    """The strobe connection of a subcommand: --port (or ``port``), else $SCET_STROBE_PORT."""
    from .strobe import StrobeLink

    port = port or getattr(args, "port", None) or os.environ.get(PORT_ENV)
    if not port:
        raise ValueError(f"no serial port: pass --port or set {PORT_ENV}")
    return StrobeLink(port, timeout_s=args.timeout, boot_s=args.boot_s,
                      keep_dtr=not args.allow_reset, settings=settings_path(args))


def strobe_plan(args):
    """The prototype's sensor and strobe settings for the plan flags (--profile, --frame-us, ...)."""
    from .profiles import plan_prototype_strobe, profile

    return plan_prototype_strobe(profile(args.profile), frame_duration_us=args.frame_us,
                                 pulses=args.pulses, pulse_us=args.pulse_us,
                                 exposure_us=args.exposure_us, analogue_gain=args.gain,
                                 single_pulse=args.single)


def _single_check(plan) -> dict:
    """Single-pulse calibration frames: the tracker reads every visible row as lit by one
    pulse placed in the window all rows share, [R(N-1) - exposure, R(0)] (Eqs. (2)-(3)); the
    exposure must cover the readout span plus the pulse. The strobe model of such frames."""
    s = plan.sensor
    span = (s.visible_lines - 1) * s.frame_period_s / s.total_lines
    slack = s.exposure_s - span
    if slack <= plan.pulse_s:
        most = (s.total_lines - 4) * s.line_time_s
        raise ValueError(f"--single: an exposure of {s.exposure_s * 1e6:.0f} us does not cover the "
                         f"readout span {span * 1e6:.0f} us plus the {plan.pulse_s * 1e6:g} us pulse "
                         f"(profile {plan.profile}); raise --exposure-us (at most {most * 1e6:.0f} us)")
    return {"pulses_per_frame": 1, "pulse_s": plan.pulse_s, "period_s": s.frame_period_s,
            "phase_s": -0.5 * slack - 0.5 * plan.pulse_s}


def _open_source(args, plan):
    """The camera of a run: a replayed dataset (paced with --realtime) or picamera2."""
    if args.replay is not None:
        from .capture.replay import ReplayCamera

        response = [float(v) for v in args.channel_response.split(",")]
        drops = [int(v) for v in args.fault_drop.split(",") if v] if args.fault_drop else []
        cam = ReplayCamera(args.replay, scene=args.scene, raw_format=args.raw_format,
                           channel_response=response, realtime=args.realtime,
                           loop=args.realtime, stall_after=args.fault_stall_after,
                           stall_s=args.fault_stall_s, drop=drops,
                           report_frame_us=args.fault_frame_us)
        return cam, cam.header()
    from .capture.picam import CaptureSettings, PicameraSource

    settings = CaptureSettings(frames=args.frames, frame_duration_us=plan.controls["FrameDurationLimits"][0],
                               exposure_us=plan.controls["ExposureTime"], analogue_gain=args.gain,
                               raw_format=args.raw_format)
    cam = PicameraSource(settings, timeout_s=args.camera_timeout).open()
    return cam, None


def _capture_run(args, *, tracker_worker=None, label="capture"):
    """The shared body of ``scet capture`` and ``scet run``: one strobe connection, the
    camera, the streaming loop with the phase lock; the report and the lock."""
    import signal
    import threading

    from estimator.capture import CaptureWriter, parse_raw_format

    from .capture.stream import stream_capture
    from .lock import LockFeed, PhaseLockLoop, acquire_single

    plan = strobe_plan(args)
    strobe_model = _single_check(plan) if args.single else None
    link = strobe_link(args, port=args.strobe_port) if args.strobe_port else None
    lock = None
    cam = None
    started = False
    try:
        strobe = dict(plan.firmware)
        if link is not None:
            fw = plan.firmware
            strobe = link.apply(pulses=fw["pulses"], width_ticks=fw["width_ticks"],
                                period_ticks=fw["period_ticks"], trim_256th=fw["trim_256th"],
                                mode=fw["mode"]).to_dict()
        cam, header = _open_source(args, plan)
        if header is None:
            header = cam.header(strobe=strobe, strobe_model=strobe_model,
                                extra={"plan": {"profile": plan.profile,
                                                "total_lines": plan.sensor.total_lines}})
        elif link is not None:
            header["strobe"] = strobe
        if "scene" not in header and getattr(args, "scene", None):
            # The rig's scene (scet run's --scene), for the commands that read the capture.
            from estimator.scene import resolve_scene

            header["scene"] = {"toml": resolve_scene(args.scene).read_text(encoding="utf-8")}
        fmt = parse_raw_format(header["raw"]["format"])
        width = header["raw"]["size"][0]
        if args.lock:
            if link is None:
                raise ValueError("--lock needs --strobe-port (the lock trims the strobe)")
            lock = PhaseLockLoop(link, frame_period_s=plan.sensor.frame_period_s,
                                 total_lines=plan.sensor.total_lines,
                                 periods_per_frame=16 if args.single else plan.firmware["pulses"])
            link.on_reset = lock.restart
        if args.single and lock is not None:
            # Calibration frames only once the lock holds: banded frames to lock the period
            # and phase, then SINGLE with the pulse moved into the shared window (not written).
            from estimator.capture import decode_raw

            if (args.pulses or 16) != 16:
                raise ValueError("--single --lock locks on 16 pulses a frame; leave --pulses out")
            link.apply(pulses=16, remember=False)
            cam.start()
            started = True
            used = acquire_single(cam, link, lock, lambda rows: decode_raw(rows, fmt, width)
                                  .astype("float64"), visible_rows=header["raw"]["size"][1],
                                  exposure_s=plan.sensor.exposure_s, timeout_s=args.lock_timeout,
                                  camera_timeout_s=args.camera_timeout)
            print(f"{label}: locked and the single pulse in the shared window after {used} frames",
                  flush=True)
            header["strobe"] = link.get().to_dict()
        writer = CaptureWriter(args.out, header)
        feed = LockFeed(lock, fmt.name, width) if lock is not None and not args.single else None
        first = []

        def on_frame(index, rows, md):
            ts = int(md["SensorTimestamp"])
            if not first:
                first.append(ts)
            f = int(round((ts - first[0]) * 1e-9 / plan.sensor.frame_period_s))
            if feed is not None:
                f = feed(rows, md)
            if tracker_worker is not None:
                tracker_worker.offer((f, rows, md, time.perf_counter()))
            if args.progress_every and (index + 1) % args.progress_every == 0:
                print(f"{label}: {index + 1} frames" + (
                    f", phase {'locked' if lock.locked else 'locking'}" if lock else ""), flush=True)

        stop = threading.Event()
        old = signal.signal(signal.SIGTERM, lambda *a: stop.set()) \
            if threading.current_thread() is threading.main_thread() else None
        try:
            if not started:
                cam.start()
            frames = args.frames
            if args.replay is not None and not args.realtime:
                frames = min(frames, len(cam))    # a dataset replayed once
            report = stream_capture(cam, writer, frames=frames,
                                    skip_frames=0 if args.replay else 4,
                                    timeout_s=args.camera_timeout, queue_frames=args.queue_frames,
                                    plan=None if args.replay else {
                                        "frame_duration_us": plan.sensor.frame_period_s * 1e6,
                                        "exposure_us": plan.sensor.exposure_s * 1e6,
                                        "line_us": plan.sensor.line_time_s * 1e6},
                                    on_frame=on_frame, stop=stop,
                                    labels_text=getattr(cam, "labels_text", None))
        finally:
            if old is not None:
                signal.signal(signal.SIGTERM, old)
            if feed is not None:
                feed.close()
    finally:
        if cam is not None:
            cam.stop()
            cam.close()
        if link is not None:
            link.close()
    return report, lock, link


def _report_line(args, report, lock, link) -> list[str]:
    lines = [f"capture folder {args.out}: {report.frames_written} frames written, "
             f"{report.dropped_camera} dropped by the camera, {report.lost_queue} lost to a full "
             f"writer queue (high-water {report.queue_high_water}), {report.state}"
             + (f": {report.stopped}" if report.stopped else "")]
    if lock is not None:
        offs = [abs(o) for _, _, o in lock.history[-lock.window:]]
        lines.append(f"phase lock: {len(lock.commands)} commands, "
                     f"{'locked' if lock.locked else 'NOT locked'} (last {len(offs)} frames within "
                     f"{max(offs) if offs else float('nan'):.2f} rows of the target)")
    if link is not None and (link.resets > 1 or link.reconnects):
        lines.append(f"strobe: {link.resets - 1} reset(s) and {link.reconnects} reconnect(s) during "
                     "the run (settings restored, phase re-locked)")
    return lines


def _exit_status(report) -> int:
    return {"complete": 0, "interrupted": 130}.get(report.state, 2)


def cmd_capture(args) -> int:
    from .capture.stream import CameraError
    from .lock import LockTimeout
    from .strobe import StrobeError

    try:
        report, lock, link = _capture_run(args)
    except (StrobeError, CameraError, FileExistsError, LockTimeout) as exc:
        print(f"scet capture: error: {exc}", file=sys.stderr)
        return 2
    lines = _report_line(args, report, lock, link)
    out = sys.stdout if report.state == "complete" else sys.stderr
    for line in lines:
        print(line if out is sys.stdout else f"scet capture: {line}", file=out)
    return _exit_status(report)


def cmd_run(args) -> int:
    """``scet run``: capture, lock and track in one process; samples written as they come."""
    import numpy as np

    from estimator.capture import decode_raw, parse_raw_format, to_tracker_frame
    from estimator.folders import track_frame, tracking_calibration
    from estimator.tracking import samples_csv
    from estimator.scene import load_scene
    from estimator.tracker import Tracker

    from .capture.stream import CameraError, Worker
    from .lock import LockTimeout
    from .strobe import StrobeError

    setup = load_scene(args.scene)
    if getattr(args, "camera", None) is not None:  # the lens calibrated by scet camera calibrate
        from dataclasses import replace

        from estimator.lens import camera_from_file, read_camera_file

        setup = replace(setup, camera=camera_from_file(
            setup.camera, read_camera_file(args.camera), args.camera))
    calibration, mapping = tracking_calibration(args.out, args.calibration, args.samples,
                                                method=args.method, n_lights=setup.lights.count)
    from estimator.lens import check_camera_record  # the calibration's camera file (issue 30)

    warning = check_camera_record(calibration.camera_file, getattr(args, "camera", None),
                                  args.calibration)
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    tracker = Tracker(setup, calibration, args.method, mapping=mapping)
    fmt = parse_raw_format(args.raw_format)
    w = setup.camera.width_px
    gains = [1.0 / float(v) for v in args.channel_response.split(",")]
    args.samples.parent.mkdir(parents=True, exist_ok=True)
    out = open(args.samples, "w", encoding="utf-8")
    out.write(samples_csv([]))
    out.flush()
    latency, tracked, counts = [], [0], {"ok": 0, "nan": 0}
    t_first = [None]

    def track(item):
        f, rows, md, arrived = item
        black = np.asarray(md["SensorBlackLevels"], dtype=np.float64) / 2.0 ** (16 - fmt.bit_depth)
        img = to_tracker_frame(decode_raw(rows, fmt, w), fmt.bayer_order, black, gains,
                               setup.sensor.black_level_dn, fmt.bit_depth)
        if t_first[0] is None:
            t_first[0] = int(md["SensorTimestamp"])
        t0 = (int(md["SensorTimestamp"]) - t_first[0]) * 1e-9
        samples = track_frame(tracker, f, t0, img, None)
        rows_text = samples_csv(samples).split("\n", 2)[2]
        out.write(rows_text)
        out.flush()
        latency.append(time.perf_counter() - arrived)
        tracked[0] += 1
        for smp in samples:
            counts["ok" if smp.reason == "ok" else "nan"] += 1

    worker = Worker(track, "tracker", slots=args.track_queue)
    try:
        report, lock, link = _capture_run(args, tracker_worker=worker, label="run")
    except (StrobeError, CameraError, FileExistsError, LockTimeout) as exc:
        print(f"scet run: error: {exc}", file=sys.stderr)
        return 2
    finally:
        worker.close()
        out.close()
    if worker.error is not None:
        raise worker.error
    for line in _report_line(args, report, lock, link):
        print(line)
    lat = np.asarray(latency) * 1e3
    print(f"tracked {tracked[0]} frames live ({worker.skipped} skipped while the tracker was busy), "
          f"{counts['ok']} samples ok, {counts['nan']} NaN, written to {args.samples}")
    if lat.size:
        print(f"latency frame in -> samples out: p50 {np.percentile(lat, 50):.1f} ms, "
              f"p99 {np.percentile(lat, 99):.1f} ms, max {lat.max():.1f} ms ({lat.size} frames)")
    return _exit_status(report)
