"""Persistent workspace: uploaded logs stored under their content hash, calibrations and estimator runs as files,
and a SQLite catalog that lists only complete entries.

Layout under the workspace root::

    catalog.sqlite                   (write-ahead log: catalog.sqlite-wal, -shm)
    workspace.lock                   writers hold it shared, the staging clean-up exclusive (fcntl.flock)
    logs/<sha256>/log.ulg            the uploaded ULog, byte for byte
    logs/<sha256>/sun.csv            optional sun-device log (and device.json)
    calibrations/<id>/calib.json
    runs/<id>/states.parquet, diagnostics.parquet, report.json
    .staging/                        work in progress and debris

Several dashboard sessions (threads) and processes (a second server, a batch) may use one workspace at once.

Writing an entry
    1. Under a *shared* lock on ``workspace.lock``, the files are written and fsync'ed in ``.staging/<random>/``.
    2. In one catalog write transaction (``BEGIN IMMEDIATE``, which serialises the writers of every process) the
       directory is moved into place with one ``os.replace`` and the catalog row inserted, then committed. If the
       insert or the commit fails, the directory is moved back out before the transaction ends, so the failed store
       leaves nothing behind and can be retried at once.

Recovery (on every open, :meth:`Workspace.recover`)
    * Entry directories the catalog does not list are removed *inside a catalog write transaction*: no writer can
      be between its move and its commit then, so an unlisted directory is the remains of a crashed writer, never
      another writer's entry in flight.
    * ``.staging`` is emptied only when the *exclusive* lock on ``workspace.lock`` is free at once, i.e. when no
      writer of any process is writing; otherwise it is left for a later open (an open never waits for an upload).
    A process that dies releases its locks (the kernel drops them), and SQLite rolls back its open transaction.

A crash before the move leaves only staging debris; a crash between the move and the commit leaves an unlisted
directory that the next open, or the next store of the same entry, removes. The catalog never lists a half-written
entry, and an entry a store reported as stored is never removed.

User-supplied file names are only ever stored as catalog text (sanitised for display, distinct among the logs);
paths are built from hashes and generated ids.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import sqlite3
import time
import unicodedata
import uuid
from collections.abc import Callable, Iterator
from contextlib import closing, contextmanager, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:  # pandas is imported where tables are read: opening and storing logs stays light for a batch
    import pandas as pd

try:
    import fcntl
except ImportError:  # Windows: no flock; staging debris is then removed by age
    fcntl = None

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
#: Lock file: shared by writers while they stage, exclusive for the staging clean-up.
LOCK_NAME = "workspace.lock"
#: How long [s] a connection waits for another process's catalog transaction.
BUSY_TIMEOUT_S = 30.0
#: Without flock (Windows), staging directories older than this [s] count as debris.
STALE_STAGING_S = 24 * 3600.0
#: Longest display name [characters].
MAX_NAME_LENGTH = 80

_T = TypeVar("_T")
#: Device names Windows reserves whatever the extension (a display name may become a download's file name).
_RESERVED = re.compile(r"(CON|PRN|AUX|NUL|COM[0-9]|LPT[0-9]) *(\..*)?", re.IGNORECASE)


def sanitize_name(name: str, max_length: int = MAX_NAME_LENGTH) -> str:
    """A display-safe version of a user-supplied file name.

    Parameters
    ----------
    name : str
        The name as uploaded (may hold a path, NUL, control or non-ASCII characters).
    max_length : int
        Longest result [characters]; a short extension is kept when the name is cut.

    Returns
    -------
    str
        The last path component, accents dropped (NFKD), restricted to letters, digits, ``._-`` and spaces (others
        become ``_``), without leading or trailing dots and spaces, ``_``-prefixed when it is a Windows device name
        (``CON``, ``NUL.ulg``, ...), never empty (``"unnamed"``).
    """
    # normalise first, so full-width slashes and dots split and strip like ASCII ones
    text = "".join(ch for ch in unicodedata.normalize("NFKD", str(name)) if not unicodedata.combining(ch))
    base = re.split(r"[\\/]", text)[-1]
    cleaned = re.sub(r"[^A-Za-z0-9._\- ]", "_", base).strip(" .")
    if not cleaned:
        return "unnamed"[:max_length]
    fitted = _fit(cleaned, "", max_length)
    return _fit(f"_{cleaned}", "", max_length) if _RESERVED.fullmatch(fitted) else fitted


def _fit(name: str, tag: str, max_length: int) -> str:
    """``name`` with ``tag`` before its extension, the stem cut so that the whole is at most ``max_length``."""
    stem, dot, ext = name.rpartition(".")
    if not dot or not stem or len(ext) > 16:
        stem, ext = name, ""
    else:
        ext = f".{ext}"
    room = max_length - len(tag) - len(ext)
    short = stem[:room].rstrip(" .") if room > 0 else ""
    if not short:  # no room for the extension: cut the whole name (its first character is neither " " nor ".")
        return name[:max(max_length - len(tag), 1)].rstrip(" .") + tag
    return short + tag + ext


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
    """A workspace directory with its catalog (see module docstring); safe to share between threads and processes.

    Parameters
    ----------
    root : str or Path
        Workspace directory; created when missing. Opening it runs :meth:`recover`.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        for sub in ("logs", "calibrations", "runs", ".staging"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)
        self.catalog_path = self.root / "catalog.sqlite"
        with closing(self._connect()) as db, db:
            # write-ahead log: the sessions' reads never hold up a writer's commit (the mode persists; busy when
            # another process is switching it at this moment)
            with suppress(sqlite3.OperationalError):
                db.execute("PRAGMA journal_mode=WAL")
            db.executescript(_SCHEMA)
        self.recover()

    def _connect(self, autocommit: bool = False) -> sqlite3.Connection:
        return sqlite3.connect(self.catalog_path, timeout=BUSY_TIMEOUT_S,
                               **({"isolation_level": None} if autocommit else {}))

    # ---------------------------------------------------------------- locking and recovery
    @contextmanager
    def _lock(self, exclusive: bool) -> Iterator[bool]:
        """Hold ``workspace.lock`` shared (waiting) or exclusive (only if free at once); yields whether it is held.

        Each call opens its own descriptor: flock locks belong to it, so threads of one process exclude each
        other as processes do, and closing it (or the process dying) releases the lock.
        """
        if fcntl is None:
            yield not exclusive
            return
        fd = os.open(self.root / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB if exclusive else fcntl.LOCK_SH)
            except BlockingIOError:
                yield False
                return
            yield True
        finally:
            os.close(fd)

    def recover(self) -> int:
        """Remove what interrupted writes left behind, never another writer's entry in flight.

        Returns
        -------
        int
            Number of unlisted entry directories removed (staging debris not counted).
        """
        staging = self.root / ".staging"
        with self._lock(exclusive=True) as alone:
            for path in list(staging.iterdir()):
                if alone or (fcntl is None and _age_s(path) > STALE_STAGING_S):
                    _remove(path)
        trash = []
        with closing(self._connect(autocommit=True)) as db:
            if not self._unlisted(db):  # the usual case, seen without taking the catalog's write lock
                return 0
            try:
                db.execute("BEGIN IMMEDIATE")  # no writer is between its move and its commit while we hold this
                for path in self._unlisted(db):
                    trash.append(staging / f"{uuid.uuid4().hex}.orphan")
                    os.replace(path, trash[-1])
                db.execute("COMMIT")
            except sqlite3.OperationalError:  # catalog busy for BUSY_TIMEOUT_S: leave it to a later open
                pass
        for path in trash:
            _remove(path)
        return len(trash)

    def _unlisted(self, db: sqlite3.Connection) -> list[Path]:
        """Entry directories the catalog does not list (rows read before the directories: a writer's entry that
        is committed meanwhile may show up; only the answer under the write lock is acted upon)."""
        listed = {kind: {row[0] for row in db.execute(f"SELECT {key} FROM {kind}")} for kind, key in _KINDS.items()}
        return [path for kind in _KINDS for path in (self.root / kind).iterdir()
                if path.name not in listed[kind] and path.is_dir()]

    def _commit_entry(self, kind: str, entry_id: str, write_files: Callable[[Path], None],
                      insert: Callable[[sqlite3.Connection], _T]) -> _T | None:
        """Store one entry (see module docstring).

        Parameters
        ----------
        kind, entry_id : str
            Catalog table (``"logs"``, ...) and the entry's id, its directory name.
        write_files : callable
            ``write_files(directory)`` writes the entry's files into an empty directory.
        insert : callable
            ``insert(db)`` inserts the catalog row in the open transaction (no commit); its result is returned.

        Returns
        -------
        object or None
            What ``insert`` returned, or None when the catalog already listed ``entry_id`` (nothing changed).
        """
        final = self.root / kind / entry_id
        staging = self.root / ".staging" / uuid.uuid4().hex
        orphan = staging.with_name(f"{staging.name}.orphan")
        with self._lock(exclusive=False):
            try:
                staging.mkdir(parents=True)
                write_files(staging)
                _fsync_tree(staging)
                with closing(self._connect(autocommit=True)) as db:
                    db.execute("BEGIN IMMEDIATE")
                    moved = False
                    try:
                        key = _KINDS[kind]
                        if db.execute(f"SELECT 1 FROM {kind} WHERE {key} = ?", (entry_id,)).fetchone():
                            return None  # stored meanwhile by another writer (same content)
                        if final.exists():  # a crashed writer's remains: no writer is in flight now
                            os.replace(final, orphan)
                        os.replace(staging, final)
                        moved = True
                        _fsync_directory(final.parent)
                        result = insert(db)
                        db.execute("COMMIT")
                        return result
                    except BaseException:
                        if moved:  # still inside the transaction: nobody saw it, and a retry finds the id free
                            os.replace(final, staging)
                        raise
                    finally:
                        if db.in_transaction:
                            db.execute("ROLLBACK")
            finally:
                _remove(staging)
                _remove(orphan)

    # ---------------------------------------------------------------- logs
    def add_log(self, content: bytes, name: str, sun_csv: bytes | None = None,
                device_json: bytes | None = None) -> LogEntry:
        """Store an uploaded ULog (and optional sun-device CSV / device JSON); returns its entry.

        Adding the same content again returns the existing entry (the hash is the identity). A different log whose
        name sanitises to one already listed gets a numbered display name (``flight (2).ulg``).
        """
        sha256 = hashlib.sha256(content).hexdigest()
        existing = self.get_log(sha256)
        if existing is not None:
            return existing

        def write_files(directory: Path) -> None:
            (directory / "log.ulg").write_bytes(content)
            if sun_csv is not None:
                (directory / "sun.csv").write_bytes(sun_csv)
            if device_json is not None:
                (directory / "device.json").write_bytes(device_json)

        def insert(db: sqlite3.Connection) -> LogEntry:
            entry = LogEntry(sha256, _distinct_name(db, sanitize_name(name)), len(content), _now_utc(),
                             sun_csv is not None)
            db.execute("INSERT INTO logs VALUES (?, ?, ?, ?, ?)",
                       (entry.sha256, entry.display_name, entry.size_bytes, entry.added_utc, int(entry.has_sun)))
            return entry

        stored = self._commit_entry("logs", sha256, write_files, insert)
        return stored if stored is not None else self.get_log(sha256)

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
        import pandas as pd

        with closing(self._connect()) as db:
            return pd.read_sql_query(query, db, params=(log_sha256,) if log_sha256 else None)

    def list_calibrations(self, log_sha256: str | None = None) -> pd.DataFrame:
        """Stored calibrations (calib_id, log_sha256, settings_json, created_utc), newest first."""
        query = ("SELECT * FROM calibrations" + (" WHERE log_sha256 = ?" if log_sha256 else "")
                 + " ORDER BY rowid DESC")
        import pandas as pd

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
        import pandas as pd

        return pd.read_parquet(self.run_table_path(run_id, table))

    def load_run_report(self, run_id: str) -> dict:
        """The report of a stored run."""
        return json.loads((self.root / "runs" / run_id / "report.json").read_text())

    def calibration_path(self, calib_id: str) -> Path:
        """Path of a stored calibration JSON."""
        return self.root / "calibrations" / calib_id / "calib.json"


