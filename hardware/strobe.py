"""The host side of the strobe firmware's serial protocol (version 1,
:mod:`.strobe_protocol`), over pyserial: :class:`StrobeLink`, one connection for a whole run,
and the settings file it restores after a reset. pyserial is the optional extra
``hardware``; it is imported when a port is opened.

Resets. Opening an Uno's port resets it: its USB-serial chip (ATmega16U2) drives the 328P's
RESET through a 100 nF capacitor from DTR, which the host raises on open, and the Optiboot
bootloader then waits about a second for an upload (its 1 s watchdog) before the firmware
starts; bytes sent meanwhile go to the bootloader. :class:`StrobeLink` therefore

* handshakes on every open: it sends ``PING`` every 0.25 s until the firmware answers (a
  reset board greets first), for up to ``boot_s`` (default 3 s); an answer of another
  protocol version, or none, is an error naming the port;
* clears HUPCL on the port (``keep_dtr``): Linux drops DTR on the last close only when HUPCL
  is set (termios(3), ``stty -hupcl``), so with it cleared DTR stays high after the first
  session and later opens do not reset the board (pyserial has no switch for it: its
  ``dsrdtr`` is flow control and DTR is raised on every open);
* keeps the wanted settings in a settings file (:class:`SettingsStore`) and re-applies and
  verifies them after every handshake, so ``scet strobe set`` followed by ``scet strobe get``
  reads the set values even where each open resets the board (the train's phase is lost in a
  reset whatever the host does: the phase lock re-acquires it). A settings file on the host,
  not EEPROM: it needs no firmware change and no EEPROM writes per run, survives reflashing,
  and the host must re-lock the phase after a reset anyway;
* recovers in the middle of a session: a board that greets again (it reset: brown-out,
  watchdog) or goes silent for longer than a reply takes and then greets, and a port that
  fails (a USB glitch: the device node goes and comes back) are reconnected, the settings
  re-applied and the command sent again; :attr:`StrobeLink.resets` counts them and
  ``on_reset`` is called (the phase lock starts over).
"""

from __future__ import annotations

import json
import logging
import re
import time
from pathlib import Path

from .strobe_protocol import (BAUD, GREETING, PROTOCOL_VERSION, StrobeCount, StrobeError,
                              StrobeReplyError, StrobeSettings, StrobeTimeout, parse_count,
                              parse_pending, parse_reply, parse_settings, ticks_from_s)

log = logging.getLogger(__name__)

# The protocol's names are re-exported: callers import the link and its errors from here.
__all__ = ["PROTOCOL_VERSION", "BAUD", "BOOT_S", "StrobeError", "StrobeTimeout",
           "StrobeReplyError", "StrobeSettings", "StrobeCount", "parse_reply", "parse_settings",
           "parse_count", "SettingsStore", "StrobeLink", "ticks_from_s"]

#: How long a reset board may take to answer: Optiboot's 1 s watchdog wait (optiboot.c,
#: WATCHDOG_1S), the 16U2's USB re-enumeration after a glitch, and margin.
BOOT_S = 3.0
#: Interval of the handshake's PINGs (bytes sent to the bootloader are lost, so it repeats).
PING_INTERVAL_S = 0.25


class _BoardReset(Exception):
    """A greeting where a reply was due (internal)."""


class _PortFailed(Exception):
    """The serial port raised (internal): the device went away."""


