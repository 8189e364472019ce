"""Cached adapters between the pages and the library (the only place the app calls ingest/calib/estimators).

Caching rules (issue 7, conventions 2.7 and practice 7):

* ``st.cache_resource`` for parsed logs and stored runs, keyed by the log's content SHA-256 (or the run id): big,
  shared, never mutated by a page, and not worth pickling on every rerun;
* ``st.cache_data`` for derived frames (tracks, phases, ...), keyed by the content hash plus the settings that
  change them, so re-visiting a page or changing a plot option recomputes nothing that did not change.

Every function takes the workspace root as a string so the cache key names the workspace too.
"""

from __future__ import annotations

import hashlib
import io
import json

import pandas as pd
import streamlit as st

from app import samples, tables
from app.workspace import LogEntry, Workspace
from calib.segments import find_stationary_segments, find_steady_segments
from estimators.environment import geodetic_to_ned
from ingest import FlightLog, InputError, SunDevice, load_flight_log
from ingest.sun_log import with_sun

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
def parsed_log(sha256: str, sun_sha256: str | None, name: str, _ulog, _sun_csv: bytes | None = None) -> FlightLog:
    """Parse a ULog and attach its sun-device CSV, cached by content hashes, so an upload that was just validated
    is not parsed again when it is opened from the workspace.

    Parameters
    ----------
    sha256, sun_sha256 : str
        Content hashes of the ULog and of the sun CSV (None without one): the cache key.
    name : str
        Display name (sanitised) used in messages.
    _ulog : path or bytes
        The ULog (not hashed).
    _sun_csv : bytes, optional
        The sun-device CSV (not hashed).

    Raises
    ------
    InputError
        The file or the CSV cannot be used (pages show it with :func:`app.session.input_errors`).
    """
    log = load_flight_log(_ulog, name=name, max_bytes=max_upload_bytes())
    return log if _sun_csv is None else with_sun(log, io.BytesIO(_sun_csv), name="sun-device CSV")


def validate_upload(content: bytes, name: str, sun_csv: bytes | None, device_json: bytes | None) -> None:
    """Parse an upload before it is stored (the parsed log stays cached); InputError when it is unusable."""
    parsed_log(_sha256(content), _sha256(sun_csv), name, content, sun_csv)
    if device_json is not None:
        sun_device_from_json(device_json)


def stored_log(root: str, sha256: str) -> FlightLog:
    """The parsed log a workspace holds under ``sha256`` (cached)."""
    workspace = open_workspace(root)
    entry = workspace.get_log(sha256)
    directory = workspace.log_dir(sha256)
    sun_path = directory / "sun.csv"
    sun_csv = sun_path.read_bytes() if sun_path.exists() else None
    return parsed_log(sha256, _sha256(sun_csv), entry.display_name if entry else sha256[:12], directory / "log.ulg",
                      sun_csv)


def stored_device(root: str, sha256: str) -> SunDevice:
    """The sun-device geometry stored with a log (``device.json``), else the default device."""
    path = open_workspace(root).log_dir(sha256) / "device.json"
    return sun_device_from_json(path.read_bytes()) if path.exists() else SunDevice()


def sun_device_from_json(content: bytes) -> SunDevice:
    """A :class:`~ingest.sun_device.SunDevice` from its JSON (keys: its field names); InputError when invalid."""
    try:
        data = json.loads(content)
        return SunDevice(**{key: tuple(value) if isinstance(value, list) else value for key, value in data.items()})
    except (ValueError, TypeError, AttributeError) as exc:
        raise InputError(f"not a sun-device geometry ({exc})", source="device JSON") from exc


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
    origin = None
    if log.has("gps"):
        gps = log["gps"].dropna(subset=["lat_deg", "lon_deg", "alt_m"])
        if len(gps):
            origin = tuple(float(v) for v in gps[["lat_deg", "lon_deg", "alt_m"]].iloc[0])
            out["GPS"] = _geodetic_track(gps, origin)
    for label, prefix in (("onboard", "onboard"), ("truth", "truth")):
        global_name, local_name = f"{prefix}_global_position", f"{prefix}_local_position"
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
