"""solarnav calib layer: sensor noise, bias, R and tau from a flight log (paper sec. 5, docs/calibration.md, 'Noise and
bias (eq 50)').

Modules, in data-flow order (calib imports only ``ingest`` and third-party libraries):

* :mod:`calib.segments`: user windows and automatic stationary / steady-cruise segments, with reasons;
* :mod:`calib.fir`: Hamming FIR design, zero-phase filtering, frequency response, rho_h;
* :mod:`calib.noise`: eq 50 literally, residual sigma and its robust variant;
* :mod:`calib.bias`: physically referenced biases (stationary; in-flight filter states passed in);
* :mod:`calib.allan`: Allan deviation and the figures read off it;
* :mod:`calib.tau`: eq 52's tau, user-set or chosen through an injected filter replay;
* :mod:`calib.calibration`: :func:`~calib.calibration.calibrate`, the eq 51 R matrices;
* :mod:`calib.tables`: Table 4 and eq 51 as DataFrames;
* :mod:`calib.export`: CALIB.json (schema ``solarnav.calibration/2``); :mod:`calib.parameter_export`: PX4 EKF2
  .params and ArduPilot EKF3 .parm files through one mapping table.
"""
