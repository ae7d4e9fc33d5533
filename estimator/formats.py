"""SCET's files on disk: every name and format version in one place, the version check, and
the one atomic write.

Every file SCET writes is versioned (a ``format`` name and an integer ``version`` in its JSON
header, or its first line) and checked on load, and every file is written atomically: to a
temporary name beside the target, flushed to disk, then moved onto the target with
:func:`os.replace`, so that a reader sees either the old file or the whole new one. The
temporary name is unique per writer (``<name>.<token><pid>-<thread>-<n>.partial``, the token
random per process, for writers on several machines): two processes writing one
file never write into each other's temporary, and the last rename wins with a whole file. A
failed write removes its temporary. Folders that are written into can be swept of the
temporaries of killed runs with :func:`remove_partials`.

Folder layout (rendered datasets and prototype captures)::

    manifest.json  labels.jsonl  timing.json  frames/NNNNNN.png  frames/NNNNNN.exr
"""

from __future__ import annotations

import itertools
import os
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from .checks import load_json
from .errors import InputError

__all__ = [
    "TIMING_FORMAT", "TIMING_VERSION", "SAMPLES_FORMAT", "SAMPLES_VERSION", "SAMPLES_READABLE",
    "CALIBRATION_FORMAT", "CALIBRATION_VERSION", "MAPPING_FORMAT", "MAPPING_VERSION",
    "DATASET_FORMAT", "DATASET_VERSION", "GLINTS_FORMAT", "GLINTS_VERSION",
    "TIMING_NAME", "MANIFEST_NAME", "LABELS_NAME", "FRAMES_DIR", "PARTIAL_SUFFIX",
    "frame_name", "check_format", "read_json", "atomic_file", "atomic_write", "remove_partials",
]

TIMING_FORMAT, TIMING_VERSION = "scet-timing", 1
SAMPLES_FORMAT, SAMPLES_VERSION = "scet-samples", 3
#: Versions the samples reader accepts (version 1 has no ``prior`` column, 1-2 no
#: ``flux_flagged``).
SAMPLES_READABLE = (1, 2, 3)
CALIBRATION_FORMAT, CALIBRATION_VERSION = "scet-calibration", 1
MAPPING_FORMAT, MAPPING_VERSION = "scet-gaze-mapping", 1
DATASET_FORMAT, DATASET_VERSION = "scet-dataset", 1
GLINTS_FORMAT, GLINTS_VERSION = "scet-glints", 1

TIMING_NAME, MANIFEST_NAME, LABELS_NAME, FRAMES_DIR = (
    "timing.json", "manifest.json", "labels.jsonl", "frames")
PARTIAL_SUFFIX = ".partial"


def frame_name(frame: int, ext: str) -> str:
    """``NNNNNN.ext``: the file name of frame ``frame`` in a ``frames/`` folder."""
    return f"{int(frame):06d}.{ext}"


def check_format(data, path, fmt: str, versions, error: type[Exception] = ValueError) -> int:
    """The version of the parsed JSON document ``data``, checked.

    Raises ``error`` naming ``path`` unless ``data`` is an object whose ``"format"`` is ``fmt``
    and whose ``"version"`` is ``versions`` (an int) or one of them (a tuple).
    """
    allowed = (versions,) if isinstance(versions, int) else tuple(versions)

    def refuse(message: str, key: str | None):
        exc = error(f"{path}: {message}")
        if isinstance(exc, InputError):  # the text stays as it was; path and key for code
            exc.path, exc.key = str(path), key
        return exc

    if not isinstance(data, dict):
        raise refuse(f"expected a {fmt!r} document (a JSON object), got {type(data).__name__}", None)
    if data.get("format") != fmt:
        raise refuse(f"key 'format' is {_short(data.get('format'))}, expected {fmt!r}", "format")
    version = data.get("version")
    if isinstance(version, bool) or version not in allowed:
        want = allowed[0] if len(allowed) == 1 else f"one of {allowed}"
        raise refuse(f"key 'version': this SCET reads {fmt} version {want}, the file says "
                     f"{_short(version)}", "version")
    return int(version)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def read_json(path, error: type[InputError] = InputError):
    """The parsed JSON document at ``path``; ``error`` naming the file if it cannot be read
    (:func:`estimator.checks.load_json`: size limit, UTF-8, nesting depth)."""
    return load_json(path, error)


_counter = itertools.count()
_counter_lock = threading.Lock()
#: Per process: temporaries stay unique across machines writing into one shared folder.
_TOKEN = os.urandom(3).hex()


def _partial_name(path: Path) -> Path:
    with _counter_lock:
        n = next(_counter)
    return path.with_name(f"{path.name}.{_TOKEN}{os.getpid()}-{threading.get_ident() % 100000}"
                          f"-{n}{PARTIAL_SUFFIX}")


@contextmanager
def atomic_file(path, *, sync: bool = True) -> Iterator[Path]:
    """A temporary path to write ``path``'s new content to; moved onto ``path`` on success.

    For writers that need a file name (OpenEXR, image encoders)::

        with atomic_file(out / "frame.exr") as tmp:
            write_exr(tmp, ...)

    The parent folder is created. On an exception the temporary is removed and ``path`` is left
    as it was; an ``OSError`` of the write (a full disk, a file-size limit) is raised again
    naming ``path``, not the temporary. ``sync=False`` leaves out the fsync before the rename
    (the file is still whole or absent if the process dies; a power cut may lose it): for
    writers that sync in batches (:class:`estimator.capture.CaptureWriter` at 60 frames/s).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _partial_name(path)
    try:
        yield tmp
        if sync:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        if isinstance(exc, OSError) and exc.errno and exc.filename in (None, str(tmp)):
            # Name the file the user asked for, not the temporary that is gone.
            raise OSError(exc.errno, f"cannot write ({exc.strerror})", str(path)) from None
        raise


def atomic_write(path, data: bytes | str) -> Path:
    """Write ``data`` (``str`` as UTF-8) to ``path`` atomically (see the module docstring)."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    with atomic_file(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
    return Path(path)


def remove_partials(folder) -> int:
    """Remove the temporaries that killed writers left in ``folder`` (not recursive); their count."""
    removed = 0
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    for p in folder.iterdir():
        if p.name.endswith(PARTIAL_SUFFIX) and p.is_file():
            try:
                p.unlink()
                removed += 1
            except OSError:
                pass
    return removed
