"""One thread map for the layers above: work whose heavy part releases the GIL (numba ``nogil`` kernels, numpy and
scipy array code) runs side by side on the CPUs."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor


def thread_map(function: Callable, items: Sequence, workers: int | None = None) -> list:
    """``[function(item) for item in items]``, in order, on ``workers`` threads (default one per CPU, at most one
    per item); in this thread when there is one worker or fewer than two items."""
    workers = min(len(items), os.cpu_count() or 1) if workers is None else max(1, int(workers))
    if workers < 2 or len(items) < 2:
        return [function(item) for item in items]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(function, items))
