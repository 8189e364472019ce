"""CALIB.json: the versioned file a :class:`~calib.calibration.Calibration` is exchanged through.

Schema ``"solarnav.calibration/2"`` (strict JSON; NaN is written as null; units are those of each sensor)::

    {
      "schema": "solarnav.calibration/2",
      "source": {"file": str, "sha256": str, "vehicle_type": int | null},
      "noise_choice": "sigma" | "eta",              # figure R is built from (eq 51)
      "sensors": {                                  # accelerometer, gyroscope, magnetometer, barometer,
        "<sensor>": {                               # airspeed, gps_position, gps_velocity (those calibrated)
          "unit": str, "axes": [str, ...],
          "segment": {"start_s": float, "end_s": float, "kind": "user" | "stationary" | "steady",
                      "reason": str},               # log clock [s]
          "meaning": str,                           # lower bound (at rest) / in-flight / upper bound (written only)
          "filter": {"design": "firwin", "window": "hamming", "zero_phase": "filtfilt",
                     "fs_hz": float, "cutoff_hz": float, "numtaps": int, "rho_h": float},
          "n_samples": int,
          "eta": [..], "beta": [..],                # paper eq 50, per axis
          "sigma": [..], "sigma_robust": [..],      # per-sample std at fs_hz (docs/calibration.md, 'Noise and bias (eq
          50)')
          "mean": [..], "warnings": [str, ...]
        }
      },
      "stationary_bias": null | {
        "segment": {..}, "n_samples": int,
        "gyro_bias_rad_s": [3], "gyro_bias_std_rad_s": [3],
        "accel_bias_parallel_m_s2": float, "accel_bias_parallel_std_m_s2": float,
        "accel_up_body": [3], "accel_bias_body_m_s2": [3], "accel_horizontal_residual_m_s2": float | null,
        "gravity_m_s2": float, "gravity_source": str, "attitude_source": str
      },
      "inflight_bias": null | {"source": str, "window_s": [2], "gyro_bias_rad_s": [3], "gyro_bias_std_rad_s": [3],
                               "accel_bias_m_s2": [3] | null, "accel_bias_std_m_s2": [3] | null},
      "allan": {"accelerometer" | "gyroscope": [        # one entry per axis x, y, z
        {"white_density": float | null, "bias_instability": float, "bias_instability_tau_s": float,
         "floor_reached": bool, "rate_random_walk": float | null, "rate_hz": float,
         "derived": {"sigma_per_sample": .., "q_white_per_step": .., "q_bias_walk_per_step": ..}}]},
      "r": {"<sensor>": {"unit": str, "role": "measurement" | "input", "matrix": [[..], ..]}},
      "tau": {"value": float, "method": "default" | "user" | "likelihood" | "nis",
              "log10_tau_grid": [..], "neg_log_likelihood": [..], "mean_nis": [..], "n_innovations": int,
              "nis_at_tau": float | null, "nis_band": [2], "lag1_autocorrelation": float | null, "note": str},
      "warnings": [str, ...],
      "figures": {"<name>": <figure>},              # calib.figures.FIGURES names, the filter figures
      "tuning": {"<estimator>": {                   # noise identified per estimator (solarnav calibrate --tune)
        "figures": {"<name>": <figure>},            # every figure the estimator ran with after tuning
        "start": {"<name>": float}, "bounds": {"<name>": [lo, hi]},   # the tuned figures, in their units
        "log_likelihood_trace": [..], "n_replays": int, "wall_s": float,
        "nis_before": [<nis>], "nis_after": [<nis>], "notes": [str, ...]}}
    }

    <figure> = {"value": float, "unit": str, "source": str, "meaning": str, "axes": [..], "note": str}
    <nis>    = {"channel": "<sensor>.<component>", "n_updates": int, "mean_nis": float, "band": [lo, hi]}

``figures`` are the calibration's filter figures (docs/calibration.md, 'From calibration to filter settings').
A figure's ``unit`` must be the unit :data:`calib.figures.FIGURES` gives its name and its ``source`` one of
:data:`calib.figures.SOURCES`; an unknown name is refused. ``meaning`` (written, not read: it follows from the
source) says what the figure is for a filter: a lower bound (at rest), an upper bound (motion counted as noise),
in-flight noise, identified, and "at its lower/upper bound" for an identified value on an identification bound;
each sensor's ``meaning`` says the same of its segment (:func:`calib.tables.noise_meaning`). "derived" Allan values
are informational (recomputed on load). The R matrices are read as written, so a hand-edited matrix is honoured.

Schema ``"solarnav.calibration/1"`` (the layout above without ``figures`` and ``tuning``) is still read, into a
:class:`~calib.calibration.Calibration` with empty ``figures`` and ``tuning``; writing always writes schema 2. Any
other schema or version, or a missing key, is refused with an :class:`~ingest.errors.InputError` naming the key.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from calib.allan import AllanFigures
from calib.bias import GravityReference, InflightBias, StationaryBias
from calib.calibration import NOISE_CHOICES, SENSORS, Calibration, SensorCalibration
from calib.figures import FIGURES, SOURCES, ChannelConsistency, Figure, TuneResult
from calib.fir import FIR_WINDOW, design_fir
from calib.segments import Segment
from calib.tables import noise_meaning
from calib.tau import TauSelection
from ingest.errors import InputError
from ingest.files import atomic_write_text

SCHEMA = "solarnav.calibration/2"
SCHEMA_FAMILY = "solarnav.calibration/"
#: Older versions still read (without ``figures`` and ``tuning``).
READABLE_SCHEMAS = (SCHEMA, "solarnav.calibration/1")
#: R of these sensors is the covariance of a filter INPUT (it enters Q), not of a measurement.
INPUT_SENSORS = ("accelerometer", "gyroscope")


def calibration_to_dict(cal: Calibration) -> dict[str, Any]:
    """JSON-ready dict of ``cal`` following the module's schema (NaN -> None)."""
    data = {
        "schema": SCHEMA,
        "source": {"file": cal.source, "sha256": cal.sha256, "vehicle_type": cal.vehicle_type},
        "noise_choice": cal.noise,
        "sensors": {name: _sensor_to_dict(s, noise_meaning(cal, name)) for name, s in cal.sensors.items()},
        "stationary_bias": None if cal.stationary_bias is None else _stationary_to_dict(cal.stationary_bias),
        "inflight_bias": None if cal.inflight_bias is None else _inflight_to_dict(cal.inflight_bias),
        "allan": {name: [_allan_to_dict(f) for f in axes] for name, axes in cal.allan.items()},
        "r": {name: {"unit": f"({cal.sensors[name].unit})^2" if name in cal.sensors else "",
                     "role": "input" if name in INPUT_SENSORS else "measurement",
                     "matrix": [list(row) for row in matrix]} for name, matrix in cal.r.items()},
        "tau": _tau_to_dict(cal.tau),
        "warnings": list(cal.warnings),
        "figures": _figures_to_dict(cal.figures),
        "tuning": {name: _tuning_to_dict(t) for name, t in cal.tuning.items()},
    }
    return _nan_to_none(data)


