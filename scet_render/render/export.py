"""``scet export-mitsuba``: a scene description written as Mitsuba XML with its
meshes and textures, renderable unchanged by ``mitsuba scene.xml``.

Mitsuba's ``mitsuba`` command cannot load Python plugins, so the renderer's cornea BSDF
(:mod:`~scet_render.render.cornea_bsdf`) is written as Mitsuba's own ``dielectric``: the same
interface and the same image in the limit of many samples, its glints noisier at low spp.
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.setup import Setup

from .cornea_bsdf import CORNEA_BSDF_TYPE
from .layout import SceneOptions
from .scene import describe_scene

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------- export

_TAGS = {"scene": "scene", "path": "integrator", "perspective": "sensor", "independent": "sampler",
         "hdrfilm": "film", "box": "rfilter", "disk": "shape", "sphere": "shape", "ply": "shape",
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
    if setup.camera.has_distortion or setup.camera.is_thin_lens:
        log.warning("export-mitsuba: %s's lens (distortion, thin lens) is not written: Mitsuba's "
                    "perspective sensor is a pinhole (SCET renders the lens with its own rays)",
                    setup.name)
    desc = describe_scene(setup, options, spp=spp, yaw_rad=yaw_rad, pitch_rad=pitch_rad)
    import cv2

    out = Path(out_dir)
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
