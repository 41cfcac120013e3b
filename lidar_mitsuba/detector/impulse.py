"""ATLAS's impulse response as flown: what the receiver adds to the Gaussian transmit pulse.
Pure numpy.

The ``pathlength`` integrator draws each photon's emission time from the Gaussian transmit pulse
(``pulse_fwhm_ns``) and returns path lengths; nothing here touches it. What a real ATLAS
records over a flat surface is not that Gaussian. Lu et al. (2021, Earth and Space Science 8,
e2021EA001729, "Enabling value added scientific applications of ICESat-2 data with effective
removal of afterpulses") find, below bright surface returns:

1. echoes ~0.45 m and ~0.9 m below the surface: the ~3 ns dead-time circuit (a channel
   re-arms on the same return's tail). Our dead-time stage already makes them
   (:mod:`.deadtime`: a channel that fired is re-armed ``dead_time_ns`` later, 3.2 ns = 0.48 m
   for ATLAS; ``tests/test_impulse.py`` checks it); nothing is added for them here;
2. echoes ~2.3 m and ~4.2 m below: optical reflections inside the receiver; each is a delayed
   copy of the return (:attr:`ImpulseResponse.echo_delays_ns`);
3. afterpulses ~10 to ~45 m below: the photomultipliers' own afterpulsing, a delayed count
   per detection (:func:`add_afterpulses`); these are detector counts, so dead time acts on
   them.

Besides, the main lobe has a trailing shoulder: ATLAS's system impulse response over flat salt
flats and deserts is described by an exponentially modified Gaussian (ex-Gaussian; Zhao, Zhang
& Wu 2025, Laser & Optoelectronics Progress 62(1), 0101001), a Gaussian (the transmit pulse)
convolved with an exponential (the receiver: photomultiplier transit spread and timing
electronics). Here a fraction :attr:`ImpulseResponse.tail_fraction` of the photons is delayed by
an exponential of mean :attr:`ImpulseResponse.tail_mean_ns`, so the response is

    h(t) = (1 - a_tail - sum_k a_k) g(t) + a_tail (g * Exp(tau))(t) + sum_k a_k g(t - d_k)

with ``g`` the Gaussian transmit pulse. The delays are drawn per photon before the dead-time
stage (:meth:`ImpulseResponse.sample_delay_ns`), a separate step after the tracer, less the
range calibration (:meth:`ImpulseResponse.calibration_ns`: the waveform's mean delay); with
:data:`GAUSSIAN` (the paper's instrument) nothing is drawn and the detector's output is the same
to the bit.

ESTIMATE: the shape's *positions* are published (above); its *strengths* (tail fraction and
mean, echo and afterpulse probabilities) are not given in any source we could read here (Lu et
al.'s figures show them, the NSIDC "ATL02 Linear Impulse Response" data set, doi
10.5067/EVKXYHW95FPJ, measures them over Salar de Uyuni, neither was readable offline). The
values of :data:`ATLAS_RESPONSE` are estimates, each with its reasoning, chosen before any
comparison with the real sea-ice subset and never adjusted to it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..constants import C_M_PER_NS, ParameterError


def range_to_delay_ns(range_m: float) -> float:
    """Round-trip delay [ns] of an apparent ``range_m`` [m] below the surface (2 r / c)."""
    return 2.0 * float(range_m) / C_M_PER_NS


@dataclass(frozen=True)
class ImpulseResponse:
    """The receiver's part of the impulse response, beyond the Gaussian transmit pulse.

    Attributes:
        tail_fraction: share of the photons delayed by an exponential (the ex-Gaussian
            shoulder), in [0, 1].
        tail_mean_ns: mean of that exponential delay [ns].
        echo_delays_ns: delays of the receiver's internal reflections [ns].
        echo_fractions: share of the photons in each echo (same length as the delays).
        afterpulse_probability: probability that a detection (signal, background or dark
            count) is followed by an afterpulse on the same channel.
        afterpulse_window_ns: ``(first, last)`` delay of an afterpulse after its detection
            [ns], uniform in between.
    """
    tail_fraction: float = 0.0
    tail_mean_ns: float = 0.0
    echo_delays_ns: tuple = ()
    echo_fractions: tuple = ()
    afterpulse_probability: float = 0.0
    afterpulse_window_ns: tuple = (0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "echo_delays_ns", tuple(float(d) for d in self.echo_delays_ns))
        object.__setattr__(self, "echo_fractions", tuple(float(a) for a in self.echo_fractions))
        if len(self.echo_delays_ns) != len(self.echo_fractions):
            raise ParameterError("echo_fractions", "needs one fraction per echo delay")
        shares = (self.tail_fraction, *self.echo_fractions)
        if any(not (0.0 <= a <= 1.0) for a in shares) or sum(shares) > 1.0:
            raise ParameterError("tail_fraction", "shares must be in [0, 1] and sum to <= 1")
        if self.tail_mean_ns < 0 or any(d < 0 for d in self.echo_delays_ns):
            raise ParameterError("tail_mean_ns", "delays must be >= 0")
        lo, hi = self.afterpulse_window_ns
        if not (0.0 <= self.afterpulse_probability <= 1.0) or not (0.0 <= lo <= hi):
            raise ParameterError("afterpulse_probability",
                                 "must be in [0, 1] with a window 0 <= first <= last")

    # ---------------------------------------------------------------- the mixture
    @property
    def direct_fraction(self) -> float:
        """Share of the photons with no added delay."""
        return 1.0 - self.tail_fraction - sum(self.echo_fractions)

    @property
    def adds_delay(self) -> bool:
        """Whether any photon gets a delay (False: the Gaussian pulse alone)."""
        return self.direct_fraction < 1.0

    def delay_moments(self) -> tuple[float, float]:
        """Mean [ns] and variance [ns^2] of the added delay (closed form)."""
        a, tau = self.tail_fraction, self.tail_mean_ns
        d = np.asarray(self.echo_delays_ns)
        w = np.asarray(self.echo_fractions)
        mean = a * tau + float(np.sum(w * d))
        second = a * 2.0 * tau ** 2 + float(np.sum(w * d ** 2))
        return mean, second - mean ** 2

    def delay_cdf(self, t_ns) -> np.ndarray:
        """P(added delay <= t_ns), closed form."""
        t = np.asarray(t_ns, np.float64)
        out = np.where(t >= 0, self.direct_fraction, 0.0)
        if self.tail_fraction > 0:
            tail = (1.0 - np.exp(-np.maximum(t, 0) / self.tail_mean_ns)
                    if self.tail_mean_ns > 0 else (t >= 0).astype(np.float64))
            out = out + self.tail_fraction * np.where(t >= 0, tail, 0.0)
        for d, a in zip(self.echo_delays_ns, self.echo_fractions):
            out = out + a * (t >= d)
        return out

    def pdf(self, t_ns, *, sigma_ns: float) -> np.ndarray:
        """The whole impulse response [1/ns] at ``t_ns`` (from the transmit pulse's peak): the
        Gaussian of ``sigma_ns`` convolved with the added delay (ex-Gaussian for the tail)."""
        t = np.asarray(t_ns, np.float64)
        g = lambda x: np.exp(-0.5 * (x / sigma_ns) ** 2) / (sigma_ns * math.sqrt(2 * math.pi))
        out = self.direct_fraction * g(t)
        for d, a in zip(self.echo_delays_ns, self.echo_fractions):
            out = out + a * g(t - d)
        if self.tail_fraction > 0:
            out = out + self.tail_fraction * _ex_gaussian(t, sigma_ns, self.tail_mean_ns)
        return out

    def cdf(self, t_ns, *, sigma_ns: float) -> np.ndarray:
        """P(time <= t_ns) of the whole response (Gaussian of ``sigma_ns`` plus the delay)."""
        from scipy.special import ndtr
        t = np.asarray(t_ns, np.float64)
        out = self.direct_fraction * ndtr(t / sigma_ns)
        for d, a in zip(self.echo_delays_ns, self.echo_fractions):
            out = out + a * ndtr((t - d) / sigma_ns)
        if self.tail_fraction > 0:
            out = out + self.tail_fraction * _ex_gaussian_cdf(t, sigma_ns, self.tail_mean_ns)
        return out

    def calibration_ns(self) -> float:
        """The range calibration [ns]: the mean delay of the pulse's waveform (the main lobe
        and its tail; the receiver echoes 15-28 ns later and the afterpulses are not part of
        it), ``a_tail * tau``, subtracted from every delay drawn. ATL03 corrects its ranges by
        a calibrated constant (``geolocation/range_bias_corr``) and ATL06 refers its heights
        to the full transmit waveform's mean (its ``tx_mean_corr`` takes a truncated window's
        mean there, from the transmitter echo path); that the calibrated reference is this
        mean is our ESTIMATE (recalled from the ATL06 ATBD, not re-read here). The Gaussian
        pulse alone has mean 0: the paper's instrument is unchanged."""
        return self.tail_fraction * self.tail_mean_ns

    def sample_delay_ns(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n,) delays [ns] drawn from the mixture: one uniform ``u`` per photon picks the
        component; inside the tail's interval ``[e, e + a)`` the rescaled ``(u - e) / a`` is
        itself uniform and gives the exponential by inversion. Draws nothing (and returns
        zeros) when there is no delay."""
        if not self.adds_delay or n == 0:
            return np.zeros(n)
        u = rng.random(n)
        out = np.zeros(n)
        edge = self.direct_fraction
        tail = np.flatnonzero((u >= edge) & (u < edge + self.tail_fraction))
        v = (edge + self.tail_fraction - u[tail]) / self.tail_fraction     # in (0, 1]
        out[tail] = -self.tail_mean_ns * np.log(v)
        edge += self.tail_fraction
        for d, a in zip(self.echo_delays_ns, self.echo_fractions):
            out[(u >= edge) & (u < edge + a)] = d
            edge += a
        return out


def _ex_gaussian_cdf(t, sigma, tau):
    """CDF of N(0, sigma^2) + Exp(mean tau): Phi(t / sigma) - tau pdf(t) (the standard
    identity F = Phi - tau f for the exponentially modified Gaussian)."""
    from scipy.special import ndtr
    return ndtr(np.asarray(t, np.float64) / sigma) - tau * _ex_gaussian(t, sigma, tau)


def _ex_gaussian(t, sigma, tau):
    """Density of N(0, sigma^2) + Exp(mean tau) at t, the exponentially modified Gaussian
    ``exp(sigma^2 / 2 tau^2 - t / tau) erfc(x) / 2 tau`` with ``x = (sigma / tau - t / sigma)
    / sqrt 2``; for ``x >= 0`` as ``exp(-t^2 / 2 sigma^2) erfcx(x) / 2 tau`` (no overflow)."""
    from scipy.special import erfc, erfcx
    t = np.asarray(t, np.float64)
    if tau <= 0:
        return np.exp(-0.5 * (t / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
    x = (sigma / tau - t / sigma) / math.sqrt(2)
    pos = x >= 0
    scaled = np.exp(-0.5 * (t / sigma) ** 2) * erfcx(np.where(pos, x, 0.0))
    direct = np.exp(np.minimum(0.5 * (sigma / tau) ** 2 - t / tau, 0.0)) * erfc(x)
    return np.where(pos, scaled, direct) / (2 * tau)


GAUSSIAN = ImpulseResponse()
"""The paper's instrument: the Gaussian transmit pulse and nothing else."""

