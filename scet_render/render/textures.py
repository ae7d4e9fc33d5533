"""Near-IR appearance: seeded procedural textures of the iris, the skin and the sclera.

What the eye looks like to the SCET camera (850 nm LEDs, a monochrome near-IR image):

* **Iris**: melanin, which makes irises brown or blue in visible light, absorbs almost nothing
  beyond 700 nm, so in the near-IR a dark and a light iris look alike: a grey disk whose
  reflectance is nearly constant over 700-900 nm, textured by its stroma's structure rather
  than its pigment (Daugman, "Absorption spectrum of melanin", www.cl.cam.ac.uk/~jgd1000/
  melanin.html, after Kollias 1995; the principal components of measured iris spectra, Medina
  et al., J. Biomed. Opt. 16(7) 076001, 2011). The texture: radial fibres (the stromal
  trabeculae, a field correlated along the radius and narrow across it, ``iris_fibres`` of
  them around), the collarette (a bright zig-zag ring at ``collarette_radius_mm``) and crypts
  (dark lens-shaped pits elongated along the radius, ``iris_crypts_per_mm2`` of them in the
  ciliary zone, outside the collarette).
* **Skin**: smooth mottling (``skin_contrast``) and pores (dark spots of 60-120 µm,
  ``skin_pores_per_mm2``) on a tile repeated over the face.
* **Sclera**: faint vessels (``sclera_vessels`` of them, contrast ``sclera_vessel_contrast``)
  running from the back of the eye toward the limbus and branching; haemoglobin absorbs far
  less at 850 nm than at its visible peaks (415-575 nm; S. Prahl's tabulation of haemoglobin's
  molar extinction, omlc.org/spectra/hemoglobin), so they are faint.

Means. Each texture's mean albedo is the configured one exactly where a render sees it:
the iris's over every circle about its centre (each column of the polar texture), the
sclera's over every circle about the gaze (each row), the skin's over its tile. A render of a
textured part therefore reads, to the Monte Carlo error of the pattern, what an untextured part
of the same albedo reads under the same light (tests/scet_render/test_textures.py). The price:
the texture carries no radial brightness profile of its own (a real iris's pupillary zone is
often a little darker than its ciliary zone).

Mapping. The iris texture is polar on Mitsuba's ``disk`` (u = r / R, v = azimuth / 2 pi; rows
are v, columns u), the sclera's on its ``sphere`` (u = azimuth / 2 pi about the gaze, v = polar
angle / pi). The skin meshes (skin shell, lids, face) carry texture coordinates of a planar
projection along the camera's general direction (z): u = x / tile, v = -y / tile, in the
meshes' rest frame, so that the texture moves with the lids.

Not modelled: the tear-film meniscus along the lid margin. It is a smooth dielectric strip a
few tenths of a millimetre high with a concave surface of similar radius (the lower meniscus
as reflective meniscometry measures it, Yokoi et al.); as geometry it would make its own
specular highlights of every strobe light (a real effect: the meniscus glints that a glint
detector must reject), but it needs a mesh that follows the lid margin as the lid moves and a
refracting BSDF over the skin, which the lid meshes (rigid shells) do not have; a texture
cannot fake a specular highlight that moves with the lights.

All three textures are drawn from ``numpy.random.default_rng(seed)`` streams, one per texture:
the same seed and parameters give byte-identical arrays.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields

import numpy as np

from estimator.errors import SceneError


__all__ = ["Appearance", "read_appearance", "appearance_table", "iris_albedo", "iris_lookup",
           "albedo_bitmap", "cached_texture", "scene_appearance",
           "iris_texture", "skin_texture",
           "sclera_texture", "skin_uv", "IRIS_TEXELS", "SCLERA_TEXELS", "SKIN_TEXELS",
           "SKIN_TILE_M"]

#: Iris texture size (angle rows, radius columns): 1024 x 256 over a 6 mm disk is 37 µm around
#: the limbus and 23 µm along the radius, finer than a pixel at 1300 px focal length (~45 µm).
IRIS_TEXELS = (1024, 256)
#: Sclera texture size (polar-angle rows over 0..pi, azimuth columns): 37 µm on a 12 mm eyeball.
SCLERA_TEXELS = (1024, 2048)
#: Skin tile: texels a side and its side (m), 31 µm a texel.
SKIN_TEXELS = 256
SKIN_TILE_M = 8e-3
#: Width of the collarette's bright ring (m, Gaussian sigma) and its zig-zag's amplitude (m)
#: and lobes around the iris.
COLLARETTE_WIDTH_M = 0.1e-3
COLLARETTE_ZIGZAG_M = 0.25e-3
COLLARETTE_LOBES = 18
#: Crypts: radial half-length and tangential half-width ranges (m), darkening range (fraction
#: of the local albedo they remove), and the soft edge (fraction of the crypt's size).
CRYPT_HALF_LENGTH_M = (0.15e-3, 0.45e-3)
CRYPT_HALF_WIDTH_M = (0.08e-3, 0.25e-3)
CRYPT_DEPTH = (0.3, 0.6)
CRYPT_EDGE = 0.3
#: Pores: radius range (m, Gaussian sigma) and darkening range.
PORE_RADIUS_M = (0.03e-3, 0.06e-3)
PORE_DEPTH = (0.15, 0.35)
#: Sclera vessels: start polar angle range (rad from the gaze), step along the vessel (m),
#: width at the start (m, Gaussian sigma; it tapers to half toward the limbus), meander (rad
#: of heading per sqrt(step)), branches per vessel.
VESSEL_START_RAD = (math.radians(70.0), math.radians(100.0))
VESSEL_STEP_M = 0.1e-3
VESSEL_WIDTH_M = 0.04e-3
VESSEL_MEANDER = 0.25
VESSEL_BRANCHES = 2


@dataclass(frozen=True, slots=True)
class Appearance:
    """The scene's ``[appearance]`` table (defaults in brackets; the module docstring says
    what each texture is).

    Albedos are near-IR (850 nm) means; None takes the renderer's untextured albedo
    (:class:`~scet_render.render.layout.SceneOptions`: iris 0.3, sclera 0.7, skin 0.6).

    Attributes
    ----------
    textured : bool
        Textures on [True]; False renders every part with its uniform albedo (the renders
        before issue 29).
    seed : int
        Seed of every texture [0].
    iris_albedo, iris_contrast : float
        Mean and relative standard deviation of the fibres' albedo [0.2].
    iris_fibres : int
        Fibres around the iris [120].
    iris_crypts_per_mm2 : float
        Crypts per mm² of the ciliary zone [0.05].
    collarette_radius_mm : float
        Radius of the collarette (mm) [3.3]; 0 for none.
    skin_albedo, skin_contrast : float
        Mean and relative standard deviation of the mottling [0.06].
    skin_pores_per_mm2 : float
        [0.5].
    sclera_albedo : float
    sclera_vessels : int
        Vessels around the eye [30].
    sclera_vessel_contrast : float
        The darkening at a vessel's centre (fraction of the albedo) [0.12].
    """

    textured: bool = True
    seed: int = 0
    iris_albedo: float | None = None
    iris_contrast: float = 0.2
    iris_fibres: int = 120
    iris_crypts_per_mm2: float = 0.05
    collarette_radius_mm: float = 3.3
    skin_albedo: float | None = None
    skin_contrast: float = 0.06
    skin_pores_per_mm2: float = 0.5
    sclera_albedo: float | None = None
    sclera_vessels: int = 30
    sclera_vessel_contrast: float = 0.12


#: Key -> (kind, lo, hi) of the table: kinds "bool", "int", "float".
_KEYS = {
    "textured": ("bool", None, None),
    "seed": ("int", 0, 2**32 - 1),
    "iris_albedo": ("float", 0.0, 1.0),
    "iris_contrast": ("float", 0.0, 1.0),
    "iris_fibres": ("int", 1, 2048),
    "iris_crypts_per_mm2": ("float", 0.0, 10.0),
    "collarette_radius_mm": ("float", 0.0, 10.0),
    "skin_albedo": ("float", 0.0, 1.0),
    "skin_contrast": ("float", 0.0, 1.0),
    "skin_pores_per_mm2": ("float", 0.0, 50.0),
    "sclera_albedo": ("float", 0.0, 1.0),
    "sclera_vessels": ("int", 0, 1000),
    "sclera_vessel_contrast": ("float", 0.0, 1.0),
}


def read_appearance(setup) -> Appearance:
    """The :class:`Appearance` of a Setup's ``[appearance]`` table (defaults without one).

    Raises
    ------
    SceneError
        An unknown key, a value of the wrong kind, an albedo or contrast outside [0, 1], a
        negative density or count; the message names the scene file and the key.
    """
    table = getattr(setup, "appearance", None)
    if table is None:
        return Appearance()
    path = getattr(setup, "source", "") or "<scene>"
    values = {}
    for key, value in table:
        where = f"appearance.{key}"
        if key not in _KEYS:
            raise SceneError(f"unknown key (known: {', '.join(sorted(_KEYS))})", path=path,
                             key=where)
        kind, lo, hi = _KEYS[key]
        if kind == "bool":
            if not isinstance(value, bool):
                raise SceneError(f"expected true or false, got {value!r}", path=path, key=where)
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise SceneError(f"expected an integer, got {value!r}", path=path, key=where)
            if not lo <= value <= hi:
                raise SceneError(f"expected an integer in [{lo}, {hi}], got {value}", path=path,
                                 key=where)
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise SceneError(f"expected a number, got {value!r}", path=path, key=where)
            value = float(value)
            if not (math.isfinite(value) and lo <= value <= hi):
                raise SceneError(f"expected a value in [{lo:g}, {hi:g}], got {value!r}",
                                 path=path, key=where)
        values[key] = value
    return Appearance(**values)


def appearance_table(appearance: Appearance, *, iris_albedo: float, skin_albedo: float,
                     sclera_albedo: float) -> dict:
    """Every key of the ``[appearance]`` table with the value rendered (albedos resolved),
    for the manifest and the effective scene."""
    out = {f.name: getattr(appearance, f.name) for f in fields(appearance)}
    for key, value in (("iris_albedo", iris_albedo), ("skin_albedo", skin_albedo),
                       ("sclera_albedo", sclera_albedo)):
        if out[key] is None:
            out[key] = float(value)
    return out


# --------------------------------------------------------------------------- helpers


def _rng(seed: int, part: str) -> np.random.Generator:
    """An independent stream per texture (the same seed, other parts' draws unchanged)."""
    tag = int.from_bytes(part.encode("ascii"), "little")
    return np.random.default_rng(np.random.SeedSequence([int(seed), tag]))


def _standardise(x: np.ndarray) -> np.ndarray:
    sd = float(x.std())
    return (x - x.mean()) / sd if sd > 0 else x * 0.0


def _fix_mean(albedo: np.ndarray, mean: float, axis: int | None) -> np.ndarray:
    """Scale ``albedo`` to ``mean`` along ``axis`` (None: overall), clipped to [0, 1]; a few
    rounds, since clipping moves the mean (none at the defaults)."""
    a = np.clip(albedo, 0.0, None)
    for _ in range(4):
        m = a.mean(axis=axis, keepdims=axis is not None)
        a = np.clip(np.where(m > 0, a * (mean / np.where(m > 0, m, 1.0)), mean), 0.0, 1.0)
    return a


def _gaussian_wrap(x: np.ndarray, sigma: tuple[float, float]) -> np.ndarray:
    """Gaussian blur (sigma in texels per axis) of a periodic array, by FFT."""
    out = np.fft.fft2(x)
    for axis, s in enumerate(sigma):
        f = np.fft.fftfreq(x.shape[axis])
        g = np.exp(-0.5 * (2 * np.pi * f * s) ** 2)
        out *= g[:, None] if axis == 0 else g[None, :]
    return np.fft.ifft2(out).real


# --------------------------------------------------------------------------- iris


def iris_texture(appearance: Appearance, mean: float, iris_radius_m: float,
                 texels: tuple[int, int] = IRIS_TEXELS) -> np.ndarray:
    """(angles, radii) float32 near-IR albedo of the iris disk (module docstring).

    Row i is the azimuth (i + 0.5) / angles x 2 pi, column j the radius (j + 0.5) / radii x
    ``iris_radius_m`` (Mitsuba's ``disk`` coordinates). Every column's mean is ``mean``
    (clipping to [0, 1] aside). The first column (under the pupil, never seen) repeats the
    last, so that the bilinear lookup wrapping at u = 1 stays continuous at the iris's edge.
    """
    n_a, n_r = texels
    rng = _rng(appearance.seed, "iris")
    R = float(iris_radius_m)
    r = (np.arange(n_r) + 0.5) / n_r * R
    phi = (np.arange(n_a) + 0.5) / n_a * 2 * np.pi
    # Fibres: white noise blurred narrowly across (a fibre's width: the circumference over
    # the count, at mid-radius) and broadly along the radius; periodic in both (the radial
    # wrap falls under the pupil, where the first column is replaced anyway).
    fibres = _gaussian_wrap(rng.standard_normal((n_a, n_r)),
                            (0.35 * n_a / appearance.iris_fibres, 0.12 * n_r))
    g = _standardise(fibres)
    albedo = 1.0 + appearance.iris_contrast * g
    rc = appearance.collarette_radius_mm * 1e-3
    if rc > 0:
        k = np.arange(1, 4)
        zig = (rng.standard_normal(3)[:, None] * np.cos(COLLARETTE_LOBES * k[:, None] * phi)
               + rng.standard_normal(3)[:, None] * np.sin(COLLARETTE_LOBES * k[:, None] * phi))
        ring_r = rc + COLLARETTE_ZIGZAG_M * zig.sum(axis=0) / math.sqrt(3.0)
        ring = np.exp(-0.5 * ((r[None, :] - ring_r[:, None]) / COLLARETTE_WIDTH_M) ** 2)
        albedo += 1.5 * appearance.iris_contrast * ring
    inner = rc if rc > 0 else 0.4 * R
    area_mm2 = math.pi * (R * R - inner * inner) * 1e6
    count = rng.poisson(appearance.iris_crypts_per_mm2 * max(area_mm2, 0.0))
    if count:
        cr = np.sqrt(rng.uniform(inner ** 2, (0.92 * R) ** 2, count))
        cphi = rng.uniform(0, 2 * np.pi, count)
        a = rng.uniform(*CRYPT_HALF_LENGTH_M, count)
        b = rng.uniform(*CRYPT_HALF_WIDTH_M, count)
        depth = rng.uniform(*CRYPT_DEPTH, count)
        keep = np.ones((n_a, n_r))
        for i in range(count):
            dphi = np.angle(np.exp(1j * (phi - cphi[i])))
            q = np.sqrt(((r[None, :] - cr[i]) / a[i]) ** 2
                        + ((r[None, :] * dphi[:, None]) / b[i]) ** 2)
            # 1 inside, a smooth step to 0 across the rim (a pit with a soft wall).
            t = np.clip((1.0 - q) / CRYPT_EDGE, 0.0, 1.0)
            keep *= 1.0 - depth[i] * t * t * (3.0 - 2.0 * t)
        albedo *= keep
    out = _fix_mean(albedo * mean, mean, axis=0).astype(np.float32)
    out[:, 0] = out[:, -1]
    return out


# --------------------------------------------------------------------------- skin


def skin_texture(appearance: Appearance, mean: float, texels: int = SKIN_TEXELS,
                 tile_m: float = SKIN_TILE_M) -> np.ndarray:
    """(texels, texels) float32 near-IR albedo of a periodic skin tile of side ``tile_m``:
    mottling (blurred noise, 0.25 mm correlation) and pores; its mean is ``mean``."""
    rng = _rng(appearance.seed, "skin")
    texel_m = tile_m / texels
    mottle = _standardise(_gaussian_wrap(rng.standard_normal((texels, texels)),
                                         (0.25e-3 / texel_m,) * 2))
    albedo = 1.0 + appearance.skin_contrast * mottle
    count = rng.poisson(appearance.skin_pores_per_mm2 * (tile_m * 1e3) ** 2)
    if count:
        centres = rng.uniform(0, texels, (count, 2))
        sigma = rng.uniform(*PORE_RADIUS_M, count) / texel_m
        depth = rng.uniform(*PORE_DEPTH, count)
        idx = np.arange(texels) + 0.5
        for (cy, cx), s, d in zip(centres, sigma, depth):
            dy = (idx - cy + texels / 2) % texels - texels / 2  # periodic distance
            dx = (idx - cx + texels / 2) % texels - texels / 2
            albedo *= 1.0 - d * np.exp(-0.5 * (dy[:, None] ** 2 + dx[None, :] ** 2) / (s * s))
    return _fix_mean(albedo * mean, mean, axis=None).astype(np.float32)


def skin_uv(vertices_m: np.ndarray, origin_m: np.ndarray,
            tile_m: float = SKIN_TILE_M) -> np.ndarray:
    """(n, 2) float32 texture coordinates of skin vertices (m, rest frame): the planar
    projection along z, in skin tiles, from ``origin_m`` (the eye's rotation centre)."""
    rel = (np.asarray(vertices_m, dtype=np.float64) - np.asarray(origin_m)) / tile_m
    return np.stack([rel[:, 0], -rel[:, 1]], axis=1).astype(np.float32)


# --------------------------------------------------------------------------- sclera


def sclera_texture(appearance: Appearance, mean: float, sclera_radius_m: float,
                   limbus_rad: float, texels: tuple[int, int] = SCLERA_TEXELS) -> np.ndarray:
    """(polar angles, azimuths) float32 near-IR albedo of the sclera sphere: faint branching
    vessels from the back toward the limbus (``limbus_rad`` from the gaze). Row i is the polar
    angle (i + 0.5) / rows x pi, column j the azimuth (j + 0.5) / columns x 2 pi; every row's
    mean is ``mean``."""
    n_t, n_p = texels
    rng = _rng(appearance.seed, "sclera")
    dark = np.zeros((n_t, n_p))
    R = float(sclera_radius_m)
    d_theta, d_phi = np.pi / n_t, 2 * np.pi / n_p
    walks = []  # (theta, phi, heading, width, trunk)
    for _ in range(appearance.sclera_vessels):
        walks.append((rng.uniform(*VESSEL_START_RAD), rng.uniform(0, 2 * np.pi),
                      rng.normal(0.0, 0.3), VESSEL_WIDTH_M, True))
    spots = []  # (theta, phi, sigma_rad) of every step
    taper = max(VESSEL_START_RAD[1] - limbus_rad, 1e-9)
    while walks:
        theta, phi, heading, width, trunk = walks.pop()
        # heading: the angle from "toward the limbus" (-theta); + turns toward +phi.
        length = int((theta - limbus_rad) * R / VESSEL_STEP_M)
        branch_at = (set(rng.integers(1, max(2, length), VESSEL_BRANCHES).tolist()) if trunk
                     else set())
        turns = rng.standard_normal(max(length, 0)) * VESSEL_MEANDER * math.sqrt(
            VESSEL_STEP_M / 1e-3)
        for step in range(max(length, 0)):
            if theta <= limbus_rad:
                break
            heading = min(max(heading + float(turns[step]), -1.2), 1.2)
            theta -= VESSEL_STEP_M / R * math.cos(heading)
            phi += VESSEL_STEP_M / (R * max(math.sin(theta), 0.05)) * math.sin(heading)
            spots.append((theta, phi, width * (0.5 + 0.5 * (theta - limbus_rad) / taper) / R))
            if step in branch_at:
                walks.append((theta, phi, heading + float(rng.choice([-0.8, 0.8])),
                              0.7 * width, False))
    if spots:
        _splat(dark, np.asarray(spots), np.pi / n_t, 2 * np.pi / n_p)
    albedo = 1.0 - appearance.sclera_vessel_contrast * dark
    return _fix_mean(albedo * mean, mean, axis=1).astype(np.float32)


def _splat(dark, spots, d_theta, d_phi) -> None:
    """Darken Gaussian spots (rows (theta, phi, sigma_rad), sigma an arc on the unit sphere)
    into ``dark``, max-combined (overlapping steps of one vessel do not add up)."""
    n_t, n_p = dark.shape
    theta, phi, sigma = spots.T
    s = np.maximum(np.sin(theta), 0.05)
    half_t = int(math.ceil(3 * sigma.max() / d_theta)) + 1
    half_p = int(math.ceil(3 * (sigma / s).max() / d_phi)) + 1
    rows = (theta / d_theta).astype(np.int64)[:, None] + np.arange(-half_t, half_t + 1)
    cols = (np.mod(phi, 2 * np.pi) / d_phi).astype(np.int64)[:, None] + np.arange(-half_p,
                                                                                  half_p + 1)
    dt = (rows + 0.5) * d_theta - theta[:, None]
    dp = np.angle(np.exp(1j * ((cols + 0.5) * d_phi - phi[:, None]))) * s[:, None]
    value = np.exp(-0.5 * (dt[:, :, None] ** 2 + dp[:, None, :] ** 2)
                   / sigma[:, None, None] ** 2)
    r = np.broadcast_to(rows[:, :, None], value.shape)
    c = np.broadcast_to(np.mod(cols, n_p)[:, None, :], value.shape)
    inside = (r >= 0) & (r < n_t)
    np.maximum.at(dark, (r[inside], c[inside]), value[inside])


# --------------------------------------------------------------------------- MNEE


def iris_lookup(mi, texture) -> dict:
    """The entries :func:`iris_albedo` reads from MNEE's light table: the iris texture
    (rows, columns) flattened to an mi.Float and its shape; None for an untextured iris."""
    if texture is None:
        return {"iris_texels": None, "iris_shape": None}
    return {"iris_texels": mi.Float(np.ascontiguousarray(texture, np.float32).ravel()),
            "iris_shape": tuple(int(n) for n in texture.shape)}


def iris_albedo(mi, state, lights, x):
    """The iris's albedo at shading points ``x`` (Array3f64, scene units), as mi.Float: the
    constant ``lights["iris_albedo"]``, or where ``lights["iris_texels"]`` holds the iris
    texture (flattened, ``lights["iris_shape"]`` (rows, columns)), its bilinear lookup with
    wrapping, as Mitsuba's ``bitmap`` makes it (filter ``bilinear``, wrap ``repeat``), at the
    disk's texture coordinates of x (u = r / R, v = azimuth / 2 pi from its local x axis
    toward y). A plain array lookup, so that MNEE's light table holds arrays only;
    tests/scet_render/test_textures.py holds it to the iris BSDF's own lookup at Mitsuba's
    intersections."""
    import drjit as dr

    texels = lights.get("iris_texels")
    if texels is None:
        return lights["iris_albedo"]
    rows, cols = lights["iris_shape"]
    rel = x - (state["center"] + state["gaze"] * state["limbus"])
    lx = dr.dot(rel, state["iris_x"]) * (1.0 / lights["iris_cm"])
    ly = dr.dot(rel, state["iris_y"]) * (1.0 / lights["iris_cm"])
    v = dr.atan2(ly, lx) * (0.5 / math.pi)
    v = mi.Float(dr.select(v < 0, v + 1.0, v))
    u = mi.Float(dr.sqrt(lx * lx + ly * ly))
    px, py = u * cols - 0.5, v * rows - 0.5
    x0, y0 = dr.floor(px), dr.floor(py)
    fx, fy = px - x0, py - y0

    def wrap(i, n):  # i in [-1, n]: u and v lie in [0, 1] (u up to the disk's rim)
        i = mi.Int32(i)
        return mi.UInt32(dr.select(i < 0, i + n, dr.select(i >= n, i - n, i)))

    c0, c1 = wrap(x0, cols), wrap(x0 + 1, cols)
    r0, r1 = wrap(y0, rows) * cols, wrap(y0 + 1, rows) * cols
    t00, t01 = dr.gather(mi.Float, texels, r0 + c0), dr.gather(mi.Float, texels, r0 + c1)
    t10, t11 = dr.gather(mi.Float, texels, r1 + c0), dr.gather(mi.Float, texels, r1 + c1)
    return dr.lerp(dr.lerp(t00, t01, fx), dr.lerp(t10, t11, fx), fy)


def albedo_bitmap(name: str) -> dict:
    """A ``bitmap`` reflectance of ``textures/<name>.png`` (bilinear, raw values, wrapped)."""
    return {"type": "bitmap", "filename": f"textures/{name}.png", "raw": True,
            "filter_type": "bilinear", "wrap_mode": "repeat"}


@functools.lru_cache(maxsize=32)
def _drawn(make, *args) -> np.ndarray:
    out = make(*args)
    out.setflags(write=False)
    return out


def cached_texture(make, *args) -> np.ndarray:
    """A copy of ``make(*args)``, drawn once for all scenes with the same arguments (a texture
    takes 0.2-0.6 s to draw; a run builds scenes of one Setup many times). A copy each time:
    handing the same read-only array to a second scene made Dr.Jit 1.5 record that scene's
    MNEE kernel once more (measured: tests/scet_render/test_mnee.py's frozen replay test after
    the file's other tests; the cause inside Dr.Jit is not known)."""
    return _drawn(make, *args).copy()


def scene_appearance(setup, options) -> tuple[Appearance, dict]:
    """The Setup's :class:`~scet_render.render.textures.Appearance` and its table with the
    albedos resolved (an albedo the table leaves out is the option's)."""
    app = read_appearance(setup)
    return app, appearance_table(app, iris_albedo=options.iris_albedo,
                                 skin_albedo=options.skin_albedo,
                                 sclera_albedo=options.sclera_albedo)
