"""Estimator states against a reference (ground truth, else the autopilot's onboard estimate): the compared
quantities on the estimators' time base, their errors, the RMS table in the layout of the paper's Table 2, and
NIS summaries of the measurement updates. Pure pandas / NumPy (no Streamlit), tested directly.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from app.figures import TimeBase
from calib.figures import chi2_quantile, mean_nis_band
from estimators.environment import geodetic_to_ned
from ingest.flightlog import FlightLog
from ingest.frames import wrap_angle_deg

#: Compared quantities in the order and with the labels of the paper's Table 2: column -> (label, unit).
QUANTITIES = {
    "roll_deg": ("Roll Angle (deg)", "deg"), "pitch_deg": ("Pitch Angle (deg)", "deg"),
    "yaw_deg": ("Yaw Angle (deg)", "deg"), "position_m": ("Position (m)", "m"), "alt_m": ("Height (m)", "m"),
    "airspeed_m_s": ("Airspeed (m/s)", "m/s"), "ground_speed_m_s": ("Ground Speed (m/s)", "m/s"),
    "course_deg": ("GPS Course (deg)", "deg"), "wind_m_s": ("Wind (m/s)", "m/s"),
}
#: The dashboard's state charts: title -> rows (column, axis title with unit), top to bottom.
STATE_PANELS = {
    "Attitude": [("roll_deg", "roll [deg]"), ("pitch_deg", "pitch [deg]"), ("yaw_deg", "yaw [deg]")],
    "Altitude and speeds": [("alt_m", "altitude [m]"), ("ground_speed_m_s", "ground speed [m/s]"),
                            ("course_deg", "course [deg]"), ("airspeed_m_s", "airspeed [m/s]")],
    "Wind": [("wind_n_m_s", "wind north [m/s]"), ("wind_e_m_s", "wind east [m/s]")],
}
#: Rows of the error charts: every :data:`QUANTITIES` column, its error with the unit.
ERROR_ROWS = [(column, f"{label.split(' (')[0].lower()} error [{unit}]")
              for column, (label, unit) in QUANTITIES.items()]
#: Angles: errors are wrapped to [-180, 180) deg.
ANGLE_COLUMNS = ("roll_deg", "pitch_deg", "yaw_deg", "course_deg")
#: Below this ground speed [m/s] the course is undefined (left NaN), as in the filters' course update.
MIN_COURSE_SPEED_M_S = 3.0
#: Reference streams by source: attitude, global position, local position (velocity), wind.
REFERENCE_STREAMS = {
    "truth": ("truth_attitude", "truth_global_position", "truth_local_position", "truth_wind"),
    "onboard": ("onboard_attitude", "onboard_global_position", "onboard_local_position", "onboard_wind"),
}
#: Probability covered by the NIS bands.
NIS_BAND_PROBABILITY = 0.95


@dataclass(frozen=True)
class Comparison:
    """Estimators and references side by side.

    Attributes
    ----------
    quantities : dict of str -> pandas.DataFrame
        Source (estimator name, ``"truth"``, ``"onboard"``) -> :func:`quantities` of its states.
    errors : dict of str -> pandas.DataFrame
        Estimator -> ``time_s`` and the error of every :data:`QUANTITIES` column against ``reference``
        (position and wind: horizontal distance [m] / vector difference [m/s]).
    reference : str or None
        ``"truth"`` when the log has ground truth, else ``"onboard"``, else None (no errors).
    """

    quantities: dict[str, pd.DataFrame]
    errors: dict[str, pd.DataFrame]
    reference: str | None


def gps_origin(log: FlightLog) -> tuple[float, float, float] | None:
    """Latitude, longitude [deg] and altitude [m] of the first good GPS fix (the local NED origin), or None."""
    if not log.has("gps"):
        return None
    fixes = log["gps"][["lat_deg", "lon_deg", "alt_m"]].dropna()
    return None if fixes.empty else tuple(float(v) for v in fixes.iloc[0])


def quantities(states: pd.DataFrame, origin: tuple[float, float, float] | None) -> pd.DataFrame:
    """The compared quantities of one source's states (columns of ``estimators.core.results.STATE_COLUMNS``).

    Returns
    -------
    pandas.DataFrame
        ``time_s`` [s], ``roll_deg``, ``pitch_deg``, ``yaw_deg`` [deg], ``north_m``, ``east_m`` [m] about
        ``origin`` (NaN without one), ``alt_m`` [m], ``ground_speed_m_s``, ``airspeed_m_s`` = |v - wind| [m/s],
        ``course_deg`` [deg] (NaN below :data:`MIN_COURSE_SPEED_M_S`), ``wind_n_m_s``, ``wind_e_m_s`` [m/s].
    """
    def column(name: str) -> np.ndarray:
        return states[name].to_numpy(dtype=float) if name in states else np.full(len(states), np.nan)

    vn, ve, vd = column("vn_m_s"), column("ve_m_s"), column("vd_m_s")
    wind_n, wind_e = column("wind_n_m_s"), column("wind_e_m_s")
    ground_speed = np.hypot(vn, ve)
    course = np.where(ground_speed >= MIN_COURSE_SPEED_M_S, np.degrees(np.arctan2(ve, vn)), np.nan)
    if origin is None:
        north = east = np.full(len(states), np.nan)
    else:
        north, east, _ = geodetic_to_ned(column("lat_deg"), column("lon_deg"), column("alt_m"), *origin)
    return pd.DataFrame({
        "time_s": column("time_s"), "roll_deg": column("roll_deg"), "pitch_deg": column("pitch_deg"),
        "yaw_deg": column("yaw_deg"), "north_m": north, "east_m": east, "alt_m": column("alt_m"),
        "ground_speed_m_s": ground_speed, "airspeed_m_s": np.sqrt((vn - wind_n) ** 2 + (ve - wind_e) ** 2 + vd**2),
        "course_deg": wrap_angle_deg(course), "wind_n_m_s": wind_n, "wind_e_m_s": wind_e,
    })


def reference_states(log: FlightLog, source: str, time_s: np.ndarray) -> pd.DataFrame | None:
    """A reference's states interpolated onto ``time_s`` [s] (NaN outside its streams; yaw unwrapped first).

    Parameters
    ----------
    log : FlightLog
        The flight.
    source : {"truth", "onboard"}
        Which reference.
    time_s : numpy.ndarray
        Times to interpolate to [s], increasing.

    Returns
    -------
    pandas.DataFrame or None
        State columns as the estimators write them; None when the log has none of the source's streams.
    """
    attitude, global_position, local_position, wind = REFERENCE_STREAMS[source]
    if not any(log.has(name) for name in REFERENCE_STREAMS[source]):
        return None
    out = {"time_s": time_s}
    wanted = {attitude: {"roll_deg": "roll_deg", "pitch_deg": "pitch_deg", "yaw_deg": "yaw_deg"},
              global_position: {"lat_deg": "lat_deg", "lon_deg": "lon_deg", "alt_m": "alt_m"},
              local_position: {"vx_m_s": "vn_m_s", "vy_m_s": "ve_m_s", "vz_m_s": "vd_m_s"},
              wind: {"wind_n_m_s": "wind_n_m_s", "wind_e_m_s": "wind_e_m_s"}}
    for stream, columns in wanted.items():
        frame = log.streams.get(stream)
        for column, name in columns.items():
            if frame is None or column not in frame or len(frame) < 2:
                out[name] = np.full(len(time_s), np.nan)
                continue
            values = frame[column].to_numpy(dtype=float)
            if name == "yaw_deg":
                values = np.degrees(np.unwrap(np.radians(values)))
            interpolated = np.interp(time_s, frame.index.to_numpy(dtype=float), values, left=np.nan, right=np.nan)
            out[name] = wrap_angle_deg(interpolated) if name == "yaw_deg" else interpolated
    return pd.DataFrame(out)


def errors(estimate: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Errors of :func:`quantities` ``estimate`` against ``reference`` on the same times: differences (angles
    wrapped), horizontal position distance [m] and wind vector difference [m/s]."""
    out = {"time_s": estimate["time_s"].to_numpy(dtype=float)}
    for column in QUANTITIES:
        if column == "position_m":
            out[column] = np.hypot(estimate["north_m"] - reference["north_m"], estimate["east_m"] - reference["east_m"])
        elif column == "wind_m_s":
            out[column] = np.hypot(estimate["wind_n_m_s"] - reference["wind_n_m_s"],
                                   estimate["wind_e_m_s"] - reference["wind_e_m_s"])
        else:
            difference = estimate[column].to_numpy(dtype=float) - reference[column].to_numpy(dtype=float)
            out[column] = wrap_angle_deg(difference) if column in ANGLE_COLUMNS else difference
    return pd.DataFrame(out)


