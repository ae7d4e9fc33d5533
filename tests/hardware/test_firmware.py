"""The strobe firmware, built with avr-gcc and run in simavr 1.6: the pulse train read back from
the VCD trace the firmware declares, and its serial protocol.

Tolerances: simavr stamps VCD changes in 10 ns units, truncated, so an interval between two
edges is within 10 ns = 0.16 tick of the cycle count: EDGE_TOL_TICKS. Pulse edges are made by
Timer1; while the CPU sleeps simavr puts them on their exact cycle, while it executes (a
command being received or parsed) on the next instruction boundary (up to a few cycles late;
silicon has no such delay, the timer drives the pin). Timing checks therefore use the pulses
that lie outside the windows in which the firmware handles serial traffic (``quiet``).
"""

import numpy as np
import pytest

from scet_hardware.firmware import pulse_train, read_vcd, run_script

#: 10 ns VCD resolution in 62.5 ns ticks, and a little for float round-off.
EDGE_TOL_TICKS = 0.2
TICK_S = 1 / 16e6
DEFAULT_WIDTH, DEFAULT_PERIOD = 1600, 16636


def simulate(firmware, tmp_path, sends, until_ms):
    run = run_script(firmware, tmp_path, sends, until_ms=until_ms)
    train = pulse_train(*read_vcd(run.vcd_path))
    # Busy from the first byte of a command to the end of its reply (and the boot message).
    busy = [(0.0, 3e-3)]
    reply_times = [t for t, _ in run.lines]
    for ms, _ in sends:
        t = ms * 1e-3
        after = [r for r in reply_times if r > t]
        busy.append((t, (after[0] if after else until_ms * 1e-3) + 1e-4))
    return run, train, busy


def quiet(train, busy):
    keep = np.ones(train.rise_s.size, bool)
    for a, b in busy:
        keep &= ~((train.fall_s >= a) & (train.rise_s <= b))
    return keep


def test_default_train_is_16_pulses_of_100us_every_1039_75us(firmware, tmp_path):
    run, train, busy = simulate(firmware, tmp_path, [], until_ms=60)
    assert run.replies() == ["READY SCET-STROBE 1"]
    ok = quiet(train, busy)
    assert ok.sum() >= 50
    np.testing.assert_allclose(train.width_ticks[ok], DEFAULT_WIDTH, atol=EDGE_TOL_TICKS)
    pair = ok[1:] & ok[:-1]
    np.testing.assert_allclose(train.period_ticks[pair], DEFAULT_PERIOD, atol=EDGE_TOL_TICKS)
    # 100 us and 1039.75 us in the trace's own time unit.
    assert np.allclose(train.width_ticks[ok] * TICK_S, 100e-6, atol=EDGE_TOL_TICKS * TICK_S)
    assert np.allclose(np.diff(train.rise_s)[pair], 1039.75e-6, atol=EDGE_TOL_TICKS * TICK_S)


@pytest.mark.parametrize("shifts", [(1000, -700), (100_000, -30_000), (1, -1)])
def test_phase_trim_shifts_the_train_by_the_requested_ticks(firmware, tmp_path, shifts):
    sends = [(20.0, f"PHASE {shifts[0]}"), (60.0, f"PHASE {shifts[1]}")]
    run, train, busy = simulate(firmware, tmp_path, sends, until_ms=100)
    assert [r for r in run.replies() if r.startswith("OK PENDING")] == [
        f"OK PENDING={shifts[0]}", f"OK PENDING={shifts[1]}"]
    ok = quiet(train, busy)
    rise = train.rise_s / TICK_S
    before = ok & (train.rise_s < 20e-3)
    ref = rise[before][0]

    def offset(mask):
        k = np.round((rise[mask] - ref) / DEFAULT_PERIOD)
        return rise[mask] - (ref + k * DEFAULT_PERIOD)

    # Let the phase shift finish (a large one is spread over a few periods).
    mid = ok & (train.rise_s > 40e-3) & (train.rise_s < 60e-3)
    late = ok & (train.rise_s > 70e-3)
    np.testing.assert_allclose(offset(before), 0.0, atol=EDGE_TOL_TICKS)
    want_mid = shifts[0] % DEFAULT_PERIOD
    got_mid = offset(mid) % DEFAULT_PERIOD
    np.testing.assert_allclose(np.minimum(abs(got_mid - want_mid), DEFAULT_PERIOD - abs(got_mid - want_mid)),
                               0.0, atol=EDGE_TOL_TICKS)
    want_late = (shifts[0] + shifts[1]) % DEFAULT_PERIOD
    got_late = offset(late) % DEFAULT_PERIOD
    np.testing.assert_allclose(np.minimum(abs(got_late - want_late), DEFAULT_PERIOD - abs(got_late - want_late)),
                               0.0, atol=EDGE_TOL_TICKS)
    # The shift is real time, not a skipped pulse: the number of pulses matches it.
    n_mid = np.sum(train.rise_s < 55e-3) - np.sum(train.rise_s < 20e-3)
    expected = (35e-3 / TICK_S - shifts[0]) / DEFAULT_PERIOD
    assert abs(n_mid - expected) <= 1.0
    np.testing.assert_allclose(train.width_ticks[ok], DEFAULT_WIDTH, atol=EDGE_TOL_TICKS)


