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

Deleting an entry (:meth:`Workspace.delete`)
    Under a shared lock, in one catalog write transaction, the rows are deleted (a log's calibrations and runs with
    it) and each directory is moved to ``.staging/<kind>+<id>+<random>.deleting``; then the transaction commits and
    the moved directories are removed. If the commit fails, the directories are moved back before the transaction
    ends. A process dying before the commit leaves its rows listed (SQLite rolls back) and its directories in
    staging: :meth:`Workspace.recover` moves them back, inside a write transaction, for every row still listed;
    ``.deleting`` directories whose row is gone are removed. So a crash leaves an entry complete and listed, or gone.

Names
    Calibrations and runs have a readable ``name`` (default: log name, settings in short, time of day UTC),
    distinct among the entries of that kind of one log; :meth:`Workspace.rename` changes it (and a log's display
    name). Adding a calibration or run whose settings (canonical JSON) equal those of a stored entry of the same
    log stores nothing and returns that entry (:class:`Stored` with ``created=False``). Catalogs from before the
    names get the column (``ALTER TABLE``) and default names on open.

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
    calib_id TEXT PRIMARY KEY, log_sha256 TEXT NOT NULL, settings_json TEXT NOT NULL, created_utc TEXT NOT NULL,
    name TEXT);
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY, log_sha256 TEXT NOT NULL, settings_json TEXT NOT NULL, created_utc TEXT NOT NULL,
    name TEXT);