ATLAS_RESPONSE = ImpulseResponse(
    # ESTIMATE: the ex-Gaussian shoulder. Its form is Zhao et al. 2025's (the system impulse
    # response over salt flat and desert fitted by an ex-Gaussian, Gaussian width 0.095 m:
    # the 1.5 ns transmit pulse's 9.6 cm); its strength is ours: a tenth of the photons
    # delayed by 1 ns (15 cm) on average, the order of a multi-anode photomultiplier's
    # late-pulse share and transit-time tail (Hamamatsu's photomultiplier handbook: late
    # pulses from photoelectrons scattered off the first dynode, ~1-10 % of pulses, delayed by
    # up to a few ns). Not read off any ATLAS measurement.
    tail_fraction=0.10,
    tail_mean_ns=1.0,
    # positions: Lu et al. 2021 (~2.3 m and ~4.2 m below the surface: receiver reflections).
    # ESTIMATE strengths 0.5 % and 0.2 % of the photons: Lu et al. show them as faint
    # echoes seen only below bright (saturating) returns, i.e. orders of magnitude below the
    # surface peak; a reflection off an uncoated-side optic (~0.5-4 % Fresnel) coupled back
    # into the field of view with a fraction of that
    echo_delays_ns=(range_to_delay_ns(2.3), range_to_delay_ns(4.2)),
    echo_fractions=(0.005, 0.002),
    # window: Lu et al. 2021 (afterpulses ~10 to ~45 m below the surface). ESTIMATE the
    # probability 1 % per detection: Hamamatsu's handbook gives afterpulse ratios of
    # ~0.1-several % for photon-counting tubes; uniform over the window (no published shape)
    afterpulse_probability=0.01,
    afterpulse_window_ns=(range_to_delay_ns(10.0), range_to_delay_ns(45.0)),
)
"""ATLAS as flown (``pulse_shape="atlas"``): positions published, strengths estimated."""

