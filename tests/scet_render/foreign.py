"""Foreign captures for `scet compare` (issue 13, part 4): renders of a PERTURBED scene,
replayed into the capture folder format with the NOMINAL scene's header (the timing, sensor
and geometry the comparison is not told), as a prototype capture would be.

The scene is paper_sim at half resolution (320x240, 650 px, S = 393), the conductor cornea
at 4 spp: ~1 s a frame here.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator.eye import Eye
from estimator.scene import load_scene
from scet_hardware.capture import replay_dataset
from scet_render.dataset import render_dataset
from scet_render.render.sensor import SensorModel
from scet_scenes import __file__ as _scenes_init

FRAMES, SPP, CORNEA = 4, 4, "conductor"
#: Lights 0.3 mm off their nominal places, each in its own random direction.
LIGHT_OFFSET_M = 0.3e-3


def small_scene(folder) -> Path:
    """paper_sim at 320x240 (the quick validation's scale) as a scene file."""
    text = (Path(_scenes_init).parent / "paper_sim.toml").read_text(encoding="utf-8")
    for a, b in (("focal_px = 1300.0", "focal_px = 650.0"),
                 ("resolution_px = [640, 480]", "resolution_px = [320, 240]"),
                 ("total_lines = 786", "total_lines = 393"),
                 ("visible_lines = 480", "visible_lines = 240"),
                 ('name = "paper_sim"', 'name = "paper_sim_320"')):
        assert a in text, a
        text = text.replace(a, b)
    path = Path(folder) / "paper_sim_320.toml"
    path.write_text(text, encoding="utf-8")
    return path


def moved_lights(setup, offset_m=LIGHT_OFFSET_M, seed=7):
    """The rig with every light moved ``offset_m`` in a random direction."""
    rng = np.random.default_rng(seed)
    groups = []
    for g in setup.lights.groups:
        d = rng.normal(size=g.points_local_m.shape)
        d *= offset_m / np.linalg.norm(d, axis=1, keepdims=True)
        groups.append(replace(g, points_local_m=g.points_local_m + d))
    return replace(setup, lights=replace(setup.lights, groups=tuple(groups)))


def perturbed(setup, kind: str):
    """(setup, sensor model) of one perturbation: what the capture is really made with."""
    sensor = SensorModel.from_sensor(setup.sensor)
    line_s = setup.sensor.frame_period_s / setup.sensor.total_lines
    if kind == "nominal":
        return setup, sensor
    if kind == "S":  # the other OV5647 VGA mode's line count (524 at 640x480), same frame
        return replace(setup, sensor=replace(setup.sensor, total_lines=262)), sensor
    if kind == "phase":
        return replace(setup, strobe=replace(setup.strobe, phase_s=200e-6)), sensor
    if kind == "exposure":
        # One line shorter: one line longer (1.042 ms) is the strobe period (1.040 ms) to
        # 2.5 us, where every row collects the same light and the bands vanish.
        s = replace(setup.sensor, exposure_s=setup.sensor.exposure_s - line_s)
        return replace(setup, sensor=s), SensorModel.from_sensor(s)
    if kind == "gain":
        return setup, replace(sensor, analog_gain=1.2)
    if kind == "lights":
        return moved_lights(setup), sensor
    if kind == "radius":
        eye = setup.eye
        return replace(setup, eye=Eye.scaled(eye.rotation_center_m, 7.6e-3,
                                             refractive_index=eye.refractive_index)), sensor
    raise ValueError(kind)


def foreign_capture(folder, scene_path, kind: str, *, frames=FRAMES, seed=3, spp=SPP,
                    cornea=CORNEA) -> Path:
    """Render ``kind``'s perturbed scene and replay it as a capture of the nominal scene."""
    folder = Path(folder)
    nominal = load_scene(scene_path)
    setup, sensor = perturbed(nominal, kind)
    text = Path(scene_path).read_text(encoding="utf-8")
    render_dataset(setup, folder / f"{kind}-dataset", frames=frames, spp=spp, cornea=cornea,
                   seed=seed, sensor=sensor, scene_text=text)
    return replay_dataset(folder / f"{kind}-dataset", folder / f"{kind}-capture",
                          scene=scene_path)


def blurred_capture(folder, scene_path, sigma_px: float, *, frames=FRAMES, seed=3) -> Path:
    """The unperturbed capture with every frame blurred by a ``sigma_px`` Gaussian after the
    sensor (a slightly defocused lens, as issue 30 measured it): the nominal render (reused
    when ``folder`` has it), its PNGs blurred and rounded, replayed as a capture."""
    import shutil

    import cv2

    folder = Path(folder)
    nominal = folder / "nominal-dataset"
    if not (nominal / "manifest.json").is_file():
        foreign_capture(folder, scene_path, "nominal", frames=frames, seed=seed)
    out = folder / f"blurred-{sigma_px:g}-dataset"
    shutil.copytree(nominal, out)
    for p in sorted((out / "frames").glob("*.png")):
        a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)
        b = cv2.GaussianBlur(a, (0, 0), sigma_px)
        cv2.imwrite(str(p), np.clip(np.rint(b), 0, 1023).astype(np.uint16))
    return replay_dataset(out, folder / f"blurred-{sigma_px:g}-capture", scene=scene_path)
