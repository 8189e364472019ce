"""Seeded mutation fuzzing of the input readers: mutation operators, seeds, and a crash/hang-proof worker pool.

Used by ``tests/test_fuzz_readers.py`` (a small seeded CI run plus the kept regression corpus in
``tests/data/fuzz/``) and by ``benchmarks/fuzz_readers.py`` (the big run, failure saving and minimisation).

The readers' contract: each returns a result or raises :class:`ingest.errors.InputError`; any other exception,
a hang or a crash (a signal) is a bug. Every case is reproducible from ``(target, case_seed)`` and the seed list:
:func:`make_case` draws the seed file, the operators and their parameters from ``numpy.random.default_rng``.

Targets: ``"ulog"`` (:func:`ingest.log_formats.load_flight_log`), ``"sun_csv"``
(:func:`ingest.sun_log.load_sun_log`) and ``"device_json"`` (:func:`ingest.sun_log.load_sun_device`).

ULog layout used by the operators: a 16-byte file header, then messages, each a 3-byte header (uint16 payload
size, uint8 type char) and the payload. The definitions section ('B' flag bits, 'F' formats, 'I'/'M' info,
'P'/'Q' parameters) ends at the first 'A' (add_logged), 'L' or 'C' message; the data section follows ('A', 'D'
data = uint16 msg_id + the fields in format order, 'L' logging, 'O' dropout, 'S' sync, 'R' remove, ...).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import json
import math
import multiprocessing
import os
import re
import signal
import struct
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Sequence
from multiprocessing.connection import wait as wait_ready
from pathlib import Path

import numpy as np

REPO_DIR = Path(__file__).resolve().parents[1]
SAMPLE_LOGS_DIR = REPO_DIR / "sample_logs"
REAL_LOGS_DIR = REPO_DIR.parent / "shared" / "real_logs"
CORPUS_DIR = REPO_DIR / "tests" / "data" / "fuzz"

TARGETS = ("ulog", "sun_csv", "device_json")
EXTENSIONS = {"ulog": "ulg", "sun_csv": "csv", "device_json": "json"}
TARGET_OF_EXTENSION = {ext: target for target, ext in EXTENSIONS.items()}
#: UTC unix time of log time 0 given to the CSV reader (any finite value: it only shifts the time axis).
CSV_TIME_OFFSET_S = 1760491800.0

ULOG_HEADER_BYTES = 16
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: Message types that end the definitions section (pyulog: add_logged, logging, tagged logging).
DATA_SECTION_TYPES = frozenset(b"ALC")
#: pyulog's basic field types and their sizes [bytes].
BASIC_TYPE_BYTES = {"int8_t": 1, "uint8_t": 1, "int16_t": 2, "uint16_t": 2, "int32_t": 4, "uint32_t": 4,
                    "int64_t": 8, "uint64_t": 8, "float": 4, "double": 8, "bool": 1, "char": 1}
IMU_TOPIC = "sensor_combined"

# --------------------------------------------------------------------------------------------------------------
# ULog structure


@dataclasses.dataclass(frozen=True)
class Message:
    """One ULog message: ``offset`` of its 3-byte header, payload ``size`` [bytes] and ``type`` char."""

    offset: int
    size: int
    type: str

    @property
    def payload(self) -> slice:
        return slice(self.offset + 3, self.offset + 3 + self.size)

    @property
    def end(self) -> int:
        return self.offset + 3 + self.size


def walk_messages(data: bytes, offset: int = ULOG_HEADER_BYTES) -> list[Message]:
    """The complete messages from ``offset`` on (a cut-off last message is left out)."""
    messages = []
    n = len(data)
    while offset + 3 <= n:
        size = data[offset] | (data[offset + 1] << 8)
        if offset + 3 + size > n:
            break
        messages.append(Message(offset, size, chr(data[offset + 2])))
        offset += 3 + size
    return messages


@dataclasses.dataclass
class UlogView:
    """Structure of a (possibly already mutated) ULog: messages, sections, formats and subscriptions."""

    data: bytes
    messages: list[Message]
    #: Index of the first data-section message (len(messages) when there is none).
    first_data_index: int
    #: Format name -> (message, fields as (type, array size, field name)).
    formats: dict[str, tuple[Message, list[tuple[str, int, str]]]]
    #: msg_id -> (multi_id, topic name).
    subscriptions: dict[int, tuple[int, str]]

    @classmethod
    def parse(cls, data: bytes) -> UlogView:
        """The structure of ``data`` (cached for the few seed files every case starts from)."""
        cached = _VIEW_CACHE.get(data)
        if cached is not None:
            return cached
        view = cls._parse(data)
        if len(_VIEW_CACHE) < 64:
            _VIEW_CACHE[data] = view
        return view

    @classmethod
    def _parse(cls, data: bytes) -> UlogView:
        messages = walk_messages(data)
        first_data = next((i for i, m in enumerate(messages) if ord(m.type) in DATA_SECTION_TYPES), len(messages))
        formats, subscriptions = {}, {}
        for message in messages:
            payload = data[message.payload]
            if message.type == "F":
                parsed = parse_format(payload)
                if parsed is not None:
                    formats[parsed[0]] = (message, parsed[1])
            elif message.type == "A" and message.size >= 4:
                multi_id, msg_id = payload[0], payload[1] | (payload[2] << 8)
                subscriptions[msg_id] = (multi_id, payload[3:].decode("latin-1"))
        return cls(data, messages, first_data, formats, subscriptions)

    @property
    def definitions_end(self) -> int:
        """Byte offset where the data section starts."""
        if self.first_data_index < len(self.messages):
            return self.messages[self.first_data_index].offset
        return self.messages[-1].end if self.messages else ULOG_HEADER_BYTES

    @property
    def definition_messages(self) -> list[Message]:
        return self.messages[:self.first_data_index]

    @property
    def data_messages(self) -> list[Message]:
        return self.messages[self.first_data_index:]

    def topic_msg_ids(self, topic: str) -> list[int]:
        return [msg_id for msg_id, (_, name) in self.subscriptions.items() if name == topic]

    def data_messages_of(self, msg_ids: Iterable[int]) -> list[Message]:
        ids = set(msg_ids)
        return [m for m in self.data_messages
                if m.type == "D" and m.size >= 2 and (self.data[m.offset + 3] | (self.data[m.offset + 4] << 8)) in ids]

    def field_offset(self, topic: str, field: str) -> int | None:
        """Byte offset of a top-level basic field in the topic's data payload (after the msg_id)."""
        if topic not in self.formats:
            return None
        offset = 0
        for type_name, array_size, name in self.formats[topic][1]:
            if name == field:
                return offset
            if type_name not in BASIC_TYPE_BYTES:
                return None
            offset += BASIC_TYPE_BYTES[type_name] * max(array_size, 1)
        return None


_VIEW_CACHE: dict[bytes, UlogView] = {}


def remember_seeds(seeds: Iterable[Seed]) -> None:
    """Parse the ULog seeds once so that the first operator of every case reuses the structure."""
    for seed in seeds:
        if seed.target == "ulog":
            _VIEW_CACHE[seed.data] = UlogView._parse(seed.data)


def parse_format(payload: bytes) -> tuple[str, list[tuple[str, int, str]]] | None:
    """``(name, fields)`` of an 'F' payload ``name:type[n] field;...``, None when it does not parse."""
    try:
        text = payload.decode("ascii")
        name, body = text.split(":", 1)
        fields = []
        for item in body.split(";"):
            if not item:
                continue
            type_str, field_name = item.split(" ", 1)
            match = re.fullmatch(r"([^\[\]]+)(?:\[(\d+)\])?", type_str)
            if match is None:
                return None
            fields.append((match.group(1), int(match.group(2) or 0), field_name))
        return name, fields
    except (UnicodeDecodeError, ValueError):
        return None


def message_bytes(msg_type: str, payload: bytes) -> bytes:
    """A complete message (the payload is cut to 65535 bytes)."""
    payload = payload[:0xFFFF]
    return struct.pack("<HB", len(payload), ord(msg_type)) + payload


def format_message(name: str, fields: Sequence[tuple[str, int, str]]) -> bytes:
    body = "".join(f"{t}[{n}] {f};" if n else f"{t} {f};" for t, n, f in fields)
    return message_bytes("F", f"{name}:{body}".encode("ascii"))


def replace_message(data: bytes, message: Message, new_message: bytes) -> bytes:
    return data[:message.offset] + new_message + data[message.end:]


def truncate_at_boundary(data: bytes, max_bytes: int) -> bytes:
    """The longest prefix of complete messages not over ``max_bytes`` (a valid, smaller ULog)."""
    end = ULOG_HEADER_BYTES
    for message in walk_messages(data):
        if message.end > max_bytes:
            break
        end = message.end
    return data[:end]


