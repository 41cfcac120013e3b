"""Open water as a Mitsuba 3 BSDF plugin (``<bsdf type="water">``): a wind-roughened
Beckmann dielectric.

Registered in every JIT variant by ``import lidar_mitsuba_plugins`` (or ``import lidar_mitsuba``).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from lidar_mitsuba_plugins.water_optics import AIR_IOR, cox_munk_mss, quan_fry_index


def _param_error(name: str, message: str) -> ValueError:
    # Raised from the constructor; mi.load_dict / mi.load_string re-raise it as a RuntimeError
    # whose message ends with this text ("water: mss must be > 0 (got -0.1)").
    return ValueError(f"water: {name} {message}")


def _number(props: mi.Properties, name: str, default: float) -> float:
    value = float(props.get(name, default))
    if not math.isfinite(value):
        raise _param_error(name, f"must be finite (got {value})")
    return value


class WaterBSDF(mi.BSDF):
    r"""
    Water surface (:monosp:`water`)
    -------------------------------

    .. pluginparameters::

     * - wind_speed_mps
       - |float|
       - Wind speed at 12.5 m above the surface [m/s] (default 0): sets the mean-square slope
         by Cox & Munk's law below. Must be >= 0.
     * - mss
       - |float|
       - Total mean-square slope :math:`s^2` of the surface, instead of the wind speed
         (overrides ``wind_speed_mps``). Must be > 0.
     * - int_ior
       - |float|
       - Phase refractive index of the water (default 1.3360, Quan & Fry at 532 nm, 0 C,
         fresh water: meltwater). Must be > 0.
     * - ext_ior
       - |float|
       - Refractive index of the air above (default 1.000277). Must be > 0.
     * - group_index
       - |float|
       - Group refractive index of the water (default 1.3577, Quan & Fry at 532 nm, 0 C,
         fresh): a pulse travels at :math:`c/n_g` in the water. Stored on the instance for
         the integrators (``bsdf.group_index``); it does not change the scattering.
         Must be >= 1.

    The surface is a microfacet dielectric (Mitsuba's ``roughdielectric``, to which
    ``sample``, ``eval``, ``pdf`` and ``eval_pdf`` are delegated: reflection and refraction)
    with the Beckmann distribution of roughness :math:`\alpha = \sqrt{s^2}`. Beckmann's slope
    density :math:`P(z_x, z_y) = e^{-(z_x^2 + z_y^2)/\alpha^2}/(\pi\alpha^2)` has
    :math:`\langle z_x^2 + z_y^2\rangle = \alpha^2`: the total mean-square slope of the sea
    surface, which for a clean surface is

    .. math:: s^2 = 0.003 + 0.00512\,U

    with :math:`U` the wind speed [m/s] at 12.5 m (C. Cox and W. Munk, "Measurement of the
    roughness of the sea surface from photographs of the sun's glitter", J. Opt. Soc. Am.
    44(11), 838-850, 1954). The default indices come from the empirical formula of X. Quan and
    E. S. Fry, "Empirical equation for the index of refraction of seawater", Appl. Opt. 34(18),
    3477-3480, 1995, at 532 nm (the phase index, and the group index
    :math:`n - \lambda\,dn/d\lambda` from its derivative); ``lidar_mitsuba.ground.water`` gives them
    at any wavelength, temperature and salinity.

    At nadir the surface returns :math:`\pi f_r\cos\theta_o = F(0)/(4 s^2)`, with
    :math:`F(0) = ((n-1)/(n+1))^2` (:math:`G = 1` there): in the integrators' weight units
    (a 0.9 Lambertian plate weighs 1), :math:`F(0)/(3.6\,s^2)`, about 1.9 for calm water and 0.2
    at 5 m/s (``lidar_mitsuba.ground.water.nadir_return_weight``).

    The instance exposes ``mss``, ``alpha``, ``phase_index`` (``int_ior / ext_ior``),
    ``group_index`` and ``wind_speed_mps`` (``None`` when ``mss`` was given). ``mi.traverse``
    gives ``eta`` (``int_ior / ext_ior``) and ``alpha`` (:math:`\sqrt{s^2}`), as
    ``roughdielectric`` names them; an edit there reaches the inner BSDF and the attributes.

    .. tabs::

        .. code-tab:: xml

            <bsdf type="water">
                <float name="wind_speed_mps" value="5"/>
                <float name="int_ior" value="1.336"/>
            </bsdf>

        .. code-tab:: python

            {'type': 'water', 'wind_speed_mps': 5.0, 'int_ior': 1.336}

    Invalid parameters raise ``ValueError("water: <name> ...")`` in the constructor, which
    ``mi.load_dict`` / ``mi.load_string`` report as a ``RuntimeError`` containing that text.
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        wind = _number(props, "wind_speed_mps", 0.0)   # (read even when mss overrides it)
        if not wind >= 0:
            raise _param_error("wind_speed_mps", f"must be >= 0 (got {wind})")
        self.wind_speed_mps = wind
        mss = cox_munk_mss(wind)
        if "mss" in props:
            mss = _number(props, "mss", 0.0)
            if not mss > 0:
                raise _param_error("mss", f"must be > 0 (got {mss})")
            self.wind_speed_mps = None
        int_ior = _number(props, "int_ior", quan_fry_index())
        ext_ior = _number(props, "ext_ior", AIR_IOR)
        for name, value in (("int_ior", int_ior), ("ext_ior", ext_ior)):
            if not value > 0:
                raise _param_error(name, f"must be > 0 (got {value})")
        group_index = _number(props, "group_index", quan_fry_index(group=True))
        if not group_index >= 1:
            raise _param_error("group_index", f"must be >= 1 (got {group_index})")
        self.mss = mss
        self.alpha = math.sqrt(mss)
        self.int_ior, self.ext_ior = int_ior, ext_ior
        self.phase_index = int_ior / ext_ior
        self.group_index = group_index
        self._inner = mi.load_dict({"type": "roughdielectric", "distribution": "beckmann",
                                    "alpha": self.alpha, "int_ior": int_ior,
                                    "ext_ior": ext_ior})
        self._eta = mi.Float(self.phase_index)
        self._alpha = mi.Float(self.alpha)
        self._copy_flags()

    def _copy_flags(self) -> None:
        inner = self._inner
        self.m_components = [inner.flags(i) for i in range(inner.component_count())]
        self.m_flags = inner.flags()

    # ---------------------------------------------------------------- interface
    def sample(self, ctx, si, sample1, sample2, active=True):
        return self._inner.sample(ctx, si, sample1, sample2, active)

    def eval(self, ctx, si, wo, active=True):
        return self._inner.eval(ctx, si, wo, active)

    def pdf(self, ctx, si, wo, active=True):
        return self._inner.pdf(ctx, si, wo, active)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._inner.eval_pdf(ctx, si, wo, active)

    def traverse(self, callback):
        # The inner roughdielectric's own parameters under the names it gives them ("eta",
        # "alpha"): an edit is passed on to it in parameters_changed.
        callback.put("eta", self._eta, mi.ParamFlags.Differentiable)
        callback.put("alpha", self._alpha, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        # eta / alpha may have been edited through mi.traverse: hand them to the inner BSDF
        # and keep the Python attributes in step. (No validation: an optimiser may step
        # anywhere.)
        inner = mi.traverse(self._inner)
        inner["eta"] = self._eta
        inner["alpha.value"] = self._alpha
        inner.update()
        self.phase_index = float(dr.ravel(self._eta)[0])
        self.alpha = float(dr.ravel(self._alpha)[0])
        self.mss = self.alpha ** 2
        self._copy_flags()

    def to_string(self):
        return (f"WaterBSDF[mss={self.mss:g}, phase_index={self.phase_index:.6f}, "
                f"group_index={self.group_index:.6f}]")


mi.register_bsdf("water", lambda props: WaterBSDF(props))
