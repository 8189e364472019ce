"""Pure plotly figure builders for the dashboard (no Streamlit), tested directly.

Every time trace is downsampled for display with MinMaxLTTB (``tsdownsample``) to at most :data:`MAX_POINTS`
points, so a 1-hour 250 Hz log draws as fast as a short one; every axis title carries its unit.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from tsdownsample import NaNMinMaxLTTBDownsampler

#: Largest number of points drawn per trace.
MAX_POINTS = 2000
#: Title of every time axis: the log clock (PX4 ``timestamp`` / 1e6).
TIME_TITLE = "time [s] (log clock)"
#: One colour per data source, the same on every page.
SOURCE_COLORS = {
    "three_stage": "#1f77b4", "full_state_direct": "#ff7f0e", "full_state_indirect": "#2ca02c",
    "onboard": "#7f7f7f", "truth": "#000000", "GPS": "#d62728", "barometer": "#9467bd", "sun device": "#e6a800",
}
#: Fill colours of the flight-phase bands.
PHASE_COLORS = {"stationary": "rgba(44,160,44,0.12)", "steady cruise": "rgba(31,119,180,0.12)",
                "manoeuvring": "rgba(255,127,14,0.10)"}
_DOWNSAMPLER = NaNMinMaxLTTBDownsampler()


def downsample_indices(x: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` samples of ``y(x)`` that keep its visual shape (MinMaxLTTB).

    Parameters
    ----------
    x : numpy.ndarray
        Increasing abscissa (time [s]), shape (n,).
    y : numpy.ndarray
        Values, shape (n,); NaN allowed.
    max_points : int
        Upper bound of the returned count (at least 4).

    Returns
    -------
    numpy.ndarray of int
        Sorted indices into ``x`` / ``y``; all of them when ``n <= max_points``.
    """
    n = len(x)
    if n <= max_points:
        return np.arange(n)
    n_out = max(4, max_points - max_points % 2)
    return np.asarray(_DOWNSAMPLER.downsample(np.asarray(x, float), np.asarray(y, float), n_out=n_out), dtype=np.int64)


def line(x, y, name: str, *, max_points: int = MAX_POINTS, color: str | None = None, **kwargs) -> go.Scatter:
    """A downsampled line trace of ``y(x)`` (``x`` increasing)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = downsample_indices(x, y, max_points)
    return go.Scatter(x=x[keep], y=y[keep], name=name, mode="lines",
                      line={"color": color or SOURCE_COLORS.get(name), "width": 1.5}, **kwargs)


def base_layout(fig: go.Figure, *, x_title: str = TIME_TITLE, y_title: str, height: int = 320,
                title: str | None = None) -> go.Figure:
    """Common layout: axis titles (with units), compact margins, legend on top."""
    fig.update_layout(height=height, margin={"l": 10, "r": 10, "t": 40 if title else 30, "b": 10},
                      legend={"orientation": "h", "yanchor": "bottom", "y": 1.0, "x": 0.0},
                      title={"text": title} if title else None, hovermode="x unified")
    fig.update_xaxes(title_text=x_title)
    fig.update_yaxes(title_text=y_title)
    return fig


def time_series_figure(series: Mapping[str, pd.Series], y_title: str, *, title: str | None = None,
                       max_points: int = MAX_POINTS) -> go.Figure:
    """One downsampled line per named series (index: time [s])."""
    fig = go.Figure([line(s.index.to_numpy(float), s.to_numpy(float), name, max_points=max_points)
                     for name, s in series.items() if len(s)])
    return base_layout(fig, y_title=y_title, title=title)


def add_phase_bands(fig: go.Figure, phases: pd.DataFrame, *, max_bands: int = 200) -> go.Figure:
    """Shade the flight phases (``phase``, ``start_s``, ``end_s``) behind the traces; the longest
    ``max_bands`` only, so a log with many short phases stays fast to draw."""
    shown = phases.nlargest(max_bands, "duration_s") if len(phases) > max_bands else phases
    for row in shown.itertuples(index=False):
        fig.add_vrect(x0=row.start_s, x1=row.end_s, fillcolor=PHASE_COLORS.get(row.phase, "rgba(0,0,0,0.05)"),
                      line_width=0, layer="below")
    for phase, color in PHASE_COLORS.items():  # legend entries for the bands
        if (shown["phase"] == phase).any():
            fig.add_trace(go.Scatter(x=[None], y=[None], mode="markers", name=phase,
                                     marker={"color": color.replace("0.1", "0.6"), "symbol": "square", "size": 12}))
    return fig


def altitude_figure(altitudes: Mapping[str, pd.Series], phases: pd.DataFrame | None = None) -> go.Figure:
    """Altitude above MSL [m] of every source over time, with the flight phases shaded."""
    fig = time_series_figure(altitudes, "altitude above MSL [m]", title="Altitude and flight phases")
    return add_phase_bands(fig, phases) if phases is not None and len(phases) else fig


def track_figure(tracks: Mapping[str, pd.DataFrame], max_points: int = MAX_POINTS) -> go.Figure:
    """Horizontal flight track(s) in local NED: east [m] right, north [m] up, equal scales."""
    fig = go.Figure()
    for name, track in tracks.items():
        step = max(1, int(np.ceil(len(track) / max_points)))
        part = track.iloc[::step]
        fig.add_trace(go.Scatter(x=part["east_m"], y=part["north_m"], name=name, mode="lines",
                                 line={"color": SOURCE_COLORS.get(name), "width": 1.5},
                                 customdata=part["time_s"], hovertemplate="t %{customdata:.1f} s<br>"
                                 "north %{y:.1f} m<br>east %{x:.1f} m"))
        if len(track):
            fig.add_trace(go.Scatter(x=[track["east_m"].iloc[0]], y=[track["north_m"].iloc[0]], mode="markers",
                                     name=f"{name} start", showlegend=False,
                                     marker={"color": SOURCE_COLORS.get(name), "symbol": "circle-open", "size": 10}))
    base_layout(fig, x_title="east [m]", y_title="north [m]", height=420, title="Track in local NED")
    fig.update_layout(hovermode="closest")
    fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig
