"""Numba's on-disk cache kept in step with every source a kernel is compiled from.

The estimator's kernels are compiled with ``numba.njit(cache=True)``: the machine code is kept
in ``__pycache__`` beside each module (``*.nbi`` index, ``*.nbc`` code) and reused while the
module's own file is unchanged (Numba compares that one file's modification time and size).
A kernel that calls kernels of other modules (the tracker's compiled band steps inline the
follow kernel, the glint projection and the small Levenberg-Marquardt fit) is not recompiled
when only one of those changes: it would run the old code. :func:`refresh` closes that gap:
it hashes the text of every estimator module that uses Numba and, when the hash differs from
the one recorded at the last refresh (``estimator/__pycache__/numba-sources.sha256``),
deletes the estimator's cached kernels, so every kernel is compiled again from today's
sources. It runs once per process, on the first import of any ``estimator`` module
(``estimator/__init__.py``), reads about 40 small files (a few milliseconds) and does nothing
where the package folder cannot be written (an installed package changes only by a
reinstall, which gives every file a new modification time, so Numba's own check suffices).
Numba's user-wide cache (used where ``__pycache__`` is not writable) is not touched.
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

#: Where the hash of the kernel sources is kept, relative to the package folder.
STAMP = Path("__pycache__") / "numba-sources.sha256"
#: A module takes part when its text contains this.
MARKER = b"numba"


def sources_digest(root: Path) -> str:
    """sha256 over the relative path and text of every module under ``root`` that mentions
    Numba, in path order."""
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        text = path.read_bytes()
        if MARKER in text:
            h.update(str(path.relative_to(root)).encode() + b"\0" + text + b"\0")
    return h.hexdigest()


def refresh(root: Path | None = None) -> bool:
    """Delete the cached kernels under ``root`` (default: this package) when the Numba
    sources changed since the last call; True when it deleted anything. Never raises: a
    folder it cannot read or write leaves the cache as it is (logged at debug level)."""
    root = Path(__file__).resolve().parent if root is None else Path(root)
    stamp = root / STAMP
    try:
        digest = sources_digest(root)
        if stamp.is_file() and stamp.read_text(encoding="ascii").strip() == digest:
            return False
        if not os.access(root, os.W_OK):
            return False
        removed = 0
        for cached in (*root.rglob("*.nbi"), *root.rglob("*.nbc")):
            cached.unlink(missing_ok=True)
            removed += 1
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest + "\n", encoding="ascii")
        if removed:
            log.info("Numba kernel sources changed: %d cached files removed, kernels compile "
                     "again", removed)
        return removed > 0
    except OSError as exc:
        log.debug("Numba cache left as it is: %s", exc)
        return False
