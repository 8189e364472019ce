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

#: A stand-in log without sun-device data (the replay itself is replaced in these tests).
NO_SUN_LOG = SimpleNamespace(has=lambda stream: False)

#: Fake seconds each stage of the stand-in takes: inputs checked, inputs built (per estimator), diagnostics, saving;
#: and each estimator's filter, the two running side by side.
CHECK_S, PREPARE_S, DIAGNOSTICS_S, SAVE_S = 0.5, 1.0, 2.0, 4.0
RUN_S = {"three_stage": 3.0, "full_state_direct": 5.0}


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
        clock.now += CHECK_S
        for name in estimators:
            progress("prepare", name)
            clock.now += PREPARE_S
        for name in estimators:  # side by side: all start, then each ends after its own time
            progress("run", name)
        started = clock.now
        for name in sorted(estimators, key=lambda name: RUN_S.get(name, 1.0)):
            clock.now = started + RUN_S.get(name, 1.0)
            progress("done", name)
        progress("report", "")
        clock.now += DIAGNOSTICS_S
        frame = pd.DataFrame({"estimator": pd.Categorical(list(estimators)), "time_s": [0.0] * len(estimators)})
        return SimpleNamespace(states=frame, diagnostics=frame, reports={name: _Report(name) for name in estimators})

    monkeypatch.setattr(runs, "replay_log", run_estimators)

    class Workspace:
        def add_run(self, *args):
            clock.now += SAVE_S
            return "run-1"

    return Workspace()


def test_every_stage_is_announced_when_it_starts_and_measured(fake):
    reports = []
    settings = runs.RunSettings(estimators=("three_stage", "full_state_direct"))
    clock = runs.StageClock(lambda fraction, text: reports.append((fraction, text)), runs.run_steps(2))
    assert runs.replay_and_store(fake, "sha", NO_SUN_LOG, settings, clock=clock) == "run-1"
    assert [text for _, text in reports] == [
        "Checking the inputs ...", "Preparing the inputs of three_stage ...",
        "Preparing the inputs of full_state_direct ...",
        "Running the filters: three_stage running, full_state_direct waiting",
        "Running the filters: three_stage running, full_state_direct running",
        "Running the filters: three_stage done, full_state_direct running",
        "Running the filters: three_stage done, full_state_direct done",
        "Computing the diagnostics ...", "Stacking the tables ...", "Saving the run in the workspace ...", "Done"]
    fractions = [fraction for fraction, _ in reports]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[-2] < 1.0
    assert len(reports) == runs.run_steps(2) + 1  # every step announced, then "Done"
    assert clock.measured == [("checking inputs", CHECK_S), ("preparing inputs", PREPARE_S),
                              ("preparing inputs", PREPARE_S), (runs.RUNNING, 5.0),
                              ("computing diagnostics", DIAGNOSTICS_S), ("stacking the tables", 0.0),
                              (runs.SAVING, SAVE_S)]
    assert clock.lanes == {runs.RUNNING: RUN_S}
    total = CHECK_S + 2 * PREPARE_S + 5.0 + DIAGNOSTICS_S + SAVE_S
    assert clock.summary() == (f"{total:.1f} s: checking inputs 0.5 s, preparing inputs 2.0 s, running the filters "
                               "5.0 s (three_stage 3.0 s, full_state_direct 5.0 s), computing diagnostics 2.0 s, "
                               "stacking the tables 0.0 s, saving 4.0 s")


def test_a_replay_on_its_own_ends_with_done_and_a_cold_filter_says_it_compiles_until_it_is_done(fake, monkeypatch):
    monkeypatch.setattr(runs, "prepare_compile", lambda names: "compiling")
    monkeypatch.setattr(runs, "cache_state", lambda names: SimpleNamespace(warm=False))
    texts = []
    runs.replay(NO_SUN_LOG, runs.RunSettings(estimators=("three_stage",)), progress=lambda f, text: texts.append(text))
    compiling = f"{runs.COMPILE_MESSAGE.capitalize()} for three_stage"
    assert texts == [f"{compiling}: checking the inputs ...", f"{compiling}: preparing the inputs of three_stage ...",
                     f"{compiling}: running the filters: three_stage running", "Running the filters: three_stage done",
                     "Computing the diagnostics ...", "Stacking the tables ...", "Done"]


def test_lanes_are_shown_in_the_selected_order_whatever_order_they_end_in(monkeypatch):
    ticks = iter([0.0, 0.0, 1.0, 2.0, 9.0, 10.0, 11.0, 12.0])  # stage start, lanes a/b/c start, c/b/a end, finish
    monkeypatch.setattr(runs.time, "perf_counter", lambda: next(ticks))
    clock = runs.StageClock(None, 1)
    clock.order_lanes(["a", "b", "c"])
    clock.start(runs.RUNNING, "")
    for lane in "abc":
        clock.lane_start(lane)
    for lane in "cba":
        clock.lane_end(lane)
    clock.finish()
    assert list(clock.lanes[runs.RUNNING]) == ["c", "b", "a"]  # recorded as they ended
    assert clock.summary() == "12.0 s: running the filters 12.0 s (a 11.0 s, b 9.0 s, c 7.0 s)"
