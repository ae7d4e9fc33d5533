"""Glints cut by a lash: flagged by their flux and dropped from a band's fit.

A lash across a glint's light path leaves part of the glint: its centroid moves (a median
0.75 px on paper_sim at 16 spp, up to 1.7 px) and its flux drops (a median 0.64 of the
unoccluded glint's; docs/guide/rendering.md, "Moving lids, blinks and lashes"). The expected flux of every
identified glint at the fitted pose (:class:`estimator.calibration.GlintFlux`: each light's
calibrated power times the convex mirror's reflected irradiance) tells such a glint from a
clear one; :func:`flagged` finds them, and the tracker does the band again without them
(:func:`kept_detections`) from the stream's state before the band: identification, fit and
the prior the next band gets all come from the remaining glints, so a sample that took the
prior is fitted again with its prior, and one left with too few glints of its own can still
take it. The check runs compiled where Numba is (:data:`estimator.matching.kernels.ENABLED`):
one loop over the band's glints (:func:`log_ratios`; the numpy model of
:func:`estimator.calibration.model_flux` otherwise). A conic calibration's check uses the
conic's flux and glints (numpy).
"""

from __future__ import annotations

import math

import numpy as np

import estimator.matching.kernels as match_kernels

from ..cornea import conic_glints
from ..eye import CORNEA_REFRACTIVE_INDEX
from ..geometry import camera_arrays, glints_one_pose
from ..geometry.compiled import glints_kernel
from .samples import GazeSample

__all__ = ["FLUX_FLAG_SD", "RESIDUAL_FLAG", "flagged", "same_points", "kept_detections",
           "log_ratios", "flag_kernel"]

#: A glint is taken as cut by a lash where both its log(measured / expected flux) is below
#: -FLUX_FLAG_SD times the calibration's own spread (:attr:`GlintFlux.log_sd`, dimensionless
#: log units) and its centroid is further than RESIDUAL_FLAG times the calibration's RMS glint
#: residual (:attr:`GlintFlux.noise_px`, px) from where the fitted pose puts it: a lash that
#: dims a glint without moving it does the fit no harm, and flux alone is noisy. Clear glints'
#: fluxes spread by a log-SD of 0.16 (dielectric cornea, 16 spp, 320 x 240) to 0.21-0.30 (4 spp,
#: conductor / dielectric): the Monte Carlo noise of the few rays that see a sub-pixel glint,
#: which no model of the pose removes. A clear glint's residual is Rayleigh-distributed about
#: the calibration's RMS, so it passes RESIDUAL_FLAG x RMS with probability
#: exp(-RESIDUAL_FLAG²): 24 % at 1.2, 0.2 % at 2.5. Measured (benchmarks/bench_cut_glints.py,
#: 48 frames with 40 lashes, geometric gaze; 16 spp: 1568 clear and 145 lash-cut glints of
#: accepted samples; 4 spp: 1443 and 106): at 2.5 x RMS and 2.0 SD the flag takes 40 cut and
#: 2 clear glints at 16 spp (recall 0.28, precision 0.95; mean error 0.043 -> 0.042 deg, p95
#: 0.097 -> 0.095) and 8 cut and 3 clear at 4 spp (0.08, 0.73); at 1.2 x, 68 and 19 (0.47,
#: 0.78; p95 -> 0.089) and 16 and 38 (0.15, 0.30). The false flags of 1.2 x cost the free-centre
#: fit of polynomial gaze a glint it needs: on the quick validation's lashless 4-spp frames
#: its own-glint median at 16 pulses rose from 0.801 to 0.867 deg (2.5 x: 0.801). Lash cuts
#: large enough to matter stand out at 2.5 x either way (Q = -0.45 moving lids, conic tracker:
#: 0.669 deg without the flag, 0.365 at 1.2 x, 0.366 at 2.5 x).
FLUX_FLAG_SD = 2.0
RESIDUAL_FLAG = 2.5