def _distinct_name(db: sqlite3.Connection, name: str) -> str:
    """``name``, or ``name (2)``, ``name (3)``, ... (before the extension): the first no listed log has."""
    taken = {row[0] for row in db.execute("SELECT display_name FROM logs")}
    candidate, number = name, 1
    while candidate in taken:
        number += 1
        candidate = _fit(name, f" ({number})", MAX_NAME_LENGTH)
    return candidate


def _age_s(path: Path) -> float:
    """Time [s] since ``path`` was last modified (0 when it is gone)."""
    try:
        return time.time() - path.stat().st_mtime
    except FileNotFoundError:
        return 0.0


def _remove(path: Path) -> None:
    """Remove a file or directory tree if it exists."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _fsync_tree(directory: Path) -> None:
    """Flush the files of a staged entry and the directory itself, so that the move publishes complete files."""
    for path in directory.iterdir():
        if path.is_file():
            fd = os.open(path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    _fsync_directory(directory)


def _fsync_directory(directory: Path) -> None:
    """Persist renames in ``directory`` (POSIX); a no-op where directories cannot be opened (Windows) or synced."""
    if not hasattr(os, "O_DIRECTORY"):
        return
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    except OSError:  # e.g. EINVAL on file systems that cannot sync a directory: the store must not fail for it
        pass
    finally:
        os.close(fd)
