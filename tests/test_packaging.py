"""``pip install .`` (not editable): the wheel builds without setuptools' warnings, carries the
scenes and the firmware sources, and runs ``scet`` outside the checkout (issue 33).

The wheel is built as pip builds it (an isolated build environment with setuptools from the
package index) and installed without dependencies into a fresh virtual environment whose only
other path is the running interpreter's site-packages (numpy, SciPy, OpenCV, Mitsuba, ...), so
nothing is downloaded but the build backend and nothing of the checkout can be imported.
"""

from __future__ import annotations

import os
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _dependency_paths() -> list[str]:
    """site-packages folders of this interpreter, without the checkout's own packages (an
    editable install adds them through a finder that a plain path entry does not run)."""
    return [p for p in sys.path if p.endswith("site-packages") and Path(p).is_dir()]


@pytest.mark.slow
def test_the_wheel_installs_and_runs_outside_the_checkout(tmp_path):
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-w",
                            str(tmp_path / "dist"), "-v"], capture_output=True, text=True,
                           timeout=600)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    log = built.stdout + built.stderr
    assert "is absent from the `packages` configuration" not in log
    wheel = next((tmp_path / "dist").glob("scet-*.whl"))

    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import site; print(site.getsitepackages()[0])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    Path(site, "zz-scet-test-deps.pth").write_text("\n".join(_dependency_paths()) + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q",
                    "--no-deps", str(wheel)], check=True, capture_output=True, timeout=300)

    run_dir = tmp_path / "elsewhere"
    run_dir.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    where = subprocess.run(
        [str(py), "-c", "import estimator, scet_render, scet_scenes, scet_hardware.firmware as f;"
         "print(estimator.__file__); print(sorted(p.name for p in f.FIRMWARE_DIR.rglob('*')))"],
        cwd=run_dir, env=env, capture_output=True, text=True, check=True).stdout.splitlines()
    assert where[0].startswith(site) and not where[0].startswith(str(ROOT))
    assert where[1] == str(sorted(["Makefile", "sim", "simstrobe.c", "strobe.c"]))
    demo = subprocess.run([str(env_dir / "bin" / "scet"), "demo", "--out", "demo"], cwd=run_dir,
                          env=env, capture_output=True, text=True, timeout=300)
    assert demo.returncode == 0, demo.stderr
    assert "scene paper_sim" in demo.stdout and (run_dir / "demo" / "bands.png").is_file()
