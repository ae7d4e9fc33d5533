"""Software phase lock (issue 13, part 2) on a simulated closed loop: the banding model's
onsets, a strobe clock off by up to -2,000 ppm (a ceramic resonator), the firmware's integer
ticks, 1/256-tick trim accumulator and one-period phase shifts (hardware.lock.FirmwareTrain)."""

import numpy as np
import pytest

from scet_hardware.lock import FirmwareTrain, lock_command, simulate_lock, split_period


def test_trim_accumulator_gives_the_fractional_period():
    # 16666 + 171/256 ticks: over 256 periods exactly 171 carry the extra tick
    tr = FirmwareTrain(16666, 171, 0.0)
    ticks = [tr.next_period_ticks() for _ in range(256)]
    assert sum(ticks) == 256 * 16666 + 171 and set(ticks) == {16666, 16667}


def test_phase_shift_is_applied_in_one_period_within_the_firmware_limits():
    tr = FirmwareTrain(16666, 0, 0.0, width_ticks=560)
    tr.pending = -20000  # more than one period can take: the rest waits
    first = tr.next_period_ticks()
    assert first == 560 + 128  # pulse width plus GAP_MIN, as strobe.c's next_top
    assert tr.pending == -20000 + (16666 - first)


@pytest.mark.parametrize("ppm", [-2000.0, -300.0, 0.0, 300.0])
def test_lock_holds_the_bands_within_a_row_for_ten_seconds(ppm):
    frames, off_rows = simulate_lock(ppm=ppm, seconds=11.0, window=10, noise_rows=0.05)
    out = np.flatnonzero(np.abs(off_rows) > 1.0)
    locked = out[-1] + 1 if out.size else 0
    # lock after the first window and its two frames of delay (12 frames, 0.2 s)
    assert locked <= 12
    held = off_rows[locked:]
    assert held.size >= 600  # 10 s of 60 Hz frames
    assert np.abs(held).max() < 1.0  # the issue's +-1 row
    if ppm == -2000.0:
        assert np.abs(off_rows[:6]).min() > 5  # unlocked, the band runs ~1 row a frame


def test_lock_command_from_measured_phases():
    # drift of -1.05 rows a frame at S = 524: the period is ~2,000 ppm short
    dt, S, M = 1 / 60, 524, 16
    period, trim = split_period(dt / M * 16e6)
    n = np.arange(10)
    ph = 3e-4 + n * (-1.0479 * dt / S)
    cmd = lock_command(ph, n, frame_period_s=dt, total_lines=S, periods_per_frame=M,
                       period_ticks=period, trim_256th=trim, target_phase_s=3e-4, next_frame=12)
    c = cmd.period_ticks + cmd.trim_256th / 256
    assert c / (period + trim / 256) == pytest.approx(1 / (1 - 2000e-6), rel=2e-6)
    # twelve frames of drift to take back, in ticks of the fast clock
    assert cmd.phase_ticks == pytest.approx(12 * 1.0479 * dt / S * 16e6 / (1 - 2e-3), abs=2)


def test_scet_strobe_lock_sends_the_law_to_the_simulated_firmware(firmware, tmp_path, capsys):
    """`scet strobe lock --timing` against the firmware in simavr: PERIOD and TRIM set to the
    law's values, the PHASE shift queued."""
    import json

    pytest.importorskip("serial", reason="could not import pyserial (extra 'hardware')")
    from scet_hardware.firmware import SimulatedBoard
    from scet_hardware.strobe import StrobeLink
    from scet_render.cli import main

    dt, S, M = 1 / 60, 524, 16
    n = np.arange(10)
    ph = (3e-4 + n * (-1.0479 * dt / S)).tolist()
    timing = tmp_path / "m.json"
    timing.write_text(json.dumps({"phase_s": ph, "phase_frames": n.tolist(), "frame_period_s": dt,
                                  "total_lines": S, "periods_per_frame": M}))
    from tests.hardware.conftest import BOOT_S

    with SimulatedBoard(firmware, tmp_path, boot_s=BOOT_S) as board:
        with StrobeLink(board.port, timeout_s=2.0) as link:
            before = link.get()
        assert main(["strobe", "lock", "--port", board.port, "--timing", str(timing),
                     "--timeout", "2"]) == 0
        with StrobeLink(board.port, timeout_s=2.0) as link:
            after = link.get()
    want = lock_command(ph, n, frame_period_s=dt, total_lines=S, periods_per_frame=M,
                        period_ticks=before.period_ticks, trim_256th=before.trim_256th,
                        target_phase_s=ph[0], next_frame=11)
    assert (after.period_ticks, after.trim_256th) == (want.period_ticks, want.trim_256th)
    assert f"PHASE {want.phase_ticks:+d} ticks" in capsys.readouterr().out
