"""PX4 EKF2 noise parameters from a calibration, in QGroundControl's ``.params`` file format.

File format (what QGC's "Save to file" writes and "Load from file" reads): ``#`` comment lines, then one
tab-separated row per parameter ``vehicle-id  component-id  NAME  VALUE  TYPE`` with TYPE the MAVLink
MAV_PARAM_TYPE (9 = REAL32, 6 = INT32). Each row here is preceded by a ``# NAME: ...`` line saying where the value
came from.

Unit semantics (PX4 ``EKF2`` module): EKF2_ACC_NOISE and EKF2_GYR_NOISE are per-sample standard deviations at the
filter's prediction period EKF2_PREDICT_US (the IMU is averaged to it; the delta-velocity / delta-angle variance is
noise^2 dt^2), so the calibrated per-sample sigma at the log rate f_log is rescaled by sqrt(f_ekf / f_log). The bias
process noises EKF2_GYR_B_NOISE / EKF2_ACC_B_NOISE add (noise dt)^2 per prediction step; an Allan rate random walk
K (variance K^2 dt per step) therefore maps to K / sqrt(dt). Measurement noises (mag, baro, airspeed, GPS) are the
per-sample standard deviations of the logged measurement. Values are clamped to PX4's documented range.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.calibration import SENSORS, Calibration, SensorCalibration
from ingest.errors import InputError
from ingest.files import atomic_write_text

#: MAV_PARAM_TYPE values used in .params files.
PARAM_TYPE_INT32 = 6
PARAM_TYPE_REAL32 = 9
MAV_PARAM_TYPES = range(1, 11)
#: EKF2's default prediction period (EKF2_PREDICT_US) [s].
DEFAULT_PREDICT_PERIOD_S = 0.01
#: PX4's documented (min, max) of the parameters written here.
PX4_RANGES = {
    "EKF2_ACC_NOISE": (0.01, 1.0), "EKF2_GYR_NOISE": (0.0001, 0.1), "EKF2_MAG_NOISE": (0.001, 1.0),
    "EKF2_BARO_NOISE": (0.01, 15.0), "EKF2_EAS_NOISE": (0.5, 5.0), "EKF2_GPS_P_NOISE": (0.01, 10.0),
    "EKF2_GPS_V_NOISE": (0.01, 5.0), "EKF2_GYR_B_NOISE": (0.0, 0.01), "EKF2_ACC_B_NOISE": (0.0, 0.01),
}


@dataclass(frozen=True)
class Px4Param:
    """One row of a .params file.

    Attributes
    ----------
    name : str
        PX4 parameter name.
    value : float
        Value in the parameter's PX4 unit.
    type : int
        MAV_PARAM_TYPE (9 = REAL32, 6 = INT32).
    comment : str
        Where the value came from ("" if none).
    """

    name: str
    value: float
    type: int = PARAM_TYPE_REAL32
    comment: str = ""


def px4_parameters(cal: Calibration, predict_period_s: float = DEFAULT_PREDICT_PERIOD_S) -> list[Px4Param]:
    """EKF2 noise parameters the calibration determines (sensors it lacks are left out).

    Parameters
    ----------
    cal : Calibration
        The calibration (its per-sample ``sigma`` is used, whatever ``cal.noise`` says: PX4 wants a std).
    predict_period_s : float
        EKF2's prediction period [s] (the log's EKF2_PREDICT_US / 1e6; PX4's default 0.01 s).
    """
    if not (math.isfinite(predict_period_s) and predict_period_s > 0):
        raise InputError(f"EKF2 prediction period must be > 0 s, got {predict_period_s!r}", field="EKF2_PREDICT_US")
    f_ekf_hz = 1.0 / predict_period_s
    params = []
    for name, sensor in (("EKF2_ACC_NOISE", "accelerometer"), ("EKF2_GYR_NOISE", "gyroscope")):
        if sensor in cal.sensors:
            s = cal.sensors[sensor]
            # EKF2 averages faster IMU data to its prediction rate; slower IMU data is used as is.
            scale = math.sqrt(min(f_ekf_hz, s.fir.fs_hz) / s.fir.fs_hz)
            params.append(_clamped(name, _rms(s.sigma) * scale,
                                   f"{sensor} sigma, RMS of {', '.join(s.axes)} = {_rms(s.sigma):.4g} {s.unit} per "
                                   f"sample at "
                                   f"{s.fir.fs_hz:.1f} Hz ({_origin(s)}), x sqrt({min(f_ekf_hz, s.fir.fs_hz):.1f}"
                                   f" / {s.fir.fs_hz:.1f}) for EKF2's {f_ekf_hz:.0f} Hz prediction rate"))
    measured = (("EKF2_MAG_NOISE", "magnetometer", None), ("EKF2_BARO_NOISE", "barometer", None),
                ("EKF2_EAS_NOISE", "airspeed", None), ("EKF2_GPS_P_NOISE", "gps_position", 2),
                ("EKF2_GPS_V_NOISE", "gps_velocity", 2))
    for name, sensor, n_axes in measured:
        if sensor in cal.sensors:
            s = cal.sensors[sensor]
            axes = s.axes[:n_axes]
            value = _rms(s.sigma[:n_axes])
            params.append(_clamped(name, value, f"{sensor} sigma, RMS of {', '.join(axes)} = {value:.4g} {s.unit} "
                                                f"per sample at {s.fir.fs_hz:.1f} Hz ({_origin(s)})"))
    for name, sensor in (("EKF2_GYR_B_NOISE", "gyroscope"), ("EKF2_ACC_B_NOISE", "accelerometer")):
        walks = [f.rate_random_walk for f in cal.allan.get(sensor, ()) if math.isfinite(f.rate_random_walk)]
        if walks:
            k = _rms(walks)
            params.append(_clamped(name, k / math.sqrt(predict_period_s),
                                   f"{sensor} Allan rate random walk K = {k:.3g} {SENSORS[sensor].unit}/sqrt(s)"
                                   f" (RMS over the {len(walks)} of 3 axes showing a +1/2 slope), / sqrt("
                                   f"{predict_period_s:g} s) since EKF2 adds (noise dt)^2 per step"))
    return params


def write_px4_params(params: list[Px4Param], path: str | os.PathLike, header: str = "",
                     vehicle_id: int = 1, component_id: int = 1) -> Path:
    """Write a QGroundControl .params file atomically; ``header`` lines become ``#`` comments after the title."""
    lines = [f"# Onboard parameters for Vehicle {vehicle_id}", "#"]
    lines += [f"# {line}".rstrip() for line in header.splitlines()]
    lines += ["#", "# Vehicle-Id Component-Id Name Value Type"]
    for p in params:
        if p.comment:
            lines.append(f"# {p.name}: {p.comment}")
        value = str(int(p.value)) if p.type == PARAM_TYPE_INT32 else format(float(p.value), ".17g")
        lines.append(f"{vehicle_id}\t{component_id}\t{p.name}\t{value}\t{p.type}")
    return atomic_write_text(path, "\n".join(lines) + "\n")