def make_ulog_seed(data: bytes, data_bytes: int) -> bytes:
    """A small valid ULog from a big one: the whole definitions section plus about ``data_bytes`` of the data
    section, cut at a message boundary; appended-data offsets in the flag bits are cleared (they would point past
    the new end)."""
    offset, end, limit = ULOG_HEADER_BYTES, ULOG_HEADER_BYTES, None
    n = len(data)
    while offset + 3 <= n:
        size = data[offset] | (data[offset + 1] << 8)
        if offset + 3 + size > n:
            break
        if limit is None and data[offset + 2] in DATA_SECTION_TYPES:
            limit = offset + data_bytes
        if limit is not None and offset + 3 + size > limit:
            break
        offset += 3 + size
        end = offset
    seed = bytearray(data[:end])
    if len(seed) >= ULOG_HEADER_BYTES + 43 and seed[ULOG_HEADER_BYTES + 2] == ord("B"):
        seed[ULOG_HEADER_BYTES + 3 + 16:ULOG_HEADER_BYTES + 3 + 40] = bytes(24)
    return bytes(seed)


# --------------------------------------------------------------------------------------------------------------
# Seeds


@dataclasses.dataclass(frozen=True)
class Seed:
    name: str
    target: str
    data: bytes


def default_ulog_sources(include_real: bool = True) -> list[Path]:
    """The bundled sample logs, then the shared real logs (when present)."""
    paths = sorted(SAMPLE_LOGS_DIR.glob("*.ulg"))
    if include_real and REAL_LOGS_DIR.is_dir():
        paths += sorted(REAL_LOGS_DIR.glob("*.ulg"))
    return paths


def ulog_seeds(paths: Sequence[Path] | None = None, data_bytes: int = 192 * 1024) -> list[Seed]:
    """Small seeds: each source log cut to its definitions plus ``data_bytes`` of data."""
    seeds = []
    for path in paths if paths is not None else default_ulog_sources():
        with open(path, "rb") as f:
            head = f.read(4 << 20)  # definitions of real logs are far smaller than 4 MiB
        seeds.append(Seed(f"{path.stem}@{data_bytes // 1024}k", "ulog", make_ulog_seed(head, data_bytes)))
    remember_seeds(seeds)
    return seeds


def _csv_rows(path: Path, n_rows: int) -> tuple[list[str], list[list[str]]]:
    lines = path.read_text(encoding="utf-8").splitlines()
    header = lines[0].split(",")
    return header, [line.split(",") for line in lines[1:1 + n_rows]]


def _csv_text(header: Sequence[str], rows: Iterable[Sequence[str]], newline: str = "\n") -> bytes:
    return (newline.join([",".join(header), *(",".join(r) for r in rows)]) + newline).encode("utf-8")


def csv_seeds(n_rows: int = 40) -> list[Seed]:
    """The sample sun CSVs cut to ``n_rows`` rows, and variants in A, with ISO times, extra columns and CRLF."""
    seeds = []
    for path in sorted(SAMPLE_LOGS_DIR.glob("*_sun.csv")):
        header, rows = _csv_rows(path, n_rows)
        stem = path.stem
        seeds.append(Seed(f"{stem}@{n_rows}", "sun_csv", _csv_text(header, rows)))
        amp_header = [h.replace("_mA", "_A") for h in header]
        amp_rows = [[r[0], *(f"{float(v) / 1000:.7f}" for v in r[1:])] for r in rows]
        seeds.append(Seed(f"{stem}@{n_rows}:amps", "sun_csv", _csv_text(amp_header, amp_rows)))
        iso_rows = [[np.datetime_as_string(np.datetime64(round(float(r[0]) * 1000), "ms"), unit="ms") + "Z",
                     *r[1:]] for r in rows]
        seeds.append(Seed(f"{stem}@{n_rows}:iso", "sun_csv", _csv_text(["time_utc", *header[1:]], iso_rows)))
        extra_rows = [[*r, str(i % 3), "note"] for i, r in enumerate(rows)]
        seeds.append(Seed(f"{stem}@{n_rows}:extra_crlf", "sun_csv",
                          _csv_text([*header, "flags", "comment"], extra_rows, newline="\r\n")))
    return seeds


def json_seeds() -> list[Seed]:
    """The sample device JSONs, minified, and partial objects."""
    seeds = []
    for path in sorted(SAMPLE_LOGS_DIR.glob("*_device.json")):
        seeds.append(Seed(path.stem, "device_json", path.read_bytes()))
    base = {"tilt_deg": 40.0, "azimuths_deg": [0.0, 61.0, 119.5, 180.0, 240.0, 300.0],
            "mount_rpy_deg": [0.0, 2.5, 90.0]}
    seeds.append(Seed("minified", "device_json", json.dumps(base, separators=(",", ":")).encode()))
    seeds.append(Seed("tilt_only", "device_json", b'{"tilt_deg": 30}'))
    seeds.append(Seed("empty_object", "device_json", b"{}"))
    return seeds


#: Data-section bytes of the ULog seeds of the CI run (each case loads in a few tens of ms).
CI_ULOG_DATA_BYTES = 64 * 1024


def ci_seeds(target: str) -> list[Seed]:
    """Seeds of the CI run (``tests/test_fuzz_readers.py``): smaller ULog seeds."""
    return default_seeds(target, ulog_data_bytes=CI_ULOG_DATA_BYTES)


def default_seeds(target: str, *, include_real: bool = True, ulog_data_bytes: int = 192 * 1024) -> list[Seed]:
    """The seed files of ``target`` (made once per process and argument set)."""
    return list(_default_seeds(target, include_real, ulog_data_bytes))


@functools.lru_cache(maxsize=16)
def _default_seeds(target: str, include_real: bool, ulog_data_bytes: int) -> tuple[Seed, ...]:
    return tuple(_make_seeds(target, include_real, ulog_data_bytes))


def _make_seeds(target: str, include_real: bool, ulog_data_bytes: int) -> list[Seed]:
    if target == "ulog":
        return ulog_seeds(default_ulog_sources(include_real), data_bytes=ulog_data_bytes)
    if target == "sun_csv":
        return csv_seeds()
    if target == "device_json":
        return json_seeds()
    raise ValueError(f"unknown target {target!r}")


# --------------------------------------------------------------------------------------------------------------
# Generic byte operators (every target)

Params = dict
Operator = Callable[[np.random.Generator, bytes], tuple[bytes, Params]]

INTERESTING_BYTES = (0x00, 0x01, 0x7F, 0x80, 0xFF, 0xFE, 0x20, 0x3A, 0x3B, 0x5B, 0x5D, 0x2C, 0x0A, 0x22)


def _pos(rng: np.random.Generator, lo: int, hi: int) -> int:
    """A position in [lo, hi) (lo when the range is empty)."""
    return int(rng.integers(lo, hi)) if hi > lo else lo


def bit_flips(rng, data, lo: int = 0, hi: int | None = None) -> tuple[bytes, Params]:
    hi = len(data) if hi is None else hi
    out = bytearray(data)
    n = int(rng.choice([1, 2, 4, 8, 32]))
    positions = sorted(_pos(rng, lo, hi) for _ in range(n)) if hi > lo else []
    for p in positions:
        out[p] ^= 1 << int(rng.integers(8))
    return bytes(out), {"n_flips": n, "first_at": positions[0] if positions else None}


def byte_overwrite(rng, data, lo: int = 0, hi: int | None = None) -> tuple[bytes, Params]:
    hi = len(data) if hi is None else hi
    out = bytearray(data)
    if hi <= lo:
        return bytes(out), {"skipped": True}
    at = _pos(rng, lo, hi)
    length = int(min(rng.choice([1, 2, 4, 8, 64]), len(out) - at))
    if rng.random() < 0.5:
        values = bytes(int(rng.choice(INTERESTING_BYTES)) for _ in range(length))
    else:
        values = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
    out[at:at + length] = values
    return bytes(out), {"at": at, "length": length}


def truncate(rng, data) -> tuple[bytes, Params]:
    at = _pos(rng, 1, len(data))
    return data[:at], {"at": at}


def duplicate_chunk(rng, data) -> tuple[bytes, Params]:
    start = _pos(rng, 0, len(data))
    length = int(min(rng.choice([1, 7, 64, 1024, 16384]), len(data) - start))
    insert_at = _pos(rng, 0, len(data))
    chunk = data[start:start + length]
    return data[:insert_at] + chunk + data[insert_at:], {"start": start, "length": length, "insert_at": insert_at}


def remove_chunk(rng, data) -> tuple[bytes, Params]:
    start = _pos(rng, 0, len(data))
    length = int(min(rng.choice([1, 3, 64, 1024, 16384]), len(data) - start))
    return data[:start] + data[start + length:], {"start": start, "length": length}


GENERIC_OPERATORS: dict[str, Operator] = {
    "bit_flips": bit_flips,
    "byte_overwrite": byte_overwrite,
    "truncate": truncate,
    "duplicate_chunk": duplicate_chunk,
    "remove_chunk": remove_chunk,
}

# --------------------------------------------------------------------------------------------------------------
# ULog operators


def ulog_bit_flips_definitions(rng, data):
    view = UlogView.parse(data)
    return bit_flips(rng, data, ULOG_HEADER_BYTES, view.definitions_end)


