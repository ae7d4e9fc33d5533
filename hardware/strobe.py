"""The host side of the strobe firmware's serial protocol (version 1), over pyserial.

One command per line, one reply line per command (``OK ...`` or ``ERR <code> <detail>``); the
board greets with ``READY SCET-STROBE 1`` after a reset (hardware/README.md, "Serial
protocol"). Every setting is in ticks of the board's 16 MHz clock. pyserial is the optional
extra ``hardware``; it is imported when a port is opened.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

from .firmware import F_CPU_HZ

__all__ = ["PROTOCOL_VERSION", "BAUD", "StrobeError", "StrobeTimeout", "StrobeReplyError",
           "StrobeSettings", "StrobeCount", "parse_reply", "parse_settings", "parse_count",
           "StrobeLink", "ticks_from_s"]

PROTOCOL_VERSION = 1
BAUD = 115_200
_GREETING = f"READY SCET-STROBE {PROTOCOL_VERSION}"


class StrobeError(RuntimeError):
    """A reply that is not the protocol's (the message names the port and the reply)."""


class StrobeTimeout(StrobeError):
    """No (complete) reply line in time."""


class StrobeReplyError(StrobeError):
    """The board answered ``ERR``: :attr:`code` (RANGE, SYNTAX, UNKNOWN, LONG) and detail."""

    def __init__(self, message: str, code: str, detail: str):
        super().__init__(message)
        self.code, self.detail = code, detail


@dataclass(frozen=True, slots=True)
class StrobeSettings:
    """The firmware's settings, as ``GET`` reports them (ticks of ``f_cpu_hz``)."""

    pulses: int
    width_ticks: int
    period_ticks: int
    trim_256th: int
    mode: str
    running: bool
    f_cpu_hz: int = F_CPU_HZ

    @property
    def pulse_s(self) -> float:
        return self.width_ticks / self.f_cpu_hz

    @property
    def period_s(self) -> float:
        """Mean pulse period, the fractional trim included."""
        return (self.period_ticks + self.trim_256th / 256) / self.f_cpu_hz

    @property
    def frame_s(self) -> float:
        return self.pulses * self.period_s

    def to_dict(self) -> dict:
        return {"pulses": self.pulses, "width_ticks": self.width_ticks,
                "period_ticks": self.period_ticks, "trim_256th": self.trim_256th,
                "mode": self.mode, "running": self.running, "f_cpu_hz": self.f_cpu_hz}


@dataclass(frozen=True, slots=True)
class StrobeCount:
    """``COUNT``: periods and frames since power-up, phase shift still to apply (ticks)."""

    periods: int
    frames: int
    pending_ticks: int


_FIELD = re.compile(r"([A-Z_]+)=(-?\d+|[A-Z]+)")


def parse_reply(line: str, source: str = "strobe") -> dict:
    """The ``KEY=VALUE`` fields of an ``OK`` reply line.

    Raises
    ------
    StrobeReplyError
        An ``ERR`` reply.
    StrobeError
        Anything else that is not ``OK`` followed by well-formed fields.
    """
    text = line.strip()
    if text.startswith("ERR"):
        parts = text.split(" ", 2)
        code = parts[1] if len(parts) > 1 else "?"
        detail = parts[2] if len(parts) > 2 else ""
        raise StrobeReplyError(f"{source}: the board refused the command: {text}", code, detail)
    words = text.split(" ")
    if words[0] != "OK":
        raise StrobeError(f"{source}: malformed reply {line!r} (expected 'OK ...' or 'ERR ...')")
    out = {}
    for w in words[1:]:
        m = _FIELD.fullmatch(w)
        if m is None:
            raise StrobeError(f"{source}: malformed field {w!r} in reply {line!r}")
        out[m.group(1)] = m.group(2)
    return out


def _require(fields: dict, keys, line: str, source: str, numeric=True) -> dict:
    out = {}
    for k in keys:
        if k not in fields:
            raise StrobeError(f"{source}: reply {line!r} lacks key {k!r}")
        v = fields[k]
        if numeric:
            if not re.fullmatch(r"-?\d+", v):
                raise StrobeError(f"{source}: key {k!r} of reply {line!r} is not an integer")
            v = int(v)
        out[k] = v
    return out


def parse_settings(line: str, source: str = "strobe") -> StrobeSettings:
    """A :class:`StrobeSettings` from a ``GET`` (or ``SET``) reply."""
    f = parse_reply(line, source)
    n = _require(f, ("PULSES", "WIDTH", "PERIOD", "TRIM", "RUN", "F_CPU"), line, source)
    mode = _require(f, ("MODE",), line, source, numeric=False)["MODE"]
    if mode not in ("BANDED", "SINGLE"):
        raise StrobeError(f"{source}: key 'MODE' of reply {line!r} is {mode!r}, expected BANDED or SINGLE")
    return StrobeSettings(n["PULSES"], n["WIDTH"], n["PERIOD"], n["TRIM"], mode.lower(),
                          bool(n["RUN"]), n["F_CPU"])


def parse_count(line: str, source: str = "strobe") -> StrobeCount:
    n = _require(parse_reply(line, source), ("PERIODS", "FRAMES", "PENDING"), line, source)
    return StrobeCount(n["PERIODS"], n["FRAMES"], n["PENDING"])


def ticks_from_s(seconds: float, f_cpu_hz: int = F_CPU_HZ) -> int:
    """Whole ticks nearest to ``seconds``."""
    return int(round(float(seconds) * f_cpu_hz))


