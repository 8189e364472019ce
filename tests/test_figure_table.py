"""The one table from calibration figures to filter settings (:data:`calib.figures.FIGURES`, issue 30): it covers
every figure the calibration and the noise identification produce, names configuration fields, estimators and
sensor-plan flags that exist, and what is derived from it (the settings of every estimator, the search vector and
its inverse, the ignored figures of the run report) is what the explicit mappings below say: the hand-keyed
mappings the code held before the table."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from calib.calibration import calibrate
from calib.figures import (
    ESTIMATOR_NAMES,
    FIGURES,
    RULE_AXES,
    RULE_FACTOR,
    RULE_NORMALISER,
    RULE_VALUE,
    RULES,
    SOURCE_TUNED,
    SOURCE_USER,
    SOURCES,
    Figure,
    TuneResult,
)
from calib.filter_figures import calibration_figures
from calib.segments import user_segment
from estimators.api import DEFAULT_ESTIMATORS, ESTIMATORS, IGNORED_FIGURES
from estimators.config import (
    CalibratedInputs,
    EstimatorConfig,
    NoiseConfig,
    config_from_calibration,
    config_from_figures,
)
from estimators.inputs.records import SensorPlan
from estimators.tuning import KNOBS, start_values, tuned_figures
from ingest.log_formats import load_flight_log

SAMPLE_LOG = Path(__file__).resolve().parents[1] / "sample_logs" / "paper.ulg"
#: A field strength for the magnetometer figures [gauss].
STRENGTH_GAUSS = 0.48

#: figure -> NoiseConfig field a measured figure is root-sum-squared into (a tuned or user one replaces it).
NOISE_FIELDS = {
    "gyro_noise_density": "gyro_noise_rad_s_sqrt_hz", "accel_noise_density": "accel_noise_m_s2_sqrt_hz",
    "gyro_bias_walk": "gyro_bias_rw_rad_s2_sqrt_hz", "accel_bias_walk": "accel_bias_rw_m_s3_sqrt_hz",
    "accel_bias_walk_z": "accel_bias_rw_z_m_s3_sqrt_hz", "baro_noise": "baro_sigma_m",
    "baro_bias_walk": "baro_bias_rw_m_sqrt_s", "airspeed_noise": "airspeed_sigma_m_s",
    "sideslip_noise": "sideslip_sigma_m_s", "gps_vel_noise": "gps_vel_sigma_default_m_s",
    "gps_vel_noise_scale": "gps_vel_accuracy_scale", "wind_walk": "wind_rw_m_s_sqrt_s",
}
#: figure -> the NoiseConfig factors and floors it multiplies.
GPS_SCALES = {"gps_pos_noise_scale": ("gps_pos_eph_scale", "gps_pos_sigma_floor_m"),
              "gps_hgt_noise_scale": ("gps_hgt_epv_scale", "gps_hgt_sigma_floor_m")}
#: figure -> CalibratedInputs field it sets (its value, or its three axes).
CALIBRATED_VALUES = {"accel_tau": "accel_tau", "accel_stage1_floor": "accel_stage1_floor_m_s2"}
CALIBRATED_AXES = {"accel_axis_noise_density": "accel_axis_density", "gyro_bias": "gyro_bias_rad_s",
                   "accel_bias": "accel_bias_m_s2"}
#: The identification's search order.
SEARCH_ORDER = ("baro_noise", "mag_noise", "airspeed_noise", "sideslip_noise", "gps_pos_noise_scale",
                "gps_hgt_noise_scale", "gps_vel_noise_scale", "accel_stage1_floor", "accel_tau", "gyro_noise_density",
                "accel_noise_density", "gyro_bias_walk", "accel_bias_walk", "accel_bias_walk_z", "wind_walk",
                "mag_bias_walk", "baro_bias_walk")
_STAGE1 = "no stage-1 accelerometer update (the accelerometer drives the propagation)"
_NO_STATE = "no such state in the three-stage estimator"
_BIAS_STATE = "estimated as a state of the filter"
_FULL_STATE_IGNORES = {"accel_tau": _STAGE1, "accel_axis_noise_density": _STAGE1, "accel_stage1_floor": _STAGE1,
                       "gyro_bias": _BIAS_STATE, "accel_bias": _BIAS_STATE}
EXPECTED_IGNORED = {
    "three_stage": {"gyro_bias_walk": _NO_STATE, "accel_bias_walk": _NO_STATE, "accel_bias_walk_z": _NO_STATE,
                    "mag_bias_walk": _NO_STATE, "baro_bias_walk": _NO_STATE,
                    "baro_noise": "the barometer is a low-passed input, not a measurement update",
                    "sideslip_noise": "no sideslip pseudo-measurement"},
    "full_state_direct": _FULL_STATE_IGNORES,
    "full_state_indirect": _FULL_STATE_IGNORES,
}


@pytest.fixture(scope="module")
def paper_log():
    return load_flight_log(SAMPLE_LOG)


@pytest.fixture(scope="module", params=["auto", "in flight"])
def paper_calibration(request, paper_log):
    """The sample log calibrated on its still segments, and on a stretch of flight (the in-flight sources)."""
    if request.param == "auto":
        return calibrate(paper_log)
    start_s = float(paper_log["imu"].index[0])
    return calibrate(paper_log, segment=user_segment(paper_log, start_s + 300.0, start_s + 360.0))


def explicit_config(figures: dict[str, Figure]) -> EstimatorConfig:
    """The configuration ``figures`` give by the explicit mappings of this module (defaults as base)."""
    default, noise, calibrated = NoiseConfig(), {}, {}
    strength = figures["mag_field_strength"].value if "mag_field_strength" in figures else math.nan

    def combined(value, figure, default_value):
        return value if figure.source in (SOURCE_TUNED, SOURCE_USER) else math.hypot(default_value, value)

    for name, figure in figures.items():
        if name in NOISE_FIELDS:
            field = NOISE_FIELDS[name]
            default_value = getattr(default, field)
            if default_value is None:
                default_value = default.accel_bias_rw_m_s3_sqrt_hz
            noise[field] = combined(figure.value, figure, default_value)
        elif name == "mag_noise" and strength > 0:
            noise["mag_sigma_axes"] = tuple(combined(a / strength, figure, default.mag_sigma)
                                            for a in figure.axes or (figure.value,) * 3)
        elif name == "mag_bias_walk" and strength > 0:
            noise["mag_bias_rw_sqrt_s"] = combined(figure.value / strength, figure, default.mag_bias_rw_sqrt_s)
        elif name in GPS_SCALES:
            noise.update({field: getattr(default, field) * figure.value for field in GPS_SCALES[name]})
        elif name in CALIBRATED_VALUES:
            calibrated[CALIBRATED_VALUES[name]] = figure.value
        elif name in CALIBRATED_AXES and len(figure.axes) == 3:
            calibrated[CALIBRATED_AXES[name]] = tuple(figure.axes)
    return EstimatorConfig(noise=dataclasses.replace(default, **noise), calibrated=CalibratedInputs(**calibrated))


def assert_explicit(config: EstimatorConfig, figures: dict[str, Figure]) -> None:
    """``config`` is :func:`explicit_config` of ``figures``, with every figure's source in its provenance."""
    assert [(name, source) for name, source, _ in config.calibrated.provenance] == [
        (name, figure.source) for name, figure in figures.items()]
    expected = explicit_config(figures)
    assert config == dataclasses.replace(expected, calibrated=dataclasses.replace(
        expected.calibrated, provenance=config.calibrated.provenance))


