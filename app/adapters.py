"""Cached adapters between the pages and the library (the only place the app calls ingest/calib/estimators).

Caching rules (issue 7, conventions 2.7 and practice 7):

* ``st.cache_resource`` for parsed logs and stored runs, keyed by the log's content SHA-256 (or the run id): big,
  shared, never mutated by a page, and not worth pickling on every rerun;
* ``st.cache_data`` for derived frames (tracks, phases, ...), keyed by the content hash plus the settings that
  change them, so re-visiting a page or changing a plot option recomputes nothing that did not change.

Every function takes the workspace root as a string so the cache key names the workspace too.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
import pandas as pd
import streamlit as st

from app import comparison, runs, samples, tables
from app.loading import load_log
from app.workspace import LogEntry, Workspace
from calib.calibration import Calibration, FirSettings, allan_curves, sensor_samples, with_tau
from calib.export import read_calibration
from calib.fir import design_fir, edge_slice, zero_phase_lowpass
from calib.segments import (
    ACCEL_COLUMNS,
    GYRO_COLUMNS,
    Segment,
    auto_segments,
    find_stationary_segments,
    find_steady_segments,
    user_segment,
)
from calib.tau import TauSelection, user_tau
from estimators.api import DEFAULT_ESTIMATORS
from estimators.environment import geodetic_to_ned
from estimators.evaluation import Evaluation, position_origin
from estimators.sun.prediction import sun_vector_table
from ingest.flightlog import FlightLog
from ingest.quality import assess_input_quality
from workflows.calibration import choose_tau_by_replay, identify_noise, measure_noise
from workflows.exports import ardupilot_replay_text, ardupilot_text, calibration_text, px4_replay_text, px4_text

#: Bytes per MB in Streamlit's ``server.maxUploadSize``.
BYTES_PER_MB = 1024 * 1024


@st.cache_resource(show_spinner=False)
def open_workspace(root: str) -> Workspace:
    """The workspace at ``root`` (opened, and recovered from interrupted writes, once per server process)."""
    return Workspace(root)


@st.cache_resource(show_spinner="Adding the bundled sample logs to the workspace ...")
def bundled_logs(root: str) -> list[LogEntry]:
    """Catalog entries of the bundled sample logs, added to the workspace on first start."""
    return samples.add_samples(open_workspace(root))


def max_upload_bytes() -> int:
    """The configured upload limit [bytes] (``server.maxUploadSize`` in ``.streamlit/config.toml``)."""
    return int(st.get_option("server.maxUploadSize")) * BYTES_PER_MB


@st.cache_resource(max_entries=4, show_spinner="Reading the flight log ...")
def parsed_log(sha256: str, sun_sha256: str | None, device_sha256: str | None, name: str, _ulog,
               _sun_csv: bytes | None = None, _device_json: bytes | None = None) -> FlightLog:
    """Parse a ULog and attach its sun-device CSV (with its device geometry), cached by the content hashes, so an
    upload that was just validated is not parsed again when it is opened from the workspace.

    Parameters
    ----------
    sha256, sun_sha256, device_sha256 : str
        Content hashes of the ULog, the sun CSV and the device JSON (None when absent): the cache key.
    name : str
        Display name (sanitised) used in messages.
    _ulog : path or bytes
        The ULog (not hashed).
    _sun_csv, _device_json : bytes, optional
        The sun-device CSV and geometry JSON (not hashed).

    Raises
    ------
    InputError
        A file cannot be used (pages show it with :func:`app.session.input_errors`).
    """
    return load_log(_ulog, _sun_csv, _device_json, name=name, max_bytes=max_upload_bytes())


def validate_upload(content: bytes, name: str, sun_csv: bytes | None, device_json: bytes | None) -> FlightLog:
    """Parse an upload before it is stored (the parsed log stays cached) and return it, its reader warnings in
    ``meta.warnings``; InputError when it is unusable."""
    return parsed_log(_sha256(content), _sha256(sun_csv), _sha256(device_json), name, content, sun_csv,
                      device_json)


def stored_log(root: str, sha256: str) -> FlightLog:
    """The parsed log a workspace holds under ``sha256`` (cached)."""
    workspace = open_workspace(root)
    entry = workspace.get_log(sha256)
    directory = workspace.log_dir(sha256)
    sun_csv, device_json = (path.read_bytes() if path.exists() else None
                            for path in (directory / "sun.csv", directory / "device.json"))
    return parsed_log(sha256, _sha256(sun_csv), _sha256(device_json), entry.display_name if entry else sha256[:12],
                      directory / "log.ulg", sun_csv, device_json)


def _sha256(content: bytes | None) -> str | None:
    return None if content is None else hashlib.sha256(content).hexdigest()


@st.cache_data(max_entries=8, show_spinner=False)
def tracks_ned(root: str, sha256: str) -> dict[str, pd.DataFrame]:
    """Flight track of every position source in local NED about the first good GPS fix.

    Returns
    -------
    dict of str -> pandas.DataFrame
        Source label (``"GPS"``, ``"onboard"``, ``"truth"``) -> columns ``time_s`` [s], ``north_m``, ``east_m``,
        ``down_m`` [m]. Without GPS, the onboard local position (PX4's own origin) is returned alone.
    """
    log = stored_log(root, sha256)
    out: dict[str, pd.DataFrame] = {}
    origin = position_origin(log)
    if origin is not None:
        out["GPS"] = _geodetic_track(log["gps"].dropna(subset=["lat_deg", "lon_deg", "alt_m"]), origin)
    for label in ("onboard", "truth"):
        global_name, local_name = f"{label}_global_position", f"{label}_local_position"
        if origin is not None and log.has(global_name):
            out[label] = _geodetic_track(log[global_name].dropna(subset=["lat_deg", "lon_deg"]), origin)
        elif log.has(local_name):
            local = log[local_name]
            out[label] = pd.DataFrame({"time_s": local.index.to_numpy(float), "north_m": local["x_m"].to_numpy(),
                                       "east_m": local["y_m"].to_numpy(), "down_m": local["z_m"].to_numpy()})
    return out


def _geodetic_track(frame: pd.DataFrame, origin: tuple[float, float, float]) -> pd.DataFrame:
    north, east, down = geodetic_to_ned(frame["lat_deg"].to_numpy(float), frame["lon_deg"].to_numpy(float),
                                        frame["alt_m"].to_numpy(float), *origin)
    return pd.DataFrame({"time_s": frame.index.to_numpy(float), "north_m": north, "east_m": east, "down_m": down})


@st.cache_data(max_entries=8, show_spinner=False)
def altitudes(root: str, sha256: str) -> dict[str, pd.Series]:
    """Altitude above MSL [m] of every source that has one (GPS, barometer, onboard, truth), by label."""
    log = stored_log(root, sha256)
    sources = {"GPS": "gps", "barometer": "baro", "onboard": "onboard_global_position",
               "truth": "truth_global_position"}
    return {label: log[stream]["alt_m"].dropna() for label, stream in sources.items() if log.has(stream)}


@st.cache_data(max_entries=8, show_spinner="Finding flight phases ...")
def flight_phases(root: str, sha256: str) -> pd.DataFrame:
    """Flight phases (stationary, steady cruise, manoeuvring) from the calibration segment search."""
    log = stored_log(root, sha256)
    return tables.phase_table(find_stationary_segments(log), find_steady_segments(log),
                              log.meta.start_time_s, log.meta.end_time_s)


@st.cache_data(max_entries=8, show_spinner=False)
def input_quality(root: str, sha256: str) -> list[dict]:
    """The log's input quality findings (:func:`ingest.quality.assess_input_quality`) as dicts (kind, severity,
    stream, message, value, threshold, unit), refused ones first."""
    return [dataclasses.asdict(finding) for finding in assess_input_quality(stored_log(root, sha256))]


# ---------------------------------------------------------------------------------------------------- calibration
#: FIR requests as hashable rows: (sensor, cutoff [Hz] or NaN for the default, taps or 0 for the default).
FirRows = tuple[tuple[str, float, int], ...]


@st.cache_resource(max_entries=4, show_spinner=False)
def imu_norms(root: str, sha256: str) -> pd.DataFrame:
    """Norms of the gyro [rad/s] and specific force [m/s^2] over the whole log (index ``time_s`` [s]), for picking
    a calibration segment. A resource (not pickled per rerun): full-rate, read-only."""
    imu = stored_log(root, sha256)["imu"]
    return pd.DataFrame({"gyro_norm_rad_s": np.linalg.norm(imu[list(GYRO_COLUMNS)].to_numpy(float), axis=1),
                         "accel_norm_m_s2": np.linalg.norm(imu[list(ACCEL_COLUMNS)].to_numpy(float), axis=1)},
                        index=imu.index)


@st.cache_data(max_entries=8, show_spinner="Searching stationary and steady segments ...")
def candidate_segments(root: str, sha256: str) -> pd.DataFrame:
    """Automatically found calibration segments (``kind``, ``start_s``, ``end_s``, ``reason``), best first."""
    found = auto_segments(stored_log(root, sha256))
    return pd.DataFrame([(s.kind, s.start_s, s.end_s, s.reason) for s in found],
                        columns=["kind", "start_s", "end_s", "reason"])


def _segment(log: FlightLog, window: tuple[float, float] | None) -> Segment | None:
    return None if window is None else user_segment(log, *window)


@st.cache_data(max_entries=16, show_spinner="Calibrating the sensors ...")
def calibration(root: str, sha256: str, window: tuple[float, float] | None, fir: FirRows,
                noise: str) -> Calibration:
    """:func:`workflows.calibration.measure_noise` of a stored log over ``window`` [s] (None: automatic segments).

    Parameters
    ----------
    fir : tuple of (sensor, cutoff_hz, numtaps)
        Filter requests; NaN cutoff / 0 taps mean the rate-based default.
    noise : {"sigma", "eta"}
        Figure the eq 51 R matrices are built from.
    """
    log = stored_log(root, sha256)
    settings = {sensor: FirSettings(None if np.isnan(cutoff) else float(cutoff), int(taps) or None)
                for sensor, cutoff, taps in fir}
    return measure_noise(log, segment=_segment(log, window), fir=settings, noise=noise)


@st.cache_data(max_entries=16, show_spinner=False)
def raw_and_filtered(root: str, sha256: str, sensor: str, segment: tuple[float, float], fs_hz: float,
                     cutoff_hz: float, numtaps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times [s], raw and zero-phase filtered samples (n, k) of ``sensor`` in its calibration segment, edges the
    filter cannot reach dropped (as in the calibration itself)."""
    log = stored_log(root, sha256)
    time_s, values = sensor_samples(log, sensor, Segment(*segment, kind="user", reason="display"))
    spec = design_fir(fs_hz, cutoff_hz, numtaps)
    keep = edge_slice(len(time_s), spec)
    return time_s[keep], values[keep], zero_phase_lowpass(values, spec)[keep]


