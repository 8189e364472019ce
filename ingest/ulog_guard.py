"""pyulog under guard: parse an untrusted ULog file in bounded time and memory, or raise :class:`InputError`.

pyulog trusts the file in ways a damaged one exploits (docs/robustness.md, 'ULog reader guard'):

* its recovery from a corrupt message header can seek back before the data it has read and repeat forever;
* it flattens every subscribed format recursively, so a self-referential format recurses without end and nested
  arrays multiply out to millions of fields (hang, ``MemoryError`` or a crash inside ``np.dtype``);
* a format without its ``uint64 timestamp`` field, or one short message, raises ``struct.error``, which pyulog
  takes for the end of the file: everything after it is silently dropped.

:func:`parse_ulog` runs pyulog in-process on a :class:`BudgetedStream` (loops detected; seeks, rewinds and, once
those exceed a clean log's, reads counted against budgets proportional to the file size) with
:class:`GuardedULog`, a pyulog subclass that checks each subscribed format before pyulog flattens it (topics not
asked for are never flattened), turns a short message into the corruption pyulog already skips, and ignores flag
bits that are not the first message. What it works around is returned as warnings; a file that cannot be read
gives an :class:`~ingest.errors.InputError`.
"""

from __future__ import annotations

import contextlib
import io
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from pyulog import ULog
from pyulog.exceptions import ULogException

from ingest.errors import InputError

#: Seeks allowed per byte of file, plus a fixed allowance. pyulog re-reads data only after a seek (a clean log
#: needs a handful); each step of its byte-by-byte recovery through a damaged stretch is one seek and two reads
#: (~3.5 us), so damaged stretches up to an eighth of the file can be stepped through.
SEEKS_PER_BYTE = 1 / 8
SEEKS_FIXED = 50_000
#: Bytes seeks may move back in total per byte of file, plus a fixed allowance [bytes] (bounds the copying).
REWIND_PER_BYTE = 32
REWIND_FIXED = 256 * 1024 * 1024
#: The same backward seek (from, to) more often than this is a loop: pyulog's parse is determined by the file
#: position, up to 4 data passes (appended data) x 2 states of its sync search.
MAX_SEEK_REPEATS = 8
#: Past this many seeks or bytes rewound [bytes] (a clean log: < 10 seeks, < 64 KiB) reads are counted too:
#: each read is about one message parsed, so their number bounds the time.
COUNT_READS_AFTER_SEEKS = 64
COUNT_READS_AFTER_REWIND = 1 << 20
#: Reads allowed once counted, per byte of file plus a fixed allowance (a clean log needs 0.04 per byte in all;
#: 2-7 us each).
READS_PER_BYTE = 1 / 4
READS_FIXED = 100_000
#: ULog file header: magic, version, start timestamp [bytes].
FILE_HEADER_BYTES = 16
#: Largest payload of one ULog data message: uint16 size minus the uint16 msg_id [bytes]; a format needing more
#: can never be logged.
MAX_DATA_BYTES = 0xFFFF - 2
#: Deepest nesting of formats accepted (PX4 nests at most 2-3 levels).
MAX_FORMAT_DEPTH = 16
#: Flattening steps (fields and nested elements) pyulog may take over all subscriptions (real logs: < 1000 for
#: the topics read; 131072 cost ~1 s).
MAX_TOTAL_STEPS = 131_072
#: pyulog's basic field types and their sizes [bytes].
BASIC_TYPE_BYTES = {name: spec[1] for name, spec in ULog._UNPACK_TYPES.items()}
#: pyulog's private hooks the guard overrides or uses; a pyulog release that renames one must fail loudly (a test
#: checks they exist).
PYULOG_HOOKS = ("_MessageAddLogged", "_MessageData", "_MessageInfo", "_MessageParameterDefault", "_MessageFlagBits",
                "MessageLogging", "MessageLoggingTagged", "MessageDropout", "_read_file_definitions", "_load_file",
                "_message_formats", "_compat_flags", "_incompat_flags", "_appended_offsets", "_file_corrupt",
                # and those ingest.ulog_fast.FastULog uses for its data passes
                "_read_file_data", "_MessageHeader", "_subscriptions", "_filtered_message_ids", "_last_timestamp",
                "_sync_seq_cnt", "_msg_info_dict_types", "_add_message_info_multiple", "_add_parameter_default",
                "_changed_parameters", "_logged_messages", "_logged_messages_tagged", "_dropouts", "_data_list")


