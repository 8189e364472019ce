"""Full-state direct filter (docs/direct.md), each module importing only the ones before it:
:mod:`~estimators.direct.model` (state layout, f, A, Q, RK4) <- :mod:`~estimators.direct.measurements` (h and H per
sensor) <- :mod:`~estimators.direct.kernel` (settings, the compiled loop over the shared schedule) <-
:mod:`~estimators.direct.run` (state table, settings, schedule, tables; the registry entry)."""
