"""CALIB.json round trip and validation; PX4 .params values, semantics and parse-back."""

from __future__ import annotations

import copy
import dataclasses
import json
import math

import numpy as np
import pytest
from test_calib_synthetic import synthetic_log

from calib.allan import AllanFigures
from calib.bias import InflightBias
from calib.calibration import calibrate, with_tau
from calib.export import SCHEMA, calibration_from_dict, calibration_to_dict, read_calibration, write_calibration
from calib.px4_params import PARAM_TYPE_REAL32, Px4Param, px4_parameters, read_px4_params, write_px4_params
from calib.tau import TauSelection
from ingest.errors import InputError


@pytest.fixture(scope="module")
def cal():
    inflight = InflightBias(source="full_state_indirect", window_s=(130.0, 160.0), gyro_bias_rad_s=(0.01, -0.02, 0.0),
                            gyro_bias_std_rad_s=(1e-3, 1e-3, 1e-3))
    tau = TauSelection(tau=2.0, method="likelihood", log10_tau_grid=(-1.0, 0.5, 2.0),
                       neg_log_likelihood=(3.0, 1.0, 2.0), mean_nis=(5.0, 1.0, 0.1), n_innovations=100,
                       nis_at_tau=1.02, nis_band=(0.75, 1.3), lag1_autocorrelation=0.1)
    return with_tau(calibrate(synthetic_log(30.0, seed=4), inflight_bias=inflight), tau)


def test_json_round_trip(cal, tmp_path):
    path = write_calibration(cal, tmp_path / "CALIB.json")
    data = json.loads(path.read_text())  # strict JSON (NaN written as null)
    assert data["schema"] == SCHEMA
    assert data["r"]["gyroscope"]["role"] == "input" and data["r"]["barometer"]["role"] == "measurement"
    back = read_calibration(path)
    assert back.sensors == cal.sensors
    assert back.r == cal.r
    assert back.inflight_bias == cal.inflight_bias
    assert back.tau == cal.tau
    assert back.stationary_bias == cal.stationary_bias
    assert (back.source, back.sha256, back.vehicle_type, back.noise) == (cal.source, cal.sha256, 1, "sigma")
    # Allan figures hold NaN (no random walk), which never compares equal: compare the JSON forms.
    assert calibration_to_dict(back) == calibration_to_dict(cal)
    assert math.isnan(back.allan["gyroscope"][0].rate_random_walk)
    assert not list(tmp_path.glob(".*.tmp"))  # the temporary file was moved into place


def test_hand_edited_r_is_honoured(cal):
    data = calibration_to_dict(cal)
    data["r"]["barometer"]["matrix"] = [[4.0]]
    assert calibration_from_dict(data).r_matrix("barometer").tolist() == [[4.0]]


def _without(data, path):
    data = copy.deepcopy(data)
    *parents, key = path.split(".")
    node = data
    for parent in parents:
        node = node[parent]
    del node[key]
    return data


@pytest.mark.parametrize("path", ["schema", "sensors", "sensors.gyroscope.sigma", "sensors.gyroscope.filter.numtaps",
                                  "tau.value", "stationary_bias", "stationary_bias.gyro_bias_rad_s", "r",
                                  "allan", "source.sha256"])
def test_missing_keys_fail_naming_the_key(cal, path):
    with pytest.raises(InputError) as err:
        calibration_from_dict(_without(calibration_to_dict(cal), path))
    assert err.value.field == path
    assert "missing key" in str(err.value)


@pytest.mark.parametrize(("schema", "message"), [("solarnav.calibration/2", "version '2' is not supported"),
                                                 ("other.tool/1", "not a solarnav calibration")])
def test_unknown_schema_fails_clearly(cal, tmp_path, schema, message):
    data = calibration_to_dict(cal)
    data["schema"] = schema
    path = tmp_path / "CALIB.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=message) as err:
        read_calibration(path)
    assert err.value.source == str(path) and err.value.field == "schema"


