"""What the readers accept as a file: a path, raw bytes, or a binary file object (a Streamlit upload)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO

from ingest.errors import FileTooLargeError, InputError

UPLOAD_NAME = "<upload>"

#: A file given by path, by content, or as an open file object.
Source = str | os.PathLike | bytes | bytearray | memoryview | IO


def source_name(source: Source) -> str:
    """Base name of a path or of a file object's ``name``; ``"<upload>"`` for nameless content."""
    if isinstance(source, (str, os.PathLike)):
        return Path(source).name
    return Path(str(getattr(source, "name", UPLOAD_NAME))).name


def read_content(source: Source, *, name: str | None = None,
                 max_bytes: int | None = None) -> tuple[bytes, str]:
    """The whole content of ``source`` and the name to show for it.

    Parameters
    ----------
    source : path, bytes or file object
        A text file object is read and encoded as UTF-8.
    name : str, optional
        Display name; default :func:`source_name`.
    max_bytes : int, optional
        Size limit [bytes]; a path is checked before it is read, a file object is read one byte past the limit.

    Raises
    ------
    FileTooLargeError
        The content is larger than ``max_bytes``.
    InputError
        The file cannot be read, or it is empty.
    """
    name = name or source_name(source)
    if isinstance(source, (bytes, bytearray, memoryview)):
        content = bytes(source)
    elif isinstance(source, (str, os.PathLike)):
        path = Path(source)
        try:
            size_bytes = path.stat().st_size
            if max_bytes is not None and size_bytes > max_bytes:
                raise FileTooLargeError(f"file is {size_bytes} bytes, over the limit of {max_bytes} bytes",
                                        source=name)
            content = path.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read the file ({exc.strerror or exc})", source=str(path)) from exc
    else:
        content = source.read() if max_bytes is None else source.read(max_bytes + 1)
        if isinstance(content, str):
            content = content.encode()
    if max_bytes is not None and len(content) > max_bytes:
        raise FileTooLargeError(f"file is over the limit of {max_bytes} bytes", source=name)
    if not content:
        raise InputError("the file is empty", source=name)
    return content, name
