"""``solarnav calibrate`` through ``app.cli.main`` on a real log."""

from __future__ import annotations

import numpy as np
import pytest

from app.cli import EXIT_BAD_INPUT, main
from calib.export import read_calibration
from calib.parameter_export import export_figures, read_ardupilot_parm, read_px4_params

LOG = "sample_px4_events.ulg"
START_S = 1710773350.0  # this SITL log's clock is unix time; it stands still for its first ~18.7 s


def test_calibrate_writes_calib_json_and_params(real_logs_dir, tmp_path, capsys):
    out, params, parm = tmp_path / "CALIB.json", tmp_path / "ekf2.params", tmp_path / "ekf3.parm"
    assert main(["calibrate", str(real_logs_dir / LOG), "-o", str(out), "--px4-params", str(params),
                 "--ardupilot-parm", str(parm)]) == 0
    printed = capsys.readouterr().out
    assert "Table 4" in printed and "stationary" in printed
    assert f"wrote {out}" in printed and f"wrote {params}" in printed and f"wrote {parm}" in printed
    cal = read_calibration(out)
    assert cal.source == LOG and cal.sensors["gyroscope"].segment.kind == "stationary"
    # Local gravity from the log's GPS (47.4 deg N, 488 m) instead of the standard 9.80665.
    assert cal.stationary_bias.gravity.value_m_s2 == pytest.approx(9.8069, abs=1e-3)
    back = read_px4_params(params)
    density = export_figures(cal)["gyro_noise_density"]
    # The log has no EKF2_PREDICT_US: PX4's default 10 ms step; EKF3 predicts every 12 ms (EKF_TARGET_DT).
    assert back["EKF2_GYR_NOISE"].value == pytest.approx(density.value / np.sqrt(0.01))
    assert f"gyro_noise_density = {density.value:.4g} rad/s/sqrt(Hz) ({density.source}: {density.meaning})" in \
        back["EKF2_GYR_NOISE"].comments[0]
    ekf3 = read_ardupilot_parm(parm)
    assert ekf3["EK3_GYRO_P_NSE"].value == pytest.approx(density.value / np.sqrt(0.012))
    # SITL's magnetometer noise (about 0.004 gauss) is below EK3_MAG_M_NSE's documented minimum of 0.01 gauss.
    mag_gauss = back["EKF2_MAG_NOISE"].value
    assert mag_gauss < 0.01 and ekf3["EK3_MAG_M_NSE"].value == 0.01
    assert ekf3["EK3_MAG_M_NSE"].comments[-1].startswith(f"clamped from {mag_gauss:.4g} to 0.01 gauss")
    assert "EK3_POSNE_M_NSE: not written" in parm.read_text()


def test_user_window_filter_and_tau(real_logs_dir, tmp_path):
    out = tmp_path / "CALIB.json"
    args = ["calibrate", str(real_logs_dir / LOG), "--start-s", str(START_S + 2), "--end-s", str(START_S + 16),
            "--cutoff-hz", "20", "--numtaps", "101", "--tau", "2.5", "--noise", "eta", "-o", str(out)]
    assert main(args) == 0
    cal = read_calibration(out)
    gyro = cal.sensors["gyroscope"]
    assert gyro.segment.kind == "user" and gyro.segment.start_s == START_S + 2
    assert (gyro.fir.cutoff_hz, gyro.fir.numtaps) == (20.0, 101)
    assert cal.sensors["barometer"].fir.cutoff_hz == pytest.approx(4.0)  # 0.2 x 20 Hz: the IMU options only
    assert (cal.tau.tau, cal.tau.method, cal.noise) == (2.5, "user", "eta")
    eta_y = cal.sensors["accelerometer"].eta[1]
    assert cal.r_matrix("accelerometer")[1, 1] == pytest.approx(2.5 * eta_y**2)
    assert cal.stationary_bias is not None  # the window lies inside the stationary stretch


def test_auto_tau_replays_the_three_stage_estimator(real_logs_dir, tmp_path, capsys):
    out = tmp_path / "CALIB.json"
    assert main(["calibrate", str(real_logs_dir / LOG), "--tau", "auto", "-o", str(out)]) == 0
    assert "(likelihood)" in capsys.readouterr().out
    tau = read_calibration(out).tau
    assert tau.method == "likelihood" and 0.1 <= tau.tau <= 100.0
    assert len(tau.log10_tau_grid) == len(tau.neg_log_likelihood) == len(tau.mean_nis) == 13
    assert tau.n_innovations > 1000  # stage-1 updates at 50 Hz over the 31 s log
    # The bounded search lands in the basin of the display grid's best point (grid step 0.25 in log10 tau).
    best_on_grid = tau.log10_tau_grid[int(np.argmin(tau.neg_log_likelihood))]
    assert abs(np.log10(tau.tau) - best_on_grid) <= 0.25


@pytest.mark.parametrize(("extra", "message"), [
    (["--tau", "big"], "positive number or 'auto'"),
    (["--start-s", "1710773352"], "go together"),
    (["--start-s", "1", "--end-s", "2"], "outside the log"),
    (["--start-s", "1710773352", "--end-s", "1710773360", "--segment", "auto"], "not both"),
    (["--cutoff-hz", "200"], "Nyquist"),
])
def test_bad_arguments_fail_with_one_line(real_logs_dir, tmp_path, capsys, extra, message):
    out = tmp_path / "CALIB.json"
    assert main(["calibrate", str(real_logs_dir / LOG), "-o", str(out), *extra]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()