"""
_KINDS = {"logs": "sha256", "calibrations": "calib_id", "runs": "run_id"}
#: Suffix of the directories a deletion moved to staging (restored by recovery while their row is listed).
DELETING_SUFFIX = ".deleting"
#: Separator of the parts of a default name.
NAME_SEPARATOR = " \u00b7 "
#: Characters a name of a calibration or run may not hold (Markdown and HTML markup), replaced by spaces.
_MARKUP = re.compile(r"[<>\[\]`*_#|\\$~{}]")
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
#: How many estimators a run has by default (estimators.api.DEFAULT_ESTIMATORS): fewer are named in a run's name.
_DEFAULT_RUN_ESTIMATORS = 3

#: Where a long name may be cut (:func:`shorten`).
_WORD_SEPARATORS = " _-.\u00b7"

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
        Longest result [characters]; a name is cut at a word boundary (:func:`shorten`), a short extension kept.

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
    short = shorten(stem, room).rstrip(" .") if room > 0 else ""
    if not short:  # no room for the extension: cut the whole name (its first character is neither " " nor ".")
        return shorten(name, max(max_length - len(tag), 1)).rstrip(" .") + tag
    return short + tag + ext


def shorten(text: str, max_length: int) -> str:
    """``text`` cut to at most ``max_length`` characters at a word or separator boundary (before a space, ``_``,
    ``-``, ``.`` or ``·``), the separators the cut leaves at the end dropped; cut mid-word only when the last
    boundary would keep less than half of ``max_length`` (one long word)."""
    if len(text) <= max_length:
        return text
    boundaries = [k for k in range(1, max_length + 1) if text[k] in _WORD_SEPARATORS]
    if not boundaries or boundaries[-1] < max_length / 2:
        return text[:max_length]
    return text[:boundaries[-1]].rstrip(_WORD_SEPARATORS) or text[:max_length]


class NameRejected(ValueError):
    """A new name that is empty after sanitising or already taken."""


def sanitize_label(name: str, max_length: int = MAX_NAME_LENGTH) -> str:
    """A display-safe name of a calibration or run (Unicode kept: ``·``, ``τ``, ``+``, accents).

    NFKC-normalised; control, format, surrogate and private-use characters and Markdown/HTML markup characters
    become spaces; runs of white space become one space; cut to ``max_length`` at a word boundary (:func:`shorten`);
    stripped. May be empty.
    """
    text = unicodedata.normalize("NFKC", str(name))
    text = "".join(" " if unicodedata.category(ch)[0] == "C" or ch.isspace() else ch for ch in text)
    text = re.sub(r" +", " ", _MARKUP.sub(" ", text)).strip()
    return shorten(text, max_length).rstrip()


def canonical_json(settings: dict) -> str:
    """The identity of a settings dict: JSON with sorted keys and no spaces (lists keep their order)."""
    return json.dumps(settings, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=str)


def _number(value, digits: int = 2) -> str:
    try:
        return f"{float(value):.{digits}g}"
    except (TypeError, ValueError):
        return str(value)


def _time_of_day(created_utc: str) -> str:
    """``HH:MM`` of an ISO time stamp (the text itself when it is not one)."""
    try:
        return datetime.fromisoformat(created_utc).strftime("%H:%M")
    except (TypeError, ValueError):
        return str(created_utc)


def default_calibration_name(log_name: str, settings: dict, created_utc: str) -> str:
    """``paper.ulg · calib auto-τ 0.27 · 14:03`` (window, η noise and FIR count when set)."""
    method = settings.get("tau_method")
    tau = settings.get("tau")
    parts = ["calib"]
    if tau is not None:
        parts.append(f"{'auto-' if method in ('likelihood', 'nis') else ''}\u03c4 {_number(tau)}")
    window = settings.get("window_s")
    if isinstance(window, list | tuple) and len(window) == 2:
        parts.append(f"{_number(window[0], 4)}\u2013{_number(window[1], 4)} s")
    if settings.get("noise") not in (None, "sigma"):
        parts.append(str(settings["noise"]))
    summary = " ".join(parts)
    return _join_name(log_name, [summary], created_utc)


def noise_source(noise) -> str:
    """The noise source a run's ``noise`` setting names, short: ``datasheet``, ``calibrated`` (automatic
    calibration of the log) or ``calib 3f2a1b`` (a saved calibration, its id cut to 6 characters)."""
    if noise in (None, "", "default"):
        return "datasheet"
    return "calibrated" if noise == "calibrated" else f"calib {str(noise)[:6]}"


def default_run_name(log_name: str, settings: dict, created_utc: str) -> str:
    """``paper · calibrated · 14:05``: the log (without extension), the noise source and the time; a heading other
    than the magnetometer, fewer estimators than the default three, a rate other than 50 Hz and an untrusted replay
    are added when set (``paper · calib 3f2a1b · mag+sun · indirect · 25 Hz · untrusted · 14:05``)."""
    parts = [noise_source(settings.get("noise"))]
    if settings.get("heading") not in (None, "", "mag", "auto"):
        parts.append(str(settings["heading"]))
    estimators = list(settings.get("estimators", ()))
    if 0 < len(estimators) < _DEFAULT_RUN_ESTIMATORS:
        parts.append(", ".join(estimators) if len(estimators) == 1 else f"{len(estimators)} estimators")
    if settings.get("rate_hz") not in (None, 50, 50.0):
        parts.append(f"{_number(settings['rate_hz'], 3)} Hz")
    if settings.get("allow_untrusted"):
        parts.append("untrusted")
    stem, dot, _ = log_name.rpartition(".")
    return _join_name(stem if dot and stem else log_name, parts, created_utc)


def _join_name(log_name: str, parts: list[str], created_utc: str) -> str:
    """``log · parts · HH:MM``, the log name cut so that the whole fits (numbering needs a few characters)."""
    tail = NAME_SEPARATOR.join([*parts, _time_of_day(created_utc)])
    room = MAX_NAME_LENGTH - 6 - len(tail) - len(NAME_SEPARATOR)
    head = shorten(sanitize_label(log_name), max(room, 8)).rstrip()
    return sanitize_label(NAME_SEPARATOR.join([head, tail]) if head else tail, MAX_NAME_LENGTH - 6)


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


@dataclass(frozen=True)
class Stored:
    """The outcome of storing a calibration or run: its id and name, and whether it was new (False: an entry
    with the same settings was stored already, and nothing was written)."""

    id: str
    name: str
    created: bool

    def message(self, what: str) -> str:
        """``Saved calibration "name".`` or ``Already saved as "name".`` (for the UI)."""
        return f"Saved {what} \u201c{self.name}\u201d." if self.created else \
            f"Already saved as \u201c{self.name}\u201d."


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
        with closing(self._connect(autocommit=True)) as db:
            # write-ahead log: the sessions' reads never hold up a writer's commit (the mode persists; busy when
            # another process is switching it at this moment)
            with suppress(sqlite3.OperationalError):
                db.execute("PRAGMA journal_mode=WAL")
            if self._needs_migration(db):
                db.execute("BEGIN IMMEDIATE")
                try:
                    for statement in _SCHEMA.split(";"):
                        if statement.strip():
                            db.execute(statement)
                    _migrate(db)
                    db.execute("COMMIT")
                finally:
                    if db.in_transaction:
                        db.execute("ROLLBACK")
        self.recover()

    @staticmethod
    def _needs_migration(db: sqlite3.Connection) -> bool:
        """Whether a table or the name column is missing, or a row has no name (read without the write lock)."""
        for kind in ("calibrations", "runs"):
            columns = {row[1] for row in db.execute(f"PRAGMA table_info({kind})")}
            if "name" not in columns or db.execute(f"SELECT 1 FROM {kind} WHERE name IS NULL LIMIT 1").fetchone():
                return True
        return not db.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'logs'").fetchone()

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
                if path.name.endswith(DELETING_SUFFIX):  # restored or removed below, under the catalog lock
                    continue
                if alone or (fcntl is None and _age_s(path) > STALE_STAGING_S):
                    _remove(path)
        trash, removed = [], 0
        with closing(self._connect(autocommit=True)) as db:
            if not self._unlisted(db) and not self._deletions():  # the usual case, seen without the write lock
                return 0
            try:
                db.execute("BEGIN IMMEDIATE")  # no writer or deleter is between its move and its commit now
                for path in self._deletions():  # a deleter that died before its commit: its rows are still listed
                    kind, entry_id = path.name.split("+")[:2]
                    final = self.root / kind / entry_id
                    key = _KINDS[kind]
                    if (db.execute(f"SELECT 1 FROM {kind} WHERE {key} = ?", (entry_id,)).fetchone()
                            and not final.exists()):
                        os.replace(path, final)
                    else:
                        trash.append(path)
                for path in self._unlisted(db):
                    trash.append(staging / f"{uuid.uuid4().hex}.orphan")
                    os.replace(path, trash[-1])
                    removed += 1
                db.execute("COMMIT")
            except sqlite3.OperationalError:  # catalog busy for BUSY_TIMEOUT_S: leave it to a later open
                pass
            finally:
                if db.in_transaction:
                    db.execute("ROLLBACK")
        for path in trash:
            _remove(path)
        return removed

    def _deletions(self) -> list[Path]:
        """Directories deletions moved to staging (``<kind>+<id>+<random>.deleting``)."""
        return [path for path in (self.root / ".staging").glob(f"*+*+*{DELETING_SUFFIX}")
                if path.name.split("+")[0] in _KINDS and path.is_dir()]

    def _unlisted(self, db: sqlite3.Connection) -> list[Path]:
        """Entry directories the catalog does not list (rows read before the directories: a writer's entry that
        is committed meanwhile may show up; only the answer under the write lock is acted upon)."""
        listed = {kind: {row[0] for row in db.execute(f"SELECT {key} FROM {kind}")} for kind, key in _KINDS.items()}
        return [path for kind in _KINDS for path in (self.root / kind).iterdir()
                if path.name not in listed[kind] and path.is_dir()]

    def _commit_entry(self, kind: str, entry_id: str, write_files: Callable[[Path], None],
                      insert: Callable[[sqlite3.Connection], _T],
                      duplicate: Callable[[sqlite3.Connection], _T | None] | None = None) -> _T | None:
        """Store one entry (see module docstring).

        Parameters
        ----------
        kind, entry_id : str
            Catalog table (``"logs"``, ...) and the entry's id, its directory name.
        write_files : callable
            ``write_files(directory)`` writes the entry's files into an empty directory.
        insert : callable
            ``insert(db)`` inserts the catalog row in the open transaction (no commit); its result is returned.
        duplicate : callable, optional
            ``duplicate(db)``, in the transaction before anything moves: what to return instead of storing (an
            equal entry stored meanwhile), or None to go on.

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
                        if duplicate is not None and (found := duplicate(db)) is not None:
                            return found
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
        """Store a calibration file for a log; returns its id (that of a stored entry with the same settings, then:
        :meth:`store_calibration`)."""
        return self.store_calibration(log_sha256, settings, calibration_json).id

    def store_calibration(self, log_sha256: str, settings: dict, calibration_json: str) -> Stored:
        """Store a calibration file for a log under a default name, unless one with the same settings is stored."""
        def write_files(directory: Path) -> None:
            (directory / "calib.json").write_text(calibration_json)

        return self._store_settings("calibrations", log_sha256, settings, write_files, default_calibration_name)

    def add_run(self, log_sha256: str, settings: dict, states: pd.DataFrame, diagnostics: pd.DataFrame,
                report: dict) -> str:
        """Store an estimator run (states, diagnostics, report) for a log; returns its id (an equal-settings
        entry's id: :meth:`store_run`)."""
        return self.store_run(log_sha256, settings, states, diagnostics, report).id

    def store_run(self, log_sha256: str, settings: dict, states: pd.DataFrame, diagnostics: pd.DataFrame,
                  report: dict) -> Stored:
        """Store an estimator run under a default name, unless one with the same settings is stored."""
        def write_files(directory: Path) -> None:
            states.to_parquet(directory / "states.parquet", index=False)
            diagnostics.to_parquet(directory / "diagnostics.parquet", index=False)
            (directory / "report.json").write_text(json.dumps(report, indent=2, default=str))

        return self._store_settings("runs", log_sha256, settings, write_files, default_run_name)

    def _store_settings(self, kind: str, log_sha256: str, settings: dict, write_files: Callable[[Path], None],
                        default_name: Callable[[str, dict, str], str]) -> Stored:
        """Store a calibration or run (``kind``) unless the log has one with the same canonical settings."""
        key = _KINDS[kind]
        identity = canonical_json(settings)

        def duplicate(db: sqlite3.Connection) -> Stored | None:
            for entry_id, text, name in db.execute(
                    f"SELECT {key}, settings_json, name FROM {kind} WHERE log_sha256 = ? ORDER BY rowid DESC",
                    (log_sha256,)):
                with suppress(ValueError):
                    if canonical_json(json.loads(text)) == identity:
                        return Stored(entry_id, name or entry_id, False)
            return None

        with closing(self._connect()) as db:  # the usual duplicate: found before any file is written
            found = duplicate(db)
        if found is not None:
            return found
        entry_id = uuid.uuid4().hex[:16]

        def insert(db: sqlite3.Connection) -> Stored:
            created = _now_utc()
            name = _distinct_label(db, kind, log_sha256, default_name(_log_name(db, log_sha256), settings, created))
            db.execute(f"INSERT INTO {kind} ({key}, log_sha256, settings_json, created_utc, name) "
                       "VALUES (?, ?, ?, ?, ?)", (entry_id, log_sha256, json.dumps(settings, sort_keys=True),
                                                  created, name))
            return Stored(entry_id, name, True)

        return self._commit_entry(kind, entry_id, write_files, insert, duplicate)

    def entry_name(self, kind: str, entry_id: str) -> str | None:
        """The name of a stored calibration or run (a log's display name for ``"logs"``), or None."""
        column = "display_name" if kind == "logs" else "name"
        with closing(self._connect()) as db:
            row = db.execute(f"SELECT {column} FROM {kind} WHERE {_KINDS[kind]} = ?", (entry_id,)).fetchone()
        return None if row is None else row[0]

    # ---------------------------------------------------------------- rename and delete
    def rename(self, kind: str, entry_id: str, name: str) -> str:
        """Rename a log (its display name), calibration or run; returns the name stored.

        Log names are sanitised as uploaded file names (:func:`sanitize_name`, they may become a download's file
        name), those of calibrations and runs by :func:`sanitize_label`.

        Raises
        ------
        NameRejected
            The name is empty once sanitised, or another entry of the same kind (of the same log, for
            calibrations and runs) has it.
        KeyError
            No such entry.
        """
        key = _KINDS[kind]
        if kind == "logs":
            column = "display_name"
            clean = sanitize_name(name)
            if clean == "unnamed" != sanitize_label(name).lower():  # sanitize_name's stand-in for nothing left
                raise NameRejected("a name cannot be empty")
        else:
            column, clean = "name", sanitize_label(name)
            if not clean:
                raise NameRejected("a name cannot be empty")
        with closing(self._connect(autocommit=True)) as db:
            db.execute("BEGIN IMMEDIATE")
            try:
                row = db.execute(f"SELECT {'sha256' if kind == 'logs' else 'log_sha256'} FROM {kind} "
                                 f"WHERE {key} = ?", (entry_id,)).fetchone()
                if row is None:
                    raise KeyError(f"no {kind[:-1]} {entry_id}")
                scope = "" if kind == "logs" else " AND log_sha256 = ?"
                params = (clean, entry_id) if kind == "logs" else (clean, entry_id, row[0])
                if db.execute(f"SELECT 1 FROM {kind} WHERE {column} = ? AND {key} != ?{scope}", params).fetchone():
                    raise NameRejected(f"the name \u201c{clean}\u201d is taken")
                old_name = _log_name(db, entry_id) if kind == "logs" else None
                db.execute(f"UPDATE {kind} SET {column} = ? WHERE {key} = ?", (clean, entry_id))
                if old_name is not None:
                    _rename_default_labels(db, entry_id, old_name, clean)
                db.execute("COMMIT")
            finally:
                if db.in_transaction:
                    db.execute("ROLLBACK")
        return clean

    def delete(self, kind: str, entry_id: str) -> int:
        """Delete a log (with its calibrations and runs), a calibration or a run: rows and files together.

        Returns
        -------
        int
            Number of entries deleted (0 when ``entry_id`` is not listed).
        """
        key = _KINDS[kind]
        staging = self.root / ".staging"
        moved: list[tuple[Path, Path]] = []
        with self._lock(exclusive=False), closing(self._connect(autocommit=True)) as db:
            db.execute("BEGIN IMMEDIATE")
            try:
                victims = [(kind, entry_id)] if db.execute(
                    f"SELECT 1 FROM {kind} WHERE {key} = ?", (entry_id,)).fetchone() else []
                if victims and kind == "logs":
                    victims += [(sub, row[0]) for sub in ("calibrations", "runs") for row in db.execute(
                        f"SELECT {_KINDS[sub]} FROM {sub} WHERE log_sha256 = ?", (entry_id,))]
                for sub, sub_id in victims:
                    db.execute(f"DELETE FROM {sub} WHERE {_KINDS[sub]} = ?", (sub_id,))
                    final = self.root / sub / sub_id
                    if final.exists():
                        trash = staging / f"{sub}+{sub_id}+{uuid.uuid4().hex}{DELETING_SUFFIX}"
                        os.replace(final, trash)
                        moved.append((final, trash))
                if moved:
                    _fsync_directory(staging)
                db.execute("COMMIT")
            except BaseException:
                if db.in_transaction:  # still listed: put the files back before anyone can look
                    for final, trash in reversed(moved):
                        os.replace(trash, final)
                raise
            finally:
                if db.in_transaction:
                    db.execute("ROLLBACK")
        for _, trash in moved:
            _remove(trash)
        return len(victims)

    def list_runs(self, log_sha256: str | None = None) -> pd.DataFrame:
        """Stored runs (run_id, log_sha256, settings_json, created_utc, name), newest first, optionally for one
        log."""
        query = "SELECT * FROM runs" + (" WHERE log_sha256 = ?" if log_sha256 else "") + " ORDER BY rowid DESC"
        import pandas as pd

        with closing(self._connect()) as db:
            return pd.read_sql_query(query, db, params=(log_sha256,) if log_sha256 else None)

    def list_calibrations(self, log_sha256: str | None = None) -> pd.DataFrame:
        """Stored calibrations (calib_id, log_sha256, settings_json, created_utc, name), newest first."""
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


