"""Full-state indirect (error-state) filter (docs/indirect.md): :mod:`~estimators.indirect.model` (state layout,
nominal kinematics, F, Q, injection) <- :mod:`~estimators.indirect.measurements` (h and H per sensor) <-
:mod:`~estimators.indirect.kernel` (the compiled loop) <- :mod:`~estimators.indirect.run` (settings, schedule,
tables; the registry entry)."""
