"""Filter noise figures: the calibrated (or identified) numbers an estimator is run with, each with its source.

A :class:`~calib.calibration.Calibration` holds what was measured (eq 50 residuals, still-segment biases, Allan
figures, eq 51 R, eq 52 tau). What a filter needs is something else: a white-noise density for the IMU, a
per-sample sigma per fused measurement axis, random walks. :data:`FIGURES` is that vocabulary, in physical units
(docs/calibration.md, 'From calibration to filter settings'); each value travels as a :class:`Figure` that says
where it came from, so a report can say which calibrated figure a run used and why, and the PX4 / ArduPilot
parameter export and CALIB.json (schema 2, section ``figures``) share one table.

:data:`FIGURES` is the one table from figures to filter settings: a :class:`FigureRow` per figure with its unit,
the sources that set it, the estimator setting it feeds and how (:class:`FigureSetting`, applied by
:func:`estimators.config.config_from_figures`), the estimators that have no use for it (each run's report) and its
identification bounds (:class:`Identification`, :data:`estimators.tuning.KNOBS`). Adding a figure is one row; code
names a figure through the table (``FIGURES.accel_tau.name``). ``calib`` does not import ``estimators``: settings
name their configuration fields as strings, which ``tests/test_figure_table.py`` checks.

Noise identification (``solarnav calibrate --tune``) returns a :class:`TuneResult` per estimator: the identified
figures (source :data:`SOURCE_TUNED`), the likelihood trace and the NIS per channel before and after.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from scipy.special import chdtri

#: Where a figure came from (the ``source`` of a :class:`Figure`).
SOURCE_DEFAULT = "default"
SOURCE_STILL = "still segment (eq 50 residual)"
SOURCE_ALLAN = "Allan deviation (still segment)"
SOURCE_INFLIGHT = "in-flight eq 50 residual"
SOURCE_INFLIGHT_BOUND = "in-flight eq 50 residual (upper bound, model-error treatment)"
SOURCE_STILL_BIAS = "still-segment bias"
SOURCE_INFLIGHT_BIAS = "in-flight bias estimate"
SOURCE_TAU = "eq 52"
SOURCE_RECEIVER = "receiver accuracy fields"
SOURCE_R = "eq 51 R (CALIB.json, hand edits honoured)"
SOURCE_TUNED = "tuned (innovation likelihood)"
SOURCE_USER = "user"
SOURCES = (SOURCE_DEFAULT, SOURCE_STILL, SOURCE_ALLAN, SOURCE_INFLIGHT, SOURCE_INFLIGHT_BOUND, SOURCE_STILL_BIAS,
           SOURCE_INFLIGHT_BIAS, SOURCE_TAU, SOURCE_RECEIVER, SOURCE_R, SOURCE_TUNED, SOURCE_USER)
#: What a figure of each source means for the filter that uses it (shown on the page, in CALIB.json, in the exports).
MEANING_LOWER_BOUND = "lower bound: sensor noise at rest, without the in-flight vibration"
MEANING_UPPER_BOUND = "upper bound: motion and vibration in the segment count as noise"
MEANING_IN_FLIGHT = "in-flight noise (steady flight, vibration included)"
MEANING_IDENTIFIED = "identified from the flight's innovations"
SOURCE_MEANINGS = {
    SOURCE_DEFAULT: "datasheet default", SOURCE_STILL: MEANING_LOWER_BOUND, SOURCE_ALLAN: MEANING_LOWER_BOUND,
    SOURCE_INFLIGHT: MEANING_IN_FLIGHT, SOURCE_INFLIGHT_BOUND: MEANING_UPPER_BOUND,
    SOURCE_STILL_BIAS: "bias measured at rest", SOURCE_INFLIGHT_BIAS: "bias estimated in flight",
    SOURCE_TAU: "eq 52 penalty factor", SOURCE_RECEIVER: "the receiver's reported accuracy",
    SOURCE_R: "eq 51 R as written in CALIB.json", SOURCE_TUNED: MEANING_IDENTIFIED, SOURCE_USER: "set by the user",
}
#: In-flight bias estimates are used only when every axis's posterior std is below these [rad/s, m/s^2].
MAX_GYRO_BIAS_STD_RAD_S = math.radians(0.05)
MAX_ACCEL_BIAS_STD_M_S2 = 0.03


#: Estimator registry names (:data:`estimators.api.ESTIMATORS`) the table's rows name.
THREE_STAGE = "three_stage"
FULL_STATE = ("full_state_direct", "full_state_indirect")
ESTIMATOR_NAMES = (THREE_STAGE, *FULL_STATE)

#: How a figure becomes a setting (:func:`estimators.config.config_from_figures` applies the rule, the noise
#: identification inverts it). ``noise.<field>`` is a :class:`estimators.config.NoiseConfig` field,
#: ``calibrated.<field>`` one of :class:`estimators.config.CalibratedInputs`.
#: A measured noise: ``noise.<field> = sqrt(default^2 + x^2)`` (x as is when tuned or set by the user).
RULE_NOISE = "noise"
#: The same on ``x / field strength`` (the filters fuse the magnetometer in units of the earth-field strength);
#: without a field strength the figure sets nothing.
RULE_NOISE_PER_STRENGTH = "noise per field strength"
#: The same per axis (``x`` on every axis when the figure has none) into a tuple field; without a field strength
#: the figure is reported ignored.
RULE_AXES_PER_STRENGTH = "noise per axis per field strength"
#: A factor: every ``noise.<field>`` named is multiplied by ``x``.
RULE_FACTOR = "factor"
#: ``calibrated.<field> = x``.
RULE_VALUE = "value"
#: ``calibrated.<field> = axes`` (three axes, else ignored).
RULE_AXES = "axes"
#: Sets nothing itself: the field strength the per-field-strength rules divide by.
RULE_NORMALISER = "normaliser"
RULES = (RULE_NOISE, RULE_NOISE_PER_STRENGTH, RULE_AXES_PER_STRENGTH, RULE_FACTOR, RULE_VALUE, RULE_AXES,
         RULE_NORMALISER)


@dataclass(frozen=True)
class FigureSetting:
    """Which estimator setting a figure feeds and how.

    Attributes
    ----------
    rule : str
        One of :data:`RULES`.
    fields : tuple of str
        The fields set (of ``noise`` or ``calibrated``, see :attr:`section`).
    default_fields : tuple of str
        Noise rules: the ``noise`` fields whose first value that is not None is the default a measured figure is
        root-sum-squared with (and the start of the identification); empty: ``fields``.
    use : str
        Calibrated and normaliser rules: what the run's report says the figure did (``{value}`` its value).
    """

    rule: str
    fields: tuple[str, ...] = ()
    default_fields: tuple[str, ...] = ()
    use: str = ""

    @property
    def section(self) -> str:
        """``"noise"`` or ``"calibrated"``: the part of the estimator configuration :attr:`fields` belong to."""
        return "calibrated" if self.rule in (RULE_VALUE, RULE_AXES) else "noise"

    @property
    def defaults(self) -> tuple[str, ...]:
        """:attr:`default_fields`, or :attr:`fields` when it names none."""
        return self.default_fields or self.fields


@dataclass(frozen=True)
class Identification:
    """How the noise identification (``solarnav calibrate --tune``, :mod:`estimators.tuning`) searches a figure.

    Attributes
    ----------
    lower, upper : float
        Search bounds in the figure's unit (the steps are :data:`estimators.tuning.STEPS_DECADES`, in log10).
    channel : str or None
        Diagnostics channel whose mean NIS the covariance-matching step uses (measurement figures only): a sensor
        (``"baro"``) or ``"sensor.c1c2"`` for some of its components (``"gps_pos.ne"``).
    estimators : tuple of str
        Estimators whose search vector holds the figure.
    needs : str or None
        Sensor-plan attribute that must be true (``has_airspeed``, ``has_mag``, ...).
    """

    lower: float
    upper: float
    channel: str | None = None
    estimators: tuple[str, ...] = ESTIMATOR_NAMES
    needs: str | None = None


@dataclass(frozen=True)
class FigureRow:
    """One filter figure: what it is, where it may come from, what it sets and how it is identified.

    Attributes
    ----------
    name : str
        The figure's name (CALIB.json ``figures`` keys, :attr:`Figure.name`).
    unit : str
        Unit of its value.
    meaning : str
        What it is.
    sources : tuple of str
        :data:`SOURCES` the calibration and the identification set it from (a hand edit in CALIB.json may give
        any figure :data:`SOURCE_DEFAULT` or :data:`SOURCE_USER`).
    setting : FigureSetting
        The estimator setting it feeds, and how.
    ignored : tuple of (str, str)
        ``(estimator, why)`` for every estimator that has no use for the setting.
    identification : Identification or None
        Its place in the identification's search vector; None: not identified.
    """

    name: str
    unit: str
    meaning: str
    sources: tuple[str, ...]
    setting: FigureSetting
    ignored: tuple[tuple[str, str], ...] = ()
    identification: Identification | None = None


class FigureTable(Mapping[str, FigureRow]):
    """The rows by name, and as attributes (``FIGURES.accel_tau.name``): code names a figure through the table, so
    each name is written once."""

    def __init__(self, rows: tuple[FigureRow, ...]):
        self._rows = {row.name: row for row in rows}
        if len(self._rows) != len(rows):
            raise ValueError("a figure name appears in two rows")

    def __getitem__(self, name: str) -> FigureRow:
        return self._rows[name]

    def __iter__(self):
        return iter(self._rows)

    def __len__(self) -> int:
        return len(self._rows)

    def __getattr__(self, name: str) -> FigureRow:
        if name.startswith("_"):  # not a row (copy and pickle probe such names before _rows exists)
            raise AttributeError(name)
        try:
            return self._rows[name]
        except KeyError:
            raise AttributeError(f"no figure {name!r} in the table") from None


def _noise(field_name: str, *default_fields: str) -> FigureSetting:
    return FigureSetting(RULE_NOISE, (field_name,), default_fields)


_MEASURED = (SOURCE_STILL, SOURCE_INFLIGHT)
_IMU_DENSITY = (SOURCE_ALLAN, SOURCE_STILL, SOURCE_INFLIGHT_BOUND, SOURCE_TUNED)
_BIAS = (SOURCE_INFLIGHT_BIAS, SOURCE_STILL_BIAS)
_STAGE1 = "no stage-1 accelerometer update (the accelerometer drives the propagation)"
_BIAS_STATE = "estimated as a state of the filter"
_NO_STATE = "no such state in the three-stage estimator"
_NOT_IN_THREE_STAGE = ((THREE_STAGE, _NO_STATE),)
_NOT_IN_FULL_STATE = tuple((name, _STAGE1) for name in FULL_STATE)
_REMOVED = "removed from the three-stage estimator's inputs"

#: The figures, in the order the identification searches them (docs/calibration.md, 'From calibration to filter
#: settings' and 'Noise identification'). Densities are per sqrt(Hz) (variance per second of a white process),
#: walks per sqrt(s), measurement noises per sample (docs/nomenclature.md). Identification bounds span the
#: low-cost sensors of docs/calibration.md, 'Noise identification'. The three-stage filter's gyro, airspeed and
#: wind figures are not identified: there they drive stages whose errors the next stage takes as exact inputs,
#: so the summed innovation likelihood of the cascade is not a joint one and rises when the error is moved into a
#: stage with few innovations (its heading, measured: 7.7 -> 21 deg in gusty air with every channel's NIS inside
#: 0.2 .. 3).
FIGURES = FigureTable((
    FigureRow("baro_noise", "m", "barometric altitude noise per sample", (*_MEASURED, SOURCE_TUNED),
              _noise("baro_sigma_m"),
              ((THREE_STAGE, "the barometer is a low-passed input, not a measurement update"),),
              Identification(0.02, 20.0, "baro", FULL_STATE, "has_baro")),
    FigureRow("mag_noise", "gauss", "magnetometer noise per sample, per axis x, y, z", (*_MEASURED, SOURCE_TUNED),
              FigureSetting(RULE_AXES_PER_STRENGTH, ("mag_sigma_axes",), ("mag_sigma",)),
              identification=Identification(2e-4, 0.3, "mag", needs="has_mag")),
    FigureRow("mag_field_strength", "gauss", "earth-field strength the magnetometer is normalised by",
              (*_MEASURED, SOURCE_TUNED), FigureSetting(RULE_NORMALISER, use="normalises the magnetometer figures")),
    FigureRow("airspeed_noise", "m/s", "true-airspeed noise per sample", (SOURCE_INFLIGHT, SOURCE_TUNED),
              _noise("airspeed_sigma_m_s"), identification=Identification(0.02, 5.0, "airspeed", FULL_STATE,
                                                                          "has_airspeed")),
    # the zero-sideslip pseudo-measurement's error is the aircraft's real sideslip (turns, gusts before the
    # weathercock settles), correlated over a turn: like the GPS position the likelihood would shrink it without
    # end, so it is floored at 0.2 m/s, about 1 deg of sideslip at 12 m/s (a well-coordinated small fixed wing)
    FigureRow("sideslip_noise", "m/s", "zero-sideslip pseudo-measurement noise on the body-y air velocity",
              (SOURCE_TUNED,), _noise("sideslip_sigma_m_s"), ((THREE_STAGE, "no sideslip pseudo-measurement"),),
              Identification(0.2, 3.0, "sideslip", FULL_STATE, "has_airspeed")),
    # GPS position error is correlated over minutes: short-term innovations would shrink its figure far below the
    # receiver's own accuracy estimate, which is the floor (the scale only inflates it, e.g. for multipath).
    FigureRow("gps_pos_noise_scale", "-", "factor on the GPS horizontal position sigma (receiver accuracy, floored)",
              (SOURCE_TUNED,), FigureSetting(RULE_FACTOR, ("gps_pos_eph_scale", "gps_pos_sigma_floor_m")),
              identification=Identification(1.0, 5.0, "gps_pos.ne", needs="has_gps")),
    FigureRow("gps_hgt_noise_scale", "-", "factor on the GPS height sigma (receiver accuracy, floored)",
              (SOURCE_TUNED,), FigureSetting(RULE_FACTOR, ("gps_hgt_epv_scale", "gps_hgt_sigma_floor_m")),
              identification=Identification(1.0, 5.0, "gps_pos.d", needs="has_gps")),
    FigureRow("gps_vel_noise", "m/s", "GPS velocity noise per sample, when the receiver reports no accuracy",
              _MEASURED, _noise("gps_vel_sigma_default_m_s")),
    FigureRow("gps_vel_noise_scale", "-", "factor on the GPS velocity sigma (receiver accuracy, floored)",
              (SOURCE_TUNED,), _noise("gps_vel_accuracy_scale"),
              identification=Identification(0.1, 10.0, "gps_vel", needs="has_gps")),
    FigureRow("accel_axis_noise_density", "m/s^2/sqrt(Hz)", "accelerometer white-noise density per axis x, y, z "
              "(eq 51 R without tau), for the three-stage stage-1 update", _MEASURED,
              FigureSetting(RULE_AXES, ("accel_axis_density",),
                            use="three-stage stage-1 R per axis (floored by model error)"), _NOT_IN_FULL_STATE),
    FigureRow("accel_stage1_floor", "m/s^2", "model-error floor of the three-stage stage-1 accelerometer sigma at "
              "its update rate", (SOURCE_TUNED,),
              FigureSetting(RULE_VALUE, ("accel_stage1_floor_m_s2",),
                            use="three-stage stage-1 sigma floor {value:.4g} m/s^2"), _NOT_IN_FULL_STATE,
              Identification(0.02, 2.0, "accel", (THREE_STAGE,))),
    FigureRow("accel_tau", "-", "eq 52 penalty factor on the stage-1 body-y accelerometer variance",
              (SOURCE_TAU, SOURCE_TUNED),
              FigureSetting(RULE_VALUE, ("accel_tau",), use="three-stage stage-1 body-y variance x {value:.4g}"),
              _NOT_IN_FULL_STATE, Identification(0.1, 100.0, None, (THREE_STAGE,))),
    FigureRow("gyro_noise_density", "rad/s/sqrt(Hz)", "gyroscope white-noise density (angle random walk)",
              _IMU_DENSITY, _noise("gyro_noise_rad_s_sqrt_hz"),
              identification=Identification(1e-5, 3e-2, None, FULL_STATE)),
    FigureRow("accel_noise_density", "m/s^2/sqrt(Hz)", "accelerometer white-noise density (velocity random walk)",
              _IMU_DENSITY, _noise("accel_noise_m_s2_sqrt_hz"),
              identification=Identification(1e-4, 0.5, None, FULL_STATE)),
    FigureRow("gyro_bias_walk", "rad/s^2/sqrt(Hz)", "gyroscope bias random walk", (SOURCE_ALLAN, SOURCE_TUNED),
              _noise("gyro_bias_rw_rad_s2_sqrt_hz"), _NOT_IN_THREE_STAGE,
              Identification(1e-7, 1e-2, None, FULL_STATE)),
    FigureRow("accel_bias_walk", "m/s^3/sqrt(Hz)", "accelerometer bias random walk, body x and y",
              (SOURCE_ALLAN, SOURCE_TUNED), _noise("accel_bias_rw_m_s3_sqrt_hz"), _NOT_IN_THREE_STAGE,
              Identification(1e-5, 3e-3, None, FULL_STATE, "has_gps")),
    # its setting is None until given: then the x/y walk is its default
    FigureRow("accel_bias_walk_z", "m/s^3/sqrt(Hz)", "accelerometer bias random walk, body z", (SOURCE_TUNED,),
              _noise("accel_bias_rw_z_m_s3_sqrt_hz", "accel_bias_rw_z_m_s3_sqrt_hz", "accel_bias_rw_m_s3_sqrt_hz"),
              _NOT_IN_THREE_STAGE, Identification(1e-5, 0.1, None, FULL_STATE, "has_gps")),
    FigureRow("wind_walk", "m/s/sqrt(s)", "wind random walk (turbulence following)", (SOURCE_TUNED,),
              _noise("wind_rw_m_s_sqrt_s"),
              identification=Identification(1e-3, 5.0, None, FULL_STATE, "has_airspeed")),
    # at most ArduPilot EKF3's EK3_MAGB_P_NSE range top (0.01 gauss/s): faster, the bias follows a disturbance
    FigureRow("mag_bias_walk", "gauss/sqrt(s)", "magnetometer hard-iron bias random walk", (SOURCE_TUNED,),
              FigureSetting(RULE_NOISE_PER_STRENGTH, ("mag_bias_rw_sqrt_s",)), _NOT_IN_THREE_STAGE,
              Identification(1e-7, 0.01, None, FULL_STATE, "has_mag")),
    FigureRow("baro_bias_walk", "m/sqrt(s)", "barometer offset (to GPS height) random walk", (SOURCE_TUNED,),
              _noise("baro_bias_rw_m_sqrt_s"), _NOT_IN_THREE_STAGE,
              Identification(1e-4, 1.0, None, FULL_STATE, "has_baro")),
    FigureRow("gyro_bias", "rad/s", "gyroscope bias, per axis x, y, z (body FRD)", _BIAS,
              FigureSetting(RULE_AXES, ("gyro_bias_rad_s",), use=_REMOVED),
              tuple((name, _BIAS_STATE) for name in FULL_STATE)),
    FigureRow("accel_bias", "m/s^2", "accelerometer bias, per axis x, y, z (body FRD)", _BIAS,
              FigureSetting(RULE_AXES, ("accel_bias_m_s2",), use=_REMOVED),
              tuple((name, _BIAS_STATE) for name in FULL_STATE)),
))


def chi2_quantile(probability: float, dof: int | float) -> float:
    """``probability`` quantile of the chi-square distribution with ``dof`` degrees of freedom (``chi2.ppf``, from
    :mod:`scipy.special`: importing :mod:`scipy.stats` costs the CLI most of a second)."""
    return float(chdtri(dof, 1.0 - probability))


def mean_nis_band(n: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the mean of ``n`` chi-square(1) values (the NIS of a consistent filter)."""
    tail = (1.0 - probability) / 2.0
    return chi2_quantile(tail, n) / n, chi2_quantile(1.0 - tail, n) / n


