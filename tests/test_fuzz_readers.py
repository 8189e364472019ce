"""Fuzz tests of the input readers: a seeded mutation run per reader and the kept regression corpus.

Contract: :func:`ingest.log_formats.load_flight_log`, :func:`ingest.sun_log.load_sun_log` and
:func:`ingest.sun_log.load_sun_device` each return a result or raise :class:`ingest.errors.InputError`; any other
exception, a hang (over the per-case time limit) or a crash (the worker dies) fails the test. Every input runs in
a worker process (``fuzz_mutations.ReaderPool``), so a hang or a segfault fails with the case's seed and
mutation instead of hanging or killing pytest.

Reproduce a failing CI case ``N`` of target ``T`` (the report prints it)::

    import fuzz_mutations as fm   # tests/ on sys.path
    case = fm.make_case(T, fm.ci_seeds(T), N); fm.classify(T, case.data)

The regression corpus ``tests/data/fuzz/<target>/*.{ulg,csv,json}`` holds minimised inputs that once broke a
reader (see ``tests/data/fuzz/README.md``); each must now load or raise InputError.
"""

from __future__ import annotations

import os
import time

import fuzz_mutations as fm
import pytest

#: Per-case time limit [s]: a clean seed loads in about 0.05 s, the slowest mutated case in 10000 took 1.3 s; a case
#: that takes longer than this under CI load is a hang.
CASE_TIMEOUT_S = 6.0
#: CI cases per target, split into chunks so that pytest-xdist can spread them over its workers.
CI_CASES = {"ulog": (300, 2), "sun_csv": (150, 1), "device_json": (100, 1)}
#: Case seeds of the CI run start here (the benchmark starts at 0).
CI_FIRST_SEED = 100_000
#: Stop a chunk after this many failures (each hang costs the time limit): enough to show the pattern.
MAX_FAILURES_REPORTED = 5

CHUNKS = [(target, chunk, n // n_chunks) for target, (n, n_chunks) in CI_CASES.items() for chunk in range(n_chunks)]


@pytest.fixture(scope="module")
def pool():
    """One reader worker per pytest(-xdist) process, warmed up on a small clean input of each target.

    ``SOLARNAV_FUZZ_CODE_ROOT=/tmp/old`` fuzzes the readers of another tree (e.g. ``git archive <commit> ingest |
    tar -x -C /tmp/old``), to check that these tests catch the bugs an older commit had."""
    warmup = [(target, min(fm.ci_seeds(target), key=lambda s: len(s.data)).data) for target in fm.TARGETS]
    with fm.ReaderPool(workers=1, timeout_s=CASE_TIMEOUT_S, memory_limit_bytes=4 << 30, warmup=warmup,
                       code_root=os.environ.get("SOLARNAV_FUZZ_CODE_ROOT") or None) as p:
        yield p


def _report(failures: list[tuple[str, fm.Outcome]]) -> str:
    lines = []
    for what, outcome in failures:
        lines.append(f"- {what}\n  -> {outcome.status} {outcome.signature}: {outcome.message}")
        tail = [line for line in outcome.detail.strip().splitlines() if line.strip()][-6:]
        lines += [f"     {line}" for line in tail]
    return "\n".join(lines)


def test_harness_classifies_hang_crash_and_exceptions():
    """The pool itself: a sleep is a hang, SIGSEGV a crash, RuntimeError another exception; the pool recovers."""
    items = [("_selftest", b"ok"), ("_selftest", b"input_error"), ("_selftest", b"raise"), ("_selftest", b"hang"),
             ("_selftest", b"segv"), ("_selftest", b"ok")]
    with fm.ReaderPool(workers=1, timeout_s=1.0, memory_limit_bytes=None) as p:
        statuses = [o.status for o in p.classify_many(items)]
        restarts = p.restarts
    assert statuses == ["loaded", "clean_error", "other_exception", "hang", "crash", "loaded"]
    assert restarts == 2


def test_ci_seeds_load_cleanly(pool):
    """Every seed loads unmutated (else its mutations would test nothing), and the cases are reproducible."""
    for target in fm.TARGETS:
        seeds = fm.ci_seeds(target)
        assert seeds, target
        outcomes = pool.classify_many([(target, seed.data) for seed in seeds])
        assert [o.status for o in outcomes] == ["loaded"] * len(seeds), [
            (s.name, o.status, o.message) for s, o in zip(seeds, outcomes, strict=True)]
        first, again = fm.make_case(target, seeds, CI_FIRST_SEED), fm.make_case(target, seeds, CI_FIRST_SEED)
        assert first.data == again.data and first.steps == again.steps
        changed = sum(fm.make_case(target, seeds, CI_FIRST_SEED + i).data != seeds[0].data for i in range(20))
        assert changed >= 15, f"{target}: the operators leave most inputs unchanged"


def test_ulog_seed_structure():
    """A seed cut at a message boundary walks to its exact end and has IMU samples in its data section."""
    for seed in fm.ci_seeds("ulog"):
        view = fm.UlogView.parse(seed.data)
        assert view.messages[-1].end == len(seed.data), seed.name
        imu_ids = view.topic_msg_ids(fm.IMU_TOPIC)
        assert imu_ids and len(view.data_messages_of(imu_ids)) >= 2, seed.name
        assert view.field_offset(fm.IMU_TOPIC, "timestamp") == 0, seed.name


@pytest.mark.parametrize(("target", "chunk", "n_cases"), CHUNKS, ids=[f"{t}-{c}" for t, c, _ in CHUNKS])
def test_fuzz_reader(pool, target, chunk, n_cases):
    """Seeded mutations of the seed files: each loads or raises InputError, within the time limit."""
    seeds = fm.ci_seeds(target)
    first = CI_FIRST_SEED + chunk * n_cases
    cases = {case.key: case for case in fm.make_cases(target, seeds, n_cases, first)}
    failures, statuses = [], []
    started = time.perf_counter()
    for key, outcome in pool.run((case.key, target, case.data) for case in cases.values()):
        statuses.append(outcome.status)
        if outcome.failed:
            case = cases[key]
            failures.append((f"fm.make_case({target!r}, fm.ci_seeds({target!r}), {case.case_seed}): "
                             f"{case.describe()[:300]}", outcome))
            if len(failures) >= MAX_FAILURES_REPORTED:
                break
    elapsed = time.perf_counter() - started
    assert not failures, (f"{len(failures)} failing case(s) after {len(statuses)} of {n_cases} {target} cases "
                          f"({elapsed:.0f} s):\n{_report(failures)}")
    assert len(statuses) == n_cases
    assert statuses.count("loaded") + statuses.count("clean_error") == n_cases


CORPUS = fm.corpus_files()


def test_corpus_present():
    """The regression corpus exists and every file is small."""
    assert CORPUS, f"no regression inputs under {fm.CORPUS_DIR}"
    big = [(p.name, p.stat().st_size) for p in CORPUS if p.stat().st_size >= 64 * 1024]
    assert not big, f"corpus files must stay under 64 KiB: {big}"


@pytest.mark.parametrize("path", CORPUS, ids=[f"{p.parent.name}/{p.name}" for p in CORPUS])
def test_regression_corpus(pool, path):
    """A minimised input that once broke a reader now loads or raises InputError, within the time limit."""
    target = fm.TARGET_OF_EXTENSION[path.suffix.lstrip(".")]
    outcome, = pool.classify_many([(target, path.read_bytes())])
    assert not outcome.failed, _report([(f"{path.relative_to(fm.REPO_DIR)} ({target})", outcome)])
