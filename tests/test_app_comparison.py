"""Comparison helpers of the dashboard (errors, Table 2 RMS, NIS bands, sun-vector angles), tested directly."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from app import comparison, sun_compare
from estimators import evaluation
from ingest.flightlog import FlightLog
from ingest.sun_device import SunDevice
from tests.app_logs import truth_only_log


def _log() -> FlightLog:
    return truth_only_log(yaw_deg=179.0)


def _estimate(log: FlightLog, name: str, yaw_deg: float, alt_offset_m: float) -> pd.DataFrame:
    time_s = np.arange(10.0, 10.0 + 79.0, 0.02)
    reference = evaluation.reference_states(log, "truth", time_s)
    return reference.assign(estimator=name, yaw_deg=yaw_deg, alt_m=reference["alt_m"] + alt_offset_m)


def test_errors_wrap_angles_and_rms_follows_table2_layout():
    log = _log()
    states = pd.concat([_estimate(log, "three_stage", -179.0, 5.0), _estimate(log, "full_state_direct", 178.0, -1.0)],
                       ignore_index=True)
    result = comparison.compare(states, log)
    assert result.reference == "truth" and set(result.quantities) == {"three_stage", "full_state_direct", "truth"}
    table = comparison.rms_table(result)
    assert list(table.columns) == [label for label, _ in comparison.QUANTITIES.values()]
    assert table.loc["three_stage", "Yaw Angle (deg)"] == pytest.approx(2.0)  # -179 vs 179 wraps to 2 deg
    assert table.loc["full_state_direct", "Yaw Angle (deg)"] == pytest.approx(1.0)
    assert table.loc["three_stage", "Height (m)"] == pytest.approx(5.0)
    assert table.loc["three_stage", "Position (m)"] == pytest.approx(0.0, abs=1e-2)  # alt shifts the tangent plane
    assert table.loc["three_stage", "Airspeed (m/s)"] == pytest.approx(0.0, abs=1e-9)
    truth = result.quantities["truth"]
    assert truth["airspeed_m_s"].iloc[0] == pytest.approx(9.0) and truth["course_deg"].iloc[0] == pytest.approx(0.0)


def test_reference_outside_its_streams_is_nan_and_course_needs_speed():
    log = _log()
    reference = evaluation.reference_states(log, "truth", np.array([0.0, 20.0, 1e4]))
    assert np.isnan(reference["roll_deg"].iloc[0]) and np.isnan(reference["roll_deg"].iloc[2])
    assert evaluation.reference_states(log, "onboard", np.array([20.0])) is None
    slow = evaluation.quantities(pd.DataFrame({"time_s": [0.0], "vn_m_s": [1.0], "ve_m_s": [1.0]}), None)
    assert np.isnan(slow["course_deg"].iloc[0]) and np.isnan(slow["north_m"].iloc[0])


def test_nis_band_and_summary():
    low, high = comparison.nis_band(100)
    assert low == pytest.approx(0.742, abs=1e-3) and high == pytest.approx(1.296, abs=1e-3)
    rng = np.random.default_rng(0)
    diagnostics = pd.DataFrame({"estimator": "e", "sensor": "baro", "component": "alt", "time_s": np.arange(5000.0),
                                "nis": rng.chisquare(1, 5000), "accepted": True})
    summary = comparison.nis_summary(diagnostics)
    assert summary.loc[0, "inside 95 % bound [%]"] == pytest.approx(95.0, abs=1.5)
    assert summary.loc[0, "mean NIS [-]"] == pytest.approx(1.0, abs=0.1)


def test_sun_body_angles_and_cell_states():
    azimuth, elevation = sun_compare.body_angles_deg(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]))
    np.testing.assert_allclose(elevation, [0.0, 90.0, 0.0])
    np.testing.assert_allclose(azimuth[[0, 2]], [0.0, 90.0])

    sun = np.array([0.9, 0.0, -np.sqrt(1 - 0.81)])  # ahead, 26 deg above the wing plane
    solution = pd.DataFrame({"sun_x": [sun[0]], "sun_y": [sun[1]], "sun_z": [sun[2]],
                             "cells_used": [0b1111111], "faulty_cells": [0b0000010]})
    states = sun_compare.cell_states(solution, SunDevice())
    assert states[0, 0] == sun_compare.CELL_LIT and states[0, 1] == sun_compare.CELL_FAULTY
    assert states[0, 4] == sun_compare.CELL_DARK  # side cell 5 faces backwards (azimuth 180 deg)


def test_no_airspeed_is_drawn_for_a_multicopter_without_an_airspeed_sensor():
    """Issue 34: an "onboard airspeed" (|v - zero wind|, the ground speed again) was drawn for an octocopter."""
    multicopter = _log()
    multicopter.meta.vehicle_type = 2  # MAV_TYPE_QUADROTOR, no airspeed stream
    states = _estimate(multicopter, "three_stage", 0.0, 0.0)
    result = comparison.compare(states, multicopter)
    frames = comparison.without_absent_airspeed(result.quantities, multicopter)
    assert set(frames) == set(result.quantities)
    assert all("airspeed_m_s" not in frame and "ground_speed_m_s" in frame for frame in frames.values())
    rows = comparison.STATE_PANELS["Altitude and speeds"]
    assert comparison.missing_rows_text(frames, rows, comparison.MISSING_STATES_WHY).startswith(
        "Not drawn, no value in any source: airspeed. ")
    for vehicle_type, streams in ((1, {}), (2, {"airspeed": pd.DataFrame({"airspeed_m_s": [12.0]}, index=[10.0])})):
        log = FlightLog(streams={**multicopter.streams, **streams}, meta=multicopter.meta)
        log.meta.vehicle_type = vehicle_type  # a fixed-wing, or a multicopter with an airspeed sensor
        assert comparison.has_airspeed(log)
        assert all("airspeed_m_s" in frame for frame in comparison.without_absent_airspeed(
            result.quantities, log).values())
    assert comparison.missing_rows_text(result.quantities, rows, "") is None
