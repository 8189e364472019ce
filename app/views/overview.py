"""Overview: what the log holds (vehicle, firmware, duration, streams, gaps, warnings), what it lacks and why that
matters, what of it the estimators refuse or flag (input quality), and the flight itself (track in local NED,
altitude and flight phases)."""

import streamlit as st

from app import adapters, figures, session, tables, time_range

log = session.require_log()
meta = log.meta
clock = figures.time_base(log)
RANGE_KEY = "overview_time_range"
st.title(f"Overview: {meta.source}")

missing = tables.missing_streams(log)
sensors_missing = missing[missing["stream"].isin(tables.SENSOR_STREAMS)]
columns = st.columns(4)
columns[0].metric("Data duration", tables.duration_text(meta.duration_s),
                  help=f"first to last IMU sample: {meta.start_time_s:.3f} .. {meta.end_time_s:.3f} s (log clock)")
columns[1].metric("Streams", len(meta.streams))
columns[2].metric("Missing sensors", len(sensors_missing))
columns[3].metric("Reader warnings", len(meta.warnings))
start_utc = (f"{log.utc(meta.start_time_s)[0]:%Y-%m-%d %H:%M:%S} UTC" if meta.utc_offset_s is not None
             else "no GPS time")
st.markdown(f"**Vehicle** {tables.vehicle_name(meta.vehicle_type)} &nbsp;·&nbsp; **Firmware** "
            f"{meta.px4_version or 'unknown'} on {meta.hardware or 'unknown hardware'} &nbsp;·&nbsp; **Start** "
            f"{start_utc} &nbsp;·&nbsp; **SHA-256** `{meta.sha256[:16]}`")

if len(sensors_missing):
    st.warning("Missing sensors:\n" + "\n".join(f"- **{row.stream}**: no {row.consequence}"
                                                 for row in sensors_missing.itertuples()))
others_missing = missing[~missing["stream"].isin(tables.SENSOR_STREAMS)]
if len(others_missing):
    st.info("Not in this log:\n" + "\n".join(f"- **{row.stream}**: no {row.consequence}"
                                             for row in others_missing.itertuples()))
for finding in adapters.input_quality(session.root(), session.selected_sha256()):
    if finding["severity"] == "refuse":
        st.error(f"**Refused input** (the estimators do not run on it unless forced): {finding['message']}")
    else:
        st.warning(f"**Flagged input**: {finding['message']}")
if meta.warnings:
    with st.expander(f"Reader warnings ({len(meta.warnings)})", expanded=len(meta.warnings) <= 3):
        for warning in meta.warnings:
            st.warning(warning)

st.subheader("Streams")
st.dataframe(clock.shift(tables.streams_table(meta), ["longest_gap_at_s"]), hide_index=True, placeholder="–",
             column_config={
    "rate_hz": st.column_config.NumberColumn("rate [Hz]", format="%.1f"),
    "longest_gap_s": st.column_config.NumberColumn("longest gap [s]", format="%.2f"),
    "longest_gap_at_s": st.column_config.NumberColumn("longest gap at [s since start]", format="%.2f"),
})


@st.fragment
def flight_plots() -> None:
    """Track and altitude with their display options (reruns alone when an option changes)."""
    root, sha256 = session.root(), session.selected_sha256()
    tracks = adapters.tracks_ned(root, sha256)
    altitudes = adapters.altitudes(root, sha256)
    sources = sorted(set(tracks) | set(altitudes), key=list(figures.SOURCE_COLORS).index)
    if not sources:
        st.warning("No position or altitude source in this log (no GPS, barometer or onboard estimate).")
        return
    shown = st.multiselect("Sources", sources, default=sources, key="overview_sources")
    show_phases = st.toggle("Shade flight phases", value=True, key="overview_phases")
    phases = adapters.flight_phases(root, sha256)
    span = figures.time_span(log)
    window = session.time_range_slider(RANGE_KEY, span, "Every time chart of the page shows this range (the track "
                                       "only the part flown in it), with the samples in it at full resolution and "
                                       "the y axes fitted to them.")
    left, right = st.columns([2, 3])
    if "GPS" not in tracks:
        left.info("No GPS fix: the track is the onboard local position about PX4's own origin.")
    left.plotly_chart(figures.note_partial(figures.track_figure({k: v for k, v in tracks.items() if k in shown},
                                                                time_base=clock, window=window),
                                           time_range.partial_text(window, span)), key="track")
    session.time_chart(figures.altitude_figure({k: v for k, v in altitudes.items() if k in shown},
                                               phases if show_phases else None, time_base=clock, window=window),
                       "altitude", RANGE_KEY, span, container=right)
    baro_note = tables.baro_gps_altitude_note(altitudes, log.meta.parameters.get("SENS_BARO_QNH"))
    if baro_note:
        right.caption(baro_note)
    st.subheader("Flight phases")
    st.dataframe(clock.shift(phases, ["start_s", "end_s"]), hide_index=True, column_config={
        "start_s": st.column_config.NumberColumn("start [s since start]", format="%.1f"),
        "end_s": st.column_config.NumberColumn("end [s since start]", format="%.1f"),
        "duration_s": st.column_config.NumberColumn("duration [s]", format="%.1f"),
    })


st.subheader("Flight")
flight_plots()
