"""Is a replay to be trusted? Mean NIS per measurement channel against its chi-square band, the innovation
log-likelihood noise identification maximises, a turbulence-intensity figure from the wind estimate and a check that
the estimated air flows forward through the airframe (docs/calibration.md, 'Noise identification' and
'Consistency checks').
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from calib.figures import ChannelConsistency, mean_nis_band
from estimators.config import NoiseConfig

#: Mean NIS outside this range makes a channel inconsistent (a visible warning). The chi-square band of the mean
#: of n NIS values is far narrower, but innovations are correlated in time (GPS, coloured sensor errors), which
#: the band ignores; a factor of 3 either side of 1 (5x on the low side) is what a filter-test engineer would
#: call wrong rather than imperfect.
NIS_WARNING_RANGE = (0.2, 3.0)
#: Normalised innovations are clipped at this many sigma in the likelihood (a rejected outlier costs a fixed
#: amount: one bad sample cannot dominate, and shrinking S until everything is rejected does not pay).
LIKELIHOOD_CLIP_SIGMA = 5.0
#: Channels with fewer updates are not judged.
MIN_UPDATES = 20
#: Window of the moving mean that separates the mean wind from gusts [s].
GUST_WINDOW_S = 60.0
#: Estimated horizontal air speed above which an epoch counts as wing-borne flight [m/s] (below every fixed-wing
#: stall speed; a hovering multirotor stays under it).
AIRBORNE_AIR_SPEED_M_S = 5.0
#: Largest share of wing-borne epochs with the air flowing backwards through the airframe that is still noise (a
#: tail-wind transient or a gust at low airspeed); above it the wind estimate is the mirrored solution.
REVERSED_AIRFLOW_LIMIT = 0.05


def _as_categorical(column: pd.Series) -> pd.Categorical:
    return column.array if isinstance(column.dtype, pd.CategoricalDtype) else pd.Categorical(column)


def log_likelihood(diagnostics: pd.DataFrame) -> float:
    """Innovation log-likelihood ``-1/2 sum_k [min(nu_k^2 / S_k, c^2) + ln(2 pi S_k)]`` over every scalar update
    of one estimator's diagnostics (c = :data:`LIKELIHOOD_CLIP_SIGMA`)."""
    nis = diagnostics["nis"].to_numpy(dtype=float)
    variance = diagnostics["innovation_var"].to_numpy(dtype=float)
    good = np.isfinite(nis) & np.isfinite(variance) & (variance > 0)
    if not good.any():
        return -math.inf
    clipped = np.minimum(nis[good], LIKELIHOOD_CLIP_SIGMA ** 2)
    return float(-0.5 * np.sum(clipped + np.log(2.0 * np.pi * variance[good])))


def _channel_keys(diagnostics: pd.DataFrame):
    """(used rows mask, integer key per used row, sensor and component categoricals, component count): one key per
    ``sensor.component`` channel, so per-channel sums are bincounts instead of a groupby (a 1-hour log has ~10^6
    updates)."""
    nis = diagnostics["nis"].to_numpy(dtype=float)
    sensor = _as_categorical(diagnostics["sensor"])
    component = _as_categorical(diagnostics["component"])
    used = np.isfinite(nis) & (sensor.codes >= 0) & (component.codes >= 0)
    n_components = max(len(component.categories), 1)
    key = sensor.codes.astype(np.int64)[used] * n_components + component.codes.astype(np.int64)[used]
    return used, key, sensor, component, n_components


