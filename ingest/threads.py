"""One thread map for the layers above: work whose heavy part releases the GIL (numba ``nogil`` kernels, numpy and
scipy array code) runs side by side on the CPUs."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")


def thread_map(function: Callable, items: Sequence, workers: int | None = None) -> list:
    """``[function(item) for item in items]``, in order, on ``workers`` threads (default one per CPU, at most one
    per item); in this thread when there is one worker or fewer than two items."""
    workers = min(len(items), os.cpu_count() or 1) if workers is None else max(1, int(workers))
    if workers < 2 or len(items) < 2:
        return [function(item) for item in items]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(function, items))


def in_background(function: Callable[..., T], *args) -> Callable[[], T]:
    """Start ``function(*args)`` on a side thread (work that releases the GIL: hashing, numpy) and return the
    call that waits for its result (re-raising its exception)."""
    pool = ThreadPoolExecutor(max_workers=1)
    future = pool.submit(function, *args)
    pool.shutdown(wait=False)
    return future.result
