"""Dashboard pages (one file each; run by :mod:`app.dashboard` through ``st.navigation``)."""