@st.cache_data(max_entries=8, show_spinner="Computing Allan deviations ...")
def allan(root: str, sha256: str, window: tuple[float, float] | None, fir: FirRows,
          noise: str) -> dict[str, list[pd.DataFrame]]:
    """Allan deviation curves behind a calibration (empty without a stationary segment)."""
    return allan_curves(stored_log(root, sha256), calibration(root, sha256, window, fir, noise))


#: Most automatic tau selections kept (:func:`auto_tau`).
MAX_TAU_SELECTIONS = 8


@st.cache_resource(show_spinner=False)
def _tau_selections() -> dict[tuple, TauSelection]:
    """The server's automatic tau selections by their settings, oldest first (kept outside ``st.cache_data``: its
    replay of elements refuses the progress bar drawn while one is computed)."""
    return {}


def auto_tau(root: str, sha256: str, window: tuple[float, float] | None, fir: FirRows, noise: str,
             method: str, progress: Callable[[int], None] | None = None) -> TauSelection:
    """Tau chosen by replaying the three-stage estimator (:func:`workflows.calibration.choose_tau_by_replay`, as the
    ``calibrate`` command does), with the evidence curves; ``progress`` is told the replays made while it is
    computed (the last :data:`MAX_TAU_SELECTIONS` are kept)."""
    selections = _tau_selections()
    key = (root, sha256, window, fir, noise, method)
    if key not in selections:
        selections[key] = choose_tau_by_replay(stored_log(root, sha256), calibration(root, sha256, window, fir, noise),
                                               method, progress)
        for oldest in list(selections)[:-MAX_TAU_SELECTIONS]:
            selections.pop(oldest, None)
    return selections[key]


