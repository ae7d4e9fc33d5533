"""``scet strobe``, ``scet capture`` and ``scet hardware``: the prototype's subcommands,
registered into the ``scet`` command by :func:`register` (heavy imports inside each)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from scet_render.runner import finite, integer  # NaN, infinite and absurd flags refused up front

__all__ = ["register"]

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


def _link(args, port=None):
    from .strobe import StrobeLink

    port = port or getattr(args, "port", None) or os.environ.get(PORT_ENV)
    if not port:
        raise ValueError(f"no serial port: pass --port or set {PORT_ENV}")
    return StrobeLink(port, timeout_s=args.timeout, boot_s=args.boot_s,
                      keep_dtr=not args.allow_reset, settings=settings_path(args))


def _lock(args, link) -> int:
    """One step of the software phase lock: the timing measured by ``scet bands --measure
    --json`` (under the firmware's current settings) to SET PERIOD, SET TRIM and PHASE."""
    from estimator.formats import read_json

    from .lock import lock_command

    if args.timing is None:
        raise ValueError("scet strobe lock needs --timing M.json (scet bands --measure --json)")
    doc = read_json(args.timing)
    phases, frames = doc.get("phase_s"), doc.get("phase_frames")
    if not (isinstance(phases, list) and isinstance(frames, list) and len(phases) == len(frames)
            and len(phases) >= 3 and all(isinstance(v, (int, float)) for v in phases + frames)):
        raise ValueError(f"{args.timing}: keys 'phase_s' and 'phase_frames' must be lists of "
                         "numbers of one length, at least 3 frames")
    for key in ("frame_period_s", "total_lines", "periods_per_frame"):
        if not isinstance(doc.get(key), (int, float)):
            raise ValueError(f"{args.timing}: key {key!r} must be a number")
    s = link.get()
    target = phases[0] if args.target_phase_us is None else args.target_phase_us * 1e-6
    cmd = lock_command(phases, frames, frame_period_s=doc["frame_period_s"],
                       total_lines=doc["total_lines"],
                       periods_per_frame=int(doc["periods_per_frame"]),
                       period_ticks=s.period_ticks, trim_256th=s.trim_256th,
                       target_phase_s=target, next_frame=int(frames[-1]) + args.delay_frames)
    link.apply(period_ticks=cmd.period_ticks, trim_256th=cmd.trim_256th)
    pending = link.shift_phase(cmd.phase_ticks) if cmd.phase_ticks else 0
    print(f"lock: PERIOD {s.period_ticks} -> {cmd.period_ticks}, TRIM {s.trim_256th} -> "
          f"{cmd.trim_256th}, PHASE {cmd.phase_ticks:+d} ticks (pending {pending}), "
          f"target phase {target * 1e6:.2f} us")
    return 0


def cmd_strobe(args) -> int:
    from .strobe import StrobeError

    try:
        with _link(args) as link:
            if args.action == "ping":
                link.ping()
                print(f"{link.port}: SCET strobe firmware, protocol 1")
                return 0
            if args.action == "get":
                s = link.get()
            elif args.action == "set":
                s = link.apply(pulses=args.pulses, width_ticks=args.width_ticks,
                               period_ticks=args.period_ticks, trim_256th=args.trim,
                               mode=args.mode)
            elif args.action == "phase":
                pending = link.shift_phase(args.ticks)
                c = link.wait_phase_applied() if args.wait else None
                print(f"phase shift of {args.ticks} ticks queued (pending {pending})"
                      + (f"; applied, {c.periods} periods since reset" if c else ""))
                return 0
            elif args.action == "lock":
                return _lock(args, link)
            elif args.action == "count":
                c = link.count()
                print(f"periods {c.periods}, frames {c.frames}, phase shift pending {c.pending_ticks} ticks")
                return 0
            else:
                s = link.run(args.action == "start")
    except StrobeError as exc:
        print(f"scet strobe: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(s.to_dict(), sort_keys=True))
    print(f"{s.pulses} pulses/frame ({s.mode}) of {s.pulse_s * 1e6:g} us every "
          f"{s.period_s * 1e6:.6f} us, frame {s.frame_s * 1e3:.6f} ms, {'running' if s.running else 'stopped'}")
    return 0


def _plan(args):
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

    plan = _plan(args)
    strobe_model = _single_check(plan) if args.single else None
    link = _link(args, port=args.strobe_port) if args.strobe_port else None
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
    calibration, mapping = tracking_calibration(args.out, args.calibration, args.samples,
                                                method=args.method, n_lights=setup.lights.count)
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


def cmd_hardware(args) -> int:
    if args.action == "mirror":
        from .mirror import MirrorParams, write_mirror

        p = MirrorParams(radius_mm=args.radius_mm, span_deg=args.span_deg, width_mm=args.width_mm,
                         thickness_mm=args.thickness_mm, turns=args.turns,
                         wire_diameter_mm=args.wire_mm)
        out = write_mirror(args.out, p)
        print(f"mirror written to {out['stl']} ({out['volume_mm3']:.0f} mm^3, watertight); "
              f"{p.turns} glint sources to {out['lights']}")
        return 0
    plan = _plan(args)
    s = plan.sensor
    print(f"profile {plan.profile}: S = {s.total_lines} lines, frame {s.frame_period_s * 1e6:.3f} us, "
          f"exposure {s.exposure_s * 1e6:.3f} us ({round(s.exposure_s / s.line_time_s)} lines)")
    print("libcamera controls: " + json.dumps(plan.controls))
    print("firmware: " + json.dumps(plan.firmware))
    print(f"strobe period {plan.period_s * 1e6:.6f} us, pulse {plan.pulse_s * 1e6:g} us, band drift "
          f"{plan.drift_rows_per_frame:.5f} rows/frame with ideal clocks")
    print("scet strobe set " + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in (
        ("pulses", plan.firmware["pulses"]), ("width_ticks", plan.firmware["width_ticks"]),
        ("period_ticks", plan.firmware["period_ticks"]), ("trim", plan.firmware["trim_256th"]),
        ("mode", plan.firmware["mode"]))))
    return 0


def _link_args(p) -> None:
    from .strobe import BOOT_S

    p.add_argument("--timeout", type=finite(0.01, 3600.0), default=1.0,
                   help="seconds to wait for a reply")
    p.add_argument("--boot-s", type=finite(0.01, 3600.0), default=BOOT_S,
                   help=f"seconds the board may take to answer after opening the port resets it "
                        f"(Optiboot waits ~1 s; default {BOOT_S:g})")
    p.add_argument("--allow-reset", action="store_true",
                   help="leave HUPCL set: every close drops DTR, so every open resets the board")
    p.add_argument("--settings", type=Path,
                   help=f"strobe settings file re-applied after a reset (default ${SETTINGS_ENV} or "
                        "~/.config/scet/strobe-settings.json)")


def _plan_args(p) -> None:
    p.add_argument("--profile", default="ov5647_mode6", choices=("ov5647_mode6", "ov5647_mode7"),
                   help="sensor reading: mode6 = today's kernel driver, S = 524 (default); mode7, S = 786")
    p.add_argument("--frame-us", type=finite(100.0, 1e7), default=16636.0, help="wanted frame period (default 16636)")
    p.add_argument("--pulses", type=integer(1, 1000), help="pulses per frame (default 16)")
    p.add_argument("--pulse-us", type=finite(0.1, 1e6), default=100.0)
    p.add_argument("--exposure-us", type=finite(1.0, 1e7), help="default Eq. (8): period - pulse")
    p.add_argument("--gain", type=finite(1.0, 64.0), default=1.0, help="analogue gain")
    p.add_argument("--single", action="store_true", help="single-pulse frames (calibration, Sec. 2.4)")


def _capture_args(p) -> None:
    p.add_argument("--out", type=Path, required=True, help="capture folder (new)")
    p.add_argument("--frames", type=integer(1, 10_000_000), default=600)
    p.add_argument("--replay", type=Path, help="a rendered dataset as the camera")
    p.add_argument("--realtime", action="store_true",
                   help="replay: deliver frames at the frame rate as the camera does (dropping "
                        "those not taken in time), repeating the dataset")
    if not any(a.dest == "scene" for a in p._actions):
        p.add_argument("--scene", help="replay: the scene (default: the one in the manifest)")
    p.add_argument("--raw-format", default="SGBRG10_CSI2P", help="SGBRG10_CSI2P (packed) or SGBRG10")
    p.add_argument("--channel-response", default="1,1,1,1", help="replay: R,Gr,Gb,B relative response")
    p.add_argument("--strobe-port", help="the strobe board: set to the plan, held for the run")
    p.add_argument("--lock", action="store_true",
                   help="lock the strobe phase from the frames as they arrive (needs --strobe-port); "
                        "with --single: lock first, then capture single-pulse frames")
    p.add_argument("--lock-timeout", type=finite(1.0, 3600.0), default=30.0,
                   help="--single --lock: seconds to lock and place the pulse (default 30)")
    p.add_argument("--camera-timeout", type=finite(0.05, 600.0), default=2.0,
                   help="seconds to wait for a frame (and any camera call) before giving up")
    p.add_argument("--queue-frames", type=integer(1, 1000), default=16,
                   help="frames held for the writer (memory bound; default 16 = 6 MB packed)")
    p.add_argument("--progress-every", type=integer(0, 10_000_000), default=0,
                   help="print a progress line every N frames (0: none)")
    for flag, kind in (("--fault-stall-after", integer(0, 10_000_000)),
                       ("--fault-stall-s", finite(0.0, 3600.0)), ("--fault-drop", str),
                       ("--fault-frame-us", integer(1, 10_000_000))):
        p.add_argument(flag, type=kind, default=0.0 if flag == "--fault-stall-s" else None,
                       help=argparse.SUPPRESS)    # replay faults, for the fault tests
    _link_args(p)
    _plan_args(p)


def register(sub) -> None:
    """Add the prototype's subcommands to the ``scet`` parser's subparsers."""
    p = sub.add_parser("strobe", help="talk to the Arduino strobe firmware over its serial port")
    p.add_argument("action", choices=("ping", "get", "set", "phase", "count", "start", "stop",
                                       "lock"))
    p.add_argument("ticks", nargs="?", type=int, help="phase: shift in ticks (+ delays the train)")
    p.add_argument("--port", help=f"serial port (default ${PORT_ENV})")
    _link_args(p)
    p.add_argument("--pulses", type=integer(1, 1000))
    p.add_argument("--width-ticks", type=int)
    p.add_argument("--period-ticks", type=int)
    p.add_argument("--trim", type=int, help="1/256 tick added to each period on average")
    p.add_argument("--mode", choices=("banded", "single"))
    p.add_argument("--wait", action="store_true", help="phase: wait until the shift is applied")
    p.add_argument("--timing", type=Path, help="lock: scet bands --measure --json output")
    p.add_argument("--target-phase-us", type=finite(0.0, 1e6),
                   help="lock: wanted delay from first readout to first band (default: the "
                        "first measured frame's)")
    p.add_argument("--delay-frames", type=integer(1, 1000), default=2,
                   help="lock: frames from the last measured one until the command acts")
    p.set_defaults(func=cmd_strobe)

    p = sub.add_parser("capture", help="capture raw frames on the Pi (streamed to disk, phase "
                                       "locked), or replay a rendered dataset")
    _capture_args(p)
    p.set_defaults(func=cmd_capture)

    p = sub.add_parser("run", help="capture, lock the strobe phase and track in one process")
    p.add_argument("--scene", required=True, help="the rig's scene")
    _capture_args(p)
    p.add_argument("--calibration", type=Path, required=True)
    p.add_argument("--samples", type=Path, required=True, help="samples CSV, written as they come")
    p.add_argument("--method", default="polynomial", choices=("polynomial", "geometric"))
    p.add_argument("--track-queue", type=integer(1, 64), default=2,
                   help="frames waiting for the tracker before frames are skipped (default 2)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("hardware", help="the prototype's mirror (STL + light list) and settings plan")
    p.add_argument("action", choices=("mirror", "plan"))
    p.add_argument("--out", type=Path, default=Path("out/mirror"), help="mirror: output folder")
    p.add_argument("--radius-mm", type=finite(1.0, 1000.0), default=33.0)
    p.add_argument("--span-deg", type=finite(1.0, 360.0), default=90.0)
    p.add_argument("--width-mm", type=finite(0.01, 100.0), default=2.0)
    p.add_argument("--thickness-mm", type=finite(0.01, 100.0), default=1.5)
    p.add_argument("--turns", type=integer(1, 10_000), default=35)
    p.add_argument("--wire-mm", type=finite(0.01, 100.0), default=0.8)
    _plan_args(p)
    p.set_defaults(func=cmd_hardware)
