"""The flight on a real map (issue 14): pure functions building the plotly ``Scattermap`` figure (MapLibre, open
tiles, no API key) of every position source, with the flight phases coloured on the GPS track. No Streamlit here.

Every track is a frame with ``time_s`` [s] (log clock), ``lat_deg``, ``lon_deg`` [deg] (WGS-84) and ``alt_m`` [m]
(above MSL); hover shows the time since log start (the first IMU sample) and the altitude.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from app.figures import MAX_POINTS, PHASE_COLORS, SOURCE_COLORS, downsample_indices
from ingest.flightlog import FlightLog

#: Open tile style (no API key).
MAP_STYLE = "open-street-map"
#: Track columns.
TRACK_COLUMNS = ("time_s", "lat_deg", "lon_deg", "alt_m")
#: Log streams of the reference tracks, by source label (labels as in :data:`app.figures.SOURCE_COLORS`).
REFERENCE_STREAMS = {"GPS": "gps", "onboard": "onboard_global_position", "truth": "truth_global_position"}
#: Sources whose track carries the phase colours, the first present is taken.
PHASE_TRACK_PREFERENCE = ("GPS", "truth", "onboard")
#: MapLibre's tile size [px]: at zoom z the world is ``TILE_PX * 2**z`` pixels wide.
TILE_PX = 512
#: Zoom range of :func:`fit_view` (MAX_ZOOM for a single point).
MIN_ZOOM, MAX_ZOOM = 0.0, 18.0
#: Map size assumed when fitting the zoom [px] (the chart is as wide as the page, at least this wide).
MAP_WIDTH_PX, MAP_HEIGHT_PX = 700, 560
#: Web-Mercator latitude limit [deg].
MERCATOR_LIMIT_DEG = 85.0511


def _track(frame: pd.DataFrame, time_s: np.ndarray) -> pd.DataFrame:
    alt = frame["alt_m"].to_numpy(float) if "alt_m" in frame else np.full(len(frame), np.nan)
    track = pd.DataFrame({"time_s": np.asarray(time_s, float), "lat_deg": frame["lat_deg"].to_numpy(float),
                          "lon_deg": frame["lon_deg"].to_numpy(float), "alt_m": alt})
    track = track.dropna(subset=["time_s", "lat_deg", "lon_deg"])
    return track.sort_values("time_s", kind="stable").reset_index(drop=True)


def reference_tracks(log: FlightLog) -> dict[str, pd.DataFrame]:
    """The log's own geodetic tracks: ``"GPS"``, ``"onboard"`` and ``"truth"`` where the log has them (and they
    hold at least one position), as :data:`TRACK_COLUMNS` frames sorted by time."""
    out = {}
    for label, stream in REFERENCE_STREAMS.items():
        if not log.has(stream):
            continue
        frame = log[stream]
        if not {"lat_deg", "lon_deg"} <= set(frame.columns):
            continue
        track = _track(frame, frame.index.to_numpy(float))
        if len(track):
            out[label] = track
    return out


def estimator_tracks(states: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """One geodetic track per estimator of a run's ``states`` (``estimator``, ``time_s``, ``lat_deg``,
    ``lon_deg``, ``alt_m``), in the run's order; estimators without any position are left out."""
    out = {}
    names = states["estimator"].cat.categories if isinstance(states["estimator"].dtype, pd.CategoricalDtype) \
        else pd.unique(states["estimator"])
    for name in names:
        part = states.loc[states["estimator"] == name]
        track = _track(part, part["time_s"].to_numpy(float))
        if len(track):
            out[str(name)] = track
    return out


def ordered_sources(names) -> list[str]:
    """Source names in the order of :data:`app.figures.SOURCE_COLORS` (unknown names last, as given)."""
    order = list(SOURCE_COLORS)
    names = list(names)
    return sorted(names, key=lambda name: (order.index(name) if name in order else len(order), names.index(name)))


