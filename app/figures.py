"""Pure plotly figure builders for the dashboard (no Streamlit), tested directly.

Time axes read seconds since the log start (:class:`TimeBase`, the first IMU sample): the log clock and UTC stay
on hover. Every time figure takes the page's shared time ``window`` [s since start]: its series are sliced to the
window at full resolution and only then downsampled with MinMaxLTTB (``tsdownsample``) to at most
:data:`MAX_POINTS` points, so a 1-hour 250 Hz log draws as fast as a short one and a narrow window shows the single
samples; the y axes autorange on the sliced data. Angles are drawn on [-180, 180), or on [0, 360) when they sit
near +-180 (:func:`angle_cut_deg`), and broken where they still wrap around instead of drawing vertical lines.
Rows without data are left out (no empty panel). Innovations are scaled to the in-flight innovations
(:func:`innovation_limit`), the samples beyond marked at the axis edge. Every axis title carries its unit.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots
from tsdownsample import NaNMinMaxLTTBDownsampler

from ingest.flightlog import FlightLog

#: Largest number of points drawn per trace.
MAX_POINTS = 2000
#: Title of every time axis of the pages: seconds since the log start (:class:`TimeBase`).
TIME_TITLE = "time since log start [s]"
#: Title of a time axis on the raw log clock (PX4 ``timestamp`` / 1e6), for figures drawn without a time base.
LOG_CLOCK_TITLE = "time [s] (log clock)"
#: Column added to downloads next to the log-clock ``time_s``.
SINCE_START_COLUMN = "time_since_start_s"
#: A jump larger than this between consecutive samples of an angle in [-180, 180) deg is a wrap-around.
WRAP_JUMP_DEG = 180.0
#: Angle columns (deg, wrapped to [-180, 180)) whose traces are broken at the wrap-arounds.
ANGLE_COLUMNS = ("roll_deg", "pitch_deg", "yaw_deg", "course_deg", "azimuth_deg")
#: One colour per data source, the same on every page.
SOURCE_COLORS = {
    "three_stage": "#1f77b4", "full_state_direct": "#ff7f0e", "full_state_indirect": "#2ca02c",
    "onboard": "#7f7f7f", "truth": "#000000", "GPS": "#d62728", "barometer": "#9467bd", "sun device": "#e6a800",
}
#: Fill colours of the flight-phase bands.
PHASE_COLORS = {"stationary": "rgba(44,160,44,0.12)", "steady cruise": "rgba(31,119,180,0.12)",
                "manoeuvring": "rgba(255,127,14,0.10)"}
_DOWNSAMPLER = NaNMinMaxLTTBDownsampler()

Window = tuple[float, float]


# ---------------------------------------------------------------------------------------------------- time axis
@dataclass(frozen=True)
class TimeBase:
    """How the pages show time: seconds since the log start on the axes, log clock and UTC on hover.

    Attributes
    ----------
    start_s : float
        Log-clock time of the log start [s] (:func:`log_start_s`).
    utc_offset_s : float or None
        UTC unix time = log clock + ``utc_offset_s`` (``LogMetadata.utc_offset_s``); None without GPS time.
    """

    start_s: float = 0.0
    utc_offset_s: float | None = None

    def since_start(self, time_s) -> np.ndarray:
        """Seconds since the log start of log-clock times ``time_s`` [s]."""
        return np.asarray(time_s, dtype=float) - self.start_s

    def hover_labels(self, since_start_s) -> list[str]:
        """Hover text of times [s since start]: the time since start, the log clock and UTC (when known)."""
        since = np.asarray(since_start_s, dtype=float)
        clock = since + self.start_s
        labels = [f"t = {t:.3f} s since start, log clock {c:.3f} s" for t, c in zip(since, clock, strict=True)]
        if self.utc_offset_s is None:
            return labels
        utc_ms = np.round((clock + self.utc_offset_s) * 1e3)  # whole milliseconds, not truncated float noise
        utc = pd.to_datetime(utc_ms, unit="ms", utc=True).strftime("%Y-%m-%d %H:%M:%S.%f")
        return [f"{label}, UTC {str(stamp)[:-3]}" for label, stamp in zip(labels, utc, strict=True)]

    def shift(self, frame: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
        """A copy of ``frame`` with the log-clock time ``columns`` [s] as seconds since the start."""
        out = frame.copy()
        for column in columns:
            if column in out:
                out[column] = self.since_start(out[column])
        return out

    def with_since_start(self, frame: pd.DataFrame, column: str = "time_s") -> pd.DataFrame:
        """A copy of ``frame`` keeping its log-clock ``column`` and adding :data:`SINCE_START_COLUMN` after it
        (for downloads)."""
        out = frame.copy()
        if column in out and SINCE_START_COLUMN not in out:
            out.insert(out.columns.get_loc(column) + 1, SINCE_START_COLUMN, self.since_start(out[column]))
        return out


def log_start_s(log: FlightLog) -> float:
    """The log start on the log clock [s]: the first IMU sample (``meta.start_time_s``), else the earliest first
    sample of any stream, else 0."""
    start = log.meta.start_time_s
    if np.isfinite(start):
        return float(start)
    firsts = [float(frame.index[0]) for frame in log.streams.values() if len(frame)]
    return min(firsts) if firsts else 0.0


def time_base(log: FlightLog) -> TimeBase:
    """The :class:`TimeBase` of a flight (its start and GPS UTC offset)."""
    return TimeBase(start_s=log_start_s(log), utc_offset_s=log.meta.utc_offset_s)


def time_span(log: FlightLog) -> Window:
    """Range of a page's time-range control [s since start]: 0 to the log's duration (at least 0.01 s)."""
    end = log.meta.end_time_s
    duration = float(end) - log_start_s(log) if np.isfinite(end) else float(log.meta.duration_s)
    return 0.0, max(duration, 0.01)


def clamp_window(window: Sequence[float] | None, span: Window) -> Window:
    """``window`` [s] clipped to ``span`` (the whole span when None or empty after clipping): a range kept in the
    session state stays valid when another log is opened."""
    if window is None or len(window) != 2:
        return span
    low, high = sorted(float(v) for v in window)
    low, high = min(max(low, span[0]), span[1]), max(min(high, span[1]), span[0])
    return (low, high) if high > low else span


def window_slice(x: np.ndarray, window: Sequence[float] | None) -> slice:
    """Slice of increasing ``x`` covering ``window`` plus one sample either side (lines reach the edges)."""
    if window is None:
        return slice(0, len(x))
    low = int(np.searchsorted(x, window[0], side="left"))
    high = int(np.searchsorted(x, window[1], side="right"))
    return slice(max(0, low - 1), min(len(x), high + 1))


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
    keep = _DOWNSAMPLER.downsample(np.ascontiguousarray(x, float), np.ascontiguousarray(y, float), n_out=n_out)
    return np.asarray(keep, dtype=np.int64)


def window_indices(x: np.ndarray, y: np.ndarray, window: Sequence[float] | None = None,
                   max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of the samples of ``y(x)`` to draw for ``window``: the full-resolution samples inside it (and one
    either side) downsampled with :func:`downsample_indices` only when they exceed ``max_points``, so a narrow
    window shows the raw samples."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    part = window_slice(x, window)
    return part.start + downsample_indices(x[part], y[part], max_points)


def break_wraps(x: np.ndarray, y: np.ndarray, jump: float = WRAP_JUMP_DEG) -> tuple[np.ndarray, np.ndarray]:
    """``x``, ``y`` with a NaN point inserted (at the mid time) wherever ``|diff(y)| > jump``: an angle wrapping
    from +180 to -180 deg is drawn as a broken line, not a vertical stroke across the axis."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    with np.errstate(invalid="ignore"):
        at = np.flatnonzero(np.abs(np.diff(y)) > jump)
    if not len(at):
        return x, y
    return np.insert(x, at + 1, 0.5 * (x[at] + x[at + 1])), np.insert(y, at + 1, np.nan)


