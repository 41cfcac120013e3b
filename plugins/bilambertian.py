"""Bi-Lambertian leaf BSDF as a Mitsuba 3 BSDF plugin (``<bsdf type="bilambertian">``).

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi


def _param_error(name: str, message: str) -> ValueError:
    # Raised from the constructor; mi.load_dict re-raises it as a RuntimeError ending with
    # this text ("bilambertian: reflectance must be >= 0 (got -0.1)").
    return ValueError(f"bilambertian: {name} {message}")


class BiLambertianBSDF(mi.BSDF):
    r"""
    Bi-Lambertian leaf (:monosp:`bilambertian`)
    -------------------------------------------

    .. pluginparameters::

     * - reflectance
       - |float|
       - Leaf hemispherical reflectance :math:`R` (default 0.12, a green leaf at 532 nm).
     * - transmittance
       - |float|
       - Leaf hemispherical transmittance :math:`T` (default 0.12). :math:`R + T \le 1`.

    A thin leaf that scatters like two Lambertian lobes (the leaf model of the radiative
    transfer codes for vegetation: Ross 1981; DART; LESS): light arriving on either face is
    reflected diffusely back to that side with albedo :math:`R` and transmitted diffusely to
    the other side with albedo :math:`T`,

    .. math::

        f(\mathbf{i}, \mathbf{o}) = \frac{R}{\pi}\ \ (i_z o_z > 0), \qquad
        f(\mathbf{i}, \mathbf{o}) = \frac{T}{\pi}\ \ (i_z o_z < 0),

    the same from both faces (two-sided: a leaf has no outside). ``eval`` returns
    :math:`f\,|\cos\theta_o|`. Sampling picks reflection with probability :math:`R/(R+T)`
    and draws :math:`\mathbf{o}` cosine-distributed on the chosen side, so the sample weight
    is :math:`R + T` (the directional albedo, for every incidence) and
    ``pdf`` = :math:`R/(R+T)\,|\cos\theta_o|/\pi` on the lit side,
    :math:`T/(R+T)\,|\cos\theta_o|/\pi` on the other. A black leaf (:math:`R = T = 0`)
    samples nothing.

    .. tabs::

        .. code-tab:: xml

            <bsdf type="bilambertian">
                <float name="reflectance" value="0.12"/>
                <float name="transmittance" value="0.12"/>
            </bsdf>

        .. code-tab:: python

            {'type': 'bilambertian', 'reflectance': 0.12, 'transmittance': 0.12}
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        r = float(props.get("reflectance", 0.12))
        t = float(props.get("transmittance", 0.12))
        for name, value in (("reflectance", r), ("transmittance", t)):
            if not value >= 0:
                raise _param_error(name, f"must be >= 0 (got {value})")
        if not r + t <= 1.0 + 1e-6:
            raise _param_error("reflectance", f"+ transmittance must be <= 1 (got {r} + {t})")
        self.reflectance = dr.opaque(mi.Float, r)
        self.transmittance = dr.opaque(mi.Float, t)
        flags_r = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
                   | mi.BSDFFlags.BackSide)
        flags_t = (mi.BSDFFlags.DiffuseTransmission | mi.BSDFFlags.FrontSide
                   | mi.BSDFFlags.BackSide)
        self.m_components = [flags_r, flags_t]
        self.m_flags = flags_r | flags_t

    def _wants(self, ctx):
        return (ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0),
                ctx.is_enabled(mi.BSDFFlags.DiffuseTransmission, 1))

    def _odds(self, ctx) -> mi.Float:
        """Probability of sampling reflection (given which lobes the context enables)."""
        has_r, has_t = self._wants(ctx)
        if has_r and not has_t:
            return mi.Float(1.0)
        if has_t and not has_r:
            return mi.Float(0.0)
        total = self.reflectance + self.transmittance
        return dr.select(total > 0, self.reflectance / total, 0.5)

    def eval(self, ctx, si, wo, active=True):
        has_r, has_t = self._wants(ctx)
        cos_i = mi.Frame3f.cos_theta(si.wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        same = cos_i * cos_o > 0
        albedo = dr.select(same, self.reflectance if has_r else 0.0,
                           self.transmittance if has_t else 0.0)
        ok = active & (cos_i != 0) & (cos_o != 0)
        return mi.Spectrum(dr.select(ok, albedo * dr.inv_pi * dr.abs(cos_o), 0.0))

    def pdf(self, ctx, si, wo, active=True):
        cos_i = mi.Frame3f.cos_theta(si.wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        p_r = self._odds(ctx)
        lobe = dr.select(cos_i * cos_o > 0, p_r, 1.0 - p_r)
        ok = active & (cos_i != 0) & (cos_o != 0)
        return dr.select(ok, lobe * dr.abs(cos_o) * dr.inv_pi, 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        has_r, has_t = self._wants(ctx)
        bs = dr.zeros(mi.BSDFSample3f)
        if not (has_r or has_t):
            return bs, mi.Spectrum(0.0)
        cos_i = mi.Frame3f.cos_theta(si.wi)
        p_r = self._odds(ctx)
        reflect = sample1 < p_r
        wo = mi.warp.square_to_cosine_hemisphere(sample2)
        # the lit side is the side of wi; transmission goes to the other one
        flip = dr.select(reflect, cos_i < 0, cos_i > 0)
        wo.z = dr.select(flip, -wo.z, wo.z)
        value, pdf = self.eval_pdf(ctx, si, wo, active)
        active = active & (cos_i != 0) & (pdf > 0)
        bs.wo = wo
        bs.pdf = dr.select(active, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(dr.select(
            reflect, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
            mi.UInt32(+mi.BSDFFlags.DiffuseTransmission)))
        bs.sampled_component = dr.select(reflect, mi.UInt32(0), mi.UInt32(1))
        weight = dr.select(active, value / dr.select(active, pdf, 1.0), mi.Spectrum(0.0))
        return bs, weight

    def traverse(self, callback):
        callback.put("reflectance", self.reflectance, mi.ParamFlags.Differentiable)
        callback.put("transmittance", self.transmittance, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        dr.make_opaque(self.reflectance, self.transmittance)

    def to_string(self):
        return (f"BiLambertianBSDF[reflectance={self.reflectance}, "
                f"transmittance={self.transmittance}]")


mi.register_bsdf("bilambertian", lambda props: BiLambertianBSDF(props))
