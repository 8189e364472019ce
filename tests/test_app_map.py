"""The Map page (issue 14): the pure figure builders of :mod:`app.maps` (traces per source, downsampled values,
phase colours, zoom fit) and the page itself headless on the bundled mission, with and without a run, and on a
log without GPS."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from streamlit.testing.v1 import AppTest

from app import adapters, figures, maps, runs, samples, session
from app.workspace import Workspace
from estimators.core.results import STATE_COLUMNS
from ingest.flightlog import FlightLog, LogMetadata
from tests.conftest import REPO_DIR

ENTRYPOINT = REPO_DIR / "app" / "dashboard.py"
PAPER = samples.SAMPLE_DIR / "paper.ulg"
TIMEOUT_S = 300
LAT0, LON0 = 34.98, 108.93


def _circle(n: int, t0: float = 20.0, rate_hz: float = 10.0, radius_m: float = 500.0) -> pd.DataFrame:
    time_s = t0 + np.arange(n) / rate_hz
    angle = 2 * np.pi * (time_s - t0) / 120.0
    return pd.DataFrame({"time_s": time_s, "lat_deg": LAT0 + radius_m * np.sin(angle) / 111_000.0,
                         "lon_deg": LON0 + radius_m * (1 - np.cos(angle)) / 91_000.0,
                         "alt_m": 600.0 + 0.1 * (time_s - t0)})


PHASES = pd.DataFrame({"phase": ["stationary", "steady cruise", "manoeuvring"], "start_s": [20.0, 50.0, 200.0],
                       "end_s": [50.0, 200.0, 520.0], "duration_s": [30.0, 150.0, 320.0], "reason": ["", "", ""]})


def _traces(fig) -> dict:
    return {trace.name: trace for trace in fig.data}


# ------------------------------------------------------------------------------------------------ pure functions
def test_one_trace_per_source_in_the_shared_colours_with_log_start_hover():
    tracks = {"truth": _circle(500), "GPS": _circle(400, t0=21.0), "three_stage": _circle(450, t0=22.0),
              "onboard": _circle(300, t0=23.0)}
    fig = maps.map_figure(tracks, start_time_s=20.0)
    assert [t.name for t in fig.data] == ["three_stage", "onboard", "truth", "GPS"]  # the pages' source order
    for trace in fig.data:
        assert trace.type == "scattermap" and trace.mode == "lines"
        assert trace.line.color == figures.SOURCE_COLORS[trace.name]
        track = tracks[trace.name]
        np.testing.assert_allclose(trace.lat, track["lat_deg"])  # short: every point
        np.testing.assert_allclose(np.asarray(trace.customdata)[:, 0], track["time_s"] - 20.0)  # since log start
        np.testing.assert_allclose(np.asarray(trace.customdata)[:, 1], track["alt_m"])
        assert "since log start" in trace.hovertemplate and "altitude" in trace.hovertemplate
    assert fig.layout.map.style == maps.MAP_STYLE


def test_long_tracks_are_downsampled_to_the_inputs_at_the_chosen_indices():
    track = _circle(30_000)
    fig = maps.map_figure({"GPS": track}, start_time_s=0.0, max_points=1000)
    [trace] = fig.data
    keep = maps.track_indices(track, 1000)
    assert 100 < len(keep) <= 1000 and np.all(np.diff(keep) > 0)
    np.testing.assert_array_equal(trace.lat, track["lat_deg"].to_numpy()[keep])
    np.testing.assert_array_equal(trace.lon, track["lon_deg"].to_numpy()[keep])
    # the union of MinMaxLTTB on latitude and longitude keeps both extremes of the circle
    assert max(trace.lat) == track["lat_deg"].max() and min(trace.lon) == track["lon_deg"].min()
    half = figures.downsample_indices(track["time_s"].to_numpy(), track["lat_deg"].to_numpy(), 500)
    assert set(half) <= set(keep)


def test_phases_colour_markers_on_the_gps_track():
    tracks = {"truth": _circle(5000), "GPS": _circle(5000)}
    fig = maps.map_figure(tracks, start_time_s=20.0, phases=PHASES)
    traces = _traces(fig)
    markers = [t for t in fig.data if t.mode == "markers"]
    assert [t.name for t in markers] == ["phase: stationary", "phase: steady cruise", "phase: manoeuvring"]
    gps = tracks["GPS"].iloc[maps.track_indices(tracks["GPS"])]  # the drawn (downsampled) points
    for trace, row in zip(markers, PHASES.itertuples(), strict=True):
        assert trace.marker.color == maps.phase_color(row.phase) and trace.marker.color.startswith("rgb(")
        times = np.asarray(trace.customdata)[:, 0] + 20.0
        assert np.all((times >= row.start_s) & (times <= row.end_s))
        inside = gps.loc[maps.phase_of(gps["time_s"].to_numpy(), PHASES) == row.phase]  # shared ends: later
        np.testing.assert_allclose(trace.lat, inside["lat_deg"])  # the GPS track's points, not the truth's
    assert sum(len(t.lat) for t in markers) == len(traces["GPS"].lat)
    assert maps.phase_color("steady cruise") == "rgb(31,119,180)"
    # without GPS the truth carries the phases
    no_gps = maps.map_figure({"truth": tracks["truth"]}, 20.0, PHASES)
    assert "truth track" in next(t for t in no_gps.data if t.mode == "markers").legendgrouptitle.text


def test_phase_of_labels_times_and_leaves_gaps_empty():
    labels = maps.phase_of(np.array([10.0, 20.0, 60.0, 300.0, 600.0]), PHASES)
    assert list(labels) == ["", "stationary", "steady cruise", "manoeuvring", ""]


def test_fit_view_zoom_follows_the_extent():
    # 360 / 2**k degrees of longitude at the equator fill 512 px at zoom k (MapLibre's 512 px tiles)
    for k in (2, 8, 14):
        span = 360.0 / 2**k
        lat, lon, zoom = maps.fit_view([0.0, 0.0], [10.0, 10.0 + span], width_px=512, height_px=10_000,
                                       padding=0.0)
        assert zoom == pytest.approx(k) and lon == pytest.approx(10.0 + span / 2) and lat == pytest.approx(0.0)
    # the tighter of the two axes decides; padding zooms out
    track = _circle(1200)
    lat, lon, zoom = maps.fit_view(track["lat_deg"], track["lon_deg"])
    assert track["lat_deg"].min() < lat < track["lat_deg"].max() and track["lon_deg"].min() < lon < \
        track["lon_deg"].max()
    assert 12.0 < zoom < 16.0  # a 1 km circle
    lon_span = track["lon_deg"].max() - track["lon_deg"].min()
    lon_zoom = np.log2(maps.MAP_WIDTH_PX * 360.0 / (maps.TILE_PX * lon_span * 1.2))  # 10 % padding each side
    assert zoom < lon_zoom  # here the latitude extent decides (the map is wider than high)
    wide = maps.fit_view(track["lat_deg"], LON0 + 10 * (track["lon_deg"] - LON0))[2]
    assert wide == pytest.approx(lon_zoom - np.log2(10.0))  # ten times as wide: the longitude decides
    assert maps.fit_view(track["lat_deg"], track["lon_deg"], padding=0.5)[2] < zoom
    # degenerate inputs
    assert maps.fit_view([LAT0], [LON0]) == (pytest.approx(LAT0), pytest.approx(LON0), maps.MAX_ZOOM)
    assert maps.fit_view([], []) == (0.0, 0.0, maps.MIN_ZOOM)
    assert maps.fit_view([np.nan], [np.nan]) == (0.0, 0.0, maps.MIN_ZOOM)
    fig = maps.map_figure({"GPS": track}, 20.0)
    assert fig.layout.map.zoom == pytest.approx(maps.fit_view(track["lat_deg"], track["lon_deg"])[2])
    assert fig.layout.map.center.lat == pytest.approx(lat)


def _log(with_gps: bool) -> FlightLog:
    track = _circle(600)
    index = pd.Index(track["time_s"].to_numpy(), name="time_s")
    streams = {"truth_local_position": pd.DataFrame({"x_m": 0.0, "y_m": 0.0, "z_m": 0.0}, index=index),
               "onboard_global_position": track.set_index("time_s").iloc[::2]}
    if with_gps:
        gps = track.set_index("time_s").copy()
        gps.iloc[:3] = np.nan  # no fix yet
        streams["gps"] = gps
    return FlightLog(streams=streams, meta=LogMetadata(source="synthetic.ulg"))


def test_reference_and_estimator_tracks():
    tracks = maps.reference_tracks(_log(with_gps=True))
    assert list(tracks) == ["GPS", "onboard"] and len(tracks["GPS"]) == 597 and len(tracks["onboard"]) == 300
    assert list(tracks["GPS"].columns) == list(maps.TRACK_COLUMNS) and tracks["GPS"]["lat_deg"].notna().all()
    assert list(maps.reference_tracks(_log(with_gps=False))) == ["onboard"]
    assert maps.map_figure({}, 0.0).data == ()  # nothing to draw: an empty map, no exception

    track = _circle(100)
    states = pd.concat([track.assign(estimator=name) for name in ("full_state_direct", "three_stage")])
    states["estimator"] = pd.Categorical(states["estimator"], categories=["three_stage", "full_state_direct",
                                                                          "full_state_indirect"])
    states.loc[states["estimator"] == "three_stage", ["lat_deg", "lon_deg"]] = np.nan  # no position
    assert list(maps.estimator_tracks(states)) == ["full_state_direct"]


# ------------------------------------------------------------------------------------------------ the page
@pytest.fixture
def open_map(monkeypatch):
    """Run the dashboard on a workspace, open the bundled mission and switch to the Map page."""
    def run(workspace_dir: Path) -> AppTest:
        monkeypatch.setenv(session.WORKSPACE_ENV, str(workspace_dir))
        at = AppTest.from_file(str(ENTRYPOINT), default_timeout=TIMEOUT_S)
        at.run()
        assert not at.exception
        at.sidebar.selectbox[0].set_value(hashlib.sha256(PAPER.read_bytes()).hexdigest()).run()
        at.switch_page("views/map.py")
        at.run()
        assert not at.exception
        return at

    return run


def _charts(at: AppTest) -> list[dict]:
    return [json.loads(chart.proto.spec) for chart in at.get("plotly_chart")]


def _synthetic_run(workspace: Workspace, sha256: str, log: FlightLog) -> str:
    """A stored run whose two estimators follow the truth 10 m north / 10 m east of it (no replay: fast)."""
    truth = log["truth_global_position"].iloc[::5]
    parts = []
    offsets = {"three_stage": (10.0 / 111_000, 0.0), "full_state_direct": (0.0, 10.0 / 91_000)}
    for name, (d_lat, d_lon) in offsets.items():
        frame = pd.DataFrame({column: np.nan for column in STATE_COLUMNS[1:]}, index=range(len(truth)))
        frame["time_s"] = truth.index.to_numpy(float)
        frame["lat_deg"] = truth["lat_deg"].to_numpy() + d_lat
        frame["lon_deg"] = truth["lon_deg"].to_numpy() + d_lon
        frame["alt_m"] = truth["alt_m"].to_numpy()
        parts.append(frame.assign(estimator=name))
    states = pd.concat(parts, ignore_index=True)[list(STATE_COLUMNS)]
    states["estimator"] = pd.Categorical(states["estimator"], categories=["three_stage", "full_state_direct"])
    settings = runs.RunSettings(estimators=("three_stage", "full_state_direct")).to_dict()
    return workspace.add_run(sha256, settings, states, pd.DataFrame(columns=["estimator", "time_s"]), {})


def test_map_page_without_and_with_a_run(open_map, tmp_path):
    at = open_map(tmp_path)
    assert any("No estimator run" in info.value for info in at.info)
    [world, ned] = _charts(at)
    names = [trace["name"] for trace in world["data"]]
    assert names[:2] == ["truth", "GPS"] and any(name.startswith("phase: ") for name in names)
    assert all(trace["type"] == "scattermap" for trace in world["data"])
    assert 10.0 < world["layout"]["map"]["zoom"] < 18.0
    assert ned["layout"]["title"]["text"] == "Track in local NED"

    sha256 = at.sidebar.selectbox[0].value
    log = adapters.stored_log(str(tmp_path.resolve()), sha256)
    run_id = _synthetic_run(Workspace(tmp_path), sha256, log)
    at.run()
    assert not at.exception and not at.error
    assert at.selectbox(key="map_run").value == run_id
    run = at.selectbox(key="map_run")  # named short; the settings on hover
    assert run.options == [Workspace(tmp_path).entry_name("runs", run_id)] and "heading aid" not in run.options[0]
    assert "estimators: three_stage, full_state_direct; heading aid: " in run.help, run.help
    [world, ned] = _charts(at)
    lines = [trace["name"] for trace in world["data"] if trace["mode"] == "lines"]
    assert lines == ["three_stage", "full_state_direct", "truth", "GPS"]
    assert {"three_stage", "full_state_direct", "truth", "GPS"} <= {trace["name"] for trace in ned["data"]}

    [sources] = at.multiselect
    assert sources.value == ["three_stage", "full_state_direct", "truth", "GPS"]
    sources.set_value(["three_stage"]).run()
    at.toggle(key="map_phases").set_value(False).run()
    assert not at.exception
    [world, _] = _charts(at)
    assert [trace["name"] for trace in world["data"]] == ["three_stage"]


def test_map_page_on_a_log_without_gps(open_map, tmp_path, monkeypatch):
    stored = adapters.stored_log

    def without_gps(root: str, sha256: str) -> FlightLog:
        log = stored(root, sha256)
        return dataclasses.replace(log, streams={name: frame for name, frame in log.streams.items()
                                                 if name not in ("gps", "truth_global_position")})

    monkeypatch.setattr(adapters, "stored_log", without_gps)
    at = open_map(tmp_path)
    assert not at.error
    assert any("no GPS" in info.value for info in at.info)
    assert any("Nothing to place on the map" in info.value for info in at.info)
    [ned] = _charts(at)  # the local track about PX4's own origin only
    assert [trace["name"] for trace in ned["data"] if trace.get("showlegend") is not False] == ["truth"]