def calibration_from_dict(data: Any, source: str = "CALIB.json") -> Calibration:
    """Validate a parsed CALIB.json and rebuild the :class:`Calibration`.

    Raises
    ------
    InputError
        Unknown schema or version, a missing key, or a value of the wrong type or shape (message names the key).
    """
    reader = _Reader(source)
    root = reader.obj(data, "")
    schema = reader.text(root, "schema")
    if schema not in READABLE_SCHEMAS:
        if schema.startswith(SCHEMA_FAMILY):
            raise InputError(f"calibration schema version {schema[len(SCHEMA_FAMILY):]!r} is not supported "
                             f"(this solarnav reads {', '.join(map(repr, READABLE_SCHEMAS))})", source=source,
                             field="schema")
        raise InputError(f"not a solarnav calibration: schema {schema!r}, expected {SCHEMA!r}", source=source,
                         field="schema")
    origin = reader.obj(root, "source")
    noise = reader.text(root, "noise_choice")
    if noise not in NOISE_CHOICES:
        raise InputError(f"must be one of {NOISE_CHOICES}, got {noise!r}", source=source, field="noise_choice")
    sensors = {name: _sensor_from_dict(reader, value, f"sensors.{name}")
               for name, value in reader.obj(root, "sensors").items()}
    unknown = sorted(set(sensors) - set(SENSORS))
    if unknown:
        raise InputError(f"unknown sensor(s) {unknown}; known: {list(SENSORS)}", source=source, field="sensors")
    r = {}
    for name, entry in reader.obj(root, "r").items():
        matrix = reader.matrix(reader.obj(entry, "", f"r.{name}"), "matrix", f"r.{name}")
        r[name] = tuple(tuple(row) for row in matrix)
    stationary = reader.nullable(root, "stationary_bias")
    inflight = reader.nullable(root, "inflight_bias")
    # Schema 1 predates the figures; the caller recomputes them from the calibration when empty.
    has_figures = schema == SCHEMA
    return Calibration(
        source=reader.text(origin, "file", "source"), sha256=reader.text(origin, "sha256", "source"),
        vehicle_type=reader.optional_integer(origin, "vehicle_type", "source"), noise=noise, sensors=sensors, r=r,
        tau=_tau_from_dict(reader, reader.obj(root, "tau")),
        stationary_bias=None if stationary is None else _stationary_from_dict(reader, stationary),
        inflight_bias=None if inflight is None else _inflight_from_dict(reader, inflight),
        allan={name: tuple(_allan_from_dict(reader, axis, f"allan.{name}[{k}]")
                           for k, axis in enumerate(reader.array(reader.obj(root, "allan"), name, "allan")))
               for name in reader.obj(root, "allan")},
        warnings=tuple(reader.texts(root, "warnings")),
        figures=_figures_from_dict(reader, reader.obj(root, "figures"), "figures") if has_figures else {},
        tuning={name: _tuning_from_dict(reader, value, f"tuning.{name}", name)
                for name, value in reader.obj(root, "tuning").items()} if has_figures else {})