def compare(states: pd.DataFrame, log: FlightLog) -> Comparison:
    """All estimators of a run against the log's best reference (truth, else onboard)."""
    origin = gps_origin(log)
    names = [str(name) for name in states["estimator"].unique()]
    by_name = {name: states.loc[states["estimator"] == name] for name in names}
    result = {name: quantities(frame, origin) for name, frame in by_name.items()}
    time_s = result[names[0]]["time_s"].to_numpy() if names else np.empty(0)
    reference = None
    for source in REFERENCE_STREAMS:
        ref = reference_states(log, source, time_s)
        if ref is not None:
            result[source] = quantities(ref, origin)
            reference = reference or source
    errs = {}
    if reference is not None:
        for name in names:
            own_times = by_name[name]["time_s"].to_numpy(dtype=float)
            ref = (result[reference] if np.array_equal(own_times, time_s)
                   else quantities(reference_states(log, reference, own_times), origin))
            errs[name] = errors(result[name], ref)
    return Comparison(quantities=result, errors=errs, reference=reference)


def rms_table(errs: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """RMS of every error, one row per estimator, columns labelled as the paper's Table 2 (NaN where an
    estimator or the reference lacks the quantity)."""
    rows = {name: [float(np.sqrt(np.nanmean(np.square(frame[column])))) if frame[column].notna().any()
                   else np.nan for column in QUANTITIES] for name, frame in errs.items()}
    return pd.DataFrame.from_dict(rows, orient="index", columns=[label for label, _ in QUANTITIES.values()])


def nis_band(window: int, probability: float = NIS_BAND_PROBABILITY) -> tuple[float, float]:
    """Two-sided chi-square band of the mean of ``window`` scalar NIS values of a consistent filter [-]."""
    return mean_nis_band(window, probability)


def nis_summary(diagnostics: pd.DataFrame) -> pd.DataFrame:
    """Per estimator and sensor: updates, share accepted, mean NIS and the share of single NIS values inside the
    95 % chi-square(1) bound (0.95 for a consistent filter)."""
    bound = chi2_quantile(NIS_BAND_PROBABILITY, 1)
    nis = diagnostics["nis"].to_numpy(float)
    frame = pd.DataFrame({"estimator": diagnostics["estimator"].astype("category"),
                          "sensor": diagnostics["sensor"].astype("category"), "nis": nis, "inside": nis <= bound,
                          "accepted": diagnostics["accepted"].to_numpy(dtype=bool)})
    grouped = frame.groupby(["estimator", "sensor"], sort=False, observed=True)
    return pd.DataFrame({"updates": grouped.size(), "accepted [%]": 100.0 * grouped["accepted"].mean(),
                         "mean NIS [-]": grouped["nis"].mean(),
                         "inside 95 % bound [%]": 100.0 * grouped["inside"].mean()}).reset_index().astype(
                             {"estimator": str, "sensor": str})


#: Unit of the innovations of each sensor (normalised vectors are dimensionless); exceptions per component below.
INNOVATION_UNITS = {"baro": "m", "airspeed": "m/s", "sideslip": "m/s", "gps_pos": "m", "gps_vel": "m/s",
                    "accel": "m/s^2", "wind": "m/s", "mag": "-", "sun": "-", "zero_velocity": "m/s"}
COMPONENT_UNITS = {("gps_vel", "chi"): "rad"}


def innovation_unit(sensor: str, component: str) -> str:
    """Unit of a diagnostics row's innovation (``"-"`` for normalised vectors)."""
    return COMPONENT_UNITS.get((sensor, component), INNOVATION_UNITS.get(sensor, "-"))


def moving_nis(diagnostics: pd.DataFrame, window: int) -> pd.DataFrame:
    """Moving mean of ``window`` consecutive NIS values per component (``time_s``, ``component``, ``mean_nis``);
    for a consistent filter it stays inside :func:`nis_band` (``window``) 95 % of the time."""
    parts = []
    for component, frame in diagnostics.groupby("component", sort=False, observed=True):
        nis = frame["nis"].rolling(window, min_periods=window).mean()
        parts.append(pd.DataFrame({"time_s": frame["time_s"].to_numpy(float), "component": str(component),
                                   "mean_nis": nis.to_numpy(float)}).dropna())
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["time_s", "component", "mean_nis"])


