"""Snow as a scattering volume at 532 nm: optical coefficients from grain size and density,
the Mitsuba scene of a snowpack under a terrain mesh, and diffusion theory's closed forms.
Pure numpy except :meth:`SnowVolume.shapes` (Mitsuba shape dicts).

At 532 nm snow is a weakly absorbing, strongly scattering volume. Its optics follow from two
quantities a glaciologist measures, the optical (effective) grain radius ``r`` and the density
``rho``, in the geometric-optics limit (grains much larger than the wavelength; Bohren &
Barkstrom 1974, J. Geophys. Res. 79, 4527; Kokhanovsky & Zege 2004, Appl. Opt. 43, 1589):

* ice volume fraction ``f = rho / 917 kg m^-3``;
* extinction ``sigma_t = 3 f / (2 r)`` [1/m] (extinction efficiency 2, diffraction included);
* absorption ``sigma_a = B f alpha_ice`` [1/m], with ``alpha_ice = 4 pi k / lambda`` the bulk
  absorption of ice and ``B`` the absorption enhancement: ``n^2 (1 - (1 - 1/n^2)^(3/2))``, about
  1.25, for a large sphere; measured on 36 natural snow samples, 0.7-2.4 with a wide peak at
  1.4-1.8, and B = 1.6 recommended for snow (Libois et al. 2014, J. Glaciol. 60, 714): the
  default (:data:`B_NATURAL_SNOW`). Absorption does not depend on grain size;
* Henyey-Greenstein phase function of asymmetry ``g``: 0.89 for spheres at n = 1.31
  (:data:`G_ICE_SPHERES`); non-spherical grains scatter less forward. The default
  :data:`G_NATURAL_SNOW` = 0.80 is our estimate for natural snow within the 0.75-0.85 that
  non-spherical shapes give (Libois et al. 2013, The Cryosphere 7, 1803, pair g = 0.80 with
  their B = 1.6 shapes; we recall that pairing and could not re-read it here). Optionally a
  backscattering lobe (a two-term HG, ``backscatter_fraction``);
* group index of the snowpack for the photons' delay, ``1 + (n_ice - 1) f`` (a random line
  through snow spends the fraction ``f`` of its length in ice);
* optionally a denser surface layer (a wind crust, ``crust_m``) of its own grains and density
  over the pack.

``alpha_ice`` at 532 nm is 0.04 m^-1 by default (k about 1.7e-9). It is uncertain: Picard et
al. 2016 (The Cryosphere 10, 2655) measured ice absorption in the 400-600 nm range about an
order of magnitude above the Warren & Brandt 2008 compilation near its 400-450 nm minimum, and
recommend taking the uncertainty into account. At 532 nm ice absorbs more and the sources
differ less; the parameter is ours to vary (``bench``'s snow-optics table: x0.5 and x2.5 move
ATL06 ``h_li`` by < 0.7 cm). For r = 100 um and rho = 350 kg m^-3 the mean free path is 0.17
mm and the single-scattering albedo 1 - 4e-6: photons wander 10^3 to 10^4 scatterings before
coming back.

The snow surface is index-matched (a ``null`` BSDF): the air-snow boundary is rough and porous
at the grain scale, and its refraction and reflection are already in the grains' scattering.

Diffusion theory (:class:`DiffusionHalfSpace`) gives the time-resolved reflectance of a
semi-infinite medium under a normal pencil beam: with the extrapolated boundary the path
length of the returned light is the sum of two inverse-Gaussian laws, so its total, mean and
variance are closed forms (Patterson, Chance & Wilson 1989, Appl. Opt. 28, 2331; Farrell,
Patterson & Wilson 1992, Med. Phys. 19, 879).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ...constants import ParameterError, check

#: density of ice [kg m^-3]
RHO_ICE_KG_M3 = 917.0
#: real refractive index of ice at 532 nm (Warren & Brandt 2008)
N_ICE_532 = 1.3117
#: bulk absorption coefficient of pure ice at 532 nm [1/m] (see the module docstring)
ICE_ABSORPTION_532_PER_M = 0.04
#: asymmetry parameter of large ice spheres at 532 nm
G_ICE_SPHERES = 0.89
#: asymmetry parameter of natural (non-spherical) snow grains, the default of
#: :func:`snow_from_grains` (our estimate; see the module docstring)
G_NATURAL_SNOW = 0.80
#: absorption enhancement of natural snow (Libois et al. 2014), :func:`snow_from_grains`'
#: default
B_NATURAL_SNOW = 1.6
#: path length inside the snow [m] that the default interaction cap covers (sigma_s x this):
#: ATL06 h_li changes by less than its Monte Carlo error (~0.5 cm) beyond it (bench's
#: snow study), while the raw photon mean never settles (the path tail falls as L^-3/2)
DEFAULT_PATH_M = 10.0


def absorption_enhancement(n: float = N_ICE_532) -> float:
    """``B = n^2 (1 - (1 - 1/n^2)^(3/2))``: absorption of a large, weakly absorbing sphere
    relative to its volume times the bulk absorption coefficient."""
    return n * n * (1.0 - (1.0 - 1.0 / (n * n)) ** 1.5)


@dataclass(frozen=True)
class SnowVolume:
    """A homogeneous snowpack under the terrain surface (its top), as a Mitsuba medium.

    Attributes:
        sigma_s_per_m: scattering coefficient [1/m].
        sigma_a_per_m: absorption coefficient [1/m].
        g: Henyey-Greenstein asymmetry parameter.
        group_index: ratio of the photons' delay inside the snow to the delay of the same
            path length in air (1 for the closed-form checks).
        depth_m: thickness of the layer [m] (``inf``: semi-infinite).
        base_albedo: Lambertian albedo of the opaque base under a finite layer (0: black).
        max_events: interactions traced per photon (volume scatterings and base hits);
            light still inside after that is lost: the accuracy-versus-time knob. ``None``
            (default): enough for ``DEFAULT_PATH_M`` of path, ``ceil(sigma_s x 10 m)``
            (:attr:`events_cap`).
        grain_radius_um, density_kg_m3: the physical parameters it came from, if any
            (:func:`snow_from_grains`), for the record.
    """
    sigma_s_per_m: float
    sigma_a_per_m: float
    g: float = G_ICE_SPHERES
    group_index: float = 1.0
    depth_m: float = math.inf
    base_albedo: float = 0.0
    max_events: int | None = None
    grain_radius_um: float | None = None
    density_kg_m3: float | None = None
    #: the asymmetry this volume was rescaled from by :meth:`similar` (None: not rescaled)
    similar_to_g: float | None = None
    #: a backscattering lobe: the phase function is the two-term Henyey-Greenstein
    #: ``(1 - b) HG(g) + b HG(backscatter_g)`` with ``b = backscatter_fraction`` (0: one term)
    backscatter_fraction: float = 0.0
    backscatter_g: float = -0.5
    #: the absorption enhancement B it came from (:func:`snow_from_grains`), for the record
    absorption_enhancement: float | None = None
    #: a denser surface layer (wind crust) this thick [m], measured vertically (0: none),
    #: with the optics of ``crust`` (a SnowVolume: its coefficients, g and group index)
    crust_m: float = 0.0
    crust: "SnowVolume | None" = None

    def __post_init__(self):
        check("sigma_s_per_m", self.sigma_s_per_m,
              math.isfinite(self.sigma_s_per_m) and self.sigma_s_per_m > 0, "must be > 0")
        check("sigma_a_per_m", self.sigma_a_per_m,
              math.isfinite(self.sigma_a_per_m) and self.sigma_a_per_m >= 0, "must be >= 0")
        check("snow_g", self.g, math.isfinite(self.g) and -1 < self.g < 1, "must be in (-1, 1)")
        check("group_index", self.group_index,
              math.isfinite(self.group_index) and 1 <= self.group_index <= 2,
              "must be in [1, 2]")
        check("snow_depth_m", self.depth_m, self.depth_m > 0, "must be > 0 (inf: semi-infinite)")
        check("base_albedo", self.base_albedo, 0 <= self.base_albedo <= 1, "must be in [0, 1]")
        check("snow_crust_m", self.crust_m, 0 <= self.crust_m < self.depth_m and (
              self.crust_m == 0 or (self.crust is not None and self.crust.crust_m == 0
                                    and self.crust.backscatter_fraction == 0)),
              "must be in [0, depth) with a crust's optics (one layer, one-term HG)")
        check("snow_backscatter", self.backscatter_fraction,
              0 <= self.backscatter_fraction < 1, "must be in [0, 1)")
        check("snow_backscatter_g", self.backscatter_g, -1 < self.backscatter_g <= 0,
              "must be in (-1, 0]")
        check("snow_max_events", self.max_events, self.max_events is None or (
              isinstance(self.max_events, (int, np.integer)) and 1 <= self.max_events <= 10 ** 7),
              "must be an integer in [1, 1e7]")

    # ------------------------------------------------------------ derived
    @property
    def sigma_t_per_m(self) -> float:
        return self.sigma_s_per_m + self.sigma_a_per_m

    @property
    def events_cap(self) -> int:
        """Interactions traced per photon: ``max_events``, or enough for ``DEFAULT_PATH_M``."""
        if self.max_events is not None:
            return int(self.max_events)
        return int(min(10 ** 7, math.ceil(self.sigma_s_per_m * DEFAULT_PATH_M)))

    @property
    def albedo(self) -> float:
        """Single-scattering albedo sigma_s / sigma_t."""
        return self.sigma_s_per_m / self.sigma_t_per_m

    @property
    def asymmetry(self) -> float:
        """The phase function's mean cosine: ``g``, or ``(1 - b) g + b g_back`` with a
        backscattering lobe."""
        b = self.backscatter_fraction
        return (1.0 - b) * self.g + b * self.backscatter_g

    @property
    def reduced_scattering_per_m(self) -> float:
        """sigma_s (1 - <cos>) [1/m]: the inverse of the transport mean free path."""
        return self.sigma_s_per_m * (1.0 - self.asymmetry)

    def similar(self, g: float) -> "SnowVolume":
        """The same snow for diffusion (same reduced scattering sigma_s (1 - g) and
        absorption) with asymmetry ``g`` instead: fewer, longer free paths, so fewer
        interactions per photon (``max_events`` scaled to cover the same path length). Exact
        where diffusion holds, approximate in the first few transport free paths, which is
        where the earliest returns come from: ``bench`` measures what it costs in accuracy."""
        check("snow_similarity_g", g, isinstance(g, (int, float)) and 0 <= g <= self.g,
              f"must be in [0, {self.g:g}] (the snow's own g)")
        check("snow_similarity_g", g, self.backscatter_fraction == 0,
              "does not apply to a two-term phase function (--snow-backscatter)")
        scale = (1.0 - self.g) / (1.0 - g)
        return dataclasses.replace(
            self, sigma_s_per_m=self.sigma_s_per_m * scale, g=float(g),
            max_events=(None if self.max_events is None
                        else max(1, int(round(self.max_events * scale)))),
            similar_to_g=self.g if self.similar_to_g is None else self.similar_to_g)

    def diffusion(self) -> "DiffusionHalfSpace":
        """Diffusion theory for this medium as a half-space (ignores ``depth_m``)."""
        return DiffusionHalfSpace(mu_s_prime_per_m=self.reduced_scattering_per_m,
                                  mu_a_per_m=self.sigma_a_per_m)

    # ------------------------------------------------------------ Mitsuba
    def phase_dict(self) -> dict:
        """Mitsuba dict of the phase function: ``hg``, or a ``blendphase`` of two."""
        hg = {"type": "hg", "g": float(self.g)}
        if self.backscatter_fraction == 0:
            return hg
        return {"type": "blendphase", "weight": float(self.backscatter_fraction),
                "phase1": hg, "phase2": {"type": "hg", "g": float(self.backscatter_g)}}

    def medium_dict(self) -> dict:
        """Mitsuba dict of the homogeneous medium."""
        return {"type": "homogeneous", "sigma_t": float(self.sigma_t_per_m),
                "albedo": float(self.albedo), "phase": self.phase_dict()}

    def shapes(self, vertices: np.ndarray, faces: np.ndarray) -> dict:
        """Mitsuba shapes of the snowpack under a terrain mesh: the terrain, index-matched
        (``null`` BSDF), with the snow as its interior medium. A finite layer's base is not
        a mesh: the integrator places it ``depth_m`` below the surface
        (:meth:`integrator_params`)."""
        from ...trace import scene as scn
        medium = scn.mi.load_dict(self.medium_dict())
        return {"terrain": scn.mitsuba_mesh(vertices, faces, bsdf={"type": "null"},
                                            interior=medium)}

    def integrator_params(self) -> dict:
        """The ``volpathlength`` integrator's parameters for this snowpack."""
        out = {"type": "volpathlength", "max_depth": self.events_cap,
               "group_index": float(self.group_index), "snow_depth_m": float(self.depth_m),
               "base_albedo": float(self.base_albedo)}
        if self.crust_m > 0:
            c = self.crust
            out.update(crust_m=float(self.crust_m), crust_sigma_t=float(c.sigma_t_per_m),
                       crust_albedo=float(c.albedo), crust_g=float(c.g),
                       crust_group_index=float(c.group_index))
        return out

    def xml(self) -> str:
        """The ``<medium>`` and ``<bsdf>`` elements to put inside a terrain ``<shape>``."""
        phase = f'<phase type="hg"><float name="g" value="{self.g:g}"/></phase>'
        if self.backscatter_fraction > 0:
            phase = (f'<phase type="blendphase">\n'
                     f'        <float name="weight" value="{self.backscatter_fraction:g}"/>\n'
                     f'        {phase}\n'
                     f'        <phase type="hg"><float name="g" value="{self.backscatter_g:g}"/>'
                     f'</phase>\n    </phase>')
        return (f'<bsdf type="null"/>\n'
                f'<medium name="interior" type="homogeneous">\n'
                f'    <float name="sigma_t" value="{self.sigma_t_per_m:.6g}"/>\n'
                f'    <float name="albedo" value="{self.albedo:.9f}"/>\n'
                f'    {phase}\n'
                f'</medium>')

    def walk_inputs(self) -> dict:
        """Everything the random walk's result depends on (a kernel table's cache key)."""
        return {"sigma_s_per_m": float(self.sigma_s_per_m),
                "sigma_a_per_m": float(self.sigma_a_per_m), "phase": self.medium_dict()["phase"],
                "group_index": float(self.group_index), "depth_m": float(self.depth_m),
                "base_albedo": float(self.base_albedo), "max_events": int(self.events_cap),
                **({"crust_m": float(self.crust_m), "crust": self.crust.walk_inputs()}
                   if self.crust_m > 0 else {})}

    def config(self) -> dict:
        return {"grain_radius_um": self.grain_radius_um, "density_kg_m3": self.density_kg_m3,
                "sigma_s_per_m": self.sigma_s_per_m, "sigma_a_per_m": self.sigma_a_per_m,
                "g": self.g, "group_index": self.group_index,
                "depth_m": None if math.isinf(self.depth_m) else self.depth_m,
                "base_albedo": self.base_albedo, "max_events": self.events_cap,
                "similar_to_g": self.similar_to_g,
                "backscatter_fraction": self.backscatter_fraction,
                "backscatter_g": self.backscatter_g,
                "absorption_enhancement": self.absorption_enhancement,
                "crust_m": self.crust_m,
                "crust": self.crust.config() if self.crust_m > 0 else None}

    def describe(self) -> str:
        """One line for ``--explain``."""
        d = self.diffusion()
        src = (f"grains r = {self.grain_radius_um:g} um, density {self.density_kg_m3:g} kg/m^3: "
               if self.grain_radius_um is not None else "")
        depth = "semi-infinite" if math.isinf(self.depth_m) else (
            f"{self.depth_m:g} m deep over a base of albedo {self.base_albedo:g}")
        if self.similar_to_g is not None:
            src += (f"rescaled by similarity from g {self.similar_to_g:g} (same sigma_s (1 - g)"
                    f"; approximate near the surface), ")
        lobe = (f" with a {self.backscatter_fraction:g} backscattering lobe (g "
                f"{self.backscatter_g:g})" if self.backscatter_fraction > 0 else "")
        b = ("" if self.absorption_enhancement is None else
             f", B {self.absorption_enhancement:g}")
        if self.crust_m > 0:
            c = self.crust
            depth = (f"under a {100 * self.crust_m:g} cm crust (sigma_s "
                     f"{c.sigma_s_per_m:.4g} /m, g {c.g:g}"
                     + (f", grains {c.grain_radius_um:g} um, {c.density_kg_m3:g} kg/m^3"
                        if c.grain_radius_um is not None else "") + "), " + depth)
        return (f"snow volume on ({src}sigma_s {self.sigma_s_per_m:.4g} /m, sigma_a "
                f"{self.sigma_a_per_m:.3g} /m{b}, g {self.g:g}{lobe}, {depth}, index-matched "
                f"surface, "
                f"group index {self.group_index:.3f}); diffusion theory: mean extra path "
                f"{d.mean_path_m():.3g} m, {d.mean_path_m() * self.sigma_s_per_m:.0f} "
                f"scatterings per returned photon on average; traced up to {self.events_cap} "
                f"interactions per photon ({self.events_cap / self.sigma_s_per_m:.3g} m of "
                f"path)")


