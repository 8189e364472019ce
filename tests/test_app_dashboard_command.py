"""``solarnav dashboard``: argument parsing, the Streamlit command line, the config it relies on, and the
workspace preparation (bundled samples added once, recognised by content hash)."""

from __future__ import annotations

import tomllib

import pytest

from app import runs, samples
from app.cli import build_parser
from app.commands import dashboard
from app.workspace import Workspace
from tests.conftest import REPO_DIR


def test_parser_and_streamlit_command(tmp_path):
    args = build_parser().parse_args(["dashboard", "--workspace", str(tmp_path / "ws"), "--port", "8765",
                                      "--skip-sample-runs"])
    assert args.run is dashboard.run and args.port == 8765 and args.skip_sample_runs
    command = dashboard.streamlit_command(tmp_path / "ws", 8765)
    assert command[1:4] == ["-m", "streamlit", "run"] and command[4].endswith("app/dashboard.py")
    assert command[command.index("--server.port") + 1] == "8765"
    assert command[-3:] == ["--", "--workspace", str(tmp_path / "ws")]
    assert (dashboard.CONFIG_DIR / ".streamlit" / "config.toml").is_file()


def test_config_sets_an_explicit_upload_limit():
    config = tomllib.loads((REPO_DIR / ".streamlit" / "config.toml").read_text())
    assert 100 <= config["server"]["maxUploadSize"] <= 2048
    assert config["server"]["headless"] is True


def test_samples_are_added_once_with_their_companions(tmp_path):
    folder = tmp_path / "samples"
    folder.mkdir()
    (folder / "mission.ulg").write_bytes(b"ulog A")
    (folder / "mission_sun.csv").write_bytes(b"time_s,i1_mA\n")
    (folder / "mission_device.json").write_bytes(b"{}")
    (folder / "mission_sim.json").write_bytes(b"{}")  # simulator metadata: not a companion
    (folder / "mission_failed_cell.ulg").write_bytes(b"ulog B")
    (folder / "mission_failed_cell_sun.csv").write_bytes(b"time_s\n")
    found = samples.find_samples(folder)
    assert [(s.ulog.name, s.sun_csv.name, getattr(s.device_json, "name", None)) for s in found] == [
        ("mission.ulg", "mission_sun.csv", "mission_device.json"),
        ("mission_failed_cell.ulg", "mission_failed_cell_sun.csv", None)]
    workspace = Workspace(tmp_path / "ws")
    first = samples.add_samples(workspace, found)
    again = samples.add_samples(Workspace(tmp_path / "ws"), found)
    assert [e.sha256 for e in first] == [e.sha256 for e in again]
    assert len(workspace.list_logs()) == 2 and all(e.has_sun for e in first)
    assert samples.find_samples(tmp_path / "missing") == []


def test_prepare_samples_stores_a_default_run_once(tmp_path):
    short = [sample for sample in samples.find_samples() if sample.ulog.name == "failed_cell.ulg"]
    assert short, "the bundled short scenario is missing (run `solarnav simulate`)"
    workspace = Workspace(tmp_path / "ws")
    lines: list[str] = []
    [entry] = samples.prepare_samples(workspace, short, report=lines.append)
    [run_id] = workspace.list_runs(entry.sha256)["run_id"]
    states, diagnostics, report = workspace.load_run(run_id)
    assert set(states["estimator"].astype(str)) == set(report) == set(runs.RunSettings().estimators)
    assert len(diagnostics) > 0 and any("running the estimators" in line for line in lines)
    assert workspace.load_run_table(run_id, "states").equals(states) and workspace.load_run_report(run_id) == report
    with pytest.raises(ValueError, match="run table"):
        workspace.run_table_path(run_id, "../catalog")
    assert runs.find_run(workspace, entry.sha256, runs.RunSettings()) == run_id
    samples.prepare_samples(Workspace(tmp_path / "ws"), short, report=lines.append)  # restart: nothing to redo
    assert len(workspace.list_runs(entry.sha256)) == 1
