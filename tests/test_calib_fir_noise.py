"""FIR design, rho_h, eq 50 and the residual sigma (calib.fir, calib.noise)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.fir import default_cutoff_hz, default_numtaps, design_fir, frequency_response, zero_phase_lowpass
from calib.noise import channel_noise, eq50
from ingest.errors import InputError


def test_eq50_literal_on_a_hand_computed_example():
    measured = np.array([1.0, 3.0, 2.0, 6.0, 4.0])
    filtered = np.array([2.0, 2.5, 3.0, 3.5, 4.0])
    # ptp(measured) = 6 - 1 = 5, ptp(filtered) = 4 - 2 = 2 -> eta = (5 - 2) / 2 = 1.5
    # mean(measured) = 16 / 5 = 3.2, mean(filtered) = 15 / 5 = 3.0 -> beta = 0.2
    eta, beta = eq50(measured, filtered)
    assert eta == pytest.approx(1.5, abs=1e-12)
    assert beta == pytest.approx(0.2, abs=1e-12)


def test_rho_h_matches_the_design_note_and_a_monte_carlo():
    # docs/calibration.md, 'Noise and bias (eq 50)': 101-tap Hamming, fc = 5 Hz, fs = 50 Hz -> rho_h = 0.801 (ideal
    # low-pass: 1 - 5/25 = 0.8).
    spec = design_fir(50.0, 5.0, 101)
    assert spec.rho_h == pytest.approx(0.801, abs=1e-3)
    # Independent check: the fraction of white-noise variance left in x - filtfilt(x).
    x = np.random.default_rng(1).normal(size=200_000)
    residual = (x - zero_phase_lowpass(x, spec))[101:-101]
    assert np.var(residual) == pytest.approx(spec.rho_h, rel=0.01)


def test_frequency_response_unity_dc_and_minus_12_db_at_cutoff():
    spec = design_fir(250.0, 15.0, 111)
    response = frequency_response(spec, n_points=4096)
    assert response.gain_single[0] == pytest.approx(1.0, abs=1e-9)  # firwin scales to unity DC gain
    at_cutoff = np.argmin(np.abs(response.freq_hz - 15.0))
    # firwin's cutoff is the -6 dB (gain 0.5) point of one pass; filtfilt squares it (-12 dB, 0.25).
    assert response.gain_single[at_cutoff] == pytest.approx(0.5, abs=0.01)
    assert response.gain_zero_phase[at_cutoff] == pytest.approx(0.25, abs=0.01)
    assert response.gain_zero_phase[-1] < 1e-4


def test_defaults_follow_the_rate_and_vehicle():
    assert default_cutoff_hz(250.0, fixed_wing=True) == 5.0
    assert default_cutoff_hz(250.0, fixed_wing=False) == 15.0
    assert default_cutoff_hz(10.0, fixed_wing=False) == pytest.approx(2.0)  # capped at 0.2 fs for slow streams
    # docs/calibration.md, 'FIR filtering': transition ~3.3 fs / numtaps; fs = 250 Hz, fc = 10 Hz, width 5 Hz -> 165
    # taps.
    assert default_numtaps(250.0, 10.0) == 165
    assert default_numtaps(250.0, 15.0) % 2 == 1


@pytest.mark.parametrize(("fs_hz", "cutoff_hz", "numtaps", "field"), [
    (250.0, 15.0, 110, "numtaps"),      # even length
    (250.0, 125.0, 111, "cutoff_hz"),   # at Nyquist
    (250.0, -1.0, 111, "cutoff_hz"),
    (0.0, 1.0, 11, "fs_hz"),
])
def test_design_rejects_bad_settings(fs_hz, cutoff_hz, numtaps, field):
    with pytest.raises(InputError) as err:
        design_fir(fs_hz, cutoff_hz, numtaps)
    assert err.value.field == field


def test_too_short_segment_fails_clearly():
    spec = design_fir(250.0, 15.0, 111)
    with pytest.raises(InputError, match="too few for a 111-tap filter"):
        zero_phase_lowpass(np.zeros(300), spec)


def test_sigma_recovers_injected_white_noise_under_motion_and_bias():
    rng = np.random.default_rng(7)
    fs_hz, sigma = 250.0, 0.02
    t = np.arange(15_000) / fs_hz
    motion = 0.5 * np.sin(2 * np.pi * 0.4 * t) + 0.2 * np.sin(2 * np.pi * 1.3 * t + 1.0)
    noise = rng.normal(0.0, sigma, t.size)
    noise[::500] += 0.5  # sparse outliers: only the robust variant should ignore them
    spec = design_fir(fs_hz, 5.0, default_numtaps(fs_hz, 5.0))
    figures = channel_noise(motion + 0.3 + noise, spec)
    assert figures.sigma_robust == pytest.approx(sigma, rel=0.05)
    # The 30 outliers of 0.5 add ~ 30 * 0.25 / 15000 = 5e-4 to the variance: sigma grows to ~0.0305.
    assert figures.sigma == pytest.approx(np.sqrt(sigma**2 + 30 * 0.25 / 15_000), rel=0.05)
    # Eq 50's beta is ~0 for a unity-gain zero-phase filter, whatever the offset of 0.3.
    assert abs(figures.beta) < 1e-3 * sigma
    assert figures.mean == pytest.approx(0.3, abs=0.01)
    assert figures.n_used == 15_000 - 2 * spec.numtaps
