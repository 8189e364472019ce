"""Every calibration figure says what it is (issue 34): at rest a lower bound of the in-flight noise, in steady
flight the in-flight noise, in any other window an upper bound; identified values on a search bound flagged; the
meanings reach CALIB.json and the exported parameter comments."""

from __future__ import annotations

import json

from calib.calibration import calibrate
from calib.export import calibration_to_dict
from calib.figures import (
    MEANING_IDENTIFIED,
    MEANING_IN_FLIGHT,
    MEANING_LOWER_BOUND,
    MEANING_UPPER_BOUND,
    SOURCE_TUNED,
    Figure,
)
from calib.segments import find_stationary_segments, user_segment
from calib.tables import noise_meaning, noise_table
from ingest.log_formats import load_flight_log
from tests.conftest import REPO_DIR
from workflows.exports import px4_text


def test_segment_kinds_give_lower_in_flight_and_upper_bounds():
    log = load_flight_log(REPO_DIR / "sample_logs" / "failed_cell.ulg")
    automatic = calibrate(log)
    kinds = {name: s.segment.kind for name, s in automatic.sensors.items()}
    for name, kind in kinds.items():
        expected = {"stationary": MEANING_LOWER_BOUND, "steady": MEANING_IN_FLIGHT}[kind]
        assert noise_meaning(automatic, name) == expected
    rest = find_stationary_segments(log)[0]
    at_rest = calibrate(log, segment=user_segment(log, rest.start_s + 1.0, rest.end_s - 1.0))
    assert {noise_meaning(at_rest, name) for name in at_rest.sensors} == {MEANING_LOWER_BOUND}
    flying = calibrate(log, segment=user_segment(log, log.meta.end_time_s - 60.0, log.meta.end_time_s - 20.0))
    assert noise_meaning(flying, "gyroscope") == MEANING_UPPER_BOUND
    assert set(noise_table(flying)["meaning"]) >= {MEANING_UPPER_BOUND}
    data = calibration_to_dict(flying)
    assert data["sensors"]["gyroscope"]["meaning"] == MEANING_UPPER_BOUND
    json.dumps(data, allow_nan=False)


def test_identified_figures_on_their_bound_are_flagged():
    figure = Figure("baro_noise", 0.02, SOURCE_TUNED)
    assert figure.meaning == MEANING_IDENTIFIED
    assert figure.meaning_within((0.02, 20.0)) == f"{MEANING_IDENTIFIED}, at its lower bound 0.02"
    assert figure.meaning_within((0.01, 20.0)) == MEANING_IDENTIFIED


def test_export_comments_carry_the_meaning():
    log = load_flight_log(REPO_DIR / "sample_logs" / "failed_cell.ulg")
    text = px4_text(calibrate(log), log.meta.parameters)
    gyro = next(line for line in text.splitlines() if line.startswith("# EKF2_GYR_NOISE: gyro_noise_density"))
    assert MEANING_LOWER_BOUND in gyro


def test_the_octocopter_without_a_still_or_steady_segment_gives_upper_bounds(real_logs_dir):
    log = load_flight_log(real_logs_dir / "px4_1.14_octo_flight_61.ulg")
    whole = calibrate(log, segment=user_segment(log, log.meta.start_time_s, log.meta.end_time_s))
    assert {noise_meaning(whole, name) for name in ("gyroscope", "accelerometer")} == {MEANING_UPPER_BOUND}