def read_px4_params(path: str | os.PathLike) -> dict[str, Px4Param]:
    """Parse a QGroundControl .params file: name -> :class:`Px4Param` (``# NAME: ...`` comments attached).

    Raises
    ------
    InputError
        Unreadable file, or a row that is not ``id  id  NAME  VALUE  TYPE`` (the message gives the line number).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read parameter file: {exc.strerror}", source=str(path)) from exc
    params: dict[str, Px4Param] = {}
    comment = ("", "")
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            name, sep, rest = line[1:].strip().partition(": ")
            comment = (name, rest) if sep else ("", "")
            continue
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
        params[name] = Px4Param(name=name, value=value, type=param_type,
                                comment=comment[1] if comment[0] == name else "")
        comment = ("", "")
    return params


def _clamped(name: str, value: float, comment: str) -> Px4Param:
    lo, hi = PX4_RANGES[name]
    clamped = min(max(value, lo), hi)
    if clamped != value:
        comment += f"; calibrated {value:.4g} clamped to PX4's range [{lo:g}, {hi:g}]"
    return Px4Param(name=name, value=clamped, comment=comment)


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _origin(s: SensorCalibration) -> str:
    return (f"FIR {s.fir.cutoff_hz:.3g} Hz / {s.fir.numtaps} taps, {s.segment.kind} segment "
            f"{s.segment.start_s:.2f} .. {s.segment.end_s:.2f} s")