#: Lower edges of the display ranges of an angle [deg]: [-180, 180) by default, [0, 360) for an angle that sits
#: near +-180 deg (a heading near south), which would otherwise break into fragments at every sample crossing it.
ANGLE_CUTS_DEG = (-180.0, 0.0)


def display_angle(angle_deg, cut_deg: float) -> np.ndarray:
    """Angles [deg] on the display range [``cut_deg``, ``cut_deg`` + 360)."""
    return np.mod(np.asarray(angle_deg, float) - cut_deg, 360.0) + cut_deg


def angle_cut_deg(angles_deg: Sequence[np.ndarray], jump: float = WRAP_JUMP_DEG) -> float:
    """The lower edge of :data:`ANGLE_CUTS_DEG` on which the series ``angles_deg`` [deg] (one per source, in
    time order) cross the range's edge least often (:func:`break_wraps` breaks a line there); -180 on a tie."""
    def crossings(cut_deg: float) -> int:
        with np.errstate(invalid="ignore"):
            return sum(int(np.count_nonzero(np.abs(np.diff(display_angle(a, cut_deg))) > jump)) for a in angles_deg)

    return min(ANGLE_CUTS_DEG, key=crossings)


def angle_title(axis_title: str, cut_deg: float) -> str:
    """An angle's axis title naming a display range other than the default [-180, 180)."""
    return axis_title if cut_deg == ANGLE_CUTS_DEG[0] else f"{axis_title} on {cut_deg:g}-{cut_deg + 360:g}"


def rows_with_data(frames: Mapping[str, pd.DataFrame], rows: Sequence[tuple[str, str]]) -> list[tuple[str, str]]:
    """The ``rows`` (column, axis title) of which at least one frame has a finite value: a chart draws no empty
    panel."""
    return [(column, axis_title) for column, axis_title in rows
            if any(column in frame and np.isfinite(frame[column].to_numpy(float)).any() for frame in frames.values())]


def apply_time_range(fig: go.Figure, window: Sequence[float] | None) -> go.Figure:
    """Show ``window`` [s] on every x axis of a time figure and let every y axis autorange (on the data sliced to
    the window); the page applies the same window to all its time figures."""
    if window is not None:
        fig.update_xaxes(range=[float(window[0]), float(window[1])], autorange=False)
    fig.update_yaxes(autorange=True)
    return fig


def note_partial(fig: go.Figure, note: str | None) -> go.Figure:
    """Append ``note`` (:func:`app.time_range.partial_text`: the part of the log shown) to the time axis title
    of ``fig``, or to its title when it has no time axis (a track); nothing for None."""
    if not note:
        return fig
    time_axes = [axis for axis in fig.select_xaxes() if axis.title.text in (TIME_TITLE, LOG_CLOCK_TITLE)]
    for axis in time_axes:
        axis.title.text = f"{axis.title.text} · {note}"
    if not time_axes:
        fig.update_layout(title_text=f"{fig.layout.title.text or ''} ({note})".lstrip())
    return fig