def medium_events_cap(medium) -> int:
    """The default interaction cap (``DEFAULT_PATH_M`` of path) for a Mitsuba homogeneous
    medium, e.g. the ``<medium>`` of an XML scene: ``ceil(scale sigma_t albedo x 10 m)``."""
    import mitsuba as mi
    p = mi.traverse(medium)
    sigma_s = (float(p["scale"]) * float(p["sigma_t.value.value"][0])
               * float(p["albedo.value.value"][0]))
    return int(min(10 ** 7, max(1, math.ceil(sigma_s * DEFAULT_PATH_M))))


def snow_from_grains(*, grain_radius_um: float, density_kg_m3: float = 350.0,
                     depth_m: float = math.inf, base_albedo: float = 0.0,
                     g: float = G_NATURAL_SNOW,
                     ice_absorption_per_m: float = ICE_ABSORPTION_532_PER_M,
                     absorption_enhancement_b: float | None = B_NATURAL_SNOW,
                     backscatter_fraction: float = 0.0, backscatter_g: float = -0.5,
                     crust_m: float = 0.0, crust_grain_um: float | None = None,
                     crust_density_kg_m3: float | None = None,
                     group_index: float | None = None,
                     max_events: int | None = None) -> SnowVolume:
    """A :class:`SnowVolume` from optical grain radius [um] and density [kg m^-3] (the
    relations in the module docstring): natural snow's ``g`` 0.80 and ``B`` 1.6 by default
    (``g=G_ICE_SPHERES, absorption_enhancement_b=None`` for spheres: ``None`` is a large
    sphere's B, :func:`absorption_enhancement`); ``backscatter_fraction`` > 0 adds a
    backscattering lobe (two-term HG); ``crust_m`` > 0 a denser surface layer (wind crust)
    of ``crust_grain_um`` and ``crust_density_kg_m3`` (default: the pack's) with the same
    ice optics; ``group_index`` ``None``: ``1 + (n_ice - 1) f``.

    >>> import lidar_mitsuba as lm
    >>> vol = lm.snow_from_grains(grain_radius_um=100, density_kg_m3=350)
    >>> res = lm.simulate(surface=lm.SurfaceSpec(kind="flat"), snow=vol, shots=500)
    ...                                                                 # doctest: +SKIP"""
    check("snow_grain_um", grain_radius_um,
          isinstance(grain_radius_um, (int, float)) and math.isfinite(grain_radius_um)
          and 5 <= grain_radius_um <= 5000, "must be in [5, 5000] um (geometric optics)")
    check("snow_density", density_kg_m3,
          isinstance(density_kg_m3, (int, float)) and math.isfinite(density_kg_m3)
          and 10 <= density_kg_m3 <= 0.9 * RHO_ICE_KG_M3,
          f"must be in [10, {0.9 * RHO_ICE_KG_M3:g}] kg/m^3")
    f = density_kg_m3 / RHO_ICE_KG_M3
    r_m = grain_radius_um * 1e-6
    sigma_t = 1.5 * f / r_m
    check("snow_absorption_b", absorption_enhancement_b, absorption_enhancement_b is None or (
          isinstance(absorption_enhancement_b, (int, float))
          and 0.5 <= absorption_enhancement_b <= 3), "must be in [0.5, 3]")
    check("snow_ice_absorption", ice_absorption_per_m, isinstance(ice_absorption_per_m, (
          int, float)) and 0 <= ice_absorption_per_m <= 10, "must be in [0, 10] 1/m")
    b = absorption_enhancement() if absorption_enhancement_b is None else absorption_enhancement_b
    crust = None
    if crust_m:
        try:
            crust = snow_from_grains(
                grain_radius_um=grain_radius_um if crust_grain_um is None else crust_grain_um,
                density_kg_m3=(density_kg_m3 if crust_density_kg_m3 is None
                               else crust_density_kg_m3),
                g=g, ice_absorption_per_m=ice_absorption_per_m, absorption_enhancement_b=b)
        except ParameterError as e:       # name the crust's own option
            raise ParameterError({"snow_grain_um": "snow_crust_grain_um",
                                  "snow_density": "snow_crust_density"}.get(e.name, e.name),
                                 e.message) from None
    elif crust_grain_um is not None or crust_density_kg_m3 is not None:
        raise ParameterError("snow_crust_m", "give the crust's thickness (> 0) with its "
                             "grains or density")
    sigma_a = b * f * ice_absorption_per_m
    if group_index is None:
        group_index = 1.0 + (N_ICE_532 - 1.0) * f
    return SnowVolume(sigma_s_per_m=sigma_t - sigma_a, sigma_a_per_m=sigma_a, g=g,
                      group_index=group_index, depth_m=depth_m, base_albedo=base_albedo,
                      max_events=max_events, grain_radius_um=float(grain_radius_um),
                      density_kg_m3=float(density_kg_m3), absorption_enhancement=float(b),
                      backscatter_fraction=float(backscatter_fraction),
                      backscatter_g=float(backscatter_g), crust_m=float(crust_m),
                      crust=crust)


