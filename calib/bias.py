"""Physically referenced sensor biases (docs/calibration.md, 'Noise and bias (eq 50)'), beside eq 50's beta which is ~0
by construction.

* stationary segment: gyro bias = mean rate (earth rate <= 7.3e-5 rad/s is neglected); accelerometer: only the
  component along gravity is identifiable from one orientation, b_parallel = |mean f| - g_local. The direction of
  gravity in body axes comes from the autopilot's attitude estimate; what the mean specific force shows
  perpendicular to it mixes horizontal accelerometer bias with attitude error and is reported, not attributed.
* in flight: the bias states of the full-state filters, averaged after convergence (passed in by the caller, since
  calib does not run the estimators).
* the g they are referenced to: :func:`local_gravity`, WGS-84 normal gravity at the log's median GPS fix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.segments import ACCEL_COLUMNS, GYRO_COLUMNS, STANDARD_GRAVITY_M_S2, Segment
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.frames import quat_to_matrix
from ingest.geodesy import local_gravity_m_s2

Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class GravityReference:
    """The g a stationary accelerometer is compared with.

    Attributes
    ----------
    value_m_s2 : float
        Gravity magnitude [m/s^2].
    source : str
        Where it came from (e.g. "WGS-84 normal gravity at 47.40 deg, 488 m").
    """

    value_m_s2: float
    source: str


#: Used when the caller gives no local gravity (differs from local g by up to ~0.03 m/s^2).
STANDARD_GRAVITY = GravityReference(STANDARD_GRAVITY_M_S2, "PX4 standard gravity (no local gravity given)")


def local_gravity(log: FlightLog) -> GravityReference:
    """WGS-84 normal gravity at the median GPS fix of ``log``; :data:`STANDARD_GRAVITY` without a GPS fix."""
    if not log.has("gps"):
        return STANDARD_GRAVITY
    gps = log["gps"][["lat_deg", "alt_m"]].dropna()
    if gps.empty:
        return STANDARD_GRAVITY
    lat_deg, alt_m = float(np.median(gps["lat_deg"])), float(np.median(gps["alt_m"]))
    return GravityReference(float(local_gravity_m_s2(lat_deg, alt_m)),
                            f"WGS-84 normal gravity at the median GPS fix ({lat_deg:.4f} deg, {alt_m:.0f} m)")


@dataclass(frozen=True)
class StationaryBias:
    """Biases referenced to physics over a stationary segment.

    Attributes
    ----------
    segment : Segment
        The stationary window used.
    n_samples : int
        IMU samples averaged.
    gyro_bias_rad_s : tuple of 3 float
        Mean gyro rate per body axis (x, y, z) [rad/s].
    gyro_bias_std_rad_s : tuple of 3 float
        Standard error of that mean assuming white noise, std / sqrt(n) [rad/s].
    accel_bias_parallel_m_s2 : float
        |mean specific force| - g: bias component along gravity [m/s^2].
    accel_bias_parallel_std_m_s2 : float
        White-noise standard error of |mean f| [m/s^2].
    accel_up_body : tuple of 3 float
        Unit vector of the at-rest specific force (-gravity direction) in body axes [-].
    accel_bias_body_m_s2 : tuple of 3 float
        ``accel_bias_parallel_m_s2 * accel_up_body``: the identifiable bias on the body axes [m/s^2]; the
        components perpendicular to ``accel_up_body`` are not identifiable from one orientation.
    accel_horizontal_residual_m_s2 : float
        Norm of the mean specific force perpendicular to ``accel_up_body`` [m/s^2]: horizontal bias plus attitude
        error, not separable; NaN without an attitude estimate.
    gravity : GravityReference
        The g used.
    attitude_source : str
        Where ``accel_up_body`` came from.
    """

    segment: Segment
    n_samples: int
    gyro_bias_rad_s: Vector3
    gyro_bias_std_rad_s: Vector3
    accel_bias_parallel_m_s2: float
    accel_bias_parallel_std_m_s2: float
    accel_up_body: Vector3
    accel_bias_body_m_s2: Vector3
    accel_horizontal_residual_m_s2: float
    gravity: GravityReference
    attitude_source: str


@dataclass(frozen=True)
class InflightBias:
    """Bias states of an in-flight filter, averaged after convergence.

    Attributes
    ----------
    source : str
        Which estimator produced them (e.g. "full_state_indirect").
    window_s : tuple of 2 float
        Averaging window on the log clock [s].
    gyro_bias_rad_s, gyro_bias_std_rad_s : tuple of 3 float
        Mean gyro bias state and RMS posterior standard deviation over the window [rad/s].
    accel_bias_m_s2, accel_bias_std_m_s2 : tuple of 3 float or None
        The same for the accelerometer bias states [m/s^2]; None when the filter has none.
    """

    source: str
    window_s: tuple[float, float]
    gyro_bias_rad_s: Vector3
    gyro_bias_std_rad_s: Vector3
    accel_bias_m_s2: Vector3 | None = None
    accel_bias_std_m_s2: Vector3 | None = None


def stationary_bias(log: FlightLog, segment: Segment, gravity: GravityReference = STANDARD_GRAVITY
                    ) -> StationaryBias:
    """Gyro bias and the along-gravity accelerometer bias over a stationary ``segment``.

    The gravity direction comes from ``onboard_attitude`` (the autopilot's estimate) when the log has it over the
    segment, else from the mean specific force itself (then the horizontal residual is undefined).

    Raises
    ------
    InputError
        When the segment holds fewer than 2 IMU samples.
    """
    imu = segment.select(log["imu"])
    if len(imu) < 2:
        raise InputError(f"stationary segment {segment.start_s:g} .. {segment.end_s:g} s holds {len(imu)} IMU "
                         "samples, need >= 2", source=log.meta.source, field="imu")
    gyro = imu[list(GYRO_COLUMNS)].to_numpy(dtype=float)
    accel = imu[list(ACCEL_COLUMNS)].to_numpy(dtype=float)
    n = len(imu)
    mean_f = accel.mean(axis=0)
    norm_f = float(np.linalg.norm(mean_f))
    # Standard error of |mean f| is that of the mean projected on its own direction.
    parallel_std = float(np.std(accel @ (mean_f / norm_f), ddof=1) / np.sqrt(n))

    attitude = segment.select(log["onboard_attitude"]) if log.has("onboard_attitude") else None
    if attitude is not None and len(attitude):
        r_nb = quat_to_matrix(attitude[["qw", "qx", "qy", "qz"]].to_numpy(dtype=float))
        # At rest f_b = R^T (0, 0, -g): the "up" direction in body axes is minus the third row of R_nb.
        up = -r_nb[:, 2, :].mean(axis=0)
        up /= np.linalg.norm(up)
        horizontal = float(np.linalg.norm(mean_f - (mean_f @ up) * up))
        attitude_source = f"onboard_attitude (mean of {len(attitude)} samples)"
    else:
        up = mean_f / norm_f
        horizontal = float("nan")
        attitude_source = "mean specific force (the log has no attitude estimate over the segment)"

    bias_parallel = norm_f - gravity.value_m_s2
    return StationaryBias(
        segment=segment, n_samples=n,
        gyro_bias_rad_s=_vec(gyro.mean(axis=0)),
        gyro_bias_std_rad_s=_vec(gyro.std(axis=0, ddof=1) / np.sqrt(n)),
        accel_bias_parallel_m_s2=bias_parallel, accel_bias_parallel_std_m_s2=parallel_std,
        accel_up_body=_vec(up), accel_bias_body_m_s2=_vec(bias_parallel * up),
        accel_horizontal_residual_m_s2=horizontal, gravity=gravity, attitude_source=attitude_source)


def summarize_bias_states(time_s: np.ndarray, gyro_bias_rad_s: np.ndarray, gyro_bias_std_rad_s: np.ndarray, *,
                          source: str, settle_s: float, accel_bias_m_s2: np.ndarray | None = None,
                          accel_bias_std_m_s2: np.ndarray | None = None) -> InflightBias:
    """Average filter bias states, shape (n, 3), over ``time_s`` [s] from ``time_s[0] + settle_s`` on.

    The reported standard deviation is the RMS of the posterior standard deviations over the window.

    Raises
    ------
    InputError
        When no sample is left after ``settle_s`` or the shapes disagree.
    """
    time_s = np.asarray(time_s, dtype=float)
    keep = time_s >= time_s[0] + settle_s if len(time_s) else np.zeros(0, dtype=bool)
    if not keep.any():
        raise InputError(f"no bias-state sample after the {settle_s:g} s convergence time", field=source)

    def average(values, stds, name):
        values, stds = np.asarray(values, dtype=float), np.asarray(stds, dtype=float)
        if values.shape != (len(time_s), 3) or stds.shape != values.shape:
            raise InputError(f"{name} and its std must have shape ({len(time_s)}, 3), got {values.shape} and "
                             f"{stds.shape}", field=source)
        return _vec(values[keep].mean(axis=0)), _vec(np.sqrt(np.mean(stds[keep] ** 2, axis=0)))

    gyro, gyro_std = average(gyro_bias_rad_s, gyro_bias_std_rad_s, "gyro bias")
    accel = accel_std = None
    if accel_bias_m_s2 is not None:
        accel, accel_std = average(accel_bias_m_s2, accel_bias_std_m_s2, "accelerometer bias")
    window = time_s[keep]
    return InflightBias(source=source, window_s=(float(window[0]), float(window[-1])), gyro_bias_rad_s=gyro,
                        gyro_bias_std_rad_s=gyro_std, accel_bias_m_s2=accel, accel_bias_std_m_s2=accel_std)


def _vec(values: np.ndarray) -> Vector3:
    return tuple(float(v) for v in values)
