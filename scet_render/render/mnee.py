"""Strobe light through the cornea: manifold next-event estimation (MNEE) onto the iris and pupil.

Each strobe light is a sphere of 0.2 mm some 30 mm from the eye. Light reaches the iris only
through the cornea, a smooth dielectric: next-event estimation cannot connect through it, and
a path that leaves the iris by BSDF sampling hits the light about once in a thousand samples
(DESIGN.md, rendering notes). The renderer's ``path`` integrator therefore carries no strobe
light through the cornea (the cornea's strobe transmittance is 0 in ``channels="split"``), and
this module adds it back exactly, after Hanika, Droske and Fascione, "Manifold Next Event
Estimation" (EGSR 2015) and Zeltner, Georgiev and Jakob, "Specular Manifold Sampling" (SIGGRAPH
2020), for the one specular vertex a path from the iris to a light has here:

1. The camera ray's first hit is on the corneal cap (the quadric of the cornea, in front of the
   limbus plane): it refracts in with weight (1 - F) / n^2 (the dielectric's transmittance and
   the radiance scaling into the denser medium), and the refracted ray finds the iris or pupil
   point x (passing the sclera's cut-away cap, which the mask makes transparent).
2. A light k is picked uniformly and a point z on its sphere uniformly by area.
3. The point y on the corneal surface where Snell's law joins x and z is solved by Newton's
   method on the direction w(a, b) = normalize(w0 + a u1 + b u2) leaving x (w0 = the direction
   to z, the solution as n -> 1): the refracted ray from y(w) must pass through z. The residual
   is the refracted ray's crossing of the plane through z normal to w0, in that plane's basis.
   The solve runs in float64 with forward differences for the 2x2 Jacobian, from (a, b) = 0.
4. The generalised geometry term (the manifold Jacobian) follows from the same 2x2 Jacobian J:
   a patch da db of the parameters is a solid angle da db / |v|^3 at x (v = w0 + a u1 + b u2)
   and an area |det J| da db on the plane through z, which is |w0 . d| / |n_z . d| times the
   light's own area (d: the refracted direction). So per unit light area,
   dOmega_x / dA_z = |n_z . d| / (|w0 . d| |det J| |v|^3); with n = 1 it is cos_z / |x - z|^2.
5. The light's radiance L enters the cornea as L (1 - F(y)) n^2, the diffuse BSDF at x weighs it
   with its cosine, and the visibility of z from y is a shadow ray (lids, lashes, skin).

The estimate of one sample is then
``(1 - F0) / n^2 * f(x) cos * L (1 - F(y)) n^2 * dOmega_x/dA_z * K * 4 pi r^2``. The n^2 factors
cancel: they are kept to show where each belongs. Paths with further vertices inside the eye
(light the iris scatters back to itself off the cornea, much of it totally reflected) are left
out: against converged path tracing with 1.5 mm lights, MNEE reads the iris 1.3-3.0 % darker
(tests/scet_render/test_mnee.py).

Everything moving is an opaque Dr.Jit input (:func:`pose_state`), so the frozen per-band
kernels replay for every eye pose without recompiling. The independent references the tests
check against live in :mod:`.mnee_reference`. A textured iris's albedo at x is its BSDF's
texture there (:func:`~scet_render.render.textures.iris_albedo`).
"""

from __future__ import annotations

import math

import numpy as np

from .layout import IRIS_OVERLAP, PUPIL_OFFSET_M, SCENE_UNITS_PER_M
from .textures import iris_albedo, iris_lookup

#: Reverse-Snell steps that start the solve, then damped Newton iterations (connect's notes).
#: On 200 random pairs of iris points and paper_sim lights (tests/scet_render/test_mnee.py),
#: the damped Newton alone from the n = 1 direction reached 140 of the 179 pairs the light-side
#: reference reaches (missing 6 % of their irradiance: steep exits start totally reflected);
#: 2 / 4 / 8 / 12 start steps then 10 iterations reach 169 / 171 / 177 / 178 of them (missing
#: 0.12 % / 0.06 % / 0.013 % / 0.002 %); with 12 start steps, 3 iterations do as well as 10.
START_STEPS = 12
NEWTON_ITERATIONS = 4
#: Largest Newton step in the direction parameters (a, b ~ tangents of the angle from w0).
MAX_STEP = 0.25
#: Forward-difference step of the Jacobian, in the direction parameters (a, b) (float64: the
#: truncation error, ~h times the map's curvature, is ~1e-7 of J).
JACOBIAN_STEP = 1e-7
#: A converged solve leaves the refracted ray this close to the light point (scene units, cm):
#: 1e-6 cm = 10 nm, far below the 0.2 mm light and far above the float64 solve's floor.
CONVERGED_CM = 1e-6


