"""How a ``scet`` run meets failure: exit statuses, the log file and checked flag types.

- Bad input is exit status 2 and one line naming the file and key: every
  :class:`~estimator.errors.InputError` (scene, tracker input, capture, dataset, backend), an
  ``OSError`` (a file that cannot be read or written: a full disk, a read-only folder), a
  ``ValueError`` that SCET's own code raises on purpose (an argument out of range), and a
  flag argparse refuses (a NaN angle, a size out of range; see :func:`finite` and
  :func:`integer`).
- Anything else is a bug: exit status 1, one line "internal error" naming the exception, and
  its traceback in a log file (:class:`RunLog`; ``scet --debug`` prints it instead). A
  ``ValueError`` raised inside numpy, OpenCV or the standard library is such a bug too.
- Log records with a traceback (the tracker's per-frame internal errors) go to the same log
  file; the terminal gets their one-line message.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import math
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

from estimator.errors import InputError

__all__ = ["EXIT_OK", "EXIT_INTERNAL", "EXIT_BAD_INPUT", "LOG_DIR_ENV", "MAX_FRAMES",
           "MAX_RENDER_FRAMES", "MAX_SPP", "MAX_SEED", "RunLog", "finite", "integer", "run",
           "bad_input"]

EXIT_OK, EXIT_INTERNAL, EXIT_BAD_INPUT = 0, 1, 2
#: Folder for the log files of internal errors (default: the system's temporary folder).
LOG_DIR_ENV = "SCET_LOG_DIR"
#: Bounds of the CLI's numbers: a frame index within a day at 1 kHz, datasets of up to a
#: million frames, up to 2^16 samples per pixel, seeds NumPy's SeedSequence takes.
MAX_FRAMES, MAX_RENDER_FRAMES, MAX_SPP, MAX_SEED = 100_000_000, 1_000_000, 65536, 2 ** 63 - 1



def _own_code() -> tuple[str, ...]:
    """Source folders of SCET's packages: a ValueError raised there was raised on purpose."""
    roots = []
    for name in ("estimator", "scet_render", "scet_hardware"):
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin:
            roots.append(str(Path(spec.origin).resolve().parent) + os.sep)
    return tuple(roots)


def finite(lo: float | None = None, hi: float | None = None):
    """An argparse type: a finite float in [lo, hi] (``nan``, ``inf`` are refused)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"expected a number in [{lo:g}, {hi:g}], got {text}"
                                             if lo is not None and hi is not None else
                                             f"expected a number >= {lo:g}, got {text}")
        return value

    parse.__name__ = "number"
    return parse


def integer(lo: int | None = None, hi: int | None = None):
    """An argparse type: an integer in [lo, hi]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"expected an integer in [{lo}, {hi}], got {text}"
                                             if hi is not None else
                                             f"expected an integer >= {lo}, got {text}")
        return value

    parse.__name__ = "integer"
    return parse


def bad_input(exc: BaseException) -> bool:
    """Whether ``exc`` is the user's bad input (exit 2) rather than a bug (exit 1)."""
    if isinstance(exc, (InputError, OSError)):
        return True
    if type(exc) is not ValueError:
        return False
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    where = str(Path(tb.tb_frame.f_code.co_filename).resolve()) if tb is not None else ""
    return where.startswith(_own_code())


def _message(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc)


class RunLog:
    """The log file of one ``scet`` run: created when the first traceback needs a home.

    Parameters
    ----------
    command : str
        The subcommand (in the file name).
    debug : bool
        Print tracebacks on stderr instead.
    """

    def __init__(self, command: str, debug: bool = False):
        self.command, self.debug, self.path = command, debug, None
        self._handlers = []

    def file(self) -> Path:
        if self.path is None:
            folder = Path(os.environ.get(LOG_DIR_ENV) or tempfile.gettempdir())
            folder.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y%m%d-%H%M%S")
            self.path = folder / f"scet-{self.command}-{stamp}-{os.getpid()}.log"
        return self.path

    def write(self, text: str) -> Path:
        path = self.file()
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(text if text.endswith("\n") else text + "\n")
        return path

    def __enter__(self) -> "RunLog":
        root = logging.getLogger()
        self._level = root.level
        if root.level > logging.WARNING or root.level == logging.NOTSET:
            root.setLevel(logging.WARNING)
        self._handlers = [_Terminal(self), _TracebackFile(self)]
        for h in self._handlers:
            root.addHandler(h)
        return self

    def __exit__(self, *exc) -> None:
        root = logging.getLogger()
        for h in self._handlers:
            root.removeHandler(h)
        root.setLevel(self._level)


class _Terminal(logging.Handler):
    """Warnings and errors on stderr, one line each (the traceback goes to the log file)."""

    def __init__(self, run_log: RunLog):
        super().__init__(logging.WARNING)
        self.run_log = run_log

    def emit(self, record: logging.LogRecord) -> None:
        try:
            line = record.getMessage()
            if record.exc_info and self.run_log.debug:
                line += "\n" + "".join(traceback.format_exception(*record.exc_info)).rstrip()
            elif record.exc_info:
                line += f" (traceback in {self.run_log.file()})"
            print(line, file=sys.stderr)
        except Exception:  # a log line must never end the run; logging's own policy
            self.handleError(record)


class _TracebackFile(logging.Handler):
    """Records with a traceback, in full, in the run's log file."""

    def __init__(self, run_log: RunLog):
        super().__init__(logging.DEBUG)
        self.run_log = run_log
        self.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        if not record.exc_info or self.run_log.debug:
            return
        try:
            self.run_log.write(self.format(record))
        except Exception:
            self.handleError(record)


def run(args, prog: str = "scet") -> int:
    """Run ``args.func(args)`` and turn what escapes into an exit status (module docstring)."""
    with RunLog(args.command, getattr(args, "debug", False)) as run_log:
        args.run_log = run_log
        try:
            return args.func(args)
        except Exception as exc:
            if bad_input(exc):
                print(f"{prog} {args.command}: error: {_message(exc)}", file=sys.stderr)
                return EXIT_BAD_INPUT
            text = "".join(traceback.format_exception(exc))
            if run_log.debug:
                print(text, file=sys.stderr, end="")
                where = "traceback above"
            else:
                try:
                    where = f"traceback in {run_log.write(text)}"
                except OSError as log_exc:
                    where = f"no log file ({log_exc}); rerun with --debug for the traceback"
            print(f"{prog} {args.command}: internal error: {type(exc).__name__}: "
                  f"{str(exc).splitlines()[0] if str(exc) else ''} ({where}); this is a bug in "
                  f"SCET, please report it", file=sys.stderr)
            return EXIT_INTERNAL