def line(x, y, name: str, *, max_points: int = MAX_POINTS, color: str | None = None,
         time_base: TimeBase | None = None, window: Sequence[float] | None = None, wrap: bool = False,
         **kwargs) -> go.Scatter:
    """A downsampled line trace of ``y(x)`` (``x`` increasing, log clock [s]).

    With a ``time_base`` the trace is drawn over seconds since the log start with the log clock and UTC on hover;
    ``window`` [s, in the drawn unit] slices the samples before the downsampling; ``wrap`` breaks an angle in
    [-180, 180) deg at its wrap-arounds (:func:`break_wraps`).
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if time_base is not None:
        x = time_base.since_start(x)
    keep = window_indices(x, y, window, max_points)
    x, y = x[keep], y[keep]
    if wrap:
        x, y = break_wraps(x, y)
    if time_base is not None:
        kwargs.setdefault("customdata", time_base.hover_labels(x))
        kwargs.setdefault("hovertemplate", f"{name}: %{{y:.4g}}<br>%{{customdata}}<extra></extra>")
    return go.Scatter(x=x, y=y, name=name, mode="lines",
                      line={"color": color or SOURCE_COLORS.get(name), "width": 1.5}, **kwargs)


def base_layout(fig: go.Figure, *, x_title: str = TIME_TITLE, y_title: str, height: int = 320,
                title: str | None = None) -> go.Figure:
    """Common layout: axis titles (with units), compact margins, legend on top."""
    fig.update_layout(height=height, margin={"l": 10, "r": 10, "t": 80 if title else 40, "b": 10},
                      legend={"orientation": "h", "yanchor": "bottom", "y": 1.01, "x": 0.0},
                      title={"text": title, "x": 0.01, "xanchor": "left", "y": 0.99, "yanchor": "top"}
                      if title else None, hovermode="x unified")
    fig.update_xaxes(title_text=x_title)
    fig.update_yaxes(title_text=y_title)
    return fig


def _time_titles(fig: go.Figure, n_rows: int, time_base: TimeBase | None) -> None:
    """Time axis title on the bottom row only."""
    fig.update_xaxes(title_text="")
    fig.update_xaxes(title_text=TIME_TITLE if time_base is not None else LOG_CLOCK_TITLE, row=n_rows, col=1)


def time_series_figure(series: Mapping[str, pd.Series], y_title: str, *, title: str | None = None,
                       max_points: int = MAX_POINTS, time_base: TimeBase | None = None,
                       window: Sequence[float] | None = None, wrap: bool = False) -> go.Figure:
    """One downsampled line per named series (index: log clock [s]) over ``window`` [s]."""
    fig = go.Figure([line(s.index.to_numpy(float), s.to_numpy(float), name, max_points=max_points,
                          time_base=time_base, window=window, wrap=wrap)
                     for name, s in series.items() if len(s)])
    base_layout(fig, x_title=TIME_TITLE if time_base is not None else LOG_CLOCK_TITLE, y_title=y_title,
                title=title)
    return apply_time_range(fig, window)


def add_phase_bands(fig: go.Figure, phases: pd.DataFrame, *, max_bands: int = 200,
                    time_base: TimeBase | None = None) -> go.Figure:
    """Shade the flight phases (``phase``, ``start_s``, ``end_s`` on the log clock) behind the traces; the
    longest ``max_bands`` only, so a log with many short phases stays fast to draw."""
    shown = phases.nlargest(max_bands, "duration_s") if len(phases) > max_bands else phases
    offset = time_base.start_s if time_base is not None else 0.0
    for row in shown.itertuples(index=False):
        fig.add_vrect(x0=row.start_s - offset, x1=row.end_s - offset,
                      fillcolor=PHASE_COLORS.get(row.phase, "rgba(0,0,0,0.05)"), line_width=0, layer="below")
    for phase, color in PHASE_COLORS.items():  # legend entries for the bands
        if (shown["phase"] == phase).any():
            fig.add_trace(go.Scatter(x=[None], y=[None], mode="markers", name=phase,
                                     marker={"color": color.replace("0.1", "0.6"), "symbol": "square", "size": 12}))
    return fig


def altitude_figure(altitudes: Mapping[str, pd.Series], phases: pd.DataFrame | None = None, *,
                    time_base: TimeBase | None = None, window: Sequence[float] | None = None) -> go.Figure:
    """Altitude above MSL [m] of every source over time, with the flight phases shaded."""
    fig = time_series_figure(altitudes, "altitude above MSL [m]", title="Altitude and flight phases",
                             time_base=time_base, window=window)
    return add_phase_bands(fig, phases, time_base=time_base) if phases is not None and len(phases) else fig


def track_figure(tracks: Mapping[str, pd.DataFrame], max_points: int = MAX_POINTS, *,
                 time_base: TimeBase | None = None, window: Sequence[float] | None = None) -> go.Figure:
    """Horizontal flight track(s) in local NED: east [m] right, north [m] up, equal scales; only the part flown
    in ``window`` [s since start] when given."""
    base = time_base or TimeBase()
    fig = go.Figure()
    for name, full in tracks.items():
        since = base.since_start(full["time_s"])
        track = full.iloc[window_slice(since, window)]
        since = base.since_start(track["time_s"])
        keep = np.unique(np.linspace(0, len(track) - 1, min(len(track), max_points)).round().astype(int))
        part = track.iloc[keep]
        fig.add_trace(go.Scatter(x=part["east_m"], y=part["north_m"], name=name, mode="lines",
                                 line={"color": SOURCE_COLORS.get(name), "width": 1.5},
                                 customdata=base.hover_labels(since[keep]), hovertemplate="%{customdata}<br>"
                                 "north %{y:.1f} m<br>east %{x:.1f} m<extra>" + name + "</extra>"))
        if len(track):
            fig.add_trace(go.Scatter(x=[track["east_m"].iloc[0]], y=[track["north_m"].iloc[0]], mode="markers",
                                     name=f"{name} start", showlegend=False,
                                     marker={"color": SOURCE_COLORS.get(name), "symbol": "circle-open", "size": 10}))
    base_layout(fig, x_title="east [m]", y_title="north [m]", height=420, title="Track in local NED")
    fig.update_layout(hovermode="closest")
    fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


# ---------------------------------------------------------------------------------------------------- calibration
SEGMENT_COLORS = {"stationary": "rgba(44,160,44,0.15)", "steady": "rgba(31,119,180,0.15)",
                  "user": "rgba(214,39,40,0.18)"}
AXIS_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def segment_figure(imu_norms: pd.DataFrame, segments: pd.DataFrame, max_points: int = MAX_POINTS, *,
                   time_base: TimeBase | None = None) -> go.Figure:
    """Gyro and specific-force (f) norms over the whole log with the candidate and chosen segments shaded; drag a
    box on it to pick a window.

    Parameters
    ----------
    imu_norms : pandas.DataFrame
        Index ``time_s`` [s, log clock]; columns ``gyro_norm_rad_s`` [rad/s], ``accel_norm_m_s2`` [m/s^2].
    segments : pandas.DataFrame
        Columns ``kind`` (stationary / steady / user), ``start_s``, ``end_s`` [s, log clock].
    time_base : TimeBase, optional
        Draw over seconds since the log start (the log clock and UTC on hover); the log clock without one.
    """
    fig = make_subplots(rows=2, cols=1, shared_xaxes=True, vertical_spacing=0.06)
    time_s = imu_norms.index.to_numpy(float)
    for row, (column, name) in enumerate((("gyro_norm_rad_s", "|gyro|"), ("accel_norm_m_s2", "|f|")), start=1):
        fig.add_trace(line(time_s, imu_norms[column].to_numpy(float), name, max_points=max_points,
                           color=AXIS_COLORS[row - 1], time_base=time_base), row=row, col=1)
    offset = time_base.start_s if time_base is not None else 0.0
    for seg in segments.itertuples(index=False):
        fig.add_vrect(x0=seg.start_s - offset, x1=seg.end_s - offset,
                      fillcolor=SEGMENT_COLORS.get(seg.kind, "rgba(0,0,0,0.1)"),
                      line_width=2 if seg.kind == "user" else 0, line_color="#d62728", layer="below")
    base_layout(fig, y_title="|gyro| [rad/s]", height=420, title="Calibration segment (drag a box to pick one)")
    fig.update_yaxes(title_text="|f| [m/s^2]", row=2, col=1)
    _time_titles(fig, 2, time_base)
    fig.update_layout(dragmode="select", selectdirection="h", hovermode="closest")
    return fig


def frequency_response_figure(freq_hz: np.ndarray, gain_single: np.ndarray, gain_zero_phase: np.ndarray,
                              cutoff_hz: float) -> go.Figure:
    """FIR magnitude response [dB] of one pass and of the zero-phase (filtfilt) filter, cutoff marked."""
    floor = 1e-6  # -120 dB, keeps log10 finite at the zeros of the response
    fig = go.Figure([
        go.Scatter(x=freq_hz, y=20 * np.log10(np.maximum(gain_single, floor)), name="one pass", mode="lines"),
        go.Scatter(x=freq_hz, y=20 * np.log10(np.maximum(gain_zero_phase, floor)), name="zero phase (filtfilt)",
                   mode="lines"),
    ])
    fig.add_vline(x=cutoff_hz, line_dash="dash", line_color="#7f7f7f",
                  annotation_text=f"cutoff {cutoff_hz:g} Hz", annotation_position="top right")
    base_layout(fig, x_title="frequency [Hz]", y_title="gain [dB]", height=300, title="FIR frequency response")
    fig.update_yaxes(range=[-100, 5])
    fig.update_layout(hovermode="x")
    return fig


def raw_filtered_figure(time_s: np.ndarray, raw: np.ndarray, filtered: np.ndarray, axes: tuple[str, ...],
                        unit: str, max_points: int = MAX_POINTS, *, time_base: TimeBase | None = None) -> go.Figure:
    """Raw samples and their zero-phase low-pass, one row per axis (``time_s``: log clock [s]; ``raw``,
    ``filtered``: shape (n, k)); over seconds since the log start with a ``time_base``."""
    fig = make_subplots(rows=len(axes), cols=1, shared_xaxes=True, vertical_spacing=0.04)
    for k, axis in enumerate(axes):
        fig.add_trace(line(time_s, raw[:, k], f"{axis} raw", max_points=max_points, color="#aec7e8",
                           legendgroup="raw", time_base=time_base), row=k + 1, col=1)
        fig.add_trace(line(time_s, filtered[:, k], f"{axis} filtered", max_points=max_points, color="#1f77b4",
                           legendgroup="filtered", time_base=time_base), row=k + 1, col=1)
    base_layout(fig, y_title="", height=120 + 150 * len(axes), title="Raw vs filtered")
    for k, axis in enumerate(axes):
        fig.update_yaxes(title_text=f"{axis} [{unit}]", row=k + 1, col=1)
    _time_titles(fig, len(axes), time_base)
    return fig


def allan_figure(curves: list[pd.DataFrame], readoffs: list, axes: tuple[str, ...], unit: str,
                 sensor: str | None = None) -> go.Figure:
    """Overlapping Allan deviation per axis (log-log) with the read-off figures drawn: the white-noise line
    N / sqrt(tau) and the bias-instability floor 0.664 B at its cluster time; the title names ``sensor``.

    Parameters
    ----------
    curves : list of pandas.DataFrame
        Per axis: ``tau_s`` [s], ``adev`` [unit], ``adev_err`` [unit].
    readoffs : list of calib.allan.AllanFigures
        Per axis: ``white_density``, ``bias_instability``, ``bias_instability_tau_s``.
    """
    fig = go.Figure()
    for k, (curve, figs, axis) in enumerate(zip(curves, readoffs, axes, strict=True)):
        color = AXIS_COLORS[k % len(AXIS_COLORS)]
        fig.add_trace(go.Scatter(x=curve["tau_s"], y=curve["adev"], name=axis, mode="lines+markers",
                                 line={"color": color}, marker={"size": 4},
                                 error_y={"type": "data", "array": curve["adev_err"], "visible": True,
                                          "thickness": 0.8}))
        if np.isfinite(figs.white_density):
            tau = curve["tau_s"].to_numpy(float)
            fig.add_trace(go.Scatter(x=tau, y=figs.white_density / np.sqrt(tau), mode="lines", showlegend=False,
                                     line={"color": color, "dash": "dot", "width": 1}, name=f"{axis} N/sqrt(tau)"))
        fig.add_trace(go.Scatter(x=[figs.bias_instability_tau_s], y=[0.664 * figs.bias_instability],
                                 mode="markers", name=f"{axis} bias instability", showlegend=False,
                                 marker={"color": color, "symbol": "star", "size": 12}))
    base_layout(fig, x_title="cluster time tau [s]", y_title=f"Allan deviation [{unit}]", height=380,
                title=f"Allan deviation{f' of the {sensor}' if sensor else ''} (dotted: white noise N/sqrt(tau); "
                      "star: bias-instability floor)")
    fig.update_xaxes(type="log")
    fig.update_yaxes(type="log")
    fig.update_layout(hovermode="closest")
    return fig


def tau_curve_figure(log10_tau_grid, neg_log_likelihood, mean_nis, chosen_tau: float,
                     nis_band: tuple[float, float]) -> go.Figure:
    """The auto-tau evidence (eq 52): mean negative log-likelihood and mean NIS over tau, chosen tau marked."""
    tau = 10.0 ** np.asarray(log10_tau_grid, dtype=float)
    fig = make_subplots(specs=[[{"secondary_y": True}]])
    fig.add_trace(go.Scatter(x=tau, y=neg_log_likelihood, name="neg. log-likelihood", mode="lines+markers"),
                  secondary_y=False)
    fig.add_trace(go.Scatter(x=tau, y=mean_nis, name="mean NIS", mode="lines+markers"), secondary_y=True)
    if all(np.isfinite(nis_band)):
        fig.add_hrect(y0=nis_band[0], y1=nis_band[1], fillcolor="rgba(44,160,44,0.15)", line_width=0,
                      secondary_y=True)
    fig.add_vline(x=chosen_tau, line_dash="dash", annotation_text=f"tau = {chosen_tau:.3g}")
    base_layout(fig, x_title="tau [-]", y_title="mean neg. log-likelihood [-]", height=320,
                title="Automatic tau (accelerometer y innovations)")
    fig.update_yaxes(title_text="mean NIS [-]", secondary_y=True)
    fig.update_xaxes(type="log")
    return fig


# ---------------------------------------------------------------------------------------------------- estimators
#: Line style per reference source (estimators are solid).
REFERENCE_DASH = {"truth": "dash", "onboard": "dot"}


def quantity_figure(frames: Mapping[str, pd.DataFrame], rows: Sequence[tuple[str, str]], *, title: str,
                    max_points: int = MAX_POINTS, time_base: TimeBase | Mapping[str, TimeBase] | None = None,
                    window: Sequence[float] | None = None,
                    angle_columns: Collection[str] = ANGLE_COLUMNS) -> go.Figure:
    """One row per quantity, one downsampled line per source (estimators, onboard, truth).

    Parameters
    ----------
    frames : mapping of source -> pandas.DataFrame
        Each with ``time_s`` [s, log clock] and the row columns (missing or all-NaN columns are skipped).
    rows : sequence of (column, axis title with unit)
        Quantities to draw, top to bottom.
    time_base, window
        Time axis (seconds since start; one time base per source when the sources come from several logs) and the
        page's shared range [s since start].
    angle_columns : collection of str
        Columns of angles [deg], drawn on [-180, 180) or, when they sit near +-180, on [0, 360)
        (:func:`angle_cut_deg`, named in the axis title) and broken where they still wrap around.

    Rows without a finite value in any source are left out (:func:`rows_with_data`): no empty panel.
    """
    rows = rows_with_data(frames, rows)
    fig = make_subplots(rows=max(1, len(rows)), cols=1, shared_xaxes=True, vertical_spacing=0.03)

    def base_of(source: str) -> TimeBase | None:
        return time_base.get(source) if isinstance(time_base, Mapping) else time_base

    def shown(source: str, column: str) -> np.ndarray:  # the samples of the window, for the display range
        frame = frames[source]
        since = (base_of(source) or TimeBase()).since_start(frame["time_s"])
        return frame[column].to_numpy(float)[window_slice(since, window)]

    cuts = {column: angle_cut_deg([shown(source, column) for source, frame in frames.items() if column in frame])
            for column, _ in rows if column in angle_columns}
    for source, frame in frames.items():
        time_s = frame["time_s"].to_numpy(float)
        for row, (column, _) in enumerate(rows, start=1):
            if column not in frame or not frame[column].notna().any():
                continue
            values = frame[column].to_numpy(float)
            trace = line(time_s, display_angle(values, cuts[column]) if column in cuts else values, source,
                         max_points=max_points, time_base=base_of(source), window=window, wrap=column in cuts,
                         legendgroup=source, showlegend=not any(t.name == source for t in fig.data))
            trace.line.dash = REFERENCE_DASH.get(source)
            fig.add_trace(trace, row=row, col=1)
    base_layout(fig, y_title="", height=90 + 170 * len(rows), title=title)
    for row, (column, axis_title) in enumerate(rows, start=1):
        fig.update_yaxes(title_text=angle_title(axis_title, cuts[column]) if column in cuts else axis_title,
                         row=row, col=1)
    _time_titles(fig, max(1, len(rows)), time_base)
    return apply_time_range(fig, window)


#: Quantile of |innovation| [-] the innovation axes show at least: the in-flight innovations, not a landing spike.
INNOVATION_QUANTILE = 0.99
#: The innovation axes show at least this many robust standard deviations of the innovations [-] (1.4826 x their
#: median absolute deviation, which a short spike does not inflate): every sample of a Gaussian innovation is in
#: view.
INNOVATION_SIGMAS = 5.0
#: Median absolute deviation -> standard deviation of a Gaussian [-].
MAD_TO_SIGMA = 1.4826
#: Margin of the innovation axes beyond the larger of the two [-].
INNOVATION_HEADROOM = 1.2
#: Name of the markers of the innovations beyond the axis, drawn at its edge.
OFF_SCALE = "off-scale"


def innovation_limit(innovation) -> float:
    """Half-range of an innovation axis [innovation unit]: :data:`INNOVATION_HEADROOM` times the larger of the
    :data:`INNOVATION_QUANTILE` quantile of |innovation| and :data:`INNOVATION_SIGMAS` robust standard deviations
    of the innovations; NaN without a finite nonzero value.

    Scaled to the innovations themselves, not to sqrt(S): a conservative filter's +-2 sqrt(S) envelope may then lie
    beyond the axis, which shows that its innovations are smaller than it expects."""
    values = np.asarray(innovation, float)
    values = values[np.isfinite(values)]
    if not values.size:
        return np.nan
    robust_sigma = MAD_TO_SIGMA * np.median(np.abs(values - np.median(values)))
    limit = INNOVATION_HEADROOM * max(float(np.quantile(np.abs(values), INNOVATION_QUANTILE)),
                                      INNOVATION_SIGMAS * robust_sigma)
    return limit if limit > 0 else np.nan


def _off_scale_markers(fig: go.Figure, row: int, time_s: np.ndarray, innovation: np.ndarray, limit: float,
                       base: TimeBase, max_points: int) -> int:
    """Mark the innovations beyond +-``limit`` at the axis edge of ``row`` (their value on hover); returns how
    many there are."""
    with np.errstate(invalid="ignore"):
        beyond = np.flatnonzero(np.abs(innovation) > limit)
    if len(beyond):
        beyond_shown = beyond[::max(1, int(np.ceil(len(beyond) / max_points)))]
        since = base.since_start(time_s[beyond_shown])
        values = innovation[beyond_shown]
        labels = [f"{label}<br>innovation {value:.4g} (off-scale)"
                  for label, value in zip(base.hover_labels(since), values, strict=True)]
        fig.add_trace(go.Scatter(x=since, y=np.sign(values) * limit, mode="markers", name=OFF_SCALE,
                                 legendgroup=OFF_SCALE, showlegend=not any(t.name == OFF_SCALE for t in fig.data),
                                 customdata=labels, hovertemplate="%{customdata}<extra></extra>",
                                 marker={"color": "#d62728", "size": 7,
                                         "symbol": np.where(values > 0, "triangle-up", "triangle-down")}),
                      row=row, col=1)
    return len(beyond)


def _scale_innovation_rows(fig: go.Figure, limits: Sequence[float], off_scale: int, total: int) -> go.Figure:
    """Fix every row's y range to +-its limit (rows without one autorange) and say how many innovations of the
    window are beyond it."""
    for row, limit in enumerate(limits, start=1):
        if np.isfinite(limit):
            fig.update_yaxes(range=[-limit, limit], autorange=False, row=row, col=1)
    if off_scale:
        fig.add_annotation(text=f"{off_scale} of {total} innovations beyond the axis (▲▼ at its edge)",
                           xref="paper", yref="paper", x=1.0, y=1.0, xanchor="right", yanchor="bottom",
                           showarrow=False, font={"color": "#d62728"})
    return fig


def innovation_figure(diagnostics: pd.DataFrame, units: Mapping[str, str], *, title: str,
                      max_points: int = MAX_POINTS, time_base: TimeBase | None = None,
                      window: Sequence[float] | None = None) -> go.Figure:
    """Innovations of one estimator's sensor, one row per component, with the +-2 sqrt(S) envelope (95 % for a
    consistent filter) and the rejected updates marked.

    Parameters
    ----------
    diagnostics : pandas.DataFrame
        Rows of one estimator and sensor: ``time_s``, ``component``, ``innovation``, ``innovation_var``,
        ``accepted``.
    units : mapping of component -> str
        Unit of each component's innovation.
    time_base, window
        Time axis (seconds since start) and the page's shared range [s since start].

    Each row's y axis spans +-:func:`innovation_limit` of the window's samples; the innovations beyond it are
    marked at the edge (:data:`OFF_SCALE`) and counted in a note.
    """
    base = time_base or TimeBase()
    parts = [(str(component), part) for component, part
             in diagnostics.groupby("component", sort=False, observed=True)]
    components = [component for component, _ in parts]
    fig = make_subplots(rows=max(1, len(components)), cols=1, shared_xaxes=True, vertical_spacing=0.04)
    options = {"max_points": max_points, "time_base": time_base, "window": window}
    limits: list[float] = []
    off_scale = total = 0
    for row, (_, part) in enumerate(parts, start=1):
        time_s = part["time_s"].to_numpy(float)
        bound = 2.0 * np.sqrt(part["innovation_var"].to_numpy(float))
        first = row == 1
        fig.add_trace(line(time_s, bound, "+2 sqrt(S)", color="#bbbbbb", legendgroup="bound", showlegend=first,
                           **options), row=row, col=1)
        fig.add_trace(line(time_s, -bound, "-2 sqrt(S)", color="#bbbbbb", legendgroup="bound", showlegend=False,
                           **options), row=row, col=1)
        fig.add_trace(line(time_s, part["innovation"].to_numpy(float), "innovation", color="#1f77b4",
                           legendgroup="innovation", showlegend=first, **options), row=row, col=1)
        shown = part.iloc[window_slice(base.since_start(time_s), window)]
        innovation = shown["innovation"].to_numpy(float)
        limits.append(innovation_limit(innovation))
        off_scale += _off_scale_markers(fig, row, shown["time_s"].to_numpy(float), innovation, limits[-1], base,
                                        max_points)
        total += int(np.isfinite(innovation).sum())
        rejected = shown.loc[~shown["accepted"].to_numpy(dtype=bool)]
        if len(rejected):
            step = max(1, int(np.ceil(len(rejected) / max_points)))
            since = base.since_start(rejected["time_s"].iloc[::step])
            fig.add_trace(go.Scatter(x=since, y=rejected["innovation"].iloc[::step],
                                     mode="markers", name="rejected", legendgroup="rejected",
                                     showlegend=not any(t.name == "rejected" for t in fig.data),
                                     customdata=base.hover_labels(since),
                                     hovertemplate="rejected: %{y:.4g}<br>%{customdata}<extra></extra>",
                                     marker={"color": "#d62728", "symbol": "x", "size": 5}), row=row, col=1)
    base_layout(fig, y_title="", height=90 + 160 * max(1, len(components)), title=title)
    for row, component in enumerate(components, start=1):
        fig.update_yaxes(title_text=f"{component} [{units.get(component, '-')}]", row=row, col=1)
    _time_titles(fig, max(1, len(components)), time_base)
    return _scale_innovation_rows(apply_time_range(fig, window), limits, off_scale, total)


def _nis_frame(fig: go.Figure, band: tuple[float, float], window: int, *, title: str | None, time_base,
               time_window) -> go.Figure:
    """The moving-NIS chart's band, expected value 1, log y axis and time range."""
    fig.add_hrect(y0=band[0], y1=band[1], fillcolor="rgba(44,160,44,0.15)", line_width=0, layer="below")
    fig.add_hline(y=1.0, line_dash="dash", line_color="#2ca02c",
                  annotation_text=f"95 % chi-square band for {window} updates", annotation_position="top left")
    base_layout(fig, x_title=TIME_TITLE if time_base is not None else LOG_CLOCK_TITLE,
                y_title=f"mean NIS over {window} updates [-]", height=320, title=title)
    fig.update_yaxes(type="log")
    return apply_time_range(fig, time_window)


