"""A flight report as one self-contained HTML file (``solarnav report``, the Estimators page's download): plotly.js
embedded once, every figure and table inline, so it opens offline and can be attached to a flight-test record.
Sections: the flight, its streams and input findings, the calibration and identified noise, each estimator's
consistency verdict, the comparison with the truth or the autopilot's onboard estimate (RMS table and charts), the
track, and the exported autopilot parameters."""

from __future__ import annotations

import datetime as dt
import html

import pandas as pd
import plotly.graph_objects as go
import plotly.offline

from app import comparison, figures, tables
from calib.tables import noise_table
from workflows.report import FlightReport

#: Section ids and titles, in order (the report's table of contents).
SECTIONS = (("flight", "Flight"), ("streams", "Streams and input findings"), ("calibration", "Calibration"),
            ("verdicts", "Estimator verdicts"), ("comparison", "Comparison"), ("track", "Track"),
            ("exports", "Exported autopilot parameters"))
_STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1100px;color:#222}
h1{font-size:1.6em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0} th,td{border:1px solid #ddd;padding:.2em .5em}
th{background:#f4f4f4} td{text-align:right} td:first-child,th:first-child{text-align:left}
.consistent{background:#e6f4ea} .conservative{background:#e8f0fe} .inconsistent{background:#fce8e6}
.verdict{padding:.4em .6em;margin:.3em 0;border-radius:4px} pre{background:#f7f7f7;padding:.6em;overflow-x:auto}
.note{color:#555;font-size:.9em} .wide{overflow-x:auto}
"""
#: Points per line of a report's charts (the dashboard draws 2000): enough for a flight's shape, and the file stays
#: a few MB (every point carries its hover text).
REPORT_MAX_POINTS = 500


def _table(frame: pd.DataFrame, *, index: bool = False) -> str:
    table = frame.to_html(index=index, float_format=lambda v: f"{v:.4g}", na_rep="–", border=0)
    return f'<div class="wide">{table}</div>'  # a wide table scrolls instead of running off the page


def _figure(fig: go.Figure) -> str:
    return fig.to_html(full_html=False, include_plotlyjs=False, config={"displaylogo": False})


def _paragraph(text: str, css: str = "") -> str:
    return f'<p class="{css}">{html.escape(text)}</p>' if css else f"<p>{html.escape(text)}</p>"


def _flight(report: FlightReport) -> str:
    meta = report.log.meta
    utc = (f"{report.log.utc(meta.start_time_s)[0]:%Y-%m-%d %H:%M:%S} UTC" if meta.utc_offset_s is not None
           else "unknown (no GPS time)")
    facts = pd.DataFrame([("file", meta.source), ("sha256", meta.sha256), ("firmware", meta.px4_version or "unknown"),
                          ("hardware", meta.hardware or "unknown"), ("vehicle", tables.vehicle_name(meta.vehicle_type)),
                          ("start", utc), ("duration", tables.duration_text(meta.duration_s))],
                         columns=["", "value"])
    return _table(facts)


def _streams(report: FlightReport) -> str:
    parts = [_table(tables.streams_table(report.log.meta))]
    parts += [_paragraph(f"{finding.severity}: {finding.message}", "note") for finding in report.findings]
    parts += [_paragraph(f"reader: {warning}", "note") for warning in report.log.meta.warnings]
    return "".join(parts)


def _calibration(report: FlightReport) -> str:
    parts = [_paragraph(f"Noise: {report.calibration_note}.")]
    cal = report.calibration
    if cal is not None:
        parts.append(_table(noise_table(cal), index=True))
        if cal.tuning:
            parts += ["<h3>Identified noise (per estimator)</h3>", _table(tables.tuning_table(cal))]
    return "".join(parts)


def _verdicts(report: FlightReport) -> str:
    if report.result is None:
        return _paragraph(f"The estimators did not run: {report.refusal}", "verdict inconsistent")
    parts = []
    for name, estimator_report in report.result.reports.items():
        verdict = estimator_report.details["verdict"]
        parts.append(f'<div class="verdict {verdict["status"]}"><b>{html.escape(name)}</b>: '
                     f'{html.escape(verdict["summary"])}</div>')
        parts.append("<details><summary>channels</summary>" + _table(tables.verdict_channels(verdict)) + "</details>")
        parts += [_paragraph(f"{name}: {warning}", "note") for warning in estimator_report.warnings
                  if warning != f"{name}: {verdict['summary']}"]
    return "".join(parts)


def _comparison(report: FlightReport) -> str:
    evaluation = report.evaluation
    if evaluation is None:
        return _paragraph("No estimates to compare.")
    base = figures.time_base(report.log)
    parts = []
    if evaluation.reference is None:
        parts.append(_paragraph("The log has neither ground truth nor an onboard estimate: no errors."))
    else:
        what = ("errors against the ground truth" if evaluation.reference == "truth" else
                "disagreement with the autopilot's onboard estimate (lower means closer to the autopilot, not "
                "necessarily better)")
        parts.append(_paragraph(f"RMS {what}; {comparison.window_caption(evaluation, base.start_s)}."))
        parts.append(_table(comparison.rms_table(evaluation), index=True))
    for title, rows in comparison.STATE_PANELS.items():
        parts.append(_figure(figures.quantity_figure(evaluation.quantities, rows, title=title, time_base=base,
                                                             max_points=REPORT_MAX_POINTS)))
    if evaluation.errors:
        parts.append(_figure(figures.quantity_figure(evaluation.errors, comparison.ERROR_ROWS, time_base=base,
                                                     title=f"Errors against the {evaluation.reference}",
                                                     max_points=REPORT_MAX_POINTS)))
    return "".join(parts)


def _track(report: FlightReport) -> str:
    evaluation = report.evaluation
    tracks = {} if evaluation is None else {source: frame for source, frame in evaluation.quantities.items()
                                            if frame["north_m"].notna().any()}
    if not tracks:
        return _paragraph("No position (no GPS fix).")
    return _figure(figures.track_figure(tracks, REPORT_MAX_POINTS, time_base=figures.time_base(report.log)))


def _exports(report: FlightReport) -> str:
    if not report.exports:
        return _paragraph("None: the flight could not be calibrated.")
    return "".join(f"<h3>{html.escape(name)}</h3><pre>{html.escape(text)}</pre>"
                   for name, text in report.exports.items())


def render_report(report: FlightReport) -> str:
    """The report as one HTML document (UTF-8 text), plotly.js included."""
    body = {"flight": _flight, "streams": _streams, "calibration": _calibration, "verdicts": _verdicts,
            "comparison": _comparison, "track": _track, "exports": _exports}
    created = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    title = f"solarnav flight report: {report.log.meta.source}"
    contents = "".join(f'<li><a href="#{key}">{label}</a></li>' for key, label in SECTIONS)
    sections = "".join(f'<section id="{key}"><h2>{label}</h2>{body[key](report)}</section>' for key, label in SECTIONS)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f"<style>{_STYLE}</style><script>{plotly.offline.get_plotlyjs()}</script></head><body>"
            f"<h1>{html.escape(title)}</h1>{_paragraph(f'made {created}', 'note')}<ul>{contents}</ul>{sections}"
            "</body></html>")
