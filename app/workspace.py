"""Persistent workspace: uploaded logs stored under their content hash, calibrations and estimator runs as files,
and a SQLite catalog that lists only complete entries.

Layout under the workspace root::

    catalog.sqlite
    logs/<sha256>/log.ulg            the uploaded ULog, byte for byte
    logs/<sha256>/sun.csv            optional sun-device log (and device.json)
    calibrations/<id>/calib.json
    runs/<id>/states.parquet, diagnostics.parquet, report.json
    .staging/                        work in progress; emptied on open

Crash safety: an entry's files are written into ``.staging/<random>/`` and moved into place with one ``os.replace``
of the directory; only then is the catalog row inserted, in a transaction. A crash before the move leaves only
staging debris (removed on the next open); a crash between the move and the insert leaves an unlisted directory
(also removed on the next open). The catalog therefore never lists a half-written entry.

User-supplied file names are only ever stored as catalog text (sanitised for display); paths are built from hashes
and generated ids.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import sqlite3
import uuid
from collections.abc import Callable
from contextlib import closing
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

_SCHEMA = """
CREATE TABLE IF NOT EXISTS logs (
    sha256 TEXT PRIMARY KEY, display_name TEXT NOT NULL, size_bytes INTEGER NOT NULL, added_utc TEXT NOT NULL,
    has_sun INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS calibrations (
    calib_id TEXT PRIMARY KEY, log_sha256 TEXT NOT NULL, settings_json TEXT NOT NULL, created_utc TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY, log_sha256 TEXT NOT NULL, settings_json TEXT NOT NULL, created_utc TEXT NOT NULL);
"""
_KINDS = {"logs": "sha256", "calibrations": "calib_id", "runs": "run_id"}
#: Tables of a stored estimator run.
RUN_TABLES = ("states", "diagnostics")


def sanitize_name(name: str, max_length: int = 80) -> str:
    """A display-safe version of a user-supplied file name: its last path component, restricted to
    letters, digits, ``._-`` and spaces (others become ``_``), at most ``max_length`` characters, never empty."""
    base = re.split(r"[\\/]", str(name))[-1]
    cleaned = re.sub(r"[^A-Za-z0-9._\- ]", "_", base).strip(" .")
    return cleaned[:max_length] or "unnamed"


def _now_utc() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


@dataclass(frozen=True)
class LogEntry:
    """A stored log: content hash, sanitised display name, size [bytes], when added (UTC ISO), sun log present."""

    sha256: str
    display_name: str
    size_bytes: int
    added_utc: str
    has_sun: bool


class Workspace:
    """A workspace directory with its catalog (see module docstring).

    Parameters
    ----------
    root : str or Path
        Workspace directory; created when missing.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        for sub in ("logs", "calibrations", "runs", ".staging"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)
        self.catalog_path = self.root / "catalog.sqlite"
        with closing(self._connect()) as db, db:
            db.executescript(_SCHEMA)
        self._recover()

    def _connect(self) -> sqlite3.Connection:
        return sqlite3.connect(self.catalog_path, timeout=30)

    def _recover(self) -> None:
        """Remove staging debris and directories the catalog does not list (interrupted writes)."""
        shutil.rmtree(self.root / ".staging", ignore_errors=True)
        (self.root / ".staging").mkdir(exist_ok=True)
        with closing(self._connect()) as db:
            for kind, key in _KINDS.items():
                listed = {row[0] for row in db.execute(f"SELECT {key} FROM {kind}")}
                for path in (self.root / kind).iterdir():
                    if path.name not in listed:
                        shutil.rmtree(path, ignore_errors=True)

    def _commit_entry(self, kind: str, entry_id: str, write_files: Callable[[Path], None],
                      insert: Callable[[sqlite3.Connection], None]) -> Path:
        """Write an entry's files in staging, move the directory into place, then insert its catalog row."""
        staging = self.root / ".staging" / uuid.uuid4().hex
        staging.mkdir()
        try:
            write_files(staging)
            final = self.root / kind / entry_id
            os.replace(staging, final)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        with closing(self._connect()) as db, db:
            insert(db)
        return final

    # ---------------------------------------------------------------- logs
    def add_log(self, content: bytes, name: str, sun_csv: bytes | None = None,
                device_json: bytes | None = None) -> LogEntry:
        """Store an uploaded ULog (and optional sun-device CSV / device JSON); returns its entry.

        Adding the same content again returns the existing entry (the hash is the identity).
        """
        sha256 = hashlib.sha256(content).hexdigest()
        existing = self.get_log(sha256)
        if existing is not None:
            return existing
        entry = LogEntry(sha256, sanitize_name(name), len(content), _now_utc(), sun_csv is not None)

        def write_files(directory: Path) -> None:
            (directory / "log.ulg").write_bytes(content)
            if sun_csv is not None:
                (directory / "sun.csv").write_bytes(sun_csv)
            if device_json is not None:
                (directory / "device.json").write_bytes(device_json)

        def insert(db: sqlite3.Connection) -> None:
            db.execute("INSERT INTO logs VALUES (?, ?, ?, ?, ?)",
                       (entry.sha256, entry.display_name, entry.size_bytes, entry.added_utc, int(entry.has_sun)))

        self._commit_entry("logs", sha256, write_files, insert)
        return entry

    def get_log(self, sha256: str) -> LogEntry | None:
        """The catalog entry of a stored log, or None."""
        with closing(self._connect()) as db:
            row = db.execute("SELECT * FROM logs WHERE sha256 = ?", (sha256,)).fetchone()
        return None if row is None else LogEntry(row[0], row[1], row[2], row[3], bool(row[4]))

    def list_logs(self) -> list[LogEntry]:
        """All stored logs, newest first."""
        with closing(self._connect()) as db:
            rows = db.execute("SELECT * FROM logs ORDER BY added_utc DESC, rowid DESC").fetchall()
        return [LogEntry(r[0], r[1], r[2], r[3], bool(r[4])) for r in rows]

    def log_dir(self, sha256: str) -> Path:
        """Directory holding a stored log's files (``log.ulg``, optional ``sun.csv``, ``device.json``)."""
        return self.root / "logs" / sha256

    # ---------------------------------------------------------------- calibrations and runs
    def add_calibration(self, log_sha256: str, settings: dict, calibration_json: str) -> str:
        """Store a calibration file for a log; returns its id."""
        calib_id = uuid.uuid4().hex[:16]

        def write_files(directory: Path) -> None:
            (directory / "calib.json").write_text(calibration_json)

        def insert(db: sqlite3.Connection) -> None:
            db.execute("INSERT INTO calibrations VALUES (?, ?, ?, ?)",
                       (calib_id, log_sha256, json.dumps(settings, sort_keys=True), _now_utc()))

        self._commit_entry("calibrations", calib_id, write_files, insert)
        return calib_id

    def add_run(self, log_sha256: str, settings: dict, states: pd.DataFrame, diagnostics: pd.DataFrame,
                report: dict) -> str:
        """Store an estimator run (states, diagnostics, report) for a log; returns its id."""
        run_id = uuid.uuid4().hex[:16]

        def write_files(directory: Path) -> None:
            states.to_parquet(directory / "states.parquet", index=False)
            diagnostics.to_parquet(directory / "diagnostics.parquet", index=False)
            (directory / "report.json").write_text(json.dumps(report, indent=2, default=str))

        def insert(db: sqlite3.Connection) -> None:
            db.execute("INSERT INTO runs VALUES (?, ?, ?, ?)",
                       (run_id, log_sha256, json.dumps(settings, sort_keys=True), _now_utc()))

        self._commit_entry("runs", run_id, write_files, insert)
        return run_id

    def list_runs(self, log_sha256: str | None = None) -> pd.DataFrame:
        """Stored runs (run_id, log_sha256, settings_json, created_utc), newest first, optionally for one log."""
        query = "SELECT * FROM runs" + (" WHERE log_sha256 = ?" if log_sha256 else "") + " ORDER BY rowid DESC"
        with closing(self._connect()) as db:
            return pd.read_sql_query(query, db, params=(log_sha256,) if log_sha256 else None)

    def list_calibrations(self, log_sha256: str | None = None) -> pd.DataFrame:
        """Stored calibrations (calib_id, log_sha256, settings_json, created_utc), newest first."""
        query = ("SELECT * FROM calibrations" + (" WHERE log_sha256 = ?" if log_sha256 else "")
                 + " ORDER BY rowid DESC")
        with closing(self._connect()) as db:
            return pd.read_sql_query(query, db, params=(log_sha256,) if log_sha256 else None)

    def load_run(self, run_id: str) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
        """States, diagnostics and report of a stored run."""
        return self.load_run_table(run_id, "states"), self.load_run_table(run_id, "diagnostics"), \
            self.load_run_report(run_id)

    def run_table_path(self, run_id: str, table: str) -> Path:
        """Parquet file of a stored run's ``"states"`` or ``"diagnostics"`` table."""
        if table not in RUN_TABLES:
            raise ValueError(f"run table must be one of {RUN_TABLES}, got {table!r}")
        return self.root / "runs" / run_id / f"{table}.parquet"

    def load_run_table(self, run_id: str, table: str) -> pd.DataFrame:
        """One table of a stored run (a large diagnostics table need not be read to show the states)."""
        return pd.read_parquet(self.run_table_path(run_id, table))

    def load_run_report(self, run_id: str) -> dict:
        """The report of a stored run."""
        return json.loads((self.root / "runs" / run_id / "report.json").read_text())

    def calibration_path(self, calib_id: str) -> Path:
        """Path of a stored calibration JSON."""
        return self.root / "calibrations" / calib_id / "calib.json"
