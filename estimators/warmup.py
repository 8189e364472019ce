"""Compile the three filters once (warm numba's on-disk cache) and tell whether that cache is warm.

The filters' loops are numba functions compiled with ``cache=True``: the first run in a fresh clone (or after an
edit of a kernel source) compiles them, which takes minutes; later processes load the machine code from the cache
(``__pycache__`` beside each source file, or ``NUMBA_CACHE_DIR``) in seconds.

* :func:`warm_up` runs each filter on a tiny synthetic flight (straight level flight, a few seconds), which compiles
  and caches every kernel a replay of a real log uses (same argument types), solves the sun vector of a few
  synthetic photocell samples (the adaptive least-squares kernel the sun heading and the Sun vector page use), warms
  the ULog reader's numba function, and returns the time it took. It compiles in two processes side by side
  (:data:`WARM_GROUPS`) when the machine has two CPUs.
* :func:`cache_state` says, without compiling anything, whether a replay would compile (:attr:`CacheState.warm`).
* :func:`prepare_compile` is what a command calls before running the estimators: if the cache is cold it drops a
  stale cache (see below) so the compile really happens, and returns the message to show.

What the check detects, per entry kernel (the ``run_kernel`` of each filter, the sun solver's
``adaptive_kernel``):

* no cache index, an index of another numba version, Python version or CPU (numba's own key), an index whose
  recorded source stamp (modification time and size of the kernel's own file) differs, or whose entries were made
  from other bytecode of the kernel function, or whose data file is missing -- numba itself would compile;
* a changed *callee in another file*: numba does not notice this (it checks only the stamp of the file defining the
  cached function, and would load the stale machine code). The check therefore also compares the index file's
  modification time with that of every estimators source that imports numba and of the estimators modules those
  import (constants are frozen into the machine code): any of them newer than the index makes the cache stale.
  :func:`prepare_compile` and :func:`warm_up` then empty the index of every cached numba function of the package
  (``Cache.flush``), so numba recompiles instead of loading stale code.

What it does not detect: a change in a module outside ``estimators`` (numpy, numba internals are covered by
numba's version key only), a source file whose modification time was set back (e.g. restored from an archive with
old times), and a kernel called with argument types the warm-up does not produce (then numba compiles that
signature on first use, silently). The ULog and DataFlash readers' numba functions are warmed, not checked.
It may report stale for an edit that did not touch any numba code (any newer
source file counts); the price is one needless compile.
"""

from __future__ import annotations

import importlib
import math
import os
import re
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

#: What a command shows (progress text, CLI line) before a compile.
COMPILE_MESSAGE = "compiling the estimators (first run only)"
#: Estimator name -> module whose ``run_kernel`` its replay calls from Python (the filter's entry point).
KERNEL_MODULES = {"three_stage": "estimators.three_stage.kernel", "full_state_direct": "estimators.direct.kernel",
                  "full_state_indirect": "estimators.indirect.kernel"}
#: Name of the sun-vector solver in :func:`cache_state` (its kernel compiles like a filter's).
SUN_SOLVER = "sun_solver"
#: Entry kernel of each estimator and of the sun solver: (module, function) called from Python.
ENTRY_KERNELS = {**{name: (module, "run_kernel") for name, module in KERNEL_MODULES.items()},
                 SUN_SOLVER: ("estimators.sun.solver_kernel", "adaptive_kernel")}
#: The package directory.
PACKAGE_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class CacheState:
    """Result of :func:`cache_state`.

    Attributes
    ----------
    warm : bool
        A replay of all three filters loads every entry kernel from the cache (no compile).
    cold : tuple of str
        ``module: reason`` of each entry kernel that would be compiled.
    stale : bool
        At least one kernel has a cache entry that numba would load although a source it depends on is newer
        (:func:`prepare_compile` drops such caches).
    """

    warm: bool
    cold: tuple[str, ...] = ()
    stale: bool = False


#: Module named by an import statement (``import a.b`` / ``from a.b import c``, indented ones too).
_IMPORT = re.compile(r"^[ \t]*(?:from|import)[ \t]+([A-Za-z_][\w.]*)", re.MULTILINE)


def _numba_sources() -> list[Path]:
    """Estimators sources that import numba, plus the estimators modules they import (their constants are compiled
    into the kernels)."""
    found: set[Path] = set()
    for path in PACKAGE_DIR.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        if "numba" not in text or path.resolve() == Path(__file__).resolve():  # this module compiles nothing
            continue
        names = _IMPORT.findall(text)
        if not any(name == "numba" or name.startswith("numba.") for name in names):
            continue
        found.add(path)
        for name in names:
            if name.startswith("estimators."):
                target = PACKAGE_DIR.parent.joinpath(*name.split("."))
                for candidate in (target.with_suffix(".py"), target / "__init__.py"):
                    if candidate.is_file():
                        found.add(candidate)
    return sorted(found)


