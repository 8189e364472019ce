"""CALIB.json (schema 2) round trip and validation, schema 1 still read."""

from __future__ import annotations

import copy
import dataclasses
import json
import math

import pytest
from test_calib_synthetic import synthetic_log

from calib.bias import InflightBias
from calib.calibration import calibrate, with_tau
from calib.export import SCHEMA, calibration_from_dict, calibration_to_dict, read_calibration, write_calibration
from calib.figures import (
    MEANING_LOWER_BOUND,
    SOURCE_ALLAN,
    SOURCE_DEFAULT,
    SOURCE_STILL,
    SOURCE_TUNED,
    ChannelConsistency,
    Figure,
    TuneResult,
)
from calib.tau import TauSelection
from ingest.errors import InputError


@pytest.fixture(scope="module")
def cal():
    inflight = InflightBias(source="full_state_indirect", window_s=(130.0, 160.0), gyro_bias_rad_s=(0.01, -0.02, 0.0),
                            gyro_bias_std_rad_s=(1e-3, 1e-3, 1e-3))
    tau = TauSelection(tau=2.0, method="likelihood", log10_tau_grid=(-1.0, 0.5, 2.0),
                       neg_log_likelihood=(3.0, 1.0, 2.0), mean_nis=(5.0, 1.0, 0.1), n_innovations=100,
                       nis_at_tau=1.02, nis_band=(0.75, 1.3), lag1_autocorrelation=0.1)
    figures = {
        "gyro_noise_density": Figure("gyro_noise_density", 2e-3, SOURCE_ALLAN, axes=(1e-3, 2e-3, 2.6e-3),
                                     note="Allan white-noise density"),
        "mag_noise": Figure("mag_noise", 0.01, SOURCE_STILL, axes=(0.01, 0.01, 0.01)),
        "wind_walk": Figure("wind_walk", 0.1, SOURCE_DEFAULT),
    }
    tuned = {**figures, "wind_walk": Figure("wind_walk", 0.35, SOURCE_TUNED, note="bounded search"),
             "gps_vel_noise_scale": Figure("gps_vel_noise_scale", 1.8, SOURCE_TUNED)}
    tuning = TuneResult(
        estimator="full_state_indirect", figures=tuned, start={"wind_walk": 0.1, "gps_vel_noise_scale": 1.0},
        bounds={"wind_walk": (0.01, 2.0), "gps_vel_noise_scale": (0.3, 3.0)},
        log_likelihood_trace=(-1200.0, -1150.5, -1149.0), n_replays=17,
        nis_before=(ChannelConsistency("gps.vn", 150, 2.4, (0.78, 1.24)),),
        nis_after=(ChannelConsistency("gps.vn", 150, 1.05, (0.78, 1.24)),), wall_s=12.5,
        notes=("wind_walk at its start bound",))
    cal = with_tau(calibrate(synthetic_log(30.0, seed=4), inflight_bias=inflight), tau)
    return dataclasses.replace(cal, figures=figures, tuning={"full_state_indirect": tuning})


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
    assert back.figures == cal.figures and back.tuning == cal.tuning
    assert data["figures"]["gyro_noise_density"] == {"value": 2e-3, "unit": "rad/s/sqrt(Hz)", "source": SOURCE_ALLAN,
                                                     "meaning": MEANING_LOWER_BOUND, "axes": [1e-3, 2e-3, 2.6e-3],
                                                     "note": "Allan white-noise density"}
    assert data["tuning"]["full_state_indirect"]["bounds"]["wind_walk"] == [0.01, 2.0]
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
                                  "allan", "source.sha256", "figures", "figures.mag_noise.unit",
                                  "tuning.full_state_indirect.n_replays",
                                  "tuning.full_state_indirect.figures.wind_walk.source"])
def test_missing_keys_fail_naming_the_key(cal, path):
    with pytest.raises(InputError) as err:
        calibration_from_dict(_without(calibration_to_dict(cal), path))
    assert err.value.field == path
    assert "missing key" in str(err.value)


@pytest.mark.parametrize(("schema", "message"), [("solarnav.calibration/3", "version '3' is not supported"),
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
    (lambda d: d["figures"]["mag_noise"].update(unit="mgauss"), "figures.mag_noise.unit"),
    (lambda d: d["figures"]["mag_noise"].update(source="guess"), "figures.mag_noise.source"),
    (lambda d: d["figures"].update(lidar_noise=d["figures"]["mag_noise"]), "figures.lidar_noise"),
    (lambda d: d["tuning"]["full_state_indirect"]["figures"]["wind_walk"].update(unit="m/s"),
     "tuning.full_state_indirect.figures.wind_walk.unit"),
    (lambda d: d["tuning"]["full_state_indirect"]["start"].update(gust=1.0), "tuning.full_state_indirect.start.gust"),
    (lambda d: d["tuning"]["full_state_indirect"]["bounds"].update(wind_walk=[0.1]),
     "tuning.full_state_indirect.bounds.wind_walk"),
    (lambda d: d["tuning"]["full_state_indirect"]["nis_after"][0].update(band=[1.0]),
     "tuning.full_state_indirect.nis_after[0].band"),
])
def test_wrong_values_fail_naming_the_key(cal, edit, field):
    data = calibration_to_dict(cal)
    edit(data)
    with pytest.raises(InputError) as err:
        calibration_from_dict(data)
    assert err.value.field == field


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["figures"]["mag_noise"].update(unit="mgauss"), "figure 'mag_noise' is in 'gauss', got 'mgauss'"),
    (lambda d: d["figures"]["mag_noise"].update(source="guess"), "unknown source 'guess'"),
    (lambda d: d["figures"].update(lidar_noise=d["figures"]["mag_noise"]), "unknown figure 'lidar_noise'"),
])
def test_bad_figures_fail_naming_the_key_in_the_message(cal, edit, message):
    data = calibration_to_dict(cal)
    edit(data)
    with pytest.raises(InputError, match=message) as err:
        calibration_from_dict(data, source="CALIB.json")
    assert str(err.value).startswith(f"CALIB.json: {err.value.field}: ")  # the key is in the one-line message


def test_schema_1_file_still_loads_without_figures(cal, tmp_path):
    data = calibration_to_dict(cal)
    del data["figures"], data["tuning"]
    data["schema"] = "solarnav.calibration/1"
    path = tmp_path / "CALIB.json"
    path.write_text(json.dumps(data))
    back = read_calibration(path)
    assert back.figures == {} and back.tuning == {}
    assert back.sensors == cal.sensors and back.r == cal.r and back.tau == cal.tau
    # Written again, it is schema 2 (with the empty sections).
    again = calibration_to_dict(back)
    assert again["schema"] == SCHEMA == "solarnav.calibration/2"
    assert (again["figures"], again["tuning"]) == ({}, {})


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
