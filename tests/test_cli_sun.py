"""``solarnav sun`` (and the sun heading of ``solarnav replay``) through ``app.cli.main``: argv in, exit code, files
and output out."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from app.cli import EXIT_BAD_INPUT, main
from estimators.sun import photocells
from estimators.sun.prediction import attitude_matrices_at, sun_ned_at
from ingest.log_formats import load_flight_log
from ingest.sun_device import SunDevice
from tests.conftest import SAMPLE_LOGS_DIR

FAILED_CELL = [str(SAMPLE_LOGS_DIR / "failed_cell.ulg"), "--sun", str(SAMPLE_LOGS_DIR / "failed_cell_sun.csv"),
               "--device", str(SAMPLE_LOGS_DIR / "failed_cell_device.json")]
PREDICTED = [f"pred_{ref}_{axis}" for ref in ("onboard", "truth") for axis in "xyz"]
REQUIRED = ["time_s", "sun_x", "sun_y", "sun_z", "cells_used", "faulty_cells", "residual", *PREDICTED,
            "angle_onboard_deg", "angle_truth_deg"]
MA_COLUMNS = [f"i{cell}_mA" for cell in range(1, 8)]


@pytest.fixture(scope="module")
def failed_cell_table(tmp_path_factory):
    out = tmp_path_factory.mktemp("sun") / "failed_cell_sun_vectors.parquet"
    assert main(["sun", *FAILED_CELL, "-o", str(out)]) == 0
    return pd.read_parquet(out)


def test_failed_cell_flight_columns_and_accuracy(failed_cell_table):
    """The bundled two-minute flight: every sample solved, the stuck forward cell (cell 2, 40-100 s mission time
    = 60-120 s log time) identified, the solution within a degree of the sun the true attitude predicts."""
    table = failed_cell_table
    assert set(REQUIRED) <= set(table.columns)
    assert len(table) == 1252 and (table["status"] == "ok").all()
    np.testing.assert_allclose(np.linalg.norm(table[["sun_x", "sun_y", "sun_z"]], axis=1), 1.0, atol=1e-12)
    faulty = (table["faulty_cells"].to_numpy() & 0b10) > 0
    window = (table["time_s"] > 62.0) & (table["time_s"] < 118.0)
    assert faulty[window].mean() > 0.8  # the stuck cell is dark (and so not a fault) whenever the sun is behind it
    assert not faulty[table["time_s"] < 58.0].any()
    angle = table["angle_truth_deg"].dropna()
    assert len(angle) >= len(table) - 1  # the last sample lies past the last truth sample
    assert np.median(angle) < 0.6 and np.percentile(angle, 95) < 1.5
    # the simulated log has no autopilot attitude: no onboard prediction, truth's up vector for the sky model
    assert table[["pred_onboard_x", "angle_onboard_deg"]].isna().all().all()
    predicted = table[["pred_truth_x", "pred_truth_y", "pred_truth_z"]].dropna().to_numpy()
    np.testing.assert_allclose(np.linalg.norm(predicted, axis=1), 1.0, atol=1e-9)


def test_csv_output_and_summary(tmp_path, capsys):
    out = tmp_path / "sun.csv"
    assert main(["sun", *FAILED_CELL, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1252 photocell samples: 1252 solved (100.0 %)" in text
    assert "(cells 2)" in text and "sky-light model up vector: truth attitude" in text
    assert "no prediction from the onboard attitude" in text and f"wrote {out}" in text
    table = pd.read_csv(out)
    assert set(REQUIRED) <= set(table.columns) and len(table) == 1252
    assert [p.name for p in tmp_path.iterdir()] == ["sun.csv"]  # atomic write: no temporary file left


def _synthetic_sun_csv(log, path, device, rng):
    """Currents the sun device would have measured on this log (its onboard attitude, the SPA sun at its GPS
    position) with 0.5 mA noise, in the CSV contract (unix time, mA)."""
    time_s = np.arange(log.meta.start_time_s + 0.5, log.meta.end_time_s - 0.5, 0.1)
    r_nb = attitude_matrices_at(log, "onboard", time_s)
    s_ned, elevation = sun_ned_at(log, time_s)
    assert np.isfinite(r_nb).all() and elevation.min() > 10.0
    s_device, up_device = photocells.device_sun_and_up(r_nb, s_ned, device)
    currents_ma = 1e3 * photocells.photocell_currents(s_device, 0.1, 0.01, device, up_device)
    currents_ma += rng.normal(0.0, 0.5, currents_ma.shape)
    lines = ["unix_time_s," + ",".join(MA_COLUMNS)]
    lines += [f"{t + log.meta.utc_offset_s:.3f}," + ",".join(f"{c:.4f}" for c in row)
              for t, row in zip(time_s, currents_ma, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return time_s


def test_real_log_onboard_prediction_with_a_rotated_mounting(real_logs_dir, tmp_path, capsys):
    """A real fixed-wing log (GPS, UTC, autopilot attitude): currents synthesised from its onboard attitude
    through a device turned 90 deg on the airframe are solved back to the body vector the onboard attitude
    predicts; the solver's sky model uses the onboard up vector."""
    log_path = real_logs_dir / "sample_log_small.ulg"
    log = load_flight_log(log_path)
    device = SunDevice(mount_rpy_deg=(0.0, 0.0, 90.0))
    sun_csv, device_json = tmp_path / "sun.csv", tmp_path / "device.json"
    device_json.write_text(json.dumps({"tilt_deg": 45.0, "mount_rpy_deg": [0.0, 0.0, 90.0]}))
    _synthetic_sun_csv(log, sun_csv, device, np.random.default_rng(5))
    out = tmp_path / "out.parquet"
    assert main(["sun", str(log_path), "--sun", str(sun_csv), "--device", str(device_json), "-o", str(out)]) == 0
    assert "sky-light model up vector: onboard attitude" in capsys.readouterr().out
    table = pd.read_parquet(out)
    assert (table["status"] == "ok").all()
    assert np.percentile(table["angle_onboard_deg"], 95) < 1.0
    assert table["angle_truth_deg"].isna().all()
    # the same currents read as if the device were not rotated: the solution is off by tens of degrees
    assert main(["sun", str(log_path), "--sun", str(sun_csv), "-o", str(tmp_path / "wrong.csv")]) == 0
    assert np.median(pd.read_csv(tmp_path / "wrong.csv")["angle_onboard_deg"]) > 20.0


