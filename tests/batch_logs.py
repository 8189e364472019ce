"""A small simulated fleet for the batch tests: one vehicle's short flights, its gyro noise doubled in the later
ones, plus an empty and a corrupt file, and the vehicle mapping file (simulated logs carry no sys_uuid); and its
batch outputs for the Fleet page tests."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from app.batch.history import read_vehicle_map
from app.batch.plan import LOGS_DIR, BatchSettings, discover_inputs
from app.batch.summary import fleet_table, write_summary
from app.batch.task import process_log
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

#: The vehicle of the simulated logs (from the mapping file).
VEHICLE = "uav-1"
#: Flights of the vehicle; the gyro noise (white and in-flight vibration) is doubled from flight DOUBLED_FROM on.
N_FLIGHTS, DOUBLED_FROM = 4, 2
#: Short flights: 30 s at rest (the calibration's stationary segment), launch and climb.
DURATION_S = 75.0


def flight_name(k: int) -> str:
    return f"uav1_day{k}"


def write_fleet(directory: Path, *, bad_files: bool = True) -> Path:
    """Simulate the fleet into ``directory`` (one day apart, 01:30 UTC); returns the vehicle mapping file."""
    directory.mkdir(parents=True, exist_ok=True)
    base = SCENARIOS["failed_cell"]
    for k in range(N_FLIGHTS):
        imu = base.sensors.imu
        if k >= DOUBLED_FROM:
            imu = dataclasses.replace(imu, gyro_noise_rad_s=2.0 * imu.gyro_noise_rad_s,
                                      gyro_vibration_rad_s=tuple(2.0 * v for v in imu.gyro_vibration_rad_s))
        scenario = dataclasses.replace(base, name=flight_name(k),
                                       sensors=dataclasses.replace(base.sensors, imu=imu),
                                       site=dataclasses.replace(base.site, start_utc=f"2025-10-{15 + k}T01:30:00Z"))
        write_outputs(simulate(scenario, np.random.default_rng(100 + k), duration_s=DURATION_S), directory)
    if bad_files:
        (directory / "empty.ulg").write_bytes(b"")
        (directory / "corrupt.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + bytes(range(256)) * 8)
    mapping = directory.parent / f"{directory.name}_vehicles.json"
    mapping.write_text(json.dumps({VEHICLE: ["uav1_day*.ulg"]}))
    return mapping


#: Estimators of :func:`write_batch_outdir` (two: the page's RMS distributions compare estimators).
OUTDIR_ESTIMATORS = ("three_stage", "full_state_indirect")


def write_batch_outdir(outdir: Path, logs: Path) -> None:
    """The fleet simulated into ``logs`` and its batch outputs in ``outdir``, as ``solarnav batch LOGS --calibrate
    --replay --vehicles ... -o OUTDIR`` with :data:`OUTDIR_ESTIMATORS` writes them; the tasks run in this process
    (the cluster runs are tests/test_batch*.py)."""
    vehicles = read_vehicle_map(write_fleet(logs))
    (outdir / LOGS_DIR).mkdir(parents=True)
    settings = BatchSettings(calibrate=True, replay=True, estimators=OUTDIR_ESTIMATORS)
    rows = [row for item in discover_inputs([str(logs)]) for row in process_log(item, settings, str(outdir))]
    write_summary(*fleet_table(rows, vehicles), outdir)