def with_tau_value(cal: Calibration, tau: float | TauSelection) -> Calibration:
    """The calibration with a user-set tau or an automatic selection (accelerometer R rebuilt; cheap)."""
    return with_tau(cal, tau if isinstance(tau, TauSelection) else user_tau(tau))


#: The files of a calibration the page offers: file name -> (button label, MIME type).
CALIBRATION_FILES = {
    "CALIB.json": ("CALIB.json", "application/json"),
    "solarnav_ekf2.params": ("PX4 EKF2 .params", "text/plain"),
    "solarnav_ek3.parm": ("ArduPilot EKF3 .parm", "text/plain"),
    "replay_params.txt": ("PX4 ekf2 replay_params.txt", "text/plain"),
    "solarnav_replay.param": ("ArduPilot Replay --param-file", "text/plain"),
}


def calibration_files(root: str, sha256: str, cal: Calibration) -> dict[str, str]:
    """File name (:data:`CALIBRATION_FILES`) -> text of every file of a calibration, for either log format
    (:mod:`workflows.exports`, as the CLI writes them)."""
    parameters = stored_log(root, sha256).meta.parameters
    return {"CALIB.json": calibration_text(cal), "solarnav_ekf2.params": px4_text(cal, parameters),
            "solarnav_ek3.parm": ardupilot_text(cal, parameters),
            "replay_params.txt": px4_replay_text(cal, parameters),
            "solarnav_replay.param": ardupilot_replay_text(cal, parameters)}