class SettingsStore:
    """The wanted firmware settings on the host: a small JSON file
    (``{"format": "scet-strobe-settings", "version": 1, "settings": {...}}``) that
    :class:`StrobeLink` re-applies after every reset. ``path`` None keeps nothing."""

    FORMAT, VERSION = "scet-strobe-settings", 1

    def __init__(self, path):
        self.path = None if path is None else Path(path)

    def load(self) -> dict | None:
        if self.path is None or not self.path.is_file():
            return None
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise StrobeError(f"{self.path}: cannot read the strobe settings ({exc})") from None
        keys = ("pulses", "width_ticks", "period_ticks", "trim_256th", "mode")
        if not (isinstance(doc, dict) and doc.get("format") == self.FORMAT
                and doc.get("version") == self.VERSION and isinstance(doc.get("settings"), dict)):
            raise StrobeError(f"{self.path}: not a {self.FORMAT} version {self.VERSION} file")
        st = doc["settings"]
        for k in keys:
            v = st.get(k)
            if (k == "mode" and v not in ("banded", "single")) or (
                    k != "mode" and (not isinstance(v, int) or isinstance(v, bool))):
                raise StrobeError(f"{self.path}: key 'settings.{k}' missing or invalid ({v!r})")
        return {k: st[k] for k in keys}

    def save(self, settings: StrobeSettings) -> None:
        if self.path is None:
            return
        from estimator.formats import atomic_write

        d = settings.to_dict()
        doc = {"format": self.FORMAT, "version": self.VERSION,
               "settings": {k: d[k] for k in ("pulses", "width_ticks", "period_ticks", "trim_256th", "mode")}}
        try:
            atomic_write(self.path, json.dumps(doc, indent=1, sort_keys=True) + "\n")
        except OSError as exc:
            raise StrobeError(f"{self.path}: cannot write the strobe settings ({exc.strerror})") from None


def _matches(settings: StrobeSettings, wanted: dict) -> bool:
    d = settings.to_dict()
    return all(d[k] == v for k, v in wanted.items())


