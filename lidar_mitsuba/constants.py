"""The ground floor: physical constants, the instrument's nominal geometry and the error type
that names a bad parameter. Imports nothing of the package, so every module (the Mitsuba
plugins included) can use it.
"""
from __future__ import annotations

import math

C_M_PER_NS = 0.299792458
"""Speed of light [m/ns]."""

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
"""Full width at half maximum of a Gaussian in units of its standard deviation (2.3548)."""

REFERENCE_ALBEDO = 0.9
"""A flat, horizontal Lambertian plate of this albedo returns weight 1 at nadir: the plate that
defines ``Instrument.signal_photons``."""

# Nominal ICESat-2 / ATLAS geometry (the paper's values); Instrument and the pathlength plugin
# both default to these.
ALTITUDE_M = 496e3
"""Spacecraft altitude above the scene's z = 0 [m]."""
FOOTPRINT_DIAMETER_M = 10.0
"""1/e^2 diameter of the Gaussian footprint on the ground [m] (sigma = diameter / 4)."""
PULSE_FWHM_NS = 1.0
"""Full width at half maximum of the Gaussian laser pulse [ns]."""
FOV_DIAMETER_M = 41.3
"""Receiver field of view on the ground [m] (83.3 microradians at 496 km)."""

WARD_NORMALIZATIONS = ("ward1992", "duer", "balanced")
"""Normalisations of the Ward specular lobe (see ``plugins/ward.py`` and :mod:`.brdf`)."""


class ParameterError(ValueError):
    """An out-of-range or inconsistent parameter.

    ``name`` is the parameter as the Python API spells it (a dataclass field or keyword, e.g.
    ``grid_m``); the CLI turns it into the option (``--grid-m``). ``message`` is the text
    without the name.
    """

    def __init__(self, name: str, message: str):
        super().__init__(f"{name}: {message}")
        self.name = name
        self.message = message


def check(name: str, value, ok: bool, expect: str) -> None:
    """Raise :class:`ParameterError` ``name: <expect> (got <value>)`` unless ``ok``."""
    if not ok:
        raise ParameterError(name, f"{expect} (got {value!r})")


class SimulationWarning(UserWarning):
    """A run that completed but whose answer deserves a second look (no photons, too few
    paths per shot, a mesh coarser than the footprint resolves, shots with no surface under
    them). ``simulate`` also lists them in ``result.config["warnings"]``."""
