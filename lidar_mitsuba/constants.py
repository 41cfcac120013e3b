"""The ground floor: physical constants, the instrument's nominal geometry and the error type
that names a bad parameter. Imports nothing of the package, so every module can use it. The
constants the Mitsuba plugins share with the pipeline (c, the FWHM factor, the reference
plate, the nominal geometry, the Ward normalisations) are defined once, on the plugins' side
(``lidar_mitsuba_plugins.constants``), and re-exported here.
"""
from __future__ import annotations

from lidar_mitsuba_plugins.constants import (  # noqa: F401 (defined once, with the plugins)
    ALTITUDE_M, C_M_PER_NS, FOOTPRINT_DIAMETER_M, FOV_DIAMETER_M, FWHM_PER_SIGMA,
    PULSE_FWHM_NS, REFERENCE_ALBEDO, WARD_NORMALIZATIONS)


class ParameterError(ValueError):
    """An out-of-range or inconsistent parameter.

    >>> import lidar_mitsuba as lm
    >>> try:
    ...     lm.Instrument(pde=2.0)
    ... except lm.ParameterError as e:
    ...     print(e.name)
    pde

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
