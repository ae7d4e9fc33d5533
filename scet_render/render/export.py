"""``scet export-mitsuba``: a scene description written as Mitsuba XML with its
meshes and textures, renderable unchanged by ``mitsuba scene.xml``.

Mitsuba's ``mitsuba`` command cannot load Python plugins, so the renderer's cornea BSDF
(:mod:`~scet_render.render.cornea_bsdf`) is written as Mitsuba's own ``dielectric``: the same
interface and the same image in the limit of many samples, its glints noisier at low spp.

The lens (:mod:`~scet_render.render.lens`): SCET renders it with its own rays, which a plain
``scene.xml`` cannot carry. What Mitsuba's own sensors can express is written:

* the thin lens (defocus): Mitsuba's ``thinlens`` sensor, with the same entrance pupil
  (``aperture_radius`` = f / (2 N)) and the same focus plane z = d_f in the camera frame
  (``focus_distance``), when the principal point is the film's centre (``thinlens`` has no
  principal point offset); otherwise the ``perspective`` pinhole, and the XML says the defocus
  is missing;
* the distortion: no Mitsuba 3 sensor has one, so the exported scene renders the *undistorted*
  (pinhole-projection) image. The lens is written beside it as ``camera.json``
  (``scet-camera``, docs/formats/camera.md: K, the OpenCV coefficients, the image size), and
  the XML names it: a distorted frame is the render resampled at the ideal pixel of each
  distorted pixel, ``cv2.remap(render, *map)`` with ``map`` from ``cv2.undistortPoints(pixels,
  K, distortion, P=K)`` (read as an array, the render's pixel [v, u] is OpenCV's pixel (u, v),
  DESIGN.md's convention). The remap
  interpolates the rendered image, which the renderer's own lens rays do not: it is not
  byte-identical to ``scet render``'s frames, and a glint narrower than a pixel is smoothed.
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.setup import Setup

from .cornea_bsdf import CORNEA_BSDF_TYPE
from .layout import SCENE_UNITS_PER_M, SceneOptions
from .scene import describe_scene

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------- export

_TAGS = {"scene": "scene", "path": "integrator", "perspective": "sensor", "independent": "sampler",
         "thinlens": "sensor", "hdrfilm": "film", "box": "rfilter", "disk": "shape",
         "sphere": "shape", "ply": "shape",
         "diffuse": "bsdf", "twosided": "bsdf", "dielectric": "bsdf", "conductor": "bsdf",
         "mask": "bsdf", "bitmap": "texture", "area": "emitter", "constant": "emitter",
         "shapegroup": "shape", "instance": "shape"}


def _xml_node(parent, key, value):
    if isinstance(value, dict) and value.get("type") == "rgb":
        ET.SubElement(parent, "rgb", name=key, value=", ".join(f"{v:.9g}" for v in value["value"]))
    elif isinstance(value, dict) and value.get("type") == "ref":
        ET.SubElement(parent, "ref", id=value["id"], name=key)
    elif isinstance(value, dict):
        node = ET.SubElement(parent, _TAGS[value["type"]], type=value["type"], id=key)
        if _TAGS[value["type"]] == "texture":
            node.attrib["name"] = node.attrib.pop("id")  # the parameter it feeds
        elif _TAGS[value["type"]] != "shape":
            del node.attrib["id"]
        for k, v in value.items():
            if k != "type":
                _xml_node(node, k, v)
    elif isinstance(value, np.ndarray):
        t = ET.SubElement(parent, "transform", name=key)
        ET.SubElement(t, "matrix", value=" ".join(f"{v:.17g}" for v in value.ravel()))
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=key, value=str(value).lower())
    elif isinstance(value, int):
        ET.SubElement(parent, "integer", name=key, value=str(value))
    elif isinstance(value, float):
        ET.SubElement(parent, "float", name=key, value=f"{value:.17g}")
    elif isinstance(value, str):
        ET.SubElement(parent, "string", name=key, value=value)
    elif isinstance(value, list) and len(value) == 3:
        ET.SubElement(parent, "point", name=key, **{a: f"{v:.17g}" for a, v in zip("xyz", value)})
    else:
        raise ValueError(f"cannot write scene entry {key!r} = {value!r} as Mitsuba XML")


def _plain_dielectric(bsdf: dict) -> dict:
    """Mitsuba's ``dielectric`` with the interface of a :data:`CORNEA_BSDF_TYPE` entry."""
    return {"type": "dielectric", "int_ior": bsdf["int_ior"], "ext_ior": bsdf["ext_ior"],
            "specular_transmittance": {"type": "rgb", "value": list(bsdf["transmittance"])}}


def _without_plugin(value, found: list):
    """``value`` with every :data:`CORNEA_BSDF_TYPE` entry, at any depth (an aspheric cornea
    nests it in a shapegroup and a mask), replaced by :func:`_plain_dielectric`; the replaced
    entries are appended to ``found``."""
    if not isinstance(value, dict):
        return value
    if value.get("type") == CORNEA_BSDF_TYPE:
        found.append(value)
        return _plain_dielectric(value)
    return {k: _without_plugin(v, found) for k, v in value.items()}