class _BudgetExceeded(Exception):
    """pyulog read more than the budget allows (not a pyulog-caught type, so it ends the parse)."""


class BudgetedStream(io.BytesIO):
    """In-memory file for pyulog that stops a parse going in circles or re-reading far more than the file.

    Without a seek pyulog only moves forward, so every loop or re-read passes through :meth:`seek`: seeks and
    the bytes they move back are counted, a backward seek repeated more than ``MAX_SEEK_REPEATS`` times is a
    loop, and once seeking exceeds what a clean log needs, reads are counted as well (before that they stay
    BytesIO's own, at full speed).

    Parameters
    ----------
    content : bytes
        The file.

    Attributes
    ----------
    content : bytes
        The file itself, for a reader that indexes it directly (:class:`ingest.ulog_fast.FastULog`).
    seeks, rewound, reads : int
        Used so far (reads: counted ones).
    closed_at : int or None
        Offset when pyulog closed the stream [bytes]: the file's length after a full parse, less where pyulog
        stopped early; None before.
    """

    def __init__(self, content: bytes):
        super().__init__(content)
        self.content = content
        n_bytes = len(content)
        self.max_seeks = int(SEEKS_PER_BYTE * n_bytes) + SEEKS_FIXED
        self.max_rewind = REWIND_PER_BYTE * n_bytes + REWIND_FIXED
        self.max_reads = int(READS_PER_BYTE * n_bytes) + READS_FIXED
        self.seeks = self.rewound = self.reads = 0
        self.closed_at: int | None = None
        self._backward: dict[tuple[int, int], int] = {}

    def seek(self, offset: int, whence: int = 0) -> int:
        before = self.tell()
        after = super().seek(offset, whence)
        self.seeks += 1
        if after < before:
            self.rewound += before - after
            repeats = self._backward[before, after] = self._backward.get((before, after), 0) + 1
            if repeats > MAX_SEEK_REPEATS:
                raise _BudgetExceeded(f"it goes in circles, seeking back from byte {before} to {after} again and "
                                      "again")
        if self.seeks > self.max_seeks or self.rewound > self.max_rewind:
            raise _BudgetExceeded(f"its recovery re-reads too much: {self.seeks} seeks back over {self.rewound} "
                                  "bytes")
        if "read" not in self.__dict__ and (self.seeks > COUNT_READS_AFTER_SEEKS
                                            or self.rewound > COUNT_READS_AFTER_REWIND):
            self.read = self._counted_read  # an instance attribute shadows BytesIO.read for pyulog
        return after

    def _counted_read(self, size: int | None = -1) -> bytes:
        self.reads += 1
        if self.reads > self.max_reads:
            raise _BudgetExceeded(f"its recovery re-reads too much: {self.reads} reads after {self.seeks} seeks")
        return io.BytesIO.read(self, size)

    def close(self) -> None:
        if not self.closed:
            self.closed_at = self.tell()
        super().close()


