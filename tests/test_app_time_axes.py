"""Time axes of the dashboard (issue 14): seconds since the log start on every axis and table, log clock and UTC on
hover and in downloads, one shared time range per page (sliced at full resolution, then downsampled; y autorange),
and angles broken at their wrap-arounds. Pure functions, tested without Streamlit."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import plotly.graph_objects as go
import pytest

from app import comparison, figures, tables
from calib.segments import Segment
from ingest.flightlog import FlightLog, LogMetadata

#: A log clock that is Unix time (as in PX4's sample_px4_events.ulg).
UNIX_START_S = 1710773350.4
RATE_HZ = 250.0


def _unix_log(duration_s: float = 600.0, start_s: float = UNIX_START_S) -> FlightLog:
    time_s = start_s + np.arange(int(duration_s * RATE_HZ)) / RATE_HZ
    imu = pd.DataFrame({"gx_rad_s": np.zeros(len(time_s))}, index=pd.Index(time_s, name="time_s"))
    meta = LogMetadata(source="unix.ulg", start_time_s=float(time_s[0]), end_time_s=float(time_s[-1]),
                       duration_s=float(time_s[-1] - time_s[0]), utc_offset_s=0.0)
    return FlightLog(streams={"imu": imu}, meta=meta)


def _series(start_s: float = UNIX_START_S, duration_s: float = 600.0, rate_hz: float = RATE_HZ) -> pd.Series:
    time_s = start_s + np.arange(int(duration_s * rate_hz)) / rate_hz
    values = np.sin((time_s - start_s) / 30.0) * 50.0 + np.random.default_rng(1).normal(0.0, 1.0, len(time_s))
    return pd.Series(values, index=pd.Index(time_s, name="time_s"))


# ---------------------------------------------------------------------------------------------------- log start
def test_log_start_is_the_first_imu_sample_else_the_earliest_stream():
    log = _unix_log()
    assert figures.log_start_s(log) == UNIX_START_S
    clock = figures.time_base(log)
    assert clock == figures.TimeBase(start_s=UNIX_START_S, utc_offset_s=0.0)
    assert figures.time_span(log) == pytest.approx((0.0, 600.0 - 1.0 / RATE_HZ))

    gps = pd.DataFrame({"lat_deg": [1.0]}, index=pd.Index([55.0], name="time_s"))
    baro = pd.DataFrame({"alt_m": [1.0]}, index=pd.Index([42.0], name="time_s"))
    no_imu = FlightLog(streams={"gps": gps, "baro": baro, "mag": pd.DataFrame()}, meta=LogMetadata(source="x"))
    assert figures.log_start_s(no_imu) == 42.0
    assert figures.log_start_s(FlightLog(streams={}, meta=LogMetadata(source="x"))) == 0.0


def test_hover_labels_carry_time_since_start_log_clock_and_utc():
    clock = figures.TimeBase(start_s=UNIX_START_S, utc_offset_s=0.0)
    assert clock.hover_labels([12.3]) == [
        "t = 12.300 s since start, log clock 1710773362.700 s, UTC 2024-03-18 14:49:22.700"]
    no_gps = figures.TimeBase(start_s=100.0)
    assert no_gps.hover_labels([1.5]) == ["t = 1.500 s since start, log clock 101.500 s"]


def test_tables_and_downloads_keep_the_log_clock_and_add_time_since_start():
    clock = figures.TimeBase(start_s=UNIX_START_S)
    phases = tables.phase_table([Segment(UNIX_START_S + 10.0, UNIX_START_S + 40.0, "stationary", "quiet")], [],
                                UNIX_START_S, UNIX_START_S + 100.0)
    shifted = clock.shift(phases, ["start_s", "end_s"])
    assert list(shifted["start_s"]) == pytest.approx([0.0, 10.0, 40.0])
    assert list(shifted["duration_s"]) == list(phases["duration_s"])
    assert phases["start_s"].iloc[0] == UNIX_START_S  # the input is left alone

    states = pd.DataFrame({"estimator": "e", "time_s": UNIX_START_S + np.arange(5) * 0.5, "roll_deg": 1.0})
    out = clock.with_since_start(states)
    assert list(out.columns) == ["estimator", "time_s", figures.SINCE_START_COLUMN, "roll_deg"]
    np.testing.assert_allclose(out["time_s"], states["time_s"])
    np.testing.assert_allclose(out[figures.SINCE_START_COLUMN], np.arange(5) * 0.5)
    from_csv = pd.read_csv(io.BytesIO(comparison.table_download(states, clock, "csv")))
    from_parquet = pd.read_parquet(io.BytesIO(comparison.table_download(states, clock, "parquet")))
    for frame in (from_csv, from_parquet):
        assert list(frame.columns) == list(out.columns)
        np.testing.assert_allclose(frame[figures.SINCE_START_COLUMN], np.arange(5) * 0.5)
        np.testing.assert_allclose(frame["time_s"], states["time_s"])
    with pytest.raises(ValueError, match="unknown download format"):
        comparison.table_download(states, clock, "xlsx")


def test_axes_read_seconds_since_start_on_a_unix_time_log():
    clock = figures.TimeBase(start_s=UNIX_START_S, utc_offset_s=0.0)
    phases = tables.phase_table([Segment(UNIX_START_S + 10.0, UNIX_START_S + 40.0, "stationary", "quiet")], [],
                                UNIX_START_S, UNIX_START_S + 600.0)
    fig = figures.altitude_figure({"GPS": _series()}, phases, time_base=clock)
    trace = fig.data[0]
    assert trace.x[0] == pytest.approx(0.0) and trace.x[-1] == pytest.approx(600.0 - 1 / RATE_HZ)
    assert fig.layout.xaxis.title.text == figures.TIME_TITLE == "time since log start [s]"
    assert "log clock 1710773350.400 s, UTC 2024-03-18 14:49:10.400" in trace.customdata[0]
    assert trace.hovertemplate.startswith("GPS: %{y")
    bands = [value for shape in fig.layout.shapes for value in (shape.x0, shape.x1)]
    assert bands[:4] == pytest.approx([0.0, 10.0, 10.0, 40.0])


# ---------------------------------------------------------------------------------------------------- shared range
def test_window_slicing_returns_raw_samples_when_few_and_downsamples_when_many():
    series = _series()
    x = series.index.to_numpy() - UNIX_START_S
    y = series.to_numpy().copy()
    narrow = figures.window_indices(x, y, (100.0, 101.0), max_points=2000)  # 250 samples + the two neighbours
    inside = np.flatnonzero((x >= 100.0) & (x <= 101.0))
    np.testing.assert_array_equal(narrow, np.arange(inside[0] - 1, inside[-1] + 2))
    single = figures.window_indices(x, y, (100.001, 100.003))  # between two samples: the raw neighbours
    np.testing.assert_array_equal(x[single], x[[25_000, 25_001]])

    y[60_000] = 1e3  # a spike inside a wide window survives the downsampling
    wide = figures.window_indices(x, y, (200.0, 500.0), max_points=2000)
    assert len(wide) <= 2000 and np.all(np.diff(wide) > 0) and 60_000 in wide
    assert x[wide].min() >= 200.0 - 1 / RATE_HZ and x[wide].max() <= 500.0 + 1 / RATE_HZ
    np.testing.assert_array_equal(figures.window_indices(x[:50], y[:50], None), np.arange(50))
    assert len(figures.window_indices(x, y, (700.0, 800.0))) <= 1  # past the end: at most the last sample


def test_zoomed_trace_reaches_single_samples_and_y_autoranges():
    clock = figures.TimeBase(start_s=UNIX_START_S)
    full = figures.time_series_figure({"GPS": _series()}, "altitude [m]", time_base=clock)
    zoomed = figures.time_series_figure({"GPS": _series()}, "altitude [m]", time_base=clock, window=(100.0, 102.0))
    assert len(full.data[0].x) <= figures.MAX_POINTS
    steps = np.diff(zoomed.data[0].x)
    np.testing.assert_allclose(steps, 1 / RATE_HZ, rtol=1e-3)  # every raw sample (float64 of a Unix clock)
    assert tuple(zoomed.layout.xaxis.range) == (100.0, 102.0) and zoomed.layout.yaxis.autorange is True
    assert np.ptp(zoomed.data[0].y) < np.ptp(full.data[0].y)  # the y range follows the window's data


def test_clamp_window_keeps_a_range_valid_for_another_log():
    span = (0.0, 100.0)
    assert figures.clamp_window(None, span) == span
    assert figures.clamp_window((20.0, 10.0), span) == (10.0, 20.0)
    assert figures.clamp_window((-5.0, 250.0), span) == span
    assert figures.clamp_window((150.0, 250.0), span) == span  # nothing left: the whole log
    assert figures.clamp_window((10.0, 250.0), span) == (10.0, 100.0)


def _diagnostics(start_s: float) -> pd.DataFrame:
    n = 30_000
    return pd.DataFrame({
        "time_s": start_s + np.repeat(np.arange(n // 3) / 10.0, 3), "component": np.tile(["n", "e", "d"], n // 3),
        "innovation": np.random.default_rng(4).normal(size=n), "innovation_var": np.ones(n),
        "nis": np.random.default_rng(5).chisquare(1, n), "accepted": np.arange(n) % 100 != 0})


def test_shared_range_is_applied_to_every_time_figure_of_a_page():
    clock = figures.TimeBase(start_s=UNIX_START_S, utc_offset_s=0.0)
    window = (120.0, 180.0)
    time_s = UNIX_START_S + np.arange(60_000) / 100.0
    states = pd.DataFrame({"time_s": time_s, "roll_deg": np.sin(time_s), "yaw_deg": (time_s * 10.0) % 360 - 180,
                           "alt_m": time_s - UNIX_START_S})
    diagnostics = _diagnostics(UNIX_START_S)
    cells = np.zeros((len(time_s), 7), dtype=int)
    built = [
        figures.time_series_figure({"GPS": _series()}, "altitude [m]", time_base=clock, window=window),
        figures.altitude_figure({"GPS": _series()}, None, time_base=clock, window=window),
        figures.quantity_figure({"three_stage": states}, [("roll_deg", "roll [deg]"), ("yaw_deg", "yaw [deg]")],
                                title="Attitude", time_base=clock, window=window),
        figures.innovation_figure(diagnostics, {}, title="gps_pos", time_base=clock, window=window),
        figures.nis_figure(comparison.moving_nis(diagnostics, 50), 50, comparison.nis_band(50), title="NIS",
                           time_base=clock, time_window=window),
        figures.cell_state_figure(time_s, cells, ("dark", "lit", "faulty"), time_base=clock, window=window),
    ]
    for fig in built:
        x_axes = [fig.layout[name] for name in fig.layout if name.startswith("xaxis")]
        y_axes = [fig.layout[name] for name in fig.layout if name.startswith("yaxis")]
        assert x_axes and all(tuple(axis.range) == window for axis in x_axes)
        assert [axis.title.text for axis in x_axes if axis.title.text] == [figures.TIME_TITLE]
        if not isinstance(fig.data[0], go.Heatmap) and fig is not built[3]:  # y fitted to the window's data
            # (the innovations: fixed to the window's in-flight scale, test_app_figures)
            assert all(axis.autorange is True for axis in y_axes)
        for trace in fig.data:
            if trace.x is not None and len(trace.x) and trace.x[0] is not None:
                x = np.asarray(trace.x, float)
                assert x.min() >= window[0] - 0.2 and x.max() <= window[1] + 0.2  # sliced, one sample of margin

    track = pd.DataFrame({"time_s": time_s, "north_m": np.arange(len(time_s)) * 1.0, "east_m": 0.0})
    fig = figures.track_figure({"GPS": track}, time_base=clock, window=window)
    assert fig.data[0].y[0] == pytest.approx(11_999.0) and fig.data[0].y[-1] == pytest.approx(18_001.0)
    assert fig.data[0].customdata[0].startswith("t = 119.990 s since start")


# ---------------------------------------------------------------------------------------------------- wrap-around
def test_break_wraps_inserts_nan_at_every_wrap_only():
    x = np.arange(8.0)
    y = np.array([170.0, 178.0, -176.0, -170.0, np.nan, -160.0, 179.0, 0.0])
    bx, by = figures.break_wraps(x, y)
    assert len(bx) == len(x) + 2  # 178 -> -176 and -160 -> 179 (the NaN gap and 179 -> 0 are no wraps)
    assert np.isnan(by[2]) and bx[2] == 1.5
    assert np.isnan(by[7]) and bx[7] == 5.5
    np.testing.assert_array_equal(by[~np.isnan(by)], y[~np.isnan(y)])
    smooth = np.linspace(-90.0, 90.0, 50)
    assert len(figures.break_wraps(np.arange(50.0), smooth)[0]) == 50


def test_angle_traces_have_no_vertical_strokes_at_wraps():
    time_s = np.arange(90_000) / 50.0
    yaw = (time_s * 10.0 + 180.0) % 360.0 - 180.0
    frame = pd.DataFrame({"time_s": time_s, "yaw_deg": yaw, "alt_m": 100.0 + 0.0 * time_s})
    for window in (None, (100.0, 200.0)):
        fig = figures.quantity_figure({"truth": frame}, [("yaw_deg", "yaw [deg]"), ("alt_m", "altitude [m]")],
                                      title="x", time_base=figures.TimeBase(), window=window)
        yaw_trace, alt_trace = fig.data
        jumps = np.abs(np.diff(np.asarray(yaw_trace.y, float)))
        assert np.nanmax(jumps) < 180.0 and np.isnan(yaw_trace.y).sum() >= 2
        assert not np.isnan(alt_trace.y).any()  # only angles are broken
    azimuth = pd.DataFrame({"time_s": time_s[:1000], "azimuth_deg": yaw[:1000]})
    fig = figures.quantity_figure({"sun device": azimuth}, [("azimuth_deg", "azimuth [deg]")], title="sun")
    # 0 -> 180 deg, then -180 -> 20 deg: one piece on 0-360 (issue 34), the range named in the axis title
    assert not np.isnan(fig.data[0].y).any() and np.ptp(fig.data[0].y) == pytest.approx(199.8)
    assert fig.layout.yaxis.title.text == "azimuth [deg] on 0-360"
    assert fig.layout.xaxis.title.text == figures.LOG_CLOCK_TITLE
