"""Checking JSON documents as they are read: typed, ranged fields, each refusal naming the
file and the dotted key.

Every JSON reader of SCET (timing sidecar, calibration file, gaze mappings, labels, dataset
manifest, capture header) reads its document through :class:`Doc`, as the scene loader reads
TOML (:mod:`estimator.scene`): a field is taken with the type and range it must have, or the
reader raises its :class:`~estimator.errors.InputError` subclass naming the file, the key
(``strobe.pulse_s``, ``mappings.eq1_25.coefficients[3][1]``) and what was expected. What a
parsed document can hold that Python does not expect is refused here, once:

- integers too large for a float (``1e400`` written as digits), NaN and infinities (Python's
  JSON reader accepts ``NaN`` and ``Infinity``), numbers beyond :data:`MAX_ABS`;
- ``true``/``false`` where a number is expected (Python's bool is an int);
- lists where objects belong and objects where lists belong, arrays of the wrong shape;
- values outside a physical range (a radius in millimetres under a ``_m`` key);
- documents nested so deeply that the parser recurses out (RecursionError), files too large
  to be what they claim (:data:`MAX_JSON_BYTES`), text that is not UTF-8.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import InputError

__all__ = ["MAX_ABS", "MAX_JSON_BYTES", "MAX_LINE_BYTES", "MAX_ARRAY_LENGTH", "Doc", "load_json", "parse_json",
           "iter_json_lines", "kind_of"]

#: No number in a SCET document may exceed this in magnitude (the scene loader's bound):
#: squares of larger values overflow, and nothing in an eye tracker comes near it.
MAX_ABS = 1e100
#: A JSON document larger than this is refused before it is read (the largest SCET writes, a
#: long dataset's labels, is a few MB per thousand frames).
MAX_JSON_BYTES = 256 * 2 ** 20
#: Longest line of a JSON-lines file (labels, frame lists): a label of a few hundred lights is
#: tens of kB.
MAX_LINE_BYTES = 16 * 2 ** 20
#: Longest array a field may hold (a guard against documents that claim, not hold, data).
MAX_ARRAY_LENGTH = 10_000_000


def kind_of(value) -> str:
    """The JSON name of a parsed value's type, for messages."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"{str(value).lower()}"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _got(value) -> str:
    """A parsed value for a message: its JSON type, and the value unless that says it all."""
    if value is None or isinstance(value, bool):
        return kind_of(value)
    return f"{kind_of(value)} {_short(value)}"


def parse_json(text: str, path, error: type[InputError] = InputError):
    """The parsed JSON text; ``error`` naming ``path`` if it is not JSON (or too deep)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise error("cannot read JSON (nested too deeply)", path=path) from None
    except ValueError as exc:  # JSONDecodeError, and integers of more than 4300 digits
        raise error(f"cannot read JSON (not JSON: {exc})", path=path) from None


def load_json(path, error: type[InputError] = InputError, *, max_bytes: int = MAX_JSON_BYTES):
    """The parsed JSON document in the file ``path``; ``error`` naming the file if it cannot
    be read, is larger than ``max_bytes``, is not UTF-8 or not JSON."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise error(f"{size} bytes, more than the {max_bytes} a SCET document may have",
                        path=path)
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read the file ({exc.strerror or exc})", path=path) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"not UTF-8 text ({exc.reason} at byte {exc.start})", path=path) from None
    return parse_json(text, path, error)