# --------------------------------------------------------------------------- pose state


def pose_state(setup, layout, cornea_to_scene: np.ndarray, yaw_rad: float, pitch_rad: float):
    """Plain numpy description of the eye at a pose, in scene units (cm).

    Parameters
    ----------
    setup : Setup
    layout : EyeLayout
    cornea_to_scene : (4, 4) float
        The cornea's object-to-scene matrix (unit sphere -> corneal sphere or ellipsoid).
    yaw_rad, pitch_rad : float

    Returns
    -------
    dict of str -> ndarray
        ``minv`` (3, 3) and ``tinv`` (3,): scene -> unit-sphere space of the cornea;
        ``center`` (3,) rotation centre, ``gaze`` (3,) unit gaze; ``limbus`` the limbus plane's
        distance along the gaze from the centre; ``sclera`` the sclera's radius; ``iris_x``,
        ``iris_y`` (3,) the iris disk's local axes.
    """
    from estimator.eye import eye_rotation_matrix

    M = np.asarray(cornea_to_scene, dtype=np.float64)
    minv = np.linalg.inv(M[:3, :3])
    face = eye_rotation_matrix(yaw_rad, pitch_rad) * np.array([1.0, -1.0, -1.0])  # R @ _GAZE_FRAME
    gaze = face[:, 2]
    return {
        "minv": minv, "tinv": -minv @ M[:3, 3],
        "center": setup.eye.rotation_center_m * SCENE_UNITS_PER_M, "gaze": gaze,
        "iris_x": face[:, 0], "iris_y": face[:, 1],
        "limbus": np.float64(layout.limbus_plane_m * SCENE_UNITS_PER_M),
        "sclera": np.float64(layout.sclera_radius_m * SCENE_UNITS_PER_M),
    }


def to_drjit(state: dict, mi) -> dict:
    """:func:`pose_state` as opaque width-1 float64 Dr.Jit variables (frozen-kernel inputs)."""
    import drjit as dr

    F64 = dr.float64_array_t(mi.Float)
    V64 = dr.float64_array_t(mi.Vector3f)

    def vec(v):
        return V64(*(dr.opaque(F64, float(c)) for c in v))

    out = {"m0": vec(state["minv"][0]), "m1": vec(state["minv"][1]),
           "m2": vec(state["minv"][2]), "t": vec(state["tinv"])}
    out.update({k: vec(state[k]) for k in ("center", "gaze", "iris_x", "iris_y")})
    return out | {k: dr.opaque(F64, float(state[k])) for k in ("limbus", "sclera")}


def light_table(setup, options, layout, mi, iris=None) -> dict:
    """The scene's constants for :func:`mnee_radiance`: the strobe lights as float64 Dr.Jit
    arrays (``center`` (K) points, ``radius`` (K), in cm, ``count`` K), the iris and pupil disks
    (radii, the pupil's offset, albedos; ``iris``: (mean albedo, texture or None)))."""
    import drjit as dr

    F64 = dr.float64_array_t(mi.Float)
    V64 = dr.float64_array_t(mi.Vector3f)
    p = np.asarray(setup.lights_world_m, dtype=np.float64) * SCENE_UNITS_PER_M
    r = np.array([g.source_radius_m for g in setup.lights.groups for _ in range(g.count)],
                 dtype=np.float64) * SCENE_UNITS_PER_M
    return {"center": V64(F64(p[:, 0]), F64(p[:, 1]), F64(p[:, 2])), "radius": F64(r),
            "count": int(p.shape[0]),
            "iris_cm": float(layout.limbus_radius_m * IRIS_OVERLAP * SCENE_UNITS_PER_M),
            "pupil_cm": float(options.pupil_radius_m * SCENE_UNITS_PER_M),
            "pupil_offset_cm": float(PUPIL_OFFSET_M * SCENE_UNITS_PER_M),
            "iris_albedo": float(iris[0]) if iris else float(options.iris_albedo),
            **iris_lookup(mi, iris[1] if iris else None),
            "pupil_albedo": float(options.pupil_albedo)}


# --------------------------------------------------------------------------- Dr.Jit kernels


def _mat(state, v):
    """minv @ v + t : scene -> the cornea's unit-sphere space."""
    import drjit as dr

    return type(v)(dr.dot(state["m0"], v), dr.dot(state["m1"], v), dr.dot(state["m2"], v))


