"""Inputs that parse but cannot give a trustworthy estimate are refused or flagged, never silently processed
(``ingest.quality``; the policy in ``estimators.api.run_estimators``; shown by ``solarnav info`` and ``replay``)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from app import runs
from app.cli import EXIT_BAD_INPUT, main
from estimators.api import FLAGGED_PREFIX, UNTRUSTED_PREFIX, checked_input_quality, run_estimators
from ingest import quality
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.log_formats import load_flight_log
from tests.conftest import SAMPLE_LOGS_DIR
from tests.estimators_synthetic import synthetic_flight

SLOW_IMU_LOG = "px4_1.9_quad_mission.ulg"
#: What each reference log gets: (kind, severity) of every finding.
EXPECTED_FINDINGS = {
    SLOW_IMU_LOG: {("imu_rate", "refuse")},
    "px4_1.14_octo_flight_61.ulg": set(),
    "px4_1.14_octo_flight_123.ulg": set(),
    "px4_1.17_quad_flight_corrupt.ulg": set(),
    "sample.ulg": set(),
    "sample_appended_multiple.ulg": set(),
    "sample_log_small.ulg": set(),
    "sample_logging_tagged_and_default_params.ulg": set(),
    "sample_px4_events.ulg": set(),
}


def _with_stream(log: FlightLog, name: str, frame) -> FlightLog:
    return replace(log, streams={**log.streams, name: frame})


@pytest.fixture(scope="module")
def flight() -> FlightLog:
    return synthetic_flight(duration_s=12.0, seed=3)


def _kinds(findings) -> set[tuple[str, str]]:
    return {(f.kind, f.severity) for f in findings}


# ------------------------------------------------------------------------------------------------ the findings
def test_clean_synthetic_flight_has_no_finding(flight):
    assert quality.assess_input_quality(flight) == ()


@pytest.mark.parametrize(("step", "expected"), [(25, ("imu_rate", "refuse")), (3, ("imu_rate", "flag")),
                                                 (2, None)])
def test_imu_rate_thresholds(flight, step, expected):
    """250 Hz decimated: 10 Hz refused, 83 Hz flagged, 125 Hz accepted."""
    log = _with_stream(flight, "imu", flight["imu"].iloc[::step])
    findings = quality.assess_input_quality(log)
    assert _kinds(findings) == ({expected} if expected else set())
    if expected:
        rate_hz = 250.0 / step
        assert findings[0].value == pytest.approx(rate_hz, rel=1e-6) and findings[0].unit == "Hz"
        assert findings[0].message.startswith(f"imu logged at {rate_hz:.1f} Hz")
        assert f"{100.0 / rate_hz:.1f} deg between samples" in findings[0].message


def _times_with_gaps(gaps_s, rate_hz=200.0, duration_s=100.0):
    time_s = np.arange(0.0, duration_s, 1.0 / rate_hz)
    for start_s, length_s in gaps_s:
        time_s = time_s[(time_s <= start_s) | (time_s >= start_s + length_s)]
    return time_s


@pytest.mark.parametrize(("gaps_s", "expected", "unit"), [
    ([(50.0, 0.3)], None, None),
    ([(50.0, 1.0)], "flag", "s"),
    ([(50.0, 6.0)], "refuse", "s"),
    ([(10.0 * k, 0.45) for k in range(1, 10)] + [(95.0, 3.0)], "flag", "s"),
    ([(4.0 * k, 0.45) for k in range(1, 24)], "flag", "fraction"),  # 10 % in short gaps
    ([(4.0 * k, 0.95) for k in range(1, 24)], "refuse", "fraction"),  # 22 %, none longer than 1 s
])
def test_imu_gap_thresholds(gaps_s, expected, unit):
    findings = quality.imu_gap_findings(_times_with_gaps(gaps_s))
    assert [(f.severity, f.unit) for f in findings] == ([(expected, unit)] if expected else [])
    if findings:
        assert findings[0].message.startswith(f"imu: {len(gaps_s)} gaps, longest")


def _manoeuvre_accel(rng, n=5000, rate_hz=250.0):
    """z specific force with a smooth 3 g pull-up (peak at 10 s) and 0.05 m/s^2 noise, x and y near zero."""
    t = np.arange(n) / rate_hz
    z = -9.81 - 2.0 * 9.81 * np.exp(-((t - 10.0) / 0.5) ** 2)
    return np.column_stack([rng.normal(0, 0.05, n), rng.normal(0, 0.05, n), z + rng.normal(0, 0.05, n)])


def test_clipping_needs_flat_runs_at_a_rail_beyond_2_g():
    rng = np.random.default_rng(0)
    accel = _manoeuvre_accel(rng)
    columns = list(quality.ACCEL_COLUMNS)
    assert quality.clipping_findings(accel, columns) == []  # a manoeuvre's peak is not a rail
    noiseless = accel.copy()
    noiseless[:, 2] = -9.81 - 2.0 * 9.81 * np.exp(-((np.arange(5000) / 250.0 - 10.0) / 0.5) ** 2)
    assert quality.clipping_findings(noiseless, columns) == []
    still = np.tile([0.0, 0.0, -9.80665], (5000, 1))  # SITL on the ground: flat, but 1 g is no rail
    assert quality.clipping_findings(still, columns) == []
    spike = accel.copy()
    spike[2600, 2] = -96.0  # one impact sample
    assert quality.clipping_findings(spike, columns) == []


@pytest.mark.parametrize(("rail_g", "severity"), [(-2.95, "flag"), (-2.5, "refuse")])
def test_clipped_accelerometer_is_flagged_then_refused(rail_g, severity):
    """The 3 g pull-up through an accelerometer saturating at ``rail_g``: 0.8 % of the rows clipped (flagged),
    then 2.7 % (refused above 1 %)."""
    accel = _manoeuvre_accel(np.random.default_rng(1))
    rail = rail_g * quality.STANDARD_GRAVITY_M_S2
    accel[:, 2] = np.maximum(accel[:, 2], rail)
    [finding] = quality.clipping_findings(accel, list(quality.ACCEL_COLUMNS))
    assert finding.kind == "accel_clipping" and finding.severity == severity
    assert finding.value == pytest.approx(np.mean(accel[:, 2] == rail), abs=1e-3)
    assert f"axis z at {rail:+.1f} m/s^2 ({rail / quality.STANDARD_GRAVITY_M_S2:+.1f} g" in finding.message


def test_gps_without_3d_fix_is_flagged(flight):
    gps = flight["gps"].assign(fix_type=2)
    [finding] = quality.assess_input_quality(_with_stream(flight, "gps", gps))
    assert (finding.kind, finding.severity, finding.stream) == ("gps_no_fix", "flag", "gps")
    assert f"no 3D fix in any of its {len(gps)} rows (best fix type 2)" in finding.message
    assert quality.gps_fix_findings(flight["gps"]) == []


def test_time_base_jumps_are_flagged():
    imu = np.arange(0.0, 300.0, 0.01)
    baro = np.concatenate([np.arange(0.0, 100.0, 0.1), np.arange(200.0, 300.0, 0.1)])  # a 100 s jump
    back = np.array([0.0, 1.0, 2.0, 1.5, 3.0])
    late = np.arange(400.0, 420.0, 1.0)  # another clock
    findings = quality.time_base_findings({"imu": imu, "baro": baro, "mag": back, "gps": late,
                                           "airspeed": np.arange(0.0, 300.0, 0.05)}, {"baro": "vehicle_air_data"})
    by_stream = {f.stream: f for f in findings}
    assert set(by_stream) == {"baro", "mag", "gps"} and {f.severity for f in findings} == {"flag"}
    assert by_stream["baro"].message.startswith("baro (vehicle_air_data): the time base jumps: 1 jumps forward")
    assert "largest 100.1 s at 99.900 s" in by_stream["baro"].message
    assert "1 steps back (largest 0.500 s)" in by_stream["mag"].message and by_stream["mag"].threshold == 0.0
    assert "119.0 s outside the IMU span" in by_stream["gps"].message


# ------------------------------------------------------------------------------------------------- the policy
def test_replay_of_a_refused_log_raises_unless_forced(flight):
    slow = _with_stream(flight, "imu", flight["imu"].iloc[::25])  # 10 Hz
    with pytest.raises(InputError, match=r"refused: imu logged at 10\.0 Hz, below the 50 Hz .* --force"):
        run_estimators(slow, estimators="three_stage", rate_hz=5.0)
    result = run_estimators(slow, estimators="three_stage", rate_hz=5.0, allow_untrusted=True)
    report = result.reports["three_stage"]
    assert report.warnings[0].startswith(UNTRUSTED_PREFIX + "imu logged at 10.0 Hz")
    assert [f["kind"] for f in report.details["input_quality"]] == ["imu_rate"]
    assert _kinds(result.input_quality) == {("imu_rate", "refuse")}


def test_flagged_inputs_are_replayed_with_the_warning(flight):
    log = _with_stream(flight, "imu", flight["imu"].iloc[::3])  # 83 Hz
    log = _with_stream(log, "gps", flight["gps"].assign(fix_type=2))
    result = run_estimators(log, estimators="full_state_direct", rate_hz=5.0)
    warnings = result.reports["full_state_direct"].warnings
    assert warnings[0].startswith(FLAGGED_PREFIX + "imu logged at 83.3 Hz")
    assert any(w.startswith(FLAGGED_PREFIX + "gps: no 3D fix") for w in warnings)
    assert "gps_pos" not in result.reports["full_state_direct"].used  # the filter degraded, as the flag says


def test_dashboard_replay_refuses_unless_the_settings_allow_it(flight):
    slow = _with_stream(flight, "imu", flight["imu"].iloc[::25])
    settings = runs.RunSettings(estimators=("three_stage",), rate_hz=5.0)
    with pytest.raises(InputError, match="refused"):
        runs.replay(slow, settings)
    forced = replace(settings, allow_untrusted=True)
    assert runs.RunSettings.from_json_dict(forced.to_dict()) == forced
    assert runs.RunSettings.from_json_dict({"estimators": ["three_stage"], "rate_hz": 5.0}) == settings
    _, _, report = runs.replay(slow, forced)
    assert report["three_stage"]["warnings"][0].startswith(UNTRUSTED_PREFIX)


# ------------------------------------------------------------------------------------------------ real logs
@pytest.mark.parametrize("name", sorted(EXPECTED_FINDINGS))
def test_reference_logs_get_exactly_their_findings(real_logs_dir, name):
    """No false positive of clipping, gaps or time jumps on real flights (peaks of 96 m/s^2 in octo_flight_61 are
    single samples); only the 10 Hz IMU of the PX4 1.9 mission is refused."""
    log = load_flight_log(real_logs_dir / name)
    findings = quality.assess_input_quality(log)
    assert _kinds(findings) == EXPECTED_FINDINGS[name], [f.message for f in findings]
    if name != SLOW_IMU_LOG:
        checked_input_quality(log)  # the replay gate lets it through


@pytest.mark.parametrize("name", ["failed_cell.ulg", "paper.ulg"])
def test_bundled_samples_are_not_refused(name):
    log = load_flight_log(SAMPLE_LOGS_DIR / name)
    assert checked_input_quality(log) == ()


def test_info_shows_the_findings(real_logs_dir, capsys):
    log = str(real_logs_dir / SLOW_IMU_LOG)
    assert main(["info", log]) == 0
    out = capsys.readouterr().out
    assert ("input quality: 1 finding\n  - REFUSED: imu (sensor_combined) logged at 9.6 Hz, below the 50 Hz "
            "strapdown integration needs (a 100 deg/s manoeuvre turns 10.4 deg between samples)") in out
    assert main(["info", log, "--json"]) == 0
    [finding] = json.loads(capsys.readouterr().out)["input_quality"]
    assert finding["kind"] == "imu_rate" and finding["severity"] == "refuse"
    assert finding["value"] == pytest.approx(9.62, abs=0.01) and finding["threshold"] == 50.0
    assert main(["info", str(real_logs_dir / "sample_px4_events.ulg")]) == 0
    assert "input quality: no finding" in capsys.readouterr().out


def test_replay_command_refuses_the_10_hz_log_in_one_line(real_logs_dir, tmp_path, capsys):
    out = tmp_path / "x.parquet"
    assert main(["replay", str(real_logs_dir / SLOW_IMU_LOG), "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"solarnav: error: {SLOW_IMU_LOG}: refused: imu (sensor_combined) "
                                                   "logged at 9.6 Hz")
    assert "--force" in err and not out.exists()
    argv = ["replay", str(real_logs_dir / SLOW_IMU_LOG), "--estimators", "three_stage", "--rate-hz", "2", "--force",
            "-o", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("WARNING: " + UNTRUSTED_PREFIX + "imu (sensor_combined) logged at 9.6 Hz")
    assert out.exists()


def test_dashboard_shows_refusal_and_runs_only_when_forced(real_logs_dir, tmp_path, monkeypatch):
    """Overview and Estimators pages of the 10 Hz log: the refusal in an error box; pressing Run without the
    override stores nothing; with it, the stored run leads with the UNTRUSTED INPUT warning."""
    from streamlit.testing.v1 import AppTest

    from app import session
    from app.workspace import Workspace
    from tests.conftest import REPO_DIR

    content = (real_logs_dir / SLOW_IMU_LOG).read_bytes()
    entry = Workspace(tmp_path).add_log(content, SLOW_IMU_LOG)
    monkeypatch.setenv(session.WORKSPACE_ENV, str(tmp_path))
    at = AppTest.from_file(str(REPO_DIR / "app" / "dashboard.py"), default_timeout=300)
    at.run()
    at.sidebar.selectbox[0].set_value(entry.sha256).run()
    at.switch_page("views/overview.py").run()
    assert not at.exception
    assert any("Refused input" in e.value and "9.6 Hz" in e.value for e in at.error)
    at.switch_page("views/estimators.py").run()
    assert any("Refused input" in e.value for e in at.error)
    at.multiselect(key="est_names").set_value(["three_stage"])
    at.button[0].click().run()
    assert not at.exception and any("refused: imu (sensor_combined)" in e.value for e in at.error)
    assert Workspace(tmp_path).list_runs(entry.sha256).empty
    at.checkbox(key="est_force").check()
    at.button[0].click().run()
    assert not at.exception
    assert len(Workspace(tmp_path).list_runs(entry.sha256)) == 1
    assert any(e.value.startswith(UNTRUSTED_PREFIX) for e in at.error)
