"""Which part of the eye each pixel sees: the regions whose mean radiance the renderer's
checks compare (``benchmarks/bench_cornea.py``'s bias table, ``bench_depth.py``, the path
depth test)."""

from __future__ import annotations

import numpy as np

from estimator.eye import eye_rotation_matrix

#: The regions :func:`region_labels` tells apart, in its index order.
REGIONS = ("iris", "pupil", "sclera", "skin")


def region_labels(renderer, yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """(H, W) int: the index into :data:`REGIONS` (-1: anything else) of what each pixel
    centre of ``renderer`` (a :class:`BandedRenderer`) sees at an eye pose: through the cornea
    by one refraction, past the sclera sphere's cap inside the limbus (cut away by its opacity
    mask, which ``ray_intersect`` does not see). Poses the renderer's eye."""
    mi = renderer.mi
    import drjit as dr

    es, cam = renderer.eye_scene, renderer.setup.camera
    es.set_pose(yaw_rad, pitch_rad)
    W, H = cam.width_px, cam.height_px
    idx = np.arange(W * H)
    film = mi.Point2f(mi.Float((idx % W + 0.5) / W), mi.Float((idx // W + 0.5) / H))
    ray, _ = es.sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
    if renderer.lens is not None:  # the chief ray through the lens (the pupil's centre)
        ray.o, ray.d = renderer.lens.rays(mi, film * mi.ScalarVector2f(W, H), mi.Point2f(0.5, 0.5))
    si = es.scene.ray_intersect(ray)
    shapes = {s.id(): s for s in es.scene.shapes()}
    on_cornea = si.shape == mi.ShapePtr(shapes["cornea"])
    _, cos_t, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(si.wi),
                                     renderer.setup.eye.refractive_index)
    inner = si.spawn_ray(si.to_world(mi.refract(si.wi, cos_t, eta_ti)))
    si2 = es.scene.ray_intersect(inner, on_cornea)
    gaze = eye_rotation_matrix(yaw_rad, pitch_rad) @ np.array([0.0, 0.0, -1.0])
    lay = es.layout
    cos_cap = lay.limbus_plane_m / np.hypot(lay.limbus_plane_m, lay.limbus_radius_m)
    sclera = mi.ShapePtr(shapes["sclera"])
    for _ in range(2):  # the cap is crossed at most twice
        p = si2.p
        cos_p = dr.dot(dr.normalize(p), mi.Vector3f(*(float(v) for v in gaze)))
        cut = on_cornea & (si2.shape == sclera) & (cos_p > cos_cap)
        si2 = dr.select(cut, es.scene.ray_intersect(si2.spawn_ray(inner.d), cut), si2)
    label = np.full(W * H, -1)
    for k, name in enumerate(REGIONS):
        ptr = mi.ShapePtr(shapes[name])
        hit = dr.select(on_cornea, si2.shape == ptr, si.shape == ptr)
        label[np.array(hit, dtype=bool)] = k
    return label.reshape(H, W)