def nis_figure(moving: pd.DataFrame, window: int, band: tuple[float, float], *, title: str,
               max_points: int = MAX_POINTS, time_base: TimeBase | None = None,
               time_window: Sequence[float] | None = None) -> go.Figure:
    """Moving mean NIS per component with its chi-square band (``moving``: ``time_s``, ``component``,
    ``mean_nis``; ``band``: 95 % bounds of the mean of ``window`` NIS values; ``time_window``: the page's shared
    range [s since start])."""
    fig = go.Figure()
    for k, (component, part) in enumerate(moving.groupby("component", sort=False)):
        fig.add_trace(line(part["time_s"].to_numpy(float), part["mean_nis"].to_numpy(float), str(component),
                           max_points=max_points, color=AXIS_COLORS[k % len(AXIS_COLORS)], time_base=time_base,
                           window=time_window))
    return _nis_frame(fig, band, window, title=title, time_base=time_base, time_window=time_window)


# ---------------------------------------------------------------------------------------------------- sun vector
#: Colours of the cell states dark / lit / faulty (codes 0, 1, 2 of :mod:`app.sun_compare`).
CELL_STATE_COLORS = ("#e8e8e8", "#f2b705", "#d62728")


def cell_state_figure(time_s: np.ndarray, states: np.ndarray, names: Sequence[str],
                      max_columns: int = MAX_POINTS, *, time_base: TimeBase | None = None,
                      window: Sequence[float] | None = None) -> go.Figure:
    """Heat map of every cell's state over time (``time_s``: log clock [s]; ``states``: shape (n, cells), codes
    0..2 named by ``names``) over ``window`` [s since start].

    The epochs in the window are reduced to ``max_columns`` time bins keeping each bin's highest code, so a short
    fault stays visible."""
    base = time_base or TimeBase()
    since, states = base.since_start(time_s), np.asarray(states)
    part = window_slice(since, window)
    since, states = since[part], states[part]
    step = max(1, int(np.ceil(len(since) / max_columns)))
    n_bins = int(np.ceil(len(since) / step))
    padded = np.full((n_bins * step, states.shape[1]), -1)
    padded[: len(states)] = states
    binned = padded.reshape(n_bins, step, states.shape[1]).max(axis=1)
    n_codes = len(CELL_STATE_COLORS)
    scale = [[edge / n_codes, color] for k, color in enumerate(CELL_STATE_COLORS) for edge in (k, k + 1)]
    x = since[::step]
    state_names = np.asarray(names, dtype=object)[np.clip(binned.T, 0, n_codes - 1)]
    times = np.asarray(base.hover_labels(x), dtype=object)
    fig = go.Figure(go.Heatmap(
        x=x, y=[f"cell {k + 1}" for k in range(states.shape[1])], z=binned.T, zmin=-0.5,
        zmax=n_codes - 0.5, colorscale=scale, hovertemplate="%{y}: %{customdata}<extra></extra>",
        customdata=state_names + "<br>" + times[None, :],
        colorbar={"tickvals": list(range(n_codes)), "ticktext": list(names), "title": {"text": "state"}}))
    base_layout(fig, x_title=TIME_TITLE if time_base is not None else LOG_CLOCK_TITLE, y_title="photocell",
                height=300, title="Cells over time")
    fig.update_layout(hovermode="closest")
    if window is not None:
        fig.update_xaxes(range=[float(window[0]), float(window[1])], autorange=False)
    return fig


