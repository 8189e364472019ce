"""Full-state indirect (error-state, multiplicative quaternion) filter: whole runs.

The model functions (F, Q, every H, injection) are checked against finite differences in
``tests/test_indirect_model.py``; the real-log acceptance (all logs without NaN, onboard/ground-truth agreement)
runs for both full-state filters in ``tests/test_estimators_real_logs.py``. Here: the error-state table and the
degraded sensor plans, accuracy and bias recovery on the exact synthetic flight, agreement with the (independently
written, Euler-angle) direct filter and between group and per-scalar injection, divergence handling, and the
simulated paper mission against Table 2 with the mean NIS per channel.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from estimators.config import EstimatorConfig
from estimators.direct import kernel as direct_kernel
from estimators.evaluation import PAPER_TABLE_2, config_for_simulation, rms_errors
from estimators.indirect import kernel as fsi
from estimators.indirect import model as m
from estimators.inputs import build, records
from ingest import load_sun_device, with_sun
from ingest.frames import euler_to_matrix, quat_to_matrix
from ingest.ulog_reader import load_flight_log
from tests.conftest import SAMPLE_LOGS_DIR
from tests.estimators_synthetic import synthetic_flight

CONFIG = EstimatorConfig()


def _run(log, config=CONFIG, **kwargs):
    return fsi.run(log, build.build_replay_inputs(log, config), config, **kwargs)


def _attitude_rms_deg(log, states, after_s):
    truth = log["truth_attitude"]
    t = states["time_s"].to_numpy()
    keep = t >= t[0] + after_s
    out = {}
    for column in ("roll_deg", "pitch_deg", "yaw_deg"):
        expected = np.interp(t, truth.index.to_numpy(), np.degrees(np.unwrap(np.radians(truth[column]))))
        err = (states[column].to_numpy() - expected + 180.0) % 360.0 - 180.0
        out[column] = float(np.sqrt(np.mean(err[keep] ** 2)))
    return out


# ----------------------------------------------------------------------------------------------------------------
# error-state table and sensor plans


def test_error_state_table_matches_the_model_layout():
    table = fsi.error_state_table(CONFIG, absolute_yaw=True)
    names = [s.name for s in table]
    assert len(table) == m.NE
    for index, name in ((m.E_P, "dpn"), (m.E_V, "dvn"), (m.E_TH, "dthx"), (m.E_BG, "dbgx"), (m.E_BA, "dbax"),
                        (m.E_W, "dwn"), (m.E_BM, "dbmx"), (m.E_BB, "dbb")):
        assert names[index] == name
    assert table[m.E_TH + 2].initial_sigma == pytest.approx(math.radians(CONFIG.initial.yaw_deg))
    unaided = fsi.error_state_table(CONFIG, absolute_yaw=False)
    assert unaided[m.E_TH + 2].initial_sigma == pytest.approx(math.radians(CONFIG.initial.yaw_unaided_deg))
    assert table[m.E_W].process_sigma == CONFIG.noise.wind_rw_m_s_sqrt_s
    assert table[m.E_BG].process_sigma == CONFIG.noise.gyro_bias_rw_rad_s2_sqrt_hz
    assert all(s.process_sigma == 0.0 for s in table[:m.E_BG])  # p, v, theta: noise through the IMU inputs


def test_initial_attitude_covariance_is_the_euler_sigmas_mapped_to_body_error():
    """P0's attitude block is W diag(sigma_Euler^2) W^T: mapped back with S = W^-1 it is the Euler diagonal."""
    log = synthetic_flight(5.0, seed=2)
    inputs = build.build_replay_inputs(log, CONFIG)
    k = fsi.kernel_inputs(inputs, CONFIG, log)
    sel = list(k["sel"])
    th = [sel.index(m.E_TH + i) for i in range(3)]
    P_th = k["P0"][np.ix_(th, th)]
    S, W = fsi.attitude_matrices(inputs.alignment.roll_rad, inputs.alignment.pitch_rad)
    np.testing.assert_allclose(S @ W, np.eye(3), atol=1e-15)
    sigmas = np.radians([CONFIG.initial.roll_pitch_deg, CONFIG.initial.roll_pitch_deg, CONFIG.initial.yaw_deg])
    np.testing.assert_allclose(S @ P_th @ S.T, np.diag(sigmas ** 2), atol=1e-15)
    # initial quaternion is the aligned attitude
    r_nb = quat_to_matrix(k["x0"][m.X_Q:m.X_Q + 4])
    align = inputs.alignment
    np.testing.assert_allclose(r_nb, euler_to_matrix(align.roll_rad, align.pitch_rad, align.yaw_rad), atol=1e-12)