def calibration_text(cal: Calibration) -> str:
    """``cal`` as CALIB.json text."""
    return json.dumps(calibration_to_dict(cal), indent=2, allow_nan=False) + "\n"


def write_calibration(cal: Calibration, path: str | os.PathLike) -> Path:
    """Write ``cal`` as CALIB.json atomically (:func:`ingest.files.atomic_write_text`); returns the path."""
    return atomic_write_text(path, calibration_text(cal))


def read_calibration(path: str | os.PathLike) -> Calibration:
    """Read and validate a CALIB.json.

    Raises
    ------
    InputError
        Unreadable file, invalid JSON, or content not following the schema.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read calibration file: {exc.strerror}", source=str(path)) from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg} at line {exc.lineno})", source=str(path)) from exc
    return calibration_from_dict(data, source=str(path))


# --- to dict ------------------------------------------------------------------------------------------------------


def _segment_to_dict(segment: Segment) -> dict[str, Any]:
    return {"start_s": segment.start_s, "end_s": segment.end_s, "kind": segment.kind, "reason": segment.reason}


def _sensor_to_dict(s: SensorCalibration, meaning: str) -> dict[str, Any]:
    return {
        "unit": s.unit, "axes": list(s.axes), "segment": _segment_to_dict(s.segment), "meaning": meaning,
        "filter": {"design": "firwin", "window": FIR_WINDOW, "zero_phase": "filtfilt", "fs_hz": s.fir.fs_hz,
                   "cutoff_hz": s.fir.cutoff_hz, "numtaps": s.fir.numtaps, "rho_h": s.fir.rho_h},
        "n_samples": s.n_samples, "eta": list(s.eta), "beta": list(s.beta), "sigma": list(s.sigma),
        "sigma_robust": list(s.sigma_robust), "mean": list(s.mean), "warnings": list(s.warnings),
    }


def _stationary_to_dict(b: StationaryBias) -> dict[str, Any]:
    return {
        "segment": _segment_to_dict(b.segment), "n_samples": b.n_samples,
        "gyro_bias_rad_s": list(b.gyro_bias_rad_s), "gyro_bias_std_rad_s": list(b.gyro_bias_std_rad_s),
        "accel_bias_parallel_m_s2": b.accel_bias_parallel_m_s2,
        "accel_bias_parallel_std_m_s2": b.accel_bias_parallel_std_m_s2,
        "accel_up_body": list(b.accel_up_body), "accel_bias_body_m_s2": list(b.accel_bias_body_m_s2),
        "accel_horizontal_residual_m_s2": b.accel_horizontal_residual_m_s2,
        "gravity_m_s2": b.gravity.value_m_s2, "gravity_source": b.gravity.source,
        "attitude_source": b.attitude_source,
    }


def _inflight_to_dict(b: InflightBias) -> dict[str, Any]:
    return {
        "source": b.source, "window_s": list(b.window_s), "gyro_bias_rad_s": list(b.gyro_bias_rad_s),
        "gyro_bias_std_rad_s": list(b.gyro_bias_std_rad_s),
        "accel_bias_m_s2": None if b.accel_bias_m_s2 is None else list(b.accel_bias_m_s2),
        "accel_bias_std_m_s2": None if b.accel_bias_std_m_s2 is None else list(b.accel_bias_std_m_s2),
    }


def _allan_to_dict(f: AllanFigures) -> dict[str, Any]:
    return {
        "white_density": f.white_density, "bias_instability": f.bias_instability,
        "bias_instability_tau_s": f.bias_instability_tau_s, "floor_reached": f.floor_reached,
        "rate_random_walk": f.rate_random_walk, "rate_hz": f.rate_hz,
        "derived": {"sigma_per_sample": f.sigma_per_sample, "q_white_per_step": f.q_white_per_step,
                    "q_bias_walk_per_step": f.q_bias_walk_per_step},
    }


def _tau_to_dict(t: TauSelection) -> dict[str, Any]:
    return {
        "value": t.tau, "method": t.method, "log10_tau_grid": list(t.log10_tau_grid),
        "neg_log_likelihood": list(t.neg_log_likelihood), "mean_nis": list(t.mean_nis),
        "n_innovations": t.n_innovations, "nis_at_tau": t.nis_at_tau, "nis_band": list(t.nis_band),
        "lag1_autocorrelation": t.lag1_autocorrelation, "note": t.note,
    }


def _figure_to_dict(f: Figure, bounds: tuple[float, float] | None = None) -> dict[str, Any]:
    return {"value": f.value, "unit": f.unit, "source": f.source, "meaning": f.meaning_within(bounds),
            "axes": list(f.axes), "note": f.note}


def _figures_to_dict(figures: dict[str, Figure], bounds: dict[str, tuple[float, float]] | None = None
                     ) -> dict[str, Any]:
    return {name: _figure_to_dict(f, (bounds or {}).get(name)) for name, f in figures.items()}


def _consistency_to_dict(c: ChannelConsistency) -> dict[str, Any]:
    return {"channel": c.channel, "n_updates": c.n_updates, "mean_nis": c.mean_nis, "band": list(c.band)}


def _tuning_to_dict(t: TuneResult) -> dict[str, Any]:
    return {
        "figures": _figures_to_dict(t.figures, t.bounds), "start": dict(t.start),
        "bounds": {name: list(bound) for name, bound in t.bounds.items()},
        "log_likelihood_trace": list(t.log_likelihood_trace), "n_replays": t.n_replays,
        "nis_before": [_consistency_to_dict(c) for c in t.nis_before],
        "nis_after": [_consistency_to_dict(c) for c in t.nis_after], "wall_s": t.wall_s, "notes": list(t.notes),
    }


def _nan_to_none(value: Any) -> Any:
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {key: _nan_to_none(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_nan_to_none(item) for item in value]
    return value


# --- from dict ----------------------------------------------------------------------------------------------------

class _Reader:
    """Typed access to parsed JSON that fails with the key path in the message."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, path: str, message: str) -> InputError:
        return InputError(message, source=self.source, field=path or None)

    def nullable(self, obj: dict, key: str, parent: str = "") -> Any:
        """The value under ``key`` (None allowed); a missing key fails."""
        if key not in obj:
            raise self.fail(_join(parent, key), "missing key")
        return obj[key]

    def obj(self, container: Any, key: str, parent: str = "") -> dict:
        """``container[key]`` (or ``container`` itself when ``key`` is "") as a JSON object."""
        value = container if key == "" else self.nullable(container, key, parent)
        if not isinstance(value, dict):
            raise self.fail(_join(parent, key), f"expected an object, got {type(value).__name__}")
        return value

    def array(self, obj: dict, key: str, parent: str = "") -> list:
        value = self.nullable(obj, key, parent)
        if not isinstance(value, list):
            raise self.fail(_join(parent, key), f"expected a list, got {type(value).__name__}")
        return value

    def text(self, obj: dict, key: str, parent: str = "") -> str:
        value = self.nullable(obj, key, parent)
        if not isinstance(value, str):
            raise self.fail(_join(parent, key), f"expected a string, got {type(value).__name__}")
        return value

    def texts(self, obj: dict, key: str, parent: str = "") -> list[str]:
        values = self.array(obj, key, parent)
        if not all(isinstance(v, str) for v in values):
            raise self.fail(_join(parent, key), "expected a list of strings")
        return values

    def number(self, obj: dict, key: str, parent: str = "") -> float:
        """A number; null reads as NaN (JSON has no NaN)."""
        return self._number(self.nullable(obj, key, parent), _join(parent, key))

    def numbers(self, obj: dict, key: str, parent: str = "", length: int | None = None) -> tuple[float, ...]:
        values = self.array(obj, key, parent)
        path = _join(parent, key)
        if length is not None and len(values) != length:
            raise self.fail(path, f"expected {length} numbers, got {len(values)}")
        return tuple(self._number(v, f"{path}[{k}]") for k, v in enumerate(values))

    def optional_numbers(self, obj: dict, key: str, parent: str, length: int) -> tuple[float, ...] | None:
        return None if self.nullable(obj, key, parent) is None else self.numbers(obj, key, parent, length)

    def optional_integer(self, obj: dict, key: str, parent: str = "") -> int | None:
        value = self.nullable(obj, key, parent)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise self.fail(_join(parent, key), f"expected an integer or null, got {value!r}")
        return value

    def integer(self, obj: dict, key: str, parent: str = "") -> int:
        value = self.optional_integer(obj, key, parent)
        if value is None:
            raise self.fail(_join(parent, key), "expected an integer, got null")
        return value

    def flag(self, obj: dict, key: str, parent: str = "") -> bool:
        value = self.nullable(obj, key, parent)
        if not isinstance(value, bool):
            raise self.fail(_join(parent, key), f"expected true or false, got {value!r}")
        return value

    def matrix(self, obj: dict, key: str, parent: str) -> np.ndarray:
        """A finite, symmetric, square matrix with a positive diagonal."""
        path = _join(parent, key)
        rows = self.array(obj, key, parent)
        values = [self.numbers({"row": row}, "row") if isinstance(row, list) else None for row in rows]
        if not values or any(row is None or len(row) != len(values) for row in values):
            raise self.fail(path, "expected a non-empty square matrix (a list of equal-length number lists)")
        matrix = np.array(values, dtype=float)
        if not np.all(np.isfinite(matrix)) or not np.allclose(matrix, matrix.T) or np.any(np.diag(matrix) <= 0):
            raise self.fail(path, "expected a finite symmetric matrix with a positive diagonal")
        return matrix

    def _number(self, value: Any, path: str) -> float:
        if value is None:
            return float("nan")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(path, f"expected a number, got {value!r}")
        return float(value)