# ---------------------------------------------------------------------------------------------------- run overlays
#: Line dash per overlaid run (issue 14): the first selected run solid, then dashed, dotted, ...
RUN_DASHES = ("solid", "dash", "dot", "dashdot", "longdash", "longdashdot")
#: Separator of estimator and run in an overlaid series name.
RUN_SEPARATOR = " · "
#: Reference sources drawn once (from the first run holding them), never per run.
REFERENCE_SOURCES = ("truth", "onboard")


def run_style(estimator: str, run_index: int) -> tuple[str, str]:
    """Colour and dash of an estimator's series in the ``run_index``-th overlaid run: the colour is the
    estimator's (:data:`SOURCE_COLORS`; an unknown name gets a stable colour of :data:`AXIS_COLORS`), the dash is
    the run's (:data:`RUN_DASHES`, cycling)."""
    color = SOURCE_COLORS.get(estimator) or AXIS_COLORS[sum(map(ord, estimator)) % len(AXIS_COLORS)]
    return color, RUN_DASHES[run_index % len(RUN_DASHES)]


def run_series_name(estimator: str, run_name: str) -> str:
    """Legend name of an estimator's series in an overlay: ``"<estimator> · <run name>"``."""
    return f"{estimator}{RUN_SEPARATOR}{run_name}"