class StrobeLink:
    """One connection to the strobe board for a whole run (module docstring: resets).

    Parameters
    ----------
    port : str
        Serial device (``/dev/ttyACM0``, ``/dev/ttyUSB0``, a pseudo-terminal of the simulator).
    timeout_s : float
        How long to wait for a reply line.
    boot_s : float
        How long the handshake after opening may take (a reset board answers after its
        bootloader, about 1 s on an Uno).
    keep_dtr : bool
        Clear HUPCL so that closing the port does not drop DTR (later opens do not reset).
    settings : path or None
        The settings file re-applied after every reset (:class:`SettingsStore`).
    reconnect_s : float
        How long to keep trying to reopen a port that failed (a USB glitch).
    on_reset : callable, optional
        Called with no argument after the board was found reset and its settings restored.
    """

    def __init__(self, port: str, *, timeout_s: float = 1.0, boot_s: float = BOOT_S,
                 keep_dtr: bool = True, settings=None, reconnect_s: float = 5.0,
                 on_reset=None, serial_factory=None):
        if serial_factory is None:
            try:
                import serial
            except ImportError:
                raise StrobeError("pyserial is not installed: pip install 'scet[hardware]'") from None
            serial_factory = serial.Serial
        self.port = port
        self.timeout_s = float(timeout_s)
        self.boot_s = float(boot_s)
        self.keep_dtr = bool(keep_dtr)
        self.store = settings if isinstance(settings, SettingsStore) else SettingsStore(settings)
        self.reconnect_s = float(reconnect_s)
        self.on_reset = on_reset
        self.resets = 0          # resets seen (greetings), the one of opening included
        self.reconnects = 0      # ports reopened after an error
        self._factory = serial_factory
        self._ser = None
        self._buf = b""
        self._connect()

    # ------------------------------------------------------------------ connection
    def _open(self) -> None:
        try:
            self._ser = self._factory(self.port, BAUD, timeout=0.05)
        except (OSError, ValueError) as exc:
            raise StrobeError(f"{self.port}: cannot open the serial port ({exc})") from None
        self._buf = b""
        if self.keep_dtr:
            try:
                import termios

                fd = self._ser.fileno()
                attrs = termios.tcgetattr(fd)
                attrs[2] &= ~termios.HUPCL
                termios.tcsetattr(fd, termios.TCSANOW, attrs)
            except (ImportError, OSError, AttributeError, ValueError) as exc:
                log.info("%s: cannot clear HUPCL (%s); each open may reset the board", self.port, exc)

    def _handshake(self) -> None:
        """PING until the firmware answers (module docstring); a greeting counts a reset."""
        deadline = time.monotonic() + self.boot_s
        other = None
        while True:
            self._write("PING")
            until = min(time.monotonic() + PING_INTERVAL_S, deadline)
            while time.monotonic() < until:
                try:
                    line = self._read_line(max(until - time.monotonic(), 0.0))
                except StrobeTimeout:
                    break
                if line == GREETING:
                    self.resets += 1
                    log.info("%s: the board reset (greeting)", self.port)
                    until = min(time.monotonic() + PING_INTERVAL_S, deadline)
                    self._write("PING")
                    continue
                m = re.fullmatch(r"OK SCET-STROBE (\S+)", line)
                if m:
                    if m.group(1) != str(PROTOCOL_VERSION):
                        raise StrobeError(f"{self.port}: the firmware speaks protocol {m.group(1)}, "
                                          f"this host {PROTOCOL_VERSION}: flash "
                                          "hardware/firmware/build/strobe.hex (hardware/README.md)")
                    return
                if line and not line.startswith("ERR") and not GREETING.endswith(line):
                    other = line
            if time.monotonic() >= deadline:
                got = f"; it sent {other!r}" if other else "; it sent nothing"
                raise StrobeError(f"{self.port}: no SCET strobe firmware answered within "
                                  f"{self.boot_s:g} s{got} (another device, or the firmware not "
                                  "flashed: hardware/README.md)")

    def _restore(self) -> None:
        """Re-apply the settings file's settings, and verify them."""
        wanted = self.store.load()
        if wanted is None:
            return
        now = parse_settings(self._command_once("GET"), self.port)
        if _matches(now, wanted):
            return
        self._apply(now, **wanted)
        now = parse_settings(self._command_once("GET"), self.port)
        if not _matches(now, wanted):
            raise StrobeError(f"{self.port}: the board did not keep the settings of "
                              f"{self.store.path}: it reports {now.to_dict()}")
        log.info("%s: settings of %s restored", self.port, self.store.path)

    def _connect(self) -> None:
        self._open()
        try:
            self._handshake()
            self._restore()
        except (_BoardReset, _PortFailed) as exc:
            self.close()
            raise StrobeError(f"{self.port}: the board reset or the port failed during the "
                              f"handshake ({type(exc).__name__.strip('_')} {exc})") from None
        except BaseException:
            self.close()
            raise

    def _reconnect(self, why: str) -> None:
        """Reopen the port (retrying while the device is away), handshake, restore."""
        log.warning("%s: %s; reconnecting", self.port, why)
        self.close()
        deadline = time.monotonic() + self.reconnect_s
        while True:
            try:
                self._connect()
                break
            except StrobeError as exc:
                if time.monotonic() > deadline:
                    raise StrobeError(f"{self.port}: lost the board ({why}) and could not "
                                      f"reconnect within {self.reconnect_s:g} s: {exc}") from None
                time.sleep(0.1)
        self.reconnects += 1
        if self.on_reset is not None:
            self.on_reset()

    def _after_greeting(self) -> None:
        """The board reset in the middle of a session: wait it out, restore the settings."""
        self.resets += 1
        log.warning("%s: the board reset during the session", self.port)
        self._handshake()
        self._restore()
        if self.on_reset is not None:
            self.on_reset()

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except OSError:
                pass
        self._ser = None

    def __enter__(self) -> "StrobeLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ lines
    def _write(self, text: str) -> None:
        try:
            self._ser.write(text.encode("ascii") + b"\n")
        except (OSError, ValueError) as exc:
            raise _PortFailed(str(exc)) from None

    def _read_line(self, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            if time.monotonic() > deadline:
                partial = self._buf.decode("ascii", "replace")
                self._buf = b""
                exc = StrobeTimeout(f"{self.port}: no reply within {timeout_s:g} s"
                                    + (f" (partial line {partial!r})" if partial else ""))
                exc.partial = partial
                raise exc
            try:
                chunk = self._ser.read(256)
            except (OSError, ValueError) as exc:
                raise _PortFailed(str(exc)) from None
            if chunk:
                self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        try:
            return line.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            raise StrobeError(f"{self.port}: reply {line!r} is not ASCII (wrong baud rate?)") from None

    def _command_once(self, text: str) -> str:
        try:
            # What came in between commands: only a greeting is expected (a reset while idle,
            # whose settings must be restored before anything else).
            waiting = self._ser.in_waiting
            stale = self._buf + (self._ser.read(waiting) if waiting else b"")
        except (OSError, ValueError) as exc:
            raise _PortFailed(str(exc)) from None
        if GREETING.encode() in stale:
            self._buf = b""
            raise _BoardReset()
        self._buf = b""
        self._write(text)
        line = self._read_line(self.timeout_s)
        if line == GREETING:
            raise _BoardReset()
        # The port may have been opened in the middle of a greeting, leaving its tail.
        while line and GREETING.endswith(line):
            line = self._read_line(self.timeout_s)
        return line

    def command(self, text: str) -> str:
        """Send one command line and return its reply line; a board that reset or a port that
        failed in between is recovered (module docstring) and the command sent again once."""
        if "\n" in text or "\r" in text:
            raise ValueError(f"command {text!r}: one line, without line breaks")
        for attempt in (0, 1):
            try:
                return self._command_once(text)
            except _BoardReset:
                self._after_greeting()
            except _PortFailed as exc:
                self._reconnect(f"the port failed ({exc})")
            except StrobeTimeout as first:
                if attempt:
                    raise
                partial = getattr(first, "partial", "")
                # Silent: a board in its bootloader after a reset greets within boot_s.
                try:
                    line = self._read_line(self.boot_s)
                except StrobeTimeout:
                    raise StrobeTimeout(f"{self.port}: no reply to {text!r} within "
                                        f"{self.timeout_s:g} s"
                                        + (f" (partial line {partial!r})" if partial else "")
                                        + f", nor a greeting within a further {self.boot_s:g} s") from None
                except _PortFailed as exc:
                    self._reconnect(f"the port failed ({exc})")
                    continue
                if line != GREETING:
                    raise StrobeError(f"{self.port}: reply {line!r} to {text!r} came late "
                                      f"(after {self.timeout_s:g} s)")
                self._after_greeting()
        raise StrobeError(f"{self.port}: the board reset again while {text!r} was sent")

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
        settings = parse_settings(self.command(f"SET {key} {str(value).upper()}"), self.port)
        self.store.save(settings)
        return settings

    def apply(self, *, pulses=None, width_ticks=None, period_ticks=None, trim_256th=None,
              mode=None, remember: bool = True) -> StrobeSettings:
        """Several settings at once (the period before the width when it grows, so that every
        intermediate state is valid); the settings after them, also written to the settings
        file (``remember``) so that a reset board gets them back."""
        for attempt in (0, 1):
            try:
                settings = self._apply(self.get(), pulses=pulses, width_ticks=width_ticks,
                                       period_ticks=period_ticks, trim_256th=trim_256th, mode=mode)
                break
            except _BoardReset:       # reset between two SETs: restore, then apply again
                self._after_greeting()
            except _PortFailed as exc:
                self._reconnect(f"the port failed ({exc})")
        else:
            raise StrobeError(f"{self.port}: the board reset again while the settings were applied")
        if remember:
            self.store.save(settings)
        return settings

    def _apply(self, settings: StrobeSettings, *, pulses=None, width_ticks=None,
               period_ticks=None, trim_256th=None, mode=None) -> StrobeSettings:
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
            settings = parse_settings(self._command_once(f"SET {key} {str(value).upper()}"), self.port)
        return settings

    def shift_phase(self, ticks: int) -> int:
        """Delay (positive) or advance the pulse train by ``ticks``; the shift still pending."""
        return parse_pending(self.command(f"PHASE {int(ticks)}"), self.port)

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