def iter_json_lines(path, error: type[InputError] = InputError, *,
                    max_line_bytes: int = MAX_LINE_BYTES) -> Iterator[tuple[str, object]]:
    """(``"<path>, line N"``, parsed line) for every non-blank line of a JSON-lines file, read
    line by line (a long dataset's labels are gigabytes); a line longer than
    ``max_line_bytes`` is refused before it is held whole."""
    path = Path(path)
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise error(f"cannot read the file ({exc.strerror or exc})", path=path) from None
    with fh:
        number = 0
        while True:
            try:
                raw = fh.readline(max_line_bytes + 1)
            except OSError as exc:
                raise error(f"cannot read the file ({exc.strerror or exc})", path=path) from None
            if not raw:
                return
            number += 1
            where = f"{path}, line {number}"
            if len(raw) > max_line_bytes:
                raise error(f"a line of more than {max_line_bytes} bytes", path=where)
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise error(f"not UTF-8 text ({exc.reason} at byte {exc.start})",
                            path=where) from None
            if line.strip():
                yield where, parse_json(line, where, error)


class Doc:
    """A JSON object being read: every field is taken typed and ranged.

    Parameters
    ----------
    data : object
        The parsed value that must be an object.
    path : str or Path
        The file (or ``"<file>, line N"``) named in errors.
    key : str
        Dotted key of this object inside the document ("" for the document itself).
    error : type
        The :class:`~estimator.errors.InputError` subclass raised.
    """

    def __init__(self, data, path, key: str = "", error: type[InputError] = InputError):
        self.path, self.key, self.error_type = str(path), key, error
        if not isinstance(data, dict):
            raise error(f"expected an object, got {kind_of(data)}", path=self.path,
                        key=key or None)
        self.data = data

    def full(self, name) -> str:
        if isinstance(name, int):
            return f"{self.key}[{name}]"
        return f"{self.key}.{name}" if self.key else str(name)

    def error(self, name, message: str) -> InputError:
        return self.error_type(message, path=self.path, key=self.full(name))

    def has(self, name: str) -> bool:
        return name in self.data and self.data[name] is not None

    def raw(self, name: str, *, required: bool = True, default=None):
        """The value at ``name`` unchecked; ``default`` where it is missing or null."""
        if name not in self.data or self.data[name] is None:
            if required:
                raise self.error(name, "missing required key" if name not in self.data
                                 else "must not be null")
            return default
        return self.data[name]

    def obj(self, name: str, *, required: bool = True) -> "Doc | None":
        value = self.raw(name, required=required)
        return None if value is None else Doc(value, self.path, self.full(name), self.error_type)

    def string(self, name: str, *, choices=None, required: bool = True, default=None):
        value = self.raw(name, required=required)
        if value is None:
            return default
        if not isinstance(value, str):
            raise self.error(name, f"expected a string, got {_got(value)}")
        if choices is not None and value not in choices:
            raise self.error(name, f"expected one of {sorted(choices)}, got {value!r}")
        return value

    def boolean(self, name: str, *, required: bool = True, default=None):
        value = self.raw(name, required=required)
        if value is None:
            return default
        if not isinstance(value, bool):
            raise self.error(name, f"expected true or false, got {_got(value)}")
        return value

    def integer(self, name: str, *, lo: int | None = None, hi: int | None = None,
                required: bool = True, default=None):
        value = self.raw(name, required=required)
        if value is None:
            return default
        return self._integer(name, value, lo, hi)

    def _integer(self, name, value, lo, hi) -> int:
        if isinstance(value, float) and value.is_integer() and abs(value) <= 2 ** 53:
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"expected an integer, got {_got(value)}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.error(name, f"expected an integer in [{lo}, {hi}], got {_short(value)}")
        return int(value)

    def number(self, name: str, *, lo: float | None = None, hi: float | None = None,
               required: bool = True, default=None, allow_nan: bool = False):
        """A finite number in [lo, hi] (``allow_nan``: NaN too, for "not measured")."""
        value = self.raw(name, required=required)
        if value is None:
            return default
        return self._number(name, value, lo, hi, allow_nan)

    def _number(self, name, value, lo, hi, allow_nan=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(name, f"expected a number, got {_got(value)}")
        try:
            x = float(value)
        except OverflowError:
            raise self.error(name, "expected a finite number, got an integer too large for a "
                                   "float") from None
        if math.isnan(x) and allow_nan:
            return x
        if not math.isfinite(x) or abs(x) > MAX_ABS:
            raise self.error(name, f"expected a finite number of magnitude below {MAX_ABS:g}, "
                                   f"got {x}")
        if (lo is not None and x < lo) or (hi is not None and x > hi):
            unit = str(name).rsplit("_", 1)[-1].rstrip("]0123456789[") if "_" in str(name) else ""
            hint = f" ({unit}; check the unit)" if unit in ("m", "s", "px", "rad") else ""
            want = (f"in [{lo:g}, {hi:g}]" if lo is not None and hi is not None
                    else f">= {lo:g}" if lo is not None else f"<= {hi:g}")
            raise self.error(name, f"expected a value {want}{hint}, got {x:g}")
        return x

    def array(self, name: str, shape: tuple, *, lo: float | None = None, hi: float | None = None,
              required: bool = True, default=None, allow_null: bool = False) -> np.ndarray:
        """A nested list of numbers of ``shape`` (None: any length) as float64; ``allow_null``:
        null leaves (or null rows) read as NaN."""
        value = self.raw(name, required=required)
        if value is None:
            return default
        out = np.array(self._nested(value, tuple(shape), lo, hi, allow_null, self.full(name)),
                       dtype=np.float64)
        if out.size == 0:
            out = out.reshape((0,) + tuple(s or 0 for s in shape[1:]))
        return out

    def _nested(self, value, shape, lo, hi, allow_null, where):
        if not shape:
            if value is None and allow_null:
                return math.nan
            # Errors inside an array name the element: key 'target_m[2]'.
            return Doc({}, self.path, "", self.error_type)._number(where, value, lo, hi)
        if value is None and allow_null and all(shape):
            return np.full(shape, np.nan).tolist()
        n = shape[0]
        if not isinstance(value, list):
            raise self.error_type(f"expected a list{f' of {n}' if n else ''}, got "
                                  f"{_got(value)}", path=self.path, key=where)
        if (n is not None and len(value) != n) or len(value) > MAX_ARRAY_LENGTH:
            raise self.error_type(f"expected {n} entries, got {len(value)}" if n is not None else
                                  f"more than {MAX_ARRAY_LENGTH} entries", path=self.path,
                                  key=where)
        return [self._nested(v, shape[1:], lo, hi, allow_null, f"{where}[{i}]")
                for i, v in enumerate(value)]

    def items(self, name: str, *, required: bool = True, max_length: int = MAX_ARRAY_LENGTH
              ) -> list:
        """The list at ``name`` (its entries unchecked)."""
        value = self.raw(name, required=required, default=[])
        if not isinstance(value, list):
            raise self.error(name, f"expected a list, got {_got(value)}")
        if len(value) > max_length:
            raise self.error(name, f"expected at most {max_length} entries, got {len(value)}")
        return value

    def integers(self, name: str, length: int | None = None, *, lo: int | None = None,
                 hi: int | None = None) -> list[int]:
        """A list of integers (``length`` of them when given), each in [lo, hi]."""
        value = self.items(name)
        if length is not None and len(value) != length:
            raise self.error(name, f"expected {length} integers, got {len(value)} entries")
        return [self._integer(f"{name}[{i}]", v, lo, hi) for i, v in enumerate(value)]

    def booleans(self, name: str) -> list[bool]:
        """A list of true/false."""
        value = self.items(name)
        for i, v in enumerate(value):
            if not isinstance(v, bool):
                raise self.error(f"{name}[{i}]", f"expected true or false, got {_got(v)}")
        return list(value)

    def keys(self) -> list[str]:
        return list(self.data)

    def only(self, allowed) -> None:
        """Refuse keys outside ``allowed``."""
        unknown = sorted(set(self.data) - set(allowed))
        if unknown:
            raise self.error(unknown[0], f"unknown key (expected some of {sorted(allowed)})")
