"""Figures and tables of the Fleet page from a batch's summary and history (plotly, no Streamlit; tested directly).
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import plotly.graph_objects as go

from app.batch.task import PARAMS_FILE
from app.figures import base_layout

#: Name of the trace of the flagged logs in :func:`trend_figure`.
FLAG_TRACE = "change flag"


def trend_figure(history: pd.DataFrame, figure: str, unit: str) -> go.Figure:
    """One line per vehicle of ``figure`` (a sensor's noise or tau) over its logs (UTC start, else the log's
    order), the flagged logs marked with a red cross and their ratio to the vehicle's earlier median in the
    hover text."""
    rows = history[history["figure"] == figure]
    use_utc = bool(rows["utc_start"].notna().all())
    fig = go.Figure()
    for vehicle, group in rows.groupby("vehicle", sort=True):
        fig.add_trace(go.Scatter(x=_x(group, use_utc), y=group["value"], mode="lines+markers", name=str(vehicle),
                                 text=group["name"], hovertemplate="%{text}: %{y:.4g}<extra>%{fullData.name}</extra>"))
    flagged = rows[rows["flagged"].astype(bool)]
    if len(flagged):
        fig.add_trace(go.Scatter(
            x=_x(flagged, use_utc), y=flagged["value"], mode="markers", name=FLAG_TRACE,
            marker={"symbol": "x", "size": 14, "color": "red", "line": {"width": 2}},
            text=[f"{row.vehicle} {row.name}: {row.ratio:.2f} x the median of its earlier logs"
                  for row in flagged.itertuples()], hovertemplate="%{text}<extra></extra>"))
    x_title = "log start (UTC)" if use_utc else "log of the vehicle (order)"
    return base_layout(fig, x_title=x_title, y_title=f"{figure} [{unit}]", title=f"{figure} per vehicle")


def rms_distribution_figure(fleet: pd.DataFrame, column: str, label: str) -> go.Figure:
    """Box plot per estimator of one RMS column across the fleet's logs (every log a point)."""
    fig = go.Figure()
    rows = fleet[fleet["estimator"].notna() & fleet[column].notna()] if column in fleet else fleet.iloc[:0]
    for estimator, group in rows.groupby("estimator", sort=False):
        fig.add_trace(go.Box(y=group[column], name=str(estimator), boxpoints="all", text=group["name"],
                             hovertemplate="%{text}: %{y:.3g}<extra>%{fullData.name}</extra>"))
    fig.update_layout(showlegend=False)
    return base_layout(fig, x_title="estimator", y_title=label)


def parameter_differences(outdir: str | Path, logs: pd.DataFrame) -> pd.DataFrame:
    """The autopilot parameters that differ between the given logs (rows of the summary with ``output_dir`` and
    ``name``): one row per parameter, one column per log (NaN where a log lacks it)."""
    columns = {}
    for row in logs.drop_duplicates("sha256").itertuples():
        path = Path(outdir) / str(row.output_dir) / PARAMS_FILE
        columns[f"{row.name} ({str(row.sha256)[:8]})"] = pd.Series(json.loads(path.read_text()), dtype=float)
    table = pd.DataFrame(columns)
    if table.empty:
        return table
    differs = table.nunique(axis=1, dropna=False) > 1
    return table[differs].sort_index()


def _x(rows: pd.DataFrame, use_utc: bool) -> pd.Series:
    return pd.to_datetime(rows["utc_start"], utc=True) if use_utc else rows["order"]
