"""The notes of a run (app.notes, issue 34): once each, the estimators named, problems first, expected conditions
apart."""

from __future__ import annotations

from app.notes import EXPECTED, PROBLEM, note_text, run_notes
from estimators.api import FLAGGED_PREFIX

MAG_HEADING = ("magnetometer fused as its heading only: the field strength spreads by 26% (1st-99th percentile) of "
               "its median, more than 12%: a disturbed field (currents, motors) would pull roll and pitch")
ESTIMATORS = ("three_stage", "full_state_direct", "full_state_indirect")


def _facts(name: str, warnings: tuple[str, ...] = ()) -> dict:
    """An estimator's report as the octocopter log px4_1.14_octo_flight_61.ulg gives it."""
    summary = f"inconsistent: baro.alt (mean NIS 6.9) of {name}"
    return {"used": ["baro", "gps_pos", "gps_vel", "mag"],
            "skipped": {"airspeed": "not in the log", "sideslip": "not a fixed-wing vehicle (MAV_TYPE)"},
            "degradations": [MAG_HEADING, "no airspeed: no wind states, no airspeed update",
                             "multicopter: no fixed-wing pseudo-measurements"],
            "warnings": [f"{FLAGGED_PREFIX}mag: flagged", f"{name}: {summary}", *warnings],
            "details": {"verdict": {"status": "inconsistent", "summary": summary}}, "timings_s": {}}


def test_octocopter_notes_are_given_once_with_the_problem_first():
    report = {name: _facts(name) for name in ESTIMATORS}
    report["full_state_direct"] = _facts("full_state_direct", ("full_state_direct: 3 updates skipped at |pitch| > 85"
                                                               " deg (Euler singularity)",))
    notes = run_notes(report, fixed_wing=False)
    assert [(note.severity, note.text) for note in notes] == [
        (PROBLEM, MAG_HEADING),
        (PROBLEM, "full_state_direct: 3 updates skipped at |pitch| > 85 deg (Euler singularity)"),
        (EXPECTED, "skipped airspeed: not in the log"),
        (EXPECTED, "skipped sideslip: not a fixed-wing vehicle (MAV_TYPE)"),
        (EXPECTED, "no airspeed: no wind states, no airspeed update"),
        (EXPECTED, "multicopter: no fixed-wing pseudo-measurements")]  # 15 notes before, verdicts and inputs apart
    assert note_text(notes[0], ESTIMATORS) == f"{MAG_HEADING} (all 3 estimators)"
    assert note_text(notes[1], ESTIMATORS).endswith("(full_state_direct only)")
    assert note_text(notes[0], ("three_stage",)) == MAG_HEADING


def test_a_fixed_wing_without_airspeed_is_a_problem_and_a_chosen_heading_is_not():
    facts = _facts("three_stage")
    facts["skipped"] = {"airspeed": "not in the log", "mag": "heading source is 'sun'", "baro": "not in the log",
                        "sideslip": "not part of the three-stage estimator"}
    facts["degradations"] = ["no airspeed: no wind states, no airspeed update"]
    notes = {note.text: note.severity for note in run_notes({"three_stage": facts}, fixed_wing=True)}
    assert notes == {"skipped airspeed: not in the log": PROBLEM, "skipped baro: not in the log": PROBLEM,
                     "no airspeed: no wind states, no airspeed update": PROBLEM,
                     "skipped mag: heading source is 'sun'": EXPECTED,
                     "skipped sideslip: not part of the three-stage estimator": EXPECTED}
