"""The notes of an estimator run as a page shows them: each note once, naming the estimators it applies to, the
problems first and the expected conditions apart (a sensor the vehicle does not carry, a multicopter's unused
fixed-wing aids, what an estimator leaves out by design, a heading source the user chose), so that the note that
matters is not buried among them.

No Streamlit here: the Estimators page draws the notes (problems as warnings, expected conditions as one info).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from estimators.api import FLAGGED_PREFIX, UNTRUSTED_PREFIX
from estimators.inputs.build import MULTICOPTER, NO_AIRSPEED, NOT_FIXED_WING, NOT_IN_LOG
from estimators.three_stage.run import NOT_IN_THREE_STAGE

PROBLEM = "problem"
EXPECTED = "expected"


@dataclass(frozen=True)
class RunNote:
    """One note of a run: :data:`PROBLEM` or :data:`EXPECTED`, its text and the estimators it applies to."""

    severity: str
    text: str
    estimators: tuple[str, ...]


def run_notes(report: Mapping[str, dict], *, fixed_wing: bool) -> list[RunNote]:
    """The notes of a run's report (estimator -> its facts, :func:`app.adapters.run_report`): skipped sensors,
    degradations and warnings, each once with the estimators it applies to, problems first (in report order).

    Left out: the refused and flagged inputs and the consistency verdicts, which the page shows on their own.
    ``fixed_wing``: the vehicle is a fixed wing (its missing airspeed is then a problem, not a condition).
    """
    applies: dict[tuple[str, str], list[str]] = {}
    for name, facts in report.items():
        verdict_warning = f"{name}: {facts['details'].get('verdict', {}).get('summary')}"
        notes = [(_skip_severity(sensor, reason, fixed_wing), f"skipped {sensor}: {reason}")
                 for sensor, reason in facts["skipped"].items()]
        notes += [(EXPECTED if text == MULTICOPTER or (text == NO_AIRSPEED and not fixed_wing) else PROBLEM, text)
                  for text in facts["degradations"]]
        notes += [(PROBLEM, text) for text in facts["warnings"]
                  if text != verdict_warning and not text.startswith((UNTRUSTED_PREFIX, FLAGGED_PREFIX))]
        for note in notes:
            applies.setdefault(note, []).append(name)
    notes = [RunNote(severity, text, tuple(names)) for (severity, text), names in applies.items()]
    return sorted(notes, key=lambda note: note.severity != PROBLEM)


def _skip_severity(sensor: str, reason: str, fixed_wing: bool) -> str:
    """:data:`EXPECTED` for the fixed-wing aids of a multicopter (sideslip, no airspeed sensor), a
    pseudo-measurement the three-stage estimator has no use for and a magnetometer left out because the user chose
    another heading source; else :data:`PROBLEM`."""
    expected = (reason in (NOT_FIXED_WING, NOT_IN_THREE_STAGE)
                or (sensor == "airspeed" and reason == NOT_IN_LOG and not fixed_wing)
                or (sensor == "mag" and reason.startswith("heading source is")))
    return EXPECTED if expected else PROBLEM


def note_text(note: RunNote, estimators: tuple[str, ...]) -> str:
    """The note's text and whom it applies to among the run's ``estimators``: nothing added for a run of one
    estimator, "all N estimators" when it applies to every one, else their names."""
    if len(estimators) == 1:
        return note.text
    if set(note.estimators) == set(estimators):
        return f"{note.text} (all {len(estimators)} estimators)"
    return f"{note.text} ({', '.join(note.estimators)} only)"
