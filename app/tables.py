"""Pure table builders for the pages (pandas in, pandas out; no Streamlit), tested directly.

Column names carry their units, as everywhere in solarnav.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from app.comparison import OTHER_REFERENCE, nis_band
from calib.figures import ChannelConsistency
from calib.fir import default_cutoff_hz
from calib.tau import COLOURED_LAG1, TauSelection
from estimators.consistency import MIN_UPDATES, NIS_WARNING_RANGE
from ingest.flightlog import FlightLog, LogMetadata

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


def duration_text(duration_s: float) -> str:
    """Duration with its units: ``"14 min 24.0 s"``, ``"1 h 02 min 05.0 s"``, ``"42.5 s"``."""
    minutes, seconds = divmod(float(duration_s), 60.0)
    hours, minutes = divmod(int(minutes), 60)
    if hours:
        return f"{hours} h {minutes:02d} min {seconds:04.1f} s"
    return f"{minutes} min {seconds:04.1f} s" if minutes else f"{seconds:.1f} s"


#: Median barometric minus GPS altitude [m] above which the Overview explains the offset.
BARO_GPS_NOTE_M = 10.0


def baro_gps_altitude_note(altitudes: dict[str, pd.Series], qnh_hpa: float | None) -> str | None:
    """A sentence explaining the median offset of the barometric altitude from the GPS altitude [m] when it exceeds
    :data:`BARO_GPS_NOTE_M` (None otherwise, or without both sources).

    The barometric altitude is a pressure altitude from the log's QNH (``SENS_BARO_QNH``, 1013.25 hPa by default):
    the day's sea-level pressure shifts it by about 8 m per hPa, so tens of metres off GPS is the weather, not a
    fault; the estimators estimate this offset (barometer-offset state)."""
    baro, gps = altitudes.get("barometer"), altitudes.get("GPS")
    if baro is None or gps is None or len(baro) < 2 or len(gps) < 2:
        return None
    gps_at_baro = np.interp(baro.index.to_numpy(float), gps.index.to_numpy(float), gps.to_numpy(float),
                            left=np.nan, right=np.nan)
    offset_m = float(np.nanmedian(baro.to_numpy(float) - gps_at_baro)) if np.isfinite(gps_at_baro).any() else np.nan
    if not np.isfinite(offset_m) or abs(offset_m) <= BARO_GPS_NOTE_M:
        return None
    qnh = f"{qnh_hpa:g} hPa" if qnh_hpa is not None else "the default 1013.25 hPa"
    return (f"The barometric altitude sits {abs(offset_m):.0f} m {'above' if offset_m > 0 else 'below'} the GPS "
            f"altitude (median). It is a pressure altitude from the log's QNH ({qnh}); a sea-level pressure "
            f"{abs(offset_m) / 8.3:.0f} hPa {'lower' if offset_m > 0 else 'higher'} than that explains it. The "
            "estimators estimate this offset; it is not a sensor fault.")


def streams_table(meta: LogMetadata) -> pd.DataFrame:
    """One row per stream: topic, samples, rate [Hz], gap count, longest gap [s] and where it starts [s], the gaps
    counted within the log's span (:func:`gaps_in_span`)."""
    rows = []
    for name, info in meta.streams.items():
        gaps = gaps_in_span(info.gaps, meta.start_time_s, meta.end_time_s)
        longest = max(gaps, key=lambda gap: gap[1]) if gaps else (np.nan, np.nan)
        rows.append({"stream": name, "topic": info.topic, "samples": info.n_samples, "rate_hz": info.rate_hz,
                     "gaps": len(gaps), "longest_gap_s": longest[1], "longest_gap_at_s": longest[0]})
    return pd.DataFrame(rows, columns=["stream", "topic", "samples", "rate_hz", "gaps", "longest_gap_s",
                                       "longest_gap_at_s"])


def gaps_in_span(gaps: Sequence[tuple[float, float]], start_s: float, end_s: float) -> list[tuple[float, float]]:
    """The ``(start_time_s, length_s)`` gaps [s] clipped to the log's span ``start_s .. end_s`` (first to last IMU
    sample, the span every page shows): a stream logged before the IMU (an ArduPilot magnetometer) has its gap
    before the start left out, not placed at a negative time since the start. A NaN bound does not clip."""
    low = start_s if np.isfinite(start_s) else -np.inf
    high = end_s if np.isfinite(end_s) else np.inf
    clipped = [(max(t0_s, low), min(t0_s + length_s, high) - max(t0_s, low)) for t0_s, length_s in gaps]
    return [(t0_s, length_s) for t0_s, length_s in clipped if length_s > 0.0]


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


