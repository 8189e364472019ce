"""Progress that tells the truth (issue 14): a dashboard run reports every stage as it starts (checking the inputs,
preparing them, the filter, the diagnostics, stacking, saving) and measures where its time went. The estimators are
replaced by a stand-in that announces its stages as :func:`estimators.api.run_estimators` does and advances a fake
clock, so the durations are known exactly."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace

import pandas as pd
import pytest

from app import runs

#: Fake seconds each stage of the stand-in takes: inputs checked, inputs built, filter, diagnostics.
CHECK_S, PREPARE_S, RUN_S, DIAGNOSTICS_S = 0.5, 1.0, 3.0, 2.0
SAVE_S = 4.0


@dataclass
class _Report:
    estimator: str
    warnings: list = field(default_factory=list)


class _Clock:
    """A perf_counter the stand-ins advance."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def fake(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(runs.time, "perf_counter", clock)
    monkeypatch.setattr(runs, "prepare_compile", lambda names: None)  # a warm cache

    def run_estimators(log, *, estimators, progress, **kwargs):
        (name,) = estimators
        clock.now += CHECK_S
        for stage, seconds in (("prepare", PREPARE_S), ("run", RUN_S), ("done", DIAGNOSTICS_S)):
            progress(stage, name)
            clock.now += seconds
        frame = pd.DataFrame({"estimator": pd.Categorical([name]), "time_s": [0.0]})
        return SimpleNamespace(states=frame, diagnostics=frame, reports={name: _Report(name)})

    monkeypatch.setattr(runs, "run_estimators", run_estimators)

    class Workspace:
        def add_run(self, *args):
            clock.now += SAVE_S
            return "run-1"

    return Workspace()


def test_every_stage_is_announced_when_it_starts_and_measured(fake):
    reports = []
    settings = runs.RunSettings(estimators=("three_stage", "full_state_direct"))
    clock = runs.StageClock(lambda fraction, text: reports.append((fraction, text)),
                            runs.STAGES_PER_ESTIMATOR * 2 + 2)
    assert runs.replay_and_store(fake, "sha", None, settings, clock=clock) == "run-1"
    assert [text for _, text in reports] == [
        "Running three_stage (1 of 2) ...", "three_stage (1 of 2): preparing inputs ...",
        "three_stage (1 of 2): running the filter ...", "three_stage (1 of 2): computing diagnostics ...",
        "Running full_state_direct (2 of 2) ...", "full_state_direct (2 of 2): preparing inputs ...",
        "full_state_direct (2 of 2): running the filter ...", "full_state_direct (2 of 2): computing diagnostics ...",
        "Stacking the tables ...", "Saving the run in the workspace ...", "Done"]
    fractions = [fraction for fraction, _ in reports]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[-2] < 1.0
    measured = dict(clock.measured[:4])
    assert measured == {"checking inputs": CHECK_S, "preparing inputs": PREPARE_S, "running three_stage": RUN_S,
                        "computing diagnostics": DIAGNOSTICS_S}
    assert clock.measured[-1] == (runs.SAVING, SAVE_S)
    total = 2 * (CHECK_S + PREPARE_S + RUN_S + DIAGNOSTICS_S) + SAVE_S
    assert clock.summary() == (f"{total:.1f} s: checking inputs 1.0 s, preparing inputs 2.0 s, running three_stage "
                               "3.0 s, computing diagnostics 4.0 s, running full_state_direct 3.0 s, stacking the "
                               "tables 0.0 s, saving 4.0 s")


def test_a_replay_on_its_own_ends_with_done_and_a_cold_filter_says_it_compiles(fake, monkeypatch):
    monkeypatch.setattr(runs, "prepare_compile", lambda names: "compiling")
    monkeypatch.setattr(runs, "cache_state", lambda names: SimpleNamespace(warm=False))
    texts = []
    runs.replay(None, runs.RunSettings(estimators=("three_stage",)), progress=lambda f, text: texts.append(text))
    compiling = runs.COMPILE_MESSAGE.capitalize()
    assert texts == [f"{compiling}: running three_stage (1 of 1) ...",
                     f"{compiling}: three_stage (1 of 1): preparing inputs ...",
                     f"{compiling}: three_stage (1 of 1): running the filter ...",
                     f"{compiling}: three_stage (1 of 1): computing diagnostics ...", "Stacking the tables ...",
                     "Done"]
