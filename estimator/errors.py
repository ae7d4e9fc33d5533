"""Exceptions raised by the estimator for bad input."""

from __future__ import annotations


class SceneError(ValueError):
    """A scene file, or a value meant for one, is malformed or physically impossible.

    The message names the file, the key (dotted TOML path) and what was expected, so that a
    user can fix the file without reading the loader.
    """

    def __init__(self, message: str, *, path: str | None = None, key: str | None = None):
        self.path = path
        self.key = key
        where = ", ".join(part for part in (path, f"key '{key}'" if key else None) if part)
        super().__init__(f"{where}: {message}" if where else message)
