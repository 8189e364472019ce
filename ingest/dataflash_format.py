"""ArduPilot DataFlash ``.bin`` records: the message walk, the ``FMT`` definitions and numpy decoding.

A DataFlash log is a chain of records, each ``0xA3 0x95 <type id>`` followed by the fields of its type; the
``FMT`` records (type 128, 89 bytes) define every type: its id, record length, name, format string (one code per
field) and comma-separated column names. :func:`walk_records` finds every record in one pass (numba), resyncing
on the next ``0xA3 0x95`` after bytes that are not a record of a known type; :func:`read_formats` parses the
``FMT`` records and checks that each one is consistent; :func:`decode` gathers the records of one type into a
numpy structured array (one copy of their bytes, no Python object per message) and :func:`scaled` applies the
DataFlash scale of a field (docs/ingest.md, 'DataFlash').
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

#: First two bytes of every record.
HEAD_1, HEAD_2 = 0xA3, 0x95
HEADER_BYTES = 3
#: Type id and record length of ``FMT`` itself (fixed by the format; a file may not redefine it).
FMT_TYPE, FMT_LENGTH = 128, 89

#: numpy type and scale of each DataFlash format code (``libraries/AP_Logger/LogStructure.h``): c/C/e/E are
#: stored x100, L is degrees x1e7; n/N/Z are NUL-padded strings, a an int16[32] array.
FORMAT_CODES: dict[str, tuple[str, float]] = {
    "b": ("i1", 1.0), "B": ("u1", 1.0), "M": ("u1", 1.0), "h": ("<i2", 1.0), "H": ("<u2", 1.0),
    "i": ("<i4", 1.0), "I": ("<u4", 1.0), "q": ("<i8", 1.0), "Q": ("<u8", 1.0), "f": ("<f4", 1.0),
    "d": ("<f8", 1.0), "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01), "E": ("<u4", 0.01),
    "L": ("<i4", 1e-7), "n": ("S4", 1.0), "N": ("S16", 1.0), "Z": ("S64", 1.0), "a": ("(32,)<i2", 1.0),
}
#: Layout of an ``FMT`` record.
FMT_DTYPE = np.dtype([("head", "V3"), ("type", "u1"), ("length", "u1"), ("name", "S4"), ("format", "S16"),
                       ("columns", "S64")])


@dataclass(frozen=True)
class MessageFormat:
    """One message type as its ``FMT`` record defines it.

    Attributes
    ----------
    type_id : int
        Record type byte.
    name : str
        Message name (``"IMU"``, ``"XKF1"``).
    length : int
        Record length [bytes], header included.
    format : str
        One DataFlash format code per field.
    columns : tuple of str
        Field names.
    dtype : numpy.dtype
        Packed little-endian layout of one record (header field ``"_head"`` first).
    """

    type_id: int
    name: str
    length: int
    format: str
    columns: tuple[str, ...]
    dtype: np.dtype

    def scale(self, column: str) -> float:
        """Factor from the stored integer to the value DataFlash means (0.01 for c/C/e/E, 1e-7 for L)."""
        return FORMAT_CODES[self.format[self.columns.index(column)]][1]


@dataclass(frozen=True)
class RecordIndex:
    """Where the records are: ``type_ids`` and byte ``offsets`` in file order, plus what the walk skipped."""

    type_ids: np.ndarray
    offsets: np.ndarray
    skipped_bytes: int
    skipped_stretches: int
    end_offset: int


def walk_records(content: np.ndarray) -> RecordIndex:
    """Every record of ``content`` (uint8 array of the whole file): type id and offset, in file order.

    A byte that does not start a record of a type defined so far (``FMT`` records are read as the walk meets
    them) is skipped up to the next ``0xA3 0x95`` of a known type; a record cut off by the end of the file ends
    the walk at its offset (``end_offset``, the file length when the last record is complete).
    """
    count, _, _, _ = _walk(content, np.empty(0, np.uint8), np.empty(0, np.int64))
    type_ids, offsets = np.empty(count, np.uint8), np.empty(count, np.int64)
    _, skipped, stretches, end = _walk(content, type_ids, offsets)
    return RecordIndex(type_ids, offsets, int(skipped), int(stretches), int(end))


@njit(cache=True)
def _walk(content, type_ids, offsets):
    """One pass over the records: their count, skipped bytes and stretches, and the walk's end offset; fills
    ``type_ids`` / ``offsets`` when they are long enough (a counting pass gives them length 0)."""
    lengths = np.zeros(256, np.int64)
    lengths[FMT_TYPE] = FMT_LENGTH
    n_bytes = content.shape[0]
    fill = type_ids.shape[0] > 0
    count = skipped = stretches = 0
    offset = 0
    in_garbage = False
    while offset + HEADER_BYTES <= n_bytes:
        type_id = content[offset + 2]
        length = lengths[type_id]
        if content[offset] == HEAD_1 and content[offset + 1] == HEAD_2 and length > 0:
            if offset + length > n_bytes:
                break
            if type_id == FMT_TYPE and content[offset + 3] != FMT_TYPE and content[offset + 4] >= HEADER_BYTES:
                lengths[content[offset + 3]] = content[offset + 4]
            if fill:
                type_ids[count] = type_id
                offsets[count] = offset
            count += 1
            offset += length
            in_garbage = False
        else:
            stretches += 0 if in_garbage else 1
            in_garbage = True
            skipped += 1
            offset += 1
    return count, skipped, stretches, offset


def read_formats(content: np.ndarray, index: RecordIndex) -> tuple[dict[int, MessageFormat], list[str]]:
    """The message formats of the file's ``FMT`` records, by type id, and why any were rejected.

    A definition is rejected when a format code is unknown, its column count differs from its code count, or
    its length does not match the sum of its field sizes ("FMT lies"); a type defined twice with different
    layouts is rejected too (its records cannot all be decoded with one layout).
    """
    fmt_offsets = index.offsets[index.type_ids == FMT_TYPE]
    records = decode_at(content, fmt_offsets, FMT_DTYPE)
    formats: dict[int, MessageFormat] = {}
    rejected: dict[int, str] = {}
    for record in records:
        type_id = int(record["type"])
        if type_id == FMT_TYPE:
            continue
        name = _text(record["name"])
        parsed = _message_format(type_id, name, int(record["length"]), _text(record["format"]),
                                 _text(record["columns"]))
        if isinstance(parsed, str):
            rejected.setdefault(type_id, f"FMT of {name or type_id!r}: {parsed}")
        elif type_id in formats and formats[type_id] != parsed:
            rejected.setdefault(type_id, f"type {type_id} is defined twice with different layouts "
                                         f"({formats[type_id].name} {formats[type_id].format}, {name} "
                                         f"{parsed.format})")
        else:
            formats.setdefault(type_id, parsed)
    for type_id in rejected:
        formats.pop(type_id, None)
    return formats, list(rejected.values())


def _message_format(type_id: int, name: str, length: int, codes: str, columns_text: str) -> MessageFormat | str:
    """The checked format, or why the ``FMT`` record cannot be right."""
    unknown = sorted(set(codes) - set(FORMAT_CODES))
    if unknown:
        return f"unknown format codes {''.join(unknown)!r}"
    columns = tuple(columns_text.split(",")) if columns_text else ()
    if len(columns) != len(codes) or len(set(columns)) != len(columns):
        return f"{len(columns)} distinct column names for {len(codes)} format codes"
    dtype = record_dtype(codes, columns)
    if dtype.itemsize != length:
        return f"record length {length} bytes, but its format {codes!r} needs {dtype.itemsize}"
    return MessageFormat(type_id, name, length, codes, columns, dtype)


def record_dtype(codes: str, columns: tuple[str, ...]) -> np.dtype:
    """Packed layout of a record with format ``codes`` and field names ``columns`` (header field ``"_head"``)."""
    return np.dtype([("_head", "V3"), *((column, FORMAT_CODES[code][0])
                                        for column, code in zip(columns, codes, strict=True))])


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


def decode_at(content: np.ndarray, offsets: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Records of layout ``dtype`` at byte ``offsets`` of ``content``, as one structured array (a copy)."""
    return _gather(content, offsets, dtype.itemsize).view(dtype).reshape(len(offsets))


@njit(cache=True)
def _gather(content, offsets, length):
    """The ``length`` bytes at each of ``offsets``, one row each (a loop of copies: 10x numpy's fancy index)."""
    rows = np.empty((offsets.shape[0], length), np.uint8)
    for k in range(offsets.shape[0]):
        offset = offsets[k]
        for j in range(length):
            rows[k, j] = content[offset + j]
    return rows


def decode(content: np.ndarray, index: RecordIndex, fmt: MessageFormat) -> np.ndarray:
    """Every record of type ``fmt`` in file order, as a structured array of stored (unscaled) values."""
    return decode_at(content, index.offsets[index.type_ids == fmt.type_id], fmt.dtype)


def scaled(records: np.ndarray, fmt: MessageFormat, column: str) -> np.ndarray:
    """Field ``column`` of ``records`` as float64 in DataFlash's meaning (x0.01 for c/C/e/E, x1e-7 for L)."""
    with np.errstate(invalid="ignore"):  # a damaged float field casts to NaN quietly
        return records[column].astype(np.float64) * fmt.scale(column)


def text_column(records: np.ndarray, column: str) -> list[str]:
    """A string field (n/N/Z) as text, NUL padding removed."""
    return [_text(value) for value in records[column]]
