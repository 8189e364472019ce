"""The shareable flight report (issue 33, item 3): one self-contained HTML file with every section, plotly.js
embedded (no network), the verdicts, the RMS table against the reference and the exported parameters."""

from __future__ import annotations

import dataclasses
import re

import pytest

from app.cli import main
from app.report import SECTIONS, render_report
from ingest.log_formats import load_flight_log
from tests.conftest import REPO_DIR
from workflows.report import flight_report


@pytest.fixture(scope="module")
def paper_report():
    log = load_flight_log(REPO_DIR / "sample_logs" / "failed_cell.ulg")
    report = flight_report(log)
    return report, render_report(report)


def test_every_section_is_there_and_nothing_is_fetched(paper_report):
    report, text = paper_report
    for key, label in SECTIONS:
        assert f'<section id="{key}"><h2>{label}</h2>' in text
    assert "Plotly" in text and text.count("Plotly.newPlot") >= 4  # attitude, altitude, wind, errors, track
    # self-contained: no script or stylesheet from elsewhere
    assert not re.search(r'<script[^>]+src=', text) and not re.search(r'<link[^>]+href=', text)
    assert report.calibration is not None and set(report.exports) == {"solarnav_ekf2.params", "solarnav_ek3.parm"}
    assert "EKF2_BARO_NOISE" in text and "EK3_ALT_M_NSE" in text


def test_verdicts_and_the_rms_table_against_the_truth(paper_report):
    report, text = paper_report
    for name, estimator_report in report.result.reports.items():
        verdict = estimator_report.details["verdict"]
        assert f'<div class="verdict {verdict["status"]}"><b>{name}</b>' in text
    assert "errors against the ground truth" in text and "Roll Angle (deg)" in text
    assert report.evaluation.reference == "truth"


def test_a_refused_log_is_reported_without_estimates(paper_report):
    report, _ = paper_report
    slow = dataclasses.replace(report.log, streams={**report.log.streams, "imu": report.log["imu"].iloc[::20]})
    refused = flight_report(slow, calibration=report.calibration)
    assert refused.result is None and refused.evaluation is None and "refused: imu" in refused.refusal
    text = render_report(refused)
    assert "The estimators did not run" in text and "No estimates to compare." in text


def test_report_cli_writes_html_only(tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(REPO_DIR / "sample_logs" / "failed_cell.ulg"), "-o", str(out)]) == 0
    assert out.read_text().startswith("<!DOCTYPE html>") and "wrote" in capsys.readouterr().out
    assert main(["report", str(REPO_DIR / "sample_logs" / "failed_cell.ulg"), "-o", str(tmp_path / "r.txt")]) == 2
    assert not (tmp_path / "r.txt").exists()
