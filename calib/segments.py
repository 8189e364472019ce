"""Calibration segments: a user window, or quiet stretches found automatically (docs/calibration.md, 'Noise and bias (eq
50)').

* stationary: the IMU sees no rotation and only gravity: the moving average of the gyro vector has norm below
  ``gyro_max_rad_s`` and that of the specific force has a constant norm, within ``accel_tol_m_s2`` of its median
  over the stretch (which itself lies within ``accel_offset_max_m_s2`` of g, allowing for an uncalibrated
  accelerometer offset along gravity), for at least ``min_duration_s``. Where GPS or airspeed exist, the median
  speed must also be below ``max_speed_m_s`` (an unaccelerated straight flight passes the IMU test too).
* steady: cruise with a low angular rate, steady speed (airspeed, else GPS ground speed) above ``min_speed_m_s``
  and a small climb rate (barometer, else GPS altitude), for at least ``min_duration_s``.

Every segment carries the reason it was chosen. Runs never span a gap in the stream (> 5 median periods, > 0.1 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.ndimage import uniform_filter1d
from scipy.signal import savgol_filter

from ingest.errors import InputError
from ingest.flightlog import FlightLog

#: PX4's standard gravity [m/s^2]; the stationary test's tolerance covers local gravity and scale errors.
STANDARD_GRAVITY_M_S2 = 9.80665

GYRO_COLUMNS = ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s")
ACCEL_COLUMNS = ("accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2")

Interval = tuple[float, float]


@dataclass(frozen=True)
class Segment:
    """A time window of the log used for calibration.

    Attributes
    ----------
    start_s, end_s : float
        Window on the log clock [s], start < end.
    kind : str
        ``"user"`` (given), ``"stationary"`` or ``"steady"`` (found automatically).
    reason : str
        Why this window: the criteria it met, or "user window".
    """

    start_s: float
    end_s: float
    kind: str
    reason: str

    @property
    def duration_s(self) -> float:
        """Window length [s]."""
        return self.end_s - self.start_s

    def select(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Rows of a stream (indexed by ``time_s``) inside the window, ends included."""
        time_s = frame.index.to_numpy(dtype=float)
        return frame.loc[(time_s >= self.start_s) & (time_s <= self.end_s)]


@dataclass(frozen=True)
class StationaryCriteria:
    """Thresholds of the stationary test.

    Attributes
    ----------
    gyro_max_rad_s : float
        Largest norm of the averaged gyro vector [rad/s] (docs/calibration.md, 'Noise and bias (eq 50)').
    accel_tol_m_s2 : float
        Largest deviation of |averaged specific force| from its median over the stretch [m/s^2] (docs/calibration.md,
        'Noise and bias (eq 50)''s
        0.2, applied around g + the along-gravity offset instead of g).
    accel_offset_max_m_s2 : float
        Largest | |averaged specific force| - g | [m/s^2]: admits uncalibrated MPU6050-class zero-g offsets (paper
        Table 1: up to 80 mg = 0.78 m/s^2), whose along-gravity part the stationary bias estimate measures.
    max_speed_m_s : float
        Largest median GPS ground speed / true airspeed [m/s] (when the log has one).
    min_duration_s : float
        Shortest segment [s].
    smooth_s : float
        Moving-average window applied before the thresholds [s] (keeps sensor noise from breaking runs).
    trim_s : float
        Dropped at each end of a run that borders motion [s]: the moving average lets the first moments of a
        motion through, and a launch or take-off must not leak into the means and the Allan deviation.
    gravity_m_s2 : float
        g used by the test [m/s^2].
    """

    gyro_max_rad_s: float = 0.05
    accel_tol_m_s2: float = 0.2
    accel_offset_max_m_s2: float = 1.0
    max_speed_m_s: float = 1.0
    min_duration_s: float = 5.0
    smooth_s: float = 0.2
    trim_s: float = 1.0
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2