def ulog_bit_flips_data(rng, data):
    view = UlogView.parse(data)
    return bit_flips(rng, data, view.definitions_end, len(data))


def ulog_overwrite_definitions(rng, data):
    view = UlogView.parse(data)
    return byte_overwrite(rng, data, ULOG_HEADER_BYTES, view.definitions_end)


def ulog_overwrite_data(rng, data):
    view = UlogView.parse(data)
    return byte_overwrite(rng, data, view.definitions_end, len(data))


def ulog_truncate_mid_message(rng, data):
    view = UlogView.parse(data)
    if not view.messages:
        return truncate(rng, data)
    message = view.messages[_pos(rng, 0, len(view.messages))]
    at = message.offset + _pos(rng, 1, message.size + 3)
    return data[:at], {"at": at, "message_type": message.type}


def _pick_messages(rng, view: UlogView, section: str) -> tuple[int, int]:
    messages = {"any": view.messages, "definitions": view.definition_messages, "data": view.data_messages}[section]
    if not messages:
        return 0, 0
    start = _pos(rng, 0, len(messages))
    count = int(min(rng.choice([1, 2, 5, 50]), len(messages) - start))
    base = view.messages.index(messages[start])
    return base, count


def ulog_duplicate_messages(rng, data):
    view = UlogView.parse(data)
    section = str(rng.choice(["any", "definitions", "data"]))
    first, count = _pick_messages(rng, view, section)
    if count == 0:
        return data, {"skipped": True}
    chunk = data[view.messages[first].offset:view.messages[first + count - 1].end]
    target = view.messages[_pos(rng, 0, len(view.messages))].offset
    return data[:target] + chunk + data[target:], {"section": section, "first": first, "count": count,
                                                  "insert_at": target}


def ulog_remove_messages(rng, data):
    view = UlogView.parse(data)
    section = str(rng.choice(["any", "definitions", "data"]))
    first, count = _pick_messages(rng, view, section)
    if count == 0:
        return data, {"skipped": True}
    start, end = view.messages[first].offset, view.messages[first + count - 1].end
    types = "".join(m.type for m in view.messages[first:first + count])[:10]
    return data[:start] + data[end:], {"section": section, "first": first, "count": count, "types": types}


def _set_size(data: bytes, message: Message, size: int) -> bytes:
    out = bytearray(data)
    out[message.offset:message.offset + 2] = struct.pack("<H", size & 0xFFFF)
    return bytes(out)


def ulog_change_message_size(rng, data):
    view = UlogView.parse(data)
    if not view.messages:
        return data, {"skipped": True}
    section = str(rng.choice(["definitions", "data"]))
    messages = view.definition_messages if section == "definitions" else view.data_messages
    messages = messages or view.messages
    message = messages[_pos(rng, 0, len(messages))]
    size = max(0, message.size + int(rng.choice([-3, -2, -1, 1, 2, 8, -message.size])))
    return _set_size(data, message, size), {"section": section, "type": message.type, "offset": message.offset,
                                           "size": message.size, "new_size": size}


def ulog_huge_message_size(rng, data):
    view = UlogView.parse(data)
    if not view.messages:
        return data, {"skipped": True}
    message = view.messages[_pos(rng, 0, len(view.messages))]
    size = int(rng.choice([0xFFFF, 0xFFFE, 0x8000, 10001, 0x7FFF]))
    return _set_size(data, message, size), {"type": message.type, "offset": message.offset, "new_size": size}