def log_ratios(pos, R, intrinsics, center, r, lights_world, light_index, used, g, flux,
               log_power, dielectric: bool, n: float) -> np.ndarray:
    """(k,) log(measured / expected flux) of a sample's glints ``used`` (k, 2), rows of the
    band's detections ``g`` (m, 2) with flux (m,), of lights ``light_index`` (k,) into
    ``lights_world`` (n, 3) and ``log_power`` (n,); camera centre ``pos`` (3,), rotation
    ``R`` (3, 3), ``intrinsics`` (fx, fy, cx, cy); cornea ``center`` (3,), radius r. The model
    of :func:`estimator.calibration.model_flux`, one glint at a time; NaN where the ray misses
    the sphere or a glint is not among ``g``."""
    k = used.shape[0]
    out = np.empty(k)
    ox, oy, oz = pos[0] - center[0], pos[1] - center[1], pos[2] - center[2]
    c_oc = ox * ox + oy * oy + oz * oz - r * r
    for a in range(k):
        row = -1
        for b in range(g.shape[0]):
            if g[b, 0] == used[a, 0] and g[b, 1] == used[a, 1]:
                row = b
                break
        xn = (used[a, 0] - intrinsics[2]) / intrinsics[0]
        yn = (used[a, 1] - intrinsics[3]) / intrinsics[1]
        q = 1.0 + xn * xn + yn * yn
        s = 1.0 / math.sqrt(q)
        dx = (xn * R[0, 0] + yn * R[1, 0] + R[2, 0]) * s
        dy = (xn * R[0, 1] + yn * R[1, 1] + R[2, 1]) * s
        dz = (xn * R[0, 2] + yn * R[1, 2] + R[2, 2]) * s
        bb = dx * ox + dy * oy + dz * oz
        disc = bb * bb - c_oc
        if row < 0 or not disc >= 0.0 or not flux[row] > 0.0:
            out[a] = math.nan
            continue
        t = -bb - math.sqrt(disc)
        cos_i = min(max(-(bb + t) / r, 1e-6), 1.0)
        li = light_index[a]
        lx = lights_world[li, 0] - (pos[0] + t * dx)
        ly = lights_world[li, 1] - (pos[1] + t * dy)
        lz = lights_world[li, 2] - (pos[2] + t * dz)
        d_l = math.sqrt(lx * lx + ly * ly + lz * lz)
        aa = 1.0 + t / d_l
        e = 1.0 / (d_l * d_l * (aa + 2.0 * t / (r * cos_i)) * (aa + 2.0 * t * cos_i / r))
        f = 1.0
        if dielectric:
            ct = math.sqrt(max(1.0 - (1.0 - cos_i * cos_i) / (n * n), 0.0))
            rs = (cos_i - n * ct) / (cos_i + n * ct)
            rp = (n * cos_i - ct) / (n * cos_i + ct)
            f = 0.5 * (rs * rs + rp * rp)
        out[a] = math.log(flux[row]) - math.log(f * e * q * math.sqrt(q)) - log_power[li]
    return out


def flag_kernel(R, O, intr, size, center, r, lights_world, light_index, used, g, flux,
                log_power, dielectric: bool, n: float, floor: float, max_off_px: float,
                out) -> None:
    """:func:`flagged`'s test in one compiled call: ``out`` (k,) True where the
    :func:`log_ratios` is below ``floor`` and (``max_off_px`` >= 0) the glint of the light at
    the pose (``glints_kernel``, projected for those glints only) is more than ``max_off_px``
    from the centroid."""
    ratios = log_ratios(O, R, intr, center, r, lights_world, light_index, used, g, flux,
                        log_power, dielectric, n)
    k = used.shape[0]
    m = 0
    for a in range(k):
        out[a] = ratios[a] < floor
        m += out[a]
    if m == 0 or max_off_px < 0:
        return
    low = np.empty((m, 3))
    at = np.empty(m, dtype=np.int64)
    b = 0
    for a in range(k):
        if out[a]:
            low[b] = lights_world[light_index[a]]
            at[b] = a
            b += 1
    pred = np.empty((m, 2))
    vis = np.empty(m, dtype=np.bool_)
    glints_kernel(R, O, intr, size, center, r, low, np.zeros(3), 0.0, False, pred, vis, False,
                  np.empty((0, 2, 3)))
    for b in range(m):
        a = at[b]
        du, dv = pred[b, 0] - used[a, 0], pred[b, 1] - used[a, 1]
        out[a] = du * du + dv * dv > max_off_px * max_off_px  # NaN (no glint there): False


