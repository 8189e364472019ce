"""``solarnav info`` through ``app.cli.main`` (argv in, exit code and output out)."""

from __future__ import annotations

import json

import pytest

from app.cli import EXIT_BAD_INPUT, main
from ingest.sun_csv import CURRENT_COLUMNS_MA


def test_text_summary(real_logs_dir, capsys):
    assert main(["info", str(real_logs_dir / "sample_log_small.ulg")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("sample_log_small.ulg  sha256 ")
    assert "MAV_TYPE 22 (fixed-wing)" in out
    assert "2021-04-21" in out  # UTC date from the log's GPS time
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith(("imu ", "gps "))}
    assert rows["imu"][1] == "sensor_combined" and rows["gps"][1] == "vehicle_gps_position"
    assert rows["gps"][2] == "32"  # samples
    assert "1 logger dropouts" in out


def test_json_summary(real_logs_dir, capsys):
    assert main(["info", str(real_logs_dir / "sample.ulg"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)  # strict JSON: NaN would not parse back as a number
    assert info["source"] == "sample.ulg"
    assert info["utc_offset_s"] is None and info["utc_start"] is None
    assert "parameters" not in info
    assert set(info["streams"]) == {"imu", "mag", "onboard_attitude", "onboard_local_position"}
    assert info["streams"]["imu"]["rate_hz"] == pytest.approx(250.0, rel=1e-3)  # 4 ms sensor_combined
    assert any(w.startswith("no gps stream") for w in info["warnings"])


def test_sun_option_attaches_the_csv(real_logs_dir, tmp_path, capsys):
    start_s = 1710773351.0  # inside sample_px4_events.ulg (its SITL log clock is unix time)
    lines = [f"time_s,{','.join(CURRENT_COLUMNS_MA)}"]
    lines += [f"{start_s + 0.05 * k:.2f}," + ",".join(["120.0"] * 7) for k in range(40)]
    sun_csv = tmp_path / "sun.csv"
    sun_csv.write_text("\n".join(lines) + "\n")
    assert main(["info", str(real_logs_dir / "sample_px4_events.ulg"), "--sun", str(sun_csv), "--json"]) == 0
    sun = json.loads(capsys.readouterr().out)["streams"]["sun"]
    assert sun["topic"] == "sun.csv" and sun["n_samples"] == 40
    assert sun["rate_hz"] == pytest.approx(20.0, rel=1e-3)


def test_bad_input_is_one_line_and_exit_code_2(tmp_path, capsys):
    not_a_log = tmp_path / "notes.ulg"
    not_a_log.write_text("hello\n")
    assert main(["info", str(not_a_log)]) == EXIT_BAD_INPUT
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1
    assert captured.err.startswith("solarnav info: error: notes.ulg: not a readable PX4 ULog file")


def test_bad_sun_csv_is_reported(real_logs_dir, tmp_path, capsys):
    sun_csv = tmp_path / "sun.csv"
    sun_csv.write_text("time_s,i1_mA\n1,2\n")
    assert main(["info", str(real_logs_dir / "sample_px4_events.ulg"), "--sun", str(sun_csv)]) == EXIT_BAD_INPUT
    assert "sun.csv: missing current column(s) i2_mA" in capsys.readouterr().err
