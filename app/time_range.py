"""A page's shared time range (issue 14, "zoom one, all follow"): the value of the page's time-range slider, set
also by a box dragged across any time chart of the page, so every chart follows and is re-sampled to the window.

The range belongs to what the page shows (issue 34): :func:`owned_range` resets it to the full span when the
owner (the log's SHA-256, with the runs shown where a page shows runs) changes, so opening another log or a new
run shows the whole flight, and :func:`partial_text` says when a chart shows part of it.

Pure logic on the selection events and a session-state mapping (no Streamlit import), tested directly; the pages
reach it through :func:`app.session.time_range_slider` and :func:`app.session.time_chart`.

A box selection event, as ``st.plotly_chart(..., on_select=..., selection_mode="box")`` stores it under the
chart's key, is ``{"selection": {"points": [...], "point_indices": [...], "box": [{"xref": "x", "yref": "y",
"x": [x0, x1], "y": [y0, y1]}], "lasso": []}}``: the box comes from the figure's rectangle selection, so it is there
even when the box holds no point (line traces never have selectable points); its x values are in the axis unit,
seconds since the log start on the pages' time charts. Time charts share their x axis across rows, so the box of
any row gives the range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, MutableMapping, Sequence

from app.figures import clamp_window

#: Narrowest range a box sets [s]: a click-sized drag still shows a few samples (12 at 250 Hz).
MIN_WIDTH_S = 0.05
#: Step of the pages' time-range sliders [s]; a box's range is rounded outwards to it.
STEP_S = 0.01

Window = tuple[float, float]


def box_range(event: Mapping | None) -> Window | None:
    """The x range [axis unit] of the first box of a plotly selection event, ascending; None without a box (a
    cleared selection, points or lasso only) or when its x values are missing or not finite."""
    if not event:
        return None
    boxes = (event.get("selection") or {}).get("box") or []
    for box in boxes:
        x = list(box.get("x") or [])[:2]
        if len(x) == 2 and all(isinstance(v, int | float) and math.isfinite(v) for v in x):
            low, high = sorted(float(v) for v in x)
            return low, high
    return None


def fit_window(window: Sequence[float], span: Window, min_width_s: float = MIN_WIDTH_S,
               step_s: float = STEP_S) -> Window:
    """``window`` [s] made a valid slider value inside ``span`` [s]: clipped to the span, at least ``min_width_s``
    wide (widened about its centre and kept inside the span; the whole span when that is narrower), rounded
    outwards to ``step_s``."""
    low, high = sorted(float(v) for v in window)
    low, high = max(low, span[0]), min(high, span[1])
    width = min(max(high - low, min_width_s), span[1] - span[0])
    centre = 0.5 * (low + high)
    low = min(max(centre - 0.5 * width, span[0]), span[1] - width)
    high = low + width
    low = max(span[0], math.floor(round(low / step_s, 6)) * step_s)
    high = min(span[1], math.ceil(round(high / step_s, 6)) * step_s)
    return round(low, 6), round(high, 6)


def selected_window(event: Mapping | None, span: Window, min_width_s: float = MIN_WIDTH_S,
                    step_s: float = STEP_S) -> Window | None:
    """The range [s since start] a box selection event sets (:func:`box_range` fitted with :func:`fit_window`);
    None when the event holds no box or the box lies outside ``span``."""
    box = box_range(event)
    if box is None or box[1] < span[0] or box[0] > span[1]:
        return None
    return fit_window(box, span, min_width_s, step_s)


def take_box_selection(state: MutableMapping, chart_key: str, range_key: str, span: Window) -> bool:
    """Selection callback of a time chart: the box just dragged on the chart ``state[chart_key]`` becomes the
    page's range ``state[range_key]`` (the slider's value). Returns whether the range was set.

    The chart then changes (new range, new samples), so Streamlit mounts it afresh and the selection is gone."""
    window = selected_window(state.get(chart_key), span)
    if window is None:
        return False
    state[range_key] = window
    return True


def reset_range(state: MutableMapping, range_key: str, span: Window) -> None:
    """Callback of the pages' *Full span* button: the range back to the whole ``span`` [s]."""
    state[range_key] = (float(span[0]), float(span[1]))


def owner_key(range_key: str) -> str:
    """Session-state key of the owner of the range ``range_key`` (:func:`owned_range`)."""
    return f"{range_key}_owner"


def owned_range(state: MutableMapping, range_key: str, owner: object, span: Window) -> Window:
    """The page's range ``state[range_key]`` [s] for what the page shows now, ``owner`` (hashable: the log's
    SHA-256, or a tuple of logs and runs): the whole ``span`` [s] when the owner differs from the one the range was
    set for (another log, a new run) or there is no range yet, else the kept range clipped to the span. Stores the
    range and its owner in ``state``."""
    kept = state.get(range_key) if state.get(owner_key(range_key)) == owner else None
    state[range_key] = clamp_window(kept, span)
    state[owner_key(range_key)] = owner
    return state[range_key]


def is_partial(window: Sequence[float] | None, span: Window, step_s: float = STEP_S) -> bool:
    """Whether ``window`` [s] shows less than ``span`` [s] (by more than half a slider step at either end)."""
    return window is not None and (window[0] > span[0] + 0.5 * step_s or window[1] < span[1] - 0.5 * step_s)


def partial_text(window: Sequence[float] | None, span: Window) -> str | None:
    """``"showing 60.0-120.0 s of 0-864 s"`` when ``window`` [s] is part of ``span`` [s], else None."""
    if not is_partial(window, span):
        return None
    return f"showing {window[0]:.1f}-{window[1]:.1f} s of {span[0]:.0f}-{span[1]:.0f} s"
