"""ULog data section at memory speed: the subscribed topics' samples gathered with numpy/numba, pyulog for the rest.

pyulog parses a data message per Python loop step (about 2.5 us each: 1.7 million in an hour at 250 Hz).
:class:`FastULog` keeps pyulog for everything but that loop: the header, the definitions (formats, info,
parameters, flag bits and appended-data offsets), every subscription ('A', flattened by pyulog under the
:class:`~ingest.ulog_guard.FormatGuard`), info, parameter changes, logged strings and dropouts of the data section,
each parsed by pyulog's own message classes. Only the data messages ('D') are read here, by two numba kernels
over the file's bytes: a walk of the message headers (uint16 size, uint8 type), then one gather of every
subscription's packed samples into one buffer, which pyulog's ``ULog.Data`` views with the subscription's
structured dtype (nested types, arrays and padding flattened by pyulog; trailing padding stripped as pyulog
strips it). The result is the pyulog object the reader already consumes, equal to a pyulog parse attribute for
attribute (docs/robustness.md, 'Fast data section').

Where pyulog's result depends on its recovery from damage (a message of unknown type whose header looks corrupt,
which pyulog steps through byte by byte and re-synchronises on sync messages, or one holding the sync bytes),
the scan refuses with :class:`FastPathRefused` and :func:`read_ulog` parses the file with pyulog instead. Damage
that pyulog only skips (a data message of unknown id or of the wrong size, a short message) is skipped alike.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

import numpy as np
from numba import njit
from pyulog import ULog

from ingest.ulog_guard import GuardedULog, parse_ulog

#: pyulog's "read until" when a data pass has no limit (larger than any file) [bytes].
NO_LIMIT = 1 << 50
#: pyulog's limit of a plausible message size for an unknown message type [bytes]; larger (or 0, or type 0) is a
#: corrupt header, from which pyulog recovers byte by byte.
MAX_UNKNOWN_MESSAGE_BYTES = 10_000
#: Message types of the data section that pyulog parses; any other one it skips (or recovers from).
DATA_SECTION_TYPES = b"IMPQALCDOS"
DATA_TYPE = ord("D")
#: Message types parsed here with pyulog's message classes (besides 'A', read first).
_OTHER_TYPES = {ord(t) for t in "IMPQLCO"}
_KNOWN_TYPE = np.zeros(256, dtype=np.bool_)
_KNOWN_TYPE[np.frombuffer(DATA_SECTION_TYPES, dtype=np.uint8)] = True
_SYNC = np.frombuffer(ULog.SYNC_BYTES, dtype=np.uint8)
#: Size of one message header (uint16 size, uint8 type) and of a data message's msg_id [bytes].
HEADER_BYTES = 3
MSG_ID_BYTES = 2


class FastPathRefused(Exception):
    """The data section holds damage whose outcome depends on pyulog's recovery; parse it with pyulog."""


@njit(cache=True)
def _scan_messages(content: np.ndarray, start: int, read_until: int, known_type: np.ndarray,
                   sync: np.ndarray) -> tuple[np.ndarray, int, int, int]:
    """Walk the messages pyulog's data pass parses from ``start`` [bytes], as pyulog walks them.

    The pass ends at the first incomplete message (the file's end) or at the first message ending after
    ``read_until`` (appended data: that message is read but not parsed). Returns ``(others, stop, end,
    refused)``: ``others`` the offsets of the messages that are not data ('D'), ``stop`` the offset after the
    last message parsed, ``end`` the stream position pyulog is left at, ``refused`` the offset of a message of
    unknown type whose header looks corrupt or whose payload holds the sync bytes (pyulog re-synchronises
    there), else -1.
    """
    n_bytes = content.shape[0]
    n_sync = sync.shape[0]
    others = np.empty(0, dtype=np.int64)
    for fill in range(2):  # count, then fill
        n_others = 0
        position = start
        end = max(start, n_bytes)
        refused = -1
        while position + HEADER_BYTES <= n_bytes:
            size = np.int64(content[position]) + 256 * np.int64(content[position + 1])
            kind = content[position + 2]
            after = position + HEADER_BYTES + size
            if after > n_bytes:
                break
            if after > read_until:
                end = after
                break
            if not known_type[kind]:
                if kind == 0 or size == 0 or size > MAX_UNKNOWN_MESSAGE_BYTES:
                    refused = position
                    break
                for i in range(position + HEADER_BYTES, after - n_sync + 1):
                    same = True
                    for j in range(n_sync):
                        if content[i + j] != sync[j]:
                            same = False
                            break
                    if same:
                        refused = position
                        break
                if refused >= 0:
                    break
            if kind != DATA_TYPE:
                if fill:
                    others[n_others] = position
                n_others += 1
            position = after
        if not fill:
            others = np.empty(n_others, dtype=np.int64)
    return others, position, end, refused


@njit(cache=True)
def _data_slot(content: np.ndarray, position: int, current: np.ndarray, is_known: np.ndarray,
               slot_bytes: np.ndarray, slot_max_bytes: np.ndarray) -> int:
    """Slot of the data message at ``position`` [bytes] as pyulog's ``_MessageData`` resolves it: the
    subscription in force for its msg_id (``current``) when its payload after the msg_id has between
    ``slot_bytes`` and ``slot_max_bytes`` bytes; -1 when pyulog skips it silently (msg_id filtered), -2 when
    pyulog takes it for corruption (shorter than a msg_id, another size, msg_id never subscribed nor filtered)."""
    size = np.int64(content[position]) + 256 * np.int64(content[position + 1])
    if size < MSG_ID_BYTES:
        return -2
    msg_id = np.int64(content[position + 3]) + 256 * np.int64(content[position + 4])
    slot = current[msg_id]
    if slot < 0:
        return -1 if is_known[msg_id] else -2
    if slot_bytes[slot] <= size - MSG_ID_BYTES <= slot_max_bytes[slot]:
        return slot
    return -2


@njit(cache=True)
def _gather_samples(content: np.ndarray, start: int, stop: int, last_us: np.uint64, event_offset: np.ndarray,
                    event_msg_id: np.ndarray, event_slot: np.ndarray, known: np.ndarray, slot_bytes: np.ndarray,
                    slot_max_bytes: np.ndarray, slot_time_offset: np.ndarray, slot_kept: np.ndarray,
                    others: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.uint64, bool]:
    """The data messages of one pass (the message chain from ``start`` to ``stop`` [bytes]), resolved and
    gathered as pyulog's data pass does.

    At offset ``event_offset[e]`` (a parsed 'A') msg_id ``event_msg_id[e]`` becomes subscribed to slot
    ``event_slot[e]`` (-1: filtered, known but not read; a subscription stays in force); ``known``: msg_ids
    filtered in earlier passes. Each data message goes to :func:`_data_slot`'s slot; its sample time (uint64
    at ``slot_time_offset`` of the sample) raises pyulog's ``_last_timestamp`` (from ``last_us``).

    Returns ``(samples, slot_start, last_before, last, corrupt)``: the samples of each slot with ``slot_kept``
    (contiguous, slot ``s`` at bytes ``slot_start[s]:slot_start[s + 1]``; the others were replaced by a later
    subscription of their msg_id, whose data pyulog keeps instead), pyulog's ``_last_timestamp`` [us] at each
    message of ``others`` (offsets, in order) and at the end, and whether any data message was corruption.
    """
    n_slots = slot_bytes.shape[0]
    counts = np.zeros(n_slots, dtype=np.int64)
    last_before = np.zeros(others.shape[0], dtype=np.uint64)
    last = last_us
    corrupt = False
    slot_start = np.zeros(n_slots + 1, dtype=np.int64)
    samples = np.empty(0, dtype=np.uint8)
    for fill in range(2):  # count, then copy: the samples are the only large allocation
        current = np.full(1 << 16, -1, dtype=np.int64)
        is_known = known.copy()
        filled = slot_start[:-1].copy()
        e = o = 0
        position = start
        while position < stop:
            if e < event_offset.shape[0] and event_offset[e] == position:
                if event_slot[e] >= 0:
                    current[event_msg_id[e]] = event_slot[e]
                is_known[event_msg_id[e]] = True
                e += 1
            if o < others.shape[0] and others[o] == position:
                if not fill:
                    last_before[o] = last
                o += 1
            if content[position + 2] == DATA_TYPE:
                slot = _data_slot(content, position, current, is_known, slot_bytes, slot_max_bytes)
                source = position + HEADER_BYTES + MSG_ID_BYTES
                if slot == -2:
                    corrupt = True
                elif slot >= 0 and not fill:
                    at = source + slot_time_offset[slot]
                    sample_us = np.uint64(0)
                    for b in range(8):
                        sample_us |= np.uint64(content[at + b]) << np.uint64(8 * b)
                    last = max(last, sample_us)
                    counts[slot] += 1
                elif slot >= 0 and slot_kept[slot]:
                    target, n_bytes = filled[slot], slot_bytes[slot]
                    samples[target:target + n_bytes] = content[source:source + n_bytes]
                    filled[slot] = target + n_bytes
            position += HEADER_BYTES + np.int64(content[position]) + 256 * np.int64(content[position + 1])
        if not fill:
            for slot in range(n_slots):
                slot_start[slot + 1] = slot_start[slot] + (counts[slot] * slot_bytes[slot] if slot_kept[slot] else 0)
            samples = np.empty(slot_start[-1], dtype=np.uint8)
    return samples, slot_start, last_before, last, corrupt