def _join(parent: str, key: str) -> str:
    return f"{parent}.{key}" if parent and key else parent or key


def _segment_from_dict(r: _Reader, data: Any, path: str) -> Segment:
    obj = r.obj(data, "", path)
    return Segment(start_s=r.number(obj, "start_s", path), end_s=r.number(obj, "end_s", path),
                   kind=r.text(obj, "kind", path), reason=r.text(obj, "reason", path))


def _sensor_from_dict(r: _Reader, data: Any, path: str) -> SensorCalibration:
    obj = r.obj(data, "", path)
    axes = tuple(r.texts(obj, "axes", path))
    filt = r.obj(obj, "filter", path)
    if r.text(filt, "window", f"{path}.filter") != FIR_WINDOW:
        raise r.fail(f"{path}.filter.window", f"expected {FIR_WINDOW!r}")
    fir = design_fir(r.number(filt, "fs_hz", f"{path}.filter"), r.number(filt, "cutoff_hz", f"{path}.filter"),
                     r.integer(filt, "numtaps", f"{path}.filter"))
    per_axis = {key: r.numbers(obj, key, path, len(axes)) for key in ("eta", "beta", "sigma", "sigma_robust",
                                                                     "mean")}
    return SensorCalibration(sensor=path.rsplit(".", 1)[-1], unit=r.text(obj, "unit", path), axes=axes,
                             segment=_segment_from_dict(r, r.obj(obj, "segment", path), f"{path}.segment"),
                             fir=fir, n_samples=r.integer(obj, "n_samples", path),
                             warnings=tuple(r.texts(obj, "warnings", path)), **per_axis)


