"""The user's actions as library functions: calibrate a log, identify its noise, replay the estimators with a
calibration, write the outputs and export autopilot parameters (docs/workflows.md).

Each function composes ingest, calib and estimators functions that do not know it (as pvlib's ``modelchain``
composes its models); the CLI commands, the dashboard adapters and the batch tasks each call one of them per user
action and add only their own input/output and presentation. Nothing here imports streamlit, argparse or dask.
"""