def _columns(rows: list[tuple[int, int, int]]) -> np.ndarray:
    """The three columns of ``rows`` as contiguous int64 arrays (the kernels' argument form)."""
    return np.array(rows, dtype=np.int64).reshape(-1, 3).T.copy()


class FastULog(GuardedULog):
    """:class:`~ingest.ulog_guard.GuardedULog` whose data passes gather the data messages with numpy/numba.

    Parameters
    ----------
    log_file : BudgetedStream
        The file; its ``content`` (the bytes) is indexed directly.
    guard : FormatGuard
        As for :class:`GuardedULog`.

    Raises
    ------
    FastPathRefused
        A data pass meets damage that only pyulog's own recovery resolves.
    """

    def _read_file_data(self, message_name_filter_list, read_until=None):
        """pyulog's data pass (same name and effect): parse the messages from the stream position on, up to
        ``read_until`` [bytes] (appended data), into subscriptions, info, parameters, strings and dropouts, and
        leave the stream where pyulog leaves it."""
        handle = self._file_handle
        raw = handle.content
        content = np.frombuffer(raw, dtype=np.uint8)
        limit = NO_LIMIT if read_until is None else min(read_until, NO_LIMIT)
        start = handle.tell()
        others, stop, end, refused = _scan_messages(content, start, limit, _KNOWN_TYPE, _SYNC)
        if refused >= 0:
            raise FastPathRefused(f"message of unknown type {content[refused + 2]} at byte {refused}")
        headers = [self._message(raw, int(offset)) for offset in others]
        known = np.zeros(1 << 16, dtype=np.bool_)
        known[list(self._filtered_message_ids)] = True
        events, slots = self._subscribe(others, headers, message_name_filter_list)
        # The kernel reads each sample's timestamp without bounds checks; the FormatGuard admits only formats with
        # a uint64_t timestamp, so this holds unless a pyulog release computes the offset differently.
        if any(s.timestamp_offset + 8 > s.dtype.itemsize for s in slots):
            raise FastPathRefused("a subscription's timestamp lies outside its sample")
        slot_of = {id(subscription): slot for slot, subscription in enumerate(slots)}
        kept = np.zeros(len(slots), dtype=np.bool_)
        kept[[slot_of[id(subscription)] for subscription in self._subscriptions.values()]] = True
        samples, slot_start, last_before, last_us, corrupt = _gather_samples(
            content, start, stop, np.uint64(self._last_timestamp), *_columns(events), known,
            *_columns([(s.dtype.itemsize, s.max_data_size, s.timestamp_offset) for s in slots]), kept, others)
        self._file_corrupt = self._file_corrupt or corrupt
        for slot, subscription in enumerate(slots):
            if kept[slot]:
                subscription.buffer = samples[slot_start[slot]:slot_start[slot + 1]]
        for (header, data), before_us in zip(headers, last_before, strict=True):
            if header.msg_type == self.MSG_TYPE_SYNC:
                self._sync_seq_cnt += 1
            elif header.msg_type in _OTHER_TYPES:
                self._parse_other(header, data, int(before_us))
        self._last_timestamp = int(last_us)
        handle.seek(end)
        while self._subscriptions:  # pyulog's final representation, in its order
            _, subscription = self._subscriptions.popitem()
            if len(subscription.buffer) > 0:
                self._data_list.append(ULog.Data(subscription))
        self._data_list.sort(key=lambda data: (data.name, data.multi_id))

    def _message(self, raw: bytes, offset: int):
        """pyulog's header object and the payload bytes of the message at ``offset`` [bytes]."""
        header = self._MessageHeader()
        header.initialize(raw[offset:offset + HEADER_BYTES])
        return header, raw[offset + HEADER_BYTES:offset + HEADER_BYTES + header.msg_size]

    def _subscribe(self, offsets: np.ndarray, headers: list, filter_list) -> tuple[list[tuple[int, int, int]], list]:
        """Parse the pass's 'A' messages (of ``offsets`` and ``headers``: the messages that are not data) as
        pyulog does (the message classes are pyulog's, under the guard).

        Returns the events ``(offset, msg_id, slot)`` in order (slot -1: filtered) and the subscriptions
        taken (one slot each); ``self._subscriptions`` ends as pyulog's does (a later subscription of a msg_id
        replaces the earlier).
        """
        events, slots = [], []
        for offset, (header, data) in zip(offsets, headers, strict=True):
            if header.msg_type != self.MSG_TYPE_ADD_LOGGED_MSG:
                continue
            try:
                add_logged = self._MessageAddLogged(data, header, self._message_formats)
            except UnicodeDecodeError:
                raise
            except (IndexError, KeyError, ValueError, OverflowError):
                self._file_corrupt = True
                continue
            if filter_list is None or add_logged.message_name in filter_list:
                self._subscriptions[add_logged.msg_id] = add_logged
                events.append((int(offset), add_logged.msg_id, len(slots)))
                slots.append(add_logged)
            else:
                self._filtered_message_ids.add(add_logged.msg_id)
                events.append((int(offset), add_logged.msg_id, -1))
        return events, slots

    def _parse_other(self, header, data: bytes, last_us: int) -> None:
        """One info, parameter, string or dropout message of the data section, as pyulog parses it;
        ``last_us`` is pyulog's ``_last_timestamp`` at that message."""
        kind = header.msg_type
        try:
            if kind == self.MSG_TYPE_INFO:
                info = self._MessageInfo(data, header)
                self._msg_info_dict[info.key] = info.value
                self._msg_info_dict_types[info.key] = info.type
            elif kind == self.MSG_TYPE_INFO_MULTIPLE:
                self._add_message_info_multiple(self._MessageInfo(data, header, is_info_multiple=True))
            elif kind == self.MSG_TYPE_PARAMETER:
                info = self._MessageInfo(data, header)
                self._changed_parameters.append((last_us, info.key, info.value))
            elif kind == self.MSG_TYPE_PARAMETER_DEFAULT:
                self._add_parameter_default(self._MessageParameterDefault(data, header))
            elif kind == self.MSG_TYPE_LOGGING:
                self._logged_messages.append(self.MessageLogging(data, header))
            elif kind == self.MSG_TYPE_LOGGING_TAGGED:
                tagged = self.MessageLoggingTagged(data, header)
                self._logged_messages_tagged.setdefault(tagged.tag, []).append(tagged)
            else:
                self._dropouts.append(self.MessageDropout(data, header, last_us))
        except UnicodeDecodeError:
            raise
        except (IndexError, KeyError, ValueError, OverflowError):
            self._file_corrupt = True