def _groups(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(key, return_inverse=True, return_counts=True)`` for small non-negative integer keys, by counting
    instead of sorting (10^6 updates of a 1-hour log)."""
    counts_by_key = np.bincount(key)
    keys = np.flatnonzero(counts_by_key)
    position = np.zeros(len(counts_by_key), dtype=np.int64)
    position[keys] = np.arange(len(keys))
    return keys, position[key], counts_by_key[keys]


def channel_consistency(diagnostics: pd.DataFrame) -> tuple[ChannelConsistency, ...]:
    """Mean NIS per ``sensor.component`` channel of one estimator's diagnostics, with the 95 % band of the mean of
    that many chi-square(1) values; channels in the order of the ``sensor`` then ``component`` categories (sorted
    names for plain columns), as a sorted groupby."""
    nis = diagnostics["nis"].to_numpy(dtype=float)
    used, key, sensor, component, n_components = _channel_keys(diagnostics)
    keys, inverse, counts = _groups(key)
    sums = np.bincount(inverse, weights=nis[used], minlength=len(keys))
    out = []
    for k, n, total in zip(keys, counts, sums, strict=True):
        sensor_name, component_name = sensor.categories[k // n_components], component.categories[k % n_components]
        out.append(ChannelConsistency(channel=f"{sensor_name}.{component_name}", n_updates=int(n),
                                      mean_nis=float(total / n), band=mean_nis_band(int(n))))
    return tuple(out)


def innovation_autocorrelation(diagnostics: pd.DataFrame) -> dict[str, float]:
    """Lag-1 autocorrelation of each channel's normalised innovations ``nu / sqrt(S)`` in update order (0 for white
    innovations; near 1 for an error correlated over many updates, such as a GPS position's), by channel name."""
    used, key, sensor, component, n_components = _channel_keys(diagnostics)
    innovation = diagnostics["innovation"].to_numpy(dtype=float)
    z = (innovation / np.sqrt(diagnostics["innovation_var"].to_numpy(dtype=float)))[used]
    finite = np.isfinite(z)
    z, key = z[finite], key[finite]
    keys, inverse, counts = _groups(key)
    # channels one after the other, each in update order (a stable sort of 16-bit keys is a radix sort)
    order = np.argsort(inverse.astype(np.int16) if len(keys) < 2 ** 15 else inverse, kind="stable")
    z, inverse = z[order], inverse[order]
    deviation = z - (np.bincount(inverse, weights=z, minlength=len(keys)) / np.maximum(counts, 1))[inverse]
    variance = np.bincount(inverse, weights=deviation * deviation, minlength=len(keys))
    same = inverse[1:] == inverse[:-1]
    covariance = np.bincount(inverse[1:][same], weights=(deviation[1:] * deviation[:-1])[same], minlength=len(keys))
    return {f"{sensor.categories[k // n_components]}.{component.categories[k % n_components]}":
            float(c / v) if v > 0 else math.nan for k, c, v in zip(keys, covariance, variance, strict=True)}


#: Verdicts of a channel (:class:`ChannelVerdict`).
CONSISTENT, CONSERVATIVE, OVERCONFIDENT, AT_BOUND, NOT_JUDGED = (
    "consistent", "conservative", "overconfident", "at documented bound", "not judged")
#: Verdicts of an estimator (:class:`EstimatorVerdict`), best first.
ESTIMATOR_STATUSES = ("consistent", "conservative", "inconsistent")
#: A GPS noise up to this factor above the receiver's own accuracy (scale and floor) still counts as "the receiver's
#: accuracy" for :func:`documented_bound`.
RECEIVER_BOUND_TOLERANCE = 1.5


@dataclass(frozen=True)
class ChannelVerdict:
    """How far one measurement channel's innovations agree with the filter's own error model.

    Attributes
    ----------
    channel : str
        ``"<sensor>.<component>"``.
    verdict : str
        :data:`CONSISTENT`, :data:`CONSERVATIVE` (mean NIS below the range: the noise is set higher than the flight
        shows; the estimate is usable, its 1-sigma overstated), :data:`OVERCONFIDENT` (above the range: innovations
        larger than the filter expects, from a noise set too low or a model error), :data:`AT_BOUND` (below the
        range on a channel whose noise is a documented conservative bound) or :data:`NOT_JUDGED` (too few updates).
    mean_nis : float
        Mean of nu^2 / S [-] (1 for a consistent filter).
    n_updates : int
        Scalar updates.
    lag1_autocorrelation : float
        Of the normalised innovations [-] (:func:`innovation_autocorrelation`).
    n_effective : float
        Independent updates they are worth: ``n (1 - rho) / (1 + rho)`` for an AR(1) error (rho >= 0).
    accepted : tuple of 2 float
        Mean NIS range judged consistent: the wider of :data:`NIS_WARNING_RANGE` and the 95 % chi-square band of
        the mean of ``n_effective`` values.
    reason : str
        The verdict in words (with the noise factor ``sqrt(mean NIS)`` or its inverse), or the documented bound.
    """

    channel: str
    verdict: str
    mean_nis: float
    n_updates: int
    lag1_autocorrelation: float
    n_effective: float
    accepted: tuple[float, float]
    reason: str


@dataclass(frozen=True)
class EstimatorVerdict:
    """One estimator's consistency verdict: ``status`` in :data:`ESTIMATOR_STATUSES` (inconsistent when any channel
    is overconfident, conservative when any is conservative), a one-line ``summary`` naming the channels behind it,
    and every channel's :class:`ChannelVerdict`."""

    estimator: str
    status: str
    summary: str
    channels: tuple[ChannelVerdict, ...]


def documented_bound(estimator: str, channel: str, noise: NoiseConfig) -> str | None:
    """Why a mean NIS below the range is expected on ``channel`` with ``noise`` (docs/calibration.md, 'Consistency
    checks'), or None where it is not.

    * the full-state filters' zero-sideslip pseudo-measurement: its noise bounds the unmodelled sideslip;
    * the three-stage filter's accelerometer (gravity) pseudo-measurement, whose variance the eq 52 tau inflates for
      the manoeuvre accelerations it does not model;
    * a GPS position whose noise is the receiver's own reported accuracy (eph / epv, scale and floor within
      :data:`RECEIVER_BOUND_TOLERANCE` of the defaults): the receiver's error is correlated over minutes and the
      filter follows it, so its innovations are smaller than the accuracy the receiver reports.
    """
    sensor, _, component = channel.partition(".")
    if sensor == "sideslip":
        return "the zero-sideslip pseudo-measurement's noise bounds the unmodelled sideslip"
    if sensor == "accel" and estimator == "three_stage":
        return "the gravity pseudo-measurement's variance is inflated (eq 52 tau) for unmodelled manoeuvres"
    if sensor == "gps_pos":
        default = NoiseConfig()
        vertical = component == "d"
        scale, default_scale = ((noise.gps_hgt_epv_scale, default.gps_hgt_epv_scale) if vertical
                                else (noise.gps_pos_eph_scale, default.gps_pos_eph_scale))
        floor, default_floor = ((noise.gps_hgt_sigma_floor_m, default.gps_hgt_sigma_floor_m) if vertical
                                else (noise.gps_pos_sigma_floor_m, default.gps_pos_sigma_floor_m))
        if 0 < scale <= RECEIVER_BOUND_TOLERANCE * default_scale and floor <= RECEIVER_BOUND_TOLERANCE * default_floor:
            return "the noise is the receiver's reported accuracy, whose error is correlated over minutes"
    return None


def channel_verdicts(estimator: str, diagnostics: pd.DataFrame, noise: NoiseConfig,
                     channels: tuple[ChannelConsistency, ...] | None = None) -> tuple[ChannelVerdict, ...]:
    """Every channel of one estimator's diagnostics judged against its own error model: the acceptance range
    widens with the innovations' correlation (fewer independent updates), and a channel with a
    :func:`documented_bound` is :data:`AT_BOUND` rather than conservative (``channels``: its
    :func:`channel_consistency`, computed when None)."""
    channels = channel_consistency(diagnostics) if channels is None else channels
    correlation = innovation_autocorrelation(diagnostics)
    out = []
    for c in channels:
        rho = correlation.get(c.channel, math.nan)
        n_effective = c.n_updates * (1.0 - rho) / (1.0 + rho) if math.isfinite(rho) and rho > 0 else c.n_updates
        n_effective = max(1.0, min(float(c.n_updates), n_effective))
        band = mean_nis_band(max(1, round(n_effective)))
        accepted = (min(NIS_WARNING_RANGE[0], band[0]), max(NIS_WARNING_RANGE[1], band[1]))
        bound = documented_bound(estimator, c.channel, noise)
        if c.n_updates < MIN_UPDATES:
            verdict, reason = NOT_JUDGED, f"only {c.n_updates} updates"
        elif c.mean_nis > accepted[1]:
            verdict = OVERCONFIDENT
            reason = (f"innovations ~{math.sqrt(c.mean_nis):.1f}x larger than the filter expects (noise set too low "
                      "or a model error)")
        elif c.mean_nis < accepted[0] and bound is not None:
            verdict, reason = AT_BOUND, bound
        elif c.mean_nis < accepted[0]:
            verdict = CONSERVATIVE
            reason = (f"noise set ~{math.sqrt(1.0 / max(c.mean_nis, 1e-12)):.1f}x higher than the flight shows "
                      "(estimate usable, its 1-sigma overstated)")
        else:
            verdict, reason = CONSISTENT, "inside its range"
        out.append(ChannelVerdict(channel=c.channel, verdict=verdict, mean_nis=c.mean_nis, n_updates=c.n_updates,
                                  lag1_autocorrelation=rho, n_effective=n_effective, accepted=accepted,
                                  reason=reason))
    return tuple(out)


def estimator_verdict(estimator: str, verdicts: tuple[ChannelVerdict, ...]) -> EstimatorVerdict:
    """The one-line verdict of an estimator from its channels' (:func:`channel_verdicts`)."""
    def listed(kind: str) -> list[ChannelVerdict]:
        return [v for v in verdicts if v.verdict == kind]

    overconfident, conservative, bounded = listed(OVERCONFIDENT), listed(CONSERVATIVE), listed(AT_BOUND)
    parts = []
    if overconfident:
        parts.append("inconsistent: " + ", ".join(f"{v.channel} (mean NIS {v.mean_nis:.2f}: innovations "
                                                   f"~{math.sqrt(v.mean_nis):.1f}x larger than expected)"
                                                   for v in overconfident)
                     + ": noise set too low or a model error; do not trust this estimate's 1-sigma")
    if conservative:
        parts.append(("conservative: " if not overconfident else "conservative on ")
                     + ", ".join(f"{v.channel} (noise ~{math.sqrt(1.0 / max(v.mean_nis, 1e-12)):.1f}x above the "
                                 "flight's)" for v in conservative)
                     + ("" if overconfident else ": estimate usable, its 1-sigma overstated"))
    status = "inconsistent" if overconfident else "conservative" if conservative else "consistent"
    if not parts:
        judged = sum(v.verdict != NOT_JUDGED for v in verdicts)
        parts.append(f"consistent ({judged} channels inside their range"
                     + (f"; {', '.join(v.channel for v in bounded)} at documented bounds" if bounded else "") + ")")
    return EstimatorVerdict(estimator=estimator, status=status, summary="; ".join(parts), channels=verdicts)


def turbulence_intensity_m_s(states: pd.DataFrame, *, settle_s: float = 60.0) -> float:
    """RMS of the estimated gust velocity [m/s]: the horizontal wind estimate minus its centred
    :data:`GUST_WINDOW_S` moving mean, after ``settle_s`` of convergence; NaN without a wind estimate.

    ``states``: one estimator's rows of the states table (``time_s``, ``wind_n_m_s``, ``wind_e_m_s``).
    """
    wind = states[["time_s", "wind_n_m_s", "wind_e_m_s"]].dropna()
    if len(wind) < 10:
        return math.nan
    wind = wind[wind["time_s"] >= wind["time_s"].iloc[0] + settle_s]
    if len(wind) < 10:
        return math.nan
    rate_hz = (len(wind) - 1) / max(float(wind["time_s"].iloc[-1] - wind["time_s"].iloc[0]), 1e-9)
    window = max(3, round(GUST_WINDOW_S * rate_hz))
    values = wind[["wind_n_m_s", "wind_e_m_s"]]
    gust = values - values.rolling(window, center=True, min_periods=1).mean()
    return float(np.sqrt(np.mean(np.sum(gust.to_numpy() ** 2, axis=1))))


def reversed_airflow_fraction(states: pd.DataFrame, *, min_air_speed_m_s: float = AIRBORNE_AIR_SPEED_M_S) -> float:
    """Share of the epochs whose estimated air velocity points backwards through the airframe (body-x component
    below zero) among those with an estimated horizontal air speed of at least ``min_air_speed_m_s``; NaN without
    a wind estimate or such epochs.

    A true-airspeed magnitude and a zero-sideslip constraint cannot tell an aircraft flying forward through the air
    from one flying backwards through an air mass moving at twice its airspeed: both fit every airspeed and GPS
    innovation. Only this geometric check, which needs no truth, shows a replay that took the mirrored solution
    (docs/calibration.md, 'Consistency checks').

    ``states``: one estimator's rows of the states table (``roll_deg`` is not needed; ``pitch_deg``, ``yaw_deg``,
    NED ground velocity ``vn_m_s``, ``ve_m_s``, ``vd_m_s`` and wind ``wind_n_m_s``, ``wind_e_m_s`` [m/s]).
    """
    columns = ["pitch_deg", "yaw_deg", "vn_m_s", "ve_m_s", "vd_m_s", "wind_n_m_s", "wind_e_m_s"]
    if any(c not in states.columns for c in columns):
        return math.nan
    values = states[columns].dropna().to_numpy(dtype=float)
    if len(values) == 0:
        return math.nan
    pitch, yaw = np.radians(values[:, 0]), np.radians(values[:, 1])
    air_n, air_e, air_d = values[:, 2] - values[:, 5], values[:, 3] - values[:, 6], values[:, 4]
    airborne = np.hypot(air_n, air_e) >= min_air_speed_m_s
    if not airborne.any():
        return math.nan
    # First row of the NED-to-body rotation: the body-x (forward) component of the air velocity.
    forward = np.cos(pitch) * (np.cos(yaw) * air_n + np.sin(yaw) * air_e) - np.sin(pitch) * air_d
    return float(np.mean(forward[airborne] < 0.0))