@pytest.mark.parametrize("pulses", [16, 4])
def test_single_pulse_mode_lights_one_period_per_frame(firmware, tmp_path, pulses):
    sends = [(5.0, f"SET PULSES {pulses}"), (20.0, "SET MODE SINGLE"), (100.0, "COUNT"),
             (150.0, "SET MODE BANDED"), (170.0, "COUNT")]
    run, train, busy = simulate(firmware, tmp_path, sends, until_ms=200)
    assert run.replies()[2].endswith("MODE=SINGLE RUN=1 F_CPU=16000000")
    ok = quiet(train, busy)
    single = ok & (train.rise_s > 30e-3) & (train.rise_s < 150e-3)
    assert single.sum() >= 3
    pair = single[1:] & single[:-1]
    gaps = train.period_ticks[pair]
    assert gaps.size >= 2
    np.testing.assert_allclose(gaps, pulses * DEFAULT_PERIOD, atol=EDGE_TOL_TICKS)
    np.testing.assert_allclose(train.width_ticks[single], DEFAULT_WIDTH, atol=EDGE_TOL_TICKS)
    banded = ok & (train.rise_s > 155e-3)
    pair = banded[1:] & banded[:-1]
    np.testing.assert_allclose(train.period_ticks[pair], DEFAULT_PERIOD, atol=EDGE_TOL_TICKS)
    # The frame counter advances once every `pulses` periods.
    counts = [dict(f.split("=") for f in r.split()[1:]) for r in run.replies()
              if r.startswith("OK PERIODS=")]
    periods = int(counts[1]["PERIODS"]) - int(counts[0]["PERIODS"])
    frames = int(counts[1]["FRAMES"]) - int(counts[0]["FRAMES"])
    assert periods == pytest.approx(70e-3 / (DEFAULT_PERIOD * TICK_S), abs=1)
    assert abs(periods / pulses - frames) <= 1.0


def test_width_period_and_fractional_trim(firmware, tmp_path):
    sends = [(5.0, "SET WIDTH 800"), (15.0, "SET PERIOD 20000"), (25.0, "SET TRIM 64"),
             (35.0, "GET")]
    run, train, busy = simulate(firmware, tmp_path, sends, until_ms=120)
    assert run.replies()[-1] == ("OK PULSES=16 WIDTH=800 PERIOD=20000 TRIM=64 MODE=BANDED RUN=1 "
                                 "F_CPU=16000000")
    ok = quiet(train, busy)
    late = ok & (train.rise_s > 45e-3)
    np.testing.assert_allclose(train.width_ticks[late], 800, atol=EDGE_TOL_TICKS)
    pair = late[1:] & late[:-1]
    periods = train.period_ticks[pair]
    # TRIM 64/256: one period in four is a tick longer.
    assert set(np.round(periods).astype(int)) == {20000, 20001}
    span = (train.rise_s[late][-1] - train.rise_s[late][0]) / TICK_S
    n = late.sum() - 1
    assert span / n == pytest.approx(20000.25, abs=0.3 / n + 0.01)


def test_stop_and_start(firmware, tmp_path):
    sends = [(10.0, "STOP"), (40.0, "START")]
    run, train, busy = simulate(firmware, tmp_path, sends, until_ms=60)
    assert [r.split()[-2] for r in run.replies()[1:]] == ["RUN=0", "RUN=1"]
    dark = (train.rise_s > 12e-3) & (train.rise_s < 40e-3)
    assert dark.sum() == 0
    assert np.sum(train.rise_s > 42e-3) >= 15


def test_protocol_errors_are_replies_not_silence(firmware, tmp_path):
    sends = [(2.0, "set width 10"), (4.0, "FROB"), (6.0, "SET PERIOD abc"), (8.0, "X" * 60),
             (15.0, "SET PULSES 0"), (20.0, "SET MODE STROBE"), (25.0, "PHASE"), (30.0, "ping"),
             (35.0, "SET WIDTH 16600")]
    run, _, _ = simulate(firmware, tmp_path, sends, until_ms=60)
    assert run.replies() == [
        "READY SCET-STROBE 1",
        "ERR RANGE WIDTH 64..PERIOD-128",
        "ERR UNKNOWN FROB",
        "ERR SYNTAX VALUE NOT AN INTEGER",
        "ERR LONG LINE OVER 48 CHARACTERS",
        "ERR RANGE PULSES 1..255",
        "ERR RANGE MODE BANDED|SINGLE",
        "ERR UNKNOWN PHASE",
        "OK SCET-STROBE 1",
        "ERR RANGE WIDTH 64..PERIOD-128",
    ]


def test_hex_holds_only_code_and_data(firmware):
    """The .hex flashed to the board is the ELF's .text + .data: the simavr trace section
    (.mmcu, at 0x910000) never reaches the chip."""
    top = 0
    for line in firmware["hex"].read_text().splitlines():
        count, addr, kind = int(line[1:3], 16), int(line[3:7], 16), int(line[7:9], 16)
        assert kind in (0, 1, 3), line
        if kind == 0:
            top = max(top, addr + count)
    assert 1000 < top < 32 * 1024 - 512   # fits below the Optiboot bootloader