RESPONSES = {"gaussian": GAUSSIAN, "atlas": ATLAS_RESPONSE}
"""``Instrument.pulse_shape`` -> the receiver's response."""


def response_of(instrument) -> ImpulseResponse:
    """The :class:`ImpulseResponse` of an instrument (its ``pulse_shape``)."""
    return RESPONSES[getattr(instrument, "pulse_shape", "gaussian")]


# -------------------------------------------------------------------- afterpulses
def add_afterpulses(shot: np.ndarray, time_ns: np.ndarray, *, response: ImpulseResponse,
                    rng: np.random.Generator, gate_end_ns: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Afterpulses of recorded detections: each detection is followed, with probability
    ``afterpulse_probability``, by a count on its own channel (and anode) a uniform delay in
    ``afterpulse_window_ns`` later, kept if before its shot's gate end (``gate_end_ns``,
    (n_shots,) [ns]; ``None``: no gate). First order: afterpulses have no afterpulses of their
    own (a 1e-4 effect at 1 %). Draws nothing when the probability is 0.

    Args:
        shot: (n_events,) shot of each recorded detection; time_ns: (n_events,) its time [ns].

    Returns:
        ``(parent, delay_ns)``: (n_after,) int64 index of each afterpulse's detection and its
        delay [ns]; the afterpulse is at ``time_ns[parent] + delay_ns``.
    """
    p = response.afterpulse_probability
    n = int(np.size(time_ns))
    if p <= 0 or n == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    # a Bernoulli process over the detections: geometric gaps between the parents
    parent, at = [], -1
    while at < n:
        m = int(n * p + 10 * math.sqrt(n * p) + 16)
        pos = at + np.cumsum(rng.geometric(p, m))
        parent.append(pos[pos < n])
        at = int(pos[-1])
    parent = np.concatenate(parent)
    lo, hi = response.afterpulse_window_ns
    delay = rng.uniform(lo, hi, parent.size)
    if gate_end_ns is not None:
        keep = np.asarray(time_ns)[parent] + delay < np.asarray(gate_end_ns)[np.asarray(shot)[parent]]
        parent, delay = parent[keep], delay[keep]
    return parent.astype(np.int64), delay
