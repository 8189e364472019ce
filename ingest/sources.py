"""What the readers accept as a file: a path, raw bytes, or a file object (a Streamlit upload)."""

from __future__ import annotations

import os
from pathlib import Path

UPLOAD_NAME = "<upload>"


def source_name(source: object) -> str:
    """Base name of a path or of a file object's ``name``; ``"<upload>"`` for nameless content."""
    if isinstance(source, (str, os.PathLike)):
        return Path(source).name
    return Path(str(getattr(source, "name", UPLOAD_NAME))).name
