"""Instrument description: an ICESat-2 / ATLAS-like photon-counting lidar.

Defaults are the paper's (Zhang & Kerekes): 532 nm, Gaussian pulse of 1 ns FWHM, Gaussian
footprint of 10 m 1/e^2 diameter, 496 km altitude, 10 kHz and 0.7 m along-track spacing,
a 16-anode PMT read as 16 channels (strong beam, 8.17 signal photons per shot) or as
4 channels of 4 summed anodes (weak beam, 2.04), PDE 0.5, fill factor 0.8, dead time 3 ns.

Field names match the CLI options (``dead_time_ns`` is ``--dead-time-ns``), and every
out-of-range value raises :class:`~lidar_mitsuba.constants.ParameterError` naming the field.

:meth:`Instrument.atlas` is ATLAS as flown (``--instrument atlas``): every parameter from the
mission's documents or its data (:data:`ATLAS`, with sources), the signal level from the lidar
equation and the background per shot from the sun and the air (:mod:`.radiometry`).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from dataclasses import dataclass, field

import numpy as np

from . import constants as K
from .constants import C_M_PER_NS, FWHM_PER_SIGMA, ParameterError, check as _check
from .radiometry import LinkBudget


@dataclass(frozen=True)
class BeamPreset:
    """Signal level and channel layout of one ATLAS beam type."""
    signal_photons: float
    channels: int


DEAD_TIME_PRESETS_NS: dict[str, float] = {"paper": 3.0, "atlas": 3.2}
"""Named dead times [ns]: the paper's 3 ns and ATLAS's ~3.2 ns."""

PULSE_SHAPES = ("gaussian", "atlas")
"""``pulse_shape``: the Gaussian pulse alone, or with ATLAS's receiver response
(:data:`lidar_mitsuba.detector.impulse.RESPONSES`)."""

BEAMS: dict[str, BeamPreset] = {
    "strong": BeamPreset(signal_photons=8.17, channels=16),
    "weak": BeamPreset(signal_photons=2.04, channels=4),
}


@dataclass(frozen=True)
class Instrument:
    """Transmitter, geometry and detector of the lidar.

    Attributes:
        beam: ``"strong"`` or ``"weak"``; sets the defaults of ``signal_photons`` and ``channels``.
        signal_photons: mean photons per shot reaching the detector from a flat, horizontal
            Lambertian surface of albedo 0.9 at nadir [photons/shot]; ``None`` = beam default.
        channels: detector outputs the ``anodes`` are summed into; ``None`` = beam default
            (16 strong, 4 weak). Must divide ``anodes``.
        anodes: anode segments of the PMT (16 for ATLAS's 4x4).
        wavelength_nm: laser wavelength [nm] (mono rendering: informational).
        pulse_fwhm_ns: full width at half maximum of the Gaussian pulse [ns].
        pulse_shape: the receiver's response added to the Gaussian pulse, ``"gaussian"``
            (none, the paper's) or ``"atlas"`` (ATLAS's as flown, with a tail, echoes and
            afterpulses). :mod:`lidar_mitsuba.detector.impulse` has the details.
        footprint_diameter_m: 1/e^2 diameter of the Gaussian footprint on the ground [m].
        altitude_m: spacecraft height above the scene's z = 0 [m].
        prf_hz: pulse repetition frequency [Hz].
        shot_spacing_m: along-track distance between footprints [m].
        fov_diameter_m: receiver field of view on the ground [m].
        pde: photon detection efficiency, probability in [0, 1].
        fill_factor: probability in [0, 1] that a photon falls on an active anode area.
        dead_time_ns: dead time of each channel [ns]. Presets: ``DEAD_TIME_PRESETS_NS``.
        paralyzable: extending dead time (every arrival, detected or not, restarts it) instead
            of the paper's non-paralyzable one (only detections start it).
        ideal_detector: no dead time (every photon that passes fill factor and PDE counts).
        background_mhz: solar background photon rate reaching the whole detector [MHz], shared
            evenly by the anodes and uniform in time; thinned by fill factor and PDE like signal.
        dark_count_hz: dark count rate of each channel [Hz], uniform in time; these are
            detector counts, so only dead time acts on them.
        range_gate_m: height window recorded around each shot's reference surface [m]
            (``z_ref +- range_gate_m / 2``); photons outside it, signal or noise, are not seen.
        link_budget: the transmitter, receiver optics and sky
            (:class:`~lidar_mitsuba.radiometry.LinkBudget`) from which ``signal_photons``
            follows (the lidar equation at nadir, sea level, ``altitude_m`` range) and, in a
            run, each shot's signal (its range and air) and background (the sun where it is,
            the air's backscatter); ``None`` (the paper's instrument): the signal is
            ``signal_photons`` and the background ``background_mhz``, as given.
    """
    beam: str = field(default="strong", metadata={"choices": ("strong", "weak")})
    signal_photons: float | None = field(default=None,
                                         metadata={"default_help": "8.17 strong, 2.04 weak"})
    channels: int | None = field(default=None, metadata={"default_help": "16 strong, 4 weak"})
    anodes: int = 16
    wavelength_nm: float = 532.0
    pulse_fwhm_ns: float = K.PULSE_FWHM_NS
    pulse_shape: str = field(default="gaussian", metadata={"choices": PULSE_SHAPES})
    footprint_diameter_m: float = K.FOOTPRINT_DIAMETER_M
    altitude_m: float = K.ALTITUDE_M
    prf_hz: float = 10e3
    shot_spacing_m: float = 0.7
    fov_diameter_m: float = K.FOV_DIAMETER_M
    pde: float = 0.5
    fill_factor: float = 0.8
    dead_time_ns: float = field(default=3.0, metadata={"presets": DEAD_TIME_PRESETS_NS})
    paralyzable: bool = False
    ideal_detector: bool = False
    background_mhz: float = 0.0
    dark_count_hz: float = 0.0
    range_gate_m: float = 30.0
    link_budget: LinkBudget | None = None

    def __post_init__(self):
        if isinstance(self.link_budget, dict):             # from a run's config (JSON)
            object.__setattr__(self, "link_budget", LinkBudget(**self.link_budget))
        _check_types(self)
        _check("beam", self.beam, self.beam in BEAMS, f"must be one of {', '.join(BEAMS)}")
        preset = BEAMS[self.beam]
        if self.link_budget is not None and self.signal_photons is None:
            object.__setattr__(self, "signal_photons", float(self.link_budget.signal_photons(
                wavelength_nm=self.wavelength_nm, range_m=self.altitude_m)))
        if self.signal_photons is None:
            object.__setattr__(self, "signal_photons", preset.signal_photons)
        if self.channels is None:
            object.__setattr__(self, "channels", preset.channels)
        f = math.isfinite
        _check("signal_photons", self.signal_photons,
               f(self.signal_photons) and 0 <= self.signal_photons <= 1e5, "must be in [0, 1e5]")
        _check("anodes", self.anodes, isinstance(self.anodes, int) and 1 <= self.anodes <= 1024,
               "must be an integer in [1, 1024]")
        divisors = [d for d in range(1, self.anodes + 1) if self.anodes % d == 0]
        _check("channels", self.channels,
               isinstance(self.channels, int) and self.channels in divisors,
               f"must divide the {self.anodes} anodes: one of {', '.join(map(str, divisors))}")
        _check("wavelength_nm", self.wavelength_nm,
               f(self.wavelength_nm) and 100 <= self.wavelength_nm <= 20000, "must be in [100, 20000]")
        _check("pulse_fwhm_ns", self.pulse_fwhm_ns,
               f(self.pulse_fwhm_ns) and 0 <= self.pulse_fwhm_ns <= 1e4, "must be in [0, 1e4]")
        _check("pulse_shape", self.pulse_shape, self.pulse_shape in PULSE_SHAPES,
               f"must be one of {', '.join(PULSE_SHAPES)}")
        _check("footprint_diameter_m", self.footprint_diameter_m,
               f(self.footprint_diameter_m) and 0 <= self.footprint_diameter_m <= 1e4,
               "must be in [0, 1e4]")
        _check("altitude_m", self.altitude_m,
               f(self.altitude_m) and 10 <= self.altitude_m <= 1e8, "must be in [10, 1e8]")
        _check("prf_hz", self.prf_hz, f(self.prf_hz) and 0 < self.prf_hz <= 1e9, "must be in (0, 1e9]")
        _check("shot_spacing_m", self.shot_spacing_m,
               f(self.shot_spacing_m) and 0 <= self.shot_spacing_m <= 1e5, "must be in [0, 1e5]")
        _check("fov_diameter_m", self.fov_diameter_m,
               f(self.fov_diameter_m) and 0 < self.fov_diameter_m <= 1e5, "must be in (0, 1e5]")
        for name in ("pde", "fill_factor"):
            value = getattr(self, name)
            _check(name, value, f(value) and 0 <= value <= 1, "must be in [0, 1]")
        _check("dead_time_ns", self.dead_time_ns,
               f(self.dead_time_ns) and 0 <= self.dead_time_ns <= 1e6, "must be in [0, 1e6]")
        _check("background_mhz", self.background_mhz,
               f(self.background_mhz) and 0 <= self.background_mhz <= 1e4, "must be in [0, 1e4]")
        _check("dark_count_hz", self.dark_count_hz,
               f(self.dark_count_hz) and 0 <= self.dark_count_hz <= 1e9, "must be in [0, 1e9]")
        _check("range_gate_m", self.range_gate_m,
               f(self.range_gate_m) and 0 < self.range_gate_m <= 1e5, "must be in (0, 1e5]")

    # Derived quantities ------------------------------------------------------------------
    @property
    def pulse_sigma_ns(self) -> float:
        """Standard deviation of the Gaussian pulse [ns]."""
        return self.pulse_fwhm_ns / FWHM_PER_SIGMA

    @property
    def footprint_sigma_m(self) -> float:
        """Standard deviation of the Gaussian footprint [m] (a quarter of the 1/e^2 diameter)."""
        return self.footprint_diameter_m / 4.0

    @property
    def anodes_per_channel(self) -> int:
        return self.anodes // self.channels

    @property
    def ranging_sigma_m(self) -> float:
        """Elevation spread of an ideal detector over a flat plate, c * sigma_t / 2 [m]."""
        return C_M_PER_NS * self.pulse_sigma_ns / 2.0

    @property
    def range_gate_ns(self) -> float:
        """Duration of the range gate [ns] (two-way time of ``range_gate_m``)."""
        return 2.0 * self.range_gate_m / C_M_PER_NS

    @property
    def noise_per_shot(self) -> tuple[float, float]:
        """Mean (background photons reaching the detector, dark counts per channel) per shot
        inside the range gate."""
        gate_s = self.range_gate_ns * 1e-9
        return self.background_mhz * 1e6 * gate_s, self.dark_count_hz * gate_s

    @property
    def effective_dead_time_ns(self) -> float:
        return 0.0 if self.ideal_detector else self.dead_time_ns

    def replace(self, **changes) -> "Instrument":
        """A copy with some fields changed (validated again; with a link budget,
        ``signal_photons`` follows it again unless given)."""
        if self.link_budget is not None and "signal_photons" not in changes:
            changes["signal_photons"] = None
        return dataclasses.replace(self, **changes)

    @classmethod
    def atlas(cls, beam: str = "strong", **changes) -> "Instrument":
        """ATLAS as flown (:data:`ATLAS`, each value with its source): the beam's pulse energy,
        pulse, footprint, field of view, detector and dark counts, a link budget for its
        signal and background. ``changes``: fields of the instrument, of its
        :class:`~lidar_mitsuba.radiometry.LinkBudget` (``pulse_energy_uj``, ...) or of the
        :class:`~lidar_mitsuba.radiometry.Atmosphere` (``aerosol_optical_depth``, ...) to
        set otherwise.

        >>> import lidar_mitsuba as lm
        >>> lm.Instrument.atlas("weak").channels
        4"""
        from .radiometry import Atmosphere
        _check("beam", beam, beam in BEAMS, f"must be one of {', '.join(BEAMS)}")
        budget_fields = {f.name for f in dataclasses.fields(LinkBudget)} - {"atmosphere"}
        air_fields = {f.name for f in dataclasses.fields(Atmosphere)}
        budget = {k: changes.pop(k) for k in list(changes) if k in budget_fields}
        air = {k: changes.pop(k) for k in list(changes) if k in air_fields}
        if "signal_photons" in changes or "background_mhz" in changes:
            name = "signal_photons" if "signal_photons" in changes else "background_mhz"
            raise ParameterError(name, "follows from the link budget with the ATLAS instrument: "
                                 "set its pulse energy, receiver transmission, ... instead")
        budget.setdefault("pulse_energy_uj", ATLAS_PULSE_ENERGY_UJ[beam])
        link = LinkBudget(atmosphere=Atmosphere(**air), **budget)
        fields = {**ATLAS, **changes}
        if "dark_count_hz" not in changes:        # every anode's dark counts, summed per channel
            from .night import dark_count_per_channel_hz
            fields["dark_count_hz"] = dark_count_per_channel_hz(
                anodes=fields["anodes"], channels=fields.get("channels") or BEAMS[beam].channels)
        return cls(beam=beam, link_budget=link, **fields)

    def integrator_dict(self, *, max_depth: int = 1, max_lanes: int = 2 ** 23) -> dict:
        """Mitsuba dict of the ``pathlength`` integrator for this instrument."""
        return {"type": "pathlength", "max_depth": int(max_depth),
                "altitude_m": float(self.altitude_m),
                "footprint_sigma_m": float(self.footprint_sigma_m),
                "pulse_sigma_ns": float(self.pulse_sigma_ns),
                "fov_radius_m": float(self.fov_diameter_m / 2.0),
                "max_lanes": int(max_lanes)}

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


INSTRUMENT_PRESETS = ("paper", "atlas")
"""``--instrument``: Zhang & Kerekes' instrument (signal and background given) or ATLAS as
flown (:meth:`Instrument.atlas`)."""

ATLAS_PULSE_ENERGY_UJ: dict[str, float] = {"weak": 27.65, "strong": 4 * 27.65}
"""Transmitted energy per pulse of one beam [uJ]. Weak: the laser energy monitor's per-beam
reading in a real ATL03 granule (``geolocation/tx_pulse_energy``, gt1l, 14 Oct 2018: 27.30 to
27.65 uJ; ``lidar_mitsuba/data/``). Strong: four times the weak beam, ATLAS's design ratio (the
strong beam "approximately four times brighter": read-ICESat-2's documentation; ATL07's
weak-beam thresholds are the strong ones / 4); ESTIMATE for the flown strong energy."""

ATLAS_WEAK_ENERGY_HISTORY: tuple[tuple[str, float, str], ...] = (
    ("2018-10-14", 27.5, "ATL03 geolocation/tx_pulse_energy, gt1l (weak), granule "
     "ATL03_20181014002445_02350104_006_02: 27.30-27.65 uJ (lidar_mitsuba/data)"),
    ("2022-04-01", 22.8, "ATL03 geolocation/tx_pulse_energy, gt1r (weak), granule "
     "ATL03_20220401221822_01501506 (ICESat2VegR inst/extdata/atl03_clip.h5)"),
    ("2023-09-15", 27.5, "Martino et al. 2023, Proc. SPIE 12512, 125120A: the laser energy "
     "setting was raised in September 2023, for the first time, to keep ranging performance "
     "at its early-mission level (ESTIMATE: back to the 2018 reading, mid-month)"),
)
"""ATLAS's weak-beam pulse energy over the mission [uJ]: dated readings of the laser energy
monitor (ATL03 ``tx_pulse_energy``) and the one published change of setting, with sources.
:func:`atlas_pulse_energy_uj` interpolates between them (ESTIMATE: linear in time; the energy
fell between the readings as the laser aged, Martino et al. 2023) and holds the ends."""


def atlas_pulse_energy_uj(beam: str, delta_time_s: float) -> tuple[float, str]:
    """The pulse energy [uJ] of an ATLAS ``beam`` (``strong``: four times the weak,
    :data:`ATLAS_PULSE_ENERGY_UJ`) at ``delta_time_s`` [s since 2018-01-01 UTC], from
    :data:`ATLAS_WEAK_ENERGY_HISTORY`, and a note of where it comes from (``ESTIMATE`` where
    interpolated or held beyond the readings). For a file without ``tx_pulse_energy``."""
    _check("beam", beam, beam in BEAMS, f"must be one of {', '.join(BEAMS)}")
    epoch = np.datetime64("2018-01-01T00:00:00")
    (t0, e0), (t1, e1), (t_step, e_step) = (
        ((np.datetime64(d) - epoch) / np.timedelta64(1, "s"), v)
        for d, v, _ in ATLAS_WEAK_ENERGY_HISTORY)
    if delta_time_s >= t_step:               # after the setting was raised
        weak = e_step
    else:                                    # the decline of the readings, held before them
        weak = e0 + (e1 - e0) / (t1 - t0) * (max(float(delta_time_s), t0) - t0)
    scale = ATLAS_PULSE_ENERGY_UJ[beam] / ATLAS_PULSE_ENERGY_UJ["weak"]
    return weak * scale, ("ESTIMATE: ATLAS's pulse-energy history (instrument."
                          "ATLAS_WEAK_ENERGY_HISTORY), interpolated to the file's time")


ATLAS: dict = {
    # pulse: Brunt, Neumann & Larsen 2019 (The Cryosphere 13, 579): "<2 ns" pulses; ATL03's
    # start-pulse detector measures 1.50 ns between its lower threshold crossings (0.40 ns at
    # the upper): a 1.5 ns FWHM Gaussian (ESTIMATE: the thresholds' levels are not given)
    "pulse_fwhm_ns": 1.5,
    # the receiver's response as flown: a trailing tail, echoes at ~2.3 and ~4.2 m and
    # afterpulses 10-45 m below bright returns (Lu et al. 2021, Earth Space Sci. 8,
    # e2021EA001729; strengths ESTIMATE: lidar_mitsuba.detector.impulse.ATLAS_RESPONSE)
    "pulse_shape": "atlas",
    # footprint: 10.9 +- 1.2 m measured with corner-cube retroreflectors (Magruder et al.
    # 2021, Earth and Space Science, doi:10.1029/2020EA001414), taken as the 1/e^2 diameter
    "footprint_diameter_m": 10.9,
    # receiver field of view on the ground: 45 m (NASA ICESat-2 science specifications page;
    # the pre-launch 83.3 urad of Zhang & Kerekes is 41.3 m at 496 km)
    "fov_diameter_m": 45.0,
    # 16 anodes; strong beam 16 channels, weak beam 4 (groups of 4 anodes; Zhang & Kerekes;
    # ATL03's ph_id_channel: 20 channels per PCE, the real weak beam uses 4)
    "anodes": 16,
    # photon detection efficiency of the PMT at 532 nm: ESTIMATE 0.2 (no flown value found);
    # fill factor 0.8 as in Zhang & Kerekes. With receiver_transmission 0.5 the receiver keeps
    # 8 % of the light the telescope collects
    "pde": 0.2,
    "fill_factor": 0.8,
    # dead time: ATLAS's ~3.2 ns (the "atlas" preset; Zhang & Kerekes: "typically 3 ns")
    "dead_time_ns": DEAD_TIME_PRESETS_NS["atlas"],
    # dark counts: every anode's own (night.DARK_COUNT_PER_ANODE_HZ, with its source), summed
    # over the anodes of a channel: both beams' detectors have 16 anodes, so both count the
    # same dark rate (the strong beam in 16 channels, the weak one in 4); Instrument.atlas sets
    # the per-channel rate from the beam's channels
    "dark_count_hz": 100.0,
}
"""ATLAS as flown, the fields :meth:`Instrument.atlas` sets (besides the beam and its link
budget), with their sources; 532 nm, 10 kHz, 0.7 m and 496 km are the paper's and ATLAS's
alike."""


def _check_types(obj) -> None:
    """ParameterError naming the first field whose value is not of its annotated type: a bool
    for bool fields (not the string "no"), an int for int fields, a real number for float
    fields, a string for str fields (``None`` where the annotation allows it)."""
    for name, allowed in _allowed_types(type(obj)):
        value = getattr(obj, name)
        if value is None and type(None) in allowed:
            continue
        if bool in allowed:
            ok = isinstance(value, (bool, np.bool_))
        elif int in allowed:
            ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
        elif float in allowed:
            ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
        else:
            ok = isinstance(value, allowed)
        kind = next(t for t in allowed if t is not type(None))
        _check(name, value, ok, "must be " + _TYPE_WORDS.get(kind, kind.__name__))


@functools.lru_cache(maxsize=None)
def _allowed_types(cls) -> tuple:
    """``((field name, its allowed types), ...)`` of a dataclass, from its annotations (read
    once a class: ``typing.get_type_hints`` took ~2 ms an instrument, 13 a granule)."""
    hints = typing.get_type_hints(cls)
    return tuple((f.name, typing.get_args(hints[f.name])
                  if typing.get_origin(hints[f.name]) in (typing.Union, types.UnionType)
                  else (hints[f.name],)) for f in dataclasses.fields(cls))


_TYPE_WORDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