@dataclasses.dataclass(frozen=True)
class IdentificationJob:
    """A noise identification running (or done) in the background: its future (the calibration with the
    identified noise), when it started (``time.monotonic()`` [s]) and its replays so far (estimator -> (replays
    done, budget)), filled in by the identification's threads."""

    future: Future
    started_s: float
    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    replays: dict[str, tuple[int, int]] = dataclasses.field(default_factory=dict)

    def progress(self) -> tuple[float, str]:
        """Share of the replay budgets spent (0..1) and what is being done: ``three_stage 12/40 replays, ...``."""
        if not self.replays:
            return 0.0, "Preparing the replays (in-flight bias, replay inputs) ..."
        shares = [min(done / budget, 1.0) for done, budget in (self.replays.get(name, (0, 1))
                                                                 for name in self.estimators)]
        text = ", ".join(f"{name} {self.replays[name][0]}/{self.replays[name][1]} replays" if name in self.replays
                         else f"{name} waiting" for name in self.estimators)
        return sum(shares) / len(shares), f"Identifying the noise: {text}"


@st.cache_resource(show_spinner=False)
def _identification_jobs() -> tuple[ThreadPoolExecutor, dict[tuple[str, str, str], IdentificationJob]]:
    """The server's one identification worker and its jobs by (workspace, log, calibration digest): a job keeps
    running when its page is left, and the page finds it again."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="identify"), {}


def identification(root: str, sha256: str, cal: Calibration, cal_digest: str) -> IdentificationJob:
    """The identification of ``cal``'s noise on a stored log (:func:`workflows.calibration.identify_noise`, as
    ``solarnav calibrate --tune``), started in the background on first call (again after a failure)."""
    pool, jobs = _identification_jobs()
    key = (root, sha256, cal_digest)
    job = jobs.get(key)
    if job is None or (job.future.done() and job.future.exception() is not None):
        replays: dict[str, tuple[int, int]] = {}

        def note(estimator: str, done: int, budget: int) -> None:  # estimators.tuning.TuneProgress
            replays[estimator] = (done, budget)

        started_s = time.monotonic()
        future = pool.submit(identify_noise, stored_log(root, sha256), cal, DEFAULT_ESTIMATORS, progress=note)
        job = jobs[key] = IdentificationJob(future, started_s, DEFAULT_ESTIMATORS, replays)
    return job


# ---------------------------------------------------------------------------------------------------- estimators
@st.cache_resource(max_entries=8, show_spinner="Loading the estimator run ...")
def run_table(root: str, run_id: str, table: str) -> pd.DataFrame:
    """The ``"states"`` or ``"diagnostics"`` of a stored run (a resource: large, read-only, never pickled per
    rerun; the diagnostics are only read when a page shows them)."""
    return open_workspace(root).load_run_table(run_id, table)


@st.cache_data(max_entries=16, show_spinner=False)
def run_report(root: str, run_id: str) -> dict:
    """The per-estimator report of a stored run."""
    return open_workspace(root).load_run_report(run_id)


@st.cache_resource(max_entries=4, show_spinner="Comparing with the reference ...")
def run_comparison(root: str, sha256: str, run_id: str) -> Evaluation:
    """The run's estimators against the log's reference (the one evaluator, :func:`app.comparison.compare`)."""
    return comparison.compare(run_table(root, run_id, "states"), stored_log(root, sha256))


@st.cache_data(max_entries=16, show_spinner=False)
def rms_table(root: str, sha256: str, run_id: str) -> pd.DataFrame:
    """RMS errors in the layout of the paper's Table 2 (empty without a reference)."""
    return comparison.rms_table(run_comparison(root, sha256, run_id))


