"""The host side of the strobe protocol against the firmware running in simavr behind a
pseudo-terminal (real time), and against a bare pseudo-terminal for what a healthy board never
sends (malformed replies, silence)."""

import os
import threading

import pytest

serial = pytest.importorskip("serial", reason="could not import pyserial (extra 'hardware')")

from scet_hardware.firmware import SimulatedBoard, pulse_train, read_vcd
from scet_hardware.strobe import (StrobeError, StrobeLink, StrobeReplyError, StrobeTimeout,
                                  parse_count, parse_reply, parse_settings)


@pytest.fixture()
def board(firmware, tmp_path):
    with SimulatedBoard(firmware, tmp_path) as b:
        yield b


def test_settings_round_trip_through_the_simulated_board(board):
    with StrobeLink(board.port, timeout_s=2.0) as link:
        link.ping()
        s = link.get()
        assert (s.pulses, s.width_ticks, s.period_ticks, s.mode, s.running) == (16, 1600, 16636, "banded", True)
        assert s.period_s == pytest.approx(1039.75e-6, abs=1e-12)
        s = link.apply(pulses=8, width_ticks=4000, period_ticks=33272, trim_256th=-3, mode="single")
        assert (s.pulses, s.width_ticks, s.period_ticks, s.trim_256th, s.mode) == (8, 4000, 33272, -3, "single")
        assert link.get() == s
        with pytest.raises(StrobeReplyError) as err:
            link.set("WIDTH", 10)
        assert err.value.code == "RANGE"
        assert link.shift_phase(500) == 500
        c = link.wait_phase_applied(timeout_s=2.0)
        assert c.pending_ticks == 0 and c.periods > 0


def test_the_phase_lock_commands_move_the_real_train(board):
    with StrobeLink(board.port, timeout_s=2.0) as link:
        link.ping()
        link.shift_phase(8000)
        link.wait_phase_applied()
        link.run(False)
    board.close()
    train = pulse_train(*read_vcd(board.vcd_path))
    periods = train.period_ticks
    # Exactly one period carries the +8000 ticks (instruction-boundary jitter < 5 ticks while
    # the CPU handles serial traffic, see test_firmware).
    assert ((periods > 16636 + 8000 - 5) & (periods < 16636 + 8000 + 5)).sum() == 1


def test_transcript_lines_parse(firmware, tmp_path):
    from scet_hardware.firmware import run_script

    run = run_script(firmware, tmp_path, [(1, "GET"), (12, "COUNT"), (20, "SET MODE SINGLE")],
                     until_ms=40)
    get, count, single = run.replies()[1:]
    assert parse_settings(get).period_ticks == 16636
    assert parse_count(count).periods >= 10
    assert parse_settings(single).mode == "single"


@pytest.mark.parametrize("line, message", [
    ("OK PULSES=16 WIDTH=1600", "lacks key 'PERIOD'"),
    ("OK PULSES=16 WIDTH=16x0 PERIOD=1 TRIM=0 MODE=BANDED RUN=1 F_CPU=16000000", "malformed field"),
    ("HELLO", "malformed reply"),
    ("OK PULSES=16 WIDTH=1 PERIOD=1 TRIM=0 MODE=STROBE RUN=1 F_CPU=1", "key 'MODE'"),
])
def test_malformed_replies_are_named(line, message):
    with pytest.raises(StrobeError, match=message):
        parse_settings(line, "COM9")


def test_err_replies_carry_code_and_detail():
    with pytest.raises(StrobeReplyError) as err:
        parse_reply("ERR RANGE WIDTH 64..PERIOD-128")
    assert (err.value.code, err.value.detail) == ("RANGE", "WIDTH 64..PERIOD-128")


def _fake_port():
    master, slave = os.openpty()
    return master, os.ttyname(slave), slave


def test_silence_is_a_timeout_naming_the_port():
    master, name, slave = _fake_port()
    try:
        with StrobeLink(name, timeout_s=0.3) as link:
            with pytest.raises(StrobeTimeout, match=f"{name}: no reply within 0.3 s"):
                link.get()
    finally:
        os.close(master)
        os.close(slave)


def test_garbage_and_partial_lines():
    master, name, slave = _fake_port()

    def answer(data):
        os.read(master, 64)
        os.write(master, data)

    try:
        with StrobeLink(name, timeout_s=0.5) as link:
            t = threading.Thread(target=answer, args=(b"\xff\xfe\x00\n",))
            t.start()
            with pytest.raises(StrobeError, match="not ASCII"):
                link.get()
            t.join()
            t = threading.Thread(target=answer, args=(b"OK PULSES=1",))
            t.start()
            with pytest.raises(StrobeTimeout, match="partial line 'OK PULSES=1'"):
                link.get()
            t.join()
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port():
    with pytest.raises(StrobeError, match="/nonexistent/tty: cannot open"):
        StrobeLink("/nonexistent/tty")