@dataclass(frozen=True)
class SteadyCriteria:
    """Thresholds of the steady-cruise test.

    Attributes
    ----------
    rate_max_rad_s : float
        Largest RMS of the (smoothed) gyro vector norm over the window [rad/s].
    speed_std_max_m_s : float
        Largest moving standard deviation of the speed [m/s].
    min_speed_m_s : float
        Smallest moving-average speed [m/s] (flying, not standing).
    climb_max_m_s : float
        Largest |climb rate| from a moving linear fit of the altitude [m/s].
    min_duration_s : float
        Shortest segment [s].
    window_s : float
        Moving window of every test [s].
    smooth_s : float
        Moving average applied to the gyro before its RMS over ``window_s`` [s].
    trim_s : float
        Dropped at each end of a run that borders a manoeuvre [s] (the windows blur the transitions).
    """

    rate_max_rad_s: float = 0.1
    speed_std_max_m_s: float = 0.5
    min_speed_m_s: float = 3.0
    climb_max_m_s: float = 0.5
    min_duration_s: float = 5.0
    window_s: float = 2.0
    smooth_s: float = 0.2
    trim_s: float = 1.0


#: Default thresholds (frozen, safe to share as argument defaults).
DEFAULT_STATIONARY = StationaryCriteria()
DEFAULT_STEADY = SteadyCriteria()


def user_segment(log: FlightLog, start_s: float, end_s: float) -> Segment:
    """A user-chosen window [s, log clock], checked against the log's IMU time span.

    Raises
    ------
    InputError
        When the bounds are not finite, not increasing, or outside the log.
    """
    if not (math.isfinite(start_s) and math.isfinite(end_s) and start_s < end_s):
        raise InputError(f"segment needs finite start < end, got {start_s!r} .. {end_s!r} s",
                         source=log.meta.source, field="segment")
    first_s, last_s = _time_span(log)
    if end_s <= first_s or start_s >= last_s:
        raise InputError(f"segment {start_s:g} .. {end_s:g} s lies outside the log's IMU data "
                         f"({first_s:.3f} .. {last_s:.3f} s, log clock)", source=log.meta.source, field="segment")
    return Segment(start_s=float(start_s), end_s=float(end_s), kind="user", reason="user window")


def find_stationary_segments(log: FlightLog, criteria: StationaryCriteria = DEFAULT_STATIONARY) -> list[Segment]:
    """Stationary segments of the log, longest first (empty without an IMU stream)."""
    if not log.has("imu"):
        return []
    imu = log["imu"]
    time_s = imu.index.to_numpy(dtype=float)
    window = _window_samples(time_s, criteria.smooth_s)
    gyro = uniform_filter1d(imu[list(GYRO_COLUMNS)].to_numpy(dtype=float), window, axis=0, mode="nearest")
    accel = uniform_filter1d(imu[list(ACCEL_COLUMNS)].to_numpy(dtype=float), window, axis=0, mode="nearest")
    norm_f = np.linalg.norm(accel, axis=1)
    coarse = ((np.linalg.norm(gyro, axis=1) < criteria.gyro_max_rad_s)
              & (np.abs(norm_f - criteria.gravity_m_s2) < criteria.accel_offset_max_m_s2))
    still = np.zeros_like(coarse)
    for a, b in _run_bounds(time_s, coarse):
        # Gravity-only means a constant |f| = g + the along-gravity offset: its median over the stretch.
        still[a:b + 1] = np.abs(norm_f[a:b + 1] - np.median(norm_f[a:b + 1])) < criteria.accel_tol_m_s2
    speed = _speed_source(log, prefer="gps")
    segments = []
    for start_s, end_s in _trimmed(_runs(time_s, still, 0.0), time_s, criteria.trim_s, criteria.min_duration_s):
        reason = (f"stationary: |mean gyro| < {criteria.gyro_max_rad_s:g} rad/s and |mean f| within "
                  f"{criteria.accel_tol_m_s2:g} m/s^2 of its median (itself within "
                  f"{criteria.accel_offset_max_m_s2:g} m/s^2 of g; {criteria.smooth_s:g} s moving averages) for "
                  f"{end_s - start_s:.1f} s (ends next to motion trimmed by {criteria.trim_s:g} s)")
        if speed is None:
            reason += "; no GPS or airspeed to confirm zero speed"
        else:
            name, values = speed
            inside = values[(values.index >= start_s) & (values.index <= end_s)]
            if len(inside) and float(inside.median()) > criteria.max_speed_m_s:
                continue  # unaccelerated flight, not standing still
            reason += f"; median {name} <= {criteria.max_speed_m_s:g} m/s"
        segments.append(Segment(start_s=start_s, end_s=end_s, kind="stationary", reason=reason))
    return sorted(segments, key=lambda s: -s.duration_s)


