"""Sensor calibration of a flight log: per sensor and axis eq 50 / sigma, biases, Allan figures, R and tau.

:func:`calibrate` is the one entry point; it returns a :class:`Calibration`, which ``calib.export`` writes as
CALIB.json. Noise convention (``docs/nomenclature.md``): every ``sigma`` is a per-sample standard deviation at the
stream's rate (``SensorCalibration.fir.fs_hz``); the density is sigma / sqrt(rate).

R (paper eq 51) is diag(noise^2) per sensor, with ``noise`` = sigma (default, docs/calibration.md, 'Penalty factor tau
(eq 52)') or eta (the paper's
literal choice); the accelerometer's body-y entry is multiplied by tau (eq 52). The gyroscope's "R" is the
covariance of the gyro INPUT (it enters the filters' Q through G), not a measurement covariance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from calib.allan import MIN_SAMPLES as ALLAN_MIN_SAMPLES
from calib.allan import AllanFigures, allan_deviation, allan_figures
from calib.bias import STANDARD_GRAVITY, GravityReference, InflightBias, StationaryBias, stationary_bias
from calib.figures import Figure, TuneResult
from calib.fir import MIN_NUMTAPS, FirSpec, default_cutoff_hz, default_numtaps, design_fir, min_samples
from calib.noise import noise_figures
from calib.segments import (
    ACCEL_COLUMNS,
    DEFAULT_STATIONARY,
    DEFAULT_STEADY,
    GYRO_COLUMNS,
    Segment,
    StationaryCriteria,
    SteadyCriteria,
    auto_segments,
    is_stationary,
)
from calib.tau import DEFAULT_TAU, TauSelection
from ingest.errors import InputError
from ingest.flightlog import FlightLog, stream_info
from ingest.geodesy import geodetic_to_ned
from ingest.threads import thread_map

NOISE_CHOICES = ("sigma", "eta")
#: GPS rows below this fix type (3 = 3D fix) carry no usable position.
MIN_GPS_FIX_TYPE = 3
#: Index of the body-y axis in the accelerometer's R (eq 52).
ACCEL_Y = 1


@dataclass(frozen=True)
class SensorChannels:
    """Where a sensor's channels live in the canonical FlightLog.

    Attributes
    ----------
    stream : str
        FlightLog stream name.
    columns : tuple of str
        Canonical columns read.
    axes : tuple of str
        Axis labels of the calibrated channels (GPS position: geodetic columns become north/east/down [m]).
    unit : str
        Unit of the calibrated channels.
    """

    stream: str
    columns: tuple[str, ...]
    axes: tuple[str, ...]
    unit: str


#: Every calibrated sensor, in report order.
SENSORS: dict[str, SensorChannels] = {
    "accelerometer": SensorChannels("imu", ACCEL_COLUMNS, ("x", "y", "z"), "m/s^2"),
    "gyroscope": SensorChannels("imu", GYRO_COLUMNS, ("x", "y", "z"), "rad/s"),
    "magnetometer": SensorChannels("mag", ("mag_x_gauss", "mag_y_gauss", "mag_z_gauss"), ("x", "y", "z"), "gauss"),
    "barometer": SensorChannels("baro", ("alt_m",), ("alt",), "m"),
    "airspeed": SensorChannels("airspeed", ("tas_m_s",), ("tas",), "m/s"),
    "gps_position": SensorChannels("gps", ("lat_deg", "lon_deg", "alt_m"), ("north", "east", "down"), "m"),
    "gps_velocity": SensorChannels("gps", ("vn_m_s", "ve_m_s", "vd_m_s"), ("north", "east", "down"), "m/s"),
}
IMU_SENSORS = ("accelerometer", "gyroscope")


@dataclass(frozen=True)
class FirSettings:
    """Requested filter for one sensor; None picks the rate-based default (docs/calibration.md, 'FIR filtering').

    Attributes
    ----------
    cutoff_hz : float or None
        -6 dB cutoff of one pass [Hz].
    numtaps : int or None
        Odd filter length. A default length is shortened to fit a short segment; a requested one is not.
    """

    cutoff_hz: float | None = None
    numtaps: int | None = None


@dataclass(frozen=True)
class SensorCalibration:
    """Noise figures of one sensor over its segment (units: ``unit``; tuples have one entry per axis).

    Attributes
    ----------
    sensor : str
        Key of :data:`SENSORS`.
    unit : str
        Unit of every figure below except ``n_*``.
    axes : tuple of str
        Axis labels.
    segment : Segment
        Window analysed.
    fir : FirSpec
        Filter used (its ``fs_hz`` is the stream's median rate in the segment).
    n_samples : int
        Samples in the segment.
    eta, beta : tuple of float
        Paper eq 50, literally.
    sigma, sigma_robust : tuple of float
        Residual standard deviation corrected by rho_h, and its MAD-based variant (per sample).
    mean : tuple of float
        Mean of the analysed samples.
    warnings : tuple of str
        Anything that weakens the figures (gaps, shortened filter).
    """

    sensor: str
    unit: str
    axes: tuple[str, ...]
    segment: Segment
    fir: FirSpec
    n_samples: int
    eta: tuple[float, ...]
    beta: tuple[float, ...]
    sigma: tuple[float, ...]
    sigma_robust: tuple[float, ...]
    mean: tuple[float, ...]
    warnings: tuple[str, ...] = ()

    def noise(self, choice: str) -> tuple[float, ...]:
        """Per-axis noise for R: ``"sigma"`` or ``"eta"``."""
        if choice not in NOISE_CHOICES:
            raise InputError(f"noise choice must be one of {NOISE_CHOICES}, got {choice!r}", field="noise")
        return self.sigma if choice == "sigma" else self.eta


@dataclass(frozen=True)
class Calibration:
    """Everything calibrated from one log (what CALIB.json holds).

    Attributes
    ----------
    source : str
        Log file name.
    sha256 : str
        Hex digest of the log file.
    vehicle_type : int or None
        MAV_TYPE of the log.
    noise : str
        ``"sigma"`` or ``"eta"``: which figure R is built from.
    sensors : dict of str -> SensorCalibration
        Per calibrated sensor (sensors the log lacks are absent).
    r : dict of str -> tuple of tuple of float
        Eq 51 matrix per sensor [unit^2], (k, k); the accelerometer's includes tau. Kept as given on load, so a
        hand-edited CALIB.json is honoured.
    tau : TauSelection
        Eq 52 penalty factor on the accelerometer's body-y variance.
    stationary_bias : StationaryBias or None
        Physically referenced biases, when a stationary segment was analysed.
    inflight_bias : InflightBias or None
        Filter bias states supplied by the caller.
    allan : dict of str -> tuple of AllanFigures
        Per IMU sensor and axis, from the stationary segment (empty without one).
    warnings : tuple of str
        Sensors skipped and why, and other caveats.
    figures : dict of str -> calib.figures.Figure
        The filter figures derived from the above, each with its source (:func:`calib.figures.filter_figures`;
        docs/calibration.md, 'From calibration to filter settings').
    tuning : dict of str -> calib.figures.TuneResult
        Per estimator, the noise identified from the flight's innovations (``solarnav calibrate --tune``; empty
        without it).
    """

    source: str
    sha256: str
    vehicle_type: int | None
    noise: str
    sensors: dict[str, SensorCalibration]
    r: dict[str, tuple[tuple[float, ...], ...]]
    tau: TauSelection
    stationary_bias: StationaryBias | None
    inflight_bias: InflightBias | None
    allan: dict[str, tuple[AllanFigures, ...]]
    warnings: tuple[str, ...] = ()
    figures: dict[str, Figure] = dataclasses.field(default_factory=dict)
    tuning: dict[str, TuneResult] = dataclasses.field(default_factory=dict)

    def r_matrix(self, sensor: str) -> np.ndarray:
        """Eq 51 matrix of ``sensor`` as an array [unit^2], shape (k, k)."""
        return np.array(self.r[sensor], dtype=float)


def calibrate(log: FlightLog, *, segment: Segment | None = None, fir: Mapping[str, FirSettings] | None = None,
              noise: str = "sigma", tau: TauSelection = DEFAULT_TAU, gravity: GravityReference = STANDARD_GRAVITY,
              inflight_bias: InflightBias | None = None,
              stationary_criteria: StationaryCriteria = DEFAULT_STATIONARY,
              steady_criteria: SteadyCriteria = DEFAULT_STEADY) -> Calibration:
    """Calibrate every sensor of ``log`` over ``segment`` (or automatically chosen segments).

    Parameters
    ----------
    log : FlightLog
        The flight.
    segment : Segment, optional
        One window for every sensor (see :func:`calib.segments.user_segment`); None: per sensor, the longest
        stationary segment holding enough of its samples, else the longest steady one.
    fir : mapping of sensor -> FirSettings, optional
        Filter requests per sensor; missing sensors use the defaults for their rate and the vehicle type.
    noise : {"sigma", "eta"}
        Figure R is built from.
    tau : TauSelection
        Eq 52 factor (see :mod:`calib.tau`).
    gravity : GravityReference
        g for the stationary accelerometer bias (local gravity is computed by the caller, which may use the
        estimators layer: calib never imports it).
    inflight_bias : InflightBias, optional
        Bias states of an in-flight filter to store beside the stationary ones.
    stationary_criteria, steady_criteria
        Thresholds of the automatic segment search.

    Raises
    ------
    InputError
        Without IMU data, without any usable segment, on a bad noise choice, or when a requested filter does not
        fit its sensor (cutoff above Nyquist, too many taps for the segment).
    """
    if noise not in NOISE_CHOICES:
        raise InputError(f"noise choice must be one of {NOISE_CHOICES}, got {noise!r}", field="noise")
    if not log.has("imu"):
        raise InputError("log has no IMU stream to calibrate", source=log.meta.source, field="imu")
    fir = dict(fir or {})
    unknown = sorted(set(fir) - set(SENSORS))
    if unknown:
        raise InputError(f"unknown sensor(s) {unknown} in the filter settings; known: {list(SENSORS)}", field="fir")

    if segment is None:
        candidates = auto_segments(log, stationary_criteria, steady_criteria)
        if not candidates:
            raise InputError("no stationary or steady segment found automatically; give a time window "
                             "(start and end on the log clock)", source=log.meta.source, field="segment")
        stationary = next((c for c in candidates if c.kind == "stationary"), None)
    else:
        candidates = [segment]
        stationary = segment if is_stationary(log, segment, stationary_criteria) else None

    warnings: list[str] = []
    sensors: dict[str, SensorCalibration] = {}
    names = [name for name, channels in SENSORS.items() if log.has(channels.stream)]
    # the filtering and the Allan sums release the GIL: a 1-hour log calibrates in 2.1 s instead of 2.9 s on 2 cores
    results = thread_map(lambda name: _calibrate_sensor(log, name, candidates, fir.get(name, FirSettings())), names)
    for name, result in zip(names, results, strict=True):
        if isinstance(result, str):
            warnings.append(result)
        else:
            sensors[name] = result
    if not any(name in sensors for name in IMU_SENSORS):
        raise InputError("; ".join(warnings) or "no IMU data in the segment", source=log.meta.source,
                         field="segment")

    bias = allan = None
    if stationary is not None:
        bias = stationary_bias(log, stationary, gravity)
        allan = _allan(log, stationary)
    else:
        warnings.append("no stationary segment: no physically referenced bias and no Allan deviation")
    return Calibration(source=log.meta.source, sha256=log.meta.sha256, vehicle_type=log.meta.vehicle_type,
                       noise=noise, sensors=sensors, r=r_matrices(sensors, noise, tau.tau), tau=tau,
                       stationary_bias=bias, inflight_bias=inflight_bias, allan=allan or {},
                       warnings=tuple(warnings))


def r_matrices(sensors: Mapping[str, SensorCalibration], noise: str, tau: float
               ) -> dict[str, tuple[tuple[float, ...], ...]]:
    """Eq 51 diag(noise^2) per sensor, with eq 52's tau on the accelerometer's body-y variance."""
    out = {}
    for name, cal in sensors.items():
        variances = np.square(cal.noise(noise))
        if name == "accelerometer":
            variances[ACCEL_Y] *= tau
        out[name] = tuple(tuple(float(v) for v in row) for row in np.diag(variances))
    return out


def with_tau(calibration: Calibration, tau: TauSelection) -> Calibration:
    """The same calibration with another tau (accelerometer R rebuilt from its noise figures)."""
    r = dict(calibration.r)
    if "accelerometer" in calibration.sensors:
        r.update(r_matrices({"accelerometer": calibration.sensors["accelerometer"]}, calibration.noise, tau.tau))
    return dataclasses.replace(calibration, tau=tau, r=r)


def sensor_samples(log: FlightLog, sensor: str, segment: Segment) -> tuple[np.ndarray, np.ndarray]:
    """Sample times [s], shape (n,), and channel values, shape (n, k), of ``sensor`` inside ``segment``.

    Times are the sensor's ``sample_time_s`` where logged and increasing, else the log time. Rows with a NaN
    channel are dropped, GPS rows below a 3D fix too; GPS position becomes local north, east,
    down [m] about the segment's first fix (ingest.geodesy.geodetic_to_ned).
    """
    channels = SENSORS[sensor]
    frame = segment.select(log[channels.stream])
    if sensor.startswith("gps") and "fix_type" in frame:
        frame = frame.loc[frame["fix_type"].to_numpy(dtype=float) >= MIN_GPS_FIX_TYPE]
    frame = frame.dropna(subset=list(channels.columns))
    values = frame[list(channels.columns)].to_numpy(dtype=float)
    if sensor == "gps_position" and len(values):
        lat, lon, alt = values.T
        values = np.column_stack(geodetic_to_ned(lat, lon, alt, lat[0], lon[0], alt[0]))
    time_s = frame.index.to_numpy(dtype=float)
    if "sample_time_s" in frame:
        # The sensor's own sample clock is regular where the logging time jitters (SITL publishes in bursts).
        sample_time_s = frame["sample_time_s"].to_numpy(dtype=float)
        if np.all(np.isfinite(sample_time_s)) and np.all(np.diff(sample_time_s) > 0):
            time_s = sample_time_s
    return time_s, values


def _calibrate_sensor(log: FlightLog, sensor: str, candidates: list[Segment], settings: FirSettings
                      ) -> SensorCalibration | str:
    """Calibration of one sensor on the first candidate segment with enough samples, or a warning why not.

    A segment too short for a requested number of taps is used anyway when no other fits, so that the filter
    raises a clear InputError instead of the sensor being skipped silently.
    """
    samples = [(segment, *sensor_samples(log, sensor, segment)) for segment in candidates]
    usable = [item for item in samples if len(item[1]) >= min_samples(MIN_NUMTAPS)]
    if not usable:
        return (f"{sensor}: skipped, no segment ({', '.join(_span(c, log) for c in candidates)}) holds enough samples "
                f"(need >= {min_samples(MIN_NUMTAPS)})")
    fitting = [item for item in usable if len(item[1]) >= min_samples(settings.numtaps or MIN_NUMTAPS)]
    segment, time_s, values = (fitting or usable)[0]

    notes = []
    info = stream_info(SENSORS[sensor].stream, time_s)
    if info.gaps:
        notes.append(f"{len(info.gaps)} gap(s) in the segment (longest {max(g for _, g in info.gaps):.2f} s): "
                     "the filter treats the samples as uniformly spaced")
    fs_hz = info.rate_hz
    cutoff_hz = settings.cutoff_hz or default_cutoff_hz(fs_hz, log.meta.is_fixed_wing)
    numtaps = settings.numtaps or default_numtaps(fs_hz, cutoff_hz)
    if settings.numtaps is None and len(time_s) < min_samples(numtaps):
        third = len(time_s) // 3
        shortened = third if third % 2 else third - 1
        notes.append(f"default filter shortened from {numtaps} to {shortened} taps to fit {len(time_s)} samples")
        numtaps = shortened
    spec = design_fir(fs_hz, cutoff_hz, numtaps)
    figures = noise_figures(values, spec)
    channels = SENSORS[sensor]
    if not all(f.sigma > 0 for f in figures):
        return f"{sensor}: skipped, constant over the segment {_span(segment, log)} (no noise to measure)"
    return SensorCalibration(
        sensor=sensor, unit=channels.unit, axes=channels.axes, segment=segment, fir=spec, n_samples=len(time_s),
        eta=tuple(f.eta for f in figures), beta=tuple(f.beta for f in figures),
        sigma=tuple(f.sigma for f in figures), sigma_robust=tuple(f.sigma_robust for f in figures),
        mean=tuple(f.mean for f in figures), warnings=tuple(notes))


def _span(segment: Segment, log: FlightLog) -> str:
    """The segment in seconds since the log start (the dashboard's axes) and on the log clock (the CLI's
    ``--segment``)."""
    start_s = log.meta.start_time_s
    return (f"{segment.start_s - start_s:.1f} .. {segment.end_s - start_s:.1f} s since log start (log clock "
            f"{segment.start_s:.3f} .. {segment.end_s:.3f} s)")


def _allan(log: FlightLog, segment: Segment) -> dict[str, tuple[AllanFigures, ...]]:
    """Allan figures of every IMU axis over the stationary segment (empty when it is too short)."""
    axes = []  # (sensor, samples of one axis, rate [Hz])
    for sensor in IMU_SENSORS:
        time_s, values = sensor_samples(log, sensor, segment)
        if len(time_s) >= ALLAN_MIN_SAMPLES:
            rate_hz = stream_info("imu", time_s).rate_hz
            axes += [(sensor, values[:, k], rate_hz) for k in range(values.shape[1])]
    figures = thread_map(lambda axis: allan_figures(allan_deviation(axis[1], axis[2])), axes)
    out: dict[str, tuple[AllanFigures, ...]] = {}
    for (sensor, _, _), figure in zip(axes, figures, strict=True):
        out[sensor] = (*out.get(sensor, ()), figure)
    return out


def allan_curves(log: FlightLog, calibration: Calibration) -> dict[str, list[pd.DataFrame]]:
    """Allan deviation curves behind ``calibration.allan`` for display: sensor -> per axis DataFrame with
    columns ``tau_s``, ``adev``, ``adev_err`` (empty without a stationary segment)."""
    if calibration.stationary_bias is None:
        return {}
    segment = calibration.stationary_bias.segment
    out = {}
    for sensor in calibration.allan:
        time_s, values = sensor_samples(log, sensor, segment)
        rate_hz = stream_info("imu", time_s).rate_hz
        curves = [allan_deviation(values[:, k], rate_hz) for k in range(values.shape[1])]
        out[sensor] = [pd.DataFrame({"tau_s": c.taus_s, "adev": c.adev, "adev_err": c.adev_err}) for c in curves]
    return out