def test_cross_axis_states_follow_the_flag():
    log = synthetic_flight(5.0, seed=4)
    off = dataclasses.replace(CONFIG, accel_cross_axis_states=False)
    states = fsi.run(log, build.build_replay_inputs(log, off), off).report.details["states"]
    assert "dkzx" not in states and "dkzy" not in states and "dbax" in states


@pytest.mark.parametrize(("kwargs", "absent"), [
    ({}, ("dkzy",)),  # fixed-wing: no lateral cross-axis state
    ({"mav_type": 2, "with_airspeed": False}, ("dwn", "dwe")),
    ({"with_gps": False}, ("dbax", "dbay", "dbaz", "dbb", "dkzx", "dkzy")),
])
def test_active_error_states_follow_the_sensor_plan(kwargs, absent):
    log = synthetic_flight(5.0, seed=4, **kwargs)
    run = _run(log)
    states = run.report.details["states"]
    full = [s.name for s in fsi.error_state_table(CONFIG, absolute_yaw=True)]
    assert states == [n for n in full if n not in absent]
    # the direct filter decides the same blocks from the same plan, and reports the same
    direct = direct_kernel.run(log, build.build_replay_inputs(log, CONFIG), CONFIG)
    for block_direct, block_indirect in (("bax", "dbax"), ("wn", "dwn"), ("bmx", "dbmx"), ("bb", "dbb")):
        assert (block_direct in direct.report.details["states"]) == (block_indirect in states)
    assert run.report.used == direct.report.used and run.report.skipped == direct.report.skipped
    assert run.report.degradations == direct.report.degradations


# ----------------------------------------------------------------------------------------------------------------
# whole runs on the exact synthetic flight


@pytest.fixture(scope="module")
def minute_flight():
    return synthetic_flight(60.0, seed=1)


def test_accuracy_bias_recovery_and_consistency(minute_flight):
    """60 s of fixed-wing flight in wind (a straight leg, a 12 deg/s turn, straight): attitude within a few
    tenths of a degree, wind within 0.2 m/s, IMU biases recovered, GPS channels consistent."""
    run = _run(minute_flight)
    rms = _attitude_rms_deg(minute_flight, run.states, after_s=20.0)
    assert rms["roll_deg"] < 0.3 and rms["pitch_deg"] < 0.3 and rms["yaw_deg"] < 0.5, rms
    t = run.states["time_s"].to_numpy()
    keep = t >= t[0] + 20.0
    wind = minute_flight["truth_wind"].iloc[0]
    wind_err = np.hypot(run.states["wind_n_m_s"] - wind["wind_n_m_s"], run.states["wind_e_m_s"] - wind["wind_e_m_s"])
    assert float(np.sqrt(np.mean(wind_err[keep] ** 2))) < 0.2
    final = run.report.details["final_state"]
    np.testing.assert_allclose([final["bgx"], final["bgy"], final["bgz"]], [0.002, -0.001, 0.0015], atol=5e-4)
    np.testing.assert_allclose([final["bax"], final["bay"], final["baz"]], [0.05, -0.03, 0.08], atol=0.03)
    assert run.report.resets == 0 and run.report.gps_resets == 0 and run.report.covariance_repairs == 0
    nis = run.diagnostics.groupby("sensor", observed=True)["nis"].mean()
    assert 0.5 < nis["gps_vel"] < 2.0 and 0.5 < nis["gps_pos"] < 2.0, nis
    # the reported attitude std covers the error (2 sigma on > 90 % of the epochs after convergence)
    truth = minute_flight["truth_attitude"]
    for column in ("roll_deg", "pitch_deg"):
        expected = np.interp(t, truth.index.to_numpy(), truth[column].to_numpy())
        inside = np.abs(run.states[column] - expected) <= 2.0 * run.states[f"{column}_std"]
        assert inside[keep].mean() > 0.9, column


