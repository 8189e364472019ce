"""Round trip: one simulated mission written as a DataFlash .bin (sim.dataflash_writer) and as a ULog
(sim.px4_export) reads back as the same streams (up to DataFlash's storage resolution) and the estimators replayed
on both meet the same accuracy against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.api import run_estimators
from estimators.evaluation import config_for_simulation, rms_errors
from ingest.flightlog import OPTIONAL_COLUMNS
from ingest.log_formats import load_flight_log
from sim.dataflash_writer import write_dataflash
from sim.px4_export import side_file, write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

DURATION_S, SEED, AFTER_S = 150.0, 3, 60.0
#: Largest difference per column between the two reads: DataFlash stores the magnetometer in whole mGauss,
#: latitude/longitude in 1e-7 deg, GPS altitude and accuracies in cm, the baro temperature in 0.01 degC; the
#: true airspeed is recomputed from the indicated one with the ISA density (the simulated air is colder).
RESOLUTION = {"mag_x_gauss": 5e-4, "mag_y_gauss": 5e-4, "mag_z_gauss": 5e-4, "lat_deg": 5e-8, "lon_deg": 5e-8,
              "alt_m": 5e-3, "eph_m": 5e-3, "epv_m": 5e-3, "temp_c": 5e-3, "vn_m_s": 1e-5, "ve_m_s": 1e-5,
              "tas_m_s": 0.05}
#: The same accuracy: |RMS(.bin) - RMS(.ulg)| within this fraction of RMS(.ulg) plus the absolute margin of
#: the quantity's unit (the magnetometer's mGauss steps move the yaw by ~0.1 deg; the TAS above the wind).
RELATIVE, ABSOLUTE = 0.2, {"deg": 0.15, "m": 0.05, "m_s": 0.05}


def _unit(column: str) -> str:
    return "m_s" if column.endswith("_m_s") else column.rsplit("_", 1)[-1]


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    result = simulate(SCENARIOS["paper"], np.random.default_rng(SEED), duration_s=DURATION_S, seed=SEED)
    directory = tmp_path_factory.mktemp("roundtrip")
    ulog = write_outputs(result, directory)["ulog"]
    dataflash = write_dataflash(result, directory / "paper.bin")
    return load_flight_log(dataflash), load_flight_log(ulog), config_for_simulation(side_file(result))


def test_same_streams(logs):
    dataflash, ulog, _ = logs
    assert set(dataflash.streams) == set(ulog.streams)
    assert dataflash.meta.vehicle_type == ulog.meta.vehicle_type == 1
    assert dataflash.meta.utc_offset_s == pytest.approx(ulog.meta.utc_offset_s, abs=1e-3)
    for name, theirs in ulog.streams.items():
        ours = dataflash[name]
        np.testing.assert_allclose(ours.index.to_numpy(), theirs.index.to_numpy(), rtol=0, atol=1e-9, err_msg=name)
        # only optional columns may be missing (DataFlash logs no IMU interval, no mag/baro/airspeed sample time)
        assert set(theirs.columns) - set(ours.columns) <= set(OPTIONAL_COLUMNS.get(name, ())), name
        for column in ours.columns:
            np.testing.assert_allclose(ours[column].to_numpy(float), theirs[column].to_numpy(float), rtol=1e-6,
                                       atol=RESOLUTION.get(column, 1e-6), err_msg=f"{name}.{column}")


def test_replay_meets_the_ulog_accuracy(logs):
    dataflash, ulog, config = logs
    rms = {name: rms_errors(run_estimators(log, config=config).states, log, after_s=AFTER_S)
           for name, log in (("bin", dataflash), ("ulg", ulog))}
    print(f"\n.bin:\n{rms['bin'].round(3).to_string()}\n.ulg:\n{rms['ulg'].round(3).to_string()}")
    difference = (rms["bin"] - rms["ulg"]).abs()
    margin = RELATIVE * rms["ulg"] + [ABSOLUTE[_unit(column)] for column in rms["ulg"].columns]
    assert np.isfinite(rms["bin"].to_numpy()).all()
    assert (difference <= margin).all().all(), (difference - margin).round(3).to_string()
