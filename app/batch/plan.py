"""What a ``solarnav batch`` processes: the input logs (files, directories searched recursively, globs) with their
sun-device companions, the settings every log is processed with and their hash, and where a log's outputs go
(docs/batch.md, 'Inputs and outputs').

No Dask here: the plan is made on the client; only :class:`LogInput` (paths) and :class:`BatchSettings` travel to
the workers.
"""

from __future__ import annotations

import dataclasses
import glob
import hashlib
from dataclasses import dataclass
from pathlib import Path

from app.samples import with_companions
from app.workspace import canonical_json, sanitize_name
from estimators.api import DEFAULT_ESTIMATORS, parse_estimator_names
from estimators.inputs.records import AUTO_HEADING, HEADING_SOURCES
from estimators.tuning import DEFAULT_BUDGET
from ingest.errors import InputError

#: Log file suffixes a directory or glob contributes (case-insensitive): PX4 ULog and ArduPilot DataFlash.
LOG_SUFFIXES = (".ulg", ".bin")
#: Bumped when the per-log outputs change meaning: older outputs are then recomputed, not resumed.
OUTPUT_VERSION = 1
#: Subdirectory of OUTDIR holding one directory per log.
LOGS_DIR = "logs"


@dataclass(frozen=True)
class LogInput:
    """One log of the batch and its companions (absolute paths, as the workers must open them).

    Attributes
    ----------
    path : str
        The log file.
    sun_csv, device_json : str or None
        ``<stem>_sun.csv`` / ``<stem>_device.json`` beside it (:func:`app.samples.with_companions`).
    """

    path: str
    sun_csv: str | None = None
    device_json: str | None = None


@dataclass(frozen=True)
class BatchSettings:
    """How every log of a batch is processed (the settings hash identifies them for resuming).

    Attributes
    ----------
    calibrate : bool
        Calibrate the log (``solarnav calibrate`` with its defaults) and write ``calib.json``.
    tune : bool
        Also identify each selected estimator's noise from the flight's innovations (``--tune``).
    tune_budget : int
        Filter replays per estimator for ``tune``.
    replay : bool
        Re-run the estimators (``solarnav replay``, with the log's calibration when ``calibrate``) and write the
        states and diagnostics.
    estimators : tuple of str
        Estimators replayed (and tuned).
    heading : str
        Absolute heading aid of the replay (``auto``: ``mag+sun`` for a log with sun-device data, else ``mag``;
        ``mag``, ``sun``, ``mag+sun``).
    rate_hz : float
        Output rate of the replay [Hz].
    force : bool
        Replay logs whose inputs the estimators refuse (``replay --force``).
    """

    calibrate: bool = False
    tune: bool = False
    tune_budget: int = DEFAULT_BUDGET
    replay: bool = False
    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    heading: str = AUTO_HEADING
    rate_hz: float = 50.0
    force: bool = False

    def __post_init__(self):
        object.__setattr__(self, "estimators", parse_estimator_names(self.estimators))
        if self.heading not in HEADING_SOURCES:
            raise InputError(f"must be one of {', '.join(HEADING_SOURCES)}, got {self.heading!r}", field="--heading")
        if self.tune and not self.calibrate:
            raise InputError("--tune refines a calibration: give --calibrate too", field="--tune")
        if self.tune and self.tune_budget < 2:
            raise InputError(f"must be at least 2 replays, got {self.tune_budget}", field="--tune-budget")
        if not self.rate_hz > 0:
            raise InputError(f"must be a positive rate, got {self.rate_hz}", field="--rate-hz")

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {**dataclasses.asdict(self), "estimators": list(self.estimators)}

    def digest(self) -> str:
        """Settings hash: 16 hex digits of the SHA-256 of the canonical settings JSON and :data:`OUTPUT_VERSION`."""
        text = canonical_json({"settings": self.to_dict(), "output_version": OUTPUT_VERSION})
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def discover_inputs(inputs: list[str]) -> list[LogInput]:
    """The logs named by ``inputs``, in the order given (each directory's and glob's matches sorted), each once.

    Parameters
    ----------
    inputs : list of str
        Files (any suffix: taken as given), directories (every :data:`LOG_SUFFIXES` file below them) or glob
        patterns (``**`` recursive; only :data:`LOG_SUFFIXES` matches).

    Raises
    ------
    InputError
        An input names nothing, or no log was found at all.
    """
    found: dict[Path, None] = {}
    for text in inputs:
        path = Path(text)
        if path.is_file():
            matches = [path]
        elif path.is_dir():
            matches = sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in LOG_SUFFIXES)
        else:
            matches = sorted(Path(p) for p in glob.glob(text, recursive=True)
                             if Path(p).is_file() and Path(p).suffix.lower() in LOG_SUFFIXES)
            if not matches:
                raise InputError("no such file or directory, and no log matches it as a pattern", source=text)
        found.update(dict.fromkeys(p.resolve() for p in matches))
    if not found:
        raise InputError(f"no {' or '.join(LOG_SUFFIXES)} log found", source=" ".join(inputs))
    items = []
    for path in found:
        sample = with_companions(path)
        items.append(LogInput(str(path), str(sample.sun_csv) if sample.sun_csv else None,
                              str(sample.device_json) if sample.device_json else None))
    return items


def log_output_dir(outdir: str | Path, sha256: str, path: str) -> Path:
    """``OUTDIR/logs/<first 16 hex digits of the content hash>_<file name, sanitised>``: one directory per log
    content and name (the same file under two names gets two)."""
    return Path(outdir) / LOGS_DIR / f"{sha256[:16]}_{sanitize_name(Path(path).name)}"