def test_settings_name_configuration_fields_that_exist():
    sections = {"noise": {f.name for f in dataclasses.fields(NoiseConfig)},
                "calibrated": {f.name for f in dataclasses.fields(CalibratedInputs)}}
    for row in FIGURES.values():
        setting = row.setting
        assert setting.rule in RULES, row.name
        assert {*setting.fields, *setting.default_fields} <= sections[setting.section], row.name
        assert bool(setting.fields) == (setting.rule != RULE_NORMALISER), row.name
        assert bool(setting.use) == (setting.rule in (RULE_VALUE, RULE_AXES, RULE_NORMALISER)), row.name


def test_rows_name_sources_estimators_and_plan_flags_that_exist():
    assert ESTIMATOR_NAMES == tuple(ESTIMATORS) == DEFAULT_ESTIMATORS
    plan_flags = {f.name for f in dataclasses.fields(SensorPlan)}
    for row in FIGURES.values():
        assert row.unit and row.meaning and set(row.sources) <= set(SOURCES), row.name
        assert {estimator for estimator, _ in row.ignored} <= set(ESTIMATORS), row.name
        search = row.identification
        if search is not None:
            assert 0 < search.lower < search.upper and set(search.estimators) <= set(ESTIMATORS), row.name
            assert search.needs is None or search.needs in plan_flags, row.name
            assert SOURCE_TUNED in row.sources, row.name
    assert FIGURES.accel_tau is FIGURES["accel_tau"]
    with pytest.raises(AttributeError, match="no figure 'lidar_noise'"):
        _ = FIGURES.lidar_noise