def test_agrees_with_the_direct_filter(minute_flight):
    """Two independent implementations of the same estimation problem (Euler angles and body velocity, RK4,
    additive update vs quaternion, NED velocity, exact exponential map, multiplicative injection): after 5 s of
    convergence they agree to a small fraction of their own uncertainty."""
    inputs = build.build_replay_inputs(minute_flight, CONFIG)
    indirect = fsi.run(minute_flight, inputs, CONFIG).states
    direct = direct_kernel.run(minute_flight, inputs, CONFIG).states
    t = indirect["time_s"].to_numpy()
    keep = t >= t[0] + 5.0
    for column, tol in (("roll_deg", 0.1), ("pitch_deg", 0.1), ("yaw_deg", 0.2), ("vn_m_s", 0.01),
                        ("ve_m_s", 0.01), ("alt_m", 0.01), ("wind_n_m_s", 0.05), ("wind_e_m_s", 0.05)):
        diff = indirect[column].to_numpy() - direct[column].to_numpy()
        if column == "yaw_deg":
            diff = (diff + 180.0) % 360.0 - 180.0
        assert np.abs(diff[keep]).max() < tol, column
        if column.endswith("_deg"):  # pointwise, against the filter's own standard deviation
            assert (np.abs(diff[keep]) < 0.5 * indirect[f"{column}_std"].to_numpy()[keep]).all(), column


@pytest.mark.parametrize(("velocity_mode", "inject"), [("ned", "group"), ("paper", "scalar")])
def test_numba_kernel_equals_numpy_twin(velocity_mode, inject):
    """The compiled kernel and the matrix-form NumPy reference (:mod:`estimators.indirect.reference`) on 10 s of flight
    with every sensor: same trajectory, innovations and final state to 1e-9."""
    log = synthetic_flight(10.0, seed=3)
    config = EstimatorConfig(gps_velocity_mode=velocity_mode)
    inputs = build.build_replay_inputs(log, config)
    fast = fsi.run(log, inputs, config, inject=inject, backend="numba")
    slow = fsi.run(log, inputs, config, inject=inject, backend="numpy")
    numeric = [c for c in fast.states.columns if c != "time_s"]
    assert len(fast.states) == len(slow.states) == inputs.output_time_s.size
    a, b = fast.states[numeric].to_numpy(), slow.states[numeric].to_numpy()
    assert np.array_equal(np.isnan(a), np.isnan(b))
    assert np.nanmax(np.abs(a - b)) < 1e-9
    assert len(fast.diagnostics) == len(slow.diagnostics) > 0
    for column in ("innovation", "innovation_var", "nis"):
        assert np.nanmax(np.abs(fast.diagnostics[column] - slow.diagnostics[column])) < 1e-9
    assert (fast.diagnostics["accepted"] == slow.diagnostics["accepted"]).all()
    final_fast, final_slow = fast.report.details["final_state"], slow.report.details["final_state"]
    assert max(abs(final_fast[k] - final_slow[k]) for k in final_fast) < 1e-9
    with pytest.raises(ValueError, match="backend"):
        fsi.run(log, inputs, config, backend="fortran")