def _stationary_from_dict(r: _Reader, data: Any) -> StationaryBias:
    path = "stationary_bias"
    obj = r.obj(data, "", path)
    return StationaryBias(
        segment=_segment_from_dict(r, r.obj(obj, "segment", path), f"{path}.segment"),
        n_samples=r.integer(obj, "n_samples", path),
        gyro_bias_rad_s=r.numbers(obj, "gyro_bias_rad_s", path, 3),
        gyro_bias_std_rad_s=r.numbers(obj, "gyro_bias_std_rad_s", path, 3),
        accel_bias_parallel_m_s2=r.number(obj, "accel_bias_parallel_m_s2", path),
        accel_bias_parallel_std_m_s2=r.number(obj, "accel_bias_parallel_std_m_s2", path),
        accel_up_body=r.numbers(obj, "accel_up_body", path, 3),
        accel_bias_body_m_s2=r.numbers(obj, "accel_bias_body_m_s2", path, 3),
        accel_horizontal_residual_m_s2=r.number(obj, "accel_horizontal_residual_m_s2", path),
        gravity=GravityReference(r.number(obj, "gravity_m_s2", path), r.text(obj, "gravity_source", path)),
        attitude_source=r.text(obj, "attitude_source", path))


def _inflight_from_dict(r: _Reader, data: Any) -> InflightBias:
    path = "inflight_bias"
    obj = r.obj(data, "", path)
    return InflightBias(
        source=r.text(obj, "source", path), window_s=r.numbers(obj, "window_s", path, 2),
        gyro_bias_rad_s=r.numbers(obj, "gyro_bias_rad_s", path, 3),
        gyro_bias_std_rad_s=r.numbers(obj, "gyro_bias_std_rad_s", path, 3),
        accel_bias_m_s2=r.optional_numbers(obj, "accel_bias_m_s2", path, 3),
        accel_bias_std_m_s2=r.optional_numbers(obj, "accel_bias_std_m_s2", path, 3))