def test_table_covers_every_figure_of_the_calibration_with_its_sources(paper_calibration):
    figures = calibration_figures(paper_calibration)
    for name, figure in figures.items():
        assert figure.source in FIGURES[name].sources, name


def test_table_covers_every_figure_of_the_identification():
    values = {k.name: k.identification.lower for k in KNOBS}
    figures = tuned_figures({}, values, EstimatorConfig(), STRENGTH_GAUSS)
    assert set(figures) == {*SEARCH_ORDER, "mag_field_strength"}
    assert all(figure.source in FIGURES[name].sources for name, figure in figures.items())


def test_search_vector_in_its_order_and_ignored_figures_as_before():
    assert tuple(k.name for k in KNOBS) == SEARCH_ORDER
    assert IGNORED_FIGURES == EXPECTED_IGNORED


def test_start_values_invert_the_settings_of_the_identified_figures():
    values = {k.name: math.sqrt(k.identification.lower * k.identification.upper) for k in KNOBS}
    start = EstimatorConfig()
    figures = tuned_figures({}, values, start, STRENGTH_GAUSS)
    config = config_from_figures(figures)
    assert_explicit(config, figures)
    back = start_values(config, STRENGTH_GAUSS)
    for k in KNOBS:
        if k.setting.rule == RULE_FACTOR:  # the factor is in the settings it multiplies: the search restarts at 1
            assert back[k.name] == 1.0
            for field in k.setting.fields:
                assert getattr(config.noise, field) == pytest.approx(getattr(start.noise, field) * values[k.name])
        else:
            assert back[k.name] == pytest.approx(values[k.name], rel=1e-12), k.name


def test_config_of_every_estimator_from_the_sample_calibration_is_the_explicit_mapping(paper_calibration):
    figures = calibration_figures(paper_calibration)
    for estimator in (None, *ESTIMATORS):
        assert_explicit(config_from_calibration(paper_calibration, estimator=estimator), figures)


def test_config_of_every_estimator_from_its_tuned_figures_is_the_explicit_mapping(paper_calibration):
    base = calibration_figures(paper_calibration)
    start = config_from_calibration(paper_calibration)
    tuning = {}
    for number, estimator in enumerate(ESTIMATORS):  # a different point of the search space per estimator
        values = {k.name: k.identification.lower * (2.0 + number) for k in KNOBS}
        tuning[estimator] = TuneResult(estimator=estimator, figures=tuned_figures(base, values, start, STRENGTH_GAUSS),
                                       start={}, bounds={}, log_likelihood_trace=(), n_replays=0)
    calibration = dataclasses.replace(paper_calibration, tuning=tuning)
    for estimator, result in tuning.items():
        assert_explicit(config_from_calibration(calibration, estimator=estimator), result.figures)
