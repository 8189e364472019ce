"""The dashboard's presentation of the one evaluator (:mod:`estimators.evaluation`): Table-2 labels and chart
rows, the RMS table, NIS summaries of the measurement updates and the comparison of several runs. Pure pandas /
NumPy (no Streamlit), tested directly.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping

import numpy as np
import pandas as pd

from app.figures import TimeBase, rows_with_data
from calib.figures import chi2_quantile, mean_nis_band
from estimators.evaluation import MIN_GROUND_SPEED_M_S, Evaluation, evaluate
from estimators.evaluation import QUANTITIES as EVALUATED
from ingest.flightlog import FlightLog

#: Compared quantities in the order and with the labels of the paper's Table 2: error column -> (label, unit).
QUANTITIES = dict(zip(EVALUATED, [
    ("Roll Angle (deg)", "deg"), ("Pitch Angle (deg)", "deg"), ("Yaw Angle (deg)", "deg"), ("Position (m)", "m"),
    ("Height (m)", "m"), ("Airspeed (m/s)", "m/s"), ("Ground Speed (m/s)", "m/s"), ("GPS Course (deg)", "deg"),
    ("Wind (m/s)", "m/s")], strict=True))
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
#: Below this ground speed [m/s] the course is undefined (left NaN), as in the filters' course update.
MIN_COURSE_SPEED_M_S = MIN_GROUND_SPEED_M_S
#: Probability covered by the NIS bands.
NIS_BAND_PROBABILITY = 0.95


def compare(states: pd.DataFrame, log: FlightLog) -> Evaluation:
    """All estimators of a run against the log's best reference (truth, else onboard), by the one evaluator's
    convention (:func:`estimators.evaluation.evaluate` with its defaults)."""
    return evaluate(states, log)


def rms_table(evaluation: Evaluation) -> pd.DataFrame:
    """:meth:`~estimators.evaluation.Evaluation.rms`, one row per estimator, columns labelled as the paper's
    Table 2 (NaN where an estimator or the reference lacks the quantity)."""
    table = evaluation.rms().rename(columns={column: label for column, (label, _) in QUANTITIES.items()})
    return table.rename_axis(None)


#: What an RMS against each reference means, in a plain sentence (every RMS table says it).
REFERENCE_SENTENCES = {
    "truth": "Errors against the ground truth.",
    "onboard": "Disagreement with the autopilot's onboard estimate (the log has no ground truth): lower means "
               "closer to the autopilot, not necessarily better.",
    None: "No reference: the log has neither ground truth nor an onboard estimate, so no errors.",
}
#: Names of the references in sentences.
REFERENCE_NAMES = {"truth": "the ground truth", "onboard": "the onboard estimate", None: "no reference"}


def reference_sentence(reference: str | None) -> str:
    """What the RMS figures against ``reference`` (``"truth"``, ``"onboard"`` or None) mean."""
    return REFERENCE_SENTENCES[reference]


def has_airspeed(log: FlightLog) -> bool:
    """Whether the log's vehicle has an airspeed: an airspeed stream with data, or a fixed-wing (whose airspeed
    the filters estimate from the wind). A multicopter without a sensor has none: its |v - wind| with the
    autopilot's zero wind is only the ground speed again."""
    return log.has("airspeed") or log.meta.is_fixed_wing


def without_absent_airspeed(frames: Mapping[str, pd.DataFrame], log: FlightLog) -> dict[str, pd.DataFrame]:
    """``frames`` (source -> quantities or errors) for charts: the ``airspeed_m_s`` column dropped when the log
    has no airspeed (:func:`has_airspeed`), so no chart draws a sensor the log does not have."""
    if has_airspeed(log):
        return dict(frames)
    return {source: frame.drop(columns="airspeed_m_s", errors="ignore") for source, frame in frames.items()}


#: Why an error chart's row may have no value (:func:`missing_rows_text`).
MISSING_ERRORS_WHY = (f"Airspeed, course and wind errors count only in flight (reference ground speed > "
                      f"{MIN_GROUND_SPEED_M_S:g} m/s); the other errors need the reference to have the quantity; "
                      "no airspeed without an airspeed sensor on a multicopter.")
#: Why a state chart's row may have no value.
MISSING_STATES_WHY = ("Neither the estimators nor the references have it (no airspeed without an airspeed sensor "
                      "on a multicopter).")
#: Why the wind chart may have no value.
MISSING_WIND_WHY = "No estimator of the run and no reference estimates the wind."


def missing_rows_text(frames: Mapping[str, pd.DataFrame], rows, why: str) -> str | None:
    """A sentence naming the chart ``rows`` (column, axis title) left out because no source has a value of them
    (:func:`app.figures.rows_with_data`), followed by ``why``; None when every row is drawn."""
    drawn = set(rows_with_data(frames, rows))
    missing = [axis_title.split(" [")[0] for column, axis_title in rows if (column, axis_title) not in drawn]
    if not missing:
        return None
    return f"Not drawn, no value in any source: {', '.join(missing)}. {why}".rstrip()


