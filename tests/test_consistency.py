"""estimators.consistency and calib.figures: the chi-square figures from scipy.special equal scipy.stats', and the
mean NIS per channel (one bincount) equals a sorted groupby, for categorical and plain columns."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from calib.figures import chi2_quantile, mean_nis_band
from estimators.consistency import channel_consistency
from estimators.three_stage.run import vector_gate


@pytest.mark.parametrize("n", [1, 2, 7, 20, 500, 43200])
def test_mean_nis_band_is_the_chi_square_band_of_the_mean(n):
    low, high = mean_nis_band(n)
    assert low == pytest.approx(stats.chi2.ppf(0.025, n) / n, rel=1e-12)
    assert high == pytest.approx(stats.chi2.ppf(0.975, n) / n, rel=1e-12)
    assert chi2_quantile(0.95, 1) == pytest.approx(stats.chi2.ppf(0.95, 1), rel=1e-12)


@pytest.mark.parametrize(("gate_sigma", "components"), [(3.0, 2), (3.0, 3), (5.0, 3), (1.0, 1)])
def test_vector_gate_keeps_the_scalar_false_rejection_probability(gate_sigma, components):
    expected = stats.chi2.isf(stats.chi2.sf(gate_sigma ** 2, 1), components)
    assert vector_gate(gate_sigma, components) == pytest.approx(expected, rel=1e-10)
    assert vector_gate(np.inf, components) == np.inf


def _reference(diagnostics: pd.DataFrame) -> list[tuple[str, int, float]]:
    out = []
    for (sensor, component), group in diagnostics.groupby(["sensor", "component"], observed=True, sort=True):
        nis = group["nis"].to_numpy(float)
        nis = nis[np.isfinite(nis)]
        if len(nis):
            out.append((f"{sensor}.{component}", len(nis), float(nis.mean())))
    return out


def _diagnostics(rng, n: int) -> pd.DataFrame:
    sensors = pd.Categorical(rng.choice(["gps_pos", "mag", "baro"], n), categories=["baro", "mag", "gps_pos", "sun"])
    components = pd.Categorical(rng.choice(["x", "y", "z"], n), categories=["z", "x", "y", "n"])
    nis = rng.chisquare(1, n)
    nis[rng.random(n) < 0.1] = np.nan  # unrecorded NIS (rejected or not computed) are left out
    return pd.DataFrame({"sensor": sensors, "component": components, "nis": nis})


def test_channel_consistency_equals_a_sorted_groupby():
    rng = np.random.default_rng(5)
    frame = _diagnostics(rng, 5000)
    frame.loc[frame["sensor"] == "baro", "nis"] = np.nan  # a channel with no finite NIS is not listed
    got = [(c.channel, c.n_updates, c.mean_nis) for c in channel_consistency(frame)]
    expected = _reference(frame)
    assert [g[:2] for g in got] == [e[:2] for e in expected]  # categories' order, not alphabetical
    np.testing.assert_allclose([g[2] for g in got], [e[2] for e in expected], rtol=1e-12)
    assert not any(channel.startswith("baro.") for channel, _, _ in got)
    band = channel_consistency(frame)[0].band
    assert band == mean_nis_band(got[0][1])


def test_channel_consistency_of_plain_string_columns_is_alphabetical():
    rng = np.random.default_rng(6)
    frame = _diagnostics(rng, 2000)
    plain = frame.assign(sensor=frame["sensor"].astype(str), component=frame["component"].astype(str))
    got = [(c.channel, c.n_updates) for c in channel_consistency(plain)]
    assert got == [e[:2] for e in _reference(plain)]
    assert [channel for channel, _ in got] == sorted(channel for channel, _ in got)
