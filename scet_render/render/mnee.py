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
2. A light k is picked uniformly (the renderer stratifies a pixel's samples over the list:
   :func:`~scet_render.render.mnee_kernels.stratified_light_choice`) and a point z on its
   sphere, mostly on the half facing the eye by projected area (:func:`sample_light_point`).
3. The point y on the corneal surface where Snell's law joins x and z is solved by Newton's
   method on the direction w(a, b) = normalize(w0 + a u1 + b u2) leaving x (w0 = the direction
   to z, the solution as n -> 1): the refracted ray from y(w) must pass through z. It starts
   in float32 and ends in float64, with forward differences for the 2x2 Jacobian.
4. The generalised geometry term (the manifold Jacobian): a patch da db of the parameters is a
   solid angle da db / |v|^3 at x (v = w0 + a u1 + b u2) and an area |det C| da db on the
   plane through z normal to the refracted direction d (C: :func:`connect`'s notes), which is
   |n_z . d| times the light's own area. So per unit light area,
   dOmega_x / dA_z = |n_z . d| / (|det C| |v|^3); with n = 1 it is cos_z / |x - z|^2.
5. The light's radiance L enters the cornea as L (1 - F(y)) n^2, the diffuse BSDF at x weighs it
   with its cosine, and the visibility of z from y is a shadow ray (lids, lashes, skin).

The estimate of one sample is then
``(1 - F0) / n^2 * f(x) cos * L (1 - F(y)) n^2 * dOmega_x/dA_z * K / p(z)``, p(z) the density
of z per unit area of the light (1 / (4 pi r^2) for a uniform point). The n^2 factors
cancel: they are kept to show where each belongs. Paths with further vertices inside the eye
(light the iris scatters back to itself off the cornea, much of it totally reflected) are left
out: against converged path tracing with 1.5 mm lights, MNEE reads the iris 1.3-3.0 % darker
(tests/scet_render/test_mnee.py).

Everything moving is an opaque Dr.Jit input (:func:`pose_state`), so the frozen kernels
(:mod:`.mnee_kernels`) replay for every eye pose without recompiling. The tests' independent
references are in :mod:`.mnee_reference`. A textured iris's albedo at x is its BSDF's texture
there (:func:`~scet_render.render.textures.iris_albedo`).
"""

from __future__ import annotations

import math

from .mnee_state import light_table, pose_state, to_drjit
from .textures import iris_albedo

#: The solve (connect's notes): extrapolated reverse-Snell steps and Newton iterations in
#: float32, then float64. Of 400 random iris point / paper_sim light pairs (test_mnee.py,
#: sphere / conic q = -0.25) the light-side reference reaches 344 / 341, the float64 solve
#: before (39 traces) 342 / 341, these 10 / 1 / 1 (20 traces, 14 float32) 344 / 341, as
#: accurately (1.3e-5 / 1.5e-5 at most, not grazing); 12 / 2 / 1 unextrapolated 339 / 341.
START_STEPS = 10
NEWTON_ITERATIONS_F32 = 1
NEWTON_ITERATIONS = 1
MAX_RATIO = 0.8  # the start steps' largest extrapolation ratio (a factor 5 at most)
#: Largest Newton step in the direction parameters (a, b ~ tangents of the angle from w0).
MAX_STEP = 0.25
#: Forward-difference step of the Jacobian in the direction parameters (a, b): float64, the
#: truncation error (~h times the map's curvature) is ~1e-7 of J; float32, rounding ~1e-7 / h
#: and truncation ~h leave J good to ~1e-3, enough for Newton.
JACOBIAN_STEP = 1e-7
JACOBIAN_STEP_F32 = 1e-3
#: A converged solve leaves the refracted ray this close to the light point (scene units, cm):
#: 1e-6 cm = 10 nm, far below the 0.2 mm light and far above the float64 solve's floor.
CONVERGED_CM = 1e-6
#: Share of the light samples drawn on the light's half that faces the eye
#: (:func:`sample_light_point`); the rest cover the whole sphere. A uniform-sphere sample
#: that faces the refracted ray but not the axis weighs at most 4 / (1 - DISK_SHARE) of the
#: light's projected area (~0.1 % of samples).
DISK_SHARE = 0.95


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


def _trace(state, x, w0, u1, u2, a, b, eta):
    """From ``x`` inside the cornea along w = normalize(v), v = w0 + a u1 + b u2: the exit
    point y, its outward normal, the refracted direction d (unit) into air, cos of incidence
    inside, v, and a validity mask (the quadric is left, no total internal reflection)."""
    import drjit as dr

    v = w0 + u1 * a + u2 * b
    w = dr.normalize(v)
    o = _mat(state, x) + state["t"]
    dl = _mat(state, w)
    A, B, C = dr.dot(dl, dl), dr.dot(o, dl), dr.dot(o, o) - 1.0
    disc = B * B - A * C
    t = (-B + dr.safe_sqrt(disc)) / A
    n = _normal(state, o + dl * t)
    cos_i = dr.dot(w, n)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    cos_t = dr.safe_sqrt(1.0 - sin2_t)
    d = w * eta - n * (eta * cos_i - cos_t)
    valid = (disc > 0) & (t > 0) & (cos_i > 0) & (sin2_t < 1.0)
    return x + w * t, n, d, cos_i, v, valid


def _start(state, x, z, eta, w0, u1, u2, a, b, steps: int):
    """Reverse-Snell steps (from where the ray leaves, the inside direction that refracts
    toward z, never totally reflected); returns (a, b) and the trace there."""
    import drjit as dr

    tr = _trace(state, x, w0, u1, u2, a, b, eta)
    pa = pb = None
    for _ in range(steps):
        n, t = tr[1], dr.normalize(z - tr[0])
        cos_out = dr.dot(t, n)
        cos_in = dr.safe_sqrt(1.0 - (1.0 - cos_out * cos_out) / (eta * eta))
        w_s = (t + n * (eta * cos_in - cos_out)) / eta
        along = dr.dot(w_s, w0)
        ok = along > 0.1  # y and n exist for any x inside the quadric
        da = dr.select(ok, dr.dot(w_s, u1) / along - a, 0.0)
        db = dr.select(ok, dr.dot(w_s, u2) / along - b, 0.0)
        # Steps that shrink by a ratio r along a line (measured: those slow to converge) sum
        # to 1 / (1 - r) times the step (Aitken); r from the last two, at most MAX_RATIO.
        r = 0.0 if pa is None else (da * pa + db * pb) / dr.maximum(pa * pa + pb * pb, 1e-30)
        g = 1.0 / (1.0 - dr.clip(r, 0.0, MAX_RATIO))
        a, b, pa, pb = a + da * g, b + db * g, da * g, db * g
        tr = _trace(state, x, w0, u1, u2, a, b, eta)
    return a, b, tr


def _jacobian(state, x, z, eta, w0, u1, u2, a, b, tr, h):
    """The miss e (the refracted direction less the direction to z, in a basis normal to the
    latter) at (a, b) and its forward-difference Jacobian (e1, e2, j11, j12, j21, j22)."""
    import drjit as dr

    q1, q2 = _basis(dr.normalize(z - tr[0]))
    e1, e2 = (dr.dot(tr[2] - dr.normalize(z - tr[0]), q) for q in (q1, q2))
    j = []
    for da, db in ((h, 0.0), (0.0, h)):
        y, _, d, _, _, _ = _trace(state, x, w0, u1, u2, a + da, b + db, eta)
        e = d - dr.normalize(z - y)
        j += [(dr.dot(e, q1) - e1) / h, (dr.dot(e, q2) - e2) / h]
    return e1, e2, j[0], j[2], j[1], j[3]


def _newton(state, x, z, eta, w0, u1, u2, a, b, tr, h, iterations: int):
    """Newton iterations on the miss, each step at most MAX_STEP: (a, b) and the trace."""
    import drjit as dr

    for _ in range(iterations):
        e1, e2, j11, j12, j21, j22 = _jacobian(state, x, z, eta, w0, u1, u2, a, b, tr, h)
        det = j11 * j22 - j12 * j21
        inv = dr.select(dr.abs(det) > 0, 1.0 / det, 0.0)
        da = inv * (j22 * e1 - j12 * e2)
        db = inv * (j11 * e2 - j21 * e1)
        step = dr.sqrt(da * da + db * db)
        shrink = dr.select(step > MAX_STEP, MAX_STEP / dr.maximum(step, 1e-30), 1.0)
        a, b = a - da * shrink, b - db * shrink
        tr = _trace(state, x, w0, u1, u2, a, b, eta)
    return a, b, tr


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
        to d at z (times |n_z . d|: per light area), ``valid`` (converged, no total reflection).

    Notes
    -----
    The start (:data:`START_STEPS` reverse-Snell steps: from the n = 1 direction alone a steep
    exit is often totally reflected) and :data:`NEWTON_ITERATIONS_F32` Newton iterations run
    in float32 (twice the SIMD width: 1.8 times faster a step, measured), then ``iterations``
    in float64. Newton runs on the angle between the refracted ray and the direction to z, in
    a basis normal to the latter (bounded and smooth even where the ray leaves near grazing).
    The geometry term (step 4 of the module docstring) needs the Jacobian C of where the ray
    crosses the plane through z normal to d: at the solution a change de of that angle moves
    the crossing by L de (L = |z - y|), so |det C| = L^2 |det J|, J from one more Jacobian.
    """
    import drjit as dr

    V32 = dr.float32_array_t(type(x))
    s32 = {k: dr.float32_array_t(type(v))(v) for k, v in state.items()}
    x32, z32 = V32(x), V32(z)
    w0 = dr.normalize(z32 - x32)
    u1, u2 = _basis(w0)
    # Zeros of the inputs' width, derived from them: a frozen caller replays at any width.
    a, b, tr = _start(s32, x32, z32, eta, w0, u1, u2, x32.x * 0.0, x32.x * 0.0, START_STEPS)
    a, b, tr = _newton(s32, x32, z32, eta, w0, u1, u2, a, b, tr, JACOBIAN_STEP_F32,
                       NEWTON_ITERATIONS_F32)
    w = type(x)(dr.normalize(w0 + u1 * a + u2 * b))
    w0 = dr.normalize(z - x)
    u1, u2 = _basis(w0)
    along = dr.dot(w, w0)
    a, b = dr.dot(w, u1) / along, dr.dot(w, u2) / along
    tr = _trace(state, x, w0, u1, u2, a, b, eta)
    a, b, tr = _newton(state, x, z, eta, w0, u1, u2, a, b, tr, h, iterations)
    y, n, d, cos_i, v, valid = tr
    _, _, j11, j12, j21, j22 = _jacobian(state, x, z, eta, w0, u1, u2, a, b, tr, h)
    L, norm_v = dr.norm(z - y), dr.norm(v)
    # dOmega_x = da db / |v|^3 and dA_perp = L^2 |det J| da db.
    denom = dr.abs(j11 * j22 - j12 * j21) * L * L * norm_v * norm_v * norm_v
    converged = dr.norm(d - dr.normalize(z - y)) * L < CONVERGED_CM
    return {"y": y, "n": n, "d": d, "w": dr.normalize(v), "cos_in": cos_i, "cos_out": dr.dot(d, n),
            "domega_dperp": dr.select(denom > 0, 1.0 / denom, 0.0),
            "valid": valid & converged & (denom > 0) & (along > 0.1)}


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


def _facing_axis(state, x, c):
    """Unit vector from light centre ``c`` toward where the straight line from ``x`` to ``c``
    leaves the cornea: the light's side that the refracted ray from ``x`` reaches, to within
    the ~1 mm the refraction moves the exit point 30 mm from the light (~0.03 rad)."""
    import drjit as dr

    o = _mat(state, x) + state["t"]
    dl = _mat(state, c - x)
    A, B, C = dr.dot(dl, dl), dr.dot(o, dl), dr.dot(o, o) - 1.0
    t = (-B + dr.safe_sqrt(B * B - A * C)) / A  # x is inside: the far root leaves
    return dr.normalize(x + (c - x) * dr.clip(t, 0.0, 1.0) - c)


def sample_light_point(mi, state, x, c, r, u):
    """A point on the spherical light (centre ``c``, radius ``r``) for the shading point ``x``:
    the unit normal there and 1 / its probability density per unit area.

    With probability :data:`DISK_SHARE` the light's half facing the eye by projected area
    (a uniform point of the disk the light shows along :func:`_facing_axis`, lifted onto the
    sphere: density cos / (pi r^2)), else the whole sphere uniformly (1 / (4 pi r^2)). The
    estimate carries the cosine between the light's normal and the refracted ray, which the
    first density follows to within ~0.03 rad; the second keeps every point that faces the
    refracted ray reachable, so the estimate stays unbiased with a bounded weight. Sampling
    the whole sphere alone left half the samples zero and gave one sample a relative standard
    deviation of 1.29 from this step alone (sqrt(5/3): the estimate is 4 cos+ of a uniform
    cosine).
    """
    import drjit as dr

    V64 = type(x)
    axis = _facing_axis(state, x, c)
    disk = u.x < DISK_SHARE
    u = mi.Point2f(dr.select(disk, u.x / DISK_SHARE, (u.x - DISK_SHARE) / (1.0 - DISK_SHARE)),
                   u.y)
    p = mi.warp.square_to_uniform_disk_concentric(u)
    e1, e2 = _basis(axis)
    px, py = type(r)(p.x), type(r)(p.y)
    lifted = e1 * px + e2 * py + axis * dr.safe_sqrt(1.0 - px * px - py * py)
    n_z = dr.select(disk, lifted, V64(mi.warp.square_to_uniform_sphere(u)))
    pdf = (DISK_SHARE * dr.maximum(dr.dot(n_z, axis), 0.0) / math.pi
           + (1.0 - DISK_SHARE) / (4.0 * math.pi)) / (r * r)
    return n_z, 1.0 / pdf


def mnee_radiance(mi, scene, sampler, ray, state, lights, eta: float, radiance: float):
    """:func:`mnee_lanes` of a camera ray, drawing its three sampler dimensions (light choice,
    point on the light) after whatever the caller drew, as an ``mi.Color3f`` with the strobe
    channel (R, ``channels="split"``) filled."""
    value = mnee_lanes(mi, scene, ray.o, ray.d, sampler.next_1d(), sampler.next_2d(), state,
                       lights, eta, radiance)
    return mi.Color3f(value, 0.0, 0.0)


def mnee_lanes(mi, scene, ray_o, ray_d, u_light, u_point, state, lights, eta: float,
               radiance: float):
    """The strobe radiance seen along camera rays through the cornea on the iris and pupil.

    Parameters
    ----------
    ray_o, ray_d : mi.Point3f, mi.Vector3f
        Camera rays (scene units), one per lane.
    u_light, u_point : mi.Float, mi.Point2f
        Uniform numbers choosing the light and the point on it.
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
    blocks y -> z. Only the lanes :func:`mnee_front` finds on the iris or pupil go on to
    :func:`mnee_back` (:func:`compact_lanes`; :mod:`.mnee_kernels` runs the two as frozen
    kernels).
    """
    import drjit as dr

    front = mnee_front(mi, ray_o, ray_d, state, lights, eta, scene)
    front["u_light"], front["u_point"] = u_light, u_point
    idx, lanes = compact_lanes(front)
    out = dr.zeros(mi.Float, dr.width(ray_o))
    dr.scatter(out, mnee_back(mi, scene, lanes, state, lights, eta, radiance), idx)
    return out


def compact_lanes(front: dict):
    """The lanes of :func:`mnee_front`'s ``hit``: (their indices, the other entries there)."""
    import drjit as dr

    idx = dr.compress(front["hit"])
    return idx, {k: dr.gather(type(v), v, idx) for k, v in front.items() if k != "hit"}


def mnee_front(mi, ray_o, ray_d, state, lights, eta: float, scene=None) -> dict:
    """Step 1 on every lane: the camera ray's hit on the corneal cap (the quadric's near root),
    the refraction in, and the pupil or iris point it reaches (a grazing ray that leaves
    through the cap again meets neither disk); with ``scene``, a shadow ray drops the lanes
    whose way to the cornea is covered (lids, lashes, skin). Returns ``hit`` (mi.Bool) and the
    per-lane inputs of :func:`mnee_back`: ``x``, ``on_pupil`` and ``w_cam`` (the camera
    side's (1 - F) / n^2), in float32 (x is a sample point: ~1e-7 cm of rounding is noise)."""
    import drjit as dr

    state = {k: dr.float32_array_t(type(v))(v) for k, v in state.items()}
    o_cam, d_cam = mi.Vector3f(ray_o), dr.normalize(mi.Vector3f(ray_d))
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
    x_p, on_pupil = _plane_hit(state, y0, d_in, lights["pupil_offset_cm"], state["pupil"])
    x_i, on_iris = _plane_hit(state, y0, d_in, 0.0, lights["iris_cm"])
    hit = mi.Bool((disc > 0) & (t0 > 0) & (cos0 > 0) & on_cap(state, y0) & (on_pupil | on_iris))
    if scene is not None:
        seen = mi.Ray3f(mi.Point3f(ray_o), d_cam)
        # Stop 1e-4 of the way short (~3 µm): float32 would find the cornea itself otherwise.
        seen.maxt = mi.Float(t0 * (1.0 - 1e-4))
        hit &= ~scene.ray_test(seen, hit)
    return {"hit": hit, "x": dr.select(on_pupil, x_p, x_i), "on_pupil": mi.Bool(on_pupil),
            "w_cam": (1.0 - _fresnel(cos0, eta)) * inv_eta * inv_eta}


def mnee_back(mi, scene, lanes: dict, state, lights, eta: float, radiance: float,
              active=True):
    """Steps 2-5 (module docstring) on the lanes :func:`mnee_front` found (or ``active``'s),
    ``u_light`` (mi.Float) and ``u_point`` (mi.Point2f) choosing the light and the point on
    it: the strobe radiance of each (mi.Float)."""
    import drjit as dr

    F64, V64 = dr.float64_array_t(mi.Float), dr.float64_array_t(mi.Vector3f)
    x = V64(lanes["x"])
    active = mi.Bool(active)
    # 2. A light and a point on it (:func:`sample_light_point`).
    K = lights["count"]
    k = dr.minimum(mi.UInt32(lanes["u_light"] * K), K - 1)
    c = dr.gather(V64, lights["center"], k)
    r = dr.gather(F64, lights["radius"], k)
    n_z, inv_pdf = sample_light_point(mi, state, x, c, r, lanes["u_point"])
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
    value = f_cos * F64(lanes["w_cam"]) * t_y * (eta * eta) * geometry * inv_pdf * (K * radiance)
    return dr.select(active, mi.Float(value), 0.0)


__all__ = ["NEWTON_ITERATIONS", "compact_lanes", "connect", "light_table", "mnee_back",
           "mnee_front", "mnee_lanes", "mnee_radiance", "on_cap", "pose_state",
           "sample_light_point", "to_drjit"]