def _normal(state, p_local):
    """Outward unit normal in the scene at a point of the unit sphere: minv^T p_local."""
    import drjit as dr

    n = state["m0"] * p_local.x + state["m1"] * p_local.y + state["m2"] * p_local.z
    return dr.normalize(n)


def _fresnel(cos_i, eta):
    """Unpolarised Fresnel reflectance of the air/cornea interface, from the cosine of the angle
    on the air side (the same for light going either way through the same pair of angles)."""
    import drjit as dr

    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = dr.safe_sqrt(1.0 - sin2_t)
    r_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


def _basis(w):
    """Two unit vectors orthogonal to unit ``w`` and to each other (Duff et al. 2017)."""
    import drjit as dr

    sign = dr.select(w.z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + w.z)
    b = w.x * w.y * a
    u1 = type(w)(1.0 + sign * w.x * w.x * a, sign * b, -sign * w.x)
    u2 = type(w)(b, sign + w.y * w.y * a, -w.y)
    return u1, u2


def _exit_ray(state, x, w, eta):
    """From ``x`` inside the cornea along unit ``w``: the exit point y, its outward normal, the
    refracted direction d (unit) into air, cos of incidence inside, and a validity mask (the
    quadric is left, no total internal reflection)."""
    import drjit as dr

    o = _mat(state, x) + state["t"]
    dl = _mat(state, w)
    A = dr.dot(dl, dl)
    B = dr.dot(o, dl)
    C = dr.dot(o, o) - 1.0
    disc = B * B - A * C
    t = (-B + dr.safe_sqrt(disc)) / A
    y = x + w * t
    n = _normal(state, o + dl * t)
    cos_i = dr.dot(w, n)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    cos_t = dr.safe_sqrt(1.0 - sin2_t)
    d = w * eta - n * (eta * cos_i - cos_t)
    valid = (disc > 0) & (t > 0) & (cos_i > 0) & (sin2_t < 1.0)
    return y, n, d, cos_i, valid


def _trace(state, x, w0, u1, u2, a, b, eta):
    """The path of direction parameters (a, b) from x: :func:`_exit_ray` of
    w = normalize(w0 + a u1 + b u2), and v = w0 + a u1 + b u2."""
    import drjit as dr

    v = w0 + u1 * a + u2 * b
    y, n, d, cos_i, valid = _exit_ray(state, x, dr.normalize(v), eta)
    return y, n, d, cos_i, v, valid


