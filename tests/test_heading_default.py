"""The default heading source (docs/estimators.md, 'Heading source by default'): ``auto`` is the magnetometer and
the sun vector for a log with sun-device data, the magnetometer alone without; explicit choices are kept."""

from __future__ import annotations

import pytest

from app.samples import SAMPLE_DIR
from estimators.inputs.build import build_replay_inputs
from estimators.inputs.records import AUTO_HEADING, HEADING_SOURCES, resolve_heading
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.log_formats import load_flight_log
from ingest.sun_log import load_sun_device, with_sun


def test_auto_is_both_with_the_sun_and_the_magnetometer_without():
    assert HEADING_SOURCES[0] == AUTO_HEADING
    assert resolve_heading(AUTO_HEADING, True) == "mag+sun"
    assert resolve_heading(AUTO_HEADING, False) == "mag"
    for explicit in ("mag", "sun", "mag+sun"):
        assert resolve_heading(explicit, True) == explicit and resolve_heading(explicit, False) == explicit


@pytest.fixture(scope="module")
def sample_log():
    return load_flight_log(SAMPLE_DIR / "failed_cell.ulg")


def test_the_default_replay_inputs_fuse_the_sun_when_the_log_has_it(sample_log):
    without = build_replay_inputs(sample_log).plan
    assert "mag" in without.used and "sun" not in without.used and not without.has_sun
    sunny = with_sun(sample_log, SAMPLE_DIR / "failed_cell_sun.csv",
                     device=load_sun_device(SAMPLE_DIR / "failed_cell_device.json"))
    both = build_replay_inputs(sunny).plan
    assert {"mag", "sun"} <= set(both.used)
    only_mag = build_replay_inputs(sunny, heading="mag").plan
    assert "sun" not in only_mag.used and not only_mag.has_sun  # an explicit choice is kept


def test_the_default_falls_back_to_the_magnetometer_when_the_sun_device_gives_no_sun_vector(sample_log):
    """Without GPS there is no ephemeris: the default heading goes on with the magnetometer and says so, an explicit
    sun heading is refused."""
    sunny = with_sun(sample_log, SAMPLE_DIR / "failed_cell_sun.csv",
                     device=load_sun_device(SAMPLE_DIR / "failed_cell_device.json"))
    no_gps = FlightLog(streams={name: frame for name, frame in sunny.streams.items() if name != "gps"},
                       meta=sunny.meta)
    inputs = build_replay_inputs(no_gps)
    assert "mag" in inputs.plan.used and "sun" not in inputs.plan.used
    assert any("magnetometer heading only" in warning for warning in inputs.warnings)
    with pytest.raises(InputError, match="needs sun-vector observations"):
        build_replay_inputs(no_gps, heading="mag+sun")


def test_calibrate_takes_the_sun_device_log_as_replay_and_report_do(tmp_path, capsys):
    """``calibrate --sun`` attaches the sun so that its replays (tau, in-flight bias, identification) head with it,
    as ``replay`` and ``report`` do; ``--device`` alone is refused before any file is read."""
    from app.cli import EXIT_BAD_INPUT, main

    out = tmp_path / "calib.json"
    assert main(["calibrate", str(SAMPLE_DIR / "failed_cell.ulg"), "--device",
                 str(SAMPLE_DIR / "failed_cell_device.json"), "-o", str(out)]) == EXIT_BAD_INPUT
    assert "give --sun too" in capsys.readouterr().err and not out.exists()
    assert main(["calibrate", str(SAMPLE_DIR / "failed_cell.ulg"), "--sun", str(SAMPLE_DIR / "failed_cell_sun.csv"),
                 "--device", str(SAMPLE_DIR / "failed_cell_device.json"), "-o", str(out)]) == 0
    assert out.exists()