def _entry_kernels(estimators: Iterable[str] | None = None) -> dict[str, object]:
    """Estimator name (or :data:`SUN_SOLVER`) -> its entry kernel's dispatcher (importing compiles nothing); all of
    them by default."""
    names = ENTRY_KERNELS if estimators is None else [name for name in estimators if name in ENTRY_KERNELS]
    return {name: getattr(importlib.import_module(ENTRY_KERNELS[name][0]), ENTRY_KERNELS[name][1]) for name in names}


def _kernel_state(dispatcher, newest_source_mtime: float) -> tuple[str | None, bool]:
    """(why the kernel would compile or None, whether a loadable entry is stale)."""
    cache = getattr(dispatcher, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    if cache_file is None:  # numba internals changed or caching disabled: cannot tell, assume a compile
        return "numba cache not inspectable", False
    index = Path(cache_file._index_path)
    overloads = cache_file._load_index()  # {} when missing, other numba version or other source stamp
    if not overloads:
        return f"no valid cache index ({index.name})", False
    wanted = cache._index_key(None, dispatcher.targetctx.codegen())[1:]  # (CPU/numba magic, bytecode hashes)
    usable = [name for key, name in overloads.items()
              if tuple(key[1:]) == wanted and (index.parent / name).is_file()]
    if not usable:
        return "no cache entry for this machine and kernel code", False
    if index.stat().st_mtime < newest_source_mtime:
        return "a source the kernel depends on is newer than its cache", True
    return None, False


def cache_state(estimators: Iterable[str] | None = None) -> CacheState:
    """Whether replaying the filters and solving the sun vector (default all; else the named ones, unknown names
    ignored; :data:`SUN_SOLVER` names the solver) would compile.

    Compiles nothing (about 0.1 s once the estimators are imported). See the module docstring for what this detects
    and what it does not.
    """
    newest = max(path.stat().st_mtime for path in _numba_sources())
    cold, stale = [], False
    for name, dispatcher in _entry_kernels(estimators).items():
        reason, is_stale = _kernel_state(dispatcher, newest)
        if reason is not None:
            cold.append(f"{name}: {reason}")
            stale = stale or is_stale
    return CacheState(warm=not cold, cold=tuple(cold), stale=stale)


def is_cache_warm(estimators: Iterable[str] | None = None) -> bool:
    """``cache_state(estimators).warm``."""
    return cache_state(estimators).warm


def drop_package_caches() -> int:
    """Empty the cache index of every cached numba function in the estimators package (numba then recompiles
    them); returns how many indexes were emptied."""
    from numba.core.registry import CPUDispatcher

    _entry_kernels()
    count = 0
    for module_name, module in list(sys.modules.items()):
        if not module_name.startswith("estimators.") or module is None:
            continue
        for value in list(vars(module).values()):
            if not isinstance(value, CPUDispatcher) or value.__module__ != module_name:
                continue
            cache_file = getattr(getattr(value, "_cache", None), "_cache_file", None)
            if cache_file is not None and os.path.exists(cache_file._index_path):
                value._cache.flush()
                count += 1
    return count


def prepare_compile(estimators: Iterable[str] | None = None) -> str | None:
    """Call before running the estimators (default all three, else the named ones): None when their cache is warm;
    otherwise (after dropping a stale cache, which numba would load silently) :data:`COMPILE_MESSAGE`."""
    state = cache_state(estimators)
    if state.warm:
        return None
    if state.stale:
        drop_package_caches()
    return COMPILE_MESSAGE


def synthetic_flight(duration_s: float = 6.0, imu_hz: float = 200.0):
    """A tiny fixed-wing flight for :func:`warm_up`: straight and level at 15 m/s heading 30 deg, noise-free, with
    IMU, magnetometer, barometer, GPS and airspeed (every measurement kind a replay without sun uses)."""
    from estimators import environment
    from ingest.flightlog import FlightLog, LogMetadata

    lat0, lon0, alt0, yaw = 35.0, 108.9, 630.0, math.radians(30.0)
    g = float(environment.local_gravity_m_s2(lat0, alt0))
    t = 1000.0 + np.arange(0.0, duration_s, 1.0 / imu_hz)
    n = len(t)

    def frame(times, columns: dict) -> pd.DataFrame:
        return pd.DataFrame(columns, index=pd.Index(times, name="time_s"))

    imu = {"gyro_x_rad_s": 0.0, "gyro_y_rad_s": 0.0, "gyro_z_rad_s": 0.0, "accel_x_m_s2": 0.0,
           "accel_y_m_s2": 0.0, "accel_z_m_s2": -g}
    streams = {"imu": frame(t, {k: np.full(n, v) for k, v in imu.items()})}
    c, s = math.cos(yaw), math.sin(yaw)
    r_bn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # NED -> body, level flight
    field_b = r_bn @ environment.earth_field_ned_gauss(lat0, lon0, alt0, 2020.0)
    t_mag = t[::4]
    streams["mag"] = frame(t_mag, {f"mag_{a}_gauss": np.full(len(t_mag), field_b[i]) for i, a in enumerate("xyz")})
    t_baro = t[1::4]
    streams["baro"] = frame(t_baro, {"alt_m": np.full(len(t_baro), alt0),
                                     "pressure_pa": np.full(len(t_baro), environment.isa_pressure_pa(alt0)),
                                     "temp_c": np.full(len(t_baro), 20.0)})
    t_air = t[2::4]
    streams["airspeed"] = frame(t_air, {"ias_m_s": np.full(len(t_air), 15.0), "tas_m_s": np.full(len(t_air), 15.0)})
    t_gps = t[3::20]
    north, east = 15.0 * c * (t_gps - t[0]), 15.0 * s * (t_gps - t[0])
    lat, lon, alt = environment.ned_to_geodetic(north, east, np.zeros(len(t_gps)), lat0, lon0, alt0)
    m = len(t_gps)
    streams["gps"] = frame(t_gps, {"lat_deg": lat, "lon_deg": lon, "alt_m": alt, "vn_m_s": np.full(m, 15.0 * c),
                                   "ve_m_s": np.full(m, 15.0 * s), "vd_m_s": np.zeros(m), "eph_m": np.full(m, 0.7),
                                   "epv_m": np.full(m, 0.5), "fix_type": np.full(m, 3),
                                   "time_utc_s": 1.6e9 + t_gps, "speed_accuracy_m_s": np.full(m, 0.1)})
    meta = LogMetadata(source="warmup-synthetic.ulg", vehicle_type=1, start_time_s=float(t[0]),
                       end_time_s=float(t[-1]), duration_s=float(t[-1] - t[0]), utc_offset_s=1.6e9)
    return FlightLog(streams=streams, meta=meta)


#: The ULog reader's numba functions in :data:`WARM_GROUPS`.
ULOG_READER = "ulog_reader"
#: What :func:`warm_up` compiles, in two groups of about equal cold-compile time that two processes compile side
#: by side (measured cold on this project's two-core machine, two processes: the three-stage filter 28 s, the
#: full-state direct 20 s, the error-state filter 13 s after it (their shared functions already compiled), the
#: sun-vector solver 10 s, the ULog reader 1-3 s). Numba's compiler lock serialises compiles within one process, so
#: threads would not help; the processes share the on-disk cache (numba writes it atomically, one file per function).
WARM_GROUPS = (("three_stage", SUN_SOLVER, ULOG_READER), ("full_state_direct", "full_state_indirect"))
#: What :func:`warm_up` reports per item.
WARM_LABELS = {SUN_SOLVER: "sun-vector solver", ULOG_READER: "ULog reader"}


def warm_groups(only: Iterable[str] | None = None) -> list[tuple[str, ...]]:
    """The non-empty groups of :data:`WARM_GROUPS`, restricted to the items ``only`` when given."""
    keep = None if only is None else set(only)
    groups = (tuple(item for item in group if keep is None or item in keep) for group in WARM_GROUPS)
    return [group for group in groups if group]


def warm_up(report: Callable[[str], None] | None = None, processes: int | None = None,
            only: Iterable[str] | None = None) -> float:
    """Compile (or load) every filter kernel by replaying :func:`synthetic_flight` with each filter, the sun-vector
    solver and the ULog reader, after dropping a stale cache; returns the wall time [s].

    Parameters
    ----------
    report : callable, optional
        Receives one line per item (``"  three_stage: 51.2 s"``), as each group of :data:`WARM_GROUPS` finishes.
    processes : int, optional
        Processes compiling side by side (default: one per group, at most one per CPU); 1 compiles in this
        process, one item after the other.
    only : iterable of str, optional
        Compile these items of :data:`WARM_GROUPS` only (e.g. the estimators a command is about to run).
    """
    start = time.perf_counter()
    if cache_state().stale:
        drop_package_caches()
    groups = warm_groups(only)
    workers = min(len(groups), os.cpu_count() or 1) if processes is None else max(1, int(processes))
    say = report if report is not None else (lambda line: None)
    if workers < 2 or len(groups) < 2:
        for group in groups:
            for line in _warm_group(group):
                say(line)
        return time.perf_counter() - start
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: a fresh interpreter (no fork of a process that may hold threads and numba's locks)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        for future in as_completed([pool.submit(_warm_group, group) for group in groups]):
            for line in future.result():
                say(line)
    return time.perf_counter() - start


def compile_side_by_side(items: Iterable[str]) -> bool:
    """Compile ``items`` (estimators, :data:`SUN_SOLVER`) now, in two processes, when they fall into both groups of
    :data:`WARM_GROUPS` and the machine has two CPUs; returns whether it did. Otherwise (one group: nothing to
    gain) they are left to compile in their first run."""
    items = tuple(items)
    if len(warm_groups(items)) < 2 or (os.cpu_count() or 1) < 2:
        return False
    warm_up(only=items)
    return True


def _warm_group(items: tuple[str, ...]) -> list[str]:
    """Compile (or load) ``items`` of :data:`WARM_GROUPS` one after the other in this process; one report line
    each, with its wall time."""
    from estimators.api import run_estimators
    from estimators.config import CalibratedInputs, EstimatorConfig

    lines = []
    log = None
    warm_up_config = EstimatorConfig(calibrated=CalibratedInputs(accel_bias_m_s2=(0.0, 0.0, 0.0)))
    for item in items:
        t0 = time.perf_counter()
        if item == ULOG_READER:
            from ingest.ulog_reader import compile_kernels

            compile_kernels()
        elif item == SUN_SOLVER:
            _solve_synthetic_sun()
        else:
            log = synthetic_flight() if log is None else log
            # a bias given: the three-stage warm-up compiles its own kernel, not the error-state filter's for the
            # bias pass (docs/three_stage.md, 'Pre-processing'), which the other process compiles
            run_estimators(log, estimators=(item,), allow_untrusted=True, config=warm_up_config)
        lines.append(f"  {WARM_LABELS.get(item, item)}: {time.perf_counter() - t0:.1f} s")
    return lines


def _solve_synthetic_sun(n_samples: int = 20) -> None:
    """Solve the sun vector of ``n_samples`` noise-free currents of the default device (sun 40 deg above the
    horizon, turning in azimuth), with a per-sample up vector as the Sun vector page passes it."""
    from estimators.sun.photocells import CURRENT_COLUMNS, photocell_currents
    from estimators.sun.solver import solve_sun_log
    from ingest.sun_device import SunDevice

    device = SunDevice()
    azimuth = np.linspace(0.0, 2.0 * math.pi, n_samples, endpoint=False)
    elevation = math.radians(40.0)
    s_device = np.column_stack([math.cos(elevation) * np.cos(azimuth), math.cos(elevation) * np.sin(azimuth),
                                np.full(n_samples, -math.sin(elevation))])
    currents = photocell_currents(s_device, 5e-3, 2e-4, device)
    frame = pd.DataFrame(currents, columns=list(CURRENT_COLUMNS),
                         index=pd.Index(np.arange(n_samples) * 0.1, name="time_s"))
    solve_sun_log(frame, device=device, noise_a=1e-5, up_body=np.tile([0.0, 0.0, -1.0], (n_samples, 1)))


def main(argv: list[str] | None = None) -> int:
    """``python -m estimators.warmup [--check]``: warm the cache (printing what it does and how long it took), or
    with ``--check`` only print ``warm``/``cold`` (exit status 0 / 1)."""
    argv = sys.argv[1:] if argv is None else argv
    state = cache_state()
    if "--check" in argv:
        print("warm" if state.warm else "cold")
        for line in state.cold:
            print(f"  {line}")
        return 0 if state.warm else 1
    if state.warm:
        print("estimators already compiled (numba cache warm)", flush=True)
        return 0
    print(f"compiling the estimators (first run only, about {FIRST_COMPILE}) ...", flush=True)
    elapsed = warm_up(report=lambda line: print(line, flush=True))
    print(f"compiled the estimators in {elapsed:.0f} s", flush=True)
    return 0


#: Measured cold compile of the filters, the sun-vector solver and the ULog reader on two shared cores, two
#: processes side by side (wall time 113 s on a slow day, when one process took 193 s; about 3 min of CPU time).
FIRST_COMPILE = "1-3 min"


if __name__ == "__main__":
    sys.exit(main())
