"""First start: the numba warm-up and its cache check (estimators/warmup.py), the CLI's compile message, and the
install stamp of scripts/bootstrap.sh.

The two cache tests compile in a fresh ``NUMBA_CACHE_DIR`` (a few minutes on two cores); the stamp test runs the
script against a fake venv whose ``python`` only records its arguments.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from types import SimpleNamespace

import pytest

from tests.conftest import REPO_DIR

#: A stand-in log without sun-device data (the replay itself is replaced in these tests).
NO_SUN_LOG = SimpleNamespace(has=lambda stream: False)

SAMPLE = REPO_DIR / "sample_logs" / "paper.ulg"


def _env(cache_dir) -> dict:
    return {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(REPO_DIR)}


def _python(args, cache_dir, timeout=1800) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=REPO_DIR, env=_env(cache_dir), capture_output=True,
                          text=True, timeout=timeout, check=False)


def test_cache_check_is_cold_on_an_empty_cache_and_warm_after_the_warm_up(tmp_path):
    cache = tmp_path / "numba"
    cold = _python(["-m", "estimators.warmup", "--check"], cache)
    assert cold.returncode == 1 and cold.stdout.startswith("cold"), cold.stdout + cold.stderr
    assert "no valid cache index" in cold.stdout
    assert "sun_solver: no valid cache index" in cold.stdout  # the Sun vector page's kernel is warmed too

    warmed = _python(["-m", "estimators.warmup"], cache)
    assert warmed.returncode == 0, warmed.stderr
    assert "compiling the estimators (first run only, about" in warmed.stdout
    assert "compiled the estimators in" in warmed.stdout and "sun-vector solver:" in warmed.stdout
    reported = [line.split(":")[0].strip() for line in warmed.stdout.splitlines() if line.startswith("  ")]
    assert sorted(reported) == sorted(["three_stage", "full_state_direct", "full_state_indirect", "sun-vector solver",
                                       "ULog reader"]), warmed.stdout  # from the two processes, each item once

    _assert_one_specialization_per_function(cache)

    warm = _python(["-m", "estimators.warmup", "--check"], cache)
    assert warm.returncode == 0 and warm.stdout.strip() == "warm", warm.stdout + warm.stderr
    again = _python(["-m", "estimators.warmup"], cache)
    assert again.returncode == 0 and "already compiled" in again.stdout and "compiling" not in again.stdout

    # A source newer than the cache index (a callee edited in another file, which numba itself ignores) makes the
    # cache stale, and prepare_compile then empties the package's indexes so numba recompiles.
    probe = textwrap.dedent("""
        import time
        from estimators import warmup
        kernels = warmup._entry_kernels()
        reason, stale = warmup._kernel_state(kernels["full_state_direct"], time.time() + 3600.0)
        print(stale, reason)
        assert warmup.drop_package_caches() > 10
        state = warmup.cache_state()
        print(state.warm, state.stale, len(state.cold))
    """)
    result = _python(["-c", probe], cache)
    assert result.returncode == 0, result.stderr
    first, second = result.stdout.strip().splitlines()
    assert first == "True a source the kernel depends on is newer than its cache"
    assert second == "False False 4"  # three filters, the sun solver


#: Cached functions allowed more than one specialization after the warm-up (docs/estimators.md, 'One compile per
#: function'): the array copies (float and bool arrays; a strided Jacobian block) and the quadratic form of the
#: three-stage output (a 3- and a 2-vector).
SEVERAL_SPECIALIZATIONS = {"core.linalg.copy_into", "core.linalg.copy_rows_into", "core.linalg.quadratic_form"}


def _cached_signatures(cache_dir) -> dict[str, list[str]]:
    """``package.module.function`` -> the argument types of every specialization in numba's cache indexes under
    ``cache_dir`` (one folder per source folder, ``<name>_<hash>``; an index is a pickled version, then a pickled
    ``(stamp, {key: file})`` with the signature first in the key)."""
    import pickle

    found: dict[str, list[str]] = {}
    for index in sorted(cache_dir.rglob("*.nbi")):
        with open(index, "rb") as f:
            pickle.load(f)
            _, overloads = pickle.loads(f.read())
        name = f"{index.parent.name.rsplit('_', 1)[0]}.{index.name.split('-')[0]}"
        found.setdefault(name, []).extend(str(key[0]) for key in overloads)
    return found


def _assert_one_specialization_per_function(cache_dir) -> None:
    signatures = _cached_signatures(cache_dir)
    assert len(signatures) > 100, sorted(signatures)  # the kernels' functions were cached
    several = {name: sigs for name, sigs in signatures.items() if len(sigs) > 1}
    literal = {name: sigs for name, sigs in several.items() if any("Literal[" in sig for sig in sigs)}
    assert not literal, f"compiled once per literal argument value: {literal}"
    assert set(several) <= SEVERAL_SPECIALIZATIONS, f"compiled more than once: {several}"


def test_the_warm_up_groups_cover_every_entry_kernel_and_the_ulog_reader_once():
    from estimators import warmup
    from estimators.api import DEFAULT_ESTIMATORS

    items = [item for group in warmup.WARM_GROUPS for item in group]
    assert len(items) == len(set(items))  # nothing compiled twice
    assert set(items) == {*warmup.ENTRY_KERNELS, warmup.ULOG_READER}
    assert set(DEFAULT_ESTIMATORS) <= set(items)


def test_warm_groups_keep_only_the_items_asked_for():
    from estimators import warmup

    assert warmup.warm_groups() == list(warmup.WARM_GROUPS)
    assert warmup.warm_groups(["three_stage"]) == [("three_stage",)]  # one group: compiled in the process itself
    assert warmup.warm_groups(["full_state_direct", "full_state_indirect"]) == [("full_state_direct",
                                                                                "full_state_indirect")]
    assert warmup.warm_groups(["full_state_indirect", "three_stage"]) == [("three_stage",), ("full_state_indirect",)]
    assert not warmup.compile_side_by_side(["full_state_direct", "full_state_indirect"])  # one group: left to the run


def test_replay_says_compiling_only_when_the_cache_is_cold(tmp_path):
    cache = tmp_path / "numba"
    command = ["-m", "app.cli", "replay", str(SAMPLE), "--estimators", "three_stage", "-o"]
    first = _python([*command, str(tmp_path / "first.parquet")], cache)
    assert first.returncode == 0, first.stderr
    assert "compiling the estimators (first run only) ..." in first.stderr
    assert "compiling the estimators" not in first.stdout  # the summary on stdout stays as it was
    second = _python([*command, str(tmp_path / "second.parquet")], cache)
    assert second.returncode == 0, second.stderr
    assert "compiling the estimators" not in second.stderr + second.stdout


FAKE_PYTHON = """#!/usr/bin/env bash
echo "$*" >> "$(dirname "$0")/../calls.log"
"""


def _bootstrap(venv, *args, warm_up=False) -> list[str]:
    """Run scripts/bootstrap.sh against the fake venv; the calls its python received in this run."""
    log = venv / "calls.log"
    log.unlink(missing_ok=True)
    env = {**os.environ, "SOLARNAV_VENV": str(venv), "SOLARNAV_SKIP_WARMUP": "0" if warm_up else "1"}
    subprocess.run(["bash", str(REPO_DIR / "scripts" / "bootstrap.sh"), *args], env=env, check=True, timeout=60)
    return log.read_text().splitlines() if log.exists() else []


def _installs(calls: list[str]) -> list[str]:
    return [call.split()[-1] for call in calls if call.startswith("-m pip install --quiet -e")]


def test_bootstrap_keeps_one_install_stamp_with_dev_as_a_superset(tmp_path):
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    python = venv / "bin" / "python"
    python.write_text(FAKE_PYTHON)
    python.chmod(0o755)
    stamp = venv / ".solarnav-installed"

    assert _installs(_bootstrap(venv)) == ["."]  # fresh venv: plain install
    assert stamp.read_text().strip() == ""
    assert _bootstrap(venv) == []  # done already
    assert _installs(_bootstrap(venv, "dev")) == [".[dev]"]  # plain done, dev needed: install dev
    assert stamp.read_text().strip() == "dev"
    assert _bootstrap(venv) == []  # dev done: the plain install is satisfied (no reinstall)
    assert _bootstrap(venv, "dev") == []
    os.utime(stamp, (0, 0))  # pyproject.toml changed since: reinstall, keeping the dev extras
    assert _installs(_bootstrap(venv)) == [".[dev]"]
    assert sorted(p.name for p in venv.glob(".solarnav-installed*")) == [".solarnav-installed"]

    # the old script's separate dev stamp is taken over (and removed)
    stamp.unlink()
    (venv / ".solarnav-installed[dev]").touch()
    assert _bootstrap(venv) == []
    assert stamp.read_text().strip() == "dev"
    assert not (venv / ".solarnav-installed[dev]").exists()

    # the warm-up runs after the install check (the real one is quick on a warm cache)
    assert _bootstrap(venv, warm_up=True) == ["-m estimators.warmup"]


class _Stop(Exception):
    pass


def test_dashboard_progress_says_compiling_only_for_a_cold_filter(monkeypatch):
    from app import runs
    from estimators.warmup import CacheState

    def stop(*args, **kwargs):
        raise _Stop

    monkeypatch.setattr(runs, "replay_log", stop)
    texts = []
    for warm in (False, True):
        monkeypatch.setattr(runs, "prepare_compile", lambda names, warm=warm: None if warm else "compiling")
        monkeypatch.setattr(runs, "cache_state", lambda names, warm=warm: CacheState(warm=warm))
        with pytest.raises(_Stop):
            runs.replay(NO_SUN_LOG, runs.RunSettings(), progress=lambda fraction, text: texts.append(text))
    assert texts == ["Compiling the estimators (first run only) for three_stage, full_state_direct, "
                     "full_state_indirect: checking the inputs ...", "Checking the inputs ..."]
