"""`scet compare` on a blurred capture (issue 30): frames blurred by a 1.2 px Gaussian (a
slightly defocused lens, the issue's measurement) are blamed on the optics, with the blur
measured, not on timing or materials. paper_sim at 640x480, 3 frames (the drift needs 3),
conductor cornea at 4 spp: ~50 s here (the 320x240 capture of the same test is in
test_compare.py)."""

import shutil

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("scet_hardware")

import cv2  # noqa: E402

from estimator.scene import load_scene  # noqa: E402
from scet_hardware.capture import replay_dataset  # noqa: E402
from scet_render.compare import compare_capture  # noqa: E402
from scet_render.dataset import render_dataset  # noqa: E402

#: The blur of the issue's measurement (px), and how well it must be measured: the fit's
#: bisection steps are 0.006 px; 1.22 px measured (the unperturbed 320x240 capture reads
#: +0.12: scet_render/compare/verdict.py TOL["blur"]).
BLUR_PX, BLUR_TOL_PX = 1.2, 0.3


@pytest.mark.slow
def test_a_blurred_capture_is_blamed_on_the_optics(tmp_path):
    setup = load_scene("paper_sim")
    render_dataset(setup, tmp_path / "ds", frames=3, spp=4, cornea="conductor", seed=3)
    shutil.copytree(tmp_path / "ds", tmp_path / "blurred")
    for p in sorted((tmp_path / "blurred" / "frames").glob("*.png")):
        a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)
        b = cv2.GaussianBlur(a, (0, 0), BLUR_PX)
        cv2.imwrite(str(p), np.clip(np.rint(b), 0, 1023).astype(np.uint16))
    cap = replay_dataset(tmp_path / "blurred", tmp_path / "capture", scene="paper_sim")
    r = compare_capture(cap, setup, frames=3, spp=4, cornea="conductor", seed=5)
    rows = {x.quantity: x for x in r.rows}
    blur = next(x for q, x in rows.items() if q.startswith("glint spot size"))
    assert not blur.passed and blur.cause == "optics"
    assert abs(r.findings["extra_blur_px"] - BLUR_PX) < BLUR_TOL_PX
    # The blur moves the timing and glint rows (the issue: pulse, phase, peak, energy, area,
    # clutter flagged against timing, sensor and material): none of them is blamed on timing
    # or materials now.
    blamed = {x.quantity: x.cause for x in r.flagged}
    assert "optics" in blamed.values()
    # Clutter is left out: its count against the blurred render swings with the fitted blur
    # by more than EXPLAINED_SHARE allows (measured on this capture, +21 a frame against the
    # sharp render: +13.7, +8.3 and +14.7 against renders blurred by 1.22, 1.24 and 1.29 px),
    # so whether it is blamed on the optics or on the material is chance here. At 320x240
    # (test_compare.py) it is the optics'.
    assert not {q for q, c in blamed.items() if c in ("timing", "material")
                and not q.startswith("clutter")}, blamed
    assert any(q.startswith("pulse") for q in blamed), "the blur lengthens the measured pulse"
    assert all("blamed on the optics" in rows[q].note for q, c in blamed.items()
               if c == "optics" and not q.startswith("glint spot size"))
