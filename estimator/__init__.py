"""SCET's tracker: glint detection, calibration and gaze from banded rolling-shutter frames."""

from . import jitcache as _jitcache

_jitcache.refresh()