def run_details(runs: pd.DataFrame, entries: Sequence, names: dict[str, str]) -> pd.DataFrame:
    """:func:`runs_table` indexed by run id with the run's short name (``names``: run id -> name) first and the
    noise source spelled out (datasheet, calibrated, or the saved calibration's full id)."""
    table = runs_table(runs, entries).set_index("run", drop=False)
    table["R"] = [{"default": "datasheet", "calibrated": "calibrated (automatic)"}.get(r, f"calibration {r}")
                  for r in table["R"]]
    return table.assign(name=[names[run_id] for run_id in table.index])[
        ["name", "estimators", "heading aid", "R", "created (UTC)", "run"]]


def flat_columns(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with MultiIndex columns joined into single labels (``"Gyroscope (deg/s) p"``, powers as
    superscripts: ``"Accelerometer (m/s²) x"``) for display."""
    if not isinstance(table.columns, pd.MultiIndex):
        return table
    return table.set_axis([pretty_unit(" ".join(str(part) for part in column)) for column in table.columns], axis=1)


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
    """One row per estimator and identified figure: start, tuned value, unit, bounds and its meaning (flagged
    "at its lower/upper bound" when the search stopped on one)."""
    rows = [{"estimator": name, "figure": figure, "calibrated": start, "tuned": result.figures[figure].value,
             "unit": result.figures[figure].unit, "bounds": f"{result.bounds[figure][0]:g} .. "
                                                             f"{result.bounds[figure][1]:g}",
             "meaning": result.figures[figure].meaning_within(result.bounds[figure])}
            for name, result in cal.tuning.items() for figure, start in result.start.items()]
    return pd.DataFrame(rows)


def tuning_nis_table(cal) -> pd.DataFrame:
    """One row per estimator and channel: mean NIS before and after the identification, the 95 % band, and the
    :func:`nis_verdict` of the tuned NIS (``verdict``, ``why``)."""
    rows = []
    for name, result in cal.tuning.items():
        after = {c.channel: c for c in result.nis_after}
        for before in result.nis_before:
            if before.channel in after:
                now = after[before.channel]
                verdict = channel_verdict(now, f"{name} {now.channel}")
                rows.append({"estimator": name, "channel": before.channel, "mean NIS calibrated": before.mean_nis,
                             "mean NIS tuned": now.mean_nis, "95 % band": f"{now.band[0]:.3f} .. {now.band[1]:.3f}",
                             "updates": now.n_updates, "verdict": verdict.level, "why": verdict.sentence})
    return pd.DataFrame(rows, columns=["estimator", "channel", "mean NIS calibrated", "mean NIS tuned", "95 % band",
                                       "updates", "verdict", "why"])


# ---------------------------------------------------------------------------------------------------- NIS verdicts
#: Verdict levels and their display colours (the dashboard's green / orange / red / grey).
VERDICT_COLORS = {"pass": "#2ca02c", "warn": "#ff7f0e", "fail": "#d62728", "not judged": "#7f7f7f"}


@dataclass(frozen=True)
class NisVerdict:
    """Pass / warn / fail of one channel's mean NIS, with its display colour and a sentence saying why."""

    level: str
    color: str
    sentence: str


def nis_verdict(label: str, mean_nis: float, band: tuple[float, float], n_updates: int) -> NisVerdict:
    """Verdict on a channel's mean NIS against its chi-square band.

    Thresholds (docs/calibration.md, 'Consistency checks'):

    * **pass**: inside the 95 % band of the mean of ``n_updates`` chi-square(1) values (``band``, inclusive);
    * **warn**: outside the band but inside :data:`estimators.consistency.NIS_WARNING_RANGE` (0.2 .. 3): the band
      ignores the time correlation of real innovations, so a long log is rarely inside it; imperfect, not wrong;
    * **fail**: outside :data:`~estimators.consistency.NIS_WARNING_RANGE`, the range outside which a replay warns
      of an inconsistent channel: R (or the model) is wrong;
    * **not judged**: fewer than :data:`estimators.consistency.MIN_UPDATES` updates or no finite NIS.

    Below 1 the innovations are smaller than the filter expects (R too pessimistic); above 1 they are larger
    (R too optimistic, or the model is wrong).
    """
    if n_updates < MIN_UPDATES or not math.isfinite(mean_nis):
        why = f"only {n_updates} updates" if n_updates < MIN_UPDATES else "no finite NIS"
        return NisVerdict("not judged", VERDICT_COLORS["not judged"],
                          f"{label}: {why}, too few to judge (needs >= {MIN_UPDATES} updates)")
    low, high = band
    text = f"{label}: mean NIS {mean_nis:.3g}"
    band_text = f"its 95 % band {low:.3g}-{high:.3g}"
    if low <= mean_nis <= high:
        return NisVerdict("pass", VERDICT_COLORS["pass"],
                          f"{text}, inside {band_text}: consistent (R matches the innovations)")
    warn_low, warn_high = NIS_WARNING_RANGE
    level = "warn" if warn_low <= mean_nis <= warn_high else "fail"
    slightly = "slightly " if level == "warn" else ""
    if mean_nis < low:
        where, meaning = "below", f"R is {slightly}too pessimistic (the filter trusts this sensor less than it could)"
    else:
        where, meaning = "above", (f"R is {slightly}too optimistic or the model is "
                                   f"{'slightly off' if slightly else 'wrong'} (the filter trusts this sensor more "
                                   "than it should)")
    if level == "warn":
        where = f"{where} {band_text} but within {warn_low:g}..{warn_high:g}"
    else:
        where = f"far {where} {band_text} (outside {warn_low:g}..{warn_high:g})"
    return NisVerdict(level, VERDICT_COLORS[level], f"{text}, {where}: {meaning}")


def channel_verdict(channel: ChannelConsistency, label: str | None = None) -> NisVerdict:
    """:func:`nis_verdict` of one channel of :func:`estimators.consistency.channel_consistency`."""
    return nis_verdict(label or channel.channel, channel.mean_nis, channel.band, channel.n_updates)


def with_nis_verdicts(summary: pd.DataFrame) -> pd.DataFrame:
    """:func:`app.comparison.nis_summary` with the 95 % band of the mean NIS of each row's updates and a
    ``verdict`` (pass / warn / fail / not judged, :func:`nis_verdict`) and ``why`` column."""
    bands = [nis_band(int(n)) if n > 0 else (math.nan, math.nan) for n in summary["updates"]]
    verdicts = [nis_verdict(f"{estimator} {sensor}", float(mean), band, int(n)) for estimator, sensor, n, mean, band
                in zip(summary["estimator"], summary["sensor"], summary["updates"], summary["mean NIS [-]"], bands,
                       strict=True)]
    out = summary.copy()
    out["95 % band [-]"] = [f"{low:.3g} .. {high:.3g}" for low, high in bands]
    out["verdict"] = [v.level for v in verdicts]
    out["why"] = [v.sentence for v in verdicts]
    return out


def verdict_style(table: pd.DataFrame, column: str = "verdict"):
    """``table`` as a pandas Styler with the ``column`` cells coloured by :data:`VERDICT_COLORS`."""
    def colour(value):
        color = VERDICT_COLORS.get(value)
        return f"background-color: {color}; color: white; font-weight: bold" if color else ""

    return table.style.map(colour, subset=[column]).format(precision=3)


# ---------------------------------------------------------------------------------------------------- auto tau
def tau_warnings(selection: TauSelection) -> list[str]:
    """Warnings on an automatic tau: its mean NIS is outside its own 95 % band (the :func:`nis_verdict`
    sentence, plus a hint when the innovations are coloured), or the search ended at a bound of its grid
    (within a tenth of a grid step). Empty for a default or user tau."""
    grid = selection.log10_tau_grid
    if not grid:
        return []
    notes = []
    verdict = nis_verdict(f"accelerometer y at tau = {selection.tau:.3g}", selection.nis_at_tau,
                          selection.nis_band, selection.n_innovations)
    if verdict.level != "pass":
        coloured = (f"; the innovations are coloured (lag-1 autocorrelation {selection.lag1_autocorrelation:.2f}"
                    f" > {COLOURED_LAG1}), so the band is too narrow" if selection.lag1_autocorrelation > COLOURED_LAG1
                    else "")
        notes.append(f"The chosen tau is outside its own 95 % NIS band: {verdict.sentence}{coloured}.")
    tolerance = (grid[-1] - grid[0]) / max(len(grid) - 1, 1) / 10.0
    chosen = math.log10(selection.tau)
    for bound, side in ((grid[0], "lower"), (grid[-1], "upper")):
        if abs(chosen - bound) <= tolerance:
            notes.append(f"The search ended at the {side} bound of its grid (tau = {10.0**bound:g}; grid "
                         f"{10.0**grid[0]:g} .. {10.0**grid[-1]:g}): the best tau may lie beyond it. Set tau by "
                         "hand or check the accelerometer calibration.")
    return notes


# ---------------------------------------------------------------------------------------------------- units
#: Sensors whose figures are displayed in another unit than they are computed in: unit -> (display unit, factor).
#: The gyroscope is shown in deg/s everywhere on the calibration page (as in the paper's Table 4); CALIB.json and
#: the PX4 .params file stay in SI (rad/s).
DISPLAY_UNITS = {"rad/s": ("deg/s", math.degrees(1.0))}


def display_unit(unit: str) -> tuple[str, float]:
    """Display unit of a figure in ``unit`` and the factor converting to it (``("deg/s", 57.3)`` for rad/s)."""
    return DISPLAY_UNITS.get(unit, (unit, 1.0))


def pretty_unit(unit: str) -> str:
    """``unit`` with its powers as superscripts: ``"m/s^2"`` -> ``"m/s²"``."""
    return unit.replace("^2", "²").replace("^3", "³")


def variance_unit(unit: str) -> str:
    """Unit of a variance of a quantity in ``unit``: ``"(m/s²)²"``, ``"(rad/s)²"``, ``"m²"``, ``"-"``."""
    if unit in ("", "-"):
        return "-"
    pretty = pretty_unit(unit)
    compound = any(mark in pretty for mark in "/*· ²³")
    return f"({pretty})²" if compound else f"{pretty}²"


def display_noise_table(table: pd.DataFrame) -> pd.DataFrame:
    """:func:`calib.tables.noise_table` (index reset) in display units (gyroscope in deg/s, :data:`DISPLAY_UNITS`)
    with powers as superscripts in the ``unit`` column."""
    out = table.copy()
    for unit, (shown, factor) in DISPLAY_UNITS.items():
        rows = out["unit"] == unit
        for column in ("eta", "beta", "sigma", "sigma_robust", "mean", "physical_bias"):
            if column in out:
                out.loc[rows, column] = out.loc[rows, column] * factor
        out.loc[rows, "unit"] = shown
    out["unit"] = out["unit"].map(pretty_unit)
    return out


def display_r_matrix(matrix: pd.DataFrame, unit: str) -> tuple[pd.DataFrame, str]:
    """An eq 51 matrix [unit^2] in display units and its heading unit (``"(deg/s)²"`` for the gyroscope)."""
    shown, factor = display_unit(unit)
    return matrix * factor**2, variance_unit(shown)


def display_allan(curves: Sequence[pd.DataFrame], readoffs: Sequence, unit: str) -> tuple[list, list, str]:
    """Allan curves (``tau_s``, ``adev``, ``adev_err``) and read-offs (calib.allan.AllanFigures) in display units."""
    shown, factor = display_unit(unit)
    if factor == 1.0:
        return list(curves), list(readoffs), shown
    scaled = [curve.assign(adev=curve["adev"] * factor, adev_err=curve["adev_err"] * factor) for curve in curves]
    figs = [dataclasses.replace(f, white_density=f.white_density * factor, bias_instability=f.bias_instability * factor,
                                rate_random_walk=f.rate_random_walk * factor) for f in readoffs]
    return scaled, figs, shown


# ---------------------------------------------------------------------------------------------------- FIR editor
def fir_editor_table(sensors: Sequence[str], rates_hz: Sequence[float], fixed_wing: bool) -> pd.DataFrame:
    """Initial rows of the FIR editor: sensor, the default cutoff it would get at its stream's rate
    (``"default (5 Hz)"``), and empty (NaN: default) ``cutoff_hz`` / ``numtaps`` cells."""
    return pd.DataFrame({
        "sensor": list(sensors),
        "default": [f"default ({default_cutoff_hz(rate, fixed_wing):.3g} Hz)" if rate > 0 else "default"
                    for rate in rates_hz],
        "cutoff_hz": np.full(len(sensors), np.nan), "numtaps": np.full(len(sensors), np.nan)})


def fir_rows(editor: pd.DataFrame) -> tuple[tuple[str, float, int], ...]:
    """Hashable FIR requests of the editor: (sensor, cutoff [Hz] or NaN for the default, taps or 0 for the
    default)."""
    def taps(value) -> int:
        return 0 if value is None or not np.isfinite(float(value)) else int(value)

    return tuple((str(row.sensor), float(row.cutoff_hz) if row.cutoff_hz is not None else math.nan,
                  taps(row.numtaps)) for row in editor.itertuples())


# ---------------------------------------------------------------------------------------------------- run comparison
#: Marks and cell colours of an RMS against the baseline run (``app.comparison`` change verdicts).
CHANGE_MARKS = {"improved": "▼", "regressed": "▲", "unchanged": "≈"}
CHANGE_COLORS = {"improved": "rgba(44,160,44,0.25)", "regressed": "rgba(214,39,40,0.25)"}


def rms_delta_cell(rms: float, delta: float, delta_pct: float, change: str, is_baseline: bool) -> str:
    """Text of one cell of :func:`rms_delta_table`: the RMS, then (not for the baseline) the difference to the
    baseline, absolute and in %, and the change mark (▼ improved, ▲ regressed, ≈ unchanged); a run against another
    reference than the baseline's has no difference (``"(other reference)"``)."""
    if not math.isfinite(rms):
        return "–"
    if is_baseline:
        return f"{rms:.2f} (baseline)"
    if change == OTHER_REFERENCE:
        return f"{rms:.2f} ({OTHER_REFERENCE})"
    if not math.isfinite(delta):
        return f"{rms:.2f} (no baseline)"
    percent = f"{delta_pct:+.1f} %" if math.isfinite(delta_pct) else "– %"
    return f"{rms:.2f} ({delta:+.2f}, {percent}) {CHANGE_MARKS.get(change, '')}".rstrip()


def rms_delta_table(comparison: pd.DataFrame, baseline: str) -> pd.DataFrame:
    """:func:`app.comparison.rms_comparison` as one row per run x estimator (index ``run``, ``estimator``; the
    baseline's rows first) and one text column per Table 2 quantity (:func:`rms_delta_cell`)."""
    cells = comparison.assign(cell=[
        rms_delta_cell(float(rms), float(delta), float(percent), str(change), run == baseline)
        for run, rms, delta, percent, change in zip(comparison["run"], comparison["RMS"], comparison["delta"],
                                                    comparison["delta [%]"], comparison["change"], strict=True)])
    return _rms_pivot(cells, "cell", baseline)


def rms_delta_style(comparison: pd.DataFrame, baseline: str):
    """:func:`rms_delta_table` as a pandas Styler: improved cells green, regressed cells red."""
    table = rms_delta_table(comparison, baseline)
    changes = _rms_pivot(comparison, "change", baseline).reindex_like(table)
    css = changes.map(lambda change: f"background-color: {CHANGE_COLORS[change]}" if change in CHANGE_COLORS
                      else "")
    return table.style.apply(lambda _: css, axis=None)


def _rms_pivot(frame: pd.DataFrame, values: str, baseline: str) -> pd.DataFrame:
    runs = list(dict.fromkeys([baseline, *frame["run"]]))
    estimators = list(dict.fromkeys(frame["estimator"]))
    quantities = list(dict.fromkeys(frame["quantity"]))
    wide = frame.pivot(index=["run", "estimator"], columns="quantity", values=values)
    order = sorted(wide.index, key=lambda key: (runs.index(key[0]), estimators.index(key[1])))
    wide = wide.reindex(index=pd.MultiIndex.from_tuples(order, names=["run", "estimator"]), columns=quantities)
    wide.columns.name = None
    return wide


def verdict_channels(verdict: dict) -> pd.DataFrame:
    """The channels behind an estimator's consistency verdict (``details["verdict"]`` of a run report,
    :class:`estimators.consistency.EstimatorVerdict` as a dict): channel, verdict, mean NIS, updates, lag-1
    autocorrelation, effective updates, accepted range and reason."""
    rows = [{"channel": c["channel"], "verdict": c["verdict"], "mean NIS [-]": c["mean_nis"],
             "updates": c["n_updates"], "lag-1 autocorrelation [-]": c["lag1_autocorrelation"],
             "independent updates": c["n_effective"],
             "accepted [-]": f"{c['accepted'][0]:.2f}..{c['accepted'][1]:.2f}", "why": c["reason"]}
            for c in verdict["channels"]]
    return pd.DataFrame(rows, columns=["channel", "verdict", "mean NIS [-]", "updates", "lag-1 autocorrelation [-]",
                                       "independent updates", "accepted [-]", "why"])
