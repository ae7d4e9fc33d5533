"""``--scene`` of ``scet calibrate``, ``scet track``, ``scet compare`` and ``scet score``: by
default the scene the input folder records, else the one the user names.

A folder records its scene in one of three places, looked up in this order:

1. ``manifest.json`` (a rendered dataset, also one written with ``scet render --raw``): its
   ``scene.toml``, the effective scene the frames were rendered with
   (:mod:`scet_render.dataset.effective`);
2. ``scene.toml`` beside the frames (calibration frames of ``scet render --calibration`` and
   ``scet validate``);
3. ``capture.json`` (a prototype capture): its optional ``scene`` object with a ``toml`` key.

Without ``--scene`` the recorded scene is used; with it, the named scene is used and a warning
names the tables in which it differs from the recorded one. A folder that records no scene
needs ``--scene``. The command prints which scene it used.
"""

from __future__ import annotations

import sys
from pathlib import Path

from estimator.errors import InputError

__all__ = ["FolderSceneError", "recorded_scene", "folder_scene", "describe_lens"]


class FolderSceneError(InputError):
    """A folder records no scene (and none was named), or records one that does not load."""


def recorded_scene(folder):
    """The scene a folder records, where, and what it does not describe of the frames:
    ``(setup, place, differs)``, or ``(None, None, [])``.

    Parameters
    ----------
    folder : str or Path
        A dataset, calibration-frames or capture folder.

    Returns
    -------
    setup : Setup or None
    place : str or None
        The file (and key) the scene was read from (``".../manifest.json (its scene.toml)"``).
    differs : list of str
        Setup fields in which the frames were rendered otherwise than the record says (a
        setup changed in code beyond what a scene file carries; ``scene.differs``).

    Raises
    ------
    DatasetError, CaptureError, SceneError
        The record exists but cannot be read, or its scene does not parse (the message names
        the file and key).
    """
    from estimator.capture.folder import CAPTURE_NAME, CaptureError
    from estimator.formats import read_json
    from estimator.scene import load_scene, parse_scene

    from .dataset.effective import DIFFERS_MARK, SCENE_NAME
    from .dataset.format import MANIFEST_NAME
    from .dataset.manifest import read_manifest

    folder = Path(folder)
    if (folder / MANIFEST_NAME).is_file():
        manifest = read_manifest(folder)  # checks format, version and that scene.toml is text
        place = f"{folder / MANIFEST_NAME} (its scene.toml)"
        setup = parse_scene(manifest["scene"]["toml"], source=place)
        differs = manifest["scene"].get("differs")
        return setup, place, [str(d) for d in differs] if isinstance(differs, list) else []
    if (folder / SCENE_NAME).is_file():
        setup = load_scene(folder / SCENE_NAME)
        first = (folder / SCENE_NAME).read_text(encoding="utf-8").partition("\n")[0]
        differs = first[len(DIFFERS_MARK):].strip().split(", ") if first.startswith(
            DIFFERS_MARK) else []
        return setup, str(folder / SCENE_NAME), differs
    head = folder / CAPTURE_NAME
    if head.is_file():
        header = read_json(head, CaptureError)
        scene = header.get("scene") if isinstance(header, dict) else None
        if scene is None:
            return None, None, []
        if not isinstance(scene, dict) or not isinstance(scene.get("toml"), str):
            raise CaptureError(f"{head}: key 'scene.toml' must be the scene's TOML text")
        place = f"{head} (its scene.toml)"
        return parse_scene(scene["toml"], source=place), place, []
    return None, None, []


def folder_scene(folder, scene, command: str):
    """The setup a command works with on ``folder``: ``scene`` (a name or file) if given,
    else the folder's recorded scene. Prints which it used; warns (stderr) where ``scene``
    differs from the record.

    Parameters
    ----------
    folder : str or Path
    scene : str or None
        The ``--scene`` argument.
    command : str
        ``"scet track"``, ... (names the warning).

    Returns
    -------
    Setup

    Raises
    ------
    FolderSceneError
        No ``scene`` and the folder records none.
    DatasetError, CaptureError, SceneError
        As :func:`recorded_scene`, or ``scene`` does not load.
    """
    from estimator.scene import load_scene

    from .dataset.effective import setup_differences

    folder = Path(folder)
    if scene is None:
        if not folder.is_dir():
            raise FolderSceneError(f"{folder}: no such folder")
        setup, place, differs = recorded_scene(folder)
        if setup is None:
            raise FolderSceneError(f"{folder}: records no scene (no manifest.json, scene.toml "
                                   "or capture.json with a scene); pass --scene")
        print(f"scene: {setup.name}, from {place}")
        if differs:
            print(f"{command}: warning: {place} says the frames were rendered with another "
                  f"{', '.join(differs)} than it records", file=sys.stderr)
        return setup
    setup = load_scene(scene)
    print(f"scene: {setup.name}, from --scene {scene}")
    if folder.is_dir():
        try:
            recorded, place, _ = recorded_scene(folder)
        except InputError as exc:  # the user's --scene stands; say why no check was made
            print(f"{command}: warning: cannot read the folder's own scene ({exc}); "
                  f"using --scene {scene}", file=sys.stderr)
            return setup
        if recorded is not None:
            diffs = setup_differences(recorded, setup)
            if diffs:
                print(f"{command}: warning: --scene {scene} differs from the scene in {place} "
                      f"({', '.join(diffs)}); using --scene", file=sys.stderr)
    return setup


def describe_lens(cam) -> str:
    """The ``scet scene`` line of a camera's lens (empty for a pinhole)."""
    import numpy as np

    parts = []
    if cam.has_distortion:
        corner = cam.undistort_px([[-0.5, -0.5], [cam.width_px - 0.5, cam.height_px - 0.5]])
        shift = np.hypot(*(corner - [[-0.5, -0.5], [cam.width_px - 0.5, cam.height_px - 0.5]]).T)
        parts.append(f"distortion {np.round(cam.distortion, 4).tolist()} (corners move "
                     f"{np.nanmax(shift):.1f} px)")
    if cam.is_thin_lens:
        parts.append(f"F{cam.f_number:g} focused at {cam.focus_distance_m * 1e3:g} mm "
                     f"(f = {cam.focal_length_m * 1e3:.2f} mm, pupil {2e3 * cam.aperture_radius_m:.2f} mm)")
    return ("\n  lens " + ", ".join(parts)) if parts else ""
