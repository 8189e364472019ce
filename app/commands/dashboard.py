"""``solarnav dashboard [--workspace DIR] [--port N]``: open the browser dashboard on a workspace.

On first start the bundled sample logs are added to the workspace and their default estimator runs computed (the
Home page opens on them processed); then Streamlit serves ``app/dashboard.py`` from the repository root, where
``.streamlit/config.toml`` (upload limit, headless) is read.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from app.workspace import Workspace

#: The Streamlit entrypoint.
ENTRYPOINT = Path(__file__).resolve().parents[1] / "dashboard.py"
#: Directory holding ``.streamlit/config.toml`` (the repository root).
CONFIG_DIR = ENTRYPOINT.parents[1]
DEFAULT_PORT = 8501


def add_parser(subparsers) -> None:
    """Register the ``dashboard`` sub-parser."""
    parser = subparsers.add_parser("dashboard", help="open the browser dashboard", description=__doc__)
    parser.add_argument("--workspace", metavar="DIR", default="workspace",
                        help="workspace directory: uploads, calibrations, runs and their catalog (default "
                             "./workspace)")
    parser.add_argument("--port", metavar="N", type=int, default=DEFAULT_PORT,
                        help=f"local port to serve on (default {DEFAULT_PORT})")
    parser.add_argument("--skip-sample-runs", action="store_true",
                        help="start faster: add the bundled samples without computing their estimator runs")


def streamlit_command(workspace: Path, port: int) -> list[str]:
    """The ``streamlit run`` command line serving the dashboard on ``workspace`` at ``port``."""
    return [sys.executable, "-m", "streamlit", "run", str(ENTRYPOINT), "--server.port", str(port),
            "--", "--workspace", str(workspace)]


def run(args: argparse.Namespace) -> int:
    """Prepare the workspace and serve the dashboard until interrupted; Streamlit's exit code."""
    workspace = Path(args.workspace).resolve()
    from app.samples import add_samples, prepare_samples  # deferred: it imports the calibration stack (1 s)

    store = Workspace(workspace)
    entries = (add_samples(store) if args.skip_sample_runs
               else prepare_samples(store, report=lambda line: print(line, flush=True)))
    print(f"workspace {workspace}: {len(entries)} bundled sample log(s) ready", flush=True)
    try:
        return subprocess.run(streamlit_command(workspace, args.port), cwd=CONFIG_DIR, check=False).returncode
    except KeyboardInterrupt:
        return 0