def table_download(frame: pd.DataFrame, time_base: TimeBase, suffix: str) -> bytes:
    """A run's ``states`` / ``diagnostics`` as Parquet or CSV bytes for a download: the log-clock ``time_s`` kept,
    ``time_since_start_s`` (:data:`app.figures.SINCE_START_COLUMN`) added after it."""
    out = time_base.with_since_start(frame)
    if suffix == "csv":
        return out.to_csv(index=False).encode()
    if suffix != "parquet":
        raise ValueError(f"unknown download format {suffix!r} (csv or parquet)")
    buffer = io.BytesIO()
    out.to_parquet(buffer, index=False)
    return buffer.getvalue()


# ---------------------------------------------------------------------------------------------------- several runs
#: A run whose RMS differs from the baseline's by less than this share [%] counts as unchanged.
RMS_CHANGE_TOLERANCE_PCT = 1.0
#: Verdicts of a run's RMS against the baseline's (lower is better).
IMPROVED, REGRESSED, UNCHANGED = "improved", "regressed", "unchanged"
#: Columns of :func:`rms_comparison`.
RMS_COMPARISON_COLUMNS = ("run", "estimator", "quantity", "RMS", "baseline RMS", "delta", "delta [%]", "change")


def run_names(stored: pd.DataFrame) -> dict[str, str]:
    """Readable name of every stored run (:meth:`app.workspace.Workspace.list_runs`, in its order): its ``name``
    when the catalog has one, else its run id; names shared by several runs get the run id appended."""
    ids = [str(run_id) for run_id in stored["run_id"]]
    given = list(stored["name"]) if "name" in stored else [None] * len(ids)
    names = [str(name).strip() if isinstance(name, str) and name.strip() else run_id
             for name, run_id in zip(given, ids, strict=True)]
    counts = pd.Series(names).value_counts()
    return {run_id: f"{name} ({run_id[:8]})" if counts[name] > 1 and name != run_id else name
            for run_id, name in zip(ids, names, strict=True)}