def read_ulog(content: bytes, name: str, topics: Iterable[str]) -> tuple[ULog, list[str]]:
    """:func:`~ingest.ulog_guard.parse_ulog` with the data section gathered by :class:`FastULog`, or parsed by
    pyulog where the fast path refuses (docs/robustness.md, 'Fast data section').

    Returns
    -------
    ulog : pyulog.ULog
        Its ``data_reader`` says which path read the data: ``"numpy"`` or ``"pyulog (<why>)"``.
    warnings : list of str
        As :func:`~ingest.ulog_guard.parse_ulog`.

    Raises
    ------
    InputError
        As :func:`~ingest.ulog_guard.parse_ulog`.
    """
    topics = tuple(topics)
    try:
        ulog, warnings = parse_ulog(content, name, topics, reader=FastULog)
        ulog.data_reader = "numpy"
    except FastPathRefused as exc:
        ulog, warnings = parse_ulog(content, name, topics)
        ulog.data_reader = f"pyulog ({exc})"
    return ulog, warnings


def compile_kernels() -> None:
    """Compile (or load from numba's cache) the kernels, with the argument types of a parse: reads a
    three-message log built here."""
    def message(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    content = (ULog.HEADER_BYTES + b"\x01" + bytes(8) + message("F", b"topic:uint64_t timestamp;")
               + message("A", b"\x00\x00\x00topic") + message("D", bytes(2 + 8)))
    read_ulog(content, "compile.ulg", ("topic",))
