"""PX4 EKF2 / ArduPilot EKF3 parameters from filter figures: the mapping table, conversions, clamping, both files."""

from __future__ import annotations

import dataclasses
import math

import pytest
from test_calib_synthetic import synthetic_log

from calib.calibration import calibrate
from calib.figures import FIGURES, MEANING_LOWER_BOUND, SOURCE_ALLAN, SOURCE_STILL, SOURCE_TUNED, Figure, TuneResult
from calib.filter_figures import calibration_figures
from calib.parameter_export import (
    MAPPING,
    PARAM_TYPE_INT32,
    PARAM_TYPE_REAL32,
    UNMAPPED,
    AutopilotParam,
    ardupilot_parameters,
    autopilot_parameters,
    export_figures,
    px4_parameters,
    read_ardupilot_parm,
    read_px4_params,
    unwritten_notes,
    write_ardupilot_parm,
    write_px4_params,
)
from ingest.errors import InputError

PX4_PARAMETERS = {"EKF2_GYR_NOISE", "EKF2_ACC_NOISE", "EKF2_GYR_B_NOISE", "EKF2_ACC_B_NOISE", "EKF2_MAG_NOISE",
                  "EKF2_BARO_NOISE", "EKF2_EAS_NOISE", "EKF2_GPS_V_NOISE", "EKF2_WIND_NSD", "EKF2_GPS_P_NOISE"}
ARDUPILOT_PARAMETERS = {"EK3_GYRO_P_NSE", "EK3_ACC_P_NSE", "EK3_MAG_M_NSE", "EK3_ALT_M_NSE", "EK3_EAS_M_NSE",
                        "EK3_POSNE_M_NSE", "EK3_VELNE_M_NSE", "EK3_VELD_M_NSE", "EK3_WIND_P_NSE", "EK3_GBIAS_P_NSE",
                        "EK3_ABIAS_P_NSE"}
SQRT_12_MS = math.sqrt(0.012)


def _figures(**values) -> dict[str, Figure]:
    return {name: Figure(name, value, SOURCE_STILL, note="test") for name, value in values.items()}


FIGURES_IN_RANGE = _figures(gyro_noise_density=2e-3, accel_noise_density=0.02, gyro_bias_walk=1e-5,
                            accel_bias_walk=1e-4, mag_noise=0.02, baro_noise=0.8, airspeed_noise=1.2,
                            gps_vel_noise=0.2, wind_walk=0.05)


def test_mapping_table_covers_every_parameter_with_known_figures():
    px4 = {row.px4.name for row in MAPPING if row.px4}
    ardupilot = {row.ardupilot.name for row in MAPPING if row.ardupilot}
    assert px4 | {n for n in UNMAPPED if n.startswith("EKF2_")} == PX4_PARAMETERS
    assert ardupilot | {n for n in UNMAPPED if n.startswith("EK3_")} == ARDUPILOT_PARAMETERS
    assert not (px4 | ardupilot) & set(UNMAPPED)
    assert all(row.figure in FIGURES and (row.scale_figure is None or row.scale_figure in FIGURES) for row in MAPPING)
    assert all(spec.min_value < spec.max_value for row in MAPPING for spec in (row.px4, row.ardupilot) if spec)


@pytest.mark.parametrize(("name", "documented"), [
    # PX4 src/modules/ekf2/module.yaml, params_airspeed.yaml, params_wind.yaml, params_gyro_bias.yaml (min, max).
    ("EKF2_GYR_NOISE", (0.0001, 0.1)), ("EKF2_EAS_NOISE", (0.5, 5.0)), ("EKF2_WIND_NSD", (0.0, 1.0)),
    ("EKF2_GYR_B_NOISE", (0.0, 0.01)), ("EKF2_BARO_NOISE", (0.01, 15.0)),
    # ArduPilot libraries/AP_NavEKF3/AP_NavEKF3.cpp @Range.
    ("EK3_WIND_P_NSE", (0.01, 2.0)), ("EK3_GBIAS_P_NSE", (0.00001, 0.001)), ("EK3_ABIAS_P_NSE", (0.00001, 0.02)),
    ("EK3_MAG_M_NSE", (0.01, 0.5)), ("EK3_ALT_M_NSE", (0.01, 100.0)), ("EK3_VELNE_M_NSE", (0.05, 5.0)),
])
def test_ranges_are_the_documented_ones(name, documented):
    spec = next(s for row in MAPPING for s in (row.px4, row.ardupilot) if s and s.name == name)
    assert (spec.min_value, spec.max_value) == documented


