"""OV5647 profiles and the planner (HARDWARE.md Sec. 1c and 2 numbers), and the mirror."""

import numpy as np
import pytest

from estimator.scene import load_scene
from scet_hardware.mirror import (MirrorParams, mirror_mesh, mirror_outline_mm, turn_angles_rad,
                                  turn_clearance_mm, turn_positions_local_m, write_mirror)
from scet_hardware.profiles import plan_prototype_strobe, profile


@pytest.mark.parametrize("name, S, frame_us, lines_1ms, exp_1ms_us", [
    ("ov5647_mode6", 524, 16636.35, 31, 984.2),
    ("ov5647_mode7", 786, 16636.25, 47, 994.8),
])
def test_both_readings_of_the_prototype(name, S, frame_us, lines_1ms, exp_1ms_us):
    p = profile(name)
    plan = plan_prototype_strobe(p, exposure_us=1000.0)
    assert plan.sensor.total_lines == S
    assert plan.sensor.frame_period_s * 1e6 == pytest.approx(frame_us, abs=0.01)
    # libcamera truncates: 16,637 us gives the wanted frame length, 16,636 one line less.
    assert plan.controls["FrameDurationLimits"] == [16637, 16637]
    assert p.frame_lines(16636) == S - 1
    assert round(plan.sensor.exposure_s / p.line_s) == lines_1ms
    assert plan.sensor.exposure_s * 1e6 == pytest.approx(exp_1ms_us, abs=0.05)
    # What the firmware is told gives the realised frame to 1/256 tick per period.
    fw = plan.firmware
    assert (fw["pulses"], fw["width_ticks"], fw["period_ticks"]) == (16, 1600, 16636)
    frame_ticks = 16 * (fw["period_ticks"] + fw["trim_256th"] / 256)
    assert frame_ticks / 16e6 == pytest.approx(plan.sensor.frame_period_s, abs=16 / 256 / 16e6)
    # The control asked for gives back the same whole lines.
    assert p.exposure_lines(plan.controls["ExposureTime"], S) == lines_1ms


def test_exposure_limits_and_bad_profiles():
    p = profile("ov5647_mode6")
    assert p.exposure_lines(10.0, 524) == 4            # OV5647_EXPOSURE_MIN
    assert p.exposure_lines(1e6, 524) == 520           # VTS - 4
    with pytest.raises(ValueError, match="unknown sensor profile"):
        profile("imx219")
    with pytest.raises(ValueError, match="firmware's limits"):
        plan_prototype_strobe(p, pulses=255, pulse_us=100.0)


def test_mirror_is_a_closed_printable_part(tmp_path):
    out = write_mirror(tmp_path)
    import trimesh

    mesh = trimesh.load(out["stl"])
    assert mesh.is_watertight and mesh.is_volume
    lo, hi = mesh.bounds
    assert hi[2] - lo[2] == pytest.approx(2.0)          # 2 mm wide
    # Band R = 33 mm, t = 1.5 mm over 90 deg plus the mount: the area of the outline x width.
    band = np.pi / 4 * (34.5 ** 2 - 33.0 ** 2)
    assert mesh.volume > 2.0 * band


def test_every_turn_can_be_wound_and_sits_on_the_strip():
    # Issue 32, fix 5: nothing on the outer face where a turn passes, and each end turn has
    # the strip under it (wire radius 0.4 mm) plus the clearance to its lug.
    p = MirrorParams()
    room = turn_clearance_mm(p)
    assert not room["blocked"].any()
    assert room["support_mm"].min() >= p.wire_diameter_mm / 2 + p.clearance_mm


def test_the_clearance_check_sees_a_stem_at_mid_arc():
    # The part before the fix: a 3 mm stem from the middle of the outer face. The check must
    # find the turns it blocks: the middle three of 35 (0-based 16-18).
    p = MirrorParams(notch_depth_mm=0.0)
    r_out, mid, half = 34.5, np.radians(45.0), 1.5
    er, et = np.array([np.cos(mid), np.sin(mid)]), np.array([-np.sin(mid), np.cos(mid)])
    stem = np.array([(33.5 * er - half * et), (42.5 * er - half * et), (42.5 * er + half * et),
                     (33.5 * er + half * et)])
    room = turn_clearance_mm(p, [mirror_outline_mm(p), stem])
    assert np.flatnonzero(room["blocked"]).tolist() == [16, 17, 18]


def test_a_notch_at_every_turn_and_a_smooth_inner_face():
    from scet_hardware.mirror import _inside

    p = MirrorParams()
    poly = mirror_outline_mm(p)
    a = turn_angles_rad(p)
    r_out = p.radius_mm + p.thickness_mm
    below = r_out - p.notch_depth_mm - 0.01
    above = r_out - p.notch_depth_mm + 0.01
    assert _inside(poly, np.c_[below * np.cos(a), below * np.sin(a)]).all()
    assert not _inside(poly, np.c_[above * np.cos(a), above * np.sin(a)]).any()
    # Between two turns the outer face is whole; the inner face is whole everywhere.
    mid = (a[:-1] + a[1:]) / 2
    assert _inside(poly, np.c_[(r_out - 0.01) * np.cos(mid), (r_out - 0.01) * np.sin(mid)]).all()
    fine = np.linspace(-0.01, a[-1] + 0.01, 2000)
    assert _inside(poly, np.c_[(p.radius_mm + 0.01) * np.cos(fine), (p.radius_mm + 0.01) * np.sin(fine)]).all()


def test_turns_are_parameters_of_the_lights_and_the_notches():
    a, b = MirrorParams(turns=35), MirrorParams(turns=20)
    assert len(turn_positions_local_m(a)) == 35 and len(turn_positions_local_m(b)) == 20
    # Each notch removes a triangle of the wire's width and the notch's depth (x the width).
    notch = 0.5 * a.wire_diameter_mm * a.notch_depth_mm * a.width_mm
    assert mirror_mesh(b).volume - mirror_mesh(a).volume == pytest.approx(15 * notch, rel=0.02)


def test_turns_on_the_arc_and_in_the_scene():
    p = MirrorParams()
    pos = turn_positions_local_m(p)
    center = np.array(p.first_m) + 0.033 * np.array(p.center_direction)
    r = np.linalg.norm(pos - center, axis=1)
    np.testing.assert_allclose(r, 0.0326, atol=1e-12)     # R - d/2
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    np.testing.assert_allclose(step, step[0], rtol=1e-12)  # evenly spaced end to end
    setup = load_scene("prototype_ov5647")
    assert setup.lights.count == 35
    world = setup.lights_world_m
    # The scene's lights are the mirror's turns placed by the scene's pose.
    np.testing.assert_allclose(world, setup.lights.groups[0].pose.apply(pos), atol=1e-9)


@pytest.mark.parametrize("kw, message", [
    ({"turns": 80}, "do not fit"), ({"radius_mm": -1.0}, "radius_mm must be positive"),
    ({"span_deg": 400.0}, "span_deg"), ({"notch_depth_mm": 0.8}, "notch_depth_mm"),
])
def test_bad_mirror_parameters(kw, message):
    with pytest.raises(ValueError, match=message):
        turn_positions_local_m(MirrorParams(**kw))
