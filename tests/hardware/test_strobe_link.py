"""The host side of the strobe protocol against the firmware running in simavr behind a
pseudo-terminal (real time) that resets as an Uno does (on open, mid-session, on a replug),
and against a bare pseudo-terminal for what a healthy board never sends (malformed replies,
silence, another device, another protocol version)."""

import os
import threading

import pytest

serial = pytest.importorskip("serial", reason="could not import pyserial (extra 'hardware')")

from scet_hardware.firmware import SimulatedBoard, pulse_train, read_vcd
from scet_hardware.strobe import (StrobeError, StrobeLink, StrobeReplyError, StrobeTimeout,
                                  parse_count, parse_reply, parse_settings)
from tests.hardware.conftest import BOOT_S


@pytest.fixture()
def board(firmware, tmp_path):
    with SimulatedBoard(firmware, tmp_path, boot_s=BOOT_S) as b:
        yield b


def test_opening_resets_the_board_and_the_link_waits_it_out(board):
    # The first open raises DTR: the board resets, the bootloader swallows the first PINGs.
    import time

    t = time.monotonic()
    with StrobeLink(board.port, boot_s=3.0) as link:
        took = time.monotonic() - t
        assert link.resets == 1
        assert link.get().pulses == 16
    assert took >= BOOT_S          # the handshake waited for the bootloader


def test_settings_survive_a_reset_on_every_open(board, tmp_path):
    # HUPCL left set: every close drops DTR and every open resets (issue 32, item 2).
    store = tmp_path / "settings.json"
    with StrobeLink(board.port, keep_dtr=False, settings=store) as link:
        link.apply(pulses=8, trim_256th=89, mode="single")
    with StrobeLink(board.port, keep_dtr=False) as link:       # no settings file: defaults
        assert link.resets == 1
        assert (link.get().pulses, link.get().trim_256th) == (16, 0)
    with StrobeLink(board.port, keep_dtr=False, settings=store) as link:
        assert link.resets == 1
        s = link.get()
        assert (s.pulses, s.trim_256th, s.mode) == (8, 89, "single")


def test_a_cleared_hupcl_keeps_the_board_from_resetting(board):
    with StrobeLink(board.port) as link:                        # keep_dtr: HUPCL cleared
        assert link.resets == 1
        link.apply(pulses=9, remember=False)
    with StrobeLink(board.port) as link:
        assert link.resets == 0 and link.get().pulses == 9


def test_a_reset_in_the_middle_of_a_session_is_recovered(board, tmp_path):
    import time

    calls = []
    with StrobeLink(board.port, settings=tmp_path / "s.json", on_reset=lambda: calls.append(1)) as link:
        link.apply(width_ticks=2000)
        board.reset()
        time.sleep(0.05)
        assert link.get().width_ticks == 2000       # restored from the settings file
        assert link.resets == 2 and calls == [1]
        assert link.count().periods < 16 * 60       # counting anew: the board did reset


def test_a_replugged_board_is_reconnected(board, tmp_path):
    import time

    with StrobeLink(board.port, settings=tmp_path / "s.json") as link:
        link.apply(pulses=12)
        board.replug()
        time.sleep(0.1)
        assert link.get().pulses == 12
        assert link.reconnects == 1


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


class FakeDevice:
    """A bare pseudo-terminal answering each line it receives from a list of replies (None:
    silence); what a healthy board never sends."""

    def __init__(self, replies):
        self.master, self.slave = os.openpty()
        self.name = os.ttyname(self.slave)
        self.replies = list(replies)
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        import select

        buf = b""
        while not self._stop:
            r, _, _ = select.select([self.master], [], [], 0.02)
            if not r:
                continue
            buf += os.read(self.master, 256)
            while b"\n" in buf:
                _, _, buf = buf.partition(b"\n")
                reply = self.replies.pop(0) if self.replies else None
                if reply is not None:
                    os.write(self.master, reply)

    def close(self):
        self._stop = True
        self._thread.join()
        os.close(self.master)
        os.close(self.slave)


def test_silence_is_a_timeout_naming_the_port():
    dev = FakeDevice([b"OK SCET-STROBE 1\n"])
    try:
        with StrobeLink(dev.name, timeout_s=0.3, boot_s=0.3) as link:
            with pytest.raises(StrobeTimeout, match=f"{dev.name}: no reply to 'GET' within 0.3 s"):
                link.get()
    finally:
        dev.close()


def test_garbage_and_partial_lines():
    dev = FakeDevice([b"OK SCET-STROBE 1\n", b"\xff\xfe\x00\n", b"OK PULSES=1"])
    try:
        with StrobeLink(dev.name, timeout_s=0.5, boot_s=0.3) as link:
            with pytest.raises(StrobeError, match="not ASCII"):
                link.get()
            with pytest.raises(StrobeError, match="OK PULSES=1"):
                link.get()
    finally:
        dev.close()


@pytest.mark.parametrize("replies, message", [
    ([b"HELLO FROM A GPS\n"] * 20, "no SCET strobe firmware answered within 0.6 s; it sent "
                                    "'HELLO FROM A GPS'"),
    ([], "no SCET strobe firmware answered within 0.6 s; it sent nothing"),
    ([b"OK SCET-STROBE 2\n"], "the firmware speaks protocol 2, this host 1"),
])
def test_not_this_firmware_is_one_clear_error(replies, message, capsys):
    from scet_render.cli import main

    dev = FakeDevice(replies)
    try:
        with pytest.raises(StrobeError, match=message):
            StrobeLink(dev.name, boot_s=0.6)
        dev.replies = list(replies)
        assert main(["strobe", "get", "--port", dev.name, "--boot-s", "0.6"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and dev.name in err[0]
    finally:
        dev.close()


def test_missing_port():
    with pytest.raises(StrobeError, match="/nonexistent/tty: cannot open"):
        StrobeLink("/nonexistent/tty")
