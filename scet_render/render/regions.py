"""Which part of the eye each pixel sees: the regions whose mean radiance the renderer's
checks compare (``benchmarks/bench_cornea.py``'s bias table, ``bench_depth.py``, the path
depth test), and the dataset's segmentation masks (``frames/NNNNNN_mask.png``).

A pixel's class is what the ray through its centre meets first, as the renderer draws it:
through the corneal cap by one refraction (Mitsuba's own ``refract`` at the surface it
intersects: the sphere, or the conic's ellipsoid), past what the opacity masks cut away (the
sclera sphere's cap inside the limbus, and the conic ellipsoid beyond the limbus; masks that
``ray_intersect`` does not see, so the rays are continued through them here). A banded frame's
mask follows the eye like the image: each row is classified at the pose of the strobe that
lights it most (rows no strobe lights: the ambient instant that weighs most,
:class:`~scet_render.render.rolling_shutter.FramePlan`), and glints are painted over it where
their labels say, in the rows their strobe lights (:func:`frame_mask`).
"""

from __future__ import annotations

import math

import numpy as np

from estimator.eye import eye_rotation_matrix

#: The regions :func:`region_labels` tells apart, in its index order.
REGIONS = ("iris", "pupil", "sclera", "skin")
#: The segmentation mask's classes; a pixel's value is the index (``frames/NNNNNN_mask.png``).
#: ``none``: nothing of the eye or face (a light seen directly, the environment, a ray that
#: leaves the cornea again without meeting the iris).
MASK_CLASSES = ("none", "skin", "sclera", "iris", "pupil", "lid", "lash", "glint")
#: Mitsuba shape ids -> mask class (every other shape: ``none``).
_SHAPE_CLASS = {"skin": "skin", "face": "skin", "sclera": "sclera", "iris": "iris",
                "pupil": "pupil", "lid_upper": "lid", "lid_lower": "lid",
                "lid_upper_surface": "lid", "lid_lower_surface": "lid", "lashes": "lash"}
#: Shape ids of the cornea: the analytic sphere, a mesh cap, or the conic's unit sphere inside
#: its shapegroup (what an instance's hit reports).
_CORNEA_IDS = ("cornea", "surface")
#: Transparent parts a ray is continued through, at most this many times: from outside, the
#: conic's ellipsoid beyond the limbus (in and out); inside the cap, the sclera sphere's
#: cut-away cap (it bulges in front of the limbus plane: crossed once before the iris).
_PASSES = 2
#: A frame whose instants' eye poses differ by less than this on the eyeball's surface (and
#: pupil edges by less) is classified once, at its first instant (px): far below the half
#: pixel at which a pixel centre's class can change; a fixation's frame takes one
#: classification instead of one per band.
MASK_SAME_POSE_PX = 0.05
#: The last scene's shape ids (its registry ids do not change while it lives).
_IDS: dict = {}


def _shape_ids(mi, scene) -> dict[int, str]:
    """{registry id of a shape: its Mitsuba id}, shapes inside shapegroups included."""
    import drjit as dr

    if _IDS.get("scene") is scene:
        return _IDS["ids"]
    found = {s.id(): s for s in scene.shapes()}
    params = mi.traverse(scene)
    for key in params.keys():
        node = params.properties[key][2]
        if isinstance(node, mi.Shape):
            found.setdefault(node.id(), node)
    ids = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]): name
           for name, s in found.items()}
    _IDS.clear()
    _IDS.update(scene=scene, ids=ids)
    return ids


#: The registry id that stands for "nothing seen".
_NONE = 0xFFFFFFFF


def _trace(mi, scene, ray, g, center, plane, cos_cap, eta, sclera, cornea):
    """Dr.Jit core of :func:`classify_rays`: a UInt32 registry id per ray (:data:`_NONE`)."""
    import drjit as dr

    def is_(si, wanted):
        ptr = dr.reinterpret_array(mi.UInt32, si.shape)
        hit = mi.Bool(False)
        for w in wanted:
            hit |= si.is_valid() & (ptr == w)
        return hit

    def through_cut(si, d, active):
        """Continue rays through the parts the opacity masks cut away."""
        for _ in range(_PASSES):
            rel = si.p - center
            sclera_cut = is_(si, [sclera]) & (dr.dot(dr.normalize(rel), g) > cos_cap)
            cornea_cut = is_(si, cornea) & (dr.dot(rel, g) <= plane)
            cut = active & (sclera_cut | cornea_cut)
            si = dr.select(cut, scene.ray_intersect(si.spawn_ray(d), cut), si)
        return si

    si = through_cut(scene.ray_intersect(ray), ray.d, mi.Bool(True))
    on_cornea = is_(si, cornea)
    _, cos_t, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(si.wi), eta)
    inner = si.spawn_ray(si.to_world(mi.refract(si.wi, cos_t, eta_ti)))
    si2 = through_cut(scene.ray_intersect(inner, on_cornea), inner.d, on_cornea)
    seen = dr.select(on_cornea, si2, si)
    hit = dr.select(seen.is_valid(), dr.reinterpret_array(mi.UInt32, seen.shape), _NONE)
    # A ray that leaves through the cornea again (grazing) sees nothing of the eye.
    return dr.select(is_(seen, cornea), _NONE, hit)