@dataclass
class FormatGuard:
    """Checks the formats pyulog is about to flatten and records the subscriptions dropped.

    Parameters
    ----------
    topics : iterable of str
        Topics the caller reads; others are never flattened (pyulog would flatten and then discard them).
    max_total_steps : int
        Flattening steps (fields and nested elements) allowed over all subscriptions.

    Attributes
    ----------
    dropped : dict
        Topic -> (why, number of subscriptions dropped).
    """

    topics: Iterable[str]
    max_total_steps: int = MAX_TOTAL_STEPS
    dropped: dict[str, tuple[str, int]] = field(default_factory=dict)
    total_steps: int = 0
    _flat: dict[str, tuple[int, int] | str] = field(default_factory=dict)

    def __post_init__(self):
        self.topics = frozenset(self.topics)

    def admit(self, topic: str, formats: dict) -> bool:
        """Whether pyulog may subscribe ``topic``; a rejected topic the caller reads is recorded in ``dropped``."""
        if topic not in self.topics:
            return False
        problem = self._topic_problem(topic, formats)
        if problem is None:
            return True
        why, count = self.dropped.get(topic, (problem, 0))
        self.dropped[topic] = (why, count + 1)
        return False

    def warnings(self) -> list[str]:
        """One warning per dropped topic."""
        return [f"{topic}: topic dropped, its format definition is unusable ({why})"
                + (f"; {count} subscriptions" if count > 1 else "") for topic, (why, count) in self.dropped.items()]

    def _topic_problem(self, topic: str, formats: dict) -> str | None:
        flat = self._flatten(topic, formats, 0)
        if isinstance(flat, str):
            return flat
        n_steps, n_bytes = flat
        if n_bytes > MAX_DATA_BYTES:
            return f"more than {MAX_DATA_BYTES} bytes per sample, more than a ULog message can hold"
        if ("uint64_t", 0, "timestamp") not in formats[topic].fields:
            return "no uint64_t timestamp field"
        if self.total_steps + n_steps > self.max_total_steps:
            return f"more than {self.max_total_steps} fields and nested elements over all topics"
        self.total_steps += n_steps
        return None

    def _flatten(self, name: str, formats: dict, depth: int) -> tuple[int, int] | str:
        """``(steps, bytes)`` of format ``name`` flattened as pyulog does, or what is wrong; steps count the
        fields and the nested elements pyulog expands (an empty nested type costs a step but adds no field).

        Results are kept per format (the cost is one pass over the definitions); a format met again while it is
        being flattened is a cycle. Recursion stops at ``MAX_FORMAT_DEPTH``; that failure depends on the path,
        so it is not kept.
        """
        known = self._flat.get(name)
        if known is not None:
            return known
        message_format = formats.get(name)
        if message_format is None:
            return f"type {name!r} is not defined"
        if depth >= MAX_FORMAT_DEPTH:
            return _TooDeep(f"formats nested deeper than {MAX_FORMAT_DEPTH} levels")
        self._flat[name] = f"format {name!r} contains itself"  # what a second visit on this path finds
        n_steps = n_bytes = 0
        seen = set()
        result: tuple[int, int] | str | None = None
        for type_name, array_size, field_name in message_format.fields:
            if field_name in seen:
                result = f"field {field_name!r} defined twice in {name!r}"
                break
            seen.add(field_name)
            count = max(array_size, 1)  # pyulog: size 0 is a scalar
            if type_name in BASIC_TYPE_BYTES:
                n_steps, n_bytes = n_steps + count, n_bytes + count * BASIC_TYPE_BYTES[type_name]
            else:
                inner = self._flatten(type_name, formats, depth + 1)
                if isinstance(inner, str):
                    result = inner
                    break
                n_steps, n_bytes = n_steps + count * (1 + inner[0]), n_bytes + count * inner[1]
            if n_bytes > MAX_DATA_BYTES or n_steps > self.max_total_steps:  # stop before the counts grow on
                break
        if isinstance(result, _TooDeep):
            del self._flat[name]
            return result
        self._flat[name] = result if result is not None else (n_steps, n_bytes)
        return self._flat[name]


class _TooDeep(str):
    """A nesting-depth failure (depends on the path to the format, so never kept)."""


class _CheckedFormats(dict):
    """pyulog's ``message_formats`` carrying the :class:`FormatGuard` to the subscriptions built from it."""

    guard: FormatGuard


def _struct_error_is_corruption(cls: type) -> type:
    """``cls`` whose constructor raises ``ValueError`` for a short message: pyulog skips it as corruption
    instead of reading the ``struct.error`` as the end of the file."""

    class Guarded(cls):
        def __init__(self, *args, **kwargs):
            try:
                super().__init__(*args, **kwargs)
            except struct.error as exc:
                raise ValueError(f"message too short ({exc})") from exc

    Guarded.__name__ = Guarded.__qualname__ = f"Guarded{cls.__name__}"
    return Guarded


class _GuardedAddLogged(_struct_error_is_corruption(ULog._MessageAddLogged)):
    """A subscription flattened only for an admitted topic; any other becomes an empty one with a name outside
    the filter list, so pyulog files its msg_id as filtered and skips its data silently."""

    def __init__(self, data, header, message_formats):
        guard = getattr(message_formats, "guard", None)
        if len(data) < 3:
            raise ValueError("add_logged message too short")
        name = ULog.parse_string(data[3:])
        if guard is None or guard.admit(name, message_formats):
            super().__init__(data, header, message_formats)
            return
        self.multi_id, self.msg_id = data[0], int.from_bytes(data[1:3], "little")
        self.message_name = "\0" + name  # not a topic name: never in the filter list
        self.field_data, self.timestamp_idx, self.max_data_size, self.timestamp_offset = [], -1, 0, 0
        self.buffer, self.dtype = bytearray(), np.dtype([])


class _GuardedMessageData(ULog._MessageData):
    """Data message whose short payload is corruption, not the end of the file."""

    def initialize(self, data, header, subscriptions, ulog_object) -> bool:
        try:
            return super().initialize(data, header, subscriptions, ulog_object)
        except struct.error as exc:
            raise ValueError(f"data message too short ({exc})") from exc