class StrobeLink:
    """A serial connection to the strobe board.

    Parameters
    ----------
    port : str
        Serial device (``/dev/ttyACM0``, ``/dev/ttyUSB0``, a pseudo-terminal of the simulator).
    timeout_s : float
        How long to wait for a reply line.
    wait_ready_s : float
        Opening an Arduino's port resets it: wait this long for its ``READY`` line (0: do
        not wait, e.g. on a port that does not reset).
    """

    def __init__(self, port: str, *, timeout_s: float = 1.0, wait_ready_s: float = 0.0,
                 serial_factory=None):
        if serial_factory is None:
            try:
                import serial
            except ImportError:
                raise StrobeError("pyserial is not installed: pip install 'scet[hardware]'") from None
            serial_factory = serial.Serial
        self.port = port
        self.timeout_s = float(timeout_s)
        try:
            self._ser = serial_factory(port, BAUD, timeout=0.05)
        except (OSError, ValueError) as exc:
            raise StrobeError(f"{port}: cannot open the serial port ({exc})") from None
        self._buf = b""
        if wait_ready_s > 0:
            line = self._read_line(wait_ready_s)
            if line != _GREETING:
                raise StrobeError(f"{port}: expected the greeting {_GREETING!r} after reset, got {line!r}")

    def close(self) -> None:
        self._ser.close()

    def __enter__(self) -> "StrobeLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _read_line(self, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            if time.monotonic() > deadline:
                partial = self._buf.decode("ascii", "replace")
                self._buf = b""
                raise StrobeTimeout(f"{self.port}: no reply within {timeout_s:g} s"
                                    + (f" (partial line {partial!r})" if partial else ""))
            chunk = self._ser.read(256)
            if chunk:
                self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        try:
            return line.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            raise StrobeError(f"{self.port}: reply {line!r} is not ASCII (wrong baud rate?)") from None

    def command(self, text: str) -> str:
        """Send one command line and return its reply line (the greeting of a board that
        reset, or its tail, is skipped)."""
        if "\n" in text or "\r" in text:
            raise ValueError(f"command {text!r}: one line, without line breaks")
        self._ser.reset_input_buffer()
        self._buf = b""
        self._ser.write(text.encode("ascii") + b"\n")
        line = self._read_line(self.timeout_s)
        # A board that reset (opening an Arduino's port does) greets; the port may also have
        # been opened in the middle of the greeting, leaving its tail.
        while line and _GREETING.endswith(line):
            line = self._read_line(self.timeout_s)
        return line

    def ping(self) -> None:
        line = self.command("PING")
        if line != f"OK SCET-STROBE {PROTOCOL_VERSION}":
            parse_reply(line, self.port)
            raise StrobeError(f"{self.port}: PING answered {line!r}; this host speaks protocol "
                              f"{PROTOCOL_VERSION}")

    def get(self) -> StrobeSettings:
        return parse_settings(self.command("GET"), self.port)

    def set(self, key: str, value) -> StrobeSettings:
        """``SET KEY VALUE`` (PULSES, WIDTH, PERIOD, TRIM in ticks or 1/256 tick; MODE
        banded/single); the settings after it."""
        key = str(key).upper()
        if isinstance(value, bool) or (key != "MODE" and not isinstance(value, int)):
            raise ValueError(f"SET {key}: expected an integer, got {value!r}")
        return parse_settings(self.command(f"SET {key} {str(value).upper()}"), self.port)

    def apply(self, *, pulses=None, width_ticks=None, period_ticks=None, trim_256th=None,
              mode=None) -> StrobeSettings:
        """Several settings at once (the period before the width when it grows, so that every
        intermediate state is valid); the settings after them."""
        settings = self.get()
        steps = []
        if pulses is not None:
            steps.append(("PULSES", int(pulses)))
        if period_ticks is not None and width_ticks is not None and width_ticks > settings.width_ticks:
            steps += [("PERIOD", int(period_ticks)), ("WIDTH", int(width_ticks))]
        else:
            if width_ticks is not None:
                steps.append(("WIDTH", int(width_ticks)))
            if period_ticks is not None:
                steps.append(("PERIOD", int(period_ticks)))
        if trim_256th is not None:
            steps.append(("TRIM", int(trim_256th)))
        if mode is not None:
            steps.append(("MODE", str(mode)))
        for key, value in steps:
            settings = self.set(key, value)
        return settings

    def shift_phase(self, ticks: int) -> int:
        """Delay (positive) or advance the pulse train by ``ticks``; the shift still pending."""
        return int(_require(parse_reply(self.command(f"PHASE {int(ticks)}"), self.port),
                            ("PENDING",), "PHASE", self.port)["PENDING"])

    def count(self) -> StrobeCount:
        return parse_count(self.command("COUNT"), self.port)

    def wait_phase_applied(self, timeout_s: float = 2.0) -> StrobeCount:
        """Poll ``COUNT`` until no phase shift is pending (the lock loop's next measurement
        may start then)."""
        deadline = time.monotonic() + timeout_s
        while True:
            c = self.count()
            if c.pending_ticks == 0:
                return c
            if time.monotonic() > deadline:
                raise StrobeTimeout(f"{self.port}: {c.pending_ticks} ticks of phase shift still "
                                    f"pending after {timeout_s:g} s")
            time.sleep(0.01)

    def run(self, on: bool) -> StrobeSettings:
        return parse_settings(self.command("START" if on else "STOP"), self.port)