def test_group_and_scalar_injection_agree(minute_flight):
    """Injecting after each sensor group (linearised innovations within the group, eq 49 corrected) or after
    every scalar (re-linearised) differ only to second order."""
    inputs = build.build_replay_inputs(minute_flight, CONFIG)
    group = fsi.run(minute_flight, inputs, CONFIG)
    scalar = fsi.run(minute_flight, inputs, CONFIG, inject="scalar")
    for column, tol in (("roll_deg", 0.01), ("pitch_deg", 0.01), ("yaw_deg", 0.02), ("vn_m_s", 1e-3),
                        ("wind_n_m_s", 0.005)):
        assert np.abs(group.states[column] - scalar.states[column]).max() < tol, column
    assert len(group.diagnostics) == len(scalar.diagnostics)
    with pytest.raises(ValueError, match="inject"):
        fsi.run(minute_flight, inputs, CONFIG, inject="never")


def test_degraded_modes_run_without_nan():
    copter = synthetic_flight(10.0, seed=4, mav_type=2, with_airspeed=False)
    run = _run(copter)
    assert run.states["wind_n_m_s"].isna().all() and "sideslip" not in run.report.used
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "vn_m_s"]].notna().all().all()
    blind = synthetic_flight(10.0, seed=5, with_gps=False)
    run = _run(blind)
    assert run.states["lat_deg"].isna().all() and run.states["vn_m_s"].isna().all()
    assert run.states[["roll_deg", "pitch_deg", "yaw_deg", "alt_m"]].notna().all().all()
    assert "zero_velocity" in run.report.used
    assert any("accelerometer bias" in d for d in run.report.degradations)


def test_divergence_is_reset_never_nan():
    log = synthetic_flight(10.0, seed=3)
    inputs = build.build_replay_inputs(log, CONFIG)
    gyro = inputs.imu.gyro_rad_s.copy()
    gyro[1200] = 1e300  # an absurd sample makes the nominal state overflow
    broken = records.ReplayInputs(**{**inputs.__dict__, "imu": records.ImuSamples(
        **{**inputs.imu.__dict__, "gyro_rad_s": gyro})})
    run = fsi.run(log, broken, CONFIG)
    assert run.report.resets >= 1 and any("reset" in w for w in run.report.warnings)
    assert run.states.notna().all().all()
    assert np.isfinite(run.states.drop(columns="time_s").to_numpy()).all()


# ----------------------------------------------------------------------------------------------------------------
# the simulated paper mission (sample_logs/paper.ulg) against Table 2


@pytest.fixture(scope="module")
def paper_mission():
    """The bundled simulated paper mission replayed with the true noise parameters of its sensors (the shared
    :func:`estimators.evaluation.config_for_simulation`, as the direct filter's test), Table 2 indirect bars."""
    log = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    sidecar = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())
    config = config_for_simulation(sidecar)
    run = _run(log, config)
    errors = rms_errors(run.states, log, after_s=60.0).iloc[0]
    gps = sidecar["sensor_errors"]["gps"]
    bars = dict(PAPER_TABLE_2[fsi.NAME])
    # position and height cannot beat the receiver's own slowly varying (Gauss-Markov) error (issue 4: 1.1 x)
    bars["position_m"] = max(bars["position_m"], 1.1 * gps["position_error_rms_horizontal_m"])
    bars["height_m"] = max(bars["height_m"], 1.1 * gps["position_error_rms_ned_m"][2])
    print("\nfull_state_indirect on sample_logs/paper.ulg, RMS after 60 s (ours / bar):")
    print("  " + "  ".join(f"{q} {errors[q]:.3f}/{bars[q]:.2f}" for q in bars))
    return run, errors, bars


#: Pitch: the simulated MPU6050's cross-axis sensitivity (+-2 %) couples the forward specific force into the z
#: accelerometer, whose effective bias then changes at every climb/cruise/descent transition; with the z bias
#: random walk alone (``SIM_ACCEL_BIAS_RW_Z``) the residual leaked into pitch (0.36 deg; without the simulated
#: cross-axis errors 0.17 deg). The error-state filter now estimates the z accelerometer's cross-axis
#: sensitivities (``accel_cross_axis_states``, k_zx converges to the simulated 0.015): 0.25 deg, within Table 2's
#: 0.30 (test below). The looser bar holds with those states switched off too.
PITCH_BAR_DEG = 0.45