def window_caption(evaluation: Evaluation, since_start_s: float) -> str:
    """The RMS window in words, on the time since the log start (``since_start_s`` subtracted from the log
    clock)."""
    start_s, end_s = evaluation.window_s
    if not np.isfinite(start_s):
        return "no estimates"
    first = min(float(frame["time_s"].min()) for frame in evaluation.errors.values()) if evaluation.errors else start_s
    return (f"RMS over {start_s - since_start_s:.0f}-{end_s - since_start_s:.0f} s since the log start (the first "
            f"{start_s - first:.0f} s of the estimates are the filters' convergence); positions about the "
            "first good GPS fix")


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
#: Verdicts of a run's RMS against the baseline's (lower is better); :data:`OTHER_REFERENCE`: not compared, the
#: run's errors are against another reference than the baseline's (truth vs onboard estimate).
IMPROVED, REGRESSED, UNCHANGED, OTHER_REFERENCE = "improved", "regressed", "unchanged", "other reference"
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


def compare_runs(states_by_run: Mapping[str, pd.DataFrame], log: FlightLog) -> dict[str, Evaluation]:
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


def like_for_like(reference: str | None, baseline_reference: str | None) -> bool:
    """Whether RMS figures against ``reference`` compare with the baseline's against ``baseline_reference``:
    only against the same reference (truth with truth, onboard with onboard)."""
    return reference is not None and reference == baseline_reference


def rms_comparison(rms_by_run: Mapping[str, pd.DataFrame], baseline: str,
                   tolerance_pct: float = RMS_CHANGE_TOLERANCE_PCT,
                   references: Mapping[str, str | None] | None = None) -> pd.DataFrame:
    """Long table of the RMS errors of several runs against a baseline run.

    Parameters
    ----------
    rms_by_run : mapping of run name -> pandas.DataFrame
        :func:`rms_table` of every run (estimators as index, Table 2 labels as columns), in display order.
    baseline : str
        The run the others are compared with (one of ``rms_by_run``).
    tolerance_pct : float
        Relative change [%] below which a row is :data:`UNCHANGED`.
    references : mapping of run name -> str or None, optional
        Each run's reference (``"truth"`` / ``"onboard"``); a run whose reference is not the baseline's
        (:func:`like_for_like`) is not compared: NaN baseline RMS and deltas, ``change`` :data:`OTHER_REFERENCE`.
        Without it every run counts as against the baseline's reference (runs of one log).

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
        comparable = references is None or like_for_like(references.get(run), references.get(baseline))
        for estimator in table.index:
            for quantity in table.columns:
                value = float(table.at[estimator, quantity])
                base = (float(reference.at[estimator, quantity])
                        if comparable and estimator in reference.index and quantity in reference.columns else np.nan)
                delta = value - base
                percent = 100.0 * delta / base if np.isfinite(base) and base != 0.0 else np.nan
                rows.append((run, str(estimator), str(quantity), value, base, delta, percent,
                             change_verdict(percent, tolerance_pct) if comparable else OTHER_REFERENCE))
    return pd.DataFrame(rows, columns=list(RMS_COMPARISON_COLUMNS))


def runs_with(stored: pd.DataFrame, estimator: str) -> list[str]:
    """Ids of the stored runs (:meth:`app.workspace.Workspace.list_runs`, in its order) that ran ``estimator``."""
    return [str(run_id) for run_id, text in zip(stored["run_id"], stored["settings_json"], strict=True)
            if estimator in json.loads(text).get("estimators", [])]


def log_rms_comparison(rms_by_log: Mapping[str, pd.DataFrame], estimator: str, baseline: str,
                       references: Mapping[str, str | None]) -> pd.DataFrame:
    """:func:`rms_comparison` of one estimator across logs: ``rms_by_log`` maps a log's label (``"<log> · <run>"``)
    to its run's :func:`rms_table`, ``references`` to its reference; the rows of the other estimators are left
    out, a log whose run lacks the estimator (or has no reference) contributes no row, and a log against another
    reference than the baseline's is not compared (like for like only)."""
    return rms_comparison({label: table.loc[[estimator]] if estimator in table.index else table.iloc[:0]
                           for label, table in rms_by_log.items()}, baseline, references=references)


def other_reference_text(references: Mapping[str, str | None], baseline: str) -> str | None:
    """The plain sentence under a cross-log RMS table naming the logs (label -> reference) whose reference
    differs from the baseline's and why they get no improved/regressed verdict; None when all are alike."""
    others = [label for label, reference in references.items()
              if label != baseline and reference is not None and not like_for_like(reference, references[baseline])]
    if not others:
        return None
    named = "; ".join(f"{label} against {REFERENCE_NAMES[references[label]]}" for label in others)
    return (f"Not compared with the baseline, which is against {REFERENCE_NAMES[references[baseline]]}: {named}. "
            "An RMS against the autopilot's onboard estimate and one against the ground truth measure different "
            "things, so neither is better or worse than the other.")


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
