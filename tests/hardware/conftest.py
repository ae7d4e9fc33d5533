"""Fixtures of the hardware tests: the firmware built once per session with the real avr-gcc,
for the real simavr.

Without the toolchain the tests that need it skip, naming what is missing; with
``SCET_REQUIRE_ALL=1`` (CI, which installs it through ``make setup``) they fail instead.
"""

import os

import pytest

from scet_hardware.firmware import build_firmware, find_toolchain


@pytest.fixture(scope="session")
def firmware(tmp_path_factory):
    missing = find_toolchain().missing
    if missing:
        reason = ("the AVR toolchain is not installed (run tools/install-avr.sh as root): "
                  + "; ".join(missing))
        if os.environ.get("SCET_REQUIRE_ALL") == "1":
            pytest.fail("SCET_REQUIRE_ALL=1 but " + reason)
        pytest.skip(reason)
    return build_firmware(tmp_path_factory.mktemp("firmware"))


#: The simulated bootloader's time (s): an Uno's Optiboot takes about 1 s; the harness takes a
#: parameter so that the tests stay fast while the host still has to wait for the reset.
BOOT_S = 0.3


@pytest.fixture(autouse=True)
def strobe_settings_file(tmp_path, monkeypatch):
    """``scet strobe`` keeps its settings file in the test's folder, never in ~/.config."""
    path = tmp_path / "strobe-settings.json"
    monkeypatch.setenv("SCET_STROBE_SETTINGS", str(path))
    return path