def test_px4_conversions_by_hand():
    params = {p.name: p for p in px4_parameters(FIGURES_IN_RANGE, predict_period_s=0.01)}
    expected = {
        "EKF2_GYR_NOISE": 2e-3 / 0.1,   # density / sqrt(dt): (dt noise)^2 = N^2 dt per 10 ms step
        "EKF2_ACC_NOISE": 0.02 / 0.1,
        "EKF2_GYR_B_NOISE": 1e-5 / 0.1,  # walk / sqrt(dt) in rad/s^2
        "EKF2_ACC_B_NOISE": 1e-4 / 0.1,
        "EKF2_MAG_NOISE": 0.02, "EKF2_BARO_NOISE": 0.8, "EKF2_EAS_NOISE": 1.2, "EKF2_GPS_V_NOISE": 0.2,
        "EKF2_WIND_NSD": 0.05,          # a spectral density, P += nsd^2 dt: the walk itself
    }
    assert set(params) == set(expected)
    for name, value in expected.items():
        assert params[name].value == pytest.approx(value, rel=1e-12), name
        assert params[name].type == PARAM_TYPE_REAL32
        assert params[name].comments[0].startswith(f"{FIGURES_IN_RANGE_FIGURE[name]} = ")
        assert f"({SOURCE_STILL}: {MEANING_LOWER_BOUND}); test" in params[name].comments[0]
    assert "x / sqrt(dt) = 0.02 rad/s at dt = 10 ms" in params["EKF2_GYR_NOISE"].comments
    assert len(params["EKF2_BARO_NOISE"].comments) == 1  # nothing converted, nothing clamped


FIGURES_IN_RANGE_FIGURE = {row.px4.name: row.figure for row in MAPPING if row.px4}


def test_ardupilot_conversions_by_hand():
    params = {p.name: p.value for p in ardupilot_parameters(FIGURES_IN_RANGE, predict_period_s=0.012)}
    expected = {
        "EK3_GYRO_P_NSE": 2e-3 / SQRT_12_MS, "EK3_ACC_P_NSE": 0.02 / SQRT_12_MS,   # 0.01826 rad/s, 0.1826 m/s^2
        "EK3_GBIAS_P_NSE": 1e-5 / SQRT_12_MS, "EK3_ABIAS_P_NSE": 1e-4 / SQRT_12_MS,
        "EK3_MAG_M_NSE": 0.02, "EK3_ALT_M_NSE": 0.8, "EK3_EAS_M_NSE": 1.2,
        "EK3_VELNE_M_NSE": 0.2, "EK3_VELD_M_NSE": 0.3,                              # 1.5 x horizontal
        "EK3_WIND_P_NSE": 0.05 / SQRT_12_MS,                                        # (dt noise)^2 per step
    }
    assert params == pytest.approx(expected, rel=1e-12)
    assert params["EK3_GYRO_P_NSE"] == pytest.approx(0.0182574, rel=1e-5)
    assert params["EK3_WIND_P_NSE"] == pytest.approx(0.456435, rel=1e-5)


def test_slow_imu_sets_the_prediction_period():
    # 50 Hz IMU data cannot be averaged to a 10 ms step: EKF2 predicts every 20 ms.
    slow = {p.name: p for p in px4_parameters(FIGURES_IN_RANGE, 0.01, imu_rate_hz=50.0)}
    assert slow["EKF2_GYR_NOISE"].value == pytest.approx(2e-3 / math.sqrt(0.02))
    assert "at dt = 20 ms" in slow["EKF2_GYR_NOISE"].comments[-1]
    fast = {p.name: p.value for p in px4_parameters(FIGURES_IN_RANGE, 0.01, imu_rate_hz=1000.0)}
    assert fast["EKF2_GYR_NOISE"] == pytest.approx(0.02)
    assert fast["EKF2_BARO_NOISE"] == 0.8  # measurement noises do not depend on the period


