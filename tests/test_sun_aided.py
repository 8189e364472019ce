"""Sun-aided attitude in the three estimators (issue 6, proof): heading ``mag`` / ``sun`` / ``mag+sun``.

The mission is the ``mag_disturbed`` scenario (five minutes, simulated here with its fixed seed): its
magnetometer carries a solar-panel disturbance of up to a third of the earth field that follows the bank angle.
Two filter set-ups, both with the simulator's true sensor noise (:func:`estimators.evaluation.config_for_simulation`):

* "modelled": the magnetometer-bias random walk is fast enough to follow the disturbance (the full-state filters'
  bias states absorb it; the three-stage filter has no magnetometer bias, so the disturbance reaches its heading);
* "unmodelled": the estimators' default bias walk, i.e. a user who does not know about the disturbance.

Claims (yaw RMS after the first 60 s, tolerance 2 deg from the issue): sun-only heading (no magnetometer use)
stays within 2 deg in every estimator and set-up; mag-only is worse than 2 deg wherever the disturbance is not
absorbed (three-stage always, full-state when unmodelled); mag+sun stays within 2 deg when the filter models the
magnetometer's disturbance. Sun-only heading converges from a 30 deg initial yaw error. Every estimator's sun
update (Jacobian in its own attitude parameterisation, tangent-plane projection) is checked against finite
differences and against the solver module's leaf functions.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from calib.bias import GravityReference
from calib.calibration import calibrate
from calib.segments import user_segment
from estimators.api import DEFAULT_ESTIMATORS, estimator_function, run_estimators
from estimators.config import EstimatorConfig, config_from_calibration
from estimators.direct import measurements as direct_measurements
from estimators.environment import local_gravity_m_s2
from estimators.evaluation import PAPER_TABLE_2, config_for_simulation, reference_states, rms_errors
from estimators.indirect import measurements as indirect_measurements
from estimators.indirect import model as m
from estimators.inputs import build, records
from estimators.sun import measurement as sun_measurement_model
from estimators.three_stage import measurements as three_stage_models
from ingest.frames import euler_to_matrix, euler_to_quat, quat_to_matrix
from ingest.log_formats import load_flight_log
from ingest.sun_device import SunDevice
from ingest.sun_log import attach_sun, load_sun_device, with_sun
from sim.px4_export import side_file
from sim.scenarios import SCENARIOS, SensorSpec
from sim.simulate import simulate
from tests.conftest import SAMPLE_LOGS_DIR

#: Yaw RMS bound of sun-aided heading (issue 6) [deg].
YAW_BOUND_DEG = 2.0
#: Convergence time excluded from the RMS [s].
AFTER_S = 60.0


def unmodelled(config: EstimatorConfig) -> EstimatorConfig:
    """``config`` with the default magnetometer-bias walk: the solar-panel disturbance is not modelled."""
    noise = dataclasses.replace(config.noise, mag_bias_rw_sqrt_s=EstimatorConfig().noise.mag_bias_rw_sqrt_s)
    return dataclasses.replace(config, noise=noise)


@pytest.fixture(scope="module")
def mission():
    scenario = SCENARIOS["mag_disturbed"]
    result = simulate(scenario, np.random.default_rng(scenario.seed), seed=scenario.seed)
    return result.log, side_file(result)


@pytest.fixture(scope="module")
def yaw_rms(mission):
    """Yaw RMS [deg]: {(set-up, heading): {estimator: value}} and the replay reports."""
    log, sidecar = mission
    modelled = config_for_simulation(sidecar)
    setups = {"modelled": modelled, "unmodelled": unmodelled(modelled)}
    table, reports = {}, {}
    for setup, config in setups.items():
        for heading in ("mag", "sun", "mag+sun"):
            if setup == "unmodelled" and heading == "sun":
                continue  # no magnetometer: the same run as "modelled"
            result = run_estimators(log, config=config, heading=heading)
            table[setup, heading] = rms_errors(result.states, log, after_s=AFTER_S)["yaw_deg"].to_dict()
            reports[setup, heading] = result.reports
    print("\nyaw RMS [deg]:", *(f"{k}: " + ", ".join(f"{n} {v:.2f}" for n, v in row.items())
                                for k, row in table.items()), sep="\n  ")
    return table, reports


def test_the_disturbance_is_strong(mission):
    _, sidecar = mission
    mag = sidecar["sensor_errors"]["mag"]
    field = np.linalg.norm(mag["earth_field_ned_gauss"])
    assert mag["solar_disturbance_max_gauss"] / field > 0.3


@pytest.mark.parametrize("estimator", DEFAULT_ESTIMATORS)
def test_sun_only_heading_within_bound_without_the_magnetometer(yaw_rms, estimator):
    table, reports = yaw_rms
    report = reports["modelled", "sun"][estimator]
    assert "sun" in report.used and "mag" not in report.used
    assert report.skipped["mag"] == "heading source is 'sun'"
    assert report.details["alignment"]["yaw_source"] == "sun"
    assert table["modelled", "sun"][estimator] <= YAW_BOUND_DEG


@pytest.mark.parametrize("estimator", DEFAULT_ESTIMATORS)
def test_mag_only_is_worse_where_the_disturbance_is_not_absorbed(yaw_rms, estimator):
    table, _ = yaw_rms
    setups = ("modelled", "unmodelled") if estimator == "three_stage" else ("unmodelled",)
    for setup in setups:
        assert table[setup, "mag"][estimator] > YAW_BOUND_DEG, setup
        assert table[setup, "mag"][estimator] > 3.0 * table["modelled", "sun"][estimator], setup


@pytest.mark.parametrize("estimator", DEFAULT_ESTIMATORS)
def test_mag_plus_sun_within_bound_when_the_disturbance_is_modelled(yaw_rms, estimator):
    table, reports = yaw_rms
    assert {"mag", "sun"} <= set(reports["modelled", "mag+sun"][estimator].used)
    assert table["modelled", "mag+sun"][estimator] <= YAW_BOUND_DEG
    assert table["modelled", "mag+sun"][estimator] < table["modelled", "mag"][estimator]


@pytest.mark.parametrize("estimator", DEFAULT_ESTIMATORS)
def test_sun_only_heading_converges_from_a_wrong_initial_yaw(mission, estimator):
    """Start 30 deg off (3 sigma of the initial yaw uncertainty). At rest the sun vector fixes two attitude
    axes at once; the rotation about the sun line is left to the tilt, which the GPS velocity only slowly
    corrects while the vehicle is still: within 3 deg at the end of the 30 s still phase, and within the bound
    (every epoch) once flying, from 60 s on."""
    log, sidecar = mission
    config = config_for_simulation(sidecar)
    inputs = build.build_replay_inputs(log, config, heading="sun")
    offset = math.radians(30.0)
    wrong = dataclasses.replace(inputs.alignment, yaw_rad=inputs.alignment.yaw_rad + offset)
    run = estimator_function(estimator)(log, dataclasses.replace(inputs, alignment=wrong), config)
    t = run.states["time_s"].to_numpy()
    truth = reference_states(log, "truth", t)  # NaN after the last truth sample
    error = (run.states["yaw_deg"].to_numpy() - truth["yaw_deg"].to_numpy() + 180.0) % 360.0 - 180.0
    end_of_still = (t >= t[0] + 28.0) & (t < t[0] + 30.0)
    assert np.abs(error[end_of_still]).max() <= 3.0
    flying = (t >= t[0] + AFTER_S) & np.isfinite(error)
    assert flying.sum() > 0.99 * (t >= t[0] + AFTER_S).sum()
    assert np.abs(error[flying]).max() <= YAW_BOUND_DEG
    assert rms_errors(run.states, log, after_s=AFTER_S).iloc[0]["yaw_deg"] <= YAW_BOUND_DEG


@pytest.fixture(scope="module")
def paper_mission():
    log = load_flight_log(SAMPLE_LOGS_DIR / "paper.ulg")
    device = load_sun_device(SAMPLE_LOGS_DIR / "paper_device.json")
    log = with_sun(log, SAMPLE_LOGS_DIR / "paper_sun.csv", device=device)
    return log, config_for_simulation(json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text()))


@pytest.mark.parametrize("estimator", ["full_state_direct", "full_state_indirect"])
def test_sun_only_full_state_filters_on_the_paper_mission(paper_mission, estimator):
    """Regression of the direct filter's sun-only divergence (17 km position RMS): without the gravity + sun
    initial yaw the filter started 61 deg off with a 10 deg yaw sigma; the first, linearised sun update collapsed
    the covariance without removing the error, the next ones were gated out, the tilt error integrated into a
    33 m/s velocity error before the first GPS fix, and the GPS north channel was then rejected for good."""
    log, config = paper_mission
    result = run_estimators(log, estimators=estimator, config=config, heading="sun")
    report = result.reports[estimator]
    assert report.details["alignment"]["yaw_source"] == "sun" and report.resets == 0
    errors = rms_errors(result.states, log, after_s=AFTER_S).iloc[0]
    assert errors["yaw_deg"] <= YAW_BOUND_DEG
    assert errors["position_m"] <= 10.0  # the GPS Gauss-Markov floor of this log is ~5 m
    sun = result.diagnostics[result.diagnostics["sensor"] == "sun"]
    assert sun["accepted"].mean() > 0.99


@pytest.mark.parametrize("estimator", ["full_state_direct", "full_state_indirect"])
def test_calibrated_sun_aided_full_state_filters_meet_table_2(paper_mission, estimator):
    """The product path without the simulator's secrets: R and the IMU noise from the calibration of the first
    cruise leg (FIR, eq 50/51, :func:`estimators.config.config_from_calibration`), default walks, sun heading.
    The magnetometer's solar-panel disturbance is a slowly drifting hard iron that no calibration segment shows
    (with the magnetometer heading the same calibration gives GPS velocity NIS ~5 and 2.6 deg yaw RMS); the sun
    vector is not disturbed, and the full-state filters meet their Table 2 rows for attitude, ground speed,
    course and wind."""
    log, _ = paper_mission
    record = json.loads((SAMPLE_LOGS_DIR / "paper_sim.json").read_text())
    start_s, end_s = next((leg["start_s"], leg["end_s"]) for leg in record["segments_log_time_s"]
                          if leg["leg"] == "cruise")
    origin = record["origin"]
    gravity = GravityReference(float(local_gravity_m_s2(origin["lat_deg"], origin["alt_m"])), "site")
    calibration = calibrate(log, segment=user_segment(log, start_s + 8.0, end_s - 8.0), gravity=gravity)
    result = run_estimators(log, estimators=estimator, config=config_from_calibration(calibration), heading="sun")
    errors = rms_errors(result.states, log, after_s=AFTER_S).iloc[0]
    paper = PAPER_TABLE_2[estimator]
    for quantity in ("roll_deg", "pitch_deg", "yaw_deg", "ground_speed_m_s", "course_deg", "wind_m_s"):
        assert errors[quantity] <= paper[quantity], quantity


def test_replay_uses_the_logs_sun_device_geometry():
    """A device with 35 deg faces turned 90 deg on the airframe (the two-minute failed-cell flight, healthy cells):
    the replay solves the currents with the geometry attached to the log, so the sun-only heading is right; with
    the default geometry the same currents give tens of degrees of yaw error."""
    device = SunDevice(tilt_deg=35.0, mount_rpy_deg=(0.0, 0.0, 90.0))
    scenario = dataclasses.replace(SCENARIOS["failed_cell"], sensors=SensorSpec(device=device))
    result = simulate(scenario, np.random.default_rng(1), seed=1)
    config = config_for_simulation(side_file(result))
    log = attach_sun(result.log, result.log["sun"], device=device)
    yaw = rms_errors(run_estimators(log, config=config, heading="sun").states, log, after_s=30.0)["yaw_deg"]
    assert (yaw <= YAW_BOUND_DEG).all(), yaw.to_dict()
    default = attach_sun(result.log, result.log["sun"])
    yaw_default = rms_errors(run_estimators(default, estimators="full_state_indirect", config=config,
                                            heading="sun").states, default, after_s=30.0)["yaw_deg"]
    assert (yaw_default > 10.0).all()


# ----------------------------------------------------------------------------------------------------------------
# the sun update of every estimator: Jacobians against finite differences and the solver's leaf functions

N_STATES = 5
STEP = 1e-6


def _random_attitudes(rng, n=N_STATES):
    return [(rng.uniform(-1.0, 1.0), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi)) for _ in range(n)]


def _sun(rng):
    s = rng.normal(size=3)
    return s / np.linalg.norm(s)


def _projected_fd(h_of, x, basis):
    """Finite-difference Jacobian of the tangent-plane scalars ``T^T h(x)`` (T fixed at the prior), shape (2, n)."""
    out = np.empty((2, len(x)))
    for i in range(len(x)):
        dx = np.zeros(len(x))
        dx[i] = STEP
        out[:, i] = basis.T @ (h_of(x + dx) - h_of(x - dx)) / (2.0 * STEP)
    return out


def _check_basis(basis, h):
    np.testing.assert_allclose(basis.T @ basis, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(basis.T @ h, 0.0, atol=1e-12)


def test_direct_filter_sun_update():
    """Euler form: H_Theta = [h]x W (:func:`estimators.sun.measurement.sun_jacobian_euler`), projected on the kernel's
    tangent basis; no other state enters."""
    layout = np.array([12, 15, 17, 20])
    n = 21
    scratch = lambda: (np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)))  # noqa: E731
    rng = np.random.default_rng(61)
    for roll, pitch, yaw in _random_attitudes(rng):
        x = rng.normal(0.0, 0.1, n)
        x[6:9] = roll, pitch, yaw
        values = np.zeros(6)
        values[3:6] = _sun(rng)

        def h_of(xx, values=values):
            return np.array([direct_measurements.measurement(xx, records.SUN, c, values, np.zeros(3), layout,
                                                             *scratch(), np.empty(n)) for c in range(3)])

        H3 = np.empty((3, n))
        for c in range(3):
            direct_measurements.measurement(x, records.SUN, c, values, np.zeros(3), layout, *scratch(), H3[c])
        r_nb = euler_to_matrix(roll, pitch, yaw)
        np.testing.assert_allclose(h_of(x), r_nb.T @ values[3:6], atol=1e-12)
        np.testing.assert_allclose(H3[:, 6:9], sun_measurement_model.sun_jacobian_euler(r_nb, values[3:6]), atol=1e-12)
        assert not np.any(np.delete(H3, [6, 7, 8], axis=1))
        basis = sun_measurement_model.sun_tangent_basis(h_of(x))
        _check_basis(basis, h_of(x))
        np.testing.assert_allclose(basis.T @ H3, _projected_fd(h_of, x, basis), atol=1e-7)


def test_indirect_filter_sun_update():
    """Error-angle form: H_dtheta = [h]x (:func:`estimators.sun.measurement.sun_jacobian_error_angle`) against finite
    differences of the right perturbation ``q (x) Exp(dtheta)``, projected on the tangent basis."""
    rng = np.random.default_rng(62)
    for roll, pitch, yaw in _random_attitudes(rng):
        x = np.zeros(m.NX)
        x[m.X_Q:m.X_Q + 4] = euler_to_quat(roll, pitch, yaw)
        sun = _sun(rng)

        def h_at(xx, sun=sun):
            H = np.empty(m.NE)
            return np.array([indirect_measurements.h_body_vector(xx, sun, c, False, H) for c in range(3)])

        H3 = np.empty((3, m.NE))
        for c in range(3):
            indirect_measurements.h_body_vector(x, sun, c, False, H3[c])
        r_nb = quat_to_matrix(x[m.X_Q:m.X_Q + 4])
        th = slice(m.E_TH, m.E_TH + 3)
        np.testing.assert_allclose(H3[:, th], sun_measurement_model.sun_jacobian_error_angle(r_nb, sun), atol=1e-12)
        assert not np.any(np.delete(H3, np.arange(m.NE)[th], axis=1))
        basis = sun_measurement_model.sun_tangent_basis(h_at(x))
        _check_basis(basis, h_at(x))

        def h_of_error(dtheta, x=x, th=th, h_at=h_at):
            xx = x.copy()
            dx = np.zeros(m.NE)
            dx[th] = dtheta
            m.inject(xx, dx, np.eye(m.NE))
            return h_at(xx)

        np.testing.assert_allclose(basis.T @ H3[:, th], _projected_fd(h_of_error, np.zeros(3), basis), atol=1e-7)


def test_three_stage_sun_update():
    """Stage 2: the yaw column of [h]x W and the tilt columns used for the stage-1 consider inflation."""
    rng = np.random.default_rng(63)
    for roll, pitch, yaw in _random_attitudes(rng):
        sun = _sun(rng)
        h, c, j_tilt = three_stage_models.stage2_h(yaw, roll, pitch, sun)
        jac = sun_measurement_model.sun_jacobian_euler(euler_to_matrix(roll, pitch, yaw), sun)
        np.testing.assert_allclose(c[:, 0], jac[:, 2], atol=1e-12)
        np.testing.assert_allclose(j_tilt, jac[:, :2], atol=1e-12)
        basis = sun_measurement_model.sun_tangent_basis(h)
        _check_basis(basis, h)
        fd = _projected_fd(lambda a, sun=sun: three_stage_models.stage2_h(a[2], a[0], a[1], sun)[0],
                           np.array([roll, pitch, yaw]), basis)
        np.testing.assert_allclose(basis.T @ jac, fd, atol=1e-7)
