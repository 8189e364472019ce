"""Map: the tracks of the GPS, the onboard estimate, the ground truth and every estimator of a stored run on an
open street map (flight phases coloured on the GPS track), and the same tracks in local NED for metre-level
detail."""

import streamlit as st

from app import adapters, comparison, figures, maps, session, tables

#: The Estimators page's run selector: the run shown there is the one the map opens on.
ESTIMATORS_RUN_KEY = "est_run"
RUN_KEY = "map_run"

log = session.require_log()
root, sha256 = session.root(), session.selected_sha256()
workspace = session.workspace()
st.title(f"Map: {log.meta.source}")

# ------------------------------------------------------------------ the run whose estimators are drawn
stored = workspace.list_runs(sha256)
run_id = None
if stored.empty:
    st.info("No estimator run for this log yet: the map shows the log's own tracks (GPS, onboard estimate, truth). "
            "Run the estimators on the **Estimators** page (or `solarnav replay`) to add their tracks.")
else:
    labels = comparison.run_names(stored)
    if st.session_state.get(RUN_KEY) not in labels:
        current = st.session_state.get(ESTIMATORS_RUN_KEY)
        st.session_state[RUN_KEY] = current if current in labels else next(iter(labels))
    details = tables.run_details(stored, workspace.list_logs(), labels)
    run_id = st.selectbox("Run", list(labels), format_func=labels.get, key=RUN_KEY,
                          help="; ".join(f"{column}: {value}" for column, value in
                                         details.loc[st.session_state[RUN_KEY]].items()))

tracks = maps.reference_tracks(log)
if run_id is not None:
    tracks.update(maps.estimator_tracks(adapters.run_table(root, run_id, "states")))
sources = maps.ordered_sources(tracks)

# ------------------------------------------------------------------ map
st.subheader("Map")
if not log.has("gps"):
    st.info("This log has no GPS: no GPS track"
            + (", and the estimators have no geodetic position (they need a GPS fix as their origin)."
               if run_id is not None else "."))
if not sources:
    st.info("Nothing to place on the map: the log has no geodetic position (no GPS fix, no onboard or true "
            "latitude / longitude). The local track below, if any, is about PX4's own origin.")
else:
    left, right = st.columns([3, 1])
    # keyed by the sources on offer: another run (other estimators) starts with all of its sources shown
    shown = left.multiselect("Sources", sources, default=sources, key=f"map_sources_{'_'.join(sources)}")
    style = right.selectbox("Tiles", ["open-street-map", "carto-positron", "carto-voyager"], key="map_style")
    color_phases = st.toggle("Colour the flight phases", value=True, key="map_phases",
                             help="markers on the GPS track (else the truth, else the onboard estimate): "
                                  "stationary, steady cruise, manoeuvring")
    phases = adapters.flight_phases(root, sha256) if color_phases else None
    st.plotly_chart(maps.map_figure({name: tracks[name] for name in shown}, log.meta.start_time_s, phases,
                                    style=style), key="map")
    st.caption("Hover: time since log start (the first IMU sample) [s] and altitude above MSL [m]. "
               f"At most {figures.MAX_POINTS} points per track are drawn.")

# ------------------------------------------------------------------ local NED
st.subheader("Local NED")
ned = dict(adapters.tracks_ned(root, sha256))
if run_id is not None:
    quantities = adapters.run_comparison(root, sha256, run_id).quantities
    ned.update({name: frame for name, frame in quantities.items()
                if name not in ("truth", "onboard") and frame["north_m"].notna().any()})
if ned:
    if "GPS" not in ned:
        st.info("No GPS fix: the local track is the onboard local position about PX4's own origin.")
    st.plotly_chart(figures.track_figure({name: ned[name] for name in maps.ordered_sources(ned)}), key="map_ned")
else:
    st.info("No position source in this log (no GPS, onboard or true position).")