def overlay_sources(per_run: Mapping[str, Mapping[str, pd.DataFrame]]
                    ) -> tuple[dict[str, pd.DataFrame], dict[str, tuple[str, str]]]:
    """Frames of several runs (run name -> source -> frame, in overlay order) as one mapping for the figure
    builders, with the style of every series.

    Estimators become ``"<estimator> · <run>"`` styled by :func:`run_style`; the references
    (:data:`REFERENCE_SOURCES`) are the same in every run of a log and are kept once, under their own name and
    style (:data:`SOURCE_COLORS`, :data:`REFERENCE_DASH`), after the estimators.
    """
    frames: dict[str, pd.DataFrame] = {}
    styles: dict[str, tuple[str, str]] = {}
    references: dict[str, pd.DataFrame] = {}
    for index, (run_name, sources) in enumerate(per_run.items()):
        for source, frame in sources.items():
            if source in REFERENCE_SOURCES:
                references.setdefault(source, frame)
                continue
            name = run_series_name(source, run_name)
            frames[name], styles[name] = frame, run_style(source, index)
    for source, frame in references.items():
        frames[source] = frame
        styles[source] = (SOURCE_COLORS[source], REFERENCE_DASH.get(source, "solid"))
    return frames, styles


def restyle(fig: go.Figure, styles: Mapping[str, tuple[str, str]]) -> go.Figure:
    """Apply ``styles`` (series name -> colour, dash) to the line and marker traces of ``fig`` named by them
    (a track's ``"<name> start"`` marker takes its series' colour)."""
    for trace in fig.data:
        name = trace.name or ""
        style = styles.get(name) or styles.get(name.removesuffix(" start"))
        if style is None:
            continue
        if trace.mode == "markers":
            trace.marker.color = style[0]
        else:
            trace.line.color, trace.line.dash = style
    return fig


