"""Project-wide test settings.

With ``SCET_REQUIRE_ALL=1`` (set by ``.ci/run``) the session stops at once when a module of
the package's extras (:data:`EXTRAS`) cannot be imported, and a test that skips because an
optional dependency cannot be imported fails instead, so that CI never passes by silently
skipping what it is meant to check (trimesh's ALL_DEPENDENCIES switch; a skip reason written
by the test does not say "could not import", hence the check at the start). It also makes
hypothesis draw a fixed sequence of examples (the "ci" profile).

With ``SCET_BASE_ONLY=1`` (set by ``make test-base``, which runs ``tests/estimator`` on the base
package alone) the session stops at once when a module of the render or fast extras
(:data:`BASE_EXCLUDES`) can be imported, and importing ``scet_render`` raises ImportError: the
estimator and its tests run without the layer above.
"""

import importlib
import importlib.abc
import importlib.util
import os
import sys

import pytest
from hypothesis import settings

# CI runs the property-based tests on a fixed sequence of examples, so that a red run can be
# reproduced; locally they draw new examples each run.
settings.register_profile("ci", derandomize=True)
if os.environ.get("SCET_REQUIRE_ALL") == "1":
    settings.load_profile("ci")


#: Modules of the extras in pyproject.toml ('render', 'fast', 'test', 'hardware', 'events',
#: 'cluster') and of matplotlib.
EXTRAS = ("mitsuba", "drjit", "OpenEXR", "trimesh", "numba", "hypothesis", "matplotlib", "serial",
          "pymovements", "ray")
#: Modules of the 'render' and 'fast' extras, which the base install must do without.
BASE_EXCLUDES = ("mitsuba", "drjit", "OpenEXR", "trimesh", "numba")


class _NoRenderer(importlib.abc.MetaPathFinder):
    """Refuses ``scet_render``: under ``SCET_BASE_ONLY=1`` the estimator's tests may not use it,
    although the base install holds it (it is part of the same distribution)."""

    def find_spec(self, name, path=None, target=None):
        if name == "scet_render" or name.startswith("scet_render."):
            raise ImportError(f"SCET_BASE_ONLY=1: {name} is the layer above the estimator; "
                              "tests/estimator must not import it")
        return None


# Installed when this file is imported, before any test module or nested conftest.
if os.environ.get("SCET_BASE_ONLY") == "1":
    sys.meta_path.insert(0, _NoRenderer())


def pytest_sessionstart(session):
    if os.environ.get("SCET_BASE_ONLY") == "1":
        present = [name for name in BASE_EXCLUDES if importlib.util.find_spec(name) is not None]
        if present:
            raise pytest.UsageError("SCET_BASE_ONLY=1 but these modules of the extras can be "
                                    f"imported: {', '.join(present)} (not a base install)")
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