def test_out_of_range_values_are_clamped_with_a_note():
    figures = _figures(airspeed_noise=0.2, gyro_noise_density=2e-2, wind_walk=1e-4)
    px4 = {p.name: p for p in px4_parameters(figures, 0.01)}
    assert px4["EKF2_EAS_NOISE"].value == 0.5
    assert px4["EKF2_EAS_NOISE"].comments[-1].startswith("clamped from 0.2 to 0.5 m/s: the documented range of "
                                                         "EKF2_EAS_NOISE is [0.5, 5]")
    assert px4["EKF2_GYR_NOISE"].value == 0.1 and "clamped from 0.2 to 0.1 rad/s" in px4["EKF2_GYR_NOISE"].comments[-1]
    assert px4["EKF2_WIND_NSD"].value == 1e-4 and not any("clamped" in c for c in px4["EKF2_WIND_NSD"].comments)
    ardupilot = {p.name: p for p in ardupilot_parameters(figures, 0.012)}
    # 1e-4 / sqrt(0.012) = 9.1e-4 m/s^2, below EK3_WIND_P_NSE's documented 0.01.
    assert ardupilot["EK3_WIND_P_NSE"].value == 0.01
    assert "clamped from 0.0009129 to 0.01 m/s^2" in ardupilot["EK3_WIND_P_NSE"].comments[-1]
    assert "ardupilot.org" in ardupilot["EK3_WIND_P_NSE"].comments[-1]


def test_absent_or_unusable_figures_are_left_out_and_said_so():
    figures = {**_figures(baro_noise=0.8, mag_noise=float("nan")),
               "gps_vel_noise": Figure("gps_vel_noise", 0.3, SOURCE_TUNED),
               "gps_vel_noise_scale": Figure("gps_vel_noise_scale", 2.0, SOURCE_TUNED)}
    params = {p.name: p for p in px4_parameters(figures)}
    assert set(params) == {"EKF2_BARO_NOISE", "EKF2_GPS_V_NOISE"}
    # The factor on the receiver's accuracy has no parameter: named, not multiplied in.
    assert params["EKF2_GPS_V_NOISE"].value == 0.3
    assert params["EKF2_GPS_V_NOISE"].comments[1].startswith(
        "gps_vel_noise_scale = 2 (tuned (innovation likelihood)) not carried")
    notes = unwritten_notes(figures, "px4")
    assert any(n.startswith("EKF2_GPS_P_NOISE: not written, no GNSS position noise figure in metres") for n in notes)
    assert "EKF2_MAG_NOISE: not written, no finite positive mag_noise figure" in notes
    assert not any(n.startswith("EK3_") for n in notes)
    assert any(n.startswith("EK3_POSNE_M_NSE") for n in unwritten_notes(figures, "ardupilot"))


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"predict_period_s": 0.0}, "prediction period must be > 0 s"),
    ({"predict_period_s": 0.01, "imu_rate_hz": float("nan")}, "IMU rate must be > 0 Hz"),
    ({"predict_period_s": 0.01, "autopilot": "inav"}, "autopilot must be one of"),
])
def test_bad_periods_fail(kwargs, message):
    with pytest.raises(InputError, match=message):
        autopilot_parameters(FIGURES_IN_RANGE, **{"autopilot": "px4", **kwargs})


def test_params_file_parses_back(tmp_path):
    params = [*px4_parameters(_figures(airspeed_noise=0.2, gyro_noise_density=2e-3)),
              AutopilotParam(name="EKF2_GPS_DELAY", value=110.0, type=9),
              AutopilotParam(name="SYS_AUTOSTART", value=4001, type=PARAM_TYPE_INT32, comments=("airframe",))]
    path = write_px4_params(params, tmp_path / "out.params",
                            header="from synthetic.ulg\nEKF2_GPS_P_NOISE: not written, no figure")
    text = path.read_text()
    assert text.startswith("# Onboard parameters for Vehicle 1\n#\n# from synthetic.ulg\n")
    assert "1\t1\tSYS_AUTOSTART\t4001\t6\n" in text
    assert "# EKF2_EAS_NOISE: clamped from 0.2 to 0.5 m/s" in text
    back = read_px4_params(path)
    assert list(back) == [p.name for p in params]
    for p in params:
        assert back[p.name] == dataclasses.replace(p, value=float(p.value))  # repr round-trips float64 exactly
    assert not list(tmp_path.glob(".*.tmp"))


