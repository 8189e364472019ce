"""Sun-aided heading: yaw RMS per estimator and heading source (``mag`` / ``sun`` / ``mag+sun``), and run time.

Missions:

* ``mag_disturbed`` (simulated here with the scenario's seed, about five minutes): the magnetometer carries a
  solar-panel disturbance of up to a third of the earth field. Two filter set-ups, both with the simulator's true
  sensor noise (:func:`estimators.evaluation.config_for_simulation`): "modelled" (magnetometer-bias walk fast
  enough to follow the disturbance) and "unmodelled" (the estimators' default walk);
* ``paper`` (the bundled sample log and its sun CSV, 14.5 minutes, the paper's light disturbance), true noise.

Yaw RMS [deg] after the first 60 s against the log's ground truth; wall time of each replay (all three
estimators, numba compiled before timing by a first run).

Run: ``.venv/bin/python benchmarks/bench_sun_aided.py``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

from estimators.api import run_estimators
from estimators.config import EstimatorConfig
from estimators.evaluation import config_for_simulation, rms_errors
from ingest.log_formats import load_flight_log
from ingest.sun_log import load_sun_device, with_sun
from sim.px4_export import side_file
from sim.scenarios import SCENARIOS
from sim.simulate import simulate

HEADINGS = ("mag", "sun", "mag+sun")
SAMPLE_LOGS_DIR = Path(__file__).resolve().parents[1] / "sample_logs"


def missions():
    """(mission, set-up) -> (log, config)."""
    scenario = SCENARIOS["mag_disturbed"]
    result = simulate(scenario, np.random.default_rng(scenario.seed), seed=scenario.seed)
    modelled = config_for_simulation(side_file(result))
    default_walk = EstimatorConfig().noise.mag_bias_rw_sqrt_s
    unmodelled = dataclasses.replace(
        modelled, noise=dataclasses.replace(modelled.noise, mag_bias_rw_sqrt_s=default_walk))
    paper = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    paper = with_sun(paper, SAMPLE_LOGS_DIR / "paper_sun.csv",
                     device=load_sun_device(SAMPLE_LOGS_DIR / "paper_device.json"))
    paper_config = config_for_simulation(json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text()))
    return {("mag_disturbed", "modelled"): (result.log, modelled),
            ("mag_disturbed", "unmodelled"): (result.log, unmodelled),
            ("paper", "true noise"): (paper, paper_config)}


def main() -> None:
    cases = missions()
    first_log, first_config = next(iter(cases.values()))
    run_estimators(first_log, config=first_config, heading="mag+sun")  # compile the kernels
    rows = []
    for (mission, setup), (log, config) in cases.items():
        for heading in HEADINGS:
            started = time.perf_counter()
            result = run_estimators(log, config=config, heading=heading)
            wall_s = time.perf_counter() - started
            yaw = rms_errors(result.states, log, after_s=60.0)["yaw_deg"]
            rows.append({"mission": mission, "set-up": setup, "heading": heading, **yaw.round(2).to_dict(),
                         "replay_s": round(wall_s, 2)})
    table = pd.DataFrame(rows).set_index(["mission", "set-up", "heading"])
    with pd.option_context("display.width", 160):
        print("yaw RMS [deg] after 60 s, per estimator; replay wall time of all three [s]")
        print(table.to_string())


if __name__ == "__main__":
    main()
