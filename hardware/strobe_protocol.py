"""The strobe firmware's serial protocol (version 1), the host's reading of it: the reply
lines, the settings and counters they carry, and the protocol's errors; no port is opened here
(:mod:`.strobe` holds the link).

One command per line, one reply line per command (``OK ...`` or ``ERR <code> <detail>``); the
board greets with ``READY SCET-STROBE 1`` after a reset (hardware/README.md, "Serial
protocol"). Every setting is in ticks of the board's 16 MHz clock.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from .firmware import F_CPU_HZ

__all__ = ["PROTOCOL_VERSION", "BAUD", "GREETING", "StrobeError", "StrobeTimeout",
           "StrobeReplyError", "StrobeSettings", "StrobeCount", "parse_reply", "parse_settings",
           "parse_count", "parse_pending", "ticks_from_s"]

PROTOCOL_VERSION = 1
BAUD = 115_200
#: The line a board sends when its firmware starts (after every reset).
GREETING = f"READY SCET-STROBE {PROTOCOL_VERSION}"


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


def parse_pending(line: str, source: str = "strobe") -> int:
    """The phase shift still pending (ticks) from a ``PHASE`` reply (an error names the
    command, ``'PHASE'``, where the other parsers name the reply line)."""
    return int(_require(parse_reply(line, source), ("PENDING",), "PHASE", source)["PENDING"])


def ticks_from_s(seconds: float, f_cpu_hz: int = F_CPU_HZ) -> int:
    """Whole ticks nearest to ``seconds``."""
    return int(round(float(seconds) * f_cpu_hz))
