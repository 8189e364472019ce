"""Tables of a :class:`~calib.calibration.Calibration` for display and reports (pandas DataFrames).

* :func:`noise_table`: one row per sensor and axis with every figure (long form, SI units);
* :func:`table4`: the layout of the paper's Table 4 (accelerometer in m/s^2, gyroscope in deg/s);
* :func:`r_tables`: the eq 51 matrices with axis labels.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from calib.calibration import Calibration
from calib.figures import MEANING_IN_FLIGHT, MEANING_LOWER_BOUND, MEANING_UPPER_BOUND

#: Paper Table 4 labels the gyro axes by their rates.
GYRO_RATE_LABELS = ("p", "q", "r")


def noise_meaning(cal: Calibration, sensor: str) -> str:
    """What a sensor's noise figures are, from the kind of its segment: at rest (a found stationary segment, or a
    window the stationarity test accepts) a lower bound of the in-flight noise; in steady flight the in-flight
    noise; in any other window an upper bound (its motion and vibration count as noise)."""
    segment = cal.sensors[sensor].segment
    at_rest = segment.kind == "stationary" or (
        cal.stationary_bias is not None and cal.stationary_bias.segment == segment)
    if at_rest:
        return MEANING_LOWER_BOUND
    return MEANING_IN_FLIGHT if segment.kind == "steady" else MEANING_UPPER_BOUND


def noise_table(cal: Calibration) -> pd.DataFrame:
    """Per sensor and axis: unit, eq 50 eta/beta, sigma, robust sigma, mean, the physically referenced bias
    (gyro mean and the identifiable along-gravity accelerometer bias on a stationary segment, NaN elsewhere),
    rate, filter, segment and what the figures mean (:func:`noise_meaning`). Index: (sensor, axis)."""
    rows = []
    for name, s in cal.sensors.items():
        bias = _physical_bias(cal, name)
        for k, axis in enumerate(s.axes):
            rows.append({
                "sensor": name, "axis": axis, "unit": s.unit, "eta": s.eta[k], "beta": s.beta[k],
                "sigma": s.sigma[k], "sigma_robust": s.sigma_robust[k], "mean": s.mean[k],
                "physical_bias": bias[k] if bias is not None else np.nan, "rate_hz": s.fir.fs_hz,
                "cutoff_hz": s.fir.cutoff_hz, "numtaps": s.fir.numtaps, "segment_kind": s.segment.kind,
                "segment_start_s": s.segment.start_s, "segment_end_s": s.segment.end_s,
                "meaning": noise_meaning(cal, name),
            })
    return pd.DataFrame(rows).set_index(["sensor", "axis"])


def table4(cal: Calibration) -> pd.DataFrame:
    """The paper's Table 4 layout: rows = figures, columns = (sensor [unit], axis); gyroscope in deg/s.

    Rows: "Noise (eq 50 eta)", "Bias (eq 50 beta)", "Noise (sigma)", "Noise (robust sigma)",
    "Bias (stationary)". Sensors the calibration lacks are left out.
    """
    columns, data = [], []
    for name, label, scale, axes in (("accelerometer", "Accelerometer (m/s^2)", 1.0, None),
                                     ("gyroscope", "Gyroscope (deg/s)", np.degrees(1.0), GYRO_RATE_LABELS)):
        if name not in cal.sensors:
            continue
        s = cal.sensors[name]
        bias = _physical_bias(cal, name)
        for k, axis in enumerate(axes or s.axes):
            columns.append((label, axis))
            data.append([s.eta[k] * scale, s.beta[k] * scale, s.sigma[k] * scale, s.sigma_robust[k] * scale,
                         bias[k] * scale if bias is not None else np.nan])
    index = ["Noise (eq 50 eta)", "Bias (eq 50 beta)", "Noise (sigma)", "Noise (robust sigma)", "Bias (stationary)"]
    return pd.DataFrame(np.array(data).T if data else np.empty((len(index), 0)), index=index,
                        columns=pd.MultiIndex.from_tuples(columns, names=["sensor", "axis"]))


def r_tables(cal: Calibration) -> dict[str, pd.DataFrame]:
    """Eq 51 matrix per sensor [unit^2] labelled by axis (the accelerometer's includes tau)."""
    out = {}
    for name in cal.r:
        matrix = cal.r_matrix(name)
        axes = cal.sensors[name].axes if name in cal.sensors else tuple(str(k) for k in range(len(matrix)))
        out[name] = pd.DataFrame(matrix, index=list(axes), columns=list(axes))
    return out


def _physical_bias(cal: Calibration, sensor: str) -> tuple[float, ...] | None:
    bias = cal.stationary_bias
    if bias is None:
        return None
    if sensor == "gyroscope":
        return bias.gyro_bias_rad_s
    if sensor == "accelerometer":
        return bias.accel_bias_body_m_s2
    return None
