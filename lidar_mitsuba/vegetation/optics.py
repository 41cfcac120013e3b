"""Optics of a forest at 532 nm: leaves, needles, bark, litter, soil and snow.

Each element is an :class:`Optics`: hemispherical reflectance ``R`` and transmittance ``T``
(both Lambertian: the bi-Lambertian leaf of ``plugins/bilambertian.py``; an opaque element
has ``T = 0`` and traces as a ``diffuse`` BSDF) and where the numbers come from. Values not
read from a source are marked ESTIMATE with the reasoning, as the developers' guide asks.

>>> from lidar_mitsuba.vegetation.optics import OPTICS
>>> OPTICS["leaf"].albedo
0.245

Mitsuba BSDF dicts: :meth:`Optics.bsdf_dict`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..constants import ParameterError, check

WAVELENGTH_NM = 532.0


@dataclass(frozen=True)
class Optics:
    """An element's optics at 532 nm.

    Attributes:
        name: what it is.
        reflectance: hemispherical reflectance R [-].
        transmittance: hemispherical transmittance T [-] (0: opaque).
        source: where the numbers come from (or ESTIMATE and why).
    """
    name: str
    reflectance: float
    transmittance: float
    source: str

    def __post_init__(self):
        for field in ("reflectance", "transmittance"):
            v = getattr(self, field)
            check(field, v, isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 1,
                  "must be in [0, 1]")
        if self.reflectance + self.transmittance > 1:
            raise ParameterError("reflectance", f"R + T must be <= 1 (got {self.reflectance} "
                                 f"+ {self.transmittance})")

    @property
    def albedo(self) -> float:
        """Single-scattering albedo R + T."""
        return round(self.reflectance + self.transmittance, 12)

    def bsdf_dict(self) -> dict:
        """The Mitsuba BSDF: ``bilambertian`` (R, T) when it transmits, else ``diffuse``
        (reflectance R, one-sided as every ground)."""
        if self.transmittance > 0:
            return {"type": "bilambertian", "reflectance": float(self.reflectance),
                    "transmittance": float(self.transmittance)}
        return {"type": "diffuse", "reflectance": {"type": "uniform",
                                                   "value": float(self.reflectance)}}

    def with_(self, *, reflectance: float | None = None,
              transmittance: float | None = None) -> "Optics":
        """A copy with other values (the user's own measurement), its source saying so."""
        return Optics(self.name, self.reflectance if reflectance is None else reflectance,
                      self.transmittance if transmittance is None else transmittance,
                      "given by the user")


OPTICS = {
    # PROSPECT (Jacquemoud & Baret 1990, Remote Sens. Environ. 34, 75-91; PROSPECT-5, Feret et
    # al. 2008, Remote Sens. Environ. 112, 3030-3043) gives a mature green leaf R ~0.11-0.13,
    # T ~0.12-0.13 at 532 nm (typical parameters: N ~1.5, chlorophyll ~40 ug/cm^2, as quoted
    # in issue 42); we take the middle of those ranges.
    "leaf": Optics("green broad leaf", 0.12, 0.125,
                   "PROSPECT green leaf (Jacquemoud & Baret 1990; Feret et al. 2008): R 0.11-"
                   "0.13, T 0.12-0.13 at 532 nm; the middle of the ranges"),
    # ESTIMATE: conifer needles are thicker than broad leaves and transmit much less in the
    # visible; Hovi et al. 2022 (Silva Fennica 56(2), 10683, Norway spruce needle albedo,
    # reflectance and transmittance spectra, compared with broadleaved foliage) and Lukes et
    # al. 2013 (Remote Sens. Lett. 4, 667-676, boreal leaves and needles) show the needles'
    # green albedo well below the broad leaves'. Values chosen in that sense, not read from
    # a table: R 0.09, T 0.05.
    "needle": Optics("conifer needle", 0.09, 0.05,
                     "ESTIMATE after Hovi et al. 2022 and Lukes et al. 2013 (needles darker "
                     "and less transmissive than broad leaves in the green)"),
    # ESTIMATE: dark stem bark (pine, spruce, aspen's grey) reflects ~0.1 in the green
    # (Juola, Hovi & Rautiainen 2020, Silva Fennica 54(4), 10331, multiangular bark spectra;
    # BOREAS TE-08 aspen bark spectra, Spencer & Rock 1999, ORNL DAAC 336); birch's white
    # bark is far brighter (~0.4) and should be given.
    "bark": Optics("stem bark", 0.12, 0.0,
                   "ESTIMATE after Juola et al. 2020 and BOREAS TE-08 (dark bark ~0.1 green)"),
    # Dry leaf litter and needle litter: issue 42 quotes measured leaf piles ~0.10 at 532 nm;
    # ESTIMATE beyond that single figure.
    "litter": Optics("forest floor litter", 0.10, 0.0,
                     "issue 42's measured leaf piles ~0.10 at 532 nm (ESTIMATE otherwise)"),
    # ESTIMATE: a moist mineral soil in the green, ~0.10-0.15 (dry bright sands reach 0.3);
    # the middle of the moist range.
    "soil": Optics("moist mineral soil", 0.12, 0.0,
                   "ESTIMATE: moist mineral soil 0.10-0.15 at 532 nm (dry sand up to 0.3)"),
}


def snow_optics(*, grain_radius_um: float = 100.0, density_kg_m3: float = 300.0) -> Optics:
    """Snow on the forest floor: its hemispherical reflectance from the project's own snow
    model (:func:`lidar_mitsuba.ground.snow.snow_from_grains`, ice absorption at 532 nm and
    the diffusion half-space's total reflectance), opaque. A snow floor traced as a volume
    (``snow=`` in ``simulate``) is better where its delay matters; this is its albedo."""
    from ..ground.snow import snow_from_grains
    vol = snow_from_grains(grain_radius_um=grain_radius_um, density_kg_m3=density_kg_m3)
    r = vol.diffusion().total_reflectance()
    return Optics(f"snow ({grain_radius_um:g} um grains)", float(r), 0.0,
                  "lidar_mitsuba.ground.snow: diffusion half-space of snow_from_grains")


def optics(name: str, **kwargs) -> Optics:
    """An element's optics by name: ``leaf``, ``needle``, ``bark``, ``litter``, ``soil`` or
    ``snow`` (keyword arguments go to :func:`snow_optics`)."""
    if name == "snow":
        return snow_optics(**kwargs)
    check("optics", name, name in OPTICS, f"must be one of {', '.join([*OPTICS, 'snow'])}")
    return OPTICS[name]
