"""Is a replay to be trusted? Mean NIS per measurement channel against its chi-square band, the innovation
log-likelihood noise identification maximises, a turbulence-intensity figure from the wind estimate and a check that
the estimated air flows forward through the airframe (docs/calibration.md, 'Noise identification' and
'Consistency checks').
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from calib.figures import ChannelConsistency, mean_nis_band

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


def channel_consistency(diagnostics: pd.DataFrame) -> tuple[ChannelConsistency, ...]:
    """Mean NIS per ``sensor.component`` channel of one estimator's diagnostics, with the 95 % band of the mean of
    that many chi-square(1) values; channels in the order of the ``sensor`` then ``component`` categories (sorted
    names for plain columns), as a sorted groupby."""
    nis = diagnostics["nis"].to_numpy(dtype=float)
    sensor = _as_categorical(diagnostics["sensor"])
    component = _as_categorical(diagnostics["component"])
    used = np.isfinite(nis) & (sensor.codes >= 0) & (component.codes >= 0)
    n_components = max(len(component.categories), 1)
    # one integer key per (sensor, component): a bincount instead of a groupby (a 1-hour log has ~10^6 updates)
    key = sensor.codes.astype(np.int64)[used] * n_components + component.codes.astype(np.int64)[used]
    keys, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=nis[used], minlength=len(keys))
    out = []
    for k, n, total in zip(keys, counts, sums, strict=True):
        sensor_name, component_name = sensor.categories[k // n_components], component.categories[k % n_components]
        out.append(ChannelConsistency(channel=f"{sensor_name}.{component_name}", n_updates=int(n),
                                      mean_nis=float(total / n), band=mean_nis_band(int(n))))
    return tuple(out)


def consistency_warnings(estimator: str, channels: tuple[ChannelConsistency, ...]) -> list[str]:
    """One warning per channel whose mean NIS is outside :data:`NIS_WARNING_RANGE` (channels with fewer than
    :data:`MIN_UPDATES` updates are not judged)."""
    low, high = NIS_WARNING_RANGE
    notes = []
    for c in channels:
        if c.n_updates < MIN_UPDATES or low <= c.mean_nis <= high:
            continue
        verdict = "innovations larger than the filter expects (noise set too low or a model error)" \
            if c.mean_nis > high else "innovations smaller than the filter expects (noise set too high)"
        notes.append(f"{estimator}: channel {c.channel} inconsistent, mean NIS {c.mean_nis:.2f} over "
                     f"{c.n_updates} updates (expected {low:g}..{high:g}; chi-square 95 % band {c.band[0]:.2f}.."
                     f"{c.band[1]:.2f}): {verdict}")
    return notes


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
