"""solarnav sim layer: a deterministic simulator of the paper's small hand-launched solar-powered UAV.

``mission`` (legs -> smooth command channels), ``wind``, ``kinematics`` (true state on the IMU grid), ``sensors``
and ``photocells`` (measurement models with Table 1 grades), ``scenarios`` (named set-ups), ``simulate``
(scenario + ``numpy.random.Generator`` -> canonical FlightLog, Truth and the error realisation), ``px4_export``
and ``ulog_writer`` (PX4 ULog, sun-device CSV and JSON files). Nothing here draws random numbers at import.
"""
