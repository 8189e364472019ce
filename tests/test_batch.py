"""``solarnav batch`` on a real Dask ``LocalCluster`` (worker processes, one thread each): every good log
processed as ``calibrate`` / ``replay`` would, one error row per bad file, the doubled gyro noise flagged, a re-run
resumed; plus the input discovery, the vehicle identity and the history rule on their own."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from app.batch.figures import parameter_differences
from app.batch.history import VehicleMap, noise_history, read_vehicle_map, vehicle_names
from app.batch.plan import BatchSettings, discover_inputs, log_output_dir
from app.batch.summary import read_summary
from app.batch.task import DIAGNOSTICS_FILE, STATES_FILE
from app.cli import main
from app.comparison import QUANTITIES, compare, rms_table
from calib.export import read_calibration
from estimators.consistency import channel_consistency
from ingest.errors import InputError
from ingest.log_formats import load_flight_log
from tests.batch_logs import DOUBLED_FROM, N_FLIGHTS, VEHICLE, flight_name, write_fleet

ESTIMATORS = ("three_stage", "full_state_direct", "full_state_indirect")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> tuple[Path, Path]:
    """The simulated fleet (with an empty and a corrupt file) and its vehicle mapping file."""
    directory = tmp_path_factory.mktemp("fleet") / "logs"
    return directory, write_fleet(directory)


@pytest.fixture(scope="module")
def batch(fleet, tmp_path_factory) -> tuple[Path, int]:
    """The batch over the fleet on a local cluster of 2 worker processes: its OUTDIR and exit status."""
    directory, mapping = fleet
    outdir = tmp_path_factory.mktemp("batch") / "out"
    status = main(["batch", str(directory), "--calibrate", "--replay", "--workers", "2", "--vehicles", str(mapping),
                   "-o", str(outdir)])
    return outdir, status


def test_every_good_log_is_processed_and_each_bad_file_is_one_error_row(batch, fleet):
    outdir, status = batch
    fleet_table, _ = read_summary(outdir)
    assert status == 1  # some logs failed
    errors = fleet_table[fleet_table["status"] == "error"].set_index("name")
    assert sorted(errors.index) == ["corrupt.ulg", "empty.ulg"]
    assert "the file is empty" in errors.at["empty.ulg", "message"]
    assert "no IMU data" in errors.at["corrupt.ulg", "message"]
    assert all("\n" not in message for message in errors["message"])
    good = fleet_table[fleet_table["status"] == "ok"]
    assert sorted(good["name"].unique()) == [f"{flight_name(k)}.ulg" for k in range(N_FLIGHTS)]
    assert all(sorted(group) == sorted(ESTIMATORS) for _, group in good.groupby("name")["estimator"])
    assert (good["vehicle"] == VEHICLE).all() and good["sun_csv"].notna().all()
    assert (good["duration_s"] > 60).all() and good["utc_start"].str.startswith("2025-10-").all()


def test_the_doubled_gyro_noise_is_flagged_in_the_later_logs_only(batch):
    outdir, _ = batch
    fleet_table, history = read_summary(outdir)
    gyro = history[history["figure"] == "gyroscope"].sort_values("order")
    assert list(gyro["name"]) == [f"{flight_name(k)}.ulg" for k in range(N_FLIGHTS)]
    assert list(gyro["flagged"]) == [k >= DOUBLED_FROM for k in range(N_FLIGHTS)]
    assert gyro["ratio"].iloc[DOUBLED_FROM:].between(1.8, 2.2).all()
    assert not history[history["figure"] != "gyroscope"]["flagged"].any()
    flags = fleet_table[fleet_table["status"] == "ok"].drop_duplicates("name").set_index("name")["noise_flags"]
    assert [flags[f"{flight_name(k)}.ulg"] for k in range(N_FLIGHTS)] == [
        "gyroscope" if k >= DOUBLED_FROM else "" for k in range(N_FLIGHTS)]


def test_the_outputs_and_summary_equal_per_log_calibrate_and_replay_runs(batch, fleet, tmp_path):
    outdir, _ = batch
    directory, _ = fleet
    log_path = directory / f"{flight_name(1)}.ulg"
    sun, device = (directory / f"{flight_name(1)}_{suffix}" for suffix in ("sun.csv", "device.json"))
    calib, states, diagnostics = tmp_path / "calib.json", tmp_path / "states.parquet", tmp_path / "diag.parquet"
    assert main(["calibrate", str(log_path), "--sun", str(sun), "--device", str(device), "-o", str(calib)]) == 0
    assert main(["replay", str(log_path), "--sun", str(sun), "--device", str(device), "--calib", str(calib),
                 "-o", str(states), "--diagnostics", str(diagnostics)]) == 0
    log = load_flight_log(log_path)
    own = log_output_dir(outdir, log.meta.sha256, str(log_path))
    assert json.loads((own / "calib.json").read_text()) == json.loads(calib.read_text())
    cli_states = pd.read_parquet(states)
    pd.testing.assert_frame_equal(pd.read_parquet(own / STATES_FILE), cli_states)
    cli_diagnostics = pd.read_parquet(diagnostics)
    pd.testing.assert_frame_equal(pd.read_parquet(own / DIAGNOSTICS_FILE), cli_diagnostics)

    fleet_table, _ = read_summary(outdir)
    rows = fleet_table[fleet_table["sha256"] == log.meta.sha256].set_index("estimator")
    gyro_sigma = read_calibration(calib).sensors["gyroscope"].sigma
    assert rows["noise_gyroscope_x_rad_s"].eq(gyro_sigma[0]).all()
    rms = rms_table(compare(cli_states, log))  # the dashboard's comparison: truth is the reference
    for estimator in ESTIMATORS:
        for quantity, label in zip(QUANTITIES, rms.columns, strict=True):
            assert rows.at[estimator, f"rms_truth_{quantity}"] == pytest.approx(rms.at[estimator, label],
                                                                                 nan_ok=True)
        for channel in channel_consistency(cli_diagnostics[cli_diagnostics["estimator"] == estimator]):
            assert rows.at[estimator, f"nis_{channel.channel}"] == pytest.approx(channel.mean_nis)


def test_a_rerun_resumes_every_finished_log_and_retries_the_bad_ones(batch, fleet):
    outdir, _ = batch
    directory, mapping = fleet
    before, _ = read_summary(outdir)
    assert main(["batch", str(directory), "--calibrate", "--replay", "--workers", "1", "--vehicles", str(mapping),
                 "-o", str(outdir)]) == 1
    after, _ = read_summary(outdir)
    good = after["status"] == "ok"
    assert after.loc[good, "resumed"].all() and not after.loc[~good, "resumed"].any()
    same = [c for c in before.columns if c not in ("resumed", "wall_s", "worker")]
    pd.testing.assert_frame_equal(after.loc[good, same].reset_index(drop=True),
                                  before.loc[before["status"] == "ok", same].reset_index(drop=True))


def test_other_settings_are_not_resumed():
    assert BatchSettings(calibrate=True).digest() != BatchSettings(calibrate=True, replay=True).digest()
    assert BatchSettings(replay=True, estimators="three_stage").digest() != BatchSettings(replay=True).digest()
    assert BatchSettings(replay=True).digest() == BatchSettings(replay=True).digest()


def test_discovery_takes_files_directories_and_globs_with_their_companions(fleet, tmp_path):
    directory, _ = fleet
    nested = tmp_path / "a" / "b"
    nested.mkdir(parents=True)
    shutil.copy(directory / f"{flight_name(0)}.ulg", nested / "deep.ULG")
    (nested / "notes.txt").write_text("not a log")
    items = discover_inputs([str(tmp_path), str(directory / "uav1_day*.ulg"), str(directory / "empty.ulg"),
                             str(directory / f"{flight_name(0)}.ulg")])
    names = [Path(item.path).name for item in items]
    assert names == ["deep.ULG", *[f"{flight_name(k)}.ulg" for k in range(N_FLIGHTS)], "empty.ulg"]
    by_name = {Path(item.path).name: item for item in items}
    assert by_name["uav1_day0.ulg"].sun_csv == str(directory / "uav1_day0_sun.csv")
    assert by_name["uav1_day0.ulg"].device_json == str(directory / "uav1_day0_device.json")
    assert by_name["deep.ULG"].sun_csv is None and by_name["empty.ulg"].device_json is None
    with pytest.raises(InputError, match="no log matches"):
        discover_inputs([str(tmp_path / "missing*.ulg")])
    with pytest.raises(InputError, match="--tune"):
        BatchSettings(tune=True)


def test_vehicle_from_the_mapping_else_the_sys_uuid_else_the_hardware(tmp_path):
    fleet_table = pd.DataFrame({"file": ["/f/sn7_a.ulg", "/f/b.ulg", "/f/c.ulg", "/f/bad.ulg"],
                                "sys_uuid": [None, "0001abc", None, None],
                                "hardware": ["CUBE", "CUBE", "CUBE", None],
                                "status": ["ok", "ok", "ok", "error"]})
    mapping = VehicleMap({"SN-7": ("sn7_*.ulg",)})
    assert list(vehicle_names(fleet_table, mapping)) == ["SN-7", "0001abc", "CUBE (no sys_uuid)", ""]
    bad = tmp_path / "bad.json"
    bad.write_text('{"SN-7": "sn7_*.ulg"}')
    with pytest.raises(InputError, match="expected an object"):
        read_vehicle_map(bad)


def test_the_reader_gives_the_sys_uuid_of_a_real_log(real_logs_dir):
    log = load_flight_log(real_logs_dir / "px4_1.9_quad_mission.ulg")
    assert log.meta.sys_uuid == "000100000000383938303138510c00430026"


def test_the_history_flags_a_departure_from_the_vehicles_own_median_in_both_directions():
    noise = [1.0, 1.1, 0.9, 1.05, 1.7, 0.55, 1.0]
    fleet_table = pd.DataFrame({
        "sha256": [f"s{k}" for k in range(7)] + ["t0", "t1", "t2"],
        "name": [f"a{k}.ulg" for k in range(7)] + ["b0.ulg", "b1.ulg", "b2.ulg"],
        "vehicle": ["A"] * 7 + ["B"] * 3, "status": "ok",
        "utc_start": [f"2025-01-0{k + 1}T00:00:00Z" for k in range(7)] + [None] * 3,
        "noise_gyroscope_rad_s": [*noise, 5.0, 5.0, 9.0], "noise_airspeed_m_s": [1.0, 1.0, 4.0, *[1.0] * 7],
        "tau": [1.0, 1.0, 3.0, *[1.0] * 7]})
    history = noise_history(fleet_table)
    gyro_a = history[(history["vehicle"] == "A") & (history["figure"] == "gyroscope")]
    assert list(gyro_a["flagged"]) == [False, False, False, False, True, True, False]
    assert np.isnan(gyro_a["baseline"].iloc[1]) and gyro_a["baseline"].iloc[2] == pytest.approx(1.05)
    gyro_b = history[(history["vehicle"] == "B") & (history["figure"] == "gyroscope")]
    assert list(gyro_b["flagged"]) == [False, False, True]  # its own history, not vehicle A's
    for figure, k in (("airspeed", 2), ("tau", 2)):  # tracked, not flagged
        rows = history[(history["vehicle"] == "A") & (history["figure"] == figure)]
        assert rows["ratio"].iloc[k] > 2 and not rows["flagged"].any()


def test_parameter_differences_list_only_the_parameters_that_differ(tmp_path):
    for name, params in (("a", {"EKF2_GPS_DELAY": 110.0, "MAV_TYPE": 1.0}),
                         ("b", {"EKF2_GPS_DELAY": 150.0, "MAV_TYPE": 1.0, "SENS_BARO_QNH": 1013.0})):
        (tmp_path / name).mkdir()
        (tmp_path / name / "params.json").write_text(json.dumps(params))
    logs = pd.DataFrame({"name": ["a.ulg", "b.ulg"], "sha256": ["aa" * 32, "bb" * 32], "output_dir": ["a", "b"]})
    table = parameter_differences(tmp_path, logs)
    assert list(table.index) == ["EKF2_GPS_DELAY", "SENS_BARO_QNH"]
    assert list(table.columns) == ["a.ulg (aaaaaaaa)", "b.ulg (bbbbbbbb)"]
    assert table.loc["EKF2_GPS_DELAY"].tolist() == [110.0, 150.0] and np.isnan(table.at["SENS_BARO_QNH",
                                                                                         "a.ulg (aaaaaaaa)"])
