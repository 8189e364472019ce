"""Vectorised writer of the ULog file format (PX4 dev guide "ULog File Format", version 1).

pyulog's ``ULog.write_ulog`` packs every field of every row with ``struct.pack`` (minutes for a one-hour
250 Hz log); this writer lays out the same bytes with numpy structured arrays. The byte stream equals what
pyulog's own writer produces from the parsed file (a test checks it): file header, flag bits, formats, info
messages, initial parameters, subscriptions, then the data messages of all topics merged by timestamp (stable:
ties keep the topic order, then the row order).

A topic is a name plus a numpy structured array whose first field is ``timestamp`` (uint64 microseconds);
sub-array fields become ULog arrays (``float[3] gyro_rad`` is read back by pyulog as ``gyro_rad[0..2]``).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence

import numpy as np

HEADER_MAGIC = b"ULog\x01\x12\x35"
FILE_VERSION = 1
#: ULog type name of each numpy scalar type (little-endian on disk).
ULOG_TYPES = {np.dtype(np.uint8): "uint8_t", np.dtype(np.int8): "int8_t", np.dtype(np.uint16): "uint16_t",
              np.dtype(np.int16): "int16_t", np.dtype(np.uint32): "uint32_t", np.dtype(np.int32): "int32_t",
              np.dtype(np.uint64): "uint64_t", np.dtype(np.int64): "int64_t", np.dtype(np.float32): "float",
              np.dtype(np.float64): "double", np.dtype(np.bool_): "bool"}
#: Rows merged per block when writing the data section (bounds the memory of the index arrays).
_BLOCK_ROWS = 65536


def _message(msg_type: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(msg_type)) + payload


def _key_value(type_name: str, name: str, value: bytes) -> bytes:
    key = f"{type_name} {name}".encode()
    return struct.pack("<B", len(key)) + key + value


def _info(name: str, value: str | int) -> bytes:
    if isinstance(value, str):
        encoded = value.encode()
        return _message("I", _key_value(f"char[{len(encoded)}]", name, encoded))
    return _message("I", _key_value("uint32_t", name, struct.pack("<I", value)))


def _parameter(name: str, value: int | float) -> bytes:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"parameter {name} must be int (int32) or float (float32), got {value!r}")
    if isinstance(value, int):
        return _message("P", _key_value("int32_t", name, struct.pack("<i", value)))
    return _message("P", _key_value("float", name, struct.pack("<f", value)))


def _format(name: str, dtype: np.dtype) -> bytes:
    fields = []
    for field_name in dtype.names:
        base, shape = dtype[field_name].base, dtype[field_name].shape
        if base not in ULOG_TYPES or len(shape) > 1:
            raise TypeError(f"topic {name}: field {field_name} has unsupported type {dtype[field_name]}")
        array = f"[{shape[0]}]" if shape else ""
        fields.append(f"{ULOG_TYPES[base]}{array} {field_name};")
    return _message("F", f"{name}:{''.join(fields)}".encode())


def _records(msg_id: int, data: np.ndarray) -> np.ndarray:
    """Data messages of one topic as a (rows, bytes) uint8 array: header, msg_id, packed little-endian fields."""
    fields = [(name, data.dtype[name].base.newbyteorder("<"), data.dtype[name].shape) for name in data.dtype.names]
    packed = np.dtype([("msg_size", "<u2"), ("msg_type", "u1"), ("msg_id", "<u2"), *fields])
    records = np.empty(len(data), dtype=packed)
    records["msg_size"] = packed.itemsize - 3
    records["msg_type"] = ord("D")
    records["msg_id"] = msg_id
    for name in data.dtype.names:
        records[name] = data[name]
    return records.view(np.uint8).reshape(len(data), packed.itemsize)


def _data_section(topics: Sequence[tuple[str, np.ndarray]]) -> bytes:
    records = [_records(msg_id, data) for msg_id, (_, data) in enumerate(topics)]
    topic_of = np.concatenate([np.full(len(data), i) for i, (_, data) in enumerate(topics)])
    row_of = np.concatenate([np.arange(len(data)) for _, data in topics])
    order = np.argsort(np.concatenate([data["timestamp"] for _, data in topics]), kind="stable")
    sizes = np.array([rec.shape[1] for rec in records])
    blocks = []
    for start in range(0, len(order), _BLOCK_ROWS):
        rows = order[start:start + _BLOCK_ROWS]
        row_sizes = sizes[topic_of[rows]]
        offsets = np.cumsum(row_sizes) - row_sizes
        block = np.empty(int(row_sizes.sum()), dtype=np.uint8)
        for i, rec in enumerate(records):
            mine = topic_of[rows] == i
            if mine.any():
                block[offsets[mine][:, None] + np.arange(rec.shape[1])] = rec[row_of[rows[mine]]]
        blocks.append(block.tobytes())
    return b"".join(blocks)


def ulog_bytes(topics: Sequence[tuple[str, np.ndarray]], *, info: Mapping[str, str | int] = (),
               parameters: Mapping[str, int | float] = ()) -> bytes:
    """The complete ULog file.

    Parameters
    ----------
    topics : sequence of (str, numpy structured array)
        Topic name and rows; the first field must be ``timestamp`` (uint64 [us]). Each topic is logged once
        (multi_id 0) with msg_id = its position in the sequence.
    info : mapping
        Information messages: ``str`` values as ``char[n]``, ``int`` values as ``uint32_t`` (``ver_data_format``).
    parameters : mapping
        Initial parameters: ``int`` as ``int32_t``, ``float`` as ``float`` (PX4's two parameter types).

    Returns
    -------
    bytes
        File header timestamp = the earliest row timestamp.
    """
    for name, data in topics:
        if data.dtype.names is None or data.dtype.names[0] != "timestamp" or data.dtype["timestamp"] != np.uint64:
            raise TypeError(f"topic {name}: the first field must be 'timestamp' of type uint64")
    start = min((int(data["timestamp"].min()) for _, data in topics if len(data)), default=0)
    parts = [HEADER_MAGIC, struct.pack("<BQ", FILE_VERSION, start),
             _message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))]
    parts += [_format(name, data.dtype) for name, data in topics]
    parts += [_info(name, value) for name, value in dict(info).items()]
    parts += [_parameter(name, value) for name, value in dict(parameters).items()]
    parts += [_message("A", struct.pack("<BH", 0, msg_id) + name.encode()) for msg_id, (name, _) in enumerate(topics)]
    parts.append(_data_section(topics))
    return b"".join(parts)
