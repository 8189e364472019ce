"""Figure and table builders of the dashboard, tested without Streamlit: traces present, downsampling bounds,
units in axis titles."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from app import figures, tables
from calib.segments import Segment
from ingest.flightlog import FlightLog, LogMetadata, StreamInfo

RATE_HZ = 250.0


def _series(duration_s: float = 3600.0, rate_hz: float = RATE_HZ, name: str = "alt_m") -> pd.Series:
    """A long noisy series (1 h at 250 Hz by default) on the log clock."""
    time_s = 100.0 + np.arange(int(duration_s * rate_hz)) / rate_hz
    values = np.sin(time_s / 60.0) * 50.0 + np.random.default_rng(1).normal(0.0, 1.0, len(time_s))
    return pd.Series(values, index=pd.Index(time_s, name="time_s"), name=name)


def _axis_titles(fig) -> list[str]:
    return [axis.title.text for axis in (fig.layout.xaxis, fig.layout.yaxis)]


def test_downsample_keeps_extremes_and_bounds_count():
    series = _series()
    series.iloc[123_456] = 1e3  # a spike must survive the decimation
    keep = figures.downsample_indices(series.index.to_numpy(), series.to_numpy(), max_points=2000)
    assert len(keep) <= 2000
    assert np.all(np.diff(keep) > 0)
    assert 123_456 in keep
    short = figures.downsample_indices(np.arange(10.0), np.arange(10.0), max_points=2000)
    np.testing.assert_array_equal(short, np.arange(10))


def test_downsample_tolerates_nan():
    series = _series(60.0)
    series.iloc[::7] = np.nan
    keep = figures.downsample_indices(series.index.to_numpy(), series.to_numpy(), max_points=500)
    assert 0 < len(keep) <= 500


def test_altitude_figure_downsamples_each_trace_and_shades_phases():
    phases = tables.phase_table([Segment(100.0, 400.0, "stationary", "quiet")],
                                [Segment(800.0, 2000.0, "steady", "cruise")], 100.0, 3700.0)
    fig = figures.altitude_figure({"GPS": _series(), "barometer": _series(rate_hz=50.0)}, phases,
                                  time_base=figures.TimeBase(start_s=100.0))
    lines = [trace for trace in fig.data if trace.mode == "lines"]
    assert [trace.name for trace in lines] == ["GPS", "barometer"]
    assert all(len(trace.x) <= figures.MAX_POINTS for trace in lines)
    assert len(fig.layout.shapes) == len(phases) == 4
    assert {trace.name for trace in fig.data} >= {"stationary", "steady cruise", "manoeuvring"}
    assert _axis_titles(fig) == [figures.TIME_TITLE, "altitude above MSL [m]"]


def test_track_figure_equal_axes_and_bounded_points():
    n = 200_000
    track = pd.DataFrame({"time_s": np.arange(n) / 100.0, "north_m": np.cos(np.arange(n) / 1e3) * 300.0,
                          "east_m": np.sin(np.arange(n) / 1e3) * 300.0, "down_m": np.zeros(n)})
    fig = figures.track_figure({"GPS": track, "truth": track.iloc[:100]})
    paths = [trace for trace in fig.data if trace.mode == "lines"]
    assert [trace.name for trace in paths] == ["GPS", "truth"]
    assert len(paths[0].x) <= figures.MAX_POINTS and len(paths[1].x) == 100
    assert fig.layout.yaxis.scaleanchor == "x"
    assert _axis_titles(fig) == ["east [m]", "north [m]"]


def test_streams_table_and_phase_table():
    meta = LogMetadata(source="x.ulg", streams={
        "imu": StreamInfo("sensor_combined", 1000, 250.0, ((10.0, 0.3), (20.0, 0.5))),
        "gps": StreamInfo("vehicle_gps_position", 50, 5.0)})
    table = tables.streams_table(meta)
    assert list(table["stream"]) == ["imu", "gps"]
    assert table.loc[0, "gaps"] == 2 and table.loc[0, "longest_gap_s"] == 0.5
    assert table.loc[0, "longest_gap_at_s"] == 20.0 and np.isnan(table.loc[1, "longest_gap_s"])

    phases = tables.phase_table([], [], 0.0, 10.0)
    assert list(phases["phase"]) == ["manoeuvring"] and phases.loc[0, "duration_s"] == 10.0


def test_streams_table_counts_gaps_within_the_log_span_only():
    """Issue 34: an ArduPilot magnetometer logged 2.6 s before the first IMU sample had its gap at -2.60 s since
    the start; a gap reaching into the span starts at the start, one past the end is cut there."""
    meta = LogMetadata(source="x.bin", start_time_s=4.0, end_time_s=90.0, streams={
        "mag": StreamInfo("MAG[0]", 850, 10.0, ((1.45, 2.5), (50.0, 0.4))),
        "baro": StreamInfo("BARO", 860, 10.0, ((3.0, 2.0), (89.0, 5.0)))})
    table = tables.streams_table(meta).set_index("stream")
    assert table.loc["mag", "gaps"] == 1 and table.loc["mag", "longest_gap_at_s"] == 50.0
    assert table.loc["baro", "gaps"] == 2 and table.loc["baro", "longest_gap_s"] == pytest.approx(1.0)
    assert table.loc["baro", "longest_gap_at_s"] == 4.0
    assert (table["longest_gap_at_s"].dropna() >= meta.start_time_s).all()


def test_segment_figure_marks_segments_and_bounds_points():
    series = _series()
    norms = pd.DataFrame({"gyro_norm_rad_s": series.abs().to_numpy() / 100.0,
                          "accel_norm_m_s2": 9.81 + series.to_numpy() / 100.0}, index=series.index)
    segments = pd.DataFrame([("stationary", 100.0, 400.0, ""), ("steady", 900.0, 1500.0, "")],
                            columns=["kind", "start_s", "end_s", "reason"])
    fig = figures.segment_figure(norms, segments)
    assert [trace.name for trace in fig.data] == ["|gyro|", "|f|"]
    assert all(len(trace.x) <= figures.MAX_POINTS for trace in fig.data)
    assert len(fig.layout.shapes) == 2 * 2 and fig.layout.dragmode == "select"  # a band per segment and row
    assert fig.layout.yaxis.title.text == "|gyro| [rad/s]" and fig.layout.yaxis2.title.text.endswith("[m/s^2]")
    assert fig.layout.xaxis2.title.text == figures.LOG_CLOCK_TITLE  # without a time base: the log clock
    clock = figures.TimeBase(start_s=float(series.index[0]))
    since = figures.segment_figure(norms, segments, time_base=clock)
    assert since.layout.xaxis2.title.text == figures.TIME_TITLE and min(since.data[0].x) == 0.0
    assert (since.layout.shapes[0].x0, since.layout.shapes[0].x1) == (100.0 - clock.start_s, 400.0 - clock.start_s)


def test_frequency_response_and_raw_filtered_figures():
    freq_hz = np.linspace(0.0, 125.0, 512)
    gain = 1.0 / np.sqrt(1.0 + (freq_hz / 15.0) ** 8)
    fig = figures.frequency_response_figure(freq_hz, gain, gain**2, 15.0)
    assert [trace.name for trace in fig.data] == ["one pass", "zero phase (filtfilt)"]
    assert _axis_titles(fig) == ["frequency [Hz]", "gain [dB]"] and np.all(np.isfinite(fig.data[1].y))

    time_s = np.arange(100_000) / RATE_HZ
    raw = np.random.default_rng(2).normal(size=(len(time_s), 3))
    fig = figures.raw_filtered_figure(time_s, raw, raw * 0.1, ("x", "y", "z"), "rad/s")
    assert len(fig.data) == 6 and all(len(trace.x) <= figures.MAX_POINTS for trace in fig.data)
    since = figures.raw_filtered_figure(time_s + 50.0, raw, raw, ("x", "y", "z"), "rad/s",
                                        time_base=figures.TimeBase(start_s=50.0))
    assert since.layout.xaxis3.title.text == figures.TIME_TITLE and min(since.data[0].x) == 0.0
    assert [fig.layout[f"yaxis{k or ''}"].title.text for k in (0, 2, 3)] == ["x [rad/s]", "y [rad/s]", "z [rad/s]"]


def test_allan_and_tau_figures():
    from calib.allan import allan_deviation, allan_figures

    white = np.random.default_rng(3).normal(0.0, 0.01, (20_000, 3))
    curves = [allan_deviation(white[:, k], RATE_HZ) for k in range(3)]
    frames = [pd.DataFrame({"tau_s": c.taus_s, "adev": c.adev, "adev_err": c.adev_err}) for c in curves]
    fig = figures.allan_figure(frames, [allan_figures(c) for c in curves], ("x", "y", "z"), "rad/s")
    assert [trace.name for trace in fig.data if trace.showlegend is not False] == ["x", "y", "z"]
    assert fig.layout.xaxis.type == "log" and fig.layout.yaxis.type == "log"
    assert _axis_titles(fig) == ["cluster time tau [s]", "Allan deviation [rad/s]"]

    fig = figures.tau_curve_figure([-1.0, 0.0, 1.0, 2.0], [1.2, 1.0, 1.1, 1.4], [4.0, 1.0, 0.3, 0.1], 1.0,
                                   (0.8, 1.2))
    assert [trace.name for trace in fig.data] == ["neg. log-likelihood", "mean NIS"]
    assert fig.layout.xaxis.title.text == "tau [-]" and fig.layout.yaxis2.title.text == "mean NIS [-]"


def _states(n: int = 90_000, rate_hz: float = 50.0) -> pd.DataFrame:
    """One estimator's states (the estimators' output columns) over n epochs."""
    time_s = np.arange(n) / rate_hz
    return pd.DataFrame({"estimator": "full_state_direct", "time_s": time_s, "roll_deg": np.sin(time_s),
                         "pitch_deg": np.cos(time_s), "yaw_deg": (time_s * 10.0) % 360.0 - 180.0,
                         "alt_m": 100.0 + time_s, "vn_m_s": np.full(n, 10.0), "ve_m_s": np.zeros(n),
                         "vd_m_s": np.zeros(n), "wind_n_m_s": np.ones(n), "wind_e_m_s": np.zeros(n)})


def test_quantity_figure_one_row_per_quantity_and_legend_once():
    states = _states()
    frames = {"full_state_direct": states, "truth": states.assign(roll_deg=np.nan)}
    rows = [("roll_deg", "roll [deg]"), ("pitch_deg", "pitch [deg]"), ("yaw_deg", "yaw [deg]")]
    fig = figures.quantity_figure(frames, rows, title="Attitude", time_base=figures.TimeBase())
    assert [t.name for t in fig.data] == ["full_state_direct"] * 3 + ["truth"] * 2  # truth roll is all NaN
    assert [t.showlegend for t in fig.data] == [True, False, False, True, False]
    # drawn samples bounded (the yaw traces add a NaN break at every wrap-around)
    assert all(np.isfinite(t.y).sum() <= figures.MAX_POINTS for t in fig.data) and fig.data[3].line.dash == "dash"
    assert [fig.layout[f"yaxis{k or ''}"].title.text for k in (0, 2, 3)] == [title for _, title in rows]
    assert fig.layout.xaxis3.title.text == figures.TIME_TITLE


def test_innovation_and_nis_figures():
    n = 30_000
    diagnostics = pd.DataFrame({
        "time_s": np.repeat(np.arange(n / 3) / 10.0, 3), "component": np.tile(["n", "e", "d"], n // 3),
        "innovation": np.random.default_rng(4).normal(size=n), "innovation_var": np.ones(n),
        "nis": np.random.default_rng(5).chisquare(1, n), "accepted": np.arange(n) % 100 != 0})
    fig = figures.innovation_figure(diagnostics, {"n": "m", "e": "m", "d": "m"}, title="gps_pos")
    assert {t.name for t in fig.data} == {"+2 sqrt(S)", "-2 sqrt(S)", "innovation", "rejected"}
    assert all(len(t.x) <= figures.MAX_POINTS for t in fig.data)
    assert [fig.layout[f"yaxis{k or ''}"].title.text for k in (0, 2, 3)] == ["n [m]", "e [m]", "d [m]"]

    from app import comparison

    moving = comparison.moving_nis(diagnostics, 50)
    assert set(moving["component"]) == {"n", "e", "d"} and moving["mean_nis"].between(0.3, 3.0).mean() > 0.95
    fig = figures.nis_figure(moving, 50, comparison.nis_band(50), title="NIS")
    assert [t.name for t in fig.data] == ["n", "e", "d"] and fig.layout.yaxis.type == "log"
    assert fig.layout.yaxis.title.text == "mean NIS over 50 updates [-]"


def test_cell_state_figure_keeps_short_faults_when_binning():
    states = np.zeros((36_000, 7), dtype=int)
    states[:, 0] = 1
    states[12_345, 1] = 2  # one faulty epoch
    fig = figures.cell_state_figure(np.arange(36_000) / 10.0, states, ("dark", "lit", "faulty"), max_columns=1000,
                                    time_base=figures.TimeBase())
    heatmap = fig.data[0]
    assert np.asarray(heatmap.z).shape == (7, 1000) and np.asarray(heatmap.z)[1].max() == 2
    assert list(heatmap.y) == [f"cell {k}" for k in range(1, 8)]
    assert fig.layout.yaxis.title.text == "photocell" and fig.layout.xaxis.title.text == figures.TIME_TITLE


def test_missing_streams_are_explained_and_runs_listed():
    from app.workspace import LogEntry

    meta = LogMetadata(source="x.ulg", vehicle_type=1)
    log = FlightLog(streams={"imu": pd.DataFrame({"gyro_x_rad_s": [0.0]})}, meta=meta)
    missing = tables.missing_streams(log)
    assert {"mag", "gps", "airspeed", "sun"} <= set(missing["stream"]) and "imu" not in set(missing["stream"])
    assert missing["consequence"].str.len().min() > 10
    log.meta.vehicle_type = 2  # a quadrotor needs no airspeed sensor
    assert "airspeed" not in set(tables.missing_streams(log)["stream"])

    entries = [LogEntry("a" * 64, "flight.ulg", 2_000_000, "2026-01-01T00:00:00+00:00", True)]
    runs = pd.DataFrame({"run_id": ["r1"], "log_sha256": ["a" * 64], "created_utc": ["2026-01-01T00:01:00+00:00"],
                         "settings_json": ['{"estimators": ["three_stage"], "heading": "mag", "noise": "default"}']})
    assert tables.logs_table(entries, runs).loc[0, "runs"] == 1
    listed = tables.runs_table(runs, entries)
    assert listed.loc[0, "log"] == "flight.ulg" and listed.loc[0, "estimators"] == "three_stage"


def test_workspace_root_from_arguments_environment_or_default(monkeypatch, tmp_path):
    from app import session

    monkeypatch.delenv(session.WORKSPACE_ENV, raising=False)
    assert session.workspace_root(["--workspace", str(tmp_path / "a")]) == tmp_path / "a"
    monkeypatch.setenv(session.WORKSPACE_ENV, str(tmp_path / "b"))
    assert session.workspace_root([]) == tmp_path / "b"
    monkeypatch.delenv(session.WORKSPACE_ENV)
    monkeypatch.chdir(tmp_path)
    assert session.workspace_root(["--other", "x"]) == tmp_path / "workspace"


def test_baro_gps_altitude_note_explains_a_large_offset_only():
    time_s = np.arange(0.0, 100.0, 1.0)
    gps = pd.Series(500.0 + time_s, index=time_s)
    far = {"GPS": gps, "barometer": pd.Series(gps.to_numpy() + 80.0, index=time_s + 0.5)}
    note = tables.baro_gps_altitude_note(far, 1013.25)
    assert note is not None and "80 m above" in note and "1013.25 hPa" in note and "lower" in note
    below = {"GPS": gps, "barometer": pd.Series(gps.to_numpy() - 25.0, index=time_s)}
    assert "25 m below" in tables.baro_gps_altitude_note(below, None)
    near = {"GPS": gps, "barometer": pd.Series(gps.to_numpy() + 3.0, index=time_s)}
    assert tables.baro_gps_altitude_note(near, 1013.25) is None
    assert tables.baro_gps_altitude_note({"GPS": gps}, 1013.25) is None


def _heading_frames(center_deg: float) -> dict[str, pd.DataFrame]:
    """An estimate and the truth of a heading wandering by +-10 deg about ``center_deg`` for 100 s."""
    time_s = np.arange(0.0, 100.0, 0.1)
    heading = center_deg + 10.0 * np.sin(time_s / 5.0)
    wrapped = (heading + 180.0) % 360.0 - 180.0
    return {"three_stage": pd.DataFrame({"time_s": time_s, "yaw_deg": wrapped}),
            "truth": pd.DataFrame({"time_s": time_s, "yaw_deg": (wrapped + 1.0 + 180.0) % 360.0 - 180.0})}


def test_a_heading_near_180_deg_is_drawn_on_0_to_360_in_one_piece():
    """Issue 34: a yaw about +-180 deg broke into fragments on a +-200 deg axis."""
    rows = [("yaw_deg", "yaw [deg]")]
    south = figures.quantity_figure(_heading_frames(180.0), rows, title="Attitude", time_base=figures.TimeBase())
    assert south.layout.yaxis.title.text == "yaw [deg] on 0-360"
    for trace in south.data:
        assert np.isfinite(trace.y).all() and np.min(trace.y) > 160.0 and np.max(trace.y) < 200.0  # no break
    north = figures.quantity_figure(_heading_frames(0.0), rows, title="Attitude", time_base=figures.TimeBase())
    assert north.layout.yaxis.title.text == "yaw [deg]"  # the default range, about 0
    assert all(np.isfinite(trace.y).all() and np.max(np.abs(trace.y)) < 20.0 for trace in north.data)
    assert figures.angle_cut_deg([np.array([170.0, -175.0, 178.0])]) == 0.0
    assert figures.angle_cut_deg([np.array([-10.0, 10.0, 350.0 - 360.0])]) == -180.0
    assert figures.display_angle([-170.0, 170.0, 0.0], 0.0).tolist() == [190.0, 170.0, 0.0]


def test_rows_without_any_value_are_left_out_and_every_chart_keeps_its_time_axis():
    """Issue 34: the Errors tab of a ground walk drew empty airspeed / course / wind panels and no time axis."""
    time_s = np.arange(0.0, 10.0, 0.1)
    errors = {"three_stage": pd.DataFrame({"time_s": time_s, "roll_deg": np.sin(time_s),
                                           "airspeed_m_s": np.nan, "wind_m_s": np.nan})}
    rows = [("roll_deg", "roll error [deg]"), ("airspeed_m_s", "airspeed error [m/s]"),
            ("wind_m_s", "wind error [m/s]")]
    assert figures.rows_with_data(errors, rows) == rows[:1]
    fig = figures.quantity_figure(errors, rows, title="Errors", time_base=figures.TimeBase())
    assert [t.yaxis for t in fig.data] == ["y"] and "yaxis2" not in fig.layout
    assert fig.layout.xaxis.title.text == figures.TIME_TITLE


def _spiky_innovations(n: int = 20_000, spike_m_s2: float = 120.0) -> pd.DataFrame:
    """Accelerometer innovations (standard deviation 0.5 m/s^2) with a 20-sample landing spike."""
    rng = np.random.default_rng(7)
    innovation = rng.normal(0.0, 0.5, n)
    innovation[-30:-10] = spike_m_s2 * np.sign(np.arange(20) % 2 - 0.5)
    return pd.DataFrame({"time_s": np.arange(n) / 50.0, "component": "x", "innovation": innovation,
                         "innovation_var": np.full(n, 0.25), "accepted": True})


def test_innovations_are_scaled_to_the_flight_not_to_a_landing_spike():
    """Issue 34: a +-120 m/s^2 landing spike flattened the in-flight innovations."""
    diagnostics = _spiky_innovations()
    limit = figures.innovation_limit(diagnostics["innovation"])
    assert limit == pytest.approx(figures.INNOVATION_HEADROOM * figures.INNOVATION_SIGMAS * 0.5, rel=0.05)
    fig = figures.innovation_figure(diagnostics, {"x": "m/s^2"}, title="accel", time_base=figures.TimeBase())
    assert tuple(fig.layout.yaxis.range) == pytest.approx((-limit, limit)) and not fig.layout.yaxis.autorange
    [off] = [t for t in fig.data if t.name == figures.OFF_SCALE]
    assert len(off.x) == 20 and np.allclose(np.abs(off.y), limit)  # at the edge, with the spike's sign
    assert set(off.marker.symbol) == {"triangle-up", "triangle-down"}
    assert fig.layout.annotations[0].text.startswith("20 of 20000 innovations beyond the axis")
    landing = figures.innovation_figure(diagnostics, {"x": "m/s^2"}, title="accel", time_base=figures.TimeBase(),
                                        window=(399.0, 400.0))  # zoomed on the landing: the spike in view
    assert landing.layout.yaxis.range[1] > 120.0 and not any(t.name == figures.OFF_SCALE for t in landing.data)
    assert np.isnan(figures.innovation_limit([np.nan])) and np.isnan(figures.innovation_limit([0.0, 0.0]))


def test_overlaid_innovations_share_one_scale_per_row():
    first, second = _spiky_innovations(), _spiky_innovations(spike_m_s2=60.0)
    fig = figures.overlay_innovation_figure({"default": first, "tuned": second}, "three_stage", {"x": "m/s^2"},
                                            title="accel", time_base=figures.TimeBase())
    limit = figures.innovation_limit(np.r_[first["innovation"], second["innovation"]])
    assert tuple(fig.layout.yaxis.range) == pytest.approx((-limit, limit))
    assert sum(len(t.x) for t in fig.data if t.name == figures.OFF_SCALE) == 40
