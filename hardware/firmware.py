"""Building the strobe firmware and running it in simavr: the ``make firmware`` build, the
simulator harness, and the pulse train read back from the VCD trace the firmware declares.

The firmware (``firmware/strobe.c``) drives OC1B (PB2, Arduino D10) from Timer1 in Fast PWM
mode; the harness (``firmware/sim/simstrobe.c``) runs it in simavr 1.6 (libsimavr) with the UART
on a script or a pseudo-terminal. Ticks are 16 MHz clock cycles (62.5 ns).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["F_CPU_HZ", "FIRMWARE_DIR", "FirmwareError", "Toolchain", "find_toolchain",
           "build_firmware", "SimRun", "run_script", "SimulatedBoard", "read_vcd", "PulseTrain",
           "pulse_train"]

#: The board's clock: every firmware setting is in ticks of it.
F_CPU_HZ = 16_000_000
#: The firmware sources (installed with the package).
FIRMWARE_DIR = Path(__file__).resolve().parent / "firmware"
_VCD_NAME = "strobe.vcd"


class FirmwareError(RuntimeError):
    """The toolchain is missing, the build failed, or the simulation did not run."""


@dataclass(frozen=True, slots=True)
class Toolchain:
    """Which tools were found: the firmware needs ``avr-gcc``; the simulator ``simavr``'s
    header and library too. ``missing`` names what is absent (empty when complete)."""

    avr_gcc: str | None
    make: str | None
    simavr_header: bool
    simavr_library: bool

    @property
    def missing(self) -> list[str]:
        out = []
        if not self.avr_gcc:
            out.append("avr-gcc (Debian: gcc-avr avr-libc)")
        if not self.make:
            out.append("make")
        if not self.simavr_header:
            out.append("/usr/include/simavr/avr/avr_mcu_section.h (Debian: libsimavr-dev)")
        if not self.simavr_library:
            out.append("libsimavr.so.2 (Debian: libsimavr2)")
        return out


def find_toolchain() -> Toolchain:
    libs = list(Path("/usr/lib").glob("*/libsimavr.so.2")) + list(Path("/usr/lib").glob("libsimavr.so.2"))
    return Toolchain(shutil.which("avr-gcc"), shutil.which("make"),
                     Path("/usr/include/simavr/avr/avr_mcu_section.h").is_file(), bool(libs))


def build_firmware(out_dir, *, sim: bool = True) -> dict:
    """Build ``strobe.elf`` and ``strobe.hex`` (and the harness ``simstrobe`` with ``sim``)
    into ``out_dir``; the paths built, by name.

    Raises
    ------
    FirmwareError
        A tool is missing or the build fails (the message holds the compiler's output).
    """
    tools = find_toolchain()
    need = tools.missing if sim else [m for m in tools.missing if "simavr" not in m]
    if need:
        raise FirmwareError("cannot build the firmware, missing: " + "; ".join(need)
                            + " (run tools/install-avr.sh as root)")
    out = Path(out_dir).resolve()
    cmd = [tools.make, "-s", "-C", str(FIRMWARE_DIR), f"OUT={out}", "sim" if sim else "all"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise FirmwareError(f"firmware build failed ({' '.join(cmd)}):\n{proc.stdout}{proc.stderr}")
    paths = {"elf": out / "strobe.elf", "hex": out / "strobe.hex"}
    if sim:
        paths["simstrobe"] = out / "simstrobe"
    return paths


@dataclass(frozen=True, slots=True)
class SimRun:
    """One scripted simulation: the firmware's serial output as (simulated s, line) pairs and
    the VCD trace it declared."""

    lines: tuple[tuple[float, str], ...]
    vcd_path: Path

    def replies(self) -> list[str]:
        return [text for _, text in self.lines]


def run_script(build: dict, workdir, sends=(), *, until_ms: float = 100.0,
               timeout_s: float = 60.0) -> SimRun:
    """Simulate ``until_ms`` of the board, typing each ``(ms, line)`` of ``sends`` into its
    serial port at that simulated time. The trace lands in ``workdir/strobe.vcd``."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    vcd = workdir / _VCD_NAME
    vcd.unlink(missing_ok=True)
    cmd = [str(build["simstrobe"]), "--until-ms", repr(float(until_ms))]
    for ms, text in sends:
        cmd += ["--send", f"{float(ms)!r}:{text}"]
    cmd.append(str(build["elf"]))
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0 or not vcd.is_file():
        raise FirmwareError(f"simulation failed (rc {proc.returncode}): {proc.stderr.strip()}")
    lines = []
    for line in proc.stdout.splitlines():
        m = re.fullmatch(r"(\d+\.\d+) (.*)", line)
        if m:
            lines.append((float(m.group(1)) * 1e-6, m.group(2)))
    return SimRun(tuple(lines), vcd)


class SimulatedBoard:
    """The firmware running in simavr behind a pseudo-terminal, paced to the wall clock: a
    serial port at :attr:`port` that any serial program can open (context manager).

    It resets as an Uno does (``firmware/sim/simstrobe.c``): opening the port after a close
    that dropped DTR resets the AVR, and the bootloader takes the host's bytes for
    ``boot_s`` (an Uno's Optiboot: about 1 s; tests pass less to stay fast) before the
    firmware starts and greets. :meth:`reset` resets it mid-session, :meth:`replug` unplugs
    and replugs it (the open port dies). ``edges=True`` logs every rising strobe edge
    (:meth:`edge_cycles`)."""

    def __init__(self, build: dict, workdir, *, boot_s: float = 1.0, edges: bool = False):
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.port = str(self.workdir / "ttySTROBE")
        self.boot_s = float(boot_s)
        self.edges_path = self.workdir / "edges.u64" if edges else None
        self._build = build
        self._proc = None

    def __enter__(self) -> "SimulatedBoard":
        cmd = [str(self._build["simstrobe"]), "--pty", self.port, "--boot-ms",
               repr(self.boot_s * 1e3)]
        if self.edges_path is not None:
            cmd += ["--edges", str(self.edges_path)]
        self._proc = subprocess.Popen(cmd + [str(self._build["elf"])], cwd=self.workdir,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 10.0
        while not os.path.exists(self.port):
            if self._proc.poll() is not None or time.monotonic() > deadline:
                err = self._proc.stderr.read() if self._proc.poll() is not None else "timed out"
                self.close()
                raise FirmwareError(f"the simulated board did not start: {err}")
            time.sleep(0.01)
        return self

    def reset(self) -> None:
        """Reset the board now (a brown-out or watchdog reset in the middle of a session)."""
        self._proc.send_signal(signal.SIGUSR1)

    def replug(self) -> None:
        """Unplug and replug the board: the open port fails, a new one appears at
        :attr:`port` and the board resets."""
        self._proc.send_signal(signal.SIGUSR2)

    def edge_cycles(self) -> np.ndarray:
        """Simulated cycle (16 MHz) of every rising strobe edge so far."""
        data = self.edges_path.read_bytes() if self.edges_path.is_file() else b""
        return np.frombuffer(data[:len(data) // 8 * 8], dtype="<u8")

    def close(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.send_signal(signal.SIGTERM)
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        if self._proc is not None:
            self._proc.stdout.close()
            self._proc.stderr.close()
        self._proc = None

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def vcd_path(self) -> Path:
        return self.workdir / _VCD_NAME


def read_vcd(path, signal_name: str = "strobe") -> tuple[np.ndarray, np.ndarray]:
    """Value changes of one 1-bit signal of a VCD file: (times s, values 0/1), repeated
    values dropped. simavr writes ``$timescale 10ns``."""
    path = Path(path)
    text = path.read_text(encoding="ascii", errors="replace")
    scale = re.search(r"\$timescale\s+(\d+)\s*(s|ms|us|ns|ps)\s+\$end", text)
    ident = re.search(r"\$var\s+\w+\s+1\s+(\S+)\s+" + re.escape(signal_name) + r"\s+\$end", text)
    if scale is None or ident is None:
        raise FirmwareError(f"{path}: no $timescale or no 1-bit signal {signal_name!r}")
    unit = int(scale.group(1)) * {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "ps": 1e-12}[scale.group(2)]
    code = ident.group(1)
    body = text.split("$enddefinitions", 1)[1]
    times, values, now, last = [], [], None, None
    for token in body.split():
        if token.startswith("#"):
            now = int(token[1:])
        elif token[1:] == code and token[0] in "01" and now is not None:
            v = int(token[0])
            if v != last:
                times.append(now)
                values.append(v)
                last = v
    return np.asarray(times, dtype=np.float64) * unit, np.asarray(values, dtype=np.int8)


@dataclass(frozen=True, slots=True)
class PulseTrain:
    """Rising and falling edges of the strobe output (s), one of each per pulse."""

    rise_s: np.ndarray
    fall_s: np.ndarray

    @property
    def width_ticks(self) -> np.ndarray:
        return (self.fall_s - self.rise_s) * F_CPU_HZ

    @property
    def period_ticks(self) -> np.ndarray:
        return np.diff(self.rise_s) * F_CPU_HZ

    def between(self, t0_s: float, t1_s: float) -> "PulseTrain":
        keep = (self.rise_s >= t0_s) & (self.fall_s <= t1_s)
        return PulseTrain(self.rise_s[keep], self.fall_s[keep])


def pulse_train(times_s: np.ndarray, values: np.ndarray) -> PulseTrain:
    """Pair each rising edge with the falling edge after it (a pulse cut by the trace's end
    is left out)."""
    times_s = np.asarray(times_s, dtype=np.float64)
    values = np.asarray(values)
    rises = times_s[values == 1]
    falls = times_s[values == 0]
    falls = falls[falls > rises[0]] if rises.size else falls[:0]
    n = min(rises.size, falls.size)
    return PulseTrain(rises[:n], falls[:n])
