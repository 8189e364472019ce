"""Shared test fixtures: where the reference logs live."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_DIR = Path(__file__).resolve().parents[1]
REAL_LOGS_DIR = REPO_DIR.parent / "shared" / "real_logs"
SAMPLE_LOGS_DIR = REPO_DIR / "sample_logs"


@pytest.fixture(scope="session")
def real_logs_dir() -> Path:
    """``../shared/real_logs``: the public PX4 logs (read in place, never copied into the repo)."""
    if not REAL_LOGS_DIR.is_dir():
        reason = f"reference logs missing: {REAL_LOGS_DIR} (shared/ must sit beside the repository)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(reason)  # CI has shared/ beside the clone: a missing folder is a broken set-up
        pytest.skip(reason)
    return REAL_LOGS_DIR