if match_kernels.ENABLED:
    import numba

    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    log_ratios = _jit(log_ratios)
    flag_kernel = _jit(flag_kernel)


def flagged(calibration, camera, lights_world_m, sample: GazeSample, g, flux,
            arrays=None) -> np.ndarray:
    """(k,) bool: which of ``sample``'s glints are cut by a lash: log(measured / expected
    flux) below -:data:`FLUX_FLAG_SD` log-SDs and the centroid more than
    :data:`RESIDUAL_FLAG` x the calibration's noise from the glint of the sample's pose.

    Parameters
    ----------
    calibration : Calibration
        Its ``glint_flux`` and ``cornea_radius_m``.
    camera : Camera
    lights_world_m : (n, 3) float
        Calibrated lights.
    sample : GazeSample
        An accepted sample; its glints are rows of ``g``.
    g : (m, 2) float
        The band's detections.
    flux : (m,) float
        Their flux (DN, :attr:`estimator.glints.GlintDetections.intensity`).
    arrays : tuple, optional
        :func:`estimator.geometry.camera_arrays` of ``camera``, when the caller keeps it.
    """
    used = sample.glints_px
    glint_flux, cornea_radius_m = calibration.glint_flux, calibration.cornea_radius_m
    floor = -FLUX_FLAG_SD * glint_flux.log_sd
    noise = glint_flux.noise_px
    if match_kernels.ENABLED and not calibration.conic:
        out = np.empty(used.shape[0], dtype=np.bool_)
        flag_kernel(*(camera_arrays(camera) if arrays is None else arrays),
                    sample.cornea_center_m, float(cornea_radius_m), lights_world_m,
                    sample.light_index, used, g, flux, glint_flux.log_power,
                    glint_flux.fresnel == "dielectric", CORNEA_REFRACTIVE_INDEX, floor,
                    RESIDUAL_FLAG * noise if np.isfinite(noise) else -1.0, out)
        return out
    # numpy: the sphere's model without Numba; a conic calibration's always (the conic's
    # expected flux with Q and the eye centre, its exact glints; its fits are numpy too).
    conic = {"asphericity": calibration.cornea_asphericity,
             "eye_center_m": calibration.eye_center_m} if calibration.conic else {}
    rows = same_points(g, used).argmax(axis=0)
    expected = glint_flux.expected(camera, sample.cornea_center_m, cornea_radius_m,
                                   lights_world_m, sample.light_index, used, **conic)
    with np.errstate(divide="ignore", invalid="ignore"):
        low = np.log(flux[rows] / expected) < floor
    if low.any() and np.isfinite(noise):  # most bands have no dim glint
        dim = lights_world_m[sample.light_index[low]]
        if conic:
            pred = conic_glints(camera, sample.cornea_center_m[None], conic["eye_center_m"],
                                cornea_radius_m, conic["asphericity"], dim)[0]
        else:
            pred, _ = glints_one_pose(camera, sample.cornea_center_m, cornea_radius_m, dim)
        off = np.hypot(pred[:, 0] - used[low, 0], pred[:, 1] - used[low, 1])
        low[low] = off > RESIDUAL_FLAG * noise  # NaN (no glint there): False
    return low


def same_points(g, points) -> np.ndarray:
    """(m, k) bool: which of the band's detections ``g`` (m, 2) each of ``points`` (k, 2) is
    (a sample's glints are copies of detections, so equal to the last bit)."""
    return (g[:, None, 0] == points[None, :, 0]) & (g[:, None, 1] == points[None, :, 1])


def kept_detections(g, cut) -> np.ndarray:
    """(m,) bool: the band's detections ``g`` (m, 2) that are not among the flagged glints
    ``cut`` (c, 2)."""
    if cut.shape[0] == 0:
        return np.ones(g.shape[0], dtype=bool)
    return ~same_points(g, cut).any(axis=1)