def track_indices(track: pd.DataFrame, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` samples of a track that keep its shape: the union of the MinMaxLTTB
    selections (:func:`app.figures.downsample_indices`) of latitude and longitude over time, half each."""
    if len(track) <= max_points:
        return np.arange(len(track))
    time_s = track["time_s"].to_numpy(float)
    half = max(4, max_points // 2)
    return np.union1d(downsample_indices(time_s, track["lat_deg"].to_numpy(float), half),
                      downsample_indices(time_s, track["lon_deg"].to_numpy(float), half)).astype(np.int64)


def fit_view(lat_deg, lon_deg, *, width_px: int = MAP_WIDTH_PX, height_px: int = MAP_HEIGHT_PX,
             padding: float = 0.1) -> tuple[float, float, float]:
    """Centre and zoom of a Web-Mercator map of ``width_px`` x ``height_px`` showing every point.

    Parameters
    ----------
    lat_deg, lon_deg : array-like
        Positions [deg] (NaN ignored).
    width_px, height_px : int
        Map size [px].
    padding : float
        Margin added to the extent on each side, as a fraction of the extent.

    Returns
    -------
    tuple of float
        Centre latitude, centre longitude [deg] and zoom (``log2`` of the world width over :data:`TILE_PX`
        pixels), clipped to ``MIN_ZOOM .. MAX_ZOOM``; ``(0, 0, MIN_ZOOM)`` without any point, MAX_ZOOM for one.
    """
    lat, lon = np.asarray(lat_deg, float).ravel(), np.asarray(lon_deg, float).ravel()
    good = np.isfinite(lat) & np.isfinite(lon)
    if not good.any():
        return 0.0, 0.0, MIN_ZOOM
    lat = np.clip(lat[good], -MERCATOR_LIMIT_DEG, MERCATOR_LIMIT_DEG)
    lon = lon[good]
    y = np.log(np.tan(np.pi / 4.0 + np.radians(lat) / 2.0))  # Mercator ordinate [rad]
    y_low, y_high = float(y.min()), float(y.max())
    center_lat = float(np.degrees(2.0 * np.arctan(np.exp((y_low + y_high) / 2.0)) - np.pi / 2.0))
    center_lon = float((lon.min() + lon.max()) / 2.0)
    scale = 1.0 + 2.0 * padding
    zooms = []
    lon_span = float(lon.max() - lon.min())
    if lon_span > 0.0:
        zooms.append(np.log2(width_px * 360.0 / (TILE_PX * lon_span * scale)))
    y_span = y_high - y_low
    if y_span > 0.0:
        zooms.append(np.log2(height_px * 2.0 * np.pi / (TILE_PX * y_span * scale)))
    zoom = min(zooms) if zooms else MAX_ZOOM
    return center_lat, center_lon, float(np.clip(zoom, MIN_ZOOM, MAX_ZOOM))


def phase_color(phase: str) -> str:
    """Opaque marker colour of a flight phase (the band colour of :data:`app.figures.PHASE_COLORS`)."""
    band = PHASE_COLORS.get(phase, "rgba(127,127,127,0.1)")
    match = re.fullmatch(r"rgba\((\d+),\s*(\d+),\s*(\d+),\s*[\d.]+\)", band)
    return f"rgb({match.group(1)},{match.group(2)},{match.group(3)})" if match else band


def phase_of(time_s: np.ndarray, phases: pd.DataFrame) -> np.ndarray:
    """Phase name of every time [s] (``phase``, ``start_s``, ``end_s`` rows; later rows win on overlap; ``""``
    outside every phase)."""
    time_s = np.asarray(time_s, float)
    out = np.full(len(time_s), "", dtype=object)
    for row in phases.itertuples(index=False):
        out[(time_s >= row.start_s) & (time_s <= row.end_s)] = row.phase
    return out


def _hover(track: pd.DataFrame, start_time_s: float, name: str) -> dict:
    customdata = np.column_stack([track["time_s"].to_numpy(float) - start_time_s, track["alt_m"].to_numpy(float)])
    return {"customdata": customdata,
            "hovertemplate": f"{name}<br>t %{{customdata[0]:.1f}} s since log start<br>"
                             "altitude %{customdata[1]:.1f} m<br>%{lat:.6f}, %{lon:.6f}<extra></extra>"}


def map_figure(tracks: Mapping[str, pd.DataFrame], start_time_s: float, phases: pd.DataFrame | None = None, *,
               max_points: int = MAX_POINTS, style: str = MAP_STYLE, height: int = MAP_HEIGHT_PX) -> go.Figure:
    """Every source's track on a map, the flight phases coloured on one track, centre and zoom fitted.

    Parameters
    ----------
    tracks : mapping of str -> pandas.DataFrame
        Source label -> :data:`TRACK_COLUMNS` frame (:func:`reference_tracks`, :func:`estimator_tracks`).
    start_time_s : float
        Log start [s] (log clock; the first IMU sample): hover times are counted from it.
    phases : pandas.DataFrame, optional
        Flight phases (``phase``, ``start_s``, ``end_s``): markers of the phase colours on the first of
        :data:`PHASE_TRACK_PREFERENCE` present (else the first track), one legend entry per phase.
    max_points : int
        Points drawn per track at most (:func:`track_indices`).
    style : str
        MapLibre tile style (open styles: ``"open-street-map"``, ``"carto-positron"``, ...).
    height : int
        Figure height [px].

    Returns
    -------
    plotly.graph_objects.Figure
        One ``lines`` trace per source (named by its label, coloured as on every page), then one ``markers``
        trace per phase named ``"phase: <name>"``.
    """
    fig = go.Figure()
    shown = {name: track.iloc[track_indices(track, max_points)] for name, track in tracks.items() if len(track)}
    for name in ordered_sources(shown):
        part = shown[name]
        fig.add_trace(go.Scattermap(lat=part["lat_deg"].to_numpy(float), lon=part["lon_deg"].to_numpy(float),
                                    mode="lines", name=name, line={"color": SOURCE_COLORS.get(name), "width": 2},
                                    **_hover(part, start_time_s, name)))
    if phases is not None and len(phases) and shown:
        carrier = next((name for name in PHASE_TRACK_PREFERENCE if name in shown), next(iter(shown)))
        part = shown[carrier]
        names = phase_of(part["time_s"].to_numpy(float), phases)
        for phase in pd.unique(phases["phase"]):
            inside = part.loc[names == phase]
            if inside.empty:
                continue
            fig.add_trace(go.Scattermap(
                lat=inside["lat_deg"].to_numpy(float), lon=inside["lon_deg"].to_numpy(float), mode="markers",
                name=f"phase: {phase}", legendgroup="phases",
                legendgrouptitle={"text": f"flight phase ({carrier} track)"},
                marker={"color": phase_color(phase), "size": 6}, **_hover(inside, start_time_s, f"{carrier}, {phase}")))
    lat = np.concatenate([part["lat_deg"].to_numpy(float) for part in shown.values()]) if shown else []
    lon = np.concatenate([part["lon_deg"].to_numpy(float) for part in shown.values()]) if shown else []
    center_lat, center_lon, zoom = fit_view(lat, lon, height_px=height)
    fig.update_layout(height=height, margin={"l": 0, "r": 0, "t": 40, "b": 0}, title={"text": "Tracks on the map",
                      "x": 0.01, "xanchor": "left"},
                      legend={"x": 0.01, "y": 0.99, "xanchor": "left", "yanchor": "top",
                              "bgcolor": "rgba(255,255,255,0.8)"},
                      map={"style": style, "center": {"lat": center_lat, "lon": center_lon}, "zoom": zoom})
    return fig
