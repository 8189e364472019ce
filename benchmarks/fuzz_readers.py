"""Mutation fuzzing of the input readers (PX4 ULog, sun-device CSV, device JSON): the big run.

Every case runs in a long-lived worker process (``tests/fuzz_mutations.ReaderPool``): a case that overruns
``--timeout-s`` is a hang (the worker is killed and restarted), a worker that dies is a crash. Each outcome is
classified as loaded / clean InputError / other exception / hang / crash; per-case times are compared with the
unmutated seed (scaled up linearly when the case is larger than its seed).

Usage::

    .venv/bin/python benchmarks/fuzz_readers.py --ulog-cases 5000 --text-cases 1000 --workers 2 \\
        --timeout-s 10 -o /tmp/fuzz.json --save-failures /tmp/fuzz_findings
    # re-run saved failing inputs (a findings folder or tests/data/fuzz):
    .venv/bin/python benchmarks/fuzz_readers.py --rerun /tmp/fuzz_findings
    # minimise one failing input per signature into the regression corpus:
    .venv/bin/python benchmarks/fuzz_readers.py --minimise /tmp/fuzz_findings --corpus-out tests/data/fuzz

``--text-cases`` is per text target (that many CSV and that many JSON cases). Case ``N`` of a target is
reproducible with ``fuzz_mutations.make_case(target, default_seeds(target), N)`` (same seed files).
"""

from __future__ import annotations

import argparse
import collections
import json
import signal
import sys
import time
from pathlib import Path

REPO_DIR = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_DIR / "tests"))
sys.path.insert(0, str(REPO_DIR))

import fuzz_mutations as fm  # noqa: E402

STATUSES = ("loaded", "clean_error", "other_exception", "hang", "crash")


def _warmup(seeds_by_target: dict[str, list[fm.Seed]]) -> list[tuple[str, bytes]]:
    """One small clean input per target: JIT caches and lazy imports are loaded before any case is timed."""
    return [(target, min(seeds, key=lambda s: len(s.data)).data) for target, seeds in seeds_by_target.items()
            if seeds]


def _pool(args, warmup=None) -> fm.ReaderPool:
    return fm.ReaderPool(args.workers, args.timeout_s, int(args.memory_limit_gib * (1 << 30)), warmup,
                         code_root=args.code_root)


def seed_baselines(pool: fm.ReaderPool, seeds_by_target: dict[str, list[fm.Seed]],
                   repeats: int = 3) -> dict[tuple[str, str], dict]:
    """Best-of-``repeats`` time and outcome of every unmutated seed."""
    items = [(target, seed) for target, seeds in seeds_by_target.items() for seed in seeds for _ in range(repeats)]
    outcomes = pool.classify_many([(target, seed.data) for target, seed in items])
    baselines: dict[tuple[str, str], dict] = {}
    for (target, seed), outcome in zip(items, outcomes, strict=True):
        entry = baselines.setdefault((target, seed.name), {"size": len(seed.data), "time_s": float("inf"),
                                                           "status": outcome.status})
        entry["time_s"] = min(entry["time_s"], outcome.elapsed_s)
    return baselines