def connect(state, x, z, eta, iterations: int = NEWTON_ITERATIONS, h: float = JACOBIAN_STEP):
    """Solve the refraction x (inside the cornea) -> y (on it) -> z (outside), vectorised.

    Parameters
    ----------
    state : dict
        :func:`to_drjit` of a pose (or arrays of matching width).
    x, z : Array3f64
        Shading points inside and light points outside (scene units).
    eta : float
        The cornea's refractive index (air outside).

    Returns
    -------
    dict
        ``y`` the refraction point, ``n`` its outward normal, ``d`` the direction from y to z,
        ``w`` the direction from x to y, ``cos_in`` / ``cos_out`` the cosines of the ray with
        the normal at y inside and outside, ``domega_dperp`` dOmega_x / dA on the plane normal
        to d at z (multiply by |n_z . d| for the light's own area), ``valid`` (converged, on
        the quadric, no total reflection).

    Notes
    -----
    Newton's method runs on the angle between the refracted ray and the direction to z, in a
    basis normal to the latter (bounded and smooth even where the ray leaves near grazing),
    each step damped to a quarter where the full one does not lower the miss or leaves the
    quadric. The geometry term comes from one more Jacobian at the solution: of where the
    refracted ray crosses the plane through z normal to d (step 4 of the module docstring).
    """
    import drjit as dr

    w0 = dr.normalize(z - x)
    u1, u2 = _basis(w0)
    # Zeros of the inputs' width, derived from them: a frozen caller replays at any width.
    a = x.x * 0.0
    b = x.x * 0.0

    def miss(a, b, q1, q2):
        y, n, d, cos_i, v, valid = _trace(state, x, w0, u1, u2, a, b, eta)
        e = d - dr.normalize(z - y)
        return dr.dot(e, q1), dr.dot(e, q2), dr.select(valid, dr.squared_norm(e), math.inf)

    y, n, d, cos_i, v, valid = _trace(state, x, w0, u1, u2, a, b, eta)
    # Start: where the straight line leaves, the inside direction that refracts toward z
    # (reverse Snell, never totally reflected), twice. From the n = 1 direction alone, a
    # steep exit is often totally reflected and the damped steps cannot leave that region.
    for _ in range(START_STEPS):
        t = dr.normalize(z - y)
        cos_out = dr.dot(t, n)
        cos_in = dr.safe_sqrt(1.0 - (1.0 - cos_out * cos_out) / (eta * eta))
        w_s = (t + n * (eta * cos_in - cos_out)) / eta
        along = dr.dot(w_s, w0)
        ok = along > 0.1  # y and n exist for any x inside the quadric
        a = dr.select(ok, dr.dot(w_s, u1) / along, a)
        b = dr.select(ok, dr.dot(w_s, u2) / along, b)
        y, n, d, cos_i, v, valid = _trace(state, x, w0, u1, u2, a, b, eta)
    for _ in range(iterations):
        q1, q2 = _basis(dr.normalize(z - y))
        e1, e2, m0 = miss(a, b, q1, q2)
        ea1, ea2, _ = miss(a + h, b, q1, q2)
        eb1, eb2, _ = miss(a, b + h, q1, q2)
        j11, j21, j12, j22 = (ea1 - e1) / h, (ea2 - e2) / h, (eb1 - e1) / h, (eb2 - e2) / h
        det = j11 * j22 - j12 * j21
        inv = dr.select(dr.abs(det) > 0, 1.0 / det, 0.0)
        da = inv * (j22 * e1 - j12 * e2)
        db = inv * (j11 * e2 - j21 * e1)
        step = dr.sqrt(da * da + db * db)
        shrink = dr.select(step > MAX_STEP, MAX_STEP / dr.maximum(step, 1e-300), 1.0)
        da, db = da * shrink, db * shrink
        _, _, m_full = miss(a - da, b - db, q1, q2)
        _, _, m_quarter = miss(a - 0.25 * da, b - 0.25 * db, q1, q2)
        full = m_full < m0
        quarter = ~full & (m_quarter < m0)
        a = dr.select(full, a - da, dr.select(quarter, a - 0.25 * da, a))
        b = dr.select(full, b - db, dr.select(quarter, b - 0.25 * db, b))
        y, n, d, cos_i, v, valid = _trace(state, x, w0, u1, u2, a, b, eta)
    angle = dr.norm(d - dr.normalize(z - y))
    # The geometry term: where rays of nearby (a, b) cross the plane through z normal to d.
    p1, p2 = _basis(d)

    def crossing(a, b):
        yy, _, dd, _, _, _ = _trace(state, x, w0, u1, u2, a, b, eta)
        s = dr.dot(z - yy, d) / dr.dot(dd, d)
        p = yy + dd * s - z
        return dr.dot(p, p1), dr.dot(p, p2)

    c1, c2 = crossing(a, b)
    ca1, ca2 = crossing(a + h, b)
    cb1, cb2 = crossing(a, b + h)
    det = dr.abs((ca1 - c1) * (cb2 - c2) - (cb1 - c1) * (ca2 - c2)) / (h * h)
    # dOmega_x = da db / |v|^3 and dA_perp = |det J| da db.
    norm_v = dr.norm(v)
    denom = det * norm_v * norm_v * norm_v
    converged = angle * dr.norm(z - y) < CONVERGED_CM
    return {"y": y, "n": n, "d": d, "w": dr.normalize(v), "cos_in": cos_i,
            "cos_out": dr.dot(d, n),
            "domega_dperp": dr.select(denom > 0, 1.0 / denom, 0.0),
            "valid": valid & converged & (denom > 0)}


def on_cap(state, p):
    """True where scene point ``p`` (Array3f64) lies in front of the limbus plane."""
    import drjit as dr

    return dr.dot(p - state["center"], state["gaze"]) > state["limbus"]


def _plane_hit(state, o, d, offset_cm, radius_cm):
    """Where the ray (o, d) meets the disk of ``radius_cm`` in the plane ``offset_cm`` in front
    of the limbus plane (normal: the gaze): the point and a hit mask."""
    import drjit as dr

    g = state["gaze"]
    t = (state["limbus"] + offset_cm - dr.dot(o - state["center"], g)) / dr.dot(d, g)
    x = o + d * t
    rel = x - state["center"]
    radial = rel - g * dr.dot(rel, g)
    return x, (t > 0) & (dr.squared_norm(radial) < radius_cm * radius_cm)


