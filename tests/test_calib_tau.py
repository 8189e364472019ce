"""Automatic tau (eq 52) against a brute-force grid on synthetic replays with a known optimum."""

from __future__ import annotations

import numpy as np
import pytest

from calib.tau import Innovations, choose_tau, mean_nis, neg_log_likelihood, user_tau
from ingest.errors import InputError

# Synthetic replay: innovations nu ~ N(0, s2) fixed, innovation variance S(tau) = P_PART + tau * R_Y0 for all k.
# The mean NLL (ln 2 pi S + mean(nu^2) / S) / 2 is minimal where S = mean(nu^2), i.e. at
# tau* = (mean(nu^2) - P_PART) / R_Y0; the mean NIS mean(nu^2) / S equals 1 at the same tau.
P_PART, R_Y0 = 0.01, 0.02
TRUE_S2 = P_PART + 3.0 * R_Y0  # tau* ~ 3


def _replay(nu):
    def replay(tau):
        return Innovations(innovation=nu, innovation_var=np.full(nu.shape, P_PART + tau * R_Y0))
    return replay


@pytest.fixture(scope="module")
def nu():
    return np.random.default_rng(11).normal(0.0, np.sqrt(TRUE_S2), 5000)


def _closed_form_log10_tau(nu):
    return np.log10((np.mean(nu**2) - P_PART) / R_Y0)


def test_likelihood_optimum_matches_closed_form_and_brute_force_grid(nu):
    replay = _replay(nu)
    choice = choose_tau(replay, method="likelihood", xatol=1e-4)
    grid = np.linspace(-1.0, 2.0, 3001)  # brute force, step 1e-3 in log10 tau
    brute = grid[np.argmin([neg_log_likelihood(replay(10.0**g)) for g in grid])]
    assert np.log10(choice.tau) == pytest.approx(brute, abs=1e-3)
    assert np.log10(choice.tau) == pytest.approx(_closed_form_log10_tau(nu), abs=2e-4)
    assert choice.tau == pytest.approx(3.0, rel=0.1)  # sampling error of mean(nu^2) over 5000 draws ~ 2 %
    # The display curve: 13 points over [-1, 2], its minimum next to the optimum.
    assert choice.log10_tau_grid[0] == -1.0 and choice.log10_tau_grid[-1] == 2.0
    assert len(choice.neg_log_likelihood) == len(choice.mean_nis) == 13
    assert abs(choice.log10_tau_grid[int(np.argmin(choice.neg_log_likelihood))] - np.log10(choice.tau)) <= 0.125
    assert choice.nis_at_tau == pytest.approx(1.0, abs=1e-3)
    assert choice.nis_band[0] < 1.0 < choice.nis_band[1]
    assert abs(choice.lag1_autocorrelation) < 0.05 and choice.note == ""


def test_nis_matching_finds_the_same_tau(nu):
    choice = choose_tau(_replay(nu), method="nis", xatol=1e-6)
    assert np.log10(choice.tau) == pytest.approx(_closed_form_log10_tau(nu), abs=1e-5)
    assert choice.method == "nis" and choice.nis_at_tau == pytest.approx(1.0, abs=1e-4)


def test_unbracketed_nis_takes_the_closer_bound_with_a_note():
    huge = np.random.default_rng(2).normal(0.0, 10.0, 2000)  # NIS > 1 even at tau = 100
    choice = choose_tau(_replay(huge), method="nis")
    assert choice.tau == pytest.approx(100.0) and "no root" in choice.note


def test_coloured_innovations_are_flagged():
    rng = np.random.default_rng(5)
    white = rng.normal(0.0, np.sqrt(TRUE_S2 * (1 - 0.9**2)), 5000)
    coloured = np.zeros_like(white)
    for k in range(1, len(white)):  # AR(1), lag-1 autocorrelation 0.9, variance TRUE_S2
        coloured[k] = 0.9 * coloured[k - 1] + white[k]
    choice = choose_tau(_replay(coloured))
    assert choice.lag1_autocorrelation == pytest.approx(0.9, abs=0.03)
    assert "coloured" in choice.note


def test_statistics_and_validation():
    innovations = Innovations(np.array([1.0, -2.0]), np.array([1.0, 4.0]))
    assert mean_nis(innovations) == pytest.approx(1.0)  # (1/1 + 4/4) / 2
    assert neg_log_likelihood(innovations) == pytest.approx(np.mean(np.log(2 * np.pi * np.array([1.0, 4.0])) + 1) / 2)
    with pytest.raises(InputError):
        mean_nis(Innovations(np.array([1.0]), np.array([0.0])))
    with pytest.raises(InputError):
        choose_tau(_replay(np.ones(3)), method="max")
    assert user_tau(2.5).tau == 2.5
    for bad in (0.0, -1.0, float("inf")):
        with pytest.raises(InputError):
            user_tau(bad)
