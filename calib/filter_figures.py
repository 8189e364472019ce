"""The filter figures a calibration yields, each with its source (docs/calibration.md, 'From calibration to filter
settings').

What each measured number means decides what it may become:

* an in-flight eq 50 residual holds, besides the sensor's noise, real motion above the FIR cutoff, vibration and
  turbulence: an upper bound of the sensor noise (source :data:`~calib.figures.SOURCE_INFLIGHT_BOUND` for the IMU,
  :data:`~calib.figures.SOURCE_INFLIGHT` for the measurements, whose model error the estimator layer adds);
* a still segment's residual and the Allan white-noise density are the sensor's own noise, without vibration;
* GPS position noise never comes from short-term residuals (its error is correlated over minutes): the filters
  weight GPS by the receiver's accuracy fields, so no figure is derived here;
* the Allan rate random walk is the bias walk; the still-segment and in-flight biases are biases.

How the estimators combine these figures with their model error is :func:`estimators.config.config_from_figures`.
"""

from __future__ import annotations

import math

import numpy as np

from calib.calibration import Calibration
from calib.figures import (
    FIGURES,
    MAX_ACCEL_BIAS_STD_M_S2,
    MAX_GYRO_BIAS_STD_RAD_S,
    SOURCE_ALLAN,
    SOURCE_INFLIGHT,
    SOURCE_INFLIGHT_BIAS,
    SOURCE_INFLIGHT_BOUND,
    SOURCE_R,
    SOURCE_STILL,
    SOURCE_STILL_BIAS,
    SOURCE_TAU,
    Figure,
    rms,
)

#: Segment kinds whose residual is the sensor's own noise.
STILL_KINDS = ("stationary",)


def calibration_figures(cal: Calibration) -> dict[str, Figure]:
    """The filter figures of ``cal``: ``cal.figures`` when it has them (a CALIB.json with a ``figures`` section,
    hand edits honoured), else derived from the measured figures as the module docstring says."""
    if cal.figures:
        return dict(cal.figures)
    figures: dict[str, Figure] = {}
    for name, sensor in ((FIGURES.gyro_noise_density.name, "gyroscope"),
                         (FIGURES.accel_noise_density.name, "accelerometer")):
        figure = _imu_density(cal, name, sensor)
        if figure is not None:
            figures[name] = figure
    accel_axes = _accel_axis_density(cal)
    if accel_axes is not None:
        figures[accel_axes.name] = accel_axes
    for name, sensor in ((FIGURES.gyro_bias_walk.name, "gyroscope"), (FIGURES.accel_bias_walk.name, "accelerometer")):
        walks = [f.rate_random_walk for f in cal.allan.get(sensor, ()) if math.isfinite(f.rate_random_walk)]
        if walks:
            figures[name] = Figure(name, rms(walks), SOURCE_ALLAN, note=f"Allan rate random walk, RMS of the "
                                                                        f"{len(walks)} axes with a +1/2 slope")
    figures.update(_biases(cal))
    tau = FIGURES.accel_tau.name
    figures[tau] = Figure(tau, cal.tau.tau, SOURCE_TAU, note=f"chosen by: {cal.tau.method}")
    for name, sensor in ((FIGURES.baro_noise.name, "barometer"), (FIGURES.airspeed_noise.name, "airspeed")):
        sigma = _r_sigma(cal, sensor)
        # at rest the airspeed is rectified pressure noise (the speed error scales with 1 / (rho V)): meaningless
        # for the filters, which fuse airspeed only in flight
        if sensor == "airspeed" and sensor in cal.sensors and cal.sensors[sensor].segment.kind in STILL_KINDS:
            continue
        if sigma is not None:
            figures[name] = Figure(name, sigma, _measurement_source(cal, sensor), note=SOURCE_R)
    if "magnetometer" in cal.sensors and "magnetometer" in cal.r:
        diagonal = np.diag(cal.r_matrix("magnetometer"))
        if np.all(np.isfinite(diagonal)) and np.all(diagonal > 0):
            axes = tuple(float(v) for v in np.sqrt(diagonal))
            mag = FIGURES.mag_noise.name
            figures[mag] = Figure(mag, rms(axes), _measurement_source(cal, "magnetometer"), axes=axes, note=SOURCE_R)
            strength = float(np.linalg.norm(cal.sensors["magnetometer"].mean))
            if strength > 0:
                name = FIGURES.mag_field_strength.name
                figures[name] = Figure(name, strength, _measurement_source(cal, "magnetometer"),
                                       note="|mean field| over the segment")
    if "gps_velocity" in cal.sensors:
        sensor = cal.sensors["gps_velocity"]
        horizontal = [s for s in sensor.sigma[:2] if math.isfinite(s) and s > 0]
        if horizontal:
            name = FIGURES.gps_vel_noise.name
            figures[name] = Figure(name, rms(horizontal), _measurement_source(cal, "gps_velocity"),
                                   note="used only when the receiver reports no speed accuracy")
    return figures