@dataclass(frozen=True)
class Figure:
    """One filter figure with its provenance.

    Attributes
    ----------
    name : str
        Key of :data:`FIGURES`.
    value : float
        The figure in the unit of :data:`FIGURES` (for a per-axis figure: the RMS over its axes).
    source : str
        One of :data:`SOURCES`.
    axes : tuple of float
        Per-axis values (empty for a scalar figure).
    note : str
        Why this source, or what was done to the raw number.
    """

    name: str
    value: float
    source: str
    axes: tuple[float, ...] = ()
    note: str = ""

    def __post_init__(self):
        if self.name not in FIGURES:
            raise ValueError(f"unknown figure {self.name!r}; known: {', '.join(FIGURES)}")

    @property
    def unit(self) -> str:
        """Unit of :attr:`value` (from :data:`FIGURES`)."""
        return FIGURES[self.name].unit

    @property
    def meaning(self) -> str:
        """What the figure is for a filter (:data:`SOURCE_MEANINGS`): a lower or upper bound of the sensor noise,
        in-flight noise, identified, ..."""
        return SOURCE_MEANINGS.get(self.source, self.source)

    def meaning_within(self, bounds: tuple[float, float] | None) -> str:
        """:attr:`meaning`, with ", at its lower/upper bound" for a value on one of the identification ``bounds``
        (the search stopped there: the flight asked for more than the bound allows)."""
        if bounds is None or self.value not in bounds:
            return self.meaning
        return f"{self.meaning}, at its {'lower' if self.value == bounds[0] else 'upper'} bound {self.value:.3g}"