def _pose_inputs(eye_scene, gaze):
    """The pose's opaque inputs of :func:`_trace` (literals would compile anew per pose)."""
    mi = eye_scene.mi
    import drjit as dr

    from .layout import SCENE_UNITS_PER_M

    lay = eye_scene.layout
    center = mi.Point3f(*(dr.opaque(mi.Float, float(c)) for c in
                          eye_scene.setup.eye.rotation_center_m * SCENE_UNITS_PER_M))
    g = mi.Vector3f(*(dr.opaque(mi.Float, float(v)) for v in gaze))
    plane = dr.opaque(mi.Float, float(lay.limbus_plane_m * SCENE_UNITS_PER_M))
    cos_cap = dr.opaque(mi.Float, lay.limbus_plane_m / math.hypot(lay.limbus_plane_m,
                                                                  lay.limbus_radius_m))
    return {"g": g, "center": center, "plane": plane, "cos_cap": cos_cap}


def _special_ids(names):
    ids = {v: k for k, v in names.items()}
    return ids.get("sclera", _NONE), [ids[c] for c in _CORNEA_IDS if c in ids]


def _to_numpy(hit) -> np.ndarray:
    out = np.asarray(hit, dtype=np.int64)
    out[out == _NONE] = -1
    return out


def classify_rays(eye_scene, ray, gaze):
    """What each ray (``mi.Ray3f``, scene units) sees first, as the renderer draws it (module
    docstring), with the eye at the pose whose unit gaze is ``gaze`` (the scene's current).

    Returns
    -------
    hit : (k,) int64
        The registry id of the shape each ray sees (-1: none).
    names : dict of int -> str
        Registry id -> the shape's Mitsuba id.
    """
    mi = eye_scene.mi
    names = _shape_ids(mi, eye_scene.scene)
    sclera, cornea = _special_ids(names)
    hit = _trace(mi, eye_scene.scene, ray, **_pose_inputs(eye_scene, gaze),
                 eta=eye_scene.setup.eye.refractive_index, sclera=sclera, cornea=cornea)
    return _to_numpy(hit), names


#: Frozen classification kernels: (scene id, rows) -> function (JIT variants).
_KERNELS: dict = {}