def find_steady_segments(log: FlightLog, criteria: SteadyCriteria = DEFAULT_STEADY) -> list[Segment]:
    """Steady-cruise segments, longest first (empty without IMU, a speed source or an altitude source)."""
    speed = _speed_source(log, prefer="airspeed")
    altitude = _altitude_source(log)
    if not log.has("imu") or speed is None or altitude is None:
        return []
    imu = log["imu"]
    imu_time_s = imu.index.to_numpy(dtype=float)
    # Smooth away sensor noise and vibration first, then take the RMS over the window: averaging the rate
    # itself over the window would hide an oscillation (rocking, phugoid).
    gyro = uniform_filter1d(imu[list(GYRO_COLUMNS)].to_numpy(dtype=float),
                            _window_samples(imu_time_s, criteria.smooth_s), axis=0, mode="nearest")
    rms_rate = np.sqrt(uniform_filter1d(np.sum(gyro**2, axis=1), _window_samples(imu_time_s, criteria.window_s),
                                        mode="nearest"))
    intervals = _runs(imu_time_s, rms_rate < criteria.rate_max_rad_s, 0.0)

    speed_name, speed_values = speed
    speed_time_s = speed_values.index.to_numpy(dtype=float)
    v = speed_values.to_numpy(dtype=float)
    n = _window_samples(speed_time_s, criteria.window_s)
    mean_v = uniform_filter1d(v, n, mode="nearest")
    std_v = np.sqrt(np.clip(uniform_filter1d(v**2, n, mode="nearest") - mean_v**2, 0.0, None))
    steady_speed = (std_v < criteria.speed_std_max_m_s) & (mean_v > criteria.min_speed_m_s)
    intervals = _intersect(intervals, _runs(speed_time_s, steady_speed, 0.0))

    altitude_name, altitude_values = altitude
    alt_time_s = altitude_values.index.to_numpy(dtype=float)
    n = _window_samples(alt_time_s, criteria.window_s)
    n = n if n % 2 else n + 1
    if len(alt_time_s) < max(n, 3):
        return []
    climb_m_s = savgol_filter(altitude_values.to_numpy(dtype=float), max(n, 3), 1, deriv=1,
                              delta=float(np.median(np.diff(alt_time_s))))
    intervals = _intersect(intervals, _runs(alt_time_s, np.abs(climb_m_s) < criteria.climb_max_m_s, 0.0))

    reason = (f"steady: RMS gyro < {criteria.rate_max_rad_s:g} rad/s, {speed_name} std < "
              f"{criteria.speed_std_max_m_s:g} m/s and mean > {criteria.min_speed_m_s:g} m/s, |climb rate from "
              f"{altitude_name}| < {criteria.climb_max_m_s:g} m/s ({criteria.window_s:g} s windows, ends next to "
              f"manoeuvres trimmed by {criteria.trim_s:g} s)")
    kept = _trimmed(intervals, imu_time_s, criteria.trim_s, criteria.min_duration_s)
    return sorted((Segment(start_s=a, end_s=b, kind="steady", reason=f"{reason} for {b - a:.1f} s")
                   for a, b in kept), key=lambda s: -s.duration_s)


def auto_segments(log: FlightLog, stationary: StationaryCriteria = DEFAULT_STATIONARY,
                  steady: SteadyCriteria = DEFAULT_STEADY) -> list[Segment]:
    """All candidate segments: stationary ones (longest first), then steady ones (longest first)."""
    return find_stationary_segments(log, stationary) + find_steady_segments(log, steady)