def ulog_garbage_after_header(rng, data):
    view = UlogView.parse(data)
    keep = ULOG_HEADER_BYTES if rng.random() < 0.5 else view.definitions_end
    n = int(rng.choice([1, 3, 100, 4096, 65536]))
    kind = str(rng.choice(["random", "zeros", "ff", "repeat_header"]))
    if kind == "random":
        garbage = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    elif kind == "zeros":
        garbage = bytes(n)
    elif kind == "ff":
        garbage = b"\xff" * n
    else:
        garbage = (data[:ULOG_HEADER_BYTES] * (n // ULOG_HEADER_BYTES + 1))[:n]
    return data[:keep] + garbage, {"keep": keep, "garbage": kind, "n": n}


def _insert_before_data(view: UlogView, extra: bytes) -> bytes:
    at = view.definitions_end
    return view.data[:at] + extra + view.data[at:]


def _target_format(rng, view: UlogView) -> str | None:
    subscribed = sorted({name for _, name in view.subscriptions.values() if name in view.formats})
    if not subscribed:
        return None
    if IMU_TOPIC in subscribed and rng.random() < 0.6:
        return IMU_TOPIC
    return subscribed[_pos(rng, 0, len(subscribed))]


def _with_extra_field(view: UlogView, topic: str, field: tuple[str, int, str], new_formats: bytes) -> bytes:
    """The log with ``field`` appended to ``topic``'s format and ``new_formats`` before the data section."""
    message, fields = view.formats[topic]
    data = replace_message(view.data, message, format_message(topic, [*fields, field]))
    return _insert_before_data(UlogView.parse(data), new_formats)


def ulog_nested_format_explosion(rng, data):
    """A field ``fz_outer[N] boom`` of a nested type with arrays of arrays: pyulog flattens every element."""
    view = UlogView.parse(data)
    topic = _target_format(rng, view)
    if topic is None:
        return data, {"skipped": True}
    n_outer = int(rng.choice([2, 255, 4096, 65535]))
    n_mid = int(rng.choice([16, 255, 65535]))
    n_leaf = int(rng.choice([1, 64, 65535]))
    formats = (format_message("fz_leaf", [("uint64_t", n_leaf, "a"), ("float", 3, "b")])
               + format_message("fz_mid", [("fz_leaf", n_mid, "leaf"), ("uint8_t", 0, "c")])
               + format_message("fz_outer", [("fz_mid", 0, "mid"), ("double", 0, "d")]))
    mode = str(rng.choice(["extend_topic", "new_subscription"]))
    if mode == "extend_topic":
        out = _with_extra_field(view, topic, ("fz_outer", n_outer, "boom"), formats)
    else:
        formats += format_message("fz_topic", [("uint64_t", 0, "timestamp"), ("fz_outer", n_outer, "boom")])
        out = _insert_before_data(view, formats + message_bytes("A", struct.pack("<BH", 0, 0xFFF0) + b"fz_topic"))
    return out, {"topic": topic, "mode": mode, "n_outer": n_outer, "n_mid": n_mid, "n_leaf": n_leaf}


def ulog_deep_nesting_chain(rng, data):
    """A chain of nested types each holding two of the next: 2**depth flattened fields."""
    view = UlogView.parse(data)
    topic = _target_format(rng, view)
    if topic is None:
        return data, {"skipped": True}
    depth = int(rng.choice([12, 24, 40, 400]))
    formats = format_message(f"fz_n{depth}", [("uint8_t", 0, "x")])
    for level in range(depth - 1, -1, -1):
        formats += format_message(f"fz_n{level}", [(f"fz_n{level + 1}", 2, "c")])
    return _with_extra_field(view, topic, ("fz_n0", 0, "chain"), formats), {"topic": topic, "depth": depth}


def ulog_self_referential_format(rng, data):
    view = UlogView.parse(data)
    topic = _target_format(rng, view)
    if topic is None:
        return data, {"skipped": True}
    mode = str(rng.choice(["self", "self_array", "mutual", "new_subscription"]))
    if mode in ("self", "self_array"):
        out = _with_extra_field(view, topic, (topic, 2 if mode == "self_array" else 0, "again"), b"")
    elif mode == "mutual":
        formats = (format_message("fz_a", [("fz_b", 0, "b")]) + format_message("fz_b", [("fz_a", 0, "a")]))
        out = _with_extra_field(view, topic, ("fz_a", 0, "loop"), formats)
    else:
        formats = format_message("fz_loop", [("uint64_t", 0, "timestamp"), ("fz_loop", 0, "next")])
        out = _insert_before_data(view, formats + message_bytes("A", struct.pack("<BH", 0, 0xFFF1) + b"fz_loop"))
    return out, {"topic": topic, "mode": mode}


FORMAT_TEXT_EDITS = ("drop_colon", "drop_space", "undefined_type", "negative_array", "huge_array", "bad_array",
                     "empty_name", "unterminated_array", "non_ascii", "duplicate_field", "drop_timestamp",
                     "timestamp_type", "many_fields")


def ulog_corrupt_format_text(rng, data):
    view = UlogView.parse(data)
    formats = [m for m in view.definition_messages if m.type == "F"]
    if not formats:
        return data, {"skipped": True}
    topic = _target_format(rng, view) if rng.random() < 0.6 else None
    message = view.formats[topic][0] if topic else formats[_pos(rng, 0, len(formats))]
    text = data[message.payload]
    edit = str(rng.choice(FORMAT_TEXT_EDITS))
    if edit == "drop_colon":
        text = text.replace(b":", b"", 1)
    elif edit == "drop_space":
        i = text.find(b" ")
        text = text[:i] + text[i + 1:] if i >= 0 else text
    elif edit == "undefined_type":
        text += b"no_such_type_t mystery;"
    elif edit == "negative_array":
        text += b"float[-1] neg;"
    elif edit == "huge_array":
        text += b"float[99999999999] huge;"
    elif edit == "bad_array":
        text += b"float[abc] bad;"
    elif edit == "empty_name":
        text = b":" + text.split(b":", 1)[-1]
    elif edit == "unterminated_array":
        text += b"float[3 x;"
    elif edit == "non_ascii":
        text = text[:5] + b"\xc3\x28\xff" + text[5:]
    elif edit == "duplicate_field":
        name, _, body = text.partition(b":")
        first = body.split(b";")[0]
        text = name + b":" + first + b";" + body
    elif edit == "drop_timestamp":
        text = text.replace(b"uint64_t timestamp;", b"", 1)
    elif edit == "timestamp_type":
        text = text.replace(b"uint64_t timestamp;", str(rng.choice(["float", "uint8_t", "char[8]",
                                                                    "double"])).encode() + b" timestamp;", 1)
    else:
        text += b"".join(b"uint8_t f%d;" % i for i in range(int(rng.choice([100, 5000]))))
    return replace_message(data, message, message_bytes("F", text)), {"format": text.split(b":")[0][:40].decode(
        "latin-1"), "edit": edit}


HUGE_TIMESTAMPS = (2**64 - 1, 2**63, 2**63 - 1, 2**62, 10**15, 2**53 + 1, 0, 1)


def ulog_corrupt_timestamp(rng, data, topic: str | None = IMU_TOPIC):
    """One sample's (or a few samples') uint64 ``timestamp`` set to a huge (or zero, or backwards) value."""
    view = UlogView.parse(data)
    if topic is None:
        names = sorted({name for _, name in view.subscriptions.values()})
        if not names:
            return data, {"skipped": True}
        topic = names[_pos(rng, 0, len(names))]
    offset = view.field_offset(topic, "timestamp")
    samples = view.data_messages_of(view.topic_msg_ids(topic))
    if offset is None or not samples:
        return data, {"skipped": True, "topic": topic}
    out = bytearray(data)
    mode = str(rng.choice(["single_huge", "single_huge", "few_huge", "backwards", "all_equal"]))
    picks = [_pos(rng, 0, len(samples))] if mode != "few_huge" else sorted(
        {_pos(rng, 0, len(samples)) for _ in range(3)})
    value = int(rng.choice(np.array(HUGE_TIMESTAMPS, dtype=object)))
    for pick in (range(len(samples)) if mode == "all_equal" else picks):
        message = samples[pick]
        at = message.offset + 3 + 2 + offset
        if at + 8 > message.end:
            continue
        if mode == "backwards":
            old, = struct.unpack_from("<Q", out, at)
            new = max(0, old - int(rng.choice([1, 1000, 10**6, 10**9])))
        elif mode == "all_equal":
            new = struct.unpack_from("<Q", data, samples[0].offset + 5 + offset)[0]
        else:
            new = value
        struct.pack_into("<Q", out, at, new)
    return bytes(out), {"topic": topic, "mode": mode, "sample": picks[0], "value": value}


def ulog_corrupt_any_timestamp(rng, data):
    return ulog_corrupt_timestamp(rng, data, topic=None)


def ulog_corrupt_subscription(rng, data):
    """An 'A' message's msg_id / multi_id / name changed, or a second subscription reusing a msg_id."""
    view = UlogView.parse(data)
    adds = [m for m in view.data_messages if m.type == "A" and m.size >= 4]
    if not adds:
        return data, {"skipped": True}
    message = adds[_pos(rng, 0, len(adds))]
    payload = bytearray(data[message.payload])
    mode = str(rng.choice(["msg_id", "multi_id", "name_unknown", "reuse_id", "name_other_format"]))
    if mode == "msg_id":
        payload[1:3] = struct.pack("<H", int(rng.choice([0, 1, 0xFFFF, int(rng.integers(0, 0x10000))])))
    elif mode == "multi_id":
        payload[0] = int(rng.choice([1, 9, 255]))
    elif mode == "name_unknown":
        payload[3:] = b"fz_not_defined"
    elif mode == "name_other_format":
        names = sorted(view.formats)
        payload[3:] = names[_pos(rng, 0, len(names))].encode()
    else:
        other = adds[_pos(rng, 0, len(adds))]
        payload[1:3] = data[other.offset + 4:other.offset + 6]
    return replace_message(data, message, message_bytes("A", bytes(payload))), {"mode": mode,
                                                                                 "offset": message.offset}


def ulog_corrupt_info_param(rng, data):
    """An 'I'/'P'/'M'/'Q' message with a wrong key length, a mistyped key or a value of the wrong size."""
    view = UlogView.parse(data)
    candidates = [m for m in view.messages if m.type in "IPMQ" and m.size >= 2]
    if not candidates:
        return data, {"skipped": True}
    message = candidates[_pos(rng, 0, len(candidates))]
    payload = bytearray(data[message.payload])
    lead = 1 if message.type in "MQ" else 0
    mode = str(rng.choice(["key_len_huge", "key_len_zero", "no_space", "type_swap", "value_short",
                           "value_nan", "value_inf"]))
    if mode == "key_len_huge":
        payload[lead] = 255
    elif mode == "key_len_zero":
        payload[lead] = 0
    elif mode == "no_space":
        payload = bytearray(payload.replace(b" ", b"_", 1))
    elif mode == "type_swap":
        key_len = payload[lead]
        key = bytes(payload[lead + 1:lead + 1 + key_len])
        for a, b in ((b"float", b"int32_t"), (b"int32_t", b"double"), (b"char[", b"float ["),
                     (b"uint8_t", b"uint64_t")):
            if key.startswith(a):
                key = b + key[len(a):]
                break
        payload = bytearray(payload[:lead] + bytes([len(key) & 0xFF]) + key + payload[lead + 1 + key_len:])
    elif mode == "value_short":
        payload = payload[:-1]
    else:
        key_len = payload[lead]
        key = bytes(payload[lead + 1:lead + 1 + key_len])
        if key.startswith(b"float") and len(payload) == lead + 1 + key_len + 4:
            payload[-4:] = struct.pack("<f", math.nan if mode == "value_nan" else math.inf)
    return replace_message(data, message, message_bytes(message.type, bytes(payload))), {
        "type": message.type, "mode": mode, "offset": message.offset}


def ulog_corrupt_flag_bits(rng, data):
    view = UlogView.parse(data)
    if not view.messages or view.messages[0].type != "B" or view.messages[0].size < 40:
        return data, {"skipped": True}
    message = view.messages[0]
    out = bytearray(data)
    mode = str(rng.choice(["appended_inside", "appended_past_end", "appended_huge", "incompat_bit",
                           "compat_all"]))
    base = message.offset + 3
    if mode == "appended_inside":
        struct.pack_into("<Q", out, base + 16, _pos(rng, ULOG_HEADER_BYTES, len(data)))
        out[base + 8] |= 1
    elif mode == "appended_past_end":
        struct.pack_into("<Q", out, base + 16, len(data) + 1000)
        out[base + 8] |= 1
    elif mode == "appended_huge":
        struct.pack_into("<Q", out, base + 16, 2**64 - 1)
        out[base + 8] |= 1
    elif mode == "incompat_bit":
        out[base + 8 + _pos(rng, 0, 8)] |= 1 << _pos(rng, 0, 8)
    else:
        out[base:base + 8] = b"\xff" * 8
    return bytes(out), {"mode": mode}


def ulog_corrupt_file_header(rng, data):
    out = bytearray(data)
    mode = str(rng.choice(["version", "start_timestamp_huge", "start_timestamp_zero"]))
    if mode == "version":
        out[7] = int(rng.choice([0, 2, 255]))
    elif mode == "start_timestamp_huge":
        struct.pack_into("<Q", out, 8, int(rng.choice(np.array([2**64 - 1, 2**63, 10**15], dtype=object))))
    else:
        struct.pack_into("<Q", out, 8, 0)
    return bytes(out), {"mode": mode}


ULOG_OPERATORS: dict[str, Operator] = {
    **GENERIC_OPERATORS,
    "bit_flips_definitions": ulog_bit_flips_definitions,
    "bit_flips_data": ulog_bit_flips_data,
    "overwrite_definitions": ulog_overwrite_definitions,
    "overwrite_data": ulog_overwrite_data,
    "truncate_mid_message": ulog_truncate_mid_message,
    "duplicate_messages": ulog_duplicate_messages,
    "remove_messages": ulog_remove_messages,
    "change_message_size": ulog_change_message_size,
    "huge_message_size": ulog_huge_message_size,
    "garbage_after_header": ulog_garbage_after_header,
    "nested_format_explosion": ulog_nested_format_explosion,
    "deep_nesting_chain": ulog_deep_nesting_chain,
    "self_referential_format": ulog_self_referential_format,
    "corrupt_format_text": ulog_corrupt_format_text,
    "imu_timestamp": ulog_corrupt_timestamp,
    "any_timestamp": ulog_corrupt_any_timestamp,
    "corrupt_subscription": ulog_corrupt_subscription,
    "corrupt_info_param": ulog_corrupt_info_param,
    "corrupt_flag_bits": ulog_corrupt_flag_bits,
    "corrupt_file_header": ulog_corrupt_file_header,
}

# --------------------------------------------------------------------------------------------------------------
# CSV operators (text is split into lines / cells; bytes are re-encoded as UTF-8 unless the operator says not)

NON_NUMERIC = ("abc", "", " ", "1,5", "0x10", "1e", "--1", "\u0661\u0662\u0663", "1_000", "True", "12:00", "[1]",
               "\"\"", "null", "None", "1e5000x", "\u00a0", "+-1", ".", "1.2.3")
NON_FINITE = ("inf", "-inf", "nan", "NaN", "-nan", "Infinity", "1e400", "-1e400", "1e308", "-1e308", "NA",
              "4.9e-324", "1" * 400, "9" * 5000)


def _split_csv(data: bytes) -> tuple[list[str], str]:
    text = data.decode("utf-8", errors="surrogateescape")
    newline = "\r\n" if "\r\n" in text else "\n"
    return text.split(newline), newline


def _join_csv(lines: list[str], newline: str) -> bytes:
    return newline.join(lines).encode("utf-8", errors="surrogateescape")


def _data_line(rng, lines: list[str]) -> int:
    n = len([line for line in lines if line])
    return _pos(rng, 1, max(n, 2))


def csv_truncate_mid_number(rng, data):
    lines, newline = _split_csv(data)
    row = _data_line(rng, lines)
    line = lines[row]
    cut = _pos(rng, 1, max(len(line), 2))
    return _join_csv([*lines[:row], line[:cut]], newline), {"row": row, "cut": cut}


def csv_duplicate_column_name(rng, data):
    lines, newline = _split_csv(data)
    header = lines[0].split(",")
    src = _pos(rng, 0, len(header))
    dst = _pos(rng, 0, len(header))
    header[dst] = header[src]
    lines[0] = ",".join(header)
    return _join_csv(lines, newline), {"copied": header[src], "over": dst}


def _set_cells(rng, data, values: Sequence[str], column: int | None = None):
    lines, newline = _split_csv(data)
    n_cols = len(lines[0].split(","))
    col = _pos(rng, 0, n_cols) if column is None else column
    n = int(rng.choice([1, 1, 3, 1000]))
    value = str(rng.choice(np.array(values, dtype=object)))
    rows = sorted({_data_line(rng, lines) for _ in range(n)})
    for row in rows:
        cells = lines[row].split(",")
        if col < len(cells):
            cells[col] = value
            lines[row] = ",".join(cells)
    return _join_csv(lines, newline), {"column": col, "value": value[:20], "rows": rows[:3]}


def csv_non_numeric_cell(rng, data):
    return _set_cells(rng, data, NON_NUMERIC)


def csv_non_finite_cell(rng, data):
    return _set_cells(rng, data, NON_FINITE)


def csv_odd_time(rng, data):
    """The time cell of a few rows: non-finite, huge, negative or (for ISO times) out-of-range dates."""
    values = (*NON_FINITE, "-1", "0", "1e19", "1e300", "-1e300", "99999999999999", "2024-13-45T00:00:00Z",
              "9999-12-31T23:59:59Z", "0001-01-01T00:00:00Z", "2024-03-18T14:49:11.250+05:00",
              "2024-03-18 14:49:11", "20240318T144911Z", "1760491800", "2024-03-18T14:49:11.250Z",
              "+275760-09-13T00:00:00Z", "2262-04-12T00:00:00Z", "1677-09-21T00:00:00Z")
    return _set_cells(rng, data, values, column=0)


def csv_bad_encoding(rng, data):
    mode = str(rng.choice(["invalid_utf8", "latin1", "nul_bytes", "utf16", "double_bom", "bom_in_header",
                           "lone_surrogate", "utf32"]))
    if mode == "invalid_utf8":
        at = _pos(rng, 0, len(data))
        return data[:at] + b"\xff\xfe\xc3\x28" + data[at:], {"mode": mode, "at": at}
    if mode == "latin1":
        return data.replace(b"i1", "\u00ef1".encode("latin-1"), 1) + "caf\u00e9".encode("latin-1"), {"mode": mode}
    if mode == "nul_bytes":
        at = _pos(rng, 0, len(data))
        return data[:at] + b"\x00" * int(rng.choice([1, 100])) + data[at:], {"mode": mode, "at": at}
    if mode == "utf16":
        return data.decode("utf-8", errors="replace").encode("utf-16"), {"mode": mode}
    if mode == "utf32":
        return data.decode("utf-8", errors="replace").encode("utf-32"), {"mode": mode}
    if mode == "double_bom":
        return b"\xef\xbb\xbf\xef\xbb\xbf" + data, {"mode": mode}
    if mode == "bom_in_header":
        i = data.find(b",")
        return data[:i + 1] + b"\xef\xbb\xbf" + data[i + 1:], {"mode": mode}
    return data.replace(b",", b",\xed\xa0\x80", 1), {"mode": mode}


def csv_reorder_timestamps(rng, data):
    lines, newline = _split_csv(data)
    body = [line for line in lines[1:] if line]
    if len(body) < 2:
        return data, {"skipped": True}
    mode = str(rng.choice(["swap", "duplicate_row", "duplicate_time", "reverse", "shuffle"]))
    i, j = _pos(rng, 0, len(body)), _pos(rng, 0, len(body))
    if mode == "swap":
        body[i], body[j] = body[j], body[i]
    elif mode == "duplicate_row":
        body.insert(i, body[i])
    elif mode == "duplicate_time":
        cells = body[j].split(",")
        cells[0] = body[i].split(",")[0]
        body[j] = ",".join(cells)
    elif mode == "reverse":
        body.reverse()
    else:
        body = [body[k] for k in rng.permutation(len(body))]
    return _join_csv([lines[0], *body, ""], newline), {"mode": mode, "i": i, "j": j}


def csv_structure(rng, data):
    """Rows with too many or too few cells, quoted newlines, blank lines, header only, whitespace, no newline."""
    lines, newline = _split_csv(data)
    mode = str(rng.choice(["extra_cells", "missing_cells", "quoted_newline", "blank_lines", "header_only",
                           "whitespace", "no_trailing_newline", "semicolons", "drop_column", "mixed_units",
                           "unquoted_quote", "long_line", "comment_line", "only_newlines"]))
    row = _data_line(rng, lines)
    if mode == "extra_cells":
        lines[row] += ",1,2,3"
    elif mode == "missing_cells":
        lines[row] = ",".join(lines[row].split(",")[:-2])
    elif mode == "quoted_newline":
        cells = lines[row].split(",")
        cells[-1] = f'"{cells[-1]}{newline}1.0"'
        lines[row] = ",".join(cells)
    elif mode == "blank_lines":
        lines.insert(row, "")
        lines.insert(row, ",,,,,,,")
    elif mode == "header_only":
        lines = [lines[0], ""]
    elif mode == "whitespace":
        lines = [",".join(f"  {c}\t " for c in line.split(",")) if line else line for line in lines]
    elif mode == "no_trailing_newline":
        lines = [line for line in lines if line]
    elif mode == "semicolons":
        lines = [line.replace(",", ";") for line in lines]
    elif mode == "drop_column":
        col = _pos(rng, 0, len(lines[0].split(",")))
        lines = [",".join(c for k, c in enumerate(line.split(",")) if k != col) if line else line
                 for line in lines]
    elif mode == "mixed_units":
        lines[0] = lines[0].replace("i3_mA", "i3_A").replace("i3_A", "i3_mA") + ",i1_A" if "_mA" in lines[0] \
            else lines[0] + ",i1_mA"
    elif mode == "unquoted_quote":
        lines[row] = '"' + lines[row]
    elif mode == "long_line":
        lines[row] += "," + "9" * 1_000_000
    elif mode == "comment_line":
        lines.insert(row, "# comment")
    else:
        lines = [""] * 5
    return _join_csv(lines, newline), {"mode": mode, "row": row}


CSV_OPERATORS: dict[str, Operator] = {
    **GENERIC_OPERATORS,
    "truncate_mid_number": csv_truncate_mid_number,
    "duplicate_column_name": csv_duplicate_column_name,
    "non_numeric_cell": csv_non_numeric_cell,
    "non_finite_cell": csv_non_finite_cell,
    "odd_time": csv_odd_time,
    "bad_encoding": csv_bad_encoding,
    "reorder_timestamps": csv_reorder_timestamps,
    "structure": csv_structure,
}

# --------------------------------------------------------------------------------------------------------------
# JSON operators

JSON_KEYS = ("tilt_deg", "azimuths_deg", "mount_rpy_deg")


def _json_value(rng, data) -> tuple[object, bool]:
    try:
        return json.loads(data), True
    except (ValueError, RecursionError):
        return None, False


def _json_with(values: dict, key: str, raw: str) -> bytes:
    """The object serialised with ``raw`` (JSON text, possibly non-standard) as the value of ``key``."""
    parts = [f"{json.dumps(k)}: {raw if k == key else json.dumps(v)}" for k, v in values.items()]
    if key not in values:
        parts.append(f"{json.dumps(key)}: {raw}")
    return ("{" + ", ".join(parts) + "}").encode("utf-8")


def _json_object(rng, data) -> dict:
    value, ok = _json_value(rng, data)
    return value if ok and isinstance(value, dict) else {"tilt_deg": 45.0}


def json_non_finite(rng, data):
    values = _json_object(rng, data)
    key = str(rng.choice(JSON_KEYS))
    token = str(rng.choice(["NaN", "Infinity", "-Infinity"]))
    raw = token if key == "tilt_deg" or rng.random() < 0.3 else (
        "[" + ", ".join([token] + ["0.0"] * (5 if key == "azimuths_deg" else 2)) + "]")
    return _json_with(values, key, raw), {"key": key, "raw": raw[:40]}


HUGE_NUMBERS = ("1e400", "-1e400", "1e308", "1e-400", "4.9e-324", "1" + "0" * 400, "1" + "0" * 5000,
                "-" + "9" * 4301, "0." + "0" * 5000 + "1", "123456789012345678901234567890")


def json_huge_number(rng, data):
    values = _json_object(rng, data)
    key = str(rng.choice(JSON_KEYS))
    number = str(rng.choice(np.array(HUGE_NUMBERS, dtype=object)))
    if key == "tilt_deg":
        raw = number
    else:
        items = ["1.0"] * (6 if key == "azimuths_deg" else 3)
        items[_pos(rng, 0, len(items))] = number
        raw = "[" + ", ".join(items) + "]"
    return _json_with(values, key, raw), {"key": key, "number": number[:30], "digits": len(number)}


def json_deep_nesting(rng, data):
    values = _json_object(rng, data)
    key = str(rng.choice([*JSON_KEYS, "top_level"]))
    depth = int(rng.choice([100, 1000, 10_000, 100_000]))
    opener, closer = ("[", "]") if rng.random() < 0.5 else ('{"a":', "}")
    raw = opener * depth + "1" + closer * depth
    if key == "top_level":
        return raw.encode(), {"key": key, "depth": depth, "opener": opener}
    return _json_with(values, key, raw), {"key": key, "depth": depth, "opener": opener}


WRONG_TYPES = ('"45"', "true", "false", "null", "{}", "[]", '{"x": 1}', "[[1, 2], 3]", '["a", "b"]', "[true]",
               "[null, 1, 2, 3, 4, 5]", "[1, 2]", "[1, 2, 3, 4, 5, 6, 7]", "0", "90", "-45", "1e-9", '"NaN"',
               "[" + ", ".join(["1"] * 100000) + "]", "[[]]", "[1.0, 2.0, 3.0]", "[0, 60, 120, 180, 240, 300]")


def json_wrong_type(rng, data):
    values = _json_object(rng, data)
    key = str(rng.choice(JSON_KEYS))
    raw = str(rng.choice(np.array(WRONG_TYPES, dtype=object)))
    return _json_with(values, key, raw), {"key": key, "raw": raw[:40]}


def json_structure(rng, data):
    mode = str(rng.choice(["top_array", "top_number", "top_string", "top_null", "unknown_key", "duplicate_key",
                           "trailing_garbage", "two_objects", "comments", "single_quotes", "trailing_comma",
                           "empty_key", "bom", "utf16", "invalid_utf8", "nul", "unicode_key", "many_keys"]))
    values = _json_object(rng, data)
    text = json.dumps(values)
    if mode == "top_array":
        out = ("[" + text + "]").encode()
    elif mode == "top_number":
        out = b"45"
    elif mode == "top_string":
        out = b'"tilt_deg"'
    elif mode == "top_null":
        out = b"null"
    elif mode == "unknown_key":
        out = _json_with(values, "tilt", "45")
    elif mode == "duplicate_key":
        out = (text[:-1] + (", " if values else "") + '"tilt_deg": 95}').encode()
    elif mode == "trailing_garbage":
        out = text.encode() + b" x"
    elif mode == "two_objects":
        out = (text + text).encode()
    elif mode == "comments":
        out = ("// device\n" + text).encode()
    elif mode == "single_quotes":
        out = text.replace('"', "'").encode()
    elif mode == "trailing_comma":
        out = (text[:-1] + ",}").encode()
    elif mode == "empty_key":
        out = _json_with(values, "", "1")
    elif mode == "bom":
        out = b"\xef\xbb\xbf" + text.encode()
    elif mode == "utf16":
        out = text.encode("utf-16")
    elif mode == "invalid_utf8":
        out = text.encode()[:-1] + b"\xff}"
    elif mode == "nul":
        out = text.encode().replace(b":", b":\x00", 1)
    elif mode == "unicode_key":
        out = _json_with(values, "tilt_deg\u0301", "45")
    else:
        out = ("{" + ", ".join(f'"k{i}": {i}' for i in range(100_000)) + "}").encode()
    return out, {"mode": mode}


JSON_OPERATORS: dict[str, Operator] = {
    **GENERIC_OPERATORS,
    "non_finite": json_non_finite,
    "huge_number": json_huge_number,
    "deep_nesting": json_deep_nesting,
    "wrong_type": json_wrong_type,
    "structure": json_structure,
}

OPERATORS: dict[str, dict[str, Operator]] = {"ulog": ULOG_OPERATORS, "sun_csv": CSV_OPERATORS,
                                             "device_json": JSON_OPERATORS}
#: Generic byte operators are drawn less often than the format-aware ones.
GENERIC_WEIGHT = 0.4


# --------------------------------------------------------------------------------------------------------------
# Cases


@dataclasses.dataclass(frozen=True)
class Case:
    """One fuzz input: reproducible with ``make_case(target, seeds, case_seed)`` (same seed list)."""

    target: str
    case_seed: int
    seed_name: str
    steps: tuple[tuple[str, Params], ...]
    data: bytes

    @property
    def key(self) -> str:
        return f"{self.target}:{self.case_seed}"

    def describe(self) -> str:
        steps = " + ".join(f"{name}({', '.join(f'{k}={v}' for k, v in params.items())})"
                           for name, params in self.steps)
        return f"case_seed={self.case_seed} seed={self.seed_name} {steps}"


def make_case(target: str, seeds: Sequence[Seed], case_seed: int) -> Case:
    """Case ``case_seed`` of ``target``: a seed file and 1-3 operators, all drawn from ``default_rng(case_seed)``."""
    rng = np.random.default_rng([case_seed, TARGETS.index(target)])
    seed = seeds[int(rng.integers(len(seeds)))]
    operators = OPERATORS[target]
    names = sorted(operators)
    weights = np.array([GENERIC_WEIGHT if name in GENERIC_OPERATORS else 1.0 for name in names])
    n_steps = int(rng.choice([1, 2, 3], p=[0.75, 0.2, 0.05]))
    data = seed.data
    steps = []
    for _ in range(n_steps):
        name = str(rng.choice(names, p=weights / weights.sum()))
        data, params = operators[name](rng, data)
        steps.append((name, params))
    if not data:
        data = b"\x00"
    return Case(target, case_seed, seed.name, tuple(steps), bytes(data))


def make_cases(target: str, seeds: Sequence[Seed], n: int, first_seed: int = 0) -> Iterator[Case]:
    for case_seed in range(first_seed, first_seed + n):
        yield make_case(target, seeds, case_seed)


# --------------------------------------------------------------------------------------------------------------
# Running one input (in a worker process)


@dataclasses.dataclass
class Outcome:
    """What a reader did with one input."""

    #: "loaded", "clean_error", "other_exception", "hang" or "crash".
    status: str
    elapsed_s: float
    #: For failures: "Type@file:line" (exception), "hang@file:function", "crash:SIGNAL@file:function".
    signature: str = ""
    message: str = ""
    detail: str = ""

    @property
    def failed(self) -> bool:
        return self.status not in ("loaded", "clean_error")


def _short_path(filename: str) -> str:
    """``ingest/ulog_reader.py``, ``pyulog/core.py``, ``json/decoder.py``: the path from the package on."""
    path = filename.replace("\\", "/")
    for package in ("/ingest/", "/tests/"):
        if package in path:
            return package.strip("/") + "/" + path.rsplit(package, 1)[1]
    for marker in ("/site-packages/", "/lib/python3"):
        if marker in path:
            path = path.split(marker, 1)[1]
            if marker == "/lib/python3":
                path = path.split("/", 1)[1] if "/" in path else path
            break
    return path


def exception_signature(exc: BaseException) -> tuple[str, str]:
    """``("Type@file:line", traceback text)`` with the innermost frame of the traceback (only the last frames are
    formatted: a RecursionError's traceback has thousands)."""
    last = collections.deque(maxlen=12)
    tb = exc.__traceback__
    while tb is not None:
        last.append(tb)
        tb = tb.tb_next
    frames = traceback.StackSummary.extract(((t.tb_frame, t.tb_lineno) for t in last), lookup_lines=True)
    where = f"{_short_path(frames[-1].filename)}:{frames[-1].lineno}" if frames else "?"
    text = "".join([*traceback.format_list(frames), *traceback.format_exception_only(type(exc), exc)])
    return f"{type(exc).__name__}@{where}", text[-4000:]


def run_reader(target: str, data: bytes) -> object:
    """Call the reader for ``target`` on ``data`` (in the current process). The target ``"_selftest"`` checks the
    harness itself: ``b"hang"`` sleeps, ``b"segv"`` kills the worker with SIGSEGV, ``b"raise"`` raises a
    RuntimeError, ``b"input_error"`` an InputError, anything else returns."""
    if target == "_selftest":
        from ingest.errors import InputError

        if data == b"hang":
            time.sleep(3600)
        elif data == b"segv":
            os.kill(os.getpid(), signal.SIGSEGV)
            time.sleep(10)
        elif data == b"raise":
            raise RuntimeError("selftest")
        elif data == b"input_error":
            raise InputError("selftest")
        return data
    if target == "ulog":
        from ingest.log_formats import load_flight_log

        return load_flight_log(data, name="fuzz.ulg")
    if target == "sun_csv":
        from ingest.sun_log import load_sun_log

        return load_sun_log(data, time_offset_s=CSV_TIME_OFFSET_S, name="fuzz.csv")
    if target == "device_json":
        from ingest.sun_log import load_sun_device

        return load_sun_device(data, name="fuzz.json")
    raise ValueError(f"unknown target {target!r}")


def classify(target: str, data: bytes) -> Outcome:
    """Run the reader and classify the result (in the current process: no hang or crash protection)."""
    from ingest.errors import InputError

    start = time.perf_counter()
    try:
        with contextlib.redirect_stdout(sys.stderr):
            run_reader(target, data)
    except InputError as exc:
        return Outcome("clean_error", time.perf_counter() - start, message=str(exc)[:300])
    except BaseException as exc:  # everything else is what we are looking for
        if isinstance(exc, KeyboardInterrupt):
            raise
        elapsed = time.perf_counter() - start
        signature, text = exception_signature(exc)
        return Outcome("other_exception", elapsed, signature, f"{type(exc).__name__}: {str(exc)[:300]}", text)
    return Outcome("loaded", time.perf_counter() - start)


# --------------------------------------------------------------------------------------------------------------
# Worker pool: long-lived worker processes fed through pipes; a worker that overruns the timeout is killed
# (hang), one that dies (signal, exit) is a crash; both are restarted. faulthandler writes the worker's stack to
# a file shortly before the timeout and on fatal signals, which names where it hung or crashed.


def _set_memory_limit(limit_bytes: int | None) -> None:
    if not limit_bytes:
        return
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
    except (ImportError, ValueError, OSError):
        pass


def _die_with_owner(owner_pid: int) -> None:
    """End this worker when the process that owns the pool is gone (a worker stuck in a hang would otherwise run
    on: its parent is the fork server, which outlives a killed owner)."""
    import threading

    def watch() -> None:
        while True:
            time.sleep(0.5)
            try:
                os.kill(owner_pid, 0)
            except ProcessLookupError:
                os._exit(1)
            except OSError:
                pass

    threading.Thread(target=watch, name="fuzz-owner-watch", daemon=True).start()


def default_warmup() -> list[tuple[str, bytes]]:
    """One small clean input per target (JIT caches and lazy imports load before any case is timed)."""
    ulog = min(ulog_seeds(sorted(SAMPLE_LOGS_DIR.glob("*.ulg")), data_bytes=16 * 1024), key=lambda s: len(s.data))
    return [("ulog", ulog.data), ("sun_csv", csv_seeds(5)[0].data), ("device_json", json_seeds()[0].data)]


def _worker_main(conn, trace_path: str, timeout_s: float, memory_limit_bytes: int | None,
                 warmup: Sequence[tuple[str, bytes]], code_root: str | None, owner_pid: int) -> None:
    import faulthandler

    _die_with_owner(owner_pid)
    if code_root:
        sys.path.insert(0, code_root)
        for name in [m for m in sys.modules if m == "ingest" or m.startswith("ingest.")]:
            del sys.modules[name]  # preloaded by a fork server started for another code root

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    trace = open(trace_path, "w+")  # noqa: SIM115 - lives as long as the worker
    faulthandler.enable(file=trace, all_threads=False)
    sys.stdout = sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - pyulog prints warnings
    _set_memory_limit(memory_limit_bytes)
    for target, data in warmup:
        classify(target, data)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            job = conn.recv()
        except EOFError:
            return
        if job is None:
            return
        key, target, data = job
        trace.seek(0)
        trace.truncate()
        faulthandler.dump_traceback_later(max(timeout_s * 0.9, timeout_s - 1.0), exit=False, file=trace)
        outcome = classify(target, data)
        faulthandler.cancel_dump_traceback_later()
        conn.send((key, dataclasses.asdict(outcome)))


#: Small functions called from the loop that really hangs: a hang is named after the loop, not after them.
HANG_HELPERS = frozenset({"__init__", "<lambda>", "<genexpr>", "<listcomp>", "<dictcomp>", "initialize",
                          "_check_packet_corruption", "parse_string", "_parse_string", "read", "seek", "tell"})


def _stack_signature(trace_text: str) -> tuple[str, str]:
    """``file:function`` of the innermost interesting frame of a faulthandler dump (most recent call first)."""
    frames = re.findall(r'File "([^"]+)", line (\d+) in (\S+)', trace_text)
    if not frames:
        return "?", trace_text
    preferred = [f for f in frames if ("/ingest/" in f[0] or "pyulog" in f[0]) and f[2] not in HANG_HELPERS]
    filename, _, function = (preferred or frames)[0]
    return f"{_short_path(filename)}:{function}", trace_text[-4000:]


#: Imported once in the fork server, so that a replacement worker starts in milliseconds, not seconds.
WORKER_PRELOAD = ["fuzz_mutations", "numpy", "pandas", "pyulog", "ingest.log_formats", "ingest.sun_log"]


def _worker_context(code_root: str | os.PathLike | None):
    """The multiprocessing context of the workers: a fork server that has imported the readers (POSIX), else
    spawn. With ``code_root`` the fork server does not import ``ingest``: each worker imports it from there."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([m for m in WORKER_PRELOAD if not (code_root and m.startswith("ingest"))])
    return ctx


class _Worker:
    """One worker process; it starts in the background and is ``ready`` once it has imported and warmed up."""

    def __init__(self, ctx, timeout_s, memory_limit_bytes, warmup, startup_timeout_s, code_root):
        fd, self.trace_path = tempfile.mkstemp(prefix="fuzz_trace_", suffix=".txt")
        os.close(fd)
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker_main, daemon=True,
                                   args=(child, self.trace_path, timeout_s, memory_limit_bytes, warmup, code_root,
                                         os.getpid()))
        self.process.start()
        child.close()
        self.ready = False
        self.startup_deadline = time.perf_counter() + startup_timeout_s
        self.job = None
        self.started = 0.0

    def check_ready(self) -> bool:
        """True once the worker has said it is ready; RuntimeError when it died or took too long to start."""
        if not self.ready:
            if self.conn.poll():
                try:
                    self.conn.recv()
                    self.ready = True
                except (EOFError, OSError):
                    pass
            if not self.ready and (not self.process.is_alive() or time.perf_counter() > self.startup_deadline):
                raise RuntimeError(f"fuzz worker failed to start (exit code {self.process.exitcode}): "
                                   f"{self.trace()[-2000:]}")
        return self.ready

    def send(self, job) -> None:
        self.job = job
        self.started = time.perf_counter()
        self.conn.send(job)

    def trace(self) -> str:
        try:
            return Path(self.trace_path).read_text(errors="replace")
        except OSError:
            return ""

    def stop(self, kill: bool = False) -> None:
        if self.process.is_alive():
            if kill or self.job is not None:
                self.process.kill()
            else:
                with contextlib.suppress(OSError, BrokenPipeError):
                    self.conn.send(None)
            self.process.join(5)
            if self.process.is_alive():
                self.process.kill()
                self.process.join()
        self.conn.close()
        with contextlib.suppress(OSError):
            os.unlink(self.trace_path)


class ReaderPool:
    """``workers`` long-lived reader processes with a per-input ``timeout_s`` and an address-space limit.

    ``warmup`` inputs (default :func:`default_warmup`) run in each worker before it takes jobs; ``code_root`` is
    put first on the workers' ``sys.path`` (to fuzz another copy of the readers, e.g. an export of HEAD). A worker
    killed after a hang or a crash is replaced in the background while the others go on.
    """

    def __init__(self, workers: int = 2, timeout_s: float = 10.0, memory_limit_bytes: int | None = 4 << 30,
                 warmup: Sequence[tuple[str, bytes]] | None = None, startup_timeout_s: float = 300.0,
                 code_root: str | os.PathLike | None = None):
        self.timeout_s = timeout_s
        self._ctx = _worker_context(code_root)
        warmup = default_warmup() if warmup is None else warmup
        self._args = (timeout_s, memory_limit_bytes, tuple(warmup), startup_timeout_s,
                      str(code_root) if code_root else None)
        self._workers = [_Worker(self._ctx, *self._args) for _ in range(workers)]
        self.restarts = 0

    def __enter__(self) -> ReaderPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for worker in self._workers:
            worker.stop()
        self._workers = []

    def _replace(self, index: int) -> None:
        self._workers[index].stop(kill=True)
        self._workers[index] = _Worker(self._ctx, *self._args)
        self.restarts += 1

    def run(self, jobs: Iterable[tuple[object, str, bytes]]) -> Iterator[tuple[object, Outcome]]:
        """Yield ``(key, Outcome)`` for each ``(key, target, data)`` job, in completion order."""
        jobs = iter(jobs)
        exhausted = False
        while True:
            for worker in self._workers:
                if worker.job is None and not exhausted and worker.check_ready():
                    job = next(jobs, None)
                    if job is None:
                        exhausted = True
                    else:
                        worker.send(job)
            busy = [i for i, w in enumerate(self._workers) if w.job is not None]
            if not busy and exhausted:
                return
            now = time.perf_counter()
            handles = {}
            for i, worker in enumerate(self._workers):
                if worker.job is not None or not worker.ready:
                    handles[worker.conn] = i
                    handles[worker.process.sentinel] = i
            wait_s = min([self._workers[i].started + self.timeout_s - now for i in busy] + [1.0])
            wait_ready(list(handles), timeout=max(0.0, wait_s) + 0.02)
            for i in range(len(self._workers)):
                worker = self._workers[i]
                if worker.job is None:
                    continue
                key = worker.job[0]
                if worker.conn.poll():
                    try:
                        _, outcome = worker.conn.recv()
                        worker.job = None
                        yield key, Outcome(**outcome)
                        continue
                    except (EOFError, OSError):
                        pass
                if not worker.process.is_alive():
                    worker.process.join()
                    code = worker.process.exitcode
                    elapsed = time.perf_counter() - worker.started
                    name = signal.Signals(-code).name if code is not None and code < 0 else f"exit{code}"
                    where, text = _stack_signature(worker.trace())
                    self._replace(i)
                    yield key, Outcome("crash", elapsed, f"crash:{name}@{where}", f"worker died ({name})", text)
                elif time.perf_counter() - worker.started > self.timeout_s:
                    time.sleep(0.05)  # let faulthandler finish writing
                    if worker.conn.poll():
                        continue  # answered right at the deadline: collected on the next pass
                    where, text = _stack_signature(worker.trace())
                    self._replace(i)
                    yield key, Outcome("hang", self.timeout_s, f"hang@{where}",
                                       f"no answer within {self.timeout_s:g} s", text)

    def classify_many(self, items: Sequence[tuple[str, bytes]]) -> list[Outcome]:
        """Outcomes of ``(target, data)`` items, in input order."""
        results: dict[int, Outcome] = {}
        for key, outcome in self.run((i, target, data) for i, (target, data) in enumerate(items)):
            results[key] = outcome
        return [results[i] for i in range(len(items))]


# --------------------------------------------------------------------------------------------------------------
# Minimisation (delta debugging by chunk removal while the signature persists)


def _ulog_units(data: bytes) -> list[tuple[int, int]]:
    """Removable units of a ULog: each message (the file header is kept), then any trailing bytes."""
    units = [(m.offset, m.end) for m in walk_messages(data)]
    end = units[-1][1] if units else ULOG_HEADER_BYTES
    if end < len(data):
        units.append((end, len(data)))
    return units


def _byte_units(data: bytes, start: int = 0) -> list[tuple[int, int]]:
    return [(i, i + 1) for i in range(start, len(data))]


def _block_units(data: bytes, size: int, start: int = 0) -> list[tuple[int, int]]:
    return [(i, min(i + size, len(data))) for i in range(start, len(data), size)]


def _line_units(data: bytes) -> list[tuple[int, int]]:
    units, start = [], 0
    for i, byte in enumerate(data):
        if byte == 0x0A:
            units.append((start, i + 1))
            start = i + 1
    if start < len(data):
        units.append((start, len(data)))
    return units


def _without(data: bytes, units: Sequence[tuple[int, int]], drop: range) -> bytes:
    keep_from = units[drop.start][0]
    keep_to = units[drop.stop - 1][1]
    return data[:keep_from] + data[keep_to:]


def ddmin(data: bytes, units_of: Callable[[bytes], list[tuple[int, int]]],
          still_fails: Callable[[list[bytes]], list[bool]], *, max_rounds: int = 400, batch: int = 2,
          log: Callable[[str], None] | None = None) -> bytes:
    """Remove runs of consecutive units (halving the run length) while ``still_fails`` holds; ``still_fails``
    takes a batch of candidates (tested in parallel) and returns one bool each."""
    rounds = 0
    units = units_of(data)
    chunk = max(1, len(units) // 2)
    while chunk >= 1 and rounds < max_rounds:
        units = units_of(data)
        progressed = False
        start = 0
        while start < len(units) and rounds < max_rounds:
            candidates, spans = [], []
            s = start
            while s < len(units) and len(candidates) < batch:
                span = range(s, min(s + chunk, len(units)))
                candidates.append(_without(data, units, span))
                spans.append(span)
                s += chunk
            rounds += 1
            if log is not None and rounds % 20 == 0:
                log(f"    ddmin round {rounds}: {len(data)} bytes, {len(units)} units, chunk {chunk}")
            verdicts = still_fails(candidates)
            hit = next((k for k, ok in enumerate(verdicts) if ok), None)
            if hit is not None:
                data = candidates[hit]
                units = units_of(data)
                progressed = True
                start = spans[hit].start  # retry at the same place: the units moved up
            else:
                start = s
        if not progressed:
            if chunk == 1:
                break
            chunk = max(1, chunk // 2)
    return data


_RUN = re.compile(rb"(.{1,6}?)\1{15,}", re.DOTALL)


def halve_runs(data: bytes, still_fails: Callable[[list[bytes]], list[bool]], max_steps: int = 20) -> bytes:
    """Halve every long run of a repeated short pattern at once (``[[[[`` and ``]]]]`` of deep nesting together,
    so that brackets stay balanced; the digits of a huge number) while the failure persists."""
    for _ in range(max_steps):
        candidate = _RUN.sub(lambda m: m.group(1) * (len(m.group(0)) // len(m.group(1)) // 2), data)
        if candidate == data or not still_fails([candidate])[0]:
            break
        data = candidate
    return data


def minimise(target: str, data: bytes, signature: str, pool: ReaderPool, *, max_rounds: int = 300,
             log: Callable[[str], None] | None = None) -> bytes:
    """A smaller input with the same failure signature: ULog messages (then bytes), text runs and lines (then
    bytes); hangs and crashes skip the byte phase (each still-failing candidate costs a timeout or a restart)."""
    def same(candidates: list[bytes]) -> list[bool]:
        outcomes = pool.classify_many([(target, c) for c in candidates])
        return [o.failed and signature_key(o.signature) == signature_key(signature) for o in outcomes]

    if target != "ulog":
        data = halve_runs(data, same)
    slow = signature.startswith(("hang", "crash"))  # every still-failing candidate costs a timeout
    if target == "ulog":
        data = ddmin(data, _ulog_units, same, max_rounds=max_rounds, log=log)
        for block in (1024, 64) if len(data) > 4096 else ():
            data = ddmin(data, lambda d, b=block: _block_units(d, b, ULOG_HEADER_BYTES), same,
                         max_rounds=max_rounds // 2, log=log)
        if len(data) < 8192 and not slow:
            data = ddmin(data, lambda d: _byte_units(d, ULOG_HEADER_BYTES), same, max_rounds=max_rounds // 2,
                         log=log)
    else:
        data = ddmin(data, _line_units, same, max_rounds=max_rounds, log=log)
        if len(data) < 4096 and not slow:
            data = ddmin(data, _byte_units, same, max_rounds=max_rounds, log=log)
    return data


def signature_key(signature: str) -> str:
    """The part of a signature that must persist while minimising (line numbers of hang frames vary)."""
    return signature


def signature_slug(signature: str) -> str:
    """A short file-name-safe name: ``RecursionError@pyulog/core.py:780`` -> ``recursionerror_core_780``."""
    kind, _, where = signature.partition("@")
    file_part, _, line = where.rpartition(":") if where.count(":") else (where, "", "")
    stem = Path(file_part).stem if file_part else ""
    slug = "_".join(p for p in (kind.replace("crash:", "crash_"), stem, line) if p)
    return re.sub(r"[^A-Za-z0-9_]+", "_", slug).strip("_").lower()[:60]


def corpus_files(root: Path = CORPUS_DIR) -> list[Path]:
    """Every input under ``root`` (``tests/data/fuzz/**``: the kept regression inputs), by extension."""
    return sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lstrip(".") in TARGET_OF_EXTENSION)
