"""What the plugins share with any pipeline built on them: the speed of light, the Gaussian
FWHM factor, the reference plate that sets the weight scale, the nominal ICESat-2 / ATLAS
geometry the integrators default to, and the Ward normalisations. Defined here, once;
``lidar_mitsuba.constants`` re-exports them. Imports nothing but the standard library.
"""
from __future__ import annotations

import math

C_M_PER_NS = 0.299792458
"""Speed of light [m/ns]."""

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
"""Full width at half maximum of a Gaussian in units of its standard deviation (2.3548)."""

REFERENCE_ALBEDO = 0.9
"""A flat, horizontal Lambertian plate of this albedo returns weight 1 at nadir: the scale of
the integrators' return weights (and of ``lidar_mitsuba``'s ``Instrument.signal_photons``)."""

# Nominal ICESat-2 / ATLAS geometry (Zhang & Kerekes' values): the integrators' defaults.
ALTITUDE_M = 496e3
"""Spacecraft altitude above the scene's z = 0 [m]."""
FOOTPRINT_DIAMETER_M = 10.0
"""1/e^2 diameter of the Gaussian footprint on the ground [m] (sigma = diameter / 4)."""
PULSE_FWHM_NS = 1.0
"""Full width at half maximum of the Gaussian laser pulse [ns]."""
FOV_DIAMETER_M = 41.3
"""Receiver field of view on the ground [m] (83.3 microradians at 496 km)."""

WARD_NORMALIZATIONS = ("ward1992", "duer", "balanced")
"""Normalisations of the Ward specular lobe (see ``ward.py``)."""
