"""Issue 13, part 1, on Mitsuba renders: captures rendered with a timing the measurement is not
told (another S, a drifting strobe clock) and replayed in the capture format with the nominal
scene's header, measured by :func:`estimator.capture.timing.measure_capture`.

paper_sim at half size (320x240, 650 px; S = 393 and 262, the half-size line counts of the
OV5647's 786 and 524: the same frame time, half the lines), conductor cornea, 4 spp, the
"fixations" trajectory (the eye covers most of the frame: a 60-frame render of it was refused
whole before the fit gate and the pitch's sub-multiple check, FIT_GATE, OCTAVE_SHARE)."""

from dataclasses import replace
from pathlib import Path

import pytest

from estimator.capture.timing import measure_capture
from estimator.scene import load_scene
from scet_scenes import __file__ as _scenes_init

pytest.importorskip("mitsuba")


def scene_file(folder: Path, S: int) -> Path:
    text = (Path(_scenes_init).parent / "paper_sim.toml").read_text(encoding="utf-8")
    for a, b in (("focal_px = 1300.0", "focal_px = 650.0"),
                 ("resolution_px = [640, 480]", "resolution_px = [320, 240]"),
                 ("total_lines = 786", f"total_lines = {S}"),
                 ("visible_lines = 480", "visible_lines = 240")):
        assert a in text, a
        text = text.replace(a, b)
    path = folder / f"paper_sim_S{S}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def rendered_capture(folder: Path, S: int, ppm: float, frames: int) -> tuple:
    """A capture of paper_sim at S lines whose strobe runs ``ppm`` off its nominal ticks."""
    from scet_hardware.capture import replay_dataset
    from scet_render.dataset import render_dataset

    scene = scene_file(folder, S)
    nominal = load_scene(scene)
    true = replace(nominal, strobe=replace(nominal.strobe,
                                           period_s=nominal.strobe.period_s * (1 + ppm * 1e-6)))
    render_dataset(true, folder / "dataset", frames=frames, spp=4, cornea="conductor", seed=4,
                   scene_text=scene.read_text(encoding="utf-8"))
    return replay_dataset(folder / "dataset", folder / "capture", scene=scene), nominal


def check(m, nominal, S, ppm):
    line_s = nominal.sensor.frame_period_s / S
    # The accuracy: S within 0.5 line, the exposure within one line, the clock within
    # 20 ppm; and honest SDs (the truth within 3 of them).
    assert abs(m.total_lines - S) < 0.5
    assert abs(m.total_lines - S) < 3 * m.total_lines_sd
    assert abs(m.exposure_s - nominal.sensor.exposure_s) < line_s
    assert abs(m.clock_ppm - ppm) < 20
    assert abs(m.clock_ppm - ppm) < 3 * m.clock_ppm_sd
    # The pulse (100 us, 2.4 lines at S = 393): within a third of a line.
    assert abs(m.pulse_s - nominal.strobe.pulse_s) < line_s / 3


def test_a_drifting_rendered_capture(tmp_path):
    """60 frames at -2,000 ppm (a ceramic resonator's error; ~0.8 row of drift a frame), the
    issue's 60 frames: ~15-20 s of rendering here. (8 of the 60 frames are refused, the band
    fit leaving more than FIT_GATE of the profile; a 12-frame render lost 7 of 12, and its
    clock came out 113 ppm off: the drift needs the frames.)"""
    cap, nominal = rendered_capture(tmp_path, 393, -2000.0, frames=60)
    check(measure_capture(cap), nominal, 393, -2000.0)


@pytest.mark.slow  # 4 renders of 60 frames: ~15-20 s each here
@pytest.mark.parametrize("S,ppm", [(393, 0.0), (262, 0.0), (393, 300.0), (393, -300.0)])
def test_sixty_rendered_frames(tmp_path, S, ppm):
    cap, nominal = rendered_capture(tmp_path, S, ppm, frames=60)
    m = measure_capture(cap)
    check(m, nominal, S, ppm)
