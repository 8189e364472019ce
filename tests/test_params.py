"""Parameter diff between flights and the onboard noise parameters next to solarnav's (issue 33, item 1;
docs/workflows.md, 'Parameter diff')."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from app.cli import main
from ingest.log_formats import load_flight_log
from tests.conftest import REPO_DIR
from workflows.calibration import calibrate_log
from workflows.exports import px4_parameter_set
from workflows.params import diff_parameters, noise_parameter_table, parameter_group


def test_diff_groups_by_prefix_and_compares_at_float32_precision():
    a = {"EKF2_BARO_NOISE": 3.5, "EKF2_GPS_DELAY": 110.0, "SENS_BOARD_ROT": 0.0, "CAL_ACC0_XOFF": 0.1,
         "MAV_TYPE": 2.0, "OLD": 1.0}
    b = {"EKF2_BARO_NOISE": 2.0, "EKF2_GPS_DELAY": 110.0000001, "SENS_BOARD_ROT": 4.0, "CAL_ACC0_XOFF": 0.1,
         "MAV_TYPE": 2.0, "NEW": 7.0}
    table = diff_parameters(a, b)
    rows = {name: (group, change) for name, group, change in zip(table["name"], table["group"], table["change"],
                                                                  strict=True)}
    assert rows == {"EKF2_BARO_NOISE": ("EKF2_", "changed"), "SENS_BOARD_ROT": ("SENS_", "changed"),
                    "NEW": ("NEW", "added"), "OLD": ("OLD", "removed")}  # 110.0000001 is 110 in float32
    assert list(table["group"]) == sorted(table["group"])
    assert math.isnan(table.set_index("name").at["NEW", "value_a"])
    assert diff_parameters(a, a).empty
    assert parameter_group("EK3_ALT_M_NSE") == "EK3_" and parameter_group("MAV") == "MAV"


def test_noise_table_puts_solarnav_next_to_the_onboard_value_in_the_autopilots_units():
    log = load_flight_log(REPO_DIR / "sample_logs" / "failed_cell.ulg")
    cal = calibrate_log(log)
    table = noise_parameter_table(log, cal).set_index("name")
    exported = {p.name: p.value for p in px4_parameter_set(cal, log.meta.parameters)[0]}
    assert set(exported) <= set(table.index) and all(name.startswith("EKF2_") for name in table.index)
    for name, value in exported.items():
        assert table.at[name, "solarnav"] == value
        onboard = log.meta.parameters.get(name, math.nan)
        assert table.at[name, "onboard"] == pytest.approx(onboard, nan_ok=True)
    without = noise_parameter_table(log, None)
    assert list(without["name"]) == list(table.index) and without["solarnav"].isna().all()


def test_params_cli_on_two_bundled_logs(tmp_path, capsys):
    out = tmp_path / "diff.csv"
    assert main(["params", str(REPO_DIR / "sample_logs" / "paper.ulg"), str(REPO_DIR / "sample_logs" /
                 "failed_cell.ulg"), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    first = printed.splitlines()[0]
    assert first.startswith("parameters: paper.ulg") and "vs failed_cell.ulg" in first
    assert printed.count("onboard EKF2 noise vs solarnav for") == 2
    written = pd.read_csv(out)
    assert list(written.columns) == ["group", "name", "change", "value_a", "value_b"]
    counts = written["change"].value_counts()
    assert first.endswith(f"{counts.get('changed', 0)} changed, {counts.get('added', 0)} added, "
                          f"{counts.get('removed', 0)} removed")


def test_params_cli_on_the_real_octocopter_and_arduplane_pairs(real_logs_dir, capsys):
    assert main(["params", str(real_logs_dir / "px4_1.14_octo_flight_61.ulg"),
                 str(real_logs_dir / "px4_1.14_octo_flight_123.ulg")]) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[0].endswith("38 changed, 0 added, 0 removed")
    assert "  COM_FLIGHT_UUID              61 -> 121" in printed
    assert "not calibrated" in printed and "EKF2_BARO_NOISE    onboard        3.5" in printed
    assert main(["params", str(real_logs_dir / "arduplane_4.0.8_ground_static.bin"),
                 str(real_logs_dir / "arduplane_4.0.8_ground_walk.bin"), "--no-noise"]) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[0].endswith("10 changed, 0 added, 0 removed")
    assert "GND_\n  GND_ABS_PRESS" in printed and "EK3_" not in printed