def test_parm_file_parses_back(tmp_path):
    params = ardupilot_parameters(FIGURES_IN_RANGE | _figures(airspeed_noise=0.2))
    path = write_ardupilot_parm(params, tmp_path / "out.parm", header="EKF3 noise parameters\nsecond line")
    lines = path.read_text().splitlines()
    assert lines[:2] == ["# EKF3 noise parameters", "# second line"]
    assert f"EK3_GYRO_P_NSE {2e-3 / SQRT_12_MS!r}" in lines
    assert all(line.startswith("#") or len(line.split()) == 2 for line in lines)
    back = read_ardupilot_parm(path)
    assert list(back) == [p.name for p in params]
    assert all(back[p.name] == p for p in params)
    assert back["EK3_EAS_M_NSE"].value == 0.5 and "clamped" in back["EK3_EAS_M_NSE"].comments[-1]


def test_parm_reader_takes_mission_planner_commas_and_refuses_garbage(tmp_path):
    path = tmp_path / "in.param"
    path.write_text("# saved by Mission Planner\nEK3_MAG_M_NSE,0.05\n\nEK3_ALT_M_NSE 3\n")
    assert {n: p.value for n, p in read_ardupilot_parm(path).items()} == {"EK3_MAG_M_NSE": 0.05, "EK3_ALT_M_NSE": 3.0}
    path.write_text("EK3_MAG_M_NSE 0.05\nEK3_ALT_M_NSE three\n")
    with pytest.raises(InputError, match="line 2"):
        read_ardupilot_parm(path)
    path.write_text("EK3_MAG_M_NSE 0.05 9\n")
    with pytest.raises(InputError, match="expected NAME and VALUE"):
        read_ardupilot_parm(path)
    with pytest.raises(InputError, match="cannot read"):
        read_ardupilot_parm(tmp_path / "absent.parm")


def test_malformed_params_file_fails_with_the_line(tmp_path):
    path = tmp_path / "bad.params"
    path.write_text("# header\n1\t1\tEKF2_ACC_NOISE\t0.3\t9\n1\t1\tEKF2_GYR_NOISE\tabc\t9\n")
    with pytest.raises(InputError, match="line 3"):
        read_px4_params(path)
    path.write_text("1 1 EKF2_ACC_NOISE 0.3 9\n")  # spaces, not tabs
    with pytest.raises(InputError, match="5 tab-separated fields"):
        read_px4_params(path)
    path.write_text("1\t1\tEKF2_ACC_NOISE\t0.3\t42\n")
    with pytest.raises(InputError, match="MAV_PARAM_TYPE"):
        read_px4_params(path)


@pytest.fixture(scope="module")
def cal():
    return calibrate(synthetic_log(30.0, seed=4))


def test_export_figures_prefer_the_indirect_filters_tuned_figures(cal):
    assert export_figures(cal) == calibration_figures(cal)
    tuned = {"wind_walk": Figure("wind_walk", 0.4, SOURCE_TUNED)}
    other = TuneResult("three_stage", {"wind_walk": Figure("wind_walk", 9.0, SOURCE_TUNED)}, {}, {}, (), 0)
    with_tuning = dataclasses.replace(cal, tuning={
        "three_stage": other, "full_state_indirect": TuneResult("full_state_indirect", tuned, {}, {}, (), 3)})
    assert export_figures(with_tuning) == tuned
    assert export_figures(dataclasses.replace(cal, tuning={"three_stage": other})) == calibration_figures(cal)


def test_calibration_figures_export_consistently_with_the_sigma(cal):
    # Without a stationary segment the gyro density is sigma / sqrt(fs): EKF2_GYR_NOISE is the RMS per-sample sigma
    # averaged from 250 Hz to EKF2's 100 Hz (variance x 100 / 250), as the former px4_params export wrote it.
    figures = export_figures(cal)
    gyro = cal.sensors["gyroscope"]
    params = {p.name: p for p in px4_parameters(figures, 0.01, imu_rate_hz=gyro.fir.fs_hz)}
    if figures["gyro_noise_density"].source != SOURCE_ALLAN:
        rms_sigma = math.sqrt(sum(s * s for s in gyro.sigma) / 3)
        assert params["EKF2_GYR_NOISE"].value == pytest.approx(rms_sigma * math.sqrt(100 / gyro.fir.fs_hz))
    assert params["EKF2_GYR_NOISE"].value == pytest.approx(figures["gyro_noise_density"].value / 0.1)
    assert figures["gyro_noise_density"].source in params["EKF2_GYR_NOISE"].comments[0]