def run_fuzz(args, seeds_by_target, counts) -> dict:
    started = time.perf_counter()
    records = []
    with _pool(args, _warmup(seeds_by_target)) as pool:
        baselines = seed_baselines(pool, seeds_by_target)
        for (target, name), entry in sorted(baselines.items()):
            if entry["status"] != "loaded":
                print(f"warning: seed {target}:{name} does not load cleanly ({entry['status']})", file=sys.stderr)
        cases = {}

        def jobs():
            for target, n in counts.items():
                for case in fm.make_cases(target, seeds_by_target[target], n, args.first_seed):
                    cases[case.key] = case
                    yield case.key, target, case.data

        total = sum(counts.values())
        for done, (key, outcome) in enumerate(pool.run(jobs()), start=1):
            case = cases.pop(key)
            base = baselines[(case.target, case.seed_name)]
            clean_s = base["time_s"] * max(1.0, len(case.data) / base["size"])
            records.append({"key": key, "target": case.target, "case_seed": case.case_seed, "seed": case.seed_name,
                            "steps": [name for name, _ in case.steps], "describe": case.describe(),
                            "size": len(case.data), "status": outcome.status, "signature": outcome.signature,
                            "message": outcome.message, "elapsed_s": round(outcome.elapsed_s, 5),
                            "clean_s": round(clean_s, 5), "ratio": round(outcome.elapsed_s / clean_s, 2),
                            "detail": outcome.detail if outcome.failed else ""})
            if outcome.failed and args.save_failures:
                _save_failure(Path(args.save_failures), case, outcome, args.max_saved_per_signature)
            if done % 200 == 0:
                print(f"  {done}/{total} cases, {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
        _confirm_worst(pool, records, seeds_by_target)
        restarts = pool.restarts
    wall_s = time.perf_counter() - started
    return {"args": vars(args), "wall_s": round(wall_s, 1), "worker_restarts": restarts,
            "baselines": {f"{t}:{n}": v for (t, n), v in sorted(baselines.items())}, "cases": records}


def _confirm_worst(pool: fm.ReaderPool, records: list[dict], seeds_by_target, n: int = 5, repeats: int = 3):
    """Re-time the ``n`` completed cases with the highest time ratio (best of ``repeats``): a single slow run can
    be a load spike on a shared machine. Sets ``ratio_confirmed`` on them."""
    timed = sorted((r for r in records if r["status"] in ("loaded", "clean_error")), key=lambda r: -r["ratio"])[:n]
    items = [(r, fm.make_case(r["target"], seeds_by_target[r["target"]], r["case_seed"])) for r in timed]
    outcomes = pool.classify_many([(case.target, case.data) for _, case in items for _ in range(repeats)])
    for k, (record, _) in enumerate(items):
        best_s = min(o.elapsed_s for o in outcomes[k * repeats:(k + 1) * repeats])
        record["ratio_confirmed"] = round(min(record["elapsed_s"], best_s) / record["clean_s"], 2)


_saved_counts: collections.Counter = collections.Counter()


def _save_failure(root: Path, case: fm.Case, outcome: fm.Outcome, limit: int) -> None:
    signature = (case.target, outcome.signature)
    _saved_counts[signature] += 1
    if _saved_counts[signature] > limit:
        return
    folder = root / case.target
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{fm.signature_slug(outcome.signature)}__{case.case_seed}"
    (folder / f"{stem}.{fm.EXTENSIONS[case.target]}").write_bytes(case.data)
    (folder / f"{stem}.txt").write_text(f"{outcome.signature}\n{case.describe()}\n{outcome.message}\n\n"
                                        f"{outcome.detail}\n")


def summarise(report: dict) -> str:
    cases = report["cases"]
    lines = ["| target | cases | loaded | clean error | other exception | hang | crash | median ms | max ms |",
             "|---|---|---|---|---|---|---|---|---|"]
    for target in fm.TARGETS:
        rows = [c for c in cases if c["target"] == target]
        if not rows:
            continue
        counts = collections.Counter(c["status"] for c in rows)
        times = sorted(c["elapsed_s"] for c in rows)
        lines.append(f"| {target} | {len(rows)} | " + " | ".join(str(counts[s]) for s in STATUSES)
                     + f" | {1e3 * times[len(times) // 2]:.1f} | {1e3 * times[-1]:.0f} |")
    lines += ["", "Distinct failure signatures:", "",
              "| target | signature | count | example | message |", "|---|---|---|---|---|"]
    failing = [c for c in cases if c["status"] not in ("loaded", "clean_error")]
    groups = collections.defaultdict(list)
    for c in failing:
        groups[(c["target"], c["signature"])].append(c)
    for (target, signature), rows in sorted(groups.items(), key=lambda kv: (kv[0][0], -len(kv[1]))):
        ex = rows[0]
        message = ex["message"].replace("|", "\\|").replace("\n", " ")[:90]
        lines.append(f"| {target} | `{signature}` | {len(rows)} | {ex['describe'][:140].replace('|', '/')} "
                     f"| {message} |")
    if not groups:
        lines.append("| - | none | 0 | | |")
    timed = [c for c in cases if c["status"] in ("loaded", "clean_error")]
    if timed:
        worst = max(timed, key=lambda c: c["ratio"])
        lines += ["", f"Worst time ratio (completed cases, vs the clean seed of that size): {worst['ratio']:.1f}x "
                  f"({1e3 * worst['elapsed_s']:.0f} ms vs {1e3 * worst['clean_s']:.0f} ms clean) in "
                  f"{worst['key']} {worst['describe'][:160]}"]
        confirmed = [c for c in timed if "ratio_confirmed" in c]
        if confirmed:
            worst = max(confirmed, key=lambda c: c["ratio_confirmed"])
            lines.append(f"Worst time ratio re-timed (best of 3 runs of the 5 worst): {worst['ratio_confirmed']:.1f}x "
                         f"in {worst['key']} {worst['describe'][:160]}")
    lines += ["", f"Wall time {report['wall_s']:.0f} s with {report['args']['workers']} workers, timeout "
              f"{report['args']['timeout_s']:g} s, {report['worker_restarts']} worker restarts."]
    return "\n".join(lines)


def rerun(args) -> int:
    """Re-run saved inputs (``DIR/<target>/*.<ext>``) and print which still fail."""
    files = fm.corpus_files(Path(args.rerun))
    items = [(fm.TARGET_OF_EXTENSION[p.suffix.lstrip(".")], p.read_bytes()) for p in files]
    with _pool(args) as pool:
        outcomes = pool.classify_many(items)
    n_failed = 0
    for path, outcome in zip(files, outcomes, strict=True):
        n_failed += outcome.failed
        verdict = "FAIL" if outcome.failed else "ok  "
        print(f"{verdict} {path.relative_to(args.rerun)} {outcome.status} {outcome.signature} "
              f"{outcome.elapsed_s:.2f}s {outcome.message[:100]}")
    print(f"{len(files) - n_failed} passed, {n_failed} failed")
    return 1 if n_failed else 0


def minimise_findings(args) -> int:
    """One minimised input per (target, signature) of a findings folder, written to ``--corpus-out``."""
    files = fm.corpus_files(Path(args.minimise))
    out_root = Path(args.corpus_out)
    with _pool(args) as pool:
        outcomes = pool.classify_many([(fm.TARGET_OF_EXTENSION[p.suffix.lstrip(".")], p.read_bytes())
                                       for p in files])
        chosen: dict[tuple[str, str], tuple[Path, fm.Outcome]] = {}
        for path, outcome in zip(files, outcomes, strict=True):
            target = fm.TARGET_OF_EXTENSION[path.suffix.lstrip(".")]
            if not outcome.failed:
                continue
            key = (target, outcome.signature)
            if key not in chosen or path.stat().st_size < chosen[key][0].stat().st_size:
                chosen[key] = (path, outcome)
        for (target, signature), (path, _) in sorted(chosen.items()):
            out = out_root / target / f"{fm.signature_slug(signature)}.{fm.EXTENSIONS[target]}"
            if args.skip_existing and out.exists():
                continue
            started = time.perf_counter()
            data = fm.minimise(target, path.read_bytes(), signature, pool, max_rounds=args.max_rounds,
                              log=lambda text: print(text, file=sys.stderr, flush=True))
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(data)
            print(f"{target} {signature}: {path.stat().st_size} -> {len(data)} bytes in "
                  f"{time.perf_counter() - started:.0f} s -> {out}", flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ulog-cases", type=int, default=600)
    parser.add_argument("--text-cases", type=int, default=200, help="cases per text target (CSV and JSON)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--timeout-s", type=float, default=10.0)
    parser.add_argument("--memory-limit-gib", type=float, default=4.0, help="address-space limit per worker")
    parser.add_argument("--first-seed", type=int, default=0, help="case seeds are first-seed, first-seed+1, ...")
    parser.add_argument("--seed-kib", type=int, default=192, help="data-section bytes kept in each ULog seed")
    parser.add_argument("--no-real-logs", action="store_true", help="only the bundled sample logs as ULog seeds")
    parser.add_argument("--code-root", help="import the readers (ingest/) from this folder instead of the repo, "
                        "e.g. an export of HEAD: git archive HEAD ingest | tar -x -C /tmp/head")
    parser.add_argument("-o", "--output", help="JSON report")
    parser.add_argument("--save-failures", help="folder for failing inputs: DIR/<target>/<signature>__<seed>.<ext>")
    parser.add_argument("--max-saved-per-signature", type=int, default=10)
    parser.add_argument("--rerun", help="re-run the inputs saved in this folder instead of fuzzing")
    parser.add_argument("--minimise", help="minimise one input per signature from this findings folder")
    parser.add_argument("--corpus-out", default=str(fm.CORPUS_DIR))
    parser.add_argument("--max-rounds", type=int, default=300)
    parser.add_argument("--skip-existing", action="store_true", help="minimise only signatures not in --corpus-out")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # so that the worker pool is shut down
    if args.rerun:
        return rerun(args)
    if args.minimise:
        return minimise_findings(args)

    counts = {"ulog": args.ulog_cases, "sun_csv": args.text_cases, "device_json": args.text_cases}
    counts = {t: n for t, n in counts.items() if n > 0}
    seeds_by_target = {t: fm.default_seeds(t, include_real=not args.no_real_logs,
                                           ulog_data_bytes=args.seed_kib * 1024) for t in counts}
    report = run_fuzz(args, seeds_by_target, counts)
    text = summarise(report)
    print(text)
    if args.output:
        Path(args.output).write_text(json.dumps(report, indent=1))
    if args.save_failures:
        root = Path(args.save_failures)
        root.mkdir(parents=True, exist_ok=True)
        failing = [c for c in report["cases"] if c["status"] not in ("loaded", "clean_error")]
        (root / "summary.json").write_text(json.dumps({"wall_s": report["wall_s"], "failures": failing}, indent=1))
        (root / "SUMMARY.md").write_text(
            "# Reader fuzz findings\n\nCommand: `" + " ".join(["benchmarks/fuzz_readers.py", *sys.argv[1:]])
            + "`\n\nEach failing input is `<target>/<signature>__<case seed>.<ext>` with a `.txt` beside it "
            "(signature, mutation, message, traceback). Reproduce: `fuzz_mutations.make_case(target, "
            "default_seeds(target), case_seed)`; re-run all: `benchmarks/fuzz_readers.py --rerun "
            f"{root}`.\n\n{text}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
