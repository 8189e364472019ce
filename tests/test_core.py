"""EKF core algebra (estimators.core.linalg, recorder) against textbook NumPy forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.core import linalg, recorder, rotations


def _random_spd(rng, n):
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


# rows with dynamics: a leading block (the filters' layout), one in the middle of random walks, all, none
DYNAMIC_ROWS = ([0, 1, 2, 3], [0, 1, 3, 5], list(range(9)), [])


@pytest.mark.parametrize("rows", DYNAMIC_ROWS)
def test_transition_matrix_is_second_order_series(rows):
    rng = np.random.default_rng(1)
    A = np.zeros((9, 9))
    A[rows] = rng.normal(size=(len(rows), 9))
    F = np.empty_like(A)
    linalg.transition_matrix(A, 0.01, F)
    expected = np.eye(9) + A * 0.01 + (A @ A) * 0.01 ** 2 / 2
    np.testing.assert_allclose(F, expected, rtol=0, atol=1e-15)


def test_transition_matrix_of_a_sparse_jacobian_equals_the_dense_series():
    # the filters' A: most coefficients of the dynamic block are zero (the product skips them), one is -0.0, and
    # the static rows are zero
    rng = np.random.default_rng(3)
    A = np.zeros((12, 12))
    A[:6] = rng.normal(size=(6, 12)) * (rng.random((6, 12)) < 0.3)
    A[2, 4] = -0.0
    F = np.full_like(A, np.nan)  # every entry must be written
    linalg.transition_matrix(A, 0.02, F)
    expected = np.eye(12) + A * 0.02 + (A @ A) * 0.02 ** 2 / 2
    np.testing.assert_allclose(F, expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("rows", DYNAMIC_ROWS)
def test_propagate_covariance_equals_dense_form(rows):
    rng = np.random.default_rng(2)
    n = 9
    P = _random_spd(rng, n)
    F = np.eye(n)
    F[rows] += 0.05 * rng.normal(size=(len(rows), n))  # the other rows without dynamics, as bias states
    Qd = 1e-3 * _random_spd(rng, n)
    expected = F @ P @ F.T + Qd
    linalg.propagate_covariance(P, F, Qd, np.empty((n, n)))
    np.testing.assert_allclose(P, expected, rtol=1e-13, atol=1e-13)
    assert np.array_equal(P, P.T)


@pytest.mark.parametrize("gate", [math.inf, 3.0])
def test_scalar_update_is_joseph_form_with_gate(gate):
    rng = np.random.default_rng(3)
    n = 6
    P0 = _random_spd(rng, n)
    H = np.zeros(n)
    H[[1, 4]] = rng.normal(size=2)
    r_var = 0.3
    S_expected = H @ P0 @ H + r_var
    for nu in (0.1 * math.sqrt(S_expected), 10.0 * math.sqrt(S_expected)):
        P = P0.copy()
        dx, ph = np.empty(n), np.empty(n)
        accepted, s_var, nis = linalg.scalar_update(P, H, nu, r_var, gate, dx, ph)
        assert s_var == pytest.approx(S_expected, rel=1e-12)
        assert nis == pytest.approx(nu ** 2 / S_expected, rel=1e-12)
        K = P0 @ H / S_expected
        if accepted:
            I_KH = np.eye(n) - np.outer(K, H)
            np.testing.assert_allclose(P, I_KH @ P0 @ I_KH.T + r_var * np.outer(K, K), rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(dx, K * nu, rtol=1e-12, atol=1e-15)
        else:
            assert nu / math.sqrt(S_expected) > gate
            np.testing.assert_array_equal(P, P0)
            np.testing.assert_array_equal(dx, 0.0)
        assert accepted == (abs(nu) / math.sqrt(S_expected) <= gate)


def test_scalar_update_rejects_non_finite_innovation():
    P = np.eye(3)
    H = np.array([1.0, 0.0, 0.0])
    dx = np.ones(3)
    accepted, _, nis = linalg.scalar_update(P, H, math.nan, 1.0, math.inf, dx, np.empty(3))
    assert not accepted and math.isnan(nis)
    np.testing.assert_array_equal(P, np.eye(3))
    np.testing.assert_array_equal(dx, 0.0)


def test_repair_covariance_limits_and_pd():
    rng = np.random.default_rng(4)
    n = 5
    P = _random_spd(rng, n)
    work = np.empty((n, n))
    lo, hi = np.full(n, 1e-9), np.full(n, 1e9)
    before = P.copy()
    assert not linalg.repair_covariance(P, lo, hi, work, 1e-12)
    np.testing.assert_array_equal(P, before)
    # variance cap scales the row and column, keeping the correlation
    hi[2] = P[2, 2] / 4
    linalg.repair_covariance(P, lo, hi, work, 1e-12)
    assert P[2, 2] == pytest.approx(hi[2])
    corr = lambda m: m[2, 0] / math.sqrt(m[2, 2] * m[0, 0])  # noqa: E731
    assert corr(P) == pytest.approx(corr(before))
    # an indefinite matrix is repaired
    bad = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert linalg.repair_covariance(bad, np.zeros(3), np.full(3, 1e9), np.empty((3, 3)), 1e-9)
    assert np.linalg.eigvalsh(bad).min() >= 1e-9 * 0.999


def test_divergence_detection_and_reset():
    x, P = np.array([1.0, np.nan]), np.eye(2)
    assert not linalg.is_healthy(x, P)
    assert not linalg.is_healthy(np.zeros(2), np.array([[1.0, np.inf], [np.inf, 1.0]]))
    assert linalg.is_healthy(np.zeros(2), np.eye(2))
    assert not linalg.is_healthy(np.zeros(2), np.diag([1.0, 0.0]))  # a variance that is not positive
    # one non-finite entry anywhere in a 21-state covariance is found (its branch-free scan)
    x21, P21 = np.zeros(21), np.eye(21) + 0.1
    P21[0, 0] = P21[20, 20] = 1e300  # large but finite
    assert linalg.is_healthy(x21, P21)
    for bad in (np.nan, np.inf, -np.inf):
        for i, j in ((0, 1), (7, 13), (20, 19), (20, 0)):
            broken = P21.copy()
            broken[i, j] = bad
            assert not linalg.is_healthy(x21, broken), (bad, i, j)
    linalg.reset_filter(x, P, np.array([3.0, 4.0]), 2 * np.eye(2))
    np.testing.assert_array_equal(x, [3.0, 4.0])
    np.testing.assert_array_equal(P, 2 * np.eye(2))


def test_recorders_count_and_drop():
    diag_f, diag_i, counter = np.zeros((2, 4)), np.zeros((2, 3), dtype=np.int64), np.zeros(2, dtype=np.int64)
    for k in range(3):
        recorder.record_update(diag_f, diag_i, counter, 0.1 * k, 3, 1, 0.5, 2.0, 0.125, k % 2 == 0)
    assert counter[0] == 2 and counter[1] == 1
    np.testing.assert_allclose(diag_f[1], [0.1, 0.5, 2.0, 0.125])
    np.testing.assert_array_equal(diag_i[:, 2], [1, 0])
    out = np.zeros((2, 3))
    recorder.record_output(out, 1, np.array([1.0, 2.0, 3.0]))
    recorder.record_output(out, 5, np.array([1.0, 2.0, 3.0]))  # out of range: ignored
    np.testing.assert_array_equal(out, [[0, 0, 0], [1, 2, 3]])
    assert rotations.wrap_pi(math.pi) == pytest.approx(-math.pi)
