"""A dataset's manifest: what made it (scene, settings, software), and the checks
that let a rerun resume it or refuse a folder of another run.
"""

from __future__ import annotations

import hashlib
import json
from importlib import metadata
from pathlib import Path

import numpy as np

from estimator.checks import Doc, load_json
from estimator.formats import check_format
from estimator.inputs import MAX_FRAMES
from estimator.setup import Setup

from ..render import SensorModel
from .effective import effective_scene_text, plain_value
from .format import (
    FORMAT,
    FRAMES_DIR,
    LABELS_NAME,
    MANIFEST_NAME,
    PARTIAL_SUFFIX,
    VERSION,
    DatasetError,
    DatasetMismatchError,
)

# --------------------------------------------------------------------------- manifest

#: Largest image side a manifest may claim (px).
MAX_IMAGE_SIDE_PX = 16384


def _manifest(setup: Setup, text: str, *, frames, spp, kind, seed, variant, cornea,
              sensor: SensorModel) -> dict:
    scene = {
        "name": setup.name,
        "file": Path(setup.source).name if setup.source else "",
        "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
        "toml": text,
    }
    effective = effective_scene_text(setup, text)
    if effective.overridden:
        # The frames' own scene (a scaled camera, a planned strobe, ...): what calibrate,
        # track, compare and score load. The file's sha256 stays on record beside it.
        scene.update(sha256=hashlib.sha256(effective.text.encode("utf-8")).hexdigest(),
                     toml=effective.text, file_sha256=scene["sha256"],
                     overridden=effective.overridden)
    if effective.differs:  # what the text could not carry: readers warn about it
        scene["differs"] = effective.differs
    return {
        "format": FORMAT,
        "version": VERSION,
        "scene": scene,
        "setup_sha256": setup_fingerprint(setup),
        "software": software_versions(),
        "seed": seed,
        "trajectory": kind,
        "frames": frames,
        "image": {"width_px": setup.camera.width_px, "height_px": setup.camera.height_px,
                  "png_bit_depth": 8 if sensor.bit_depth <= 8 else 16},
        "render": {"spp": spp, "variant": variant, "cornea": cornea, "renderer": None},
        "sensor": sensor.to_dict(),
        "files": {"radiance": f"{FRAMES_DIR}/{{frame:06d}}.exr",
                  "sensor": f"{FRAMES_DIR}/{{frame:06d}}.png", "labels": LABELS_NAME},
    }


def _manifest_bytes(manifest: dict) -> bytes:
    return (json.dumps(manifest, indent=2, allow_nan=False) + "\n").encode("utf-8")


def software_versions() -> dict:
    """Versions of the packages whose behaviour shapes a dataset's bytes ("absent" if missing)."""
    import cv2

    def version(dist):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "absent"

    return {"scet": version("scet"), "numpy": np.__version__, "mitsuba": version("mitsuba"),
            "drjit": version("drjit"), "openexr": version("OpenEXR"), "opencv": cv2.__version__}


def setup_fingerprint(setup: Setup) -> str:
    """sha256 of every field of a Setup (arrays and floats exactly), except its source path."""
    text = json.dumps(plain_value(setup), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _scene_text(setup: Setup, scene_text: str | None) -> str:
    if scene_text is not None:
        if not isinstance(scene_text, str):
            raise ValueError("scene_text must be the scene's TOML text (a str)")
        return scene_text
    path = Path(setup.source)
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read the scene file {setup.source!r} named by the setup ({exc}); "
                         "pass scene_text=") from None
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    if setup.source_sha256 and digest != setup.source_sha256:
        raise ValueError(f"{path}: the file changed since the setup was loaded (sha256 differs "
                         "from setup.source_sha256); reload it or pass scene_text=")
    return text


def _compare_manifests(found: dict, expected: dict, path: Path, *, before_renderer: bool = False,
                       ignore_variant: bool = False) -> None:
    """Raise DatasetMismatchError naming every entry where ``found`` differs from ``expected``.

    ``before_renderer`` skips what only the renderer knows (its settings; with
    ``ignore_variant``, also the variant that None resolves to).
    """
    want = json.loads(_manifest_bytes(expected))
    # The machine that rendered (CPU, LLVM features) is on record, not compared: the bytes
    # depend on the backend's vector width, which is (render.renderer.llvm).
    skip = {"render.llvm_host"}
    if before_renderer:
        skip.add("render.renderer")
        if ignore_variant:
            skip.add("render.variant")
    diffs = []

    def walk(a, b, where):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b)):
                name = f"{where}.{key}" if where else key
                if name not in skip:
                    walk(a.get(key, "<missing>"), b.get(key, "<missing>"), name)
        elif a != b:
            diffs.append((where, a, b))

    walk(found, want, "")
    if diffs:
        def short(v):
            s = json.dumps(v) if not isinstance(v, str) else repr(v)
            return s if len(s) <= 80 else s[:77] + "..."

        lines = "; ".join(f"{k}: dataset has {short(a)}, this run wants {short(b)}"
                          for k, a, b in diffs)
        raise DatasetMismatchError(
            f"{path}: the folder holds another dataset ({lines}). Use another output folder, or "
            "rerun with the dataset's arguments to resume it")


def _prepare_folder(out: Path) -> dict | None:
    """Existing manifest (None for a new dataset); removes partial files of a killed run."""
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{out}: exists and is not a folder")
    if not out.exists():
        return None
    manifest = out / MANIFEST_NAME
    frames_dir = out / FRAMES_DIR
    if not manifest.exists():
        foreign = [p.name for p in out.iterdir()
                   if not p.name.endswith(PARTIAL_SUFFIX)
                   and not (p == frames_dir and p.is_dir() and not any(frames_dir.iterdir()))]
        if foreign:
            raise DatasetError(f"{out}: not empty and not a SCET dataset (no {MANIFEST_NAME}; "
                               f"found {sorted(foreign)[:5]}); refusing to write into it")
    for folder in (out, frames_dir):
        if folder.is_dir():
            for p in folder.iterdir():
                if p.name.endswith(PARTIAL_SUFFIX) and p.is_file():
                    p.unlink()
    return read_manifest(out) if manifest.exists() else None


# --------------------------------------------------------------------------- reading


def read_manifest(path) -> dict:
    """The manifest of a dataset folder, after checking its format and version.

    Parameters
    ----------
    path : str or Path
        The dataset folder (or its ``manifest.json``).

    Raises
    ------
    DatasetError
        Missing, unreadable, another format or version, or a field the readers use
        (``frames``, ``image``, ``scene.toml``, ``seed``, ``trajectory``) of the wrong type or
        range (:mod:`estimator.checks`; the message names the key).
    """
    path = Path(path)
    file = path if path.name == MANIFEST_NAME and path.is_file() else path / MANIFEST_NAME
    if not file.exists():
        raise DatasetError(f"{file}: no such file; not a SCET dataset")
    data = load_json(file, DatasetError)
    check_format(data, file, FORMAT, VERSION, DatasetError)
    doc = Doc(data, file, error=DatasetError)
    doc.integer("frames", lo=1, hi=MAX_FRAMES)
    image = doc.obj("image")
    for key in ("width_px", "height_px"):
        image.integer(key, lo=1, hi=MAX_IMAGE_SIDE_PX)
    if image.integer("png_bit_depth") not in (8, 16):
        raise image.error("png_bit_depth", f"expected 8 or 16, got {image.data['png_bit_depth']}")
    doc.obj("scene").string("toml")
    doc.integer("seed", lo=0)
    doc.string("trajectory")
    return data