def test_time_offset_for_a_log_without_utc(real_logs_dir, tmp_path, capsys):
    """``--sun-time-offset-s`` puts the CSV on a log without GPS time (no prediction: no position either)."""
    log_path = real_logs_dir / "sample.ulg"  # no GPS at all
    log = load_flight_log(log_path)
    offset = 1.7e9
    lines = ["unix_time_s," + ",".join(MA_COLUMNS)]
    lines += [f"{offset + t:.3f}," + ",".join(["50.0"] * 6 + ["20.0"])
              for t in np.arange(log.meta.start_time_s + 1.0, log.meta.start_time_s + 5.0, 0.1)]
    (tmp_path / "sun.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.csv"
    argv = ["sun", str(log_path), "--sun", str(tmp_path / "sun.csv"), "-o", str(out)]
    assert main(argv) == EXIT_BAD_INPUT
    assert "time offset" in capsys.readouterr().err
    assert not out.exists()
    assert main([*argv, "--sun-time-offset-s", str(offset)]) == 0
    table = pd.read_csv(out)
    assert len(table) == 40 and table[PREDICTED].isna().all().all()
    assert "sky-light model up vector: onboard attitude" in capsys.readouterr().out


@pytest.mark.parametrize(("extra", "message"), [
    (["-o", "out.txt"], "must end in .parquet or .csv"),
    (["-o", "missing_dir/out.csv"], "does not exist"),
])
def test_bad_output_paths(tmp_path, monkeypatch, capsys, extra, message):
    monkeypatch.chdir(tmp_path)
    assert main(["sun", *FAILED_CELL, *extra]) == EXIT_BAD_INPUT
    assert message in capsys.readouterr().err


def test_sun_csv_is_required(capsys):
    assert main(["sun", FAILED_CELL[0], "-o", "out.csv"]) == EXIT_BAD_INPUT
    assert "--sun" in capsys.readouterr().err


def test_sun_csv_outside_the_log_is_a_clear_error(tmp_path, capsys):
    """A time offset that puts the currents outside the flight: exit 2, one line naming the file and both spans,
    and an existing output file is left untouched."""
    out = tmp_path / "out.csv"
    out.write_text("previous\n")
    argv = ["sun", *FAILED_CELL, "--sun-time-offset-s", "0", "-o", str(out)]
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("solarnav: error: ") and "failed_cell_sun.csv" in err and "time offset" in err
    assert out.read_text() == "previous\n"


def test_replay_heading_option_reaches_the_estimators(tmp_path, capsys):
    """``solarnav replay --heading sun``: the sun vector is fused and the magnetometer left out."""
    out = tmp_path / "states.csv"
    diag = tmp_path / "diag.csv"
    argv = ["replay", *FAILED_CELL, "--estimators", "full_state_indirect", "--heading", "sun", "-o", str(out),
            "--diagnostics", str(diag)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "sun" in text.split("used ")[1].split(";")[0] and "mag (heading source is 'sun')" in text
    sensors = set(pd.read_csv(diag)["sensor"])
    assert "sun" in sensors and "mag" not in sensors
    assert main(["replay", FAILED_CELL[0], "--heading", "sun", "-o", str(out)]) == EXIT_BAD_INPUT
    assert "needs sun-vector observations" in capsys.readouterr().err
