"""Noise, gating, initialisation and timing settings shared by the three estimators.

One frozen :class:`EstimatorConfig` holds everything a replay needs besides the log; the kernels receive plain
floats and arrays taken from it (never the object). Every default below is documented with where it comes from:
the paper's Table 1 (sensor grades), Table 4 / eq. 51 (in-flight IMU noise), the docs (docs/estimators.md,
docs/calibration.md)
or PX4 EKF2's defaults where the paper gives nothing.

Noise convention (docs/estimators.md, 'Process noise and random walks', option i): IMU noise is given as a white-noise
DENSITY (per sqrt(Hz)) so that the
same numbers hold at any IMU rate; a per-sample standard deviation ``sigma`` at rate ``f_s`` relates to it by
``density = sigma / sqrt(f_s)``. Bias and wind random walks are densities too (per sqrt(s)): the discrete
variance added over ``dt`` is ``density**2 * dt``. Measurement noises are per-sample standard deviations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

from calib.figures import (
    FIGURES,
    RULE_AXES,
    RULE_AXES_PER_STRENGTH,
    RULE_FACTOR,
    RULE_NOISE,
    RULE_NOISE_PER_STRENGTH,
    RULE_NORMALISER,
    RULE_VALUE,
    SOURCE_TUNED,
    SOURCE_USER,
    FigureSetting,
)
from ingest.errors import InputError

#: Default EKF2_GPS_DELAY of PX4 [ms], used when a log has no such parameter.
PX4_DEFAULT_GPS_DELAY_MS = 110.0


@dataclass(frozen=True)
class NoiseConfig:
    """Sensor and process noise.

    Attributes
    ----------
    gyro_noise_rad_s_sqrt_hz : float
        Gyro white-noise density N_g [rad/s/sqrt(Hz)]. Default 2.0e-3: the MPU6050 static density (Table 1 row
        "0.05 deg/s-rms", about 0.005 deg/s/sqrt(Hz) = 8.7e-5 rad/s/sqrt(Hz)) is a lower bound; in flight,
        vibration dominates (Table 4: 4-6 deg/s per sample at 50 Hz, which docs/calibration.md, 'Noise and bias (eq 50)'
        judges overstated
        by about 10x in variance, i.e. ~1.6 deg/s at 50 Hz = 4e-3 rad/s/sqrt(Hz)). 2e-3 sits between that and
        PX4 EKF2's EKF2_GYR_NOISE (0.015 rad/s per 100 Hz sample = 1.5e-3).
    accel_noise_m_s2_sqrt_hz : float
        Accelerometer white-noise density N_a [m/s^2/sqrt(Hz)]. Default 0.035: Table 4 / eq. 51 in-flight
        per-sample values 0.02-0.25 m/s^2 at 50 Hz (0.003-0.035 per sqrt(Hz)); PX4 EKF2_ACC_NOISE 0.35 m/s^2 per
        100 Hz sample = 0.035. The larger value also covers vibration on multicopters.
    gyro_bias_rw_rad_s2_sqrt_hz : float
        Gyro bias random walk K_g [rad/s^2/sqrt(Hz)] (process sigma of the bias states). Default 1e-4 (PX4
        EKF2_GYR_B_NOISE 1e-3 rad/s^2 is tuned for temperature drift of a 100 Hz filter; the paper's controller is
        at constant 25 degC, so a 10x smaller walk).
    accel_bias_rw_m_s3_sqrt_hz : float
        Accelerometer bias random walk K_a [m/s^3/sqrt(Hz)]. Default 1e-3 (PX4 EKF2_ACC_B_NOISE 3e-3 / 3, same
        reasoning).
    accel_bias_rw_z_m_s3_sqrt_hz : float or None
        Random walk of the body-z accelerometer bias when it differs from x/y (None: the same). The effective z
        bias of a fixed-wing changes with every pitch transition through the cross-axis sensitivity (Table 1:
        +-2 % of the forward specific force, which changes by a few m/s^2 between climb, cruise and descent),
        while x and y see the nearly constant -g through theirs.
    accel_cross_axis_rw_sqrt_s : float
        Random walk of the z accelerometer's cross-axis sensitivities (``accel_cross_axis_states``) [1/sqrt(s)].
        Default 1e-5: a constant of the sensor (a walk this slow only keeps the estimate from freezing).
    wind_rw_m_s_sqrt_s : float
        Wind random walk [m/s/sqrt(s)]. Default 0.05 (docs/three_stage.md, 'Stage 3: navigation and wind': (0.01-0.1
        m/s)^2/s; PX4 EKF2_WIND_NSD 0.05).
    mag_bias_rw_sqrt_s : float
        Magnetometer hard-iron bias random walk [field units/sqrt(s)] (the magnetometer is used normalised by the
        earth-field strength, so biases are fractions of it). Default 1e-4 (PX4 EKF2_MAG_B_NOISE 1e-4 gauss/s
        over a ~0.5 gauss field, per sqrt(s)).
    baro_bias_rw_m_sqrt_s : float
        Barometer bias (offset to GPS height) random walk [m/sqrt(s)]. Default 0.01 (weather/temperature drift).
    baro_sigma_m : float
        Barometric altitude noise [m]. Default 0.5 (Table 1: MS5611 resolution ~0.1 m, accuracy +/-1.5 mbar is a
        slow offset handled by the bias state; PX4 EKF2_BARO_NOISE 3.5 m is for prop-wash, too loose here).
    airspeed_sigma_m_s : float
        True-airspeed noise [m/s]. Default 0.5 (Table 1: MPXV7002 +/-2.5 % of 2 kPa over 96 Pa dynamic pressure
        at 12.5 m/s is far larger as an offset; as white noise PX4 EKF2_EAS_NOISE 1.4 m/s; the paper's airspeed
        error 0.5-0.8 m/s).
    sideslip_sigma_m_s : float
        Zero-sideslip pseudo-measurement noise on the body-y air velocity [m/s] (docs/direct.md, 'Measurement models':
        0.5-1 m/s).
        Without wind states it is inflated to ``sideslip_no_wind_sigma_m_s``.
    sideslip_no_wind_sigma_m_s : float
        Sideslip pseudo noise when no wind is estimated (docs/estimators.md, 'Sensor plan': 2 m/s).
    gps_pos_sigma_floor_m : float
        Floor of the per-axis GPS horizontal position sigma [m] (docs/three_stage.md, 'Stage 3: navigation and wind':
        0.5 m).
    gps_hgt_sigma_floor_m : float
        Floor of the GPS height sigma [m].
    gps_pos_eph_scale : float
        Per-axis horizontal sigma = ``gps_pos_eph_scale * eph`` (eph is a horizontal radial accuracy;
        docs/three_stage.md, 'Stage 3: navigation and wind': eph / sqrt(2)), floored at ``gps_pos_sigma_floor_m``.
    gps_hgt_epv_scale : float
        Vertical sigma = ``gps_hgt_epv_scale * epv``, floored at ``gps_hgt_sigma_floor_m``.
    gps_vel_sigma_floor_m_s : float
        Floor of the GPS velocity sigma [m/s] (docs/three_stage.md, 'Stage 3: navigation and wind': 0.1 m/s).
    gps_vel_sigma_default_m_s : float
        GPS velocity sigma when the receiver reports no speed accuracy [m/s] (PX4 EKF2_GPS_V_NOIS 0.3... 0.5).
    gps_vel_accuracy_scale : float
        Factor on the GPS velocity sigma (receiver accuracy or the default, floored) [-]; 1: as reported.
    mag_sigma : float
        Magnetometer noise per axis in units of the field strength (docs/three_stage.md, 'Stage 2: heading': 0.02-0.05
        for unit vectors).
    mag_sigma_axes : tuple of 3 float or None
        Per-axis magnetometer noise (body x, y, z) in units of the field strength; None: ``mag_sigma`` on every
        axis.
    sun_sigma_rad : float
        Sun-vector direction noise per tangent axis [rad] (docs/sun.md, 'Quality': a few tenths of a degree to 1 deg).
    zero_velocity_sigma_m_s : float
        Noise of the zero-NED-velocity pseudo-measurement used only when a log has no GPS (docs/estimators.md, 'Sensor
        plan': keeps
        tilt observable, like PX4 EKF2's fake-position fusion) [m/s].
    """

    gyro_noise_rad_s_sqrt_hz: float = 2.0e-3
    accel_noise_m_s2_sqrt_hz: float = 0.035
    gyro_bias_rw_rad_s2_sqrt_hz: float = 1.0e-4
    accel_bias_rw_m_s3_sqrt_hz: float = 1.0e-3
    accel_bias_rw_z_m_s3_sqrt_hz: float | None = None
    accel_cross_axis_rw_sqrt_s: float = 1.0e-5
    wind_rw_m_s_sqrt_s: float = 0.05
    mag_bias_rw_sqrt_s: float = 1.0e-4
    baro_bias_rw_m_sqrt_s: float = 0.01
    baro_sigma_m: float = 0.5
    airspeed_sigma_m_s: float = 0.5
    sideslip_sigma_m_s: float = 0.7
    sideslip_no_wind_sigma_m_s: float = 2.0
    gps_pos_sigma_floor_m: float = 0.5
    gps_hgt_sigma_floor_m: float = 0.7
    gps_pos_eph_scale: float = 1.0 / math.sqrt(2.0)
    gps_hgt_epv_scale: float = 1.0
    gps_vel_sigma_floor_m_s: float = 0.1
    gps_vel_sigma_default_m_s: float = 0.3
    gps_vel_accuracy_scale: float = 1.0
    mag_sigma: float = 0.03
    mag_sigma_axes: tuple[float, float, float] | None = None
    sun_sigma_rad: float = math.radians(0.5)
    zero_velocity_sigma_m_s: float = 1.0


@dataclass(frozen=True)
class GateConfig:
    """Chi-square gates per sensor: a scalar update is rejected when ``|nu| / sqrt(S) > gate``.

    docs/estimators.md, 'GPS re-acquisition': gamma = 3..5 sigma, configurable per sensor. Pseudo-measurements
    (sideslip, zero velocity)
    are never gated. ``math.inf`` disables a gate.

    Attributes
    ----------
    baro, airspeed, gps_pos, gps_vel, mag, sun : float
        Gate in innovation standard deviations [-].
    """

    baro: float = 5.0
    airspeed: float = 5.0
    gps_pos: float = 5.0
    gps_vel: float = 5.0
    mag: float = 5.0
    sun: float = 5.0


@dataclass(frozen=True)
class InitialSigmas:
    """Initial 1-sigma uncertainties (docs/estimators.md, 'Initial alignment').

    Attributes
    ----------
    position_m : float
        Horizontal/vertical position [m] (the GPS eph is used when larger).
    velocity_m_s : float
        Velocity [m/s].
    roll_pitch_deg : float
        Roll and pitch [deg].
    yaw_deg : float
        Yaw with an absolute heading source [deg].
    yaw_unaided_deg : float
        Yaw without any absolute heading source (magnetometer, sun, onboard attitude) [deg].
    gyro_bias_deg_s : float
        Gyro bias [deg/s].
    accel_bias_m_s2 : float
        Accelerometer bias [m/s^2].
    accel_cross_axis : float
        Cross-axis sensitivity of the z accelerometer to x and y [-] (Table 1, MPU6050: +-2 %).
    wind_m_s : float
        Wind (north, east) [m/s].
    mag_bias : float
        Magnetometer hard-iron bias [field units].
    baro_bias_m : float
        Barometer bias relative to GPS height [m].
    """

    position_m: float = 3.0
    velocity_m_s: float = 0.5
    roll_pitch_deg: float = 2.0
    yaw_deg: float = 10.0
    yaw_unaided_deg: float = 30.0
    gyro_bias_deg_s: float = 0.5
    accel_bias_m_s2: float = 0.2
    accel_cross_axis: float = 0.02
    wind_m_s: float = 3.0
    mag_bias: float = 0.1
    baro_bias_m: float = 2.0


@dataclass(frozen=True)
class TimingConfig:
    """Sensor timing and rates (docs/estimators.md, 'Inputs'; docs/estimators.md, 'Scheduling rule'; docs/estimators.md,
    'GPS re-acquisition'; docs/three_stage.md, 'Stage 3: navigation and wind').

    Attributes
    ----------
    gps_delay_s : float or None
        GPS measurement latency [s] subtracted from the GPS sample time. None: the log's ``EKF2_GPS_DELAY``
        parameter [ms], else :data:`PX4_DEFAULT_GPS_DELAY_MS`.
    covariance_rate_hz : float
        Rate at which the covariance is propagated (the state is integrated at the IMU rate; PX4 EKF2 also
        predicts covariance at ~100 Hz). The covariance is also brought up to date before every update.
    pseudo_rate_hz : float
        Rate of pseudo-measurements (zero sideslip, zero velocity) [Hz] (docs/three_stage.md, 'Stage 3: navigation and
        wind'; docs/three_stage.md, 'Corrections to the paper': a fixed rate such
        as the GPS rate, never every IMU step).
    max_imu_gap_factor : float
        An IMU interval longer than this many median periods is a gap (docs/estimators.md, 'Scheduling rule': 5).
    still_window_s : float
        Minimum length of the stationary window used for initial alignment [s] (docs/estimators.md, 'Initial alignment':
        >= 2 s).
    still_gyro_rad_s : float
        Stationary when ``|gyro| <`` this [rad/s] (docs/estimators.md, 'Initial alignment': 0.05).
    still_accel_m_s2 : float
        Stationary when ``| |accel| - g | <`` this [m/s^2] (docs/estimators.md, 'Initial alignment': 0.2).
    gps_reset_after_s : float
        T_rej: a GPS position or velocity component rejected continuously this long -> position and velocity
        reset to the GPS (docs/estimators.md, 'GPS re-acquisition': 5 s) [s].
    gps_outage_reset_s : float
        T_out: GPS back after an outage longer than this -> position and velocity reset to the GPS
        (docs/estimators.md, 'GPS re-acquisition': 10 s) [s].
    min_airspeed_m_s : float
        Airspeed samples below this are not fused (on the ground, before launch) [m/s].
    min_ground_speed_m_s : float
        V_min of docs/estimators.md, 'Sensor plan' for course updates [m/s].
    """

    gps_delay_s: float | None = None
    covariance_rate_hz: float = 100.0
    pseudo_rate_hz: float = 10.0
    max_imu_gap_factor: float = 5.0
    still_window_s: float = 2.0
    still_gyro_rad_s: float = 0.05
    still_accel_m_s2: float = 0.2
    gps_reset_after_s: float = 5.0
    gps_outage_reset_s: float = 10.0
    min_airspeed_m_s: float = 5.0
    min_ground_speed_m_s: float = 3.0


@dataclass(frozen=True)
class CalibratedInputs:
    """Calibrated figures that are not noise densities: biases applied to the three-stage estimator's inputs (it
    has no bias states) and its stage-1 accelerometer weighting (docs/calibration.md, 'From calibration to filter
    settings').

    Attributes
    ----------
    gyro_bias_rad_s : tuple of 3 float or None
        Gyro bias subtracted from the three-stage estimator's rates [rad/s, body FRD]; None: the bias of its own
        still-window alignment.
    accel_bias_m_s2 : tuple of 3 float or None
        Accelerometer bias subtracted from the three-stage estimator's specific force [m/s^2, body FRD].
    accel_tau : float
        Eq 52 penalty factor on the stage-1 body-y accelerometer variance [-].
    accel_axis_density : tuple of 3 float or None
        Per-axis accelerometer density for the stage-1 R (eq 51) [m/s^2/sqrt(Hz)]; None: the isotropic
        ``noise.accel_noise_m_s2_sqrt_hz``.
    accel_stage1_floor_m_s2 : float or None
        Model-error floor of the stage-1 accelerometer sigma at its update rate [m/s^2]; None: the estimator's
        default.
    provenance : tuple of (str, str, str)
        ``(figure, source, how it was used)`` for every calibrated figure behind this configuration (empty for
        the defaults); each run's report lists them with what the estimator did with each.
    """

    gyro_bias_rad_s: tuple[float, float, float] | None = None
    accel_bias_m_s2: tuple[float, float, float] | None = None
    accel_tau: float = 1.0
    accel_axis_density: tuple[float, float, float] | None = None
    accel_stage1_floor_m_s2: float | None = None
    provenance: tuple[tuple[str, str, str], ...] = ()


@dataclass(frozen=True)
class EstimatorConfig:
    """Everything an estimator run needs besides the log.

    Attributes
    ----------
    noise : NoiseConfig
    gates : GateConfig
    initial : InitialSigmas
    timing : TimingConfig
    accel_bias_states : bool
        Estimate accelerometer biases (docs/direct.md, 'State vector': on for real logs; off reproduces the paper's 14
        states).
    accel_cross_axis_states : bool
        Estimate the z accelerometer's cross-axis sensitivity to the x (and, off fixed-wing, y) specific force
        (the error-state filter only, and only with GPS like the accelerometer bias).
    mag_bias_states : bool
        Estimate magnetometer hard-iron biases when a magnetometer is fused.
    baro_bias_state : bool
        Estimate the barometer offset against GPS height when both are present.
    gps_velocity_mode : str
        ``"ned"`` (default, docs/direct.md, 'Measurement models') or ``"paper"`` (ground speed and course, eqs 42-43
        corrected).
    mag_fusion : str
        How the full-state filters fuse the magnetometer (docs/estimators.md, 'Magnetometer heading fusion'):
        ``"vector"`` (its three axes), ``"heading"`` (the heading of the tilt-compensated field, PX4 EKF2's heading
        fusion: the magnetometer corrects yaw and its bias, never roll and pitch, which a field disturbed by panel or
        motor currents would pull) or ``"auto"`` (default: the heading when the log's field strength spreads by more
        than ``estimators.inputs.build.MAG_HEADING_SPREAD``, else the vector).
    calibrated : CalibratedInputs
        Biases, eq 52 tau and stage-1 weighting from a calibration (defaults: none).
    """

    noise: NoiseConfig = field(default_factory=NoiseConfig)
    gates: GateConfig = field(default_factory=GateConfig)
    initial: InitialSigmas = field(default_factory=InitialSigmas)
    timing: TimingConfig = field(default_factory=TimingConfig)
    accel_bias_states: bool = True
    accel_cross_axis_states: bool = True
    mag_bias_states: bool = True
    baro_bias_state: bool = True
    gps_velocity_mode: str = "ned"
    mag_fusion: str = "auto"
    calibrated: CalibratedInputs = field(default_factory=CalibratedInputs)

    def __post_init__(self):
        validate_config(self)

    def with_noise(self, **changes) -> EstimatorConfig:
        """A copy with some :class:`NoiseConfig` fields replaced."""
        return replace(self, noise=replace(self.noise, **changes))


def config_from_calibration(calibration, base: EstimatorConfig | None = None, *,
                            estimator: str | None = None) -> EstimatorConfig:
    """Settings from a :class:`calib.calibration.Calibration` (CALIB.json), other settings from ``base``.

    The figures are ``calibration.tuning[estimator].figures`` when ``solarnav calibrate --tune`` identified noise
    for ``estimator``, else the calibration's figures (:func:`calib.filter_figures.calibration_figures`); they are
    mapped by :func:`config_from_figures`.
    """
    from calib.filter_figures import calibration_figures  # deferred: the calibration stack is slow to import

    tuned = calibration.tuning.get(estimator) if estimator is not None else None
    figures = tuned.figures if tuned is not None else calibration_figures(calibration)
    return config_from_figures(figures, base)


#: Figures taken as they are (identified as a whole filter setting, or set by the user).
_TOTAL_SOURCES = (SOURCE_TUNED, SOURCE_USER)


def config_from_figures(figures, base: EstimatorConfig | None = None) -> EstimatorConfig:
    """Settings from filter figures (``{name: calib.figures.Figure}``), other settings from ``base``.

    Which setting each figure feeds, and by which rule, is its row of :data:`calib.figures.FIGURES`
    (docs/calibration.md, 'From calibration to filter settings'):

    * a MEASURED noise figure (still segment, Allan, in-flight residual) is the sensor's noise; the filter also
      needs its model error (scale factors, misalignment, vibration, pitot and static-port errors, unmodelled
      dynamics), which the default of ``base`` stands for: the setting is ``sqrt(default^2 + measured^2)``, never
      below the default. A noisier sensor than the default assumes raises the setting; a quiet one does not make
      the filter trust a model it cannot trust.
    * a TUNED or USER figure (source ``tuned (innovation likelihood)`` or ``user``) is a whole filter setting and
      is used as it is.
    * the magnetometer figures [gauss] are divided by the field strength (the filters fuse the field in units of
      its strength), per axis; the GPS scales multiply the receiver-accuracy factors and floors.
    * biases, eq 52 tau and the per-axis stage-1 density go to :class:`CalibratedInputs` (the three-stage
      estimator, which has no bias states).

    Every figure's source and use is recorded in ``config.calibrated.provenance``.
    """
    config = EstimatorConfig() if base is None else base
    noise, changes, calibrated, provenance = config.noise, {}, {}, []
    normaliser = FIGURES.mag_field_strength
    strength = figures[normaliser.name].value if normaliser.name in figures else math.nan

    def setting(value, source, default):
        if source in _TOTAL_SOURCES:
            return value, "as is"
        return math.hypot(default, value), f"sqrt(default {default:.4g}^2 + measured^2)"

    for name, figure in figures.items():
        if not math.isfinite(figure.value):
            provenance.append((name, figure.source, "ignored: not a finite number"))
            continue
        spec = FIGURES[name].setting if name in FIGURES else None
        rule = spec.rule if spec is not None else None
        if rule in (RULE_NOISE, RULE_NOISE_PER_STRENGTH):
            if rule == RULE_NOISE_PER_STRENGTH and not strength > 0:
                continue  # no provenance line, unlike the per-axis rule: every configuration stays as it was
            measured = figure.value / strength if rule == RULE_NOISE_PER_STRENGTH else figure.value
            value, how = setting(measured, figure.source, noise_default(noise, spec))
            changes[spec.fields[0]] = value
            provenance.append((name, figure.source, f"noise.{spec.fields[0]} = {value:.4g} ({how})"))
        elif rule == RULE_AXES_PER_STRENGTH:
            if not strength > 0:
                provenance.append((name, figure.source, "ignored: no field strength to normalise by"))
                continue
            axes = figure.axes or (figure.value,) * 3
            values = tuple(setting(a / strength, figure.source, noise_default(noise, spec))[0] for a in axes)
            changes[spec.fields[0]] = values
            provenance.append((name, figure.source, f"noise.{spec.fields[0]} = ("
                               + ", ".join(f"{v:.4g}" for v in values)
                               + f") field units (/ {strength:.4g} {normaliser.unit}, "
                               + ("as is)" if figure.source in _TOTAL_SOURCES else "root-sum-squared with the "
                                                                                   "default)")))
        elif rule == RULE_FACTOR:
            for field_name in spec.fields:
                changes[field_name] = getattr(noise, field_name) * figure.value
            provenance.append((name, figure.source, f"{' and '.join(spec.fields)} x {figure.value:.4g}"))
        elif rule == RULE_VALUE:
            calibrated[spec.fields[0]] = figure.value
            provenance.append((name, figure.source, spec.use.format(value=figure.value)))
        elif rule == RULE_AXES and len(figure.axes) == 3:
            calibrated[spec.fields[0]] = tuple(figure.axes)
            provenance.append((name, figure.source, spec.use))
        elif rule == RULE_NORMALISER:
            provenance.append((name, figure.source, spec.use))
        else:
            provenance.append((name, figure.source, "ignored: no setting takes it"))
    noise = replace(noise, **changes)
    calibrated_inputs = replace(config.calibrated, **calibrated, provenance=tuple(provenance))
    return replace(config, noise=noise, calibrated=calibrated_inputs)


def noise_default(noise: NoiseConfig, setting: FigureSetting) -> float:
    """The value of a noise rule's setting in ``noise`` that a measured figure is combined with: its first default
    field that is set (``accel_bias_rw_z``: the x/y walk unless given)."""
    return next(value for value in (getattr(noise, name) for name in setting.defaults) if value is not None)


def validate_config(config: EstimatorConfig) -> None:
    """Raise :class:`InputError` naming the field when a setting is not usable (negative noise, bad mode)."""
    for section_name in ("noise", "gates", "initial", "timing"):
        section = getattr(config, section_name)
        for item in fields(section):
            value = getattr(section, item.name)
            if value is None:
                continue
            for number in (value if isinstance(value, tuple) else (value,)):
                if not isinstance(number, (int, float)) or math.isnan(number) or number < 0:
                    raise InputError(f"must be a non-negative number, got {value!r}",
                                     field=f"{section_name}.{item.name}")
    for name in ("covariance_rate_hz", "pseudo_rate_hz", "max_imu_gap_factor"):
        if not getattr(config.timing, name) > 0:
            raise InputError("must be positive", field=f"timing.{name}")
    if config.gps_velocity_mode not in ("ned", "paper"):
        raise InputError(f"must be 'ned' or 'paper', got {config.gps_velocity_mode!r}",
                         field="gps_velocity_mode")
    if config.mag_fusion not in ("auto", "heading", "vector"):
        raise InputError(f"must be 'auto', 'heading' or 'vector', got {config.mag_fusion!r}", field="mag_fusion")
