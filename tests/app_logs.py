"""Synthetic flight logs shared by the dashboard tests."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ingest.flightlog import FlightLog, LogMetadata


def truth_only_log(n: int = 2000, rate_hz: float = 25.0, *, yaw_deg: float = 0.0) -> FlightLog:
    """A log with GPS and ground truth only: level flight north at 10 m/s in a 1 m/s northerly wind, heading
    ``yaw_deg`` [deg], from log time 10 s."""
    time_s = 10.0 + np.arange(n) / rate_hz
    index = pd.Index(time_s, name="time_s")
    lat = 35.0 + 10.0 * (time_s - time_s[0]) / 111_000.0
    return FlightLog(streams={
        "gps": pd.DataFrame({"lat_deg": lat, "lon_deg": 108.0, "alt_m": 600.0}, index=index),
        "truth_attitude": pd.DataFrame({"roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": yaw_deg}, index=index),
        "truth_global_position": pd.DataFrame({"lat_deg": lat, "lon_deg": 108.0, "alt_m": 600.0}, index=index),
        "truth_local_position": pd.DataFrame({"vx_m_s": 10.0, "vy_m_s": 0.0, "vz_m_s": 0.0}, index=index),
        "truth_wind": pd.DataFrame({"wind_n_m_s": 1.0, "wind_e_m_s": 0.0}, index=index),
    }, meta=LogMetadata(source="synthetic.ulg"))
