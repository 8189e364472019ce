"""Reading a log the way the app stores it: the ULog plus, optionally, the sun-device CSV and its geometry JSON.

No Streamlit here: the cached adapter (:func:`app.adapters.parsed_log`) and the ``dashboard`` command share it.
"""

from __future__ import annotations

from app.workspace import Workspace
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.log_formats import load_flight_log
from ingest.sources import Source
from ingest.sun_log import load_sun_device, with_sun


def load_log(ulog: Source, sun_csv: Source | None = None, device_json: Source | None = None, *, name: str,
             max_bytes: int | None = None) -> FlightLog:
    """Parse a ULog and attach its sun-device CSV with the device geometry.

    Parameters
    ----------
    ulog, sun_csv, device_json : path or bytes
        The files (the last two optional; a geometry without currents is refused).
    name : str
        Display name of the log in messages.
    max_bytes : int, optional
        Size limit of the ULog [bytes].

    Raises
    ------
    InputError
        A file cannot be used.
    """
    log = load_flight_log(ulog, name=name, max_bytes=max_bytes)
    device = None if device_json is None else load_sun_device(device_json, name="sun-device JSON")
    if sun_csv is None:
        if device is not None:
            raise InputError("a device geometry was given without the sun-device CSV it describes",
                             source="sun-device JSON")
        return log
    return with_sun(log, sun_csv, device=device, name="sun-device CSV")


def load_stored_log(workspace: Workspace, sha256: str) -> FlightLog:
    """The log a workspace holds under ``sha256``, with its sun-device files when stored."""
    directory = workspace.log_dir(sha256)
    entry = workspace.get_log(sha256)
    sun_csv, device_json = (path if path.exists() else None
                            for path in (directory / "sun.csv", directory / "device.json"))
    return load_log(directory / "log.ulg", sun_csv, device_json, name=entry.display_name if entry else sha256[:12])
