"""Barometric relations used to complete PX4 air-data streams (ISA troposphere, as PX4's sensors module).

PX4 turns static pressure into ``baro_alt_meter`` with the ISA troposphere, a QNH from the ``SENS_BARO_QNH``
parameter and its own gas constant (287.1 J/(kg K)); these functions use the same constants so that a
pressure derived from a logged altitude (or the reverse) reproduces what PX4 would have logged.
"""

from __future__ import annotations

import numpy as np

#: PX4's CONSTANTS_ONE_G [m/s^2] and CONSTANTS_AIR_GAS_CONST [J/(kg K)].
STANDARD_GRAVITY_M_S2 = 9.80665
AIR_GAS_CONSTANT_J_KG_K = 287.1
#: ISA sea-level temperature [K], tropospheric lapse rate [K/m], sea-level pressure [Pa] and density [kg/m^3].
ISA_SEA_LEVEL_TEMP_K = 288.15
ISA_LAPSE_RATE_K_M = 0.0065
ISA_SEA_LEVEL_PRESSURE_PA = 101325.0
ISA_SEA_LEVEL_DENSITY_KG_M3 = 1.225
#: Exponent L R / g of the barometric formula.
_EXPONENT = ISA_LAPSE_RATE_K_M * AIR_GAS_CONSTANT_J_KG_K / STANDARD_GRAVITY_M_S2


def pressure_altitude_m(pressure_pa, qnh_pa=ISA_SEA_LEVEL_PRESSURE_PA):
    """Altitude [m] above the QNH reference of static pressure ``pressure_pa`` [Pa] (PX4 ``baro_alt_meter``)."""
    ratio = np.asarray(pressure_pa, dtype=float) / qnh_pa
    return ISA_SEA_LEVEL_TEMP_K / ISA_LAPSE_RATE_K_M * (1.0 - ratio**_EXPONENT)


def altitude_pressure_pa(alt_m, qnh_pa=ISA_SEA_LEVEL_PRESSURE_PA):
    """Static pressure [Pa] at altitude ``alt_m`` [m] above the QNH reference (inverse of
    :func:`pressure_altitude_m`)."""
    temp_ratio = 1.0 - ISA_LAPSE_RATE_K_M * np.asarray(alt_m, dtype=float) / ISA_SEA_LEVEL_TEMP_K
    return qnh_pa * temp_ratio ** (1.0 / _EXPONENT)


def isa_density_kg_m3(pressure_pa):
    """Air density [kg/m^3] at static pressure ``pressure_pa`` [Pa] with the ISA temperature of that pressure
    level (the logged baro temperature is the sensor's, heated by the board, not the air's)."""
    temp_k = ISA_SEA_LEVEL_TEMP_K - ISA_LAPSE_RATE_K_M * pressure_altitude_m(pressure_pa)
    return np.asarray(pressure_pa, dtype=float) / (AIR_GAS_CONSTANT_J_KG_K * temp_k)
