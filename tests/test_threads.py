"""ingest.threads.thread_map: results in input order, on several threads when asked, inline otherwise."""

from __future__ import annotations

import threading
import time

from ingest.threads import thread_map


def test_results_keep_the_input_order_and_two_workers_use_two_threads():
    def slow_square(x):
        time.sleep(0.05 * (5 - x))  # the first items finish last
        return x * x, threading.get_ident()

    results = thread_map(slow_square, list(range(5)), workers=2)
    assert [value for value, _ in results] == [0, 1, 4, 9, 16]
    assert len({ident for _, ident in results}) == 2
    assert threading.get_ident() not in {ident for _, ident in results}


def test_one_worker_or_one_item_runs_in_the_calling_thread():
    here = threading.get_ident()
    assert thread_map(lambda x: threading.get_ident(), [1, 2, 3], workers=1) == [here] * 3
    assert thread_map(lambda x: threading.get_ident(), [1]) == [here]
    assert thread_map(lambda x: x, []) == []