def _log_name(db: sqlite3.Connection, sha256: str) -> str:
    row = db.execute("SELECT display_name FROM logs WHERE sha256 = ?", (sha256,)).fetchone()
    return row[0] if row else sha256[:12]


def _distinct_label(db: sqlite3.Connection, kind: str, log_sha256: str, name: str,
                    exclude: str | None = None) -> str:
    """``name``, or ``name (2)``, ...: the first no other calibration or run (``kind``) of the log has."""
    taken = {row[0] for row in db.execute(f"SELECT name FROM {kind} WHERE log_sha256 = ? AND {_KINDS[kind]} != ?",
                                          (log_sha256, exclude or ""))}
    candidate, number = name, 1
    while candidate in taken:
        number += 1
        candidate = f"{name} ({number})"
    return candidate


def _rename_default_labels(db: sqlite3.Connection, log_sha256: str, old_log_name: str, new_log_name: str) -> None:
    """In the open write transaction: the calibrations and runs of a renamed log that still carry their default
    name (numbered or not) take the default name with the log's new name; names a user gave stay."""
    for kind, default_name in (("calibrations", default_calibration_name), ("runs", default_run_name)):
        key = _KINDS[kind]
        rows = db.execute(f"SELECT {key}, settings_json, created_utc, name FROM {kind} WHERE log_sha256 = ? "
                          "ORDER BY rowid", (log_sha256,)).fetchall()
        for entry_id, text, created, name in rows:
            settings = json.loads(text)
            old_default = default_name(old_log_name, settings, created)
            if name == old_default or re.fullmatch(re.escape(old_default) + r" \(\d+\)", name or ""):
                new_name = _distinct_label(db, kind, log_sha256, default_name(new_log_name, settings, created),
                                           exclude=entry_id)
                db.execute(f"UPDATE {kind} SET name = ? WHERE {key} = ?", (new_name, entry_id))


def _migrate(db: sqlite3.Connection) -> None:
    """In the open write transaction: add the ``name`` column where missing and name the unnamed rows."""
    for kind, default_name in (("calibrations", default_calibration_name), ("runs", default_run_name)):
        key = _KINDS[kind]
        if "name" not in {row[1] for row in db.execute(f"PRAGMA table_info({kind})")}:
            db.execute(f"ALTER TABLE {kind} ADD COLUMN name TEXT")
        rows = db.execute(f"SELECT {key}, log_sha256, settings_json, created_utc FROM {kind} WHERE name IS NULL "
                          "ORDER BY rowid").fetchall()
        for entry_id, log_sha256, text, created in rows:
            try:
                settings = json.loads(text)
            except ValueError:
                settings = {}
            settings = settings if isinstance(settings, dict) else {}
            name = _distinct_label(db, kind, log_sha256, default_name(_log_name(db, log_sha256), settings, created),
                                   exclude=entry_id)
            db.execute(f"UPDATE {kind} SET name = ? WHERE {key} = ?", (name, entry_id))


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
