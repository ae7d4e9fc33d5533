"""Project-wide test settings.

With ``SCET_REQUIRE_ALL=1`` (set by ``.ci/run``) the session stops at once when a module of
the package's extras (:data:`EXTRAS`) cannot be imported, and a test that skips because an
optional dependency cannot be imported fails instead, so that CI never passes by silently
skipping what it is meant to check (trimesh's ALL_DEPENDENCIES switch; a skip reason written
by the test does not say "could not import", hence the check at the start). It also makes
hypothesis draw a fixed sequence of examples (the "ci" profile).
"""

import importlib
import os

import pytest
from hypothesis import settings

# CI runs the property-based tests on a fixed sequence of examples, so that a red run can be
# reproduced; locally they draw new examples each run.
settings.register_profile("ci", derandomize=True)
if os.environ.get("SCET_REQUIRE_ALL") == "1":
    settings.load_profile("ci")


#: Modules of the extras in pyproject.toml ('render', 'fast', 'test', 'hardware') and of matplotlib.
EXTRAS = ("mitsuba", "drjit", "OpenEXR", "trimesh", "numba", "hypothesis", "matplotlib", "serial")


def pytest_sessionstart(session):
    if os.environ.get("SCET_REQUIRE_ALL") != "1":
        return
    missing = []
    for name in EXTRAS:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            missing.append(f"{name} ({exc})")
    if missing:
        raise pytest.UsageError("SCET_REQUIRE_ALL=1 but these required modules cannot be "
                                "imported: " + ", ".join(missing))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if os.environ.get("SCET_REQUIRE_ALL") != "1" or not report.skipped:
        return
    reason = str(report.longrepr[-1]) if isinstance(report.longrepr, tuple) else str(report.longrepr)
    if "could not import" in reason:
        report.outcome = "failed"
        report.longrepr = f"SCET_REQUIRE_ALL=1 but a required dependency is missing: {reason}"
