"""Named scenarios: a mission, a site, a wind model, the sensor grades and a seed.

``paper``
    The paper's mission (section 4, docs/evaluation.md, 'Table 2 set-up'): 60 s at rest on the ground (initial
    alignment, static
    calibration), hand launch into the wind, circling climb at 3 m/s to 600 m above ground at about 12.5 m/s,
    cruise out, loiter three circles of 100 m radius ("hover"), turn back, cruise home, circling descent, landing
    and 10 s at rest; about 14.5 minutes. The paper's simulation was windless; here a light steady wind (2.5 m/s
    from 300 deg, the field test had 3.5 m/s) with a slow variation exercises the wind estimators. The
    magnetometer carries the solar-panel disturbance.
``calm``
    ``paper`` without wind (the paper's own set-up).
``gusty``
    ``paper`` in 5 m/s wind with 1.5 m/s gusts.
``cloudy``
    ``paper`` with a cloud dimming the sun to 30 % for two minutes of the cruise and loiter.
``failed_cell``
    Two minutes: 30 s at rest, launch, circling climb to 100 m and one loiter circle; side cell 2 (facing
    forward) is stuck at 0 A from 40 s to 100 s.
``static``
    Ten minutes at rest on the ground (Allan deviation, static calibration).
``mag_disturbed``
    About five minutes: 30 s at rest, launch, circling climb to 150 m, two loiter circles, a cruise leg, a half
    turn and a cruise back; the solar-panel disturbance of the magnetometer is twelve times the ``paper`` one
    (0.06 gauss/A: up to 0.24 gauss at full panel current, 0.17 gauss in this flight, a third of the earth
    field), so it changes with the bank angle through the sun's incidence on the wing. The proof case of
    sun-aided heading (``tests/test_sun_aided.py``).
``turbulent``
    About 10.4 minutes at low altitude, where turbulence is realistic: 60 s at rest, hand launch, circling climb to
    150 m above ground, cruise 120 s, three loiter circles of 100 m radius, half turn, cruise 120 s back, circling
    descent, landing and 10 s at rest; 5 m/s mean wind from 300 deg (slowly varying), moderate Dryden turbulence
    (W20 = 12 m/s: at 150 m sigma_u = sigma_v = 1.49 m/s, sigma_w = 1.2 m/s, L_u = L_v = 287 m, L_w = 150 m) and
    four discrete 1-cosine gusts: a 3 m/s head gust over 40 m (150 s), a 2.5 m/s updraft over 30 m (200 s), a
    2 m/s gust from the right over 60 m in the loiter (300 s) and a 2 m/s downdraft over 20 m (480 s). The gusts
    move the aircraft (docs/evaluation.md, 'Turbulence (Dryden and discrete gusts)').
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ingest.sun_device import SunDevice
from sim.kinematics import Site
from sim.mission import ChangeAltitude, Cruise, HandLaunch, Land, Mission, Still, Turn
from sim.photocells import SunCellGrade
from sim.sensors import AirspeedGrade, BaroGrade, GpsGrade, ImuGrade, MagGrade
from sim.turbulence import DiscreteGust, TurbulenceConfig
from sim.wind import WindConfig


@dataclass(frozen=True)
class SensorSpec:
    """Grades of every simulated sensor and the sun-device geometry.

    Attributes
    ----------
    imu, mag, baro, airspeed, gps, sun : grade dataclasses
        See :mod:`sim.sensors` and :mod:`sim.photocells`.
    device : SunDevice
        Photocell geometry and mounting.
    """

    imu: ImuGrade = field(default_factory=ImuGrade)
    mag: MagGrade = field(default_factory=MagGrade)
    baro: BaroGrade = field(default_factory=BaroGrade)
    airspeed: AirspeedGrade = field(default_factory=AirspeedGrade)
    gps: GpsGrade = field(default_factory=GpsGrade)
    sun: SunCellGrade = field(default_factory=SunCellGrade)
    device: SunDevice = field(default_factory=SunDevice)


@dataclass(frozen=True)
class Scenario:
    """Everything a simulation run needs except the random generator.

    Attributes
    ----------
    name : str
        Identifier (CLI ``--scenario``, output file names).
    mission : Mission
        Flight plan.
    site : Site
        Location, time and atmosphere.
    wind : WindConfig
        Wind model.
    sensors : SensorSpec
        Sensor grades.
    seed : int
        Default seed of the generator (``numpy.random.default_rng(seed)``).
    truth_rate_hz : float
        Rate of the ground-truth streams in the output log [Hz]; 25 Hz keeps the bundled logs small and resolves
        the smooth kinematic motion (linear interpolation error < 0.001 deg).
    """

    name: str
    mission: Mission
    site: Site = field(default_factory=Site)
    wind: WindConfig = field(default_factory=WindConfig)
    sensors: SensorSpec = field(default_factory=SensorSpec)
    seed: int = 0
    truth_rate_hz: float = 25.0


_PAPER_MISSION = Mission(
    legs=(Still(60.0), HandLaunch(airspeed_m_s=12.5), ChangeAltitude(600.0, 3.0, turn_radius_m=300.0),
          Cruise(90.0), Turn(3 * 360.0, radius_m=100.0), Turn(180.0, radius_m=150.0), Cruise(90.0),
          ChangeAltitude(0.0, 3.0, turn_radius_m=300.0, clockwise=False), Land(), Still(10.0)),
    initial_heading_deg=300.0)

_PAPER = Scenario(name="paper", mission=_PAPER_MISSION, seed=3)

_TURBULENT_MISSION = Mission(
    legs=(Still(60.0), HandLaunch(airspeed_m_s=12.5), ChangeAltitude(150.0, 3.0, turn_radius_m=150.0),
          Cruise(120.0), Turn(3 * 360.0, radius_m=100.0), Turn(180.0, radius_m=150.0), Cruise(120.0),
          ChangeAltitude(0.0, 3.0, turn_radius_m=150.0, clockwise=False), Land(), Still(10.0)),
    initial_heading_deg=300.0)
_TURBULENT_WIND = WindConfig(speed_m_s=5.0, slow_sigma_m_s=0.5, turbulence=TurbulenceConfig(
    w20_m_s=12.0, gusts=(DiscreteGust(150.0, -3.0, 40.0, "u"), DiscreteGust(200.0, -2.5, 30.0, "w"),
                         DiscreteGust(300.0, -2.0, 60.0, "v"), DiscreteGust(480.0, 2.0, 20.0, "w"))))

#: Every named scenario.
SCENARIOS: dict[str, Scenario] = {
    "paper": _PAPER,
    "calm": replace(_PAPER, name="calm", wind=WindConfig(speed_m_s=0.0, slow_sigma_m_s=0.0)),
    "gusty": replace(_PAPER, name="gusty", wind=WindConfig(speed_m_s=5.0, slow_sigma_m_s=1.0, gust_sigma_m_s=1.5)),
    "cloudy": replace(_PAPER, name="cloudy",
                      sensors=SensorSpec(sun=SunCellGrade(cloud_window_s=(330.0, 450.0)))),
    "failed_cell": Scenario(
        name="failed_cell",
        mission=Mission(legs=(Still(30.0), HandLaunch(), ChangeAltitude(100.0, 3.0, turn_radius_m=150.0),
                              Turn(360.0, radius_m=100.0)), initial_heading_deg=300.0),
        sensors=SensorSpec(sun=SunCellGrade(failed_cell=2, failed_window_s=(40.0, 100.0))), seed=7),
    "static": Scenario(name="static", mission=Mission(legs=(Still(600.0),), initial_heading_deg=120.0), seed=11),
    "mag_disturbed": Scenario(
        name="mag_disturbed",
        mission=Mission(legs=(Still(30.0), HandLaunch(), ChangeAltitude(150.0, 3.0, turn_radius_m=150.0),
                              Turn(2 * 360.0, radius_m=100.0), Cruise(45.0), Turn(180.0, radius_m=120.0),
                              Cruise(45.0)), initial_heading_deg=300.0),
        sensors=SensorSpec(mag=MagGrade(solar_gauss_per_a=0.06)), seed=13),
    "turbulent": Scenario(name="turbulent", mission=_TURBULENT_MISSION, wind=_TURBULENT_WIND, seed=17),
}
