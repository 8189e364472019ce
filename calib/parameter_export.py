"""PX4 EKF2 and ArduPilot EKF3 noise parameters from the filter figures, through one mapping table.

:data:`MAPPING` is the table (docs/calibration.md, 'Autopilot parameter export'): one :class:`MappingRow` per
(figure of :data:`calib.figures.FIGURES`, PX4 parameter, ArduPilot parameter), each parameter with its unit, the
conversion from the figure's unit and the documented range. :func:`px4_parameters` / :func:`ardupilot_parameters`
turn a ``dict[str, Figure]`` (:func:`export_figures`: the figures a filter ran with, possibly tuned) into
:class:`AutopilotParam` rows; :func:`write_px4_params` writes QGroundControl's ``.params`` format and
:func:`write_ardupilot_parm` ArduPilot's ``.parm`` format, both atomically.

How the parameters enter the filters (both are error-state EKFs predicting on delta angles / delta velocities
accumulated over one prediction step ``dt``):

* **IMU noise** (EKF2_GYR_NOISE, EKF2_ACC_NOISE; EK3_GYRO_P_NSE, EK3_ACC_P_NSE): the delta-angle (delta-velocity)
  variance added per step is ``(dt * noise)^2`` (PX4 ``src/modules/ekf2/EKF/covariance.cpp``, ``d_ang_var =
  sq(dt * gyro_noise)``; ArduPilot ``libraries/AP_NavEKF3/AP_NavEKF3_core.cpp``, CovariancePrediction, ``daxVar =
  sq(dt*_gyrNoise)``). A white-noise density ``N`` integrates to ``N^2 dt`` over the step, so
  ``noise = N / sqrt(dt)``: the per-sample sigma of the IMU averaged to the prediction rate.
* **Bias random walks** (EKF2_GYR_B_NOISE, EKF2_ACC_B_NOISE; EK3_GBIAS_P_NSE, EK3_ABIAS_P_NSE): ``(dt * noise)^2``
  added to the bias-state variance per step (same files); a random walk ``K`` adds ``K^2 dt``: ``noise = K /
  sqrt(dt)``.
* **Wind**: PX4's EKF2_WIND_NSD is a spectral density, ``P += nsd^2 dt`` (covariance.cpp), so it is the wind
  walk itself; EK3_WIND_P_NSE adds ``(dt * noise)^2`` per step (AP_NavEKF3_core.cpp, ``windVelVar``), so
  ``noise = walk / sqrt(dt)``. Both scale it further with the height rate (EKF2 internally, EK3_WIND_PSCALE), and
  EKF3 uses at most 1 m/s^2 (``constrain_ftype(_windVelProcessNoise, 0.0f, 1.0f)``) although its documented range
  goes to 2.
* **Measurement noises** (mag, baro, airspeed): per-sample standard deviations of the fused measurement, as the
  figures. The airspeed figure is a true-airspeed noise, the parameters are equivalent-airspeed noises
  (EAS = TAS sqrt(rho / rho0)): equal at sea level, the figure overstates EAS noise above it.
* **GNSS velocity** (EKF2_GPS_V_NOISE, EK3_VELNE_M_NSE, EK3_VELD_M_NSE): a *lower limit* on the receiver's reported
  speed accuracy, and the value used when the receiver reports none (PX4 ``vel_noise = max(sacc,
  gps_vel_noise)``; ArduPilot AP_NavEKF3_Measurements.cpp ``gpsSpdAccuracy = MAX(gpsSpdAccuracy,
  _gpsHorizVelNoise)``, and the parameter pages), as the figure ``gps_vel_noise``. EK3_VELD_M_NSE gets 1.5 times
  it, the vertical / horizontal ratio PX4 applies to the same parameter (``vel_var * sq(1.5f)``). A
  ``gps_vel_noise_scale`` (a factor on the receiver's accuracy) has no parameter: a comment names it.
* **GNSS position** (EKF2_GPS_P_NOISE, EK3_POSNE_M_NSE): not written. The figures hold only a factor on the
  receiver's accuracy (``gps_pos_noise_scale``), no position noise in metres (:data:`UNMAPPED`).

Prediction period ``dt``: EKF2 predicts every EKF2_PREDICT_US (default 10 ms), an integer multiple of the IMU
period (PX4 ``src/modules/ekf2/module.yaml``); EKF3 accumulates IMU data until EKF_TARGET_DT = 12 ms
(``AP_NavEKF3_core.h``; ``readIMUData`` in AP_NavEKF3_Measurements.cpp), with ``dtEkfAvg = max(1 / loop rate,
EKF_TARGET_DT)`` (``setup_core``). Slower IMU data is not upsampled, so the period used is ``max(dt, 1 / f_imu)``
when the IMU rate is given.

Documented ranges: PX4 ``src/modules/ekf2/module.yaml`` and ``params_*.yaml`` (rendered at
https://docs.px4.io/main/en/advanced_config/parameter_reference.html); ArduPilot's ``@Range`` in the
``AP_NavEKF3.cpp`` parameter table (https://ardupilot.org/plane/docs/parameters.html). A value
outside is clamped (the ground stations refuse or flag out-of-range values) with a comment saying from what to
what; every row carries a comment with its figure's source and value.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from calib.calibration import Calibration
from calib.figures import FIGURES, Figure
from calib.filter_figures import calibration_figures
from ingest.errors import InputError
from ingest.files import atomic_write_text

#: MAV_PARAM_TYPE values used in .params files.
PARAM_TYPE_INT32 = 6
PARAM_TYPE_REAL32 = 9
MAV_PARAM_TYPES = range(1, 11)
#: EKF2's default prediction period (EKF2_PREDICT_US = 10000 us) [s].
DEFAULT_PREDICT_PERIOD_S = 0.01
#: EKF3's target prediction period (EKF_TARGET_DT) [s].
EKF3_TARGET_DT_S = 0.012
#: Estimator whose tuned figures an export prefers: EKF2 and EKF3 are error-state filters like it.
EXPORT_ESTIMATOR = "full_state_indirect"
#: Vertical / horizontal GNSS velocity noise ratio PX4 applies (``vel_var * sq(1.5f)``).
GNSS_VERTICAL_RATIO = 1.5
AUTOPILOTS = ("px4", "ardupilot")
PX4_REFERENCE = "https://docs.px4.io/main/en/advanced_config/parameter_reference.html"
ARDUPILOT_REFERENCE = "https://ardupilot.org/plane/docs/parameters.html"


@dataclass(frozen=True)
class Conversion:
    """From a figure in its :data:`calib.figures.FIGURES` unit to a parameter: ``factor x / sqrt(dt)^per_step``.

    Attributes
    ----------
    formula : str
        The rule as text, ``x`` the figure, ``dt`` the prediction period [s].
    factor : float
        Constant factor.
    per_step : bool
        Divide by sqrt(dt): a density or walk becoming the sigma the filter multiplies by dt per step.
    """

    formula: str
    factor: float = 1.0
    per_step: bool = False

    def apply(self, value: float, period_s: float) -> float:
        """The parameter value for figure ``value`` at prediction period ``period_s`` [s]."""
        return self.factor * value / (math.sqrt(period_s) if self.per_step else 1.0)


SAME = Conversion("x")
PER_STEP = Conversion("x / sqrt(dt)", per_step=True)
VERTICAL = Conversion(f"{GNSS_VERTICAL_RATIO:g} x", factor=GNSS_VERTICAL_RATIO)


@dataclass(frozen=True)
class ParameterSpec:
    """One autopilot parameter of the table.

    Attributes
    ----------
    name : str
        Parameter name.
    unit : str
        Its unit.
    min_value, max_value : float
        Documented range (in ``unit``).
    conversion : Conversion
        From the row's figure.
    meaning : str
        How the autopilot uses it, with the source file.
    """

    name: str
    unit: str
    min_value: float
    max_value: float
    conversion: Conversion
    meaning: str


@dataclass(frozen=True)
class MappingRow:
    """A figure and the PX4 / ArduPilot parameter set from it (None: that autopilot has none).

    Attributes
    ----------
    figure : str
        Key of :data:`calib.figures.FIGURES`.
    px4, ardupilot : ParameterSpec or None
        The parameters.
    scale_figure : str or None
        A factor figure the filter applies on the same channel that the parameter cannot carry (named in a
        comment when present).
    """

    figure: str
    px4: ParameterSpec | None
    ardupilot: ParameterSpec | None
    scale_figure: str | None = None

    def spec(self, autopilot: str) -> ParameterSpec | None:
        """The parameter of ``autopilot`` (``"px4"`` or ``"ardupilot"``)."""
        return self.px4 if autopilot == "px4" else self.ardupilot


_PX4_COV = "src/modules/ekf2/EKF/covariance.cpp"
_AP_COV = "libraries/AP_NavEKF3/AP_NavEKF3_core.cpp (CovariancePrediction)"
_PX4_GNSS = "PX4 uses max(receiver speed accuracy, this)"
_AP_GNSS = "lower limit on the receiver's speed accuracy (AP_NavEKF3_Measurements.cpp, readGpsData)"

#: The one table (ranges from PX4 module.yaml / params_*.yaml and ArduPilot AP_NavEKF3.cpp @Range).
MAPPING: tuple[MappingRow, ...] = (
    MappingRow(FIGURES.gyro_noise_density.name,
               ParameterSpec("EKF2_GYR_NOISE", "rad/s", 0.0001, 0.1, PER_STEP,
                             f"delta-angle variance (dt noise)^2 per step ({_PX4_COV})"),
               ParameterSpec("EK3_GYRO_P_NSE", "rad/s", 0.0001, 0.1, PER_STEP,
                             f"delta-angle variance (dt noise)^2 per step ({_AP_COV})")),
    MappingRow(FIGURES.accel_noise_density.name,
               ParameterSpec("EKF2_ACC_NOISE", "m/s^2", 0.01, 1.0, PER_STEP,
                             f"delta-velocity variance (dt noise)^2 per step ({_PX4_COV})"),
               ParameterSpec("EK3_ACC_P_NSE", "m/s^2", 0.01, 1.0, PER_STEP,
                             f"delta-velocity variance (dt noise)^2 per step ({_AP_COV})")),
    MappingRow(FIGURES.gyro_bias_walk.name,
               ParameterSpec("EKF2_GYR_B_NOISE", "rad/s^2", 0.0, 0.01, PER_STEP,
                             f"gyro-bias variance (dt noise)^2 per step ({_PX4_COV})"),
               ParameterSpec("EK3_GBIAS_P_NSE", "rad/s^2", 0.00001, 0.001, PER_STEP,
                             f"gyro-bias variance (dt noise)^2 per step ({_AP_COV})")),
    MappingRow(FIGURES.accel_bias_walk.name,
               ParameterSpec("EKF2_ACC_B_NOISE", "m/s^3", 0.0, 0.01, PER_STEP,
                             f"accelerometer-bias variance (dt noise)^2 per step ({_PX4_COV})"),
               ParameterSpec("EK3_ABIAS_P_NSE", "m/s^3", 0.00001, 0.02, PER_STEP,
                             f"accelerometer-bias variance (dt noise)^2 per step ({_AP_COV})")),
    MappingRow(FIGURES.mag_noise.name,
               ParameterSpec("EKF2_MAG_NOISE", "gauss", 0.001, 1.0, SAME, "3-axis magnetometer fusion noise"),
               ParameterSpec("EK3_MAG_M_NSE", "gauss", 0.01, 0.5, SAME, "RMS magnetometer measurement noise")),
    MappingRow(FIGURES.baro_noise.name,
               ParameterSpec("EKF2_BARO_NOISE", "m", 0.01, 15.0, SAME, "barometric altitude noise"),
               ParameterSpec("EK3_ALT_M_NSE", "m", 0.01, 100.0, SAME, "RMS altitude measurement noise")),
    MappingRow(FIGURES.airspeed_noise.name,
               ParameterSpec("EKF2_EAS_NOISE", "m/s", 0.5, 5.0, SAME, "airspeed fusion noise (EAS)"),
               ParameterSpec("EK3_EAS_M_NSE", "m/s", 0.5, 5.0, SAME, "RMS equivalent-airspeed noise")),
    MappingRow(FIGURES.gps_vel_noise.name,
               ParameterSpec("EKF2_GPS_V_NOISE", "m/s", 0.01, 5.0, SAME, _PX4_GNSS),
               ParameterSpec("EK3_VELNE_M_NSE", "m/s", 0.05, 5.0, SAME, f"horizontal: {_AP_GNSS}"),
               scale_figure=FIGURES.gps_vel_noise_scale.name),
    MappingRow(FIGURES.gps_vel_noise.name, None,
               ParameterSpec("EK3_VELD_M_NSE", "m/s", 0.05, 5.0, VERTICAL,
                             f"vertical: {_AP_GNSS}; 1.5 x horizontal as PX4 (vel_var * sq(1.5f))"),
               scale_figure=FIGURES.gps_vel_noise_scale.name),
    MappingRow(FIGURES.wind_walk.name,
               ParameterSpec("EKF2_WIND_NSD", "m/s^2/sqrt(Hz)", 0.0, 1.0, SAME,
                             f"wind variance nsd^2 dt per step ({_PX4_COV})"),
               ParameterSpec("EK3_WIND_P_NSE", "m/s^2", 0.01, 2.0, PER_STEP,
                             f"wind variance (dt noise)^2 per step ({_AP_COV}; used up to 1)")),
)

#: Parameters of the brief's list left out, and why.
UNMAPPED: dict[str, str] = {
    "EKF2_GPS_P_NOISE": "no GNSS position noise figure in metres (only gps_pos_noise_scale, a factor on the "
                        "receiver's accuracy); PX4's default stays",
    "EK3_POSNE_M_NSE": "no GNSS position noise figure in metres (only gps_pos_noise_scale, a factor on the "
                       "receiver's accuracy); ArduPilot's default stays",
}


@dataclass(frozen=True)
class AutopilotParam:
    """One parameter row of a .params / .parm file.

    Attributes
    ----------
    name : str
        Parameter name.
    value : float
        Value in the parameter's unit.
    type : int
        MAV_PARAM_TYPE (9 = REAL32, 6 = INT32); the .parm format has none (read back as REAL32).
    comments : tuple of str
        ``# NAME: ...`` lines written before the row: the figure's source and value, the conversion, a clamp.
    """

    name: str
    value: float
    type: int = PARAM_TYPE_REAL32
    comments: tuple[str, ...] = ()


def export_figures(cal: Calibration) -> dict[str, Figure]:
    """The figures an autopilot export writes.

    The tuned figures of :data:`EXPORT_ESTIMATOR` (``full_state_indirect``) when ``cal.tuning`` has them: EKF2 and
    EKF3 are error-state filters like it, so the noise identified for it is the closest to theirs. Otherwise the
    calibration's figures (:func:`calib.filter_figures.calibration_figures`: ``cal.figures``, or derived from the
    measured figures when it has none, e.g. read from a schema-1 CALIB.json).

    Parameters
    ----------
    cal : Calibration
        The calibration.

    Returns
    -------
    dict of str -> Figure
        Figure name -> figure, in the units of :data:`calib.figures.FIGURES`.
    """
    tuned = cal.tuning.get(EXPORT_ESTIMATOR)
    return dict(tuned.figures) if tuned is not None else calibration_figures(cal)


def autopilot_parameters(figures: dict[str, Figure], autopilot: str, predict_period_s: float,
                         imu_rate_hz: float | None = None) -> list[AutopilotParam]:
    """The parameters of ``autopilot`` that ``figures`` determine, in :data:`MAPPING` order.

    Parameters
    ----------
    figures : dict of str -> Figure
        The figures (:func:`export_figures`); rows whose figure is absent or not finite and positive are left
        out.
    autopilot : {"px4", "ardupilot"}
        Which column of the table.
    predict_period_s : float
        The filter's prediction period [s] (EKF2_PREDICT_US / 1e6; EKF3 max(1 / loop rate, 0.012 s)).
    imu_rate_hz : float, optional
        IMU sample rate [Hz]; slower IMU data makes the prediction period its sample period.

    Raises
    ------
    InputError
        A period or IMU rate that is not finite and positive, or an unknown autopilot.
    """
    if autopilot not in AUTOPILOTS:
        raise InputError(f"autopilot must be one of {AUTOPILOTS}, got {autopilot!r}", field="autopilot")
    if not (math.isfinite(predict_period_s) and predict_period_s > 0):
        raise InputError(f"prediction period must be > 0 s, got {predict_period_s!r}", field="predict_period_s")
    if imu_rate_hz is not None and not (math.isfinite(imu_rate_hz) and imu_rate_hz > 0):
        raise InputError(f"IMU rate must be > 0 Hz, got {imu_rate_hz!r}", field="imu_rate_hz")
    period_s = predict_period_s if imu_rate_hz is None else max(predict_period_s, 1.0 / imu_rate_hz)
    params = []
    for row in MAPPING:
        spec = row.spec(autopilot)
        figure = figures.get(row.figure)
        if spec is None or figure is None or not (math.isfinite(figure.value) and figure.value > 0):
            continue
        value = figure.value
        comments = [f"{figure.name} = {figure.value:.4g} {figure.unit} ({figure.source}: {figure.meaning})"
                    + (f"; {figure.note}" if figure.note else "")]
        scale = figures.get(row.scale_figure) if row.scale_figure else None
        if scale is not None and scale.value != 1.0:
            # The autopilots use the receiver's accuracy unscaled: a factor on it has no parameter.
            comments.append(f"{scale.name} = {scale.value:.4g} ({scale.source}) not carried: the autopilot uses "
                            "the receiver's accuracy unscaled")
        converted = spec.conversion.apply(value, period_s)
        if spec.conversion.per_step or spec.conversion.factor != 1.0:
            comments.append(f"{spec.conversion.formula} = {converted:.4g} {spec.unit}"
                            + (f" at dt = {period_s * 1e3:g} ms" if spec.conversion.per_step else ""))
        clamped = min(max(converted, spec.min_value), spec.max_value)
        if clamped != converted:
            comments.append(f"clamped from {converted:.4g} to {clamped:g} {spec.unit}: the documented range of "
                            f"{spec.name} is [{spec.min_value:g}, {spec.max_value:g}] "
                            f"({PX4_REFERENCE if autopilot == 'px4' else ARDUPILOT_REFERENCE})")
        params.append(AutopilotParam(name=spec.name, value=clamped, comments=tuple(comments)))
    return params


def px4_parameters(figures: dict[str, Figure], predict_period_s: float = DEFAULT_PREDICT_PERIOD_S,
                   imu_rate_hz: float | None = None) -> list[AutopilotParam]:
    """PX4 EKF2 parameters of ``figures`` (:func:`autopilot_parameters` with ``"px4"``)."""
    return autopilot_parameters(figures, "px4", predict_period_s, imu_rate_hz)


def ardupilot_parameters(figures: dict[str, Figure], predict_period_s: float = EKF3_TARGET_DT_S,
                         imu_rate_hz: float | None = None) -> list[AutopilotParam]:
    """ArduPilot EKF3 parameters of ``figures`` (:func:`autopilot_parameters` with ``"ardupilot"``)."""
    return autopilot_parameters(figures, "ardupilot", predict_period_s, imu_rate_hz)


def unwritten_notes(figures: dict[str, Figure], autopilot: str) -> list[str]:
    """``NAME: why`` for every parameter of ``autopilot`` in the table or :data:`UNMAPPED` that is not written."""
    prefix = "EKF2_" if autopilot == "px4" else "EK3_"
    notes = [f"{name}: not written, {why}" for name, why in UNMAPPED.items() if name.startswith(prefix)]
    for row in MAPPING:
        spec = row.spec(autopilot)
        figure = figures.get(row.figure)
        if spec is not None and (figure is None or not (math.isfinite(figure.value) and figure.value > 0)):
            notes.append(f"{spec.name}: not written, no finite positive {row.figure} figure")
    return notes


def px4_params_text(params: list[AutopilotParam], header: str = "", vehicle_id: int = 1,
                    component_id: int = 1) -> str:
    """A QGroundControl .params file's text; ``header`` lines become ``#`` comments after the title.

    Rows are ``vehicle-id<TAB>component-id<TAB>NAME<TAB>VALUE<TAB>TYPE`` (TYPE the MAV_PARAM_TYPE), each preceded
    by its ``# NAME: ...`` comment lines.
    """
    lines = [f"# Onboard parameters for Vehicle {vehicle_id}", "#"]
    lines += [f"# {line}".rstrip() for line in header.splitlines()]
    lines += ["#", "# Vehicle-Id Component-Id Name Value Type"]
    for p in params:
        lines += [f"# {p.name}: {comment}" for comment in p.comments]
        lines.append(f"{vehicle_id}\t{component_id}\t{p.name}\t{_format(p)}\t{p.type}")
    return "\n".join(lines) + "\n"


def ardupilot_parm_text(params: list[AutopilotParam], header: str = "") -> str:
    """An ArduPilot .parm file's text: ``NAME VALUE`` lines, ``header`` and comments as ``#`` lines."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    for p in params:
        lines += [f"# {p.name}: {comment}" for comment in p.comments]
        lines.append(f"{p.name} {_format(p)}")
    return "\n".join(lines) + "\n"


