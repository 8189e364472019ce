"""Pure table builders for the pages (pandas in, pandas out; no Streamlit), tested directly.

Column names carry their units, as everywhere in solarnav.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ingest import FlightLog, LogMetadata

#: MAVLink MAV_TYPE values a PX4 log is likely to carry.
MAV_TYPE_NAMES = {
    1: "fixed wing", 2: "quadrotor", 3: "coaxial", 4: "helicopter", 13: "hexarotor", 14: "octorotor",
    15: "tricopter", 19: "VTOL tailsitter (duorotor)", 20: "VTOL tailsitter (quadrotor)", 21: "VTOL tiltrotor",
    22: "VTOL (fixed wing + quadrotor)", 23: "VTOL", 24: "VTOL", 25: "VTOL",
}

#: Measurement streams (their absence is a warning; references, truth and the sun log are often absent).
SENSOR_STREAMS = ("imu", "mag", "baro", "gps", "airspeed")

#: What each stream is used for, shown when a log lacks it (so missing sensors are explained, never hidden).
STREAM_ROLES = {
    "mag": "magnetometer: heading must come from the GPS course or the sun vector",
    "baro": "barometer: altitude is aided by GPS only",
    "gps": "GPS: no position or velocity aiding, no track and no wind; only attitude can be estimated",
    "airspeed": "airspeed sensor: wind is not observable from airspeed on this fixed-wing",
    "onboard_attitude": "autopilot attitude estimate: nothing onboard to compare attitude with",
    "onboard_global_position": "autopilot global position: the onboard track uses PX4's local frame, if any",
    "onboard_wind": "autopilot wind estimate: nothing onboard to compare wind with",
    "truth_attitude": "ground-truth attitude (simulation only): errors are taken against the onboard estimate",
    "truth_global_position": "ground-truth position (simulation only)",
    "truth_wind": "ground-truth wind (simulation only)",
    "sun": "sun-device log: no sun heading aid and no Sun vector page (upload its CSV with the log)",
}


def vehicle_name(mav_type: int | None) -> str:
    """Readable vehicle type of a MAV_TYPE value (``"unknown"`` without one)."""
    if mav_type is None:
        return "unknown"
    return f"{MAV_TYPE_NAMES.get(mav_type, 'other')} (MAV_TYPE {mav_type})"


def format_duration(duration_s: float) -> str:
    """``h:mm:ss`` / ``m:ss.s`` text of a duration [s]."""
    minutes, seconds = divmod(float(duration_s), 60.0)
    hours, minutes = divmod(int(minutes), 60)
    return f"{hours}:{minutes:02d}:{seconds:04.1f}" if hours else f"{minutes}:{seconds:04.1f}"


def streams_table(meta: LogMetadata) -> pd.DataFrame:
    """One row per stream: topic, samples, rate [Hz], gap count, longest gap [s] and where it starts [s]."""
    rows = []
    for name, info in meta.streams.items():
        longest = max(info.gaps, key=lambda gap: gap[1]) if info.gaps else (np.nan, np.nan)
        rows.append({"stream": name, "topic": info.topic, "samples": info.n_samples, "rate_hz": info.rate_hz,
                     "gaps": len(info.gaps), "longest_gap_s": longest[1], "longest_gap_at_s": longest[0]})
    return pd.DataFrame(rows, columns=["stream", "topic", "samples", "rate_hz", "gaps", "longest_gap_s",
                                       "longest_gap_at_s"])


def missing_streams(log: FlightLog) -> pd.DataFrame:
    """Streams the log lacks and what that means (airspeed only counts for fixed-wing vehicles)."""
    rows = [{"stream": name, "consequence": role} for name, role in STREAM_ROLES.items()
            if not log.has(name) and (name != "airspeed" or log.meta.is_fixed_wing)]
    return pd.DataFrame(rows, columns=["stream", "consequence"])


def phase_table(stationary: Sequence, steady: Sequence, start_s: float, end_s: float,
                min_gap_s: float = 1.0) -> pd.DataFrame:
    """Flight phases covering ``start_s .. end_s`` [s]: the stationary and steady segments found by
    :mod:`calib.segments`, and ``"manoeuvring"`` for every gap between them longer than ``min_gap_s``.

    Parameters
    ----------
    stationary, steady : sequence of calib.segments.Segment
        Segments with ``start_s``, ``end_s`` [s] and ``reason``.
    start_s, end_s : float
        Time span of the log [s].
    min_gap_s : float
        Shorter gaps between segments are left out [s].

    Returns
    -------
    pandas.DataFrame
        Columns ``phase``, ``start_s``, ``end_s``, ``duration_s``, ``reason``, sorted by ``start_s``.
    """
    found = [("stationary", s) for s in stationary] + [("steady cruise", s) for s in steady]
    found.sort(key=lambda item: item[1].start_s)
    rows, cursor = [], start_s
    for phase, segment in found:
        if segment.start_s - cursor > min_gap_s:
            rows.append(("manoeuvring", cursor, segment.start_s, "neither stationary nor steady"))
        rows.append((phase, segment.start_s, segment.end_s, segment.reason))
        cursor = max(cursor, segment.end_s)
    if end_s - cursor > min_gap_s:
        rows.append(("manoeuvring", cursor, end_s, "neither stationary nor steady"))
    table = pd.DataFrame(rows, columns=["phase", "start_s", "end_s", "reason"])
    table.insert(3, "duration_s", table["end_s"] - table["start_s"])
    return table


def logs_table(entries: Sequence, runs: pd.DataFrame) -> pd.DataFrame:
    """The workspace's stored logs (in the given order) with their number of estimator runs.

    Parameters
    ----------
    entries : sequence of app.workspace.LogEntry
        Stored logs.
    runs : pandas.DataFrame
        :meth:`app.workspace.Workspace.list_runs` (column ``log_sha256``).
    """
    counts = runs["log_sha256"].value_counts() if len(runs) else pd.Series(dtype=int)
    return pd.DataFrame({
        "name": [e.display_name for e in entries],
        "sha256": [e.sha256 for e in entries],
        "size [MB]": [round(e.size_bytes / 1e6, 2) for e in entries],
        "added (UTC)": [e.added_utc for e in entries],
        "sun log": [e.has_sun for e in entries],
        "runs": [int(counts.get(e.sha256, 0)) for e in entries],
    })


def runs_table(runs: pd.DataFrame, entries: Sequence) -> pd.DataFrame:
    """Stored estimator runs with their log's name and the settings they were made with."""
    names = {e.sha256: e.display_name for e in entries}
    settings = [json.loads(text) for text in runs["settings_json"]]
    return pd.DataFrame({
        "run": runs["run_id"].to_numpy(dtype=object),
        "log": [names.get(sha, sha[:12]) for sha in runs["log_sha256"]],
        "estimators": [", ".join(s.get("estimators", [])) for s in settings],
        "heading aid": [s.get("heading", "") for s in settings],
        "R": [s.get("noise", "") for s in settings],
        "created (UTC)": runs["created_utc"].to_numpy(dtype=object),
    })


