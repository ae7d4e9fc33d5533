"""The frozen Dr.Jit kernels that add MNEE's strobe light to a band of rows
(:mod:`.mnee`, :class:`~scet_render.render.rolling_shutter.BandedRenderer`).

MNEE runs in two frozen functions of its own, beside the path kernel and with camera rays of
its own (an independent estimate of the light the path tracer leaves out, so the path kernel
stays as it was):

1. the front, on every pixel-sample of the band: the camera ray, its refraction into the
   cornea and the shadow ray in front of it (:func:`.mnee.mnee_front`). Its camera rays use
   the band's width as a literal, so it is keyed by (spp, rows) like the path kernel;
2. the lanes that reach the iris or pupil are compacted (:func:`.mnee.compact_lanes`) outside
   both functions: a ``dr.compress`` inside a frozen function records anew for every count;
3. the back on those lanes only: the light sample, the manifold solve and the shadow ray to
   the light (:func:`.mnee.mnee_back`). Every input has the compacted width and nothing in it
   reads a width, so one recording replays at every count (Dr.Jit sizes its kernels from the
   inputs), for every band height and pose.
"""

from __future__ import annotations

import contextlib
import gc

import numpy as np

from .mnee import compact_lanes, mnee_back, mnee_front


@contextlib.contextmanager
def _collector_held():
    """Python's cyclic garbage collector off for the duration (restored after)."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()


#: MNEE's samples per pixel (:func:`mnee_samples`): half the path tracer's, never fewer than
#: this (or than the path tracer's own, if fewer).
MIN_MNEE_SAMPLES = 4


def mnee_samples(spp: int) -> int:
    """Samples per pixel MNEE takes when the path tracer takes ``spp``.

    MNEE is an estimate of its own (its own camera rays), so it need not take every sample.
    paper_sim_designed's iris at 320 x 240, per-pixel relative standard deviation of MNEE's
    light (median over the iris, 8 seeds; 2026-12-05): 0.85 at 4 samples with the uniform
    light choice and uniform sphere points before; with :func:`stratified_light_choice` and
    :func:`~scet_render.render.mnee.sample_light_point` 0.25 at 4 samples and 0.48 at 2 (the
    light choice stratifies poorly over 2). A 640 x 480 16-spp frame of paper_sim costs 1.29-1.34
    times the render without MNEE when MNEE takes all 16 samples, 1.16-1.18 with 8
    (``benchmarks/bench_mnee.py``, CPU time, same run): half the samples, at least 4.
    """
    spp = int(spp)
    return min(spp, max(MIN_MNEE_SAMPLES, (spp + 1) // 2))


def stratified_light_choice(mi, idx, u, spp: int):
    """The light-choice numbers ``u`` of the lanes ``idx`` (a pixel's ``spp`` samples are
    consecutive lanes) stratified over the pixel: sample s of a pixel draws from
    [s / spp, (s + 1) / spp), so its samples pick lights spread over the whole list instead
    of ``spp`` independent picks. Each number is still uniform over [0, 1) (s is uniform
    over the samples), so the estimate stays unbiased."""
    s = mi.Float(idx % spp)
    return (s + u) * (1.0 / spp)


class MneeKernels:
    """MNEE's frozen front kernels (one per spp and band height) and its back kernel.

    Parameters
    ----------
    mi : module
        Mitsuba with a JIT variant set.
    setup : Setup
    options : SceneOptions
    band_rays : callable
        ``band_rays(mi, sensor, row0, seed, lanes, spp, W, H) -> (sampler, ray, weight)``,
        the renderer's camera rays of a band.
    """

    def __init__(self, mi, setup, options, band_rays):
        self.mi, self.band_rays = mi, band_rays
        self.width, self.height = setup.camera.width_px, setup.camera.height_px
        self.eta = float(setup.eye.refractive_index)
        self.radiance = float(options.light_radiance)
        self.fronts = {}
        self.back = None

    def front(self, spp: int, n_rows: int):
        """The frozen front kernel of bands of ``n_rows`` rows at ``spp``."""
        if (spp, n_rows) not in self.fronts:
            import drjit as dr

            mi, eta, W, H = self.mi, self.eta, self.width, self.height

            def front(scene, sensor, row0, seed, lanes, state):
                sampler, ray, weight = self.band_rays(mi, sensor, row0, seed, lanes, spp, W, H)
                out = mnee_front(mi, ray.o, ray.d, state["pose"], state["lights"], eta, scene)
                out["w_cam"] = out["w_cam"] * weight[0]
                out["u_light"] = stratified_light_choice(
                    mi, dr.arange(mi.UInt32, dr.width(lanes)), sampler.next_1d(), spp)
                out["u_point"] = sampler.next_2d()
                dr.eval(out)
                return out

            self.fronts[spp, n_rows] = dr.freeze(front)
        return self.fronts[spp, n_rows]

    def back_kernel(self):
        """The frozen back kernel (any number of lanes)."""
        if self.back is None:
            import drjit as dr

            mi, eta, radiance = self.mi, self.eta, self.radiance

            def back(scene, lanes, state):
                value = mnee_back(mi, scene, lanes, state["pose"], state["lights"], eta,
                                  radiance)
                dr.eval(value)
                return value

            self.back = dr.freeze(back)
        return self.back

    def rows(self, eye_scene, row_start: int, n_rows: int, spp: int, seed: int) -> np.ndarray:
        """(n_rows, W) float32: the strobe radiance MNEE adds to the rows from ``row_start``
        at ``eye_scene``'s current pose, from the sample stream of ``seed``."""
        import drjit as dr

        mi, es, W = self.mi, eye_scene, self.width
        # Python's cyclic collector is held off while the kernels run: a collection in the
        # middle of recording one (its trace makes many objects) aborted Dr.Jit 1.5 once in
        # a fresh process ("Garbage-collecting" in connect).
        with _collector_held():
            front = self.front(spp, n_rows)(
                es.scene, es.sensor, dr.opaque(mi.UInt32, row_start), dr.opaque(mi.UInt32, seed),
                dr.zeros(mi.UInt32, n_rows * W * spp), es.mnee_state)
            idx, lanes = compact_lanes(front)
            if dr.width(idx) == 0:
                return np.zeros((n_rows, W), dtype=np.float32)
            value = self.back_kernel()(es.scene, lanes, es.mnee_state)
            lanes = dr.zeros(mi.Float, n_rows * W * spp)
            dr.scatter(lanes, value, idx)
            pixels = dr.block_sum(lanes, spp) * (1.0 / spp)
            return np.asarray(pixels, dtype=np.float32).reshape(n_rows, W)




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


__all__ = ["MIN_MNEE_SAMPLES", "MneeKernels", "mnee_integrator", "mnee_samples",
           "stratified_light_choice"]
