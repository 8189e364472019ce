"""The calibration loop against truth: default settings vs ``--calib`` (eq 50-52) vs ``--tune`` per estimator and
Table-2 metric, on simulated missions including seeds, sites and sensor grades the defaults were not tuned on.

    .venv/bin/python benchmarks/calibration_loop.py [--cases paper,gusty,...] [--no-tune] [-o OUT.json]

Each case is simulated, written as a ULog and read back (the path a user's file takes), calibrated with
``--segment auto --tau auto``, optionally tuned, and replayed three times (all three estimators each time).
Prints one table per case (rows: estimator x setting, columns: Table-2 metrics) and the ratio calib/default and
tune/default per metric; ``-o`` saves every number as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from estimators.evaluation import rms_errors
from ingest.log_formats import load_flight_log
from sim.kinematics import Site
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS, SensorSpec
from sim.sensors import AirspeedGrade, BaroGrade, GpsGrade, ImuGrade, MagGrade
from sim.simulate import simulate
from sim.wind import WindConfig
from workflows.calibration import calibrate_log, identify_noise
from workflows.replay import replay_log

METRICS = ("roll_deg", "pitch_deg", "yaw_deg", "position_m", "height_m", "airspeed_m_s", "wind_m_s")

#: Sensor grades unlike the simulator's defaults: noisier IMU and pressure sensors, a worse GPS velocity.
_ROUGH_SENSORS = SensorSpec(
    imu=ImuGrade(gyro_noise_rad_s=float(np.radians(0.1)),
                 gyro_vibration_rad_s=tuple(float(v) for v in np.radians((2.0, 2.5, 1.8))),
                 accel_vibration_m_s2=(0.06, 0.03, 0.12), gyro_bias_walk_rad_s_sqrt_s=5e-5),
    mag=MagGrade(noise_gauss=0.008), baro=BaroGrade(noise_pa=3.0), airspeed=AirspeedGrade(noise_pa=2.0),
    gps=GpsGrade(velocity_noise_m_s=0.1, position_sigma_m=(1.5, 1.5, 3.0)))
#: Quieter sensors and a faster GPS error.
_FINE_SENSORS = SensorSpec(
    imu=ImuGrade(gyro_vibration_rad_s=tuple(float(v) for v in np.radians((0.6, 0.8, 0.7))),
                 accel_vibration_m_s2=(0.015, 0.004, 0.04)),
    mag=MagGrade(noise_gauss=0.003), baro=BaroGrade(noise_pa=1.0), airspeed=AirspeedGrade(noise_pa=0.7),
    gps=GpsGrade(velocity_noise_m_s=0.03, position_tau_s=300.0))


def scenarios() -> dict:
    """Case name -> (Scenario, seed)."""
    out = {name: (SCENARIOS[name], SCENARIOS[name].seed) for name in ("paper", "gusty", "mag_disturbed")
           if name in SCENARIOS}
    if "turbulent" in SCENARIOS:
        out["turbulent"] = (SCENARIOS["turbulent"], SCENARIOS["turbulent"].seed)
    paper = SCENARIOS["paper"]
    out["zurich_winter_rough"] = (replace(
        paper, name="zurich_winter_rough",
        site=Site(lat_deg=47.38, lon_deg=8.54, ground_alt_m=430.0, start_utc="2025-01-20T09:00:00Z",
                  ground_temp_c=-2.0, sea_level_pressure_pa=102100.0),
        wind=WindConfig(speed_m_s=4.0, from_deg=230.0, slow_sigma_m_s=0.5, gust_sigma_m_s=0.6),
        sensors=_ROUGH_SENSORS), 101)
    out["sydney_summer_fine"] = (replace(
        paper, name="sydney_summer_fine",
        site=Site(lat_deg=-33.87, lon_deg=151.2, ground_alt_m=40.0, start_utc="2025-12-20T02:00:00Z",
                  ground_temp_c=28.0, sea_level_pressure_pa=100900.0),
        wind=WindConfig(speed_m_s=1.5, from_deg=120.0, slow_sigma_m_s=0.2),
        sensors=_FINE_SENSORS), 202)
    return out


def evaluate(name: str, scenario, seed: int, *, tune: bool, workdir: Path) -> dict:
    """RMS errors per setting and estimator for one case, plus timings."""
    result = simulate(scenario, np.random.default_rng(seed), seed=seed)
    paths = write_outputs(result, workdir / name)
    log = load_flight_log(paths["ulog"])
    started = time.perf_counter()
    cal = calibrate_log(log, tau=None)  # automatic segments, tau by replay, the filter figures
    timings = {"calibrate_s": time.perf_counter() - started}
    settings = {"default": None, "calib": cal}
    if tune:
        started = time.perf_counter()
        tuned = identify_noise(log, cal)
        timings["tune_s"] = time.perf_counter() - started
        settings["tune"] = tuned
    tables = {}
    for setting, calibration in settings.items():
        states = replay_log(log, calibration=calibration).states
        tables[setting] = rms_errors(states, log).loc[:, list(METRICS)]
    return {"tables": tables, "timings": timings, "tau": cal.tau.tau}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    parser.add_argument("--no-tune", action="store_true", help="leave out the --tune setting")
    parser.add_argument("-o", "--output", default=None, help="JSON file of every number")
    args = parser.parse_args(argv)
    available = scenarios()
    names = args.cases.split(",") if args.cases else list(available)
    saved = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            scenario, seed = available[name]
            out = evaluate(name, scenario, seed, tune=not args.no_tune, workdir=Path(tmp))
            print(f"\n## {name} (seed {seed}, tau {out['tau']:.3g}; "
                  + ", ".join(f"{k} {v:.1f} s" for k, v in out["timings"].items()) + ")")
            rows = []
            for setting, table in out["tables"].items():
                for estimator, row in table.iterrows():
                    rows.append({"estimator": estimator, "setting": setting, **row.to_dict()})
            frame = pd.DataFrame(rows).set_index(["estimator", "setting"]).sort_index(level=0, sort_remaining=False)
            print(frame.to_string(float_format=lambda v: f"{v:.3f}"))
            default = out["tables"]["default"]
            for setting in [s for s in out["tables"] if s != "default"]:
                ratio = out["tables"][setting] / default
                print(f"{setting}/default: worst {ratio.max().max():.3f}, mean {ratio.mean().mean():.3f}")
                print(ratio.to_string(float_format=lambda v: f"{v:.2f}"))
            saved[name] = {"seed": seed, "tau": out["tau"], "timings": out["timings"],
                           "tables": {k: v.to_dict(orient="index") for k, v in out["tables"].items()}}
            sys.stdout.flush()
    if args.output:
        Path(args.output).write_text(json.dumps(saved, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