def overlay_quantity_figure(per_run: Mapping[str, Mapping[str, pd.DataFrame]], rows: Sequence[tuple[str, str]],
                            *, title: str, max_points: int = MAX_POINTS, time_base: TimeBase | None = None,
                            window: Sequence[float] | None = None) -> go.Figure:
    """:func:`quantity_figure` of several runs overlaid (:func:`overlay_sources`): colour per estimator, dash per
    run, the references once; ``time_base`` / ``window`` as for a single run."""
    frames, styles = overlay_sources(per_run)
    fig = quantity_figure(frames, rows, title=title, max_points=max_points, time_base=time_base, window=window)
    return restyle(fig, styles)


def overlay_track_figure(per_run: Mapping[str, Mapping[str, pd.DataFrame]], max_points: int = MAX_POINTS, *,
                         time_base: TimeBase | None = None, window: Sequence[float] | None = None) -> go.Figure:
    """:func:`track_figure` of several runs overlaid (:func:`overlay_sources`)."""
    frames, styles = overlay_sources(per_run)
    return restyle(track_figure(frames, max_points, time_base=time_base, window=window), styles)


def overlay_innovation_figure(per_run: Mapping[str, pd.DataFrame], estimator: str, units: Mapping[str, str], *,
                              title: str, max_points: int = MAX_POINTS, time_base: TimeBase | None = None,
                              window: Sequence[float] | None = None) -> go.Figure:
    """Innovations of one estimator's sensor in several runs (run name -> its diagnostics rows, in overlay
    order): one row per component, one line per run (:func:`run_style`), the +-2 sqrt(S) envelope of the first
    run that has the component in grey; each row scaled as in :func:`innovation_figure` over all runs."""
    components = list(dict.fromkeys(str(c) for part in per_run.values() for c in part["component"].unique()))
    fig = make_subplots(rows=max(1, len(components)), cols=1, shared_xaxes=True, vertical_spacing=0.04)
    options = {"max_points": max_points, "time_base": time_base, "window": window}
    base = time_base or TimeBase()
    shown = {run_name: diagnostics.iloc[window_slice(base.since_start(diagnostics["time_s"]), window)]
             for run_name, diagnostics in per_run.items()}
    limits = []
    for component in components:
        parts = [part.loc[part["component"].astype(str) == component] for part in shown.values()]
        limits.append(innovation_limit(np.concatenate([part["innovation"].to_numpy(float) for part in parts])))
    off_scale = total = 0
    bounded: set[str] = set()
    for index, (run_name, diagnostics) in enumerate(per_run.items()):
        name = run_series_name(estimator, run_name)
        color, dash = run_style(estimator, index)
        for row, component in enumerate(components, start=1):
            part = diagnostics.loc[diagnostics["component"].astype(str) == component]
            if part.empty:
                continue
            time_s = part["time_s"].to_numpy(float)
            if component not in bounded:
                bound = 2.0 * np.sqrt(part["innovation_var"].to_numpy(float))
                label = f"+-2 sqrt(S) · {run_name}"
                for sign in (1.0, -1.0):
                    fig.add_trace(line(time_s, sign * bound, label, color="#bbbbbb", legendgroup="bound",
                                       showlegend=not bounded and sign > 0, **options), row=row, col=1)
                bounded.add(component)
            trace = line(time_s, part["innovation"].to_numpy(float), name, color=color, legendgroup=name,
                         showlegend=not any(t.name == name for t in fig.data), **options)
            trace.line.dash = dash
            fig.add_trace(trace, row=row, col=1)
            inside = shown[run_name].loc[shown[run_name]["component"].astype(str) == component]
            innovation = inside["innovation"].to_numpy(float)
            off_scale += _off_scale_markers(fig, row, inside["time_s"].to_numpy(float), innovation,
                                            limits[row - 1], base, max_points)
            total += int(np.isfinite(innovation).sum())
    base_layout(fig, y_title="", height=90 + 160 * max(1, len(components)), title=title)
    for row, component in enumerate(components, start=1):
        fig.update_yaxes(title_text=f"{component} [{units.get(component, '-')}]", row=row, col=1)
    _time_titles(fig, max(1, len(components)), time_base)
    return _scale_innovation_rows(apply_time_range(fig, window), limits, off_scale, total)


