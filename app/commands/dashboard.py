"""``solarnav dashboard [--workspace DIR] [--port N]``: open the browser dashboard on a workspace.

The bundled sample logs are added to the workspace on first start, then Streamlit serves ``app/dashboard.py`` from
the repository root, where ``.streamlit/config.toml`` (upload limit, headless) is read.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from app.samples import add_samples
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


def streamlit_command(workspace: Path, port: int) -> list[str]:
    """The ``streamlit run`` command line serving the dashboard on ``workspace`` at ``port``."""
    return [sys.executable, "-m", "streamlit", "run", str(ENTRYPOINT), "--server.port", str(port),
            "--", "--workspace", str(workspace)]


def run(args: argparse.Namespace) -> int:
    """Prepare the workspace and serve the dashboard until interrupted; Streamlit's exit code."""
    workspace = Path(args.workspace).resolve()
    entries = add_samples(Workspace(workspace))
    print(f"workspace {workspace}: {len(entries)} bundled sample log(s) ready", flush=True)
    try:
        return subprocess.run(streamlit_command(workspace, args.port), cwd=CONFIG_DIR, check=False).returncode
    except KeyboardInterrupt:
        return 0