@pytest.mark.parametrize(("edit", "field"), [
    (lambda d: d["sensors"]["gyroscope"].update(sigma=[1.0, 2.0]), "sensors.gyroscope.sigma"),
    (lambda d: d["sensors"]["gyroscope"].update(sigma=["a", 1.0, 2.0]), "sensors.gyroscope.sigma[0]"),
    (lambda d: d["r"]["gyroscope"].update(matrix=[[1.0, 0.0], [0.0]]), "r.gyroscope.matrix"),
    (lambda d: d["r"]["gyroscope"].update(matrix=[[-1.0]]), "r.gyroscope.matrix"),
    (lambda d: d["tau"].update(value=0), "tau.value"),
    (lambda d: d.update(noise_choice="max"), "noise_choice"),
    (lambda d: d["sensors"].update(lidar=d["sensors"]["barometer"]), "sensors"),
])
def test_wrong_values_fail_naming_the_key(cal, edit, field):
    data = calibration_to_dict(cal)
    edit(data)
    with pytest.raises(InputError) as err:
        calibration_from_dict(data)
    assert err.value.field == field


def test_unreadable_or_invalid_json_fails(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        read_calibration(tmp_path / "absent.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_calibration(bad)
    bad.write_text("[]")
    with pytest.raises(InputError, match="expected an object"):
        read_calibration(bad)


def test_px4_parameters_follow_ekf2_unit_semantics(cal):
    params = {p.name: p for p in px4_parameters(cal, predict_period_s=0.01)}
    assert set(params) == {"EKF2_ACC_NOISE", "EKF2_GYR_NOISE", "EKF2_MAG_NOISE", "EKF2_BARO_NOISE",
                           "EKF2_EAS_NOISE", "EKF2_GPS_P_NOISE", "EKF2_GPS_V_NOISE"}  # no random walk: no B_NOISE
    gyro = np.array(cal.sensors["gyroscope"].sigma)
    # 250 Hz per-sample std averaged to EKF2's 100 Hz: variance scales by 100 / 250.
    assert params["EKF2_GYR_NOISE"].value == pytest.approx(np.sqrt(np.mean(gyro**2) * 100 / 250))
    gps = np.array(cal.sensors["gps_position"].sigma[:2])
    assert params["EKF2_GPS_P_NOISE"].value == pytest.approx(np.sqrt(np.mean(gps**2)))  # horizontal only
    assert params["EKF2_BARO_NOISE"].value == pytest.approx(cal.sensors["barometer"].sigma[0])
    # The synthetic airspeed noise (0.2 m/s) is below PX4's minimum EKF2_EAS_NOISE of 0.5 m/s.
    assert params["EKF2_EAS_NOISE"].value == 0.5 and "clamped" in params["EKF2_EAS_NOISE"].comment
    assert all(p.type == PARAM_TYPE_REAL32 and p.comment for p in params.values())
    assert "gyroscope sigma" in params["EKF2_GYR_NOISE"].comment


def test_bias_process_noise_from_allan_rate_random_walk(cal):
    walk = AllanFigures(white_density=1e-4, bias_instability=1e-4, bias_instability_tau_s=10.0, floor_reached=True,
                        rate_random_walk=2e-5, rate_hz=250.0)
    with_walk = dataclasses.replace(cal, allan={**cal.allan, "gyroscope": (walk,) * 3})
    params = {p.name: p for p in px4_parameters(with_walk, predict_period_s=0.004)}
    # Per step EKF2 adds (noise dt)^2, a random walk K adds K^2 dt: noise = K / sqrt(dt).
    assert params["EKF2_GYR_B_NOISE"].value == pytest.approx(2e-5 / np.sqrt(0.004))
    assert "EKF2_ACC_B_NOISE" not in params


def test_params_file_parses_back(cal, tmp_path):
    params = [*px4_parameters(cal), Px4Param(name="EKF2_GPS_DELAY", value=110.0, type=9),
              Px4Param(name="SYS_AUTOSTART", value=4001, type=6, comment="airframe")]
    path = write_px4_params(params, tmp_path / "out.params", header="from synthetic.ulg\nsecond line")
    text = path.read_text()
    assert text.startswith("# Onboard parameters for Vehicle 1\n#\n# from synthetic.ulg\n# second line\n")
    assert "1\t1\tSYS_AUTOSTART\t4001\t6\n" in text
    back = read_px4_params(path)
    assert list(back) == [p.name for p in params]
    for p in params:
        assert back[p.name].value == p.value  # .17g round-trips float64 exactly
        assert (back[p.name].type, back[p.name].comment) == (p.type, p.comment)


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