def _imu_density(cal: Calibration, name: str, sensor: str) -> Figure | None:
    """White-noise density of an IMU sensor: Allan (still) > still residual > in-flight residual (upper bound)."""
    allan = [f.white_density for f in cal.allan.get(sensor, ()) if math.isfinite(f.white_density)]
    if len(allan) == 3:
        return Figure(name, rms(allan), SOURCE_ALLAN, axes=tuple(allan), note="Allan white-noise density")
    if sensor not in cal.sensors:
        return None
    s = cal.sensors[sensor]
    axes = tuple(sigma / math.sqrt(s.fir.fs_hz) for sigma in s.sigma)
    if s.segment.kind in STILL_KINDS:
        return Figure(name, rms(axes), SOURCE_STILL, axes=axes,
                      note=f"sigma / sqrt({s.fir.fs_hz:.1f} Hz) over {s.segment.start_s:.1f}..{s.segment.end_s:.1f} s")
    return Figure(name, rms(axes), SOURCE_INFLIGHT_BOUND, axes=axes,
                  note=f"sigma / sqrt({s.fir.fs_hz:.1f} Hz) over the {s.segment.kind} segment "
                       f"{s.segment.start_s:.1f}..{s.segment.end_s:.1f} s: holds motion above the "
                       f"{s.fir.cutoff_hz:g} Hz cutoff and vibration")


def _accel_axis_density(cal: Calibration) -> Figure | None:
    """Per-axis accelerometer density from the noise figures R is built from (eq 51, the calibration's noise
    choice): tau is a figure of its own (``accel_tau``), so editing it in CALIB.json changes the stage-1 y weight."""
    if "accelerometer" not in cal.sensors:
        return None
    sensor = cal.sensors["accelerometer"]
    noise = np.asarray(sensor.noise(cal.noise), dtype=float)
    if not (len(noise) == 3 and np.all(np.isfinite(noise)) and np.all(noise > 0)):
        return None
    axes = tuple(float(v) for v in noise / np.sqrt(sensor.fir.fs_hz))
    return Figure(FIGURES.accel_axis_noise_density.name, rms(axes), _measurement_source(cal, "accelerometer"),
                  axes=axes, note=f"{cal.noise} per axis / sqrt({sensor.fir.fs_hz:.1f} Hz) (eq 51 without tau)")


def _biases(cal: Calibration) -> dict[str, Figure]:
    """Gyro and accelerometer biases: the in-flight filter estimate where present, else the still segment's."""
    out = {}
    gyro, accel = FIGURES.gyro_bias.name, FIGURES.accel_bias.name
    flight, still = cal.inflight_bias, cal.stationary_bias
    if flight is not None and not (_converged(flight.gyro_bias_std_rad_s, MAX_GYRO_BIAS_STD_RAD_S)
                                   and _converged(flight.accel_bias_std_m_s2, MAX_ACCEL_BIAS_STD_M_S2)):
        flight = None  # an estimate that has not converged (short flight, few turns) is no calibration
    if flight is not None:
        out[gyro] = Figure(gyro, rms(flight.gyro_bias_rad_s), SOURCE_INFLIGHT_BIAS, axes=tuple(flight.gyro_bias_rad_s),
                           note=f"{flight.source} bias states over {flight.window_s[0]:.0f}.."
                                f"{flight.window_s[1]:.0f} s")
        if flight.accel_bias_m_s2 is not None:
            out[accel] = Figure(accel, rms(flight.accel_bias_m_s2), SOURCE_INFLIGHT_BIAS,
                                axes=tuple(flight.accel_bias_m_s2), note=f"{flight.source} bias states")
    if still is not None:
        if gyro not in out:
            out[gyro] = Figure(gyro, rms(still.gyro_bias_rad_s), SOURCE_STILL_BIAS, axes=tuple(still.gyro_bias_rad_s),
                               note="mean rate over the still segment")
        if accel not in out and all(math.isfinite(v) for v in still.accel_bias_body_m_s2):
            out[accel] = Figure(accel, rms(still.accel_bias_body_m_s2), SOURCE_STILL_BIAS,
                                axes=tuple(still.accel_bias_body_m_s2),
                                note="component along gravity only (one orientation); the horizontal components "
                                     "are not identifiable from it")
    return out


def _converged(std, limit: float) -> bool:
    return std is not None and all(math.isfinite(v) and v <= limit for v in std)


def _measurement_source(cal: Calibration, sensor: str) -> str:
    return SOURCE_STILL if cal.sensors[sensor].segment.kind in STILL_KINDS else SOURCE_INFLIGHT


def _r_sigma(cal: Calibration, sensor: str) -> float | None:
    if sensor not in cal.r or sensor not in cal.sensors:
        return None
    diagonal = [v for v in np.diag(cal.r_matrix(sensor)) if math.isfinite(v) and v > 0]
    return math.sqrt(sum(diagonal) / len(diagonal)) if diagonal else None