@dataclass(frozen=True)
class ChannelConsistency:
    """Mean NIS of one measurement channel (sensor, component) of one replay against its chi-square band.

    Attributes
    ----------
    channel : str
        ``"<sensor>.<component>"`` as in the diagnostics table.
    n_updates : int
        Scalar updates of the channel.
    mean_nis : float
        Mean of nu^2 / S over them [-] (1 for a consistent filter).
    band : tuple of 2 float
        95 % two-sided band of the mean of ``n_updates`` chi-square(1) values.
    """

    channel: str
    n_updates: int
    mean_nis: float
    band: tuple[float, float]


@dataclass(frozen=True)
class TuneResult:
    """Noise identified for one estimator from the flight's own innovations.

    Attributes
    ----------
    estimator : str
        Registry name of the estimator.
    figures : dict of str -> Figure
        Every figure the estimator was run with after tuning (tuned ones with source :data:`SOURCE_TUNED`, the
        others as they came from the calibration).
    start : dict of str -> float
        Starting value of every tuned figure.
    bounds : dict of str -> tuple of 2 float
        Search bounds of every tuned figure.
    log_likelihood_trace : tuple of float
        Innovation log-likelihood of the best point after each replay (first entry: the start).
    n_replays : int
        Filter replays spent.
    nis_before, nis_after : tuple of ChannelConsistency
        Per channel, at the start and at the tuned figures.
    wall_s : float
        Wall time of the identification [s].
    notes : tuple of str
        What the search did (bounds reached, budget spent, parameters left out and why).
    """

    estimator: str
    figures: dict[str, Figure]
    start: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    log_likelihood_trace: tuple[float, ...]
    n_replays: int
    nis_before: tuple[ChannelConsistency, ...] = ()
    nis_after: tuple[ChannelConsistency, ...] = ()
    wall_s: float = 0.0
    notes: tuple[str, ...] = field(default_factory=tuple)


def rms(values) -> float:
    """Root mean square of a non-empty sequence of numbers (the value of a per-axis figure)."""
    values = [float(v) for v in values]
    return math.sqrt(sum(v * v for v in values) / len(values))