def _write_lens(setup: Setup, objects: dict, out: Path) -> list[str]:
    """Put the camera's thin lens into ``objects["camera"]`` where Mitsuba's ``thinlens`` can
    carry it, write ``camera.json`` for a distortion; the XML comments saying what is missing
    (module docstring)."""
    cam = setup.camera
    notes = []
    if cam.is_thin_lens:
        sensor = objects["camera"]
        centred = (abs(sensor["principal_point_offset_x"]) < 1e-12
                   and abs(sensor["principal_point_offset_y"]) < 1e-12)
        if centred:
            sensor = {k: v for k, v in sensor.items() if not k.startswith("principal_point")}
            sensor["type"] = "thinlens"
            sensor["aperture_radius"] = cam.aperture_radius_m * SCENE_UNITS_PER_M
            sensor["focus_distance"] = cam.focus_distance_m * SCENE_UNITS_PER_M
            objects["camera"] = sensor
            notes.append(f"camera: thin lens f/{cam.f_number:g} focused at "
                         f"{cam.focus_distance_m * 1e3:g} mm (Mitsuba's thinlens: "
                         f"aperture_radius {cam.aperture_radius_m * 1e3:.6g} mm)")
        else:
            notes.append("camera: the thin lens (defocus) is NOT written: Mitsuba's thinlens "
                         "has no principal point offset, and this camera's principal point is "
                         "off the film's centre; the sensor is the perspective pinhole")
    if cam.has_distortion:
        from estimator.lens import CameraFile, write_camera_file

        write_camera_file(CameraFile(cam.K, cam.distortion, cam.width_px, cam.height_px,
                                     model="given"), out / "camera.json")
        notes.append("camera: the lens distortion (OpenCV "
                     f"[{', '.join(f'{d:.6g}' for d in cam.distortion)}]) is NOT rendered: no "
                     "Mitsuba sensor has one, so this scene renders the undistorted image. The "
                     "lens is in camera.json beside this file: resample the render with "
                     "cv2.remap at cv2.undistortPoints(pixels, K, distortion, P=K) for the "
                     "distorted frame (scet_render/render/export.py)")
    for n in notes:
        if "NOT" in n:
            log.warning("export-mitsuba: %s: %s", setup.name, n)
    return notes


def export_mitsuba(setup: Setup, out_dir: str | Path, options: SceneOptions | None = None, *,
                   yaw_rad: float = 0.0, pitch_rad: float = 0.0, spp: int = 64) -> Path:
    """Write ``scene.xml``, ``meshes/*.ply`` and ``textures/*.png`` that ``mitsuba scene.xml``
    renders unchanged.

    Parameters
    ----------
    setup : Setup
    out_dir : path
        Created if needed; existing files of the same names are replaced.
    options : SceneOptions, optional
        Default: the renderer's defaults with ``channels="grey"`` (white lights and ambient).
    yaw_rad, pitch_rad : float
        Eye pose.
    spp : int
        Samples per pixel written into the sensor.

    Returns
    -------
    Path
        The XML file.
    """
    options = SceneOptions(channels="grey") if options is None else options
    desc = describe_scene(setup, options, spp=spp, yaw_rad=yaw_rad, pitch_rad=pitch_rad)
    import cv2

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lens_notes = _write_lens(setup, desc.objects, out)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    (out / "textures").mkdir(parents=True, exist_ok=True)
    for name, mesh in desc.meshes.items():
        mesh.export(out / "meshes" / f"{name}.ply", encoding="binary", vertex_normal=True)
    for name, data in desc.textures.items():
        # 16-bit: exact for a 0/1 mask, 1.5e-5 steps for an albedo texture; "raw" keeps
        # Mitsuba from linearising it as sRGB.
        if not cv2.imwrite(str(out / "textures" / f"{name}.png"),
                           np.round(np.clip(data, 0, 1) * 65535).astype(np.uint16)):
            raise OSError(f"cannot write {out / 'textures' / f'{name}.png'}")
    root = ET.Element("scene", version="3.0.0")
    for note in lens_notes:
        root.append(ET.Comment(f" {note} "))
    for key, value in desc.objects.items():
        if key != "type":
            found = []
            value = _without_plugin(value, found)
            for bsdf in found:
                root.append(ET.Comment(
                    f" {key}: SCET's cornea BSDF ({CORNEA_BSDF_TYPE}, reflection sampled with "
                    f"probability {bsdf['reflect_probability']:g}) is a Python plugin that the "
                    "mitsuba command cannot load: written as Mitsuba's dielectric (same image "
                    "in the limit, glints noisier at low spp) "))
            _xml_node(root, key, value)
    ET.indent(root)
    path = out / "scene.xml"
    atomic_write(path, f"<!-- SCET scene {setup.name}: yaw {yaw_rad:.9g} rad, pitch "
                       f"{pitch_rad:.9g} rad -->\n" + ET.tostring(root, encoding="unicode") + "\n")
    return path