def is_stationary(log: FlightLog, segment: Segment, criteria: StationaryCriteria = DEFAULT_STATIONARY) -> bool:
    """True when one stationary run covers the whole ``segment`` (used to qualify user windows)."""
    return any(s.start_s <= segment.start_s + 1e-9 and s.end_s >= segment.end_s - 1e-9
               for s in find_stationary_segments(log, criteria))


def _time_span(log: FlightLog) -> Interval:
    if not log.has("imu"):
        raise InputError("log has no IMU stream to calibrate", source=log.meta.source, field="imu")
    time_s = log["imu"].index.to_numpy(dtype=float)
    return float(time_s[0]), float(time_s[-1])


def _window_samples(time_s: np.ndarray, window_s: float) -> int:
    """Samples in ``window_s`` at the stream's median rate (at least 1)."""
    if len(time_s) < 2:
        return 1
    return max(1, round(window_s / float(np.median(np.diff(time_s)))))


def _speed_source(log: FlightLog, prefer: str) -> tuple[str, pd.Series] | None:
    """("GPS ground speed", |v_h|) or ("true airspeed", TAS), the ``prefer``-red stream ("gps" or "airspeed")
    first; None without either. Standing still is about ground speed (wind blows through a parked pitot);
    cruise is about airspeed."""
    sources = {}
    if log.has("gps"):
        gps = log["gps"]
        sources["gps"] = ("GPS ground speed", np.hypot(gps["vn_m_s"], gps["ve_m_s"]).dropna())
    if log.has("airspeed"):
        sources["airspeed"] = ("true airspeed", log["airspeed"]["tas_m_s"].dropna())
    return sources.get(prefer) or next(iter(sources.values()), None)


def _altitude_source(log: FlightLog) -> tuple[str, pd.Series] | None:
    """("barometric altitude", alt) or ("GPS altitude", alt); None without either."""
    for stream, name in (("baro", "barometric altitude"), ("gps", "GPS altitude")):
        if log.has(stream):
            values = log[stream]["alt_m"].dropna()
            if len(values) >= 2:
                return name, values
    return None


def _run_bounds(time_s: np.ndarray, mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) indices of maximal runs of True in ``mask`` that do not cross a stream gap."""
    n = len(time_s)
    if n == 0:
        return []
    dt = np.diff(time_s)
    gap = dt > max(5.0 * float(np.median(dt)), 0.1) if n > 1 else np.zeros(0, dtype=bool)
    linked = mask[:-1] & mask[1:] & ~gap
    starts = np.flatnonzero(mask & np.r_[True, ~linked])
    ends = np.flatnonzero(mask & np.r_[~linked, True])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _runs(time_s: np.ndarray, mask: np.ndarray, min_duration_s: float) -> list[Interval]:
    """(start, end) times of the runs of :func:`_run_bounds` lasting at least ``min_duration_s`` (and > 0)."""
    return [(float(time_s[a]), float(time_s[b])) for a, b in _run_bounds(time_s, mask)
            if b > a and time_s[b] - time_s[a] >= min_duration_s]


def _trimmed(intervals: list[Interval], time_s: np.ndarray, trim_s: float, min_duration_s: float
             ) -> list[Interval]:
    """Intervals shortened by ``trim_s`` at every end that is not within ``trim_s`` of the start or end of the
    record (streams end a sample apart), then kept when at least ``min_duration_s`` long."""
    out = []
    for a, b in intervals:
        a = a + trim_s if a > time_s[0] + trim_s else a
        b = b - trim_s if b < time_s[-1] - trim_s else b
        if b - a >= min_duration_s:
            out.append((a, b))
    return out


def _intersect(a: list[Interval], b: list[Interval]) -> list[Interval]:
    """Intersection of two sorted lists of disjoint closed intervals."""
    out = []
    i = j = 0
    while i < len(a) and j < len(b):
        lo, hi = max(a[i][0], b[j][0]), min(a[i][1], b[j][1])
        if lo < hi:
            out.append((lo, hi))
        if a[i][1] < b[j][1]:
            i += 1
        else:
            j += 1
    return out