def _allan_from_dict(r: _Reader, data: Any, path: str) -> AllanFigures:
    obj = r.obj(data, "", path)
    return AllanFigures(
        white_density=r.number(obj, "white_density", path), bias_instability=r.number(obj, "bias_instability", path),
        bias_instability_tau_s=r.number(obj, "bias_instability_tau_s", path),
        floor_reached=r.flag(obj, "floor_reached", path),
        rate_random_walk=r.number(obj, "rate_random_walk", path), rate_hz=r.number(obj, "rate_hz", path))


def _tau_from_dict(r: _Reader, obj: dict) -> TauSelection:
    path = "tau"
    tau = r.number(obj, "value", path)
    if not (math.isfinite(tau) and tau > 0):
        raise r.fail("tau.value", f"expected a positive number, got {tau!r}")
    return TauSelection(
        tau=tau, method=r.text(obj, "method", path), log10_tau_grid=r.numbers(obj, "log10_tau_grid", path),
        neg_log_likelihood=r.numbers(obj, "neg_log_likelihood", path), mean_nis=r.numbers(obj, "mean_nis", path),
        n_innovations=r.integer(obj, "n_innovations", path), nis_at_tau=r.number(obj, "nis_at_tau", path),
        nis_band=r.numbers(obj, "nis_band", path, 2),
        lag1_autocorrelation=r.number(obj, "lag1_autocorrelation", path), note=r.text(obj, "note", path))