def mnee_radiance(mi, scene, sampler, ray, state, lights, eta: float, radiance: float):
    """:func:`mnee_lanes` of a camera ray, drawing its three sampler dimensions (light choice,
    point on the light) after whatever the caller drew, as an ``mi.Color3f`` with the strobe
    channel (R, ``channels="split"``) filled."""
    value = mnee_lanes(mi, scene, ray.o, ray.d, sampler.next_1d(), sampler.next_2d(), state,
                       lights, eta, radiance)
    return mi.Color3f(value, 0.0, 0.0)


def mnee_lanes(mi, scene, ray_o, ray_d, u_light, u_point, state, lights, eta: float,
               radiance: float, compact: bool = True):
    """The strobe radiance seen along camera rays through the cornea on the iris and pupil.

    Parameters
    ----------
    ray_o, ray_d : mi.Point3f, mi.Vector3f
        Camera rays (scene units), one per lane.
    u_light : mi.Float
        Uniform numbers choosing the light.
    u_point : mi.Point2f
        Uniform numbers choosing the point on it.
    state, lights : dict
        :func:`to_drjit` of the pose and :func:`light_table` of the scene.

    Returns
    -------
    mi.Float
        The strobe radiance per lane, zero where the ray does not see the iris or pupil through
        the corneal cap.

    Notes
    -----
    The eye's inside is analytic: the cap and the limbus plane bound a convex region that holds
    nothing but the iris and pupil disks (the sclera's cap there is cut away), so the camera
    ray's path into it and the segment x -> y need no ray casts; one shadow ray checks that
    nothing covers the cornea in front of the camera (lids, lashes) and one that nothing
    blocks y -> z. :func:`mnee_front` runs on every lane; with ``compact`` only the lanes that
    reach the iris or pupil go on to :func:`mnee_back` (``dr.compress``: the solve costs nothing
    where the camera sees skin), without it every lane runs it under a mask. The renderer's
    frozen kernels take the masked form: a compaction's count changes with the pose, and
    Dr.Jit 1.5 records (and compiles) a frozen function anew for each count.
    """
    import drjit as dr

    front = mnee_front(mi, ray_o, ray_d, state, lights, eta)
    if not compact:
        hit = front.pop("hit")
        return mnee_back(mi, scene, front, u_light, u_point, state, lights, eta, radiance, hit)
    idx = dr.compress(front.pop("hit"))
    lanes = {k: dr.gather(type(v), v, idx) for k, v in front.items()}
    value = mnee_back(mi, scene, lanes, dr.gather(mi.Float, u_light, idx),
                      dr.gather(mi.Point2f, u_point, idx), state, lights, eta, radiance)
    out = dr.zeros(mi.Float, dr.width(ray_o))
    dr.scatter(out, value, idx)
    return out


def mnee_front(mi, ray_o, ray_d, state, lights, eta: float) -> dict:
    """Step 1 on every lane: the camera ray's hit on the corneal cap (the quadric's near root),
    the refraction in, and the pupil or iris point it reaches (a grazing ray that leaves
    through the cap again meets neither disk). Returns ``hit`` (mi.Bool) and the per-lane
    inputs of :func:`mnee_back`: ``x``, ``on_pupil``, ``w_cam`` (the camera side's (1 - F) /
    n^2), ``t0`` (the distance to the cap), and the rays ``o``, ``d``."""
    import drjit as dr

    V64 = dr.float64_array_t(mi.Vector3f)
    o_cam, d_cam = V64(ray_o), dr.normalize(V64(ray_d))
    o = _mat(state, o_cam) + state["t"]
    dl = _mat(state, d_cam)
    A, B, C = dr.dot(dl, dl), dr.dot(o, dl), dr.dot(o, o) - 1.0
    disc = B * B - A * C
    t0 = (-B - dr.safe_sqrt(disc)) / A
    y0 = o_cam + d_cam * t0
    n0 = _normal(state, o + dl * t0)
    cos0 = -dr.dot(d_cam, n0)
    inv_eta = 1.0 / eta
    cos0_t = dr.safe_sqrt(1.0 - inv_eta * inv_eta * (1.0 - cos0 * cos0))
    d_in = d_cam * inv_eta + n0 * (inv_eta * cos0 - cos0_t)
    x_p, on_pupil = _plane_hit(state, y0, d_in, lights["pupil_offset_cm"], lights["pupil_cm"])
    x_i, on_iris = _plane_hit(state, y0, d_in, 0.0, lights["iris_cm"])
    hit = (disc > 0) & (t0 > 0) & (cos0 > 0) & on_cap(state, y0) & (on_pupil | on_iris)
    return {"hit": mi.Bool(hit), "x": dr.select(on_pupil, x_p, x_i),
            "on_pupil": mi.Bool(on_pupil),
            "w_cam": (1.0 - _fresnel(cos0, eta)) * inv_eta * inv_eta, "t0": t0,
            "o": mi.Point3f(ray_o), "d": mi.Vector3f(ray_d)}