@pytest.mark.parametrize("quantity", ["roll_deg", "yaw_deg", "position_m", "height_m", "airspeed_m_s",
                                      "ground_speed_m_s", "course_deg", "wind_m_s"])
def test_paper_mission_meets_table_2(paper_mission, quantity):
    _, errors, bars = paper_mission
    assert errors[quantity] <= bars[quantity], (quantity, errors[quantity], bars[quantity])


def test_paper_mission_pitch(paper_mission):
    _, errors, _ = paper_mission
    assert errors["pitch_deg"] <= PITCH_BAR_DEG, errors["pitch_deg"]


def test_paper_mission_pitch_table_2(paper_mission):
    _, errors, bars = paper_mission
    assert errors["pitch_deg"] <= bars["pitch_deg"]


def test_paper_mission_estimates_the_z_accelerometer_cross_axis(paper_mission):
    """k_zx (z accelerometer's sensitivity to the forward specific force) converges to the simulated coupling:
    observable through the vertical channel as the forward specific force changes (launch, climbs, descents).
    k_zy is not estimated on a fixed-wing: coordinated flight keeps the lateral specific force near zero."""
    run, _, _ = paper_mission
    details = run.report.details
    simulated = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())["sensor_errors"]["imu"]["accel_matrix"]
    estimate, sigma = details["final_state"]["kzx"], details["final_state_std"]["dkzx"]
    print(f"k_zx {estimate:.4f} +- {sigma:.4f}, simulated {simulated[2][0]:.4f}")
    assert sigma < 0.5 * CONFIG.initial.accel_cross_axis
    assert abs(estimate - simulated[2][0]) < 3.0 * sigma
    assert "dkzy" not in details["states"]


@pytest.fixture(scope="module")
def paper_mission_with_sun():
    """The paper mission with the photocell sun vector fused as well (heading "mag+sun")."""
    log = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    device = load_sun_device(SAMPLE_LOGS_DIR / "paper_device.json")
    log = with_sun(log, SAMPLE_LOGS_DIR / "paper_sun.csv", device=device)
    sidecar = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())
    config = config_for_simulation(sidecar)
    run = fsi.run(log, build.build_replay_inputs(log, config, heading="mag+sun"), config)
    return run, rms_errors(run.states, log, after_s=60.0).iloc[0]


def test_paper_mission_with_sun_vector_meets_the_whole_row(paper_mission, paper_mission_with_sun):
    """The sun vector fixes two attitude axes independently of the accelerometer: with it the tilt is no longer
    limited by the accelerometer's cross-axis error and the whole Table 2 row is met."""
    _, _, bars = paper_mission
    run, errors = paper_mission_with_sun
    print("\nwith the sun vector (ours / bar):", "  ".join(f"{q} {errors[q]:.3f}/{bars[q]:.2f}" for q in bars))
    assert "sun" in run.report.used
    failing = {q: (round(errors[q], 3), bars[q]) for q in bars if not errors[q] <= bars[q]}
    assert not failing, failing
    sun = run.diagnostics[run.diagnostics["sensor"] == "sun"]
    assert len(sun) > 1000 and sun["accepted"].mean() > 0.99


def test_paper_mission_nis_per_channel(paper_mission):
    """Mean NIS per measured channel in [0.5, 2] (pseudo-measurements excluded: their sigma is a modelling
    allowance, not a sensor noise)."""
    run, _, _ = paper_mission
    diagnostics = run.diagnostics
    measured = diagnostics[~diagnostics["sensor"].isin([records.SENSOR_NAMES[k] for k in records.PSEUDO_KINDS])]
    nis = measured.groupby(["sensor", "component"], observed=True)["nis"].mean()
    print("mean NIS per channel:", nis.round(2).to_dict())
    assert set(nis.index.get_level_values("sensor")) == {"baro", "airspeed", "gps_pos", "gps_vel", "mag"}
    assert ((nis >= 0.5) & (nis <= 2.0)).all(), nis
    assert measured["accepted"].mean() > 0.99
    assert run.report.resets == 0 and run.report.gps_resets == 0