def _rows_kernel(eye_scene, n_rows: int, lens=None):
    """A ``dr.freeze``-recorded classification of ``n_rows`` image rows from an opaque first
    row (pixel centres; through ``lens``'s chief rays, :class:`~scet_render.render.lens.LensRays`,
    when the camera has one), replayed at every pose like the renderer's band kernels: a pose's
    classification costs its rays, not a trace of the Python above."""
    key = (id(eye_scene.scene), n_rows, id(lens))
    if _KERNELS.get("scene") is not eye_scene.scene:
        _KERNELS.clear()
        _KERNELS["scene"] = eye_scene.scene
    if key not in _KERNELS:
        import drjit as dr

        mi = eye_scene.mi
        cam = eye_scene.setup.camera
        W, H = cam.width_px, cam.height_px
        sclera, cornea = _special_ids(_shape_ids(mi, eye_scene.scene))
        eta = eye_scene.setup.eye.refractive_index

        def kernel(scene, sensor, row0, lanes, pose):
            idx = dr.arange(mi.UInt32, dr.width(lanes))
            film = mi.Point2f(mi.Float(idx % W) + 0.5, mi.Float(idx // W + row0) + 0.5)
            ray, _ = sensor.sample_ray(0.0, 0.5, film * mi.ScalarVector2f(1.0 / W, 1.0 / H),
                                       mi.Point2f(0.5, 0.5))
            if lens is not None:  # the chief ray through the lens (the pupil's centre)
                ray.o, ray.d = lens.rays(mi, film, mi.Point2f(0.5, 0.5))
            hit = _trace(mi, scene, ray, **pose, eta=eta, sclera=sclera, cornea=cornea)
            dr.eval(hit)
            return hit

        _KERNELS[key] = dr.freeze(kernel)
    return _KERNELS[key]


def _pixel_rays(eye_scene, rows, lens=None):
    """Rays through the pixel centres of image ``rows`` ((k,) int), row-major (the chief rays of
    ``lens`` when the camera has one)."""
    mi = eye_scene.mi
    cam = eye_scene.setup.camera
    W, H = cam.width_px, cam.height_px
    rows = np.asarray(rows, dtype=np.int64)
    u = np.tile(np.arange(W), rows.size)
    v = np.repeat(rows, W)
    film = mi.Point2f(mi.Float((u + 0.5) / W), mi.Float((v + 0.5) / H))
    ray, _ = eye_scene.sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
    if lens is not None:
        ray.o, ray.d = lens.rays(mi, film * mi.ScalarVector2f(W, H), mi.Point2f(0.5, 0.5))
    return ray


def _lookup(hit, names, table: dict, default: int) -> np.ndarray:
    """Map registry ids to ``table[shape id]`` (``default`` for ids not in it and for -1)."""
    out = np.full(hit.shape, default, dtype=np.int64)
    for ptr, name in names.items():
        if name in table:
            out[hit == ptr] = table[name]
    return out


def region_labels(renderer, yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """(H, W) int: the index into :data:`REGIONS` (-1: anything else) of what each pixel
    centre of ``renderer`` (a :class:`BandedRenderer`) sees at an eye pose (module docstring;
    ``skin`` is the skin shell around the eye, not the face beyond it). Poses the renderer's
    eye."""
    es, cam = renderer.eye_scene, renderer.setup.camera
    es.set_pose(yaw_rad, pitch_rad)
    gaze = eye_rotation_matrix(yaw_rad, pitch_rad) @ np.array([0.0, 0.0, -1.0])
    hit, names = classify_rays(es, _pixel_rays(es, np.arange(cam.height_px),
                                                getattr(renderer, "lens", None)), gaze)
    label = _lookup(hit, names, {name: k for k, name in enumerate(REGIONS)}, -1)
    return label.reshape(cam.height_px, cam.width_px)


def pose_mask(renderer, yaw_rad: float, pitch_rad: float, *, closure: float = 0.0,
              pupil_radius_m: float | None = None, rows=None) -> np.ndarray:
    """(len(rows), W) uint8 :data:`MASK_CLASSES` of image ``rows`` (default: all; ascending)
    with the eye at one pose, without glints. Poses the renderer's eye. JIT variants replay a
    frozen kernel per run of consecutive rows (:func:`_rows_kernel`)."""
    from .backend import is_jit_variant

    es, cam = renderer.eye_scene, renderer.setup.camera
    lens = getattr(renderer, "lens", None)
    rows = np.arange(cam.height_px) if rows is None else np.asarray(rows, dtype=np.int64)
    es.set_pose(yaw_rad, pitch_rad, closure, pupil_radius_m)
    gaze = eye_rotation_matrix(yaw_rad, pitch_rad) @ np.array([0.0, 0.0, -1.0])
    table = {name: MASK_CLASSES.index(c) for name, c in _SHAPE_CLASS.items()}
    names = _shape_ids(es.mi, es.scene)
    if not is_jit_variant(es.mi.variant()):
        hit, _ = classify_rays(es, _pixel_rays(es, rows, lens), gaze)
        return _lookup(hit, names, table, 0).astype(np.uint8).reshape(rows.size, cam.width_px)
    import drjit as dr

    mi = es.mi
    out = np.zeros((rows.size, cam.width_px), dtype=np.uint8)
    pose = _pose_inputs(es, gaze)
    breaks = np.flatnonzero(np.diff(rows) != 1) + 1
    at = 0
    for run in np.split(rows, breaks):
        hit = _rows_kernel(es, run.size, lens)(es.scene, es.sensor, dr.opaque(mi.UInt32, int(run[0])),
                                         dr.zeros(mi.UInt32, run.size * cam.width_px), pose)
        out[at:at + run.size] = _lookup(_to_numpy(hit), names, table, 0).reshape(
            run.size, cam.width_px)
        at += run.size
    return out


def glint_radius_px(setup, cornea_center_m) -> np.ndarray:
    """(n,) radius (px) of each light's glint: the virtual image of its sphere (radius rho,
    distance D from the cornea) in a convex mirror of radius R is rho R / (2 D + R) across
    (paraxial), seen from the camera at distance d: f rho R / ((2 D + R) d)."""
    R = setup.eye.cornea_radius_m
    lights = setup.lights_world_m
    rho = np.array([g.source_radius_m for g in setup.lights.groups for _ in range(g.count)])
    D = np.linalg.norm(lights - cornea_center_m, axis=-1) - R
    d = np.linalg.norm(setup.camera.position_m - cornea_center_m) - R
    return setup.camera.fx_px * rho * R / ((2.0 * D + R) * d)


def paint_glints(mask, rows, glints_px, visible, radius_px) -> None:
    """Mark ``glint`` in the (H, W) ``mask``'s ``rows`` ((H,) bool) on every pixel whose square
    overlaps a visible glint's disk (centre ``glints_px`` (n, 2), radius (n,))."""
    H, W = mask.shape
    g = MASK_CLASSES.index("glint")
    for (u, v), ok, r in zip(np.asarray(glints_px), np.asarray(visible), np.asarray(radius_px)):
        if not (ok and np.isfinite(u) and np.isfinite(v)):
            continue
        u0, u1 = max(0, math.floor(u - r - 0.5)), min(W - 1, math.ceil(u + r + 0.5))
        v0, v1 = max(0, math.floor(v - r - 0.5)), min(H - 1, math.ceil(v + r + 0.5))
        for y in range(v0, v1 + 1):
            if not rows[y]:
                continue
            for x in range(u0, u1 + 1):
                # Distance from the disk's centre to the pixel's square [x +- 0.5, y +- 0.5].
                du = max(abs(u - x) - 0.5, 0.0)
                dv = max(abs(v - y) - 0.5, 0.0)
                if du * du + dv * dv < r * r or (du == 0.0 and dv == 0.0):
                    mask[y, x] = g


def frame_mask(renderer, trajectory, frame_index: int, labels) -> np.ndarray:
    """(H, W) uint8 segmentation mask of a banded frame (module docstring).

    Parameters
    ----------
    renderer : BandedRenderer
    trajectory : Trajectory
    frame_index : int
    labels : list of dict
        The frame's labels (:func:`scet_render.dataset.frame_labels`): each strobe's
        ``glints_px`` and ``glints_visible`` place its glints.

    Returns
    -------
    (H, W) uint8
        Indices into :data:`MASK_CLASSES`.
    """
    from ..motion.pupil import pupil_diameters

    plan = renderer.plan(trajectory, frame_index)
    H, W = renderer.setup.camera.height_px, renderer.setup.camera.width_px
    M = plan.times_s.size
    strobe_w = np.zeros((H, M))
    for k in np.flatnonzero(plan.pulse_column >= 0):
        strobe_w[:, k] = plan.row_weights[:, plan.pulse_column[k]]
    lit = strobe_w.max(axis=1) > 0
    choice = np.where(lit, strobe_w.argmax(axis=1), plan.ambient_weights_s.argmax(axis=1))
    yaw, pitch = (np.atleast_1d(a) for a in trajectory.angles_at(plan.times_s))
    closure = getattr(trajectory, "lid_closure_at", None)
    closure = np.zeros(M) if closure is None else np.atleast_1d(closure(plan.times_s))
    pupil = pupil_diameters(trajectory, plan.times_s, 2.0 * renderer.options.pupil_radius_m)
    mask = np.zeros((H, W), dtype=np.uint8)
    setup = renderer.setup
    eye = setup.eye
    # Pixels of eyeball surface per radian of rotation (motion_instants' measure), and of
    # the pupil's edge per metre of its radius.
    px_per_rad = setup.camera.fx_px * (eye.cornea_offset_m + eye.cornea_radius_m) / float(
        np.linalg.norm(setup.camera.position_m - eye.rotation_center_m))
    px_per_m = setup.camera.fx_px / float(np.linalg.norm(setup.camera.position_m
                                                          - eye.rotation_center_m))
    used = np.unique(choice)
    moved = (np.abs(yaw[used] - yaw[used[0]]) + np.abs(pitch[used] - pitch[used[0]])) * px_per_rad
    grown = 0.5 * np.abs(pupil[used] - pupil[used[0]]) * px_per_m
    if (np.all(np.maximum(moved, grown) < MASK_SAME_POSE_PX)
            and np.all(closure[used] == closure[used[0]])):
        # Nothing moves by more than MASK_SAME_POSE_PX (a fixation): one classification.
        k = used[0]
        mask[:] = pose_mask(renderer, yaw[k], pitch[k], closure=closure[k],
                            pupil_radius_m=0.5 * pupil[k])
    else:
        for k in used:
            rows = np.flatnonzero(choice == k)
            mask[rows] = pose_mask(renderer, yaw[k], pitch[k], closure=closure[k],
                                   pupil_radius_m=0.5 * pupil[k], rows=rows)
    by_strobe = {int(lb["strobe"]): lb for lb in labels}
    for col, j in enumerate(plan.pulse_indices):
        lb = by_strobe.get(int(j))
        if lb is None:
            continue
        glints = np.array([g if g is not None else [np.nan, np.nan] for g in lb["glints_px"]])
        radius = glint_radius_px(renderer.setup, np.asarray(lb["cornea_center_m"]))
        paint_glints(mask, plan.row_weights[:, col] > 0, glints, lb["glints_visible"], radius)
    return mask