def _figure_name(r: _Reader, name: str, path: str) -> str:
    """``name`` if it is a :data:`calib.figures.FIGURES` key; fails naming ``path`` otherwise."""
    if name not in FIGURES:
        raise r.fail(path, f"unknown figure {name!r}; known: {', '.join(FIGURES)}")
    return name


def _figure_from_dict(r: _Reader, name: str, data: Any, path: str) -> Figure:
    obj = r.obj(data, "", path)
    _figure_name(r, name, path)
    unit, expected = r.text(obj, "unit", path), FIGURES[name].unit
    if unit != expected:
        raise r.fail(f"{path}.unit", f"figure {name!r} is in {expected!r}, got {unit!r}")
    figure_source = r.text(obj, "source", path)
    if figure_source not in SOURCES:
        raise r.fail(f"{path}.source", f"unknown source {figure_source!r}; known: {', '.join(map(repr, SOURCES))}")
    return Figure(name=name, value=r.number(obj, "value", path), source=figure_source,
                  axes=r.numbers(obj, "axes", path), note=r.text(obj, "note", path))


def _figures_from_dict(r: _Reader, obj: dict, path: str) -> dict[str, Figure]:
    return {name: _figure_from_dict(r, name, value, f"{path}.{name}") for name, value in obj.items()}


def _consistency_from_dict(r: _Reader, data: Any, path: str) -> ChannelConsistency:
    obj = r.obj(data, "", path)
    return ChannelConsistency(channel=r.text(obj, "channel", path), n_updates=r.integer(obj, "n_updates", path),
                              mean_nis=r.number(obj, "mean_nis", path), band=r.numbers(obj, "band", path, 2))


def _tuning_from_dict(r: _Reader, data: Any, path: str, estimator: str) -> TuneResult:
    obj = r.obj(data, "", path)
    start = r.obj(obj, "start", path)
    bounds = r.obj(obj, "bounds", path)
    return TuneResult(
        estimator=estimator, figures=_figures_from_dict(r, r.obj(obj, "figures", path), f"{path}.figures"),
        start={_figure_name(r, name, f"{path}.start.{name}"): r.number(start, name, f"{path}.start")
               for name in start},
        bounds={_figure_name(r, name, f"{path}.bounds.{name}"): r.numbers(bounds, name, f"{path}.bounds", 2)
                for name in bounds},
        log_likelihood_trace=r.numbers(obj, "log_likelihood_trace", path),
        n_replays=r.integer(obj, "n_replays", path),
        nis_before=tuple(_consistency_from_dict(r, c, f"{path}.nis_before[{k}]")
                         for k, c in enumerate(r.array(obj, "nis_before", path))),
        nis_after=tuple(_consistency_from_dict(r, c, f"{path}.nis_after[{k}]")
                        for k, c in enumerate(r.array(obj, "nis_after", path))),
        wall_s=r.number(obj, "wall_s", path), notes=tuple(r.texts(obj, "notes", path)))
