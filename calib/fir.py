"""Zero-phase FIR low-pass used to split a measured channel into "motion" and "noise" (docs/calibration.md, 'Noise and
bias (eq 50)'; docs/calibration.md, 'FIR filtering').

The filter is a Hamming-window FIR (``scipy.signal.firwin``, odd length, linear phase, unity DC gain) applied
forward and backward with ``scipy.signal.filtfilt`` (zero phase, magnitude |H|^2). The first and last ``numtaps``
samples of the filtered signal depend on the padding and are discarded by every statistic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from ingest.errors import InputError

#: Window of every FIR we design (stored in CALIB.json for traceability).
FIR_WINDOW = "hamming"
#: Hamming-window transition width is about this many times fs / numtaps (docs/calibration.md, 'FIR filtering').
HAMMING_WIDTH_FACTOR = 3.3
#: Default cutoffs [Hz]: above the rigid-body motion, below vibration (docs/calibration.md, 'FIR filtering').
DEFAULT_CUTOFF_FIXED_WING_HZ = 5.0
DEFAULT_CUTOFF_MULTICOPTER_HZ = 15.0
#: A default cutoff never exceeds this fraction of the sample rate, so slow streams (GPS, baro) keep some noise band.
MAX_DEFAULT_CUTOFF_FRACTION = 0.2
#: Smallest filter we shrink a default design to on short segments.
MIN_NUMTAPS = 11


@dataclass(frozen=True)
class FirSpec:
    """A designed low-pass FIR.

    Attributes
    ----------
    fs_hz : float
        Sample rate the filter is designed for [Hz].
    cutoff_hz : float
        -6 dB point of one pass (-12 dB after filtfilt) [Hz].
    numtaps : int
        Filter length (odd).
    rho_h : float
        Fraction of white-noise variance that survives in the residual x - filtfilt(x) (docs/calibration.md, 'Noise and
        bias (eq 50)'):
        ``sum((delta - h * reverse(h))^2)``; divide var(residual) by it to estimate the white-noise variance.
    taps : numpy.ndarray
        Filter coefficients, shape (numtaps,); derived from the three design values, not compared.
    """

    fs_hz: float
    cutoff_hz: float
    numtaps: int
    rho_h: float
    taps: np.ndarray = field(compare=False, repr=False)

    @property
    def transition_width_hz(self) -> float:
        """Approximate transition band of one pass [Hz] (Hamming: 3.3 fs / numtaps)."""
        return HAMMING_WIDTH_FACTOR * self.fs_hz / self.numtaps


@dataclass(frozen=True)
class FrequencyResponse:
    """Magnitude response of a :class:`FirSpec` for display.

    Attributes
    ----------
    freq_hz : numpy.ndarray
        Frequencies from 0 to fs/2 [Hz], shape (n,).
    gain_single : numpy.ndarray
        |H(f)| of one pass [-], shape (n,).
    gain_zero_phase : numpy.ndarray
        |H(f)|^2, the magnitude of the forward-backward (filtfilt) filter [-], shape (n,).
    """

    freq_hz: np.ndarray
    gain_single: np.ndarray
    gain_zero_phase: np.ndarray


def residual_variance_factor(taps: np.ndarray) -> float:
    """rho_h of docs/calibration.md, 'Noise and bias (eq 50)' [-]: white-noise variance fraction left in x -
    filtfilt(taps, x).

    The effective filtfilt impulse response is g = h * reverse(h), centred; the residual filter is delta - g.
    """
    g = np.convolve(taps, taps[::-1])
    residual = -g
    residual[len(taps) - 1] += 1.0
    return float(np.sum(residual**2))


def design_fir(fs_hz: float, cutoff_hz: float, numtaps: int) -> FirSpec:
    """Hamming-window low-pass FIR (``scipy.signal.firwin``) for a stream sampled at ``fs_hz``.

    Parameters
    ----------
    fs_hz : float
        Sample rate [Hz], > 0.
    cutoff_hz : float
        -6 dB cutoff of one pass [Hz], 0 < cutoff_hz < fs_hz / 2.
    numtaps : int
        Odd filter length >= 3 (odd: type-I linear phase with an integer group delay).

    Raises
    ------
    InputError
        On a non-positive rate, a cutoff outside (0, Nyquist) or an even / too short length.
    """
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise InputError(f"sample rate must be a positive number of Hz, got {fs_hz!r}", field="fs_hz")
    if not (math.isfinite(cutoff_hz) and 0 < cutoff_hz < fs_hz / 2):
        raise InputError(f"cutoff must lie in (0, {fs_hz / 2:g}) Hz (below Nyquist of the {fs_hz:g} Hz stream), "
                         f"got {cutoff_hz!r}", field="cutoff_hz")
    if int(numtaps) != numtaps or numtaps < 3 or numtaps % 2 == 0:
        raise InputError(f"number of taps must be an odd integer >= 3, got {numtaps!r}", field="numtaps")
    taps = signal.firwin(int(numtaps), cutoff_hz, window=FIR_WINDOW, fs=fs_hz)
    return FirSpec(fs_hz=float(fs_hz), cutoff_hz=float(cutoff_hz), numtaps=int(numtaps),
                   rho_h=residual_variance_factor(taps), taps=taps)


def default_cutoff_hz(fs_hz: float, fixed_wing: bool) -> float:
    """Default cutoff [Hz]: 5 Hz fixed-wing, 15 Hz otherwise, at most 0.2 fs (docs/calibration.md, 'FIR filtering')."""
    vehicle_cutoff = DEFAULT_CUTOFF_FIXED_WING_HZ if fixed_wing else DEFAULT_CUTOFF_MULTICOPTER_HZ
    return min(vehicle_cutoff, MAX_DEFAULT_CUTOFF_FRACTION * fs_hz)


def default_numtaps(fs_hz: float, cutoff_hz: float) -> int:
    """Odd length giving a transition width of cutoff/2: numtaps ~ 3.3 fs / (cutoff / 2)
    (docs/calibration.md, 'FIR filtering')."""
    n = math.ceil(HAMMING_WIDTH_FACTOR * fs_hz / (cutoff_hz / 2))
    return n if n % 2 else n + 1


def min_samples(numtaps: int) -> int:
    """Fewest samples a segment needs for a filter of ``numtaps``: both discarded edges plus numtaps kept."""
    return 3 * numtaps


def zero_phase_lowpass(x: np.ndarray, spec: FirSpec) -> np.ndarray:
    """filtfilt(taps, 1, x) along the first axis; same shape as ``x``.

    Only ``x[edge_slice(len(x), spec)]`` is independent of the padding.

    Raises
    ------
    InputError
        When ``x`` has fewer than :func:`min_samples` samples.
    """
    x = np.asarray(x, dtype=float)
    if len(x) < min_samples(spec.numtaps):
        raise InputError(f"{len(x)} samples are too few for a {spec.numtaps}-tap filter "
                         f"(need >= {min_samples(spec.numtaps)}: lengthen the segment or use fewer taps)",
                         field="numtaps")
    # The padding only shapes the discarded edges, so its length just has to be valid.
    return signal.filtfilt(spec.taps, [1.0], x, axis=0, padlen=spec.numtaps - 1)


def edge_slice(n_samples: int, spec: FirSpec) -> slice:
    """Samples of a filtered segment of length ``n_samples`` kept after discarding numtaps at both ends."""
    return slice(spec.numtaps, n_samples - spec.numtaps)


def frequency_response(spec: FirSpec, n_points: int = 1024) -> FrequencyResponse:
    """Magnitude response (``scipy.signal.freqz``) of one pass and of the zero-phase filter."""
    freq_hz, response = signal.freqz(spec.taps, [1.0], worN=n_points, fs=spec.fs_hz)
    gain = np.abs(response)
    return FrequencyResponse(freq_hz=freq_hz, gain_single=gain, gain_zero_phase=gain**2)
