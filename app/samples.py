"""Bundled sample logs: find them in ``sample_logs/`` and add them to a workspace on first start.

A sample is a ``.ulg`` file plus, optionally, a sun-device CSV and a device JSON named after the ULog's stem
(``paper.ulg``, ``paper_sun.csv``, ``paper_device.json``; other files such as ``paper_sim.json`` are ignored).
No Streamlit here: the app's entrypoint calls :func:`add_samples`, the ``dashboard`` command
:func:`prepare_samples`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from app import runs
from app.loading import load_stored_log
from app.workspace import LogEntry, Workspace

#: Where the simulator writes the bundled logs (``solarnav simulate``).
SAMPLE_DIR = Path(__file__).resolve().parents[1] / "sample_logs"


@dataclass(frozen=True)
class SampleLog:
    """One bundled sample.

    Attributes
    ----------
    ulog : Path
        The ``.ulg`` file.
    sun_csv : Path or None
        Sun-device CSV beside it, if any.
    device_json : Path or None
        Sun-device geometry JSON beside it, if any.
    """

    ulog: Path
    sun_csv: Path | None = None
    device_json: Path | None = None


def find_samples(directory: Path = SAMPLE_DIR) -> list[SampleLog]:
    """The bundled samples in ``directory``, sorted by file name (empty when the folder is missing)."""
    if not directory.is_dir():
        return []
    return [with_companions(ulog) for ulog in sorted(directory.glob("*.ulg"))]


def with_companions(ulog: Path) -> SampleLog:
    """A log with the sun-device CSV and device JSON beside it named after its stem (``<stem>_sun.csv``,
    ``<stem>_device.json``), each None when absent (the ``solarnav batch`` inputs follow the same rule)."""
    def companion(path: Path) -> Path | None:
        return path if path.is_file() else None

    return SampleLog(ulog, companion(ulog.with_name(f"{ulog.stem}_sun.csv")),
                     companion(ulog.with_name(f"{ulog.stem}_device.json")))


def add_samples(workspace: Workspace, samples: list[SampleLog] | None = None) -> list[LogEntry]:
    """Add the bundled samples to ``workspace`` (stored logs are recognised by content hash and kept as they are).

    Returns
    -------
    list of LogEntry
        The samples' catalog entries, in :func:`find_samples` order.
    """
    samples = find_samples() if samples is None else samples
    return [workspace.add_log(sample.ulog.read_bytes(), sample.ulog.name,
                              sun_csv=sample.sun_csv.read_bytes() if sample.sun_csv else None,
                              device_json=sample.device_json.read_bytes() if sample.device_json else None)
            for sample in samples]


def prepare_samples(workspace: Workspace, samples: list[SampleLog] | None = None,
                    report: Callable[[str], None] = print) -> list[LogEntry]:
    """Add the bundled samples and give each one without a stored run the default estimator run, so the dashboard
    opens on processed logs (first start only; later starts find the runs in the workspace).

    Parameters
    ----------
    workspace : Workspace
        Where the samples and runs are stored.
    samples : list of SampleLog, optional
        Default :func:`find_samples`.
    report : callable
        Receives one progress line per step.
    """
    entries = add_samples(workspace, samples)
    for entry in entries:
        if workspace.list_runs(entry.sha256).empty:
            report(f"{entry.display_name}: running the estimators (first start only) ...")
            runs.replay_and_store(workspace, entry.sha256, load_stored_log(workspace, entry.sha256),
                                  runs.RunSettings(), progress=lambda fraction, text: report(f"  {text}"))
    return entries