def write_px4_params(params: list[AutopilotParam], path: str | os.PathLike, header: str = "") -> Path:
    """Write :func:`px4_params_text` to ``path`` atomically."""
    return atomic_write_text(path, px4_params_text(params, header))


def write_ardupilot_parm(params: list[AutopilotParam], path: str | os.PathLike, header: str = "") -> Path:
    """Write :func:`ardupilot_parm_text` to ``path`` atomically."""
    return atomic_write_text(path, ardupilot_parm_text(params, header))


def read_px4_params(path: str | os.PathLike) -> dict[str, AutopilotParam]:
    """Parse a QGroundControl .params file: name -> :class:`AutopilotParam` (``# NAME: ...`` comments attached).

    Raises
    ------
    InputError
        Unreadable file, or a row that is not ``id  id  NAME  VALUE  TYPE`` (the message gives the line number).
    """
    params: dict[str, AutopilotParam] = {}
    for number, raw, comments in _rows(path):
        fields = raw.split("\t")
        try:
            if len(fields) != 5:
                raise ValueError(f"expected 5 tab-separated fields, got {len(fields)}")
            _, _, name, value_text, type_text = (f.strip() for f in fields)
            int(fields[0]), int(fields[1])
            param_type = int(type_text)
            if param_type not in MAV_PARAM_TYPES:
                raise ValueError(f"unknown MAV_PARAM_TYPE {param_type}")
            value = float(value_text)
        except ValueError as exc:
            raise InputError(f"line {number}: {exc} (expected 'vehicle-id<TAB>component-id<TAB>NAME<TAB>VALUE<TAB>"
                             "TYPE')", source=str(path)) from None
        params[name] = AutopilotParam(name=name, value=value, type=param_type, comments=comments.get(name, ()))
    return params


