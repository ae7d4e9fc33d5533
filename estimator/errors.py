"""Exceptions raised by the estimator for bad input.

Every refusal of a user's input is an :class:`InputError` (a ``ValueError``): the scene loader's
:class:`SceneError`, the tracker's :class:`TrackerInputError` (timing sidecar, frames,
calibration, labels), and, above the estimator, the capture and dataset readers' errors. The
message names the file and the key (dotted path) and what was expected; ``path`` and ``key``
keep them apart for code. ``scet`` answers an InputError with exit status 2 and its message;
anything else that escapes is a bug (exit status 1, "internal error").
"""

from __future__ import annotations

__all__ = ["InputError", "SceneError", "TrackerInputError"]


class InputError(ValueError):
    """A file, or a value meant for one, is malformed or physically impossible.

    The message names the file, the key (dotted path) and what was expected, so that a user
    can fix the input without reading the reader.
    """

    def __init__(self, message: str, *, path: str | None = None, key: str | None = None):
        self.path = None if path is None else str(path)
        self.key = key
        where = ", ".join(part for part in (self.path, f"key '{key}'" if key else None) if part)
        super().__init__(f"{where}: {message}" if where else message)


class SceneError(InputError):
    """A scene file, or a value meant for one, is malformed or physically impossible (the key
    is the dotted TOML path)."""


class TrackerInputError(InputError):
    """A tracker input file (timing sidecar, calibration, frames folder, labels) is missing or
    malformed; the message names the file (and key)."""
