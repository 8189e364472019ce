"""Everything a flight report holds, computed once: the log's streams and findings, its calibration (and identified
noise), each estimator's replay and verdict, the comparison with the truth or the autopilot's onboard estimate, and
the exported autopilot parameters. ``app.report`` renders it as one self-contained HTML file (``solarnav report``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from calib.calibration import Calibration
from estimators.api import DEFAULT_ESTIMATORS, ReplayResult
from estimators.evaluation import Evaluation, evaluate
from estimators.inputs.records import AUTO_HEADING
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.quality import QualityFinding, assess_input_quality
from workflows.calibration import CompileNotice, calibrate_log
from workflows.exports import ardupilot_text, px4_text
from workflows.replay import replay_log

#: Output rate of a report's replay [Hz]: enough for the charts and the RMS table of a flight.
REPORT_RATE_HZ = 10.0


@dataclass(frozen=True)
class FlightReport:
    """The content of a flight report.

    Attributes
    ----------
    log : FlightLog
        The flight.
    findings : tuple of QualityFinding
        Input quality (what the estimators refuse or flag).
    calibration : Calibration or None
        The calibration used for the replay and the exports (None: the datasheet noise).
    calibration_note : str
        Where the calibration came from, or why there is none.
    result : ReplayResult or None
        The estimators' replay (None when the inputs were refused: ``refusal`` says why).
    refusal : str
        Why the estimators did not run ("" when they did).
    evaluation : Evaluation or None
        The estimates against the truth or the onboard estimate (:func:`estimators.evaluation.evaluate`).
    exports : dict of str -> str
        File name -> text of the exported autopilot parameters (empty without a calibration).
    """

    log: FlightLog
    findings: tuple[QualityFinding, ...]
    calibration: Calibration | None
    calibration_note: str
    result: ReplayResult | None
    refusal: str = ""
    evaluation: Evaluation | None = None
    exports: dict[str, str] = field(default_factory=dict)


def flight_report(log: FlightLog, *, calibration: Calibration | None = None, tune: bool = False,
                  estimators: str | Sequence[str] = DEFAULT_ESTIMATORS, heading: str = AUTO_HEADING,
                  rate_hz: float = REPORT_RATE_HZ, on_compile: CompileNotice | None = None) -> FlightReport:
    """Calibrate ``log`` (unless ``calibration`` is given; ``tune`` identifies the noise too), replay
    ``estimators`` with it at ``rate_hz`` [Hz] (output rate), evaluate them and export the autopilot parameters.

    A log without a segment to calibrate on is replayed with the datasheet noise, and one whose inputs the
    estimators refuse is reported without estimates; both say why."""
    note = "given"
    if calibration is None:
        try:
            calibration = calibrate_log(log, tune=estimators if tune else (), on_compile=on_compile)
            note = "identified from the flight's innovations" if tune else "calibrated from the flight (eq 50-52)"
        except InputError as exc:
            note = f"not calibrated, replayed with the datasheet noise: {exc}"
    result, refusal, evaluation = None, "", None
    try:
        result = replay_log(log, estimators=estimators, calibration=calibration, heading=heading,
                            rate_hz=rate_hz)
        evaluation = evaluate(result.states, log)
    except InputError as exc:
        refusal = str(exc)
    exports = {} if calibration is None else {
        "solarnav_ekf2.params": px4_text(calibration, log.meta.parameters),
        "solarnav_ek3.parm": ardupilot_text(calibration, log.meta.parameters)}
    return FlightReport(log=log, findings=assess_input_quality(log), calibration=calibration,
                        calibration_note=note, result=result, refusal=refusal, evaluation=evaluation,
                        exports=exports)