def read_ardupilot_parm(path: str | os.PathLike) -> dict[str, AutopilotParam]:
    """Parse an ArduPilot .parm / .param file (``NAME VALUE`` or ``NAME,VALUE``; ``#`` comments).

    Raises
    ------
    InputError
        Unreadable file, or a row that is not a name and a number (the message gives the line number).
    """
    params: dict[str, AutopilotParam] = {}
    for number, raw, comments in _rows(path):
        fields = re.split(r"[\s,]+", raw.strip())
        try:
            if len(fields) != 2:
                raise ValueError(f"expected NAME and VALUE, got {len(fields)} fields")
            name, value = fields[0], float(fields[1])
        except ValueError as exc:
            raise InputError(f"line {number}: {exc} (expected 'NAME VALUE')", source=str(path)) from None
        params[name] = AutopilotParam(name=name, value=value, comments=comments.get(name, ()))
    return params


def _rows(path: str | os.PathLike):
    """(line number, row, pending ``# NAME: ...`` comments by name) for every non-comment line of ``path``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read parameter file: {exc.strerror}", source=str(path)) from exc
    comments: dict[str, tuple[str, ...]] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            name, sep, rest = line[1:].strip().partition(": ")
            if sep and " " not in name:
                comments[name] = (*comments.get(name, ()), rest)
            continue
        yield number, raw, comments
        # Comments belong to the row right after them.
        comments = {}


def _format(p: AutopilotParam) -> str:
    # repr: the shortest text that reads back as the same float64.
    return str(int(p.value)) if p.type == PARAM_TYPE_INT32 else repr(float(p.value))

