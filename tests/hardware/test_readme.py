"""hardware/README.md as a new user runs it: every ``sh`` block line by line in a shell, the
Pi blocks (``sh pi``) with ``--replay`` of a dataset instead of the camera (drawn analytically:
single-pulse calibration frames and banded frames of the prototype scene), the strobe commands
against the firmware running in simavr behind a pseudo-terminal. ``sh board`` blocks need a
board; their files must exist. About 30 s (a dozen `scet` processes); part of `make test`, so CI runs the README's commands."""

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from estimator.folders import timing_document
from estimator.scene import load_scene
from scet_hardware.firmware import SimulatedBoard
from estimator.banding import calibration_setup
from tests.estimator.test_tracker import draw_frame

REPO = Path(__file__).resolve().parents[2]
README = REPO / "hardware" / "README.md"


def blocks():
    text = README.read_text(encoding="utf-8")
    return [(m.group(1).strip(), m.group(2)) for m in
            re.finditer(r"^```(sh[^\n]*)\n(.*?)^```", text, re.S | re.M)]


def draw_dataset(folder: Path, setup, targets, *, single: bool):
    (folder / "frames").mkdir(parents=True)
    frame_setup = calibration_setup(setup) if single else setup
    yaw, pitch = setup.eye.angles_toward(targets)
    rng = np.random.default_rng(11)
    for f in range(len(targets)):
        img = draw_frame(frame_setup, f, float(yaw[f]), float(pitch[f]), rng)
        cv2.imwrite(str(folder / "frames" / f"{f:06d}.png"), img)
    dt = setup.sensor.frame_period_s
    if single:
        (folder / "timing.json").write_text(timing_document(
            {f: f * dt for f in range(len(targets))}, exposure_s=frame_setup.sensor.exposure_s,
            strobe=frame_setup.strobe))
    manifest = {"format": "scet-dataset", "version": 1, "frames": len(targets),
                "scene": {"name": setup.name, "toml": Path(setup.source).read_text()},
                "image": {"width_px": 640, "height_px": 480, "png_bit_depth": 16}}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    (folder / "labels.jsonl").write_text("".join(
        json.dumps({"frame": f, "target_m": list(map(float, t))}) + "\n" for f, t in enumerate(targets)))


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    setup = load_scene("prototype_ov5647")
    root = tmp_path_factory.mktemp("readme-data")
    draw_dataset(root / "calib", setup, setup.screen.grid(4, 3, margin=0.0), single=True)
    draw_dataset(root / "run", setup, setup.screen.grid(3, 1), single=False)
    return root


def test_the_readme_runs(firmware, datasets, tmp_path):
    found = blocks()
    kinds = [k for k, _ in found]
    assert "sh" in kinds and "sh pi" in kinds and "sh board" in kinds
    shutil.rmtree(REPO / "out" / "session", ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    prelude = f'scet() {{ {shlex.quote(sys.executable)} -m scet_render.cli "$@"; }}\nset -e\n'
    from tests.hardware.conftest import BOOT_S

    with SimulatedBoard(firmware, tmp_path / "board", boot_s=BOOT_S) as board:
        env["SCET_STROBE_PORT"] = board.port
        for kind, body in found:
            for line in body.strip().splitlines():
                if kind == "sh board":
                    # Needs a board; what it flashes must have been built by `make firmware`.
                    hexfile = re.search(r"flash:w:(\S+):i", line).group(1)
                    assert (REPO / hexfile).is_file(), hexfile
                    continue
                if kind == "sh pi":
                    which = "calib" if "/calib" in line else "run"
                    line += f" --replay {datasets / which}"
                proc = subprocess.run(["bash", "-c", prelude + line], cwd=REPO, env=env,
                                      capture_output=True, text=True, timeout=300)
                assert proc.returncode == 0, f"{line}\n{proc.stdout}\n{proc.stderr}"
    samples = (REPO / "out" / "session" / "samples.csv").read_text().splitlines()
    assert samples[0] == "# scet-samples 3"
    ok = [r for r in samples[2:] if ",ok," in r]
    assert ok, "no gaze sample estimated from the replayed capture"
    cal = json.loads((REPO / "out" / "session" / "cal.json").read_text())
    assert cal["format"] == "scet-calibration"