def mnee_back(mi, scene, lanes: dict, u_light, u_point, state, lights, eta: float,
              radiance: float, active=True):
    """Steps 2-5 (module docstring) on the lanes :func:`mnee_front` found on the iris or
    pupil (or those of ``active``): the strobe radiance of each (mi.Float)."""
    import drjit as dr

    V64 = dr.float64_array_t(mi.Vector3f)
    F64 = dr.float64_array_t(mi.Float)
    x = lanes["x"]
    seen = mi.Ray3f(lanes["o"], dr.normalize(lanes["d"]))
    # Stop 1e-4 of the way short (~3 µm): float32 would find the cornea itself otherwise.
    seen.maxt = mi.Float(lanes["t0"] * (1.0 - 1e-4))
    active = mi.Bool(active)
    active &= ~scene.ray_test(seen, active)  # lids, lashes, skin in front of the cornea
    # 2. A light and a point on it.
    K = lights["count"]
    k = dr.minimum(mi.UInt32(u_light * K), K - 1)
    c = dr.gather(V64, lights["center"], k)
    r = dr.gather(F64, lights["radius"], k)
    n_z = V64(mi.warp.square_to_uniform_sphere(u_point))
    z = c + n_z * r
    # 3.-4. The refraction point and the manifold's geometry term.
    sol = connect(state, x, z, eta)
    facing = -dr.dot(n_z, sol["d"])
    cos_x = dr.dot(sol["w"], state["gaze"])
    active &= mi.Bool(sol["valid"] & on_cap(state, sol["y"]) & (facing > 0) & (cos_x > 0))
    # 5. Visibility of z from y, the diffuse BSDF at x with its cosine, the light.
    shadow = mi.Ray3f(mi.Point3f(sol["y"] + sol["n"] * 1e-5), mi.Vector3f(sol["d"]))
    shadow.maxt = mi.Float(dr.norm(z - sol["y"]) * (1.0 - 1e-4))
    active &= ~scene.ray_test(shadow, active)
    albedo = dr.select(lanes["on_pupil"], lights["pupil_albedo"],
                       iris_albedo(mi, state, lights, x))
    f_cos = F64(albedo) * (1.0 / math.pi) * cos_x
    t_y = 1.0 - _fresnel(sol["cos_out"], eta)
    geometry = sol["domega_dperp"] * facing
    area = 4.0 * math.pi * r * r
    value = f_cos * lanes["w_cam"] * t_y * (eta * eta) * geometry * area * (float(K) * radiance)
    return dr.select(active, mi.Float(value), 0.0)


_INTEGRATOR_CLASSES: dict[str, type] = {}


def mnee_integrator(mi, eye_scene):
    """A sampling integrator for ``mi.render``: the scene's ``path`` integrator plus
    :meth:`EyeScene.mnee` at the scene's current pose (the full-frame reference renders)."""
    variant = mi.variant()
    if variant not in _INTEGRATOR_CLASSES:

        class PathWithMnee(mi.SamplingIntegrator):
            def __init__(self, props=None):
                mi.SamplingIntegrator.__init__(self, props or mi.Properties())
                self.inner = None
                self.eye_scene = None

            def sample(self, scene, sampler, ray, medium=None, active=True):
                L, valid, aovs = self.inner.sample(scene, sampler, ray, medium, active)
                L = L + self.eye_scene.mnee(sampler, ray)
                return L, valid, aovs

            def aov_names(self):
                return []

            def to_string(self):
                return "PathWithMnee[]"

        _INTEGRATOR_CLASSES[variant] = PathWithMnee
    integrator = _INTEGRATOR_CLASSES[variant]()
    integrator.inner = eye_scene.scene.integrator()
    integrator.eye_scene = eye_scene
    return integrator


__all__ = ["NEWTON_ITERATIONS", "connect", "light_table", "mnee_back", "mnee_front",
           "mnee_integrator", "mnee_lanes", "mnee_radiance", "pose_state", "to_drjit", "on_cap"]
