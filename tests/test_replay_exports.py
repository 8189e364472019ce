"""Override files for the autopilots' own replay tools (issue 33, item 2): each read back by its tool's own rules
equals the .params / .parm export (docs/calibration.md, 'Replaying with the autopilot replay tools')."""

from __future__ import annotations

import re

import pytest

from app.cli import main
from calib.export import read_calibration
from calib.parameter_export import read_ardupilot_parm, read_px4_params
from tests.conftest import REPO_DIR

FAILED_CELL = REPO_DIR / "sample_logs" / "failed_cell.ulg"


def px4_replay_rules(text: str) -> dict[str, float]:
    """PX4 replay's reading of replay_params.txt: leading blanks trimmed, empty and ``#`` lines skipped, then the
    parameter name and its value, the first two whitespace-separated words."""
    params = {}
    for raw in text.splitlines():
        line = raw.lstrip(" \t")
        if not line or line.startswith("#"):
            continue
        name, value = line.split()[:2]
        params[name] = float(value)
    return params


def ardupilot_param_line_rules(text: str) -> dict[str, float]:
    """ArduPilot's parameter-line parsing (Replay --param-file): ``#`` starts a comment, the name and the value are
    separated by a comma or whitespace, names are at most 16 characters."""
    params = {}
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        name, value = re.split(r"[\s,]+", line)[:2]
        assert len(name) <= 16
        params[name] = float(value)
    return params


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("exports")
    paths = {name: out / name for name in ("C.json", "ekf2.params", "ekf3.parm", "replay_params.txt", "replay.param")}
    assert main(["calibrate", str(FAILED_CELL), "--tune", "--tune-budget", "4", "--estimators", "full_state_indirect",
                 "-o", str(paths["C.json"]), "--px4-params", str(paths["ekf2.params"]), "--ardupilot-parm",
                 str(paths["ekf3.parm"]), "--px4-replay-params", str(paths["replay_params.txt"]),
                 "--ardupilot-replay-params", str(paths["replay.param"])]) == 0
    return paths


def test_px4_replay_params_read_back_by_px4s_rules(exported):
    text = exported["replay_params.txt"].read_text()
    values = px4_replay_rules(text)
    expected = {name: p.value for name, p in read_px4_params(exported["ekf2.params"]).items()}
    assert values == expected and all(name.startswith("EKF2_") for name in values)
    header = [line for line in text.splitlines() if line.startswith("#")]
    cal = read_calibration(exported["C.json"])
    assert any(f"from failed_cell.ulg (sha256 {cal.sha256})" in line for line in header)
    assert any("the noise identified for full_state_indirect" in line for line in header)
    assert any("replay_params.txt" in line for line in header)


def test_ardupilot_replay_param_file_read_back_by_ardupilots_rules(exported):
    text = exported["replay.param"].read_text()
    values = ardupilot_param_line_rules(text)
    expected = {name: p.value for name, p in read_ardupilot_parm(exported["ekf3.parm"]).items()}
    assert values == expected and all(name.startswith("EK3_") for name in values)
    assert all("," in line for line in text.splitlines() if not line.startswith("#"))
    assert any("--param-file" in line for line in text.splitlines() if line.startswith("#"))