class GuardedULog(ULog):
    """pyulog's :class:`~pyulog.core.ULog` with the checks of :class:`FormatGuard` and short messages taken as
    corruption (the parse itself is pyulog's).

    Parameters
    ----------
    log_file : file object
        Usually a :class:`BudgetedStream`.
    guard : FormatGuard
        Decides which topics are subscribed (its ``topics`` is also the message filter list).
    """

    _MessageAddLogged = _GuardedAddLogged
    _MessageData = _GuardedMessageData
    _MessageInfo = _struct_error_is_corruption(ULog._MessageInfo)
    _MessageParameterDefault = _struct_error_is_corruption(ULog._MessageParameterDefault)
    MessageLogging = _struct_error_is_corruption(ULog.MessageLogging)
    MessageLoggingTagged = _struct_error_is_corruption(ULog.MessageLoggingTagged)
    MessageDropout = _struct_error_is_corruption(ULog.MessageDropout)

    def __init__(self, log_file, guard: FormatGuard):
        self._guard = guard
        super().__init__(log_file, message_name_filter_list=sorted(guard.topics))

    def _MessageFlagBits(self, data, header):  # pyulog's name; a method here, so it sees the file offset
        """Flag bits; ones that are not the file's first message are corruption and keep the flags read so far
        (pyulog would act on them, e.g. refuse the whole file for a random "incompatible" bit)."""
        flag_bits = ULog._MessageFlagBits(data, header)
        if self._file_handle.tell() != FILE_HEADER_BYTES + 3 + header.msg_size:
            self._file_corrupt = True
            flag_bits.compat_flags, flag_bits.incompat_flags = self._compat_flags, self._incompat_flags
            flag_bits.appended_offsets = self._appended_offsets
        return flag_bits

    def _read_file_definitions(self):
        super()._read_file_definitions()
        formats = _CheckedFormats(self._message_formats)
        formats.guard = self._guard
        self._message_formats = formats

    def _load_file(self, log_file, message_name_filter_list, parse_header_only=False):
        super()._load_file(log_file, message_name_filter_list, parse_header_only)
        self._message_formats = dict(self._message_formats)  # a plain dict again for the caller


def parse_ulog(content: bytes, name: str, topics: Iterable[str], *,
               reader: type[GuardedULog] = GuardedULog) -> tuple[ULog, list[str]]:
    """Parse ``content`` with pyulog under the guards, reading only ``topics``.

    Parameters
    ----------
    content : bytes
        The whole file.
    name : str
        File name for messages.
    topics : iterable of str
        Topics to load.
    reader : type, optional
        :class:`GuardedULog` or a subclass (:class:`ingest.ulog_fast.FastULog`); its own exceptions pass through.

    Returns
    -------
    ulog : pyulog.ULog
        The parsed log (a ``reader``).
    warnings : list of str
        Topics dropped for an unusable format and where pyulog stopped early, if it did.

    Raises
    ------
    InputError
        Not a ULog, or so damaged that pyulog cannot get through it within the budget (a loop in its
        recovery, or far more reading than the file's size explains), or any failure inside pyulog.
    """
    if not content.startswith(ULog.HEADER_BYTES):
        raise InputError("not a PX4 ULog file: it does not start with the ULog header bytes", source=name)
    n_bytes = len(content)
    stream = BudgetedStream(content)
    guard = FormatGuard(topics)
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # pyulog prints its corruption notes
            ulog = reader(stream, guard)
    except _BudgetExceeded as exc:
        raise InputError(f"not a readable PX4 ULog file: the ULog parser cannot get past damaged messages ({exc}; "
                         f"the file has {n_bytes} bytes)", source=name) from None
    except RecursionError:
        raise InputError("not a readable PX4 ULog file: its definitions nest without end", source=name) from None
    except MemoryError:
        raise InputError("not a readable PX4 ULog file: its definitions need more memory than the file's size "
                         "explains", source=name) from None
    except (ULogException, struct.error, ValueError, IndexError, KeyError, OverflowError, TypeError,
            UnicodeDecodeError, AttributeError, OSError) as exc:
        raise InputError(f"not a readable PX4 ULog file ({exc})", source=name) from exc
    warnings = guard.warnings()
    if stream.closed_at is not None and stream.closed_at < n_bytes:
        warnings.append(f"the ULog parser stopped at byte {stream.closed_at} of {n_bytes} on a damaged message; "
                        "the rest of the file is not read")
    return ulog, warnings
