"""``scet strobe``, ``scet capture``, ``scet run`` and ``scet hardware``: the prototype's
subcommands, registered into the ``scet`` command by :func:`register` (heavy imports inside
each); the capture and the live run are in :mod:`.cli_run`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scet_render.runner import finite, integer  # NaN, infinite and absurd flags refused up front

from .cli_run import PORT_ENV, SETTINGS_ENV, cmd_capture, cmd_run, strobe_link, strobe_plan

__all__ = ["register"]


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
        with strobe_link(args) as link:
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



def _board(args) -> int:
    """``scet hardware board``: the printable ChArUco board and its board.json."""
    from estimator.lens import BoardError, BoardSpec

    from .board import write_printable_board

    try:
        sx, sy = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        print(f"scet hardware board: error: --squares must be COLSxROWS (e.g. 11x8), got "
              f"{args.squares!r}", file=sys.stderr)
        return 2
    try:
        square_mm, marker_mm = args.square_mm, args.marker_mm
        fitted = ""
        if square_mm is None:  # sized to the scene's field (estimator.lens.board_for_setup)
            from estimator.lens import board_for_setup, working_distance_m
            from estimator.scene import load_scene

            setup = load_scene(args.scene)
            square_mm = board_for_setup(setup, (sx, sy), args.dictionary).square_mm
            cam = setup.camera
            wd = working_distance_m(setup)
            fitted = (f"; sized to {setup.name}'s field at its {wd * 1e3:.1f} mm working "
                      f"distance ({wd * cam.width_px / cam.fx_px * 1e3:.1f} x "
                      f"{wd * cam.height_px / cam.fy_px * 1e3:.1f} mm)")
        if marker_mm is None:
            marker_mm = round(0.75 * square_mm, 4)
        spec = BoardSpec(sx, sy, square_mm, marker_mm, args.dictionary)
    except BoardError as exc:
        print(f"scet hardware board: error: {exc}", file=sys.stderr)
        return 2
    out = write_printable_board(args.out or Path("out/board"), spec)
    w, h = spec.size_mm
    print(f"board {sx}x{sy} squares of {spec.square_mm:g} mm ({w:g} x {h:g} mm, markers "
          f"{spec.marker_mm:g} mm, {spec.dictionary}, {spec.inner_corners} corners) written to "
          f"{out['svg']} and {out['pdf']} (page {out['page_mm'][0]:g} x {out['page_mm'][1]:g} "
          f"mm: print at 100 %); description {out['json']}{fitted}")
    return 0


def cmd_hardware(args) -> int:
    if args.action == "board":
        return _board(args)
    if args.action == "mirror":
        from dataclasses import replace

        from .mirror import DESIGNED, MirrorParams, write_mirror

        base = DESIGNED if args.designed else MirrorParams()
        p = replace(base, radius_mm=args.radius_mm, span_deg=args.span_deg,
                    width_mm=base.width_mm if args.width_mm is None else args.width_mm,
                    thickness_mm=args.thickness_mm, turns=args.turns, wire_diameter_mm=args.wire_mm,
                    winding=args.winding,
                    led_position_m=base.led_position_m if args.led_mm is None
                    else tuple(1e-3 * x for x in args.led_mm))
        try:
            out = write_mirror(args.out or Path("out/mirror"), p)
        except ValueError as exc:
            print(f"scet hardware mirror: {exc}", file=sys.stderr)
            return 2
        print(f"mirror written to {out['stl']} ({out['volume_mm3']:.0f} mm^3, watertight); "
              f"{p.turns} glint sources to {out['lights']}; the wire_mirror group (strip, wire, "
              f"LED) to {out['wire_lights']}")
        return 0
    plan = strobe_plan(args)
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


def _capture_args(p, *, scene: bool = True) -> None:
    """The flags of ``scet capture`` and ``scet run``; ``scene`` False leaves out the replay's
    optional --scene (``scet run`` has its own, required)."""
    p.add_argument("--out", type=Path, required=True, help="capture folder (new)")
    p.add_argument("--frames", type=integer(1, 10_000_000), default=600)
    p.add_argument("--replay", type=Path, help="a rendered dataset as the camera")
    p.add_argument("--realtime", action="store_true",
                   help="replay: deliver frames at the frame rate as the camera does (dropping "
                        "those not taken in time), repeating the dataset")
    if scene:
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
    _capture_args(p, scene=False)
    p.add_argument("--calibration", type=Path, required=True)
    p.add_argument("--camera", type=Path,
                   help="camera file (scet camera calibrate): its intrinsics and lens distortion "
                        "replace the scene's; detected glints are undistorted")
    p.add_argument("--samples", type=Path, required=True, help="samples CSV, written as they come")
    p.add_argument("--method", default="polynomial", choices=("polynomial", "geometric"))
    p.add_argument("--track-queue", type=integer(1, 64), default=2,
                   help="frames waiting for the tracker before frames are skipped (default 2)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("hardware", help="the prototype's mirror (STL + light list), settings "
                                        "plan, and printable camera-calibration board")
    p.add_argument("action", choices=("mirror", "plan", "board"))
    p.add_argument("--out", type=Path, help="mirror, board: output folder (default out/mirror, "
                                            "out/board)")
    p.add_argument("--radius-mm", type=finite(1.0, 1000.0), default=33.0)
    p.add_argument("--span-deg", type=finite(1.0, 360.0), default=90.0)
    p.add_argument("--width-mm", type=finite(0.01, 100.0),
                   help="mirror: strip width (default 2, or 3 with --designed)")
    p.add_argument("--designed", action="store_true",
                   help="mirror: the designed part (reports/wire_mirror.md, Design): 3 mm strip, its LED")
    p.add_argument("--winding", choices=("end_to_end", "mid_cell"), default="end_to_end",
                   help="mirror: turns at both ends of the span, or in the middle of equal cells")
    p.add_argument("--led-mm", type=finite(-1000.0, 1000.0), nargs=3, metavar=("X", "Y", "Z"),
                   help="mirror: the LED in the group's frame (default the prototype scene's)")
    p.add_argument("--thickness-mm", type=finite(0.01, 100.0), default=1.5)
    p.add_argument("--turns", type=integer(1, 10_000), default=35)
    p.add_argument("--wire-mm", type=finite(0.01, 100.0), default=0.8)
    # The default board spans 60 % of the scene's field at its working distance
    # (estimator/lens/board.py says why).
    p.add_argument("--squares", default="11x8", help="board: squares COLSxROWS (default 11x8)")
    p.add_argument("--scene", default="prototype_ov5647",
                   help="board: size the squares so the board spans 60 %% of this scene's field "
                        "width at its working distance (default prototype_ov5647: 1.3 mm "
                        "squares, 14.3 x 10.4 mm, in a 22.9 x 17.2 mm field at 23 mm)")
    p.add_argument("--square-mm", type=finite(0.1, 1000.0), default=None,
                   help="board: square side in mm (default: from --scene; 2.5 is "
                        "scet camera calibrate's default board, for 35 mm)")
    p.add_argument("--marker-mm", type=finite(0.1, 1000.0), default=None,
                   help="board: marker side in mm (default 0.75 of a square)")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="board: ArUco dictionary")
    _plan_args(p)
    p.set_defaults(func=cmd_hardware)