# --------------------------------------------------------------------------- diffusion theory
@dataclass(frozen=True)
class DiffusionHalfSpace:
    """Diffusion theory of a semi-infinite, index-matched medium under a normal pencil beam.

    The beam is replaced by an isotropic source at depth ``z0 = 1/mu_s'``; the boundary
    condition (zero fluence at the extrapolated boundary ``zb = 2 D``, ``D = 1/(3 mu_s')``)
    adds a negative image at ``-(z0 + 2 zb)``. The flux leaving the surface, integrated over
    the surface, as a density in path length ``L`` [m] travelled inside the medium, is

        R(L) = 1/2 sum_i  a_i / (2 sqrt(pi)) L^(-3/2) exp(-a_i^2 / (4 L)) exp(-mu_a L),
        a_1 = z0 / sqrt(D),   a_2 = (z0 + 2 zb) / sqrt(D),

    two inverse-Gaussian laws: total ``R = 1/2 sum exp(-a_i sqrt(mu_a))``, and closed-form
    moments. Valid where ``mu_a << mu_s'`` and for paths much longer than ``1/mu_s'``.

    Attributes:
        mu_s_prime_per_m: reduced scattering coefficient sigma_s (1 - g) [1/m].
        mu_a_per_m: absorption coefficient [1/m] (>= 0; 0: the moments are infinite).
    """
    mu_s_prime_per_m: float
    mu_a_per_m: float

    @property
    def _a(self) -> np.ndarray:
        z0 = 1.0 / self.mu_s_prime_per_m
        D = z0 / 3.0
        return np.array([z0, z0 + 4.0 * D]) / math.sqrt(D)

    def total_reflectance(self) -> float:
        """Fraction of the incident power that leaves the surface."""
        return float(0.5 * np.sum(np.exp(-self._a * math.sqrt(self.mu_a_per_m))))

    def path_pdf(self, L_m) -> np.ndarray:
        """R(L) [1/m]: returned power per unit path length (integrates to the total)."""
        L = np.asarray(L_m, float)[..., None]
        a = self._a
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            f = a / (2.0 * math.sqrt(math.pi)) * L ** -1.5 * np.exp(-a * a / (4.0 * L)
                                                                     - self.mu_a_per_m * L)
        return 0.5 * np.sum(np.where(L > 0, f, 0.0), axis=-1)

    def path_cdf(self, L_m) -> np.ndarray:
        """Returned power with path length below ``L`` (closed form; -> total as L -> inf)."""
        from scipy.special import erfc, erfcx
        L = np.maximum(np.asarray(L_m, float)[..., None], 1e-300)
        a, mu = self._a, self.mu_a_per_m
        s = math.sqrt(mu)
        x = a / (2.0 * np.sqrt(L))
        y = s * np.sqrt(L)
        # Laplace-tilted Levy law: 1/2 [e^{-a s} erfc(x - y) + e^{a s} erfc(x + y)], the
        # second written as erfcx(x + y) e^{-x^2 - y^2} (2 x y = a s), which cannot overflow
        term = 0.5 * (np.exp(-a * s) * erfc(x - y) + erfcx(x + y) * np.exp(-x * x - y * y))
        return 0.5 * np.sum(term, axis=-1)

    def _moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Per image term: its weight and its (mean, second moment) of path length."""
        if self.mu_a_per_m <= 0:
            raise ValueError("the path-length moments of a non-absorbing half-space are infinite")
        a, s = self._a, math.sqrt(self.mu_a_per_m)
        weight = 0.5 * np.exp(-a * s)
        mean = a / (2.0 * s)                 # inverse Gaussian: mean m, shape a^2 / 2
        var = mean ** 3 / (a * a / 2.0)
        return weight, np.stack([mean, var + mean * mean])

    def mean_path_m(self) -> float:
        """Mean path length [m] inside the medium of the returned light."""
        w, (m1, _) = self._moments()
        return float(np.sum(w * m1) / np.sum(w))

    def var_path_m2(self) -> float:
        """Variance of the path length [m^2] of the returned light."""
        w, (m1, m2) = self._moments()
        mean = np.sum(w * m1) / np.sum(w)
        return float(np.sum(w * m2) / np.sum(w) - mean * mean)


def gamma_fit(path_m: np.ndarray, weight: np.ndarray) -> tuple[float, float]:
    """Gamma law (shape k, scale theta [m]) fitted to weighted path lengths by maximum
    likelihood (as Hu et al. 2022 describe the lidar return of snow): k solves
    ``ln k - digamma(k) = ln(mean L) - mean(ln L)`` and ``theta = mean L / k`` (weighted
    means; paths must be > 0)."""
    from scipy.optimize import brentq
    from scipy.special import digamma
    w = np.asarray(weight, float)
    x = np.asarray(path_m, float)
    if np.any(x <= 0) or np.sum(w) <= 0:
        raise ValueError("gamma_fit needs path lengths > 0 and a positive total weight")
    mean = np.sum(w * x) / np.sum(w)
    s = math.log(mean) - np.sum(w * np.log(x)) / np.sum(w)
    k = brentq(lambda k: math.log(k) - digamma(k) - s, 1e-6, 1e8)
    return float(k), float(mean / k)