def overlay_nis_figure(per_run: Mapping[str, pd.DataFrame], estimator: str, window: int,
                       band: tuple[float, float], *, title: str, max_points: int = MAX_POINTS,
                       time_base: TimeBase | None = None, time_window: Sequence[float] | None = None) -> go.Figure:
    """:func:`nis_figure` of several runs (run name -> moving mean NIS, in overlay order): colour per component,
    dash per run (:data:`RUN_DASHES`), series ``"<component>: <estimator> · <run>"``."""
    fig = go.Figure()
    components: list[str] = []
    for index, (run_name, moving) in enumerate(per_run.items()):
        dash = RUN_DASHES[index % len(RUN_DASHES)]
        for component, part in moving.groupby("component", sort=False):
            component = str(component)
            if component not in components:
                components.append(component)
            trace = line(part["time_s"].to_numpy(float), part["mean_nis"].to_numpy(float),
                         f"{component}: {run_series_name(estimator, run_name)}", max_points=max_points,
                         color=AXIS_COLORS[components.index(component) % len(AXIS_COLORS)], time_base=time_base,
                         window=time_window)
            trace.line.dash = dash
            fig.add_trace(trace)
    return _nis_frame(fig, band, window, title=title, time_base=time_base, time_window=time_window)


# ---------------------------------------------------------------------------------------------------- log overlays
@dataclass(frozen=True)
class LogRun:
    """One log's run in a cross-log overlay: its names, its time base and its frames (source -> frame with
    ``time_s`` on that log's clock: an estimator's quantities or errors, and the references)."""

    log_name: str
    run_name: str
    time_base: TimeBase
    frames: Mapping[str, pd.DataFrame]

    @property
    def label(self) -> str:
        """``"<log name> · <run name>"``: the log's row in the RMS comparison."""
        return f"{self.log_name}{RUN_SEPARATOR}{self.run_name}"


def overlay_log_sources(log_runs: Sequence[LogRun], estimator: str
                        ) -> tuple[dict[str, pd.DataFrame], dict[str, TimeBase], dict[str, tuple[str, str]]]:
    """The frames of one estimator in several logs for :func:`quantity_figure`: series
    ``"<estimator> · <log name> · <run name>"`` and the log's references ``"<reference> · <log name>"``, each
    log's series with its own time base (every log from its own start) and colour (:data:`AXIS_COLORS` in order;
    the estimator solid, the references dashed as :data:`REFERENCE_DASH`)."""
    frames: dict[str, pd.DataFrame] = {}
    bases: dict[str, TimeBase] = {}
    styles: dict[str, tuple[str, str]] = {}
    for index, log_run in enumerate(log_runs):
        color = AXIS_COLORS[index % len(AXIS_COLORS)]
        named = [(f"{estimator}{RUN_SEPARATOR}{log_run.label}", estimator, "solid")]
        named += [(f"{source}{RUN_SEPARATOR}{log_run.log_name}", source, REFERENCE_DASH.get(source, "solid"))
                  for source in REFERENCE_SOURCES]
        for name, source, dash in named:
            if source in log_run.frames:
                frames[name], bases[name], styles[name] = log_run.frames[source], log_run.time_base, (color, dash)
    return frames, bases, styles


def overlay_logs_figure(log_runs: Sequence[LogRun], estimator: str, rows: Sequence[tuple[str, str]], *, title: str,
                        max_points: int = MAX_POINTS, window: Sequence[float] | None = None) -> go.Figure:
    """:func:`quantity_figure` of one estimator across several logs (:func:`overlay_log_sources`), over seconds
    since each log's start and the page's shared ``window`` [s]."""
    frames, bases, styles = overlay_log_sources(log_runs, estimator)
    fig = quantity_figure(frames, rows, title=title, max_points=max_points, time_base=bases, window=window)
    return restyle(fig, styles)