def compare_runs(states_by_run: Mapping[str, pd.DataFrame], log: FlightLog) -> dict[str, Comparison]:
    """:func:`compare` of every run (run name -> its states) of one log, in the given order."""
    return {name: compare(states, log) for name, states in states_by_run.items()}


def change_verdict(delta_pct: float, tolerance_pct: float = RMS_CHANGE_TOLERANCE_PCT) -> str:
    """:data:`IMPROVED` / :data:`REGRESSED` / :data:`UNCHANGED` of an RMS change [%] against the baseline
    (an RMS is an error: lower is better); ``""`` when it cannot be judged (NaN)."""
    if not np.isfinite(delta_pct):
        return ""
    if abs(delta_pct) < tolerance_pct:
        return UNCHANGED
    return IMPROVED if delta_pct < 0 else REGRESSED


def rms_comparison(rms_by_run: Mapping[str, pd.DataFrame], baseline: str,
                   tolerance_pct: float = RMS_CHANGE_TOLERANCE_PCT) -> pd.DataFrame:
    """Long table of the RMS errors of several runs against a baseline run.

    Parameters
    ----------
    rms_by_run : mapping of run name -> pandas.DataFrame
        :func:`rms_table` of every run (estimators as index, Table 2 labels as columns), in display order.
    baseline : str
        The run the others are compared with (one of ``rms_by_run``).
    tolerance_pct : float
        Relative change [%] below which a row is :data:`UNCHANGED`.

    Returns
    -------
    pandas.DataFrame
        :data:`RMS_COMPARISON_COLUMNS`, one row per run x estimator x quantity (runs, then estimators, then the
        Table 2 quantities in order): ``RMS`` and the baseline's ``baseline RMS`` of the same estimator and
        quantity, ``delta`` = RMS - baseline RMS (in the quantity's unit), ``delta [%]`` relative to the
        baseline RMS, ``change`` (:func:`change_verdict`). The deltas are NaN where the baseline lacks the
        estimator or quantity (or has a zero RMS, for the percentage); the baseline's own rows have zero deltas.
    """
    if baseline not in rms_by_run:
        raise KeyError(f"baseline run {baseline!r} is not among the compared runs {list(rms_by_run)}")
    reference = rms_by_run[baseline]
    rows = []
    for run, table in rms_by_run.items():
        for estimator in table.index:
            for quantity in table.columns:
                value = float(table.at[estimator, quantity])
                base = (float(reference.at[estimator, quantity])
                        if estimator in reference.index and quantity in reference.columns else np.nan)
                delta = value - base
                percent = 100.0 * delta / base if np.isfinite(base) and base != 0.0 else np.nan
                rows.append((run, str(estimator), str(quantity), value, base, delta, percent,
                             change_verdict(percent, tolerance_pct)))
    return pd.DataFrame(rows, columns=list(RMS_COMPARISON_COLUMNS))


def runs_with(stored: pd.DataFrame, estimator: str) -> list[str]:
    """Ids of the stored runs (:meth:`app.workspace.Workspace.list_runs`, in its order) that ran ``estimator``."""
    return [str(run_id) for run_id, text in zip(stored["run_id"], stored["settings_json"], strict=True)
            if estimator in json.loads(text).get("estimators", [])]


def log_rms_comparison(rms_by_log: Mapping[str, pd.DataFrame], estimator: str, baseline: str) -> pd.DataFrame:
    """:func:`rms_comparison` of one estimator across logs: ``rms_by_log`` maps a log's label (``"<log> · <run>"``)
    to its run's :func:`rms_table`; the rows of the other estimators are left out, a log whose run lacks the
    estimator (or has no reference) contributes no row."""
    return rms_comparison({label: table.loc[[estimator]] if estimator in table.index else table.iloc[:0]
                           for label, table in rms_by_log.items()}, baseline)


def nis_comparison(summaries: Mapping[str, pd.DataFrame]) -> pd.DataFrame:
    """:func:`nis_summary` of several runs (run name -> summary) as one long table with a leading ``run``
    column, the runs of each estimator and sensor next to each other (estimators and sensors in order of first
    appearance, runs in the given order)."""
    parts = [summary.assign(run=run) for run, summary in summaries.items()]
    if not parts:
        return pd.DataFrame(columns=["run", "estimator", "sensor", "updates", "accepted [%]", "mean NIS [-]",
                                     "inside 95 % bound [%]"])
    table = pd.concat(parts, ignore_index=True)
    table = table[["run", *[column for column in table.columns if column != "run"]]]
    order = {key: k for k, key in enumerate(dict.fromkeys(zip(table["estimator"], table["sensor"], strict=True)))}
    runs = {run: k for k, run in enumerate(summaries)}
    keys = [(order[(e, s)], runs[r]) for e, s, r in zip(table["estimator"], table["sensor"], table["run"],
                                                        strict=True)]
    return table.iloc[sorted(range(len(table)), key=keys.__getitem__)].reset_index(drop=True)
