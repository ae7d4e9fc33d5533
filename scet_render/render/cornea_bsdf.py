"""The cornea's material: a smooth dielectric whose glints converge at low sample counts.

Mitsuba's ``dielectric`` chooses reflection with probability F, the Fresnel reflectance (about
0.03 at the glints' 40-55 degree incidence), so a glint gets a handful of reflected samples
per pixel at 16 spp and its centroid is Monte Carlo noise (DESIGN.md, rendering notes). This
BSDF is the same physical interface (same Fresnel equations, same reflected and refracted
directions, same radiance scaling) sampled differently: from outside it picks reflection with
a fixed probability ``p`` and weights the lobes by F / p and (1 - F) / (1 - p), so the estimator
is unbiased and a glint gets ``p`` of the samples. From inside (light leaving the cornea
through the iris path) it samples like ``dielectric``, by F.

``transmittance`` scales the refracted lobe per channel (``channels="split"`` zeroes the strobe
channel's: see :mod:`scet_render.render.scene`). The type is a Python plugin, so Mitsuba's own
``mitsuba`` command cannot load it; :mod:`scet_render.render.export` writes a plain
``dielectric`` instead.
"""

from __future__ import annotations

#: Mitsuba plugin name of the cornea BSDF.
CORNEA_BSDF_TYPE = "scet_cornea"
#: Probability of sampling reflection from outside (DESIGN.md: 0.75 converges the glints;
#: 0.9 makes the iris 1.7x noisier).
REFLECT_PROBABILITY = 0.75

_REGISTERED: set[str] = set()


def fresnel_dielectric(cos_theta_i, eta):
    """Unpolarised Fresnel reflectance of a smooth dielectric interface (numpy, independent of
    Mitsuba; used by the tests).

    Parameters
    ----------
    cos_theta_i : array_like
        Cosine of the incidence angle, > 0 on the side of the normal.
    eta : float
        Relative index of refraction n_inside / n_outside.

    Returns
    -------
    ndarray
        F in [0, 1]; 1 under total internal reflection.
    """
    import numpy as np

    c = np.asarray(cos_theta_i, dtype=float)
    e = np.where(c >= 0, eta, 1.0 / eta)
    c = np.abs(c)
    sin2_t = (1.0 - c * c) / (e * e)
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    r_s = (c - e * cos_t) / (c + e * cos_t)
    r_p = (e * c - cos_t) / (e * c + cos_t)
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (r_s * r_s + r_p * r_p))


def register_cornea_bsdf(mi) -> None:
    """Register :data:`CORNEA_BSDF_TYPE` for Mitsuba's current variant (idempotent)."""
    variant = mi.variant()
    if variant in _REGISTERED:
        return
    import drjit as dr

    class CorneaBSDF(mi.BSDF):
        """Smooth dielectric, reflection sampled with a fixed probability from outside."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            int_ior = float(props.get("int_ior", 1.376))
            ext_ior = float(props.get("ext_ior", 1.0))
            self.eta = int_ior / ext_ior
            self.p_reflect = float(props.get("reflect_probability", REFLECT_PROBABILITY))
            if not (self.eta > 0 and 0.0 < self.p_reflect < 1.0):
                raise ValueError(f"{CORNEA_BSDF_TYPE}: need int_ior / ext_ior > 0 and 0 < "
                                 f"reflect_probability < 1, got {self.eta}, {self.p_reflect}")
            t = props.get("transmittance", [1.0, 1.0, 1.0])
            self.transmittance = mi.Color3f(float(t[0]), float(t[1]), float(t[2]))
            both = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            reflection = mi.BSDFFlags.DeltaReflection | both
            transmission = mi.BSDFFlags.DeltaTransmission | both | mi.BSDFFlags.NonSymmetric
            self.m_components = [reflection, transmission]
            self.m_flags = reflection | transmission

        def sample(self, ctx, si, sample1, sample2, active=True):
            cos_theta_i = mi.Frame3f.cos_theta(si.wi)
            F, cos_theta_t, eta_it, eta_ti = mi.fresnel(cos_theta_i, self.eta)
            has_r = ctx.is_enabled(mi.BSDFFlags.DeltaReflection, 0)
            has_t = ctx.is_enabled(mi.BSDFFlags.DeltaTransmission, 1)
            outside = cos_theta_i > 0
            # Probability of the reflected lobe: p from outside (F may be 0.03 there), F inside.
            p_r = dr.select(outside, self.p_reflect, F)
            if not (has_r and has_t):
                p_r = dr.full(mi.Float, 1.0 if has_r else 0.0) + 0.0 * F
            pick_r = sample1 <= p_r
            pdf = dr.select(pick_r, p_r, 1.0 - p_r)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = dr.select(pick_r, mi.reflect(si.wi), mi.refract(si.wi, cos_theta_t, eta_ti))
            bs.eta = dr.select(pick_r, 1.0, eta_it)
            bs.pdf = pdf
            bs.sampled_component = dr.select(pick_r, mi.UInt32(0), mi.UInt32(1))
            bs.sampled_type = dr.select(pick_r, mi.UInt32(+mi.BSDFFlags.DeltaReflection),
                                        mi.UInt32(+mi.BSDFFlags.DeltaTransmission))
            # Radiance crossing into the other medium is scaled by (eta_i / eta_t)^2.
            scale = eta_ti * eta_ti if ctx.mode == mi.TransportMode.Radiance else 1.0
            lobe = dr.select(pick_r, F, (1.0 - F) * scale)
            w = dr.select(pdf > 0, lobe / dr.maximum(pdf, 1e-30), 0.0)
            weight = dr.select(pick_r, mi.Color3f(1.0), self.transmittance) * w
            ok = active & (pdf > 0) & (cos_theta_i != 0)
            bs.pdf = dr.select(ok, bs.pdf, 0.0)
            return bs, dr.select(ok, weight, 0.0)

        def eval(self, ctx, si, wo, active=True):
            return mi.Color3f(0.0)  # delta lobes only

        def pdf(self, ctx, si, wo, active=True):
            return mi.Float(0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return mi.Color3f(0.0), mi.Float(0.0)

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return (f"CorneaBSDF[eta={self.eta}, reflect_probability={self.p_reflect}, "
                    f"transmittance={self.transmittance}]")

    mi.register_bsdf(CORNEA_BSDF_TYPE, lambda props: CorneaBSDF(props))
    _REGISTERED.add(variant)
