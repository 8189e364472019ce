"""The shared time range of a page (issue 14, "zoom one, all follow"): a box dragged on any time chart becomes the
range of every chart; Streamlit's selection events turned into a range, clamped, widened, reset. Pure functions;
the charts' selection set-up is checked through the dashboard's pages (AppTest)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pandas as pd
import pytest

from app import figures, samples, session, time_range
from tests.test_app_pages import SHORT_SAMPLE, open_page, workspace_dir  # noqa: F401 (fixtures)

SPAN = (0.0, 120.0)


def _event(*boxes: tuple[float, float], points: int = 0) -> dict:
    """A selection event as ``st.plotly_chart(..., selection_mode="box")`` stores it (x in s since start)."""
    return {"selection": {"points": [{"x": 1.0, "y": 2.0}] * points, "point_indices": list(range(points)),
                          "box": [{"xref": "x", "yref": "y", "x": list(box), "y": [-1.0, 1.0]} for box in boxes],
                          "lasso": []}}


def test_the_first_box_gives_the_range_with_or_without_points():
    assert time_range.box_range(_event((42.5, 17.25))) == (17.25, 42.5)  # dragged right to left
    assert time_range.box_range(_event((10.0, 20.0), points=3)) == (10.0, 20.0)
    assert time_range.box_range(_event((10.0, 20.0), (30.0, 40.0))) == (10.0, 20.0)
    row_two = {"selection": {"box": [{"xref": "x2", "yref": "y2", "x": [5.0, 6.0], "y": [0.0, 1.0]}]}}
    assert time_range.box_range(row_two) == (5.0, 6.0)  # shared x axes: any row's box


@pytest.mark.parametrize("event", [None, {}, _event(), {"selection": {"box": [{"x": []}]}},
                                   {"selection": {"box": [{"x": [1.0, float("nan")]}]}},
                                   {"selection": {"box": [{"x": ["a", "b"]}]}}])
def test_no_range_without_a_usable_box(event):
    assert time_range.box_range(event) is None
    assert time_range.selected_window(event, SPAN) is None


def test_a_box_is_clipped_to_the_span_widened_to_the_minimum_and_rounded_to_the_slider_step():
    assert time_range.selected_window(_event((-30.0, 12.3456)), SPAN) == (0.0, 12.35)
    assert time_range.selected_window(_event((100.0, 500.0)), SPAN) == (100.0, 120.0)
    low, high = time_range.selected_window(_event((50.0, 50.001)), SPAN)  # a click-sized drag
    assert time_range.MIN_WIDTH_S - 1e-9 <= high - low <= time_range.MIN_WIDTH_S + 2 * time_range.STEP_S
    assert low <= 50.0 <= high
    assert time_range.selected_window(_event((119.999, 120.0)), SPAN) == (119.95, 120.0)  # kept inside the span
    assert time_range.selected_window(_event((130.0, 140.0)), SPAN) is None  # wholly outside
    assert time_range.fit_window((1.0, 2.0), (0.0, 0.01)) == (0.0, 0.01)  # a span narrower than the minimum


def test_the_selection_callback_sets_the_page_range_and_the_reset_restores_the_span():
    state = {"chart": _event((10.0, 20.0)), "range": SPAN}
    assert time_range.take_box_selection(state, "chart", "range", SPAN)
    assert state["range"] == (10.0, 20.0)
    state["chart"] = _event()  # a cleared selection keeps the range
    assert not time_range.take_box_selection(state, "chart", "range", SPAN)
    assert state["range"] == (10.0, 20.0)
    time_range.reset_range(state, "range", SPAN)
    assert state["range"] == SPAN


def test_the_time_charts_of_a_page_select_horizontal_boxes_without_local_zoom(open_page):  # noqa: F811
    at = open_page("views/sun.py", SHORT_SAMPLE)
    charts = at.get("plotly_chart")
    assert len(charts) == 4
    for chart in charts:
        layout, config = json.loads(chart.proto.spec)["layout"], json.loads(chart.proto.config)
        assert layout["dragmode"] == "select" and layout["selectdirection"] == "h"
        assert set(session.LOCAL_ZOOM_BUTTONS) <= set(config["modeBarButtonsToRemove"])
        assert list(chart.proto.selection_mode)  # a selection widget: its box reaches the page
    reset = at.button(key="sun_time_range_reset")
    assert reset.disabled  # the full span already
    at.slider(key="sun_time_range").set_value((10.0, 20.0)).run()
    assert not at.button(key="sun_time_range_reset").disabled
    at.button(key="sun_time_range_reset").click().run()
    slider = at.slider(key="sun_time_range")
    assert slider.min == 0.0 and tuple(slider.value) == pytest.approx((slider.min, slider.max))


def test_the_range_belongs_to_its_log_and_resets_on_another_log_or_run():
    """Issue 34: a range kept from the previous log (78.7 s of an octocopter) hid most of the next one."""
    state: dict = {}
    octo, paper = (0.0, 78.72), (0.0, 864.0)
    assert time_range.owned_range(state, "range", "octo", octo) == octo  # no range yet: the whole log
    state["range"] = (10.0, 20.0)  # the user zooms
    assert time_range.owned_range(state, "range", "octo", octo) == (10.0, 20.0)  # kept on the same log
    assert time_range.owned_range(state, "range", "paper", paper) == paper  # another log: its whole span
    assert state["range"] == paper and state[time_range.owner_key("range")] == "paper"
    state["range"] = (100.0, 900.0)
    assert time_range.owned_range(state, "range", "paper", paper) == (100.0, 864.0)  # clipped to the span
    assert time_range.owned_range(state, "range", ("paper", "run1", "run2"), paper) == paper  # a new run shown


def test_a_partial_range_is_named_and_the_full_span_is_not():
    assert time_range.partial_text((60.0, 120.0), (0.0, 864.0)) == "showing 60.0-120.0 s of 0-864 s"
    assert time_range.partial_text((0.0, 864.0), (0.0, 864.0)) is None
    assert time_range.partial_text((0.0, 863.999), (0.0, 864.0)) is None  # within half a slider step
    assert time_range.partial_text(None, (0.0, 864.0)) is None


def test_a_chart_of_part_of_the_log_says_so_on_its_time_axis():
    series = {"GPS": pd.Series(np.arange(10.0), index=np.arange(10.0))}
    fig = figures.time_series_figure(series, "altitude [m]", time_base=figures.TimeBase(), window=(2.0, 5.0))
    figures.note_partial(fig, time_range.partial_text((2.0, 5.0), (0.0, 9.0)))
    assert fig.layout.xaxis.title.text == f"{figures.TIME_TITLE} · showing 2.0-5.0 s of 0-9 s"
    track = figures.note_partial(figures.track_figure({}), "showing 2.0-5.0 s of 0-9 s")
    assert track.layout.title.text == "Track in local NED (showing 2.0-5.0 s of 0-9 s)"  # no time axis: the title
    assert figures.note_partial(figures.track_figure({}), None).layout.title.text == "Track in local NED"


def test_opening_another_log_shows_its_whole_span(open_page):  # noqa: F811
    at = open_page("views/overview.py", SHORT_SAMPLE)
    short_span = (at.slider(key="overview_time_range").min, at.slider(key="overview_time_range").max)
    at.slider(key="overview_time_range").set_value((10.0, 20.0)).run()
    assert tuple(at.slider(key="overview_time_range").value) == pytest.approx((10.0, 20.0))
    paper = hashlib.sha256((samples.SAMPLE_DIR / "paper.ulg").read_bytes()).hexdigest()
    at.sidebar.selectbox[0].set_value(paper).run()
    assert not at.exception
    slider = at.slider(key="overview_time_range")
    assert slider.max > 5 * short_span[1]  # the bundled mission, much longer than the short sample
    assert tuple(slider.value) == pytest.approx((slider.min, slider.max))