def flat_columns(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with MultiIndex columns joined into single labels (``"Gyroscope (deg/s) p"``) for display."""
    if not isinstance(table.columns, pd.MultiIndex):
        return table
    return table.set_axis([" ".join(str(part) for part in column) for column in table.columns], axis=1)


def allan_table(per_axis: Sequence, axes: Sequence[str], unit: str) -> pd.DataFrame:
    """Allan read-off figures of one IMU sensor, one row per axis.

    Parameters
    ----------
    per_axis : sequence of calib.allan.AllanFigures
        ``Calibration.allan[sensor]``.
    axes : sequence of str
        Axis labels.
    unit : str
        Unit U of the sensor's data (m/s^2, rad/s).

    Returns
    -------
    pandas.DataFrame
        Columns axis, white-noise density N [U/sqrt(Hz)], per-sample sigma N sqrt(f) [U], bias instability
        B [U], its cluster time [s], whether the floor was reached, rate random walk K [U sqrt(Hz)/s].
    """
    return pd.DataFrame([{"axis": axis, f"N [{unit}/sqrt(Hz)]": figs.white_density,
                          f"sigma per sample [{unit}]": figs.sigma_per_sample, f"B [{unit}]": figs.bias_instability,
                          "B at tau [s]": figs.bias_instability_tau_s, "floor reached": figs.floor_reached,
                          f"K [{unit} sqrt(Hz)/s]": figs.rate_random_walk}
                         for axis, figs in zip(axes, per_axis, strict=True)])


def tuning_table(cal) -> pd.DataFrame:
    """One row per estimator and identified figure: start, tuned value, unit, bounds."""
    rows = [{"estimator": name, "figure": figure, "calibrated": start, "tuned": result.figures[figure].value,
             "unit": result.figures[figure].unit, "bounds": f"{result.bounds[figure][0]:g} .. "
                                                             f"{result.bounds[figure][1]:g}"}
            for name, result in cal.tuning.items() for figure, start in result.start.items()]
    return pd.DataFrame(rows)


def tuning_nis_table(cal) -> pd.DataFrame:
    """One row per estimator and channel: mean NIS before and after the identification, and the 95 % band."""
    rows = []
    for name, result in cal.tuning.items():
        after = {c.channel: c for c in result.nis_after}
        for before in result.nis_before:
            if before.channel in after:
                now = after[before.channel]
                rows.append({"estimator": name, "channel": before.channel, "mean NIS calibrated": before.mean_nis,
                             "mean NIS tuned": now.mean_nis, "95 % band": f"{now.band[0]:.3f} .. {now.band[1]:.3f}",
                             "updates": now.n_updates})
    return pd.DataFrame(rows)
