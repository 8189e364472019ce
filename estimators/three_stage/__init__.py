"""Three-stage series estimator (docs/three_stage.md).

Modules, each importing only the ones listed before it: :mod:`~estimators.three_stage.model` (state layouts and the
process models f, A, G per stage), :mod:`~estimators.three_stage.measurements` (the measurement models h and their
Jacobians), :mod:`~estimators.three_stage.stages` (the per-stage numba steps), :mod:`~estimators.three_stage.kernel`
(kernel parameters, work arrays and the compiled loop over the shared schedule) and
:mod:`~estimators.three_stage.run` (options, state tables, kernel setup and :func:`~estimators.three_stage.run.run`,
the registry entry of :mod:`estimators.api`).
"""