@st.cache_data(max_entries=16, show_spinner=False)
def nis_summary(root: str, run_id: str) -> pd.DataFrame:
    """Per estimator and sensor: updates, accepted share, mean NIS, share inside the 95 % bound."""
    return comparison.nis_summary(run_table(root, run_id, "diagnostics"))


@st.cache_data(max_entries=16, show_spinner=False)
def moving_nis(root: str, run_id: str, estimator: str, sensor: str, window: int) -> pd.DataFrame:
    """Moving mean NIS of one estimator's sensor (:func:`app.comparison.moving_nis`)."""
    return comparison.moving_nis(sensor_diagnostics(root, run_id, estimator, sensor), window)


def sensor_diagnostics(root: str, run_id: str, estimator: str, sensor: str) -> pd.DataFrame:
    """Diagnostics rows of one estimator and sensor of a stored run."""
    diagnostics = run_table(root, run_id, "diagnostics")
    return diagnostics.loc[(diagnostics["estimator"] == estimator) & (diagnostics["sensor"] == sensor)]


def run_calibration(root: str, sha256: str, noise: str) -> Calibration | None:
    """The calibration a run's ``noise`` setting names: None for the default noise, the automatic calibration of
    the log, or a calibration saved in the workspace."""
    if noise == runs.DEFAULT_NOISE:
        return None
    if noise == runs.AUTO_CALIBRATION:
        return calibration(root, sha256, None, (), "sigma")
    return read_calibration(open_workspace(root).calibration_path(noise))


def flight_report_html(root: str, sha256: str, settings: dict) -> str:
    """The self-contained HTML flight report (as ``solarnav report``) of a log replayed with a stored run's
    settings: its estimators, heading aid, output rate and calibration (a datasheet run's report is calibrated from
    the flight, as the command's)."""
    from app.report import render_report  # plotly's offline page: only this download needs it
    from workflows.report import flight_report

    defaults = runs.RunSettings()
    calibration = run_calibration(root, sha256, settings.get("noise", defaults.noise))
    return render_report(flight_report(stored_log(root, sha256), calibration=calibration,
                                       estimators=tuple(settings.get("estimators", defaults.estimators)),
                                       heading=settings.get("heading", defaults.heading),
                                       rate_hz=float(settings.get("rate_hz", defaults.rate_hz))))


# ---------------------------------------------------------------------------------------------------- sun vector
@st.cache_data(max_entries=8, show_spinner="Solving the sun vector ...")
def sun_table(root: str, sha256: str) -> pd.DataFrame:
    """Solved and predicted sun vector of every photocell sample
    (:func:`estimators.sun.prediction.sun_vector_table`)."""
    return sun_vector_table(stored_log(root, sha256))
