"""``scet strobe``, ``scet capture`` and ``scet hardware``: the prototype's subcommands,
registered into the ``scet`` command by :func:`register` (heavy imports inside each)."""

from __future__ import annotations

import json
import os
import sys
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


def cmd_capture(args) -> int:
    from tqdm import tqdm

    if args.replay is not None:
        from .capture.replay import replay_dataset

        response = [float(v) for v in args.channel_response.split(",")]
        with tqdm(unit="frame", desc="replay", disable=None) as bar:
            def progress(done, total):
                bar.total = total
                bar.n = done
                bar.refresh()
            out = replay_dataset(args.replay, args.out, scene=args.scene, raw_format=args.raw_format,
                                 channel_response=response, progress=progress)
        print(f"capture folder {out} written from dataset {args.replay} ({args.raw_format})")
        return 0
    from .capture.picam import CaptureSettings, capture_to_folder

    plan = _plan(args)
    strobe = dict(plan.firmware)
    if args.strobe_port:
        with _link(args, port=args.strobe_port) as link:
            strobe = link.apply(pulses=strobe["pulses"], width_ticks=strobe["width_ticks"],
                                period_ticks=strobe["period_ticks"], trim_256th=strobe["trim_256th"],
                                mode=strobe["mode"]).to_dict()
    strobe_model = None
    if args.single:
        # Single-pulse calibration frames: the tracker reads every visible row as lit by one
        # pulse placed in the window all rows share, [R(N-1) - exposure, R(0)] (Eqs. (2)-(3));
        # lock the strobe's phase there (scet strobe phase) before capturing.
        s = plan.sensor
        span = (s.visible_lines - 1) * s.frame_period_s / s.total_lines
        slack = s.exposure_s - span
        if slack <= plan.pulse_s:
            raise ValueError(f"--single: an exposure of {s.exposure_s * 1e6:.0f} us does not cover "
                             f"the readout span {span * 1e6:.0f} us plus the pulse; raise --exposure-us")
        strobe_model = {"pulses_per_frame": 1, "pulse_s": plan.pulse_s,
                        "period_s": s.frame_period_s, "phase_s": -0.5 * slack - 0.5 * plan.pulse_s}
    settings = CaptureSettings(frames=args.frames, strobe_model=strobe_model, frame_duration_us=plan.controls["FrameDurationLimits"][0],
                               exposure_us=plan.controls["ExposureTime"], analogue_gain=args.gain,
                               raw_format=args.raw_format, strobe=strobe,
                               extra={"plan": {"profile": plan.profile, "total_lines": plan.sensor.total_lines}})
    with tqdm(total=args.frames, unit="frame", desc="capture", disable=None) as bar:
        out = capture_to_folder(args.out, settings, progress=lambda d, t: bar.update(d - bar.n))
    print(f"capture folder {out}: {args.frames} frames")
    return 0


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

    p = sub.add_parser("capture", help="capture raw frames on the Pi, or replay a rendered dataset")
    p.add_argument("--out", type=Path, required=True, help="capture folder")
    p.add_argument("--frames", type=integer(1, 10_000_000), default=600)
    p.add_argument("--replay", type=Path, help="a rendered dataset to replay instead of a camera")
    p.add_argument("--scene", help="replay: the scene (default: the one in the manifest)")
    p.add_argument("--raw-format", default="SGBRG10_CSI2P", help="SGBRG10_CSI2P (packed) or SGBRG10")
    p.add_argument("--channel-response", default="1,1,1,1", help="replay: R,Gr,Gb,B relative response")
    p.add_argument("--strobe-port", help="set the strobe firmware to the plan first (serial port)")
    _link_args(p)
    _plan_args(p)
    p.set_defaults(func=cmd_capture)

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
