"""Forward model of the 7-photocell sun device (docs/sun.md, 'Current model'): cell currents from the sun and up
vectors in the device frame, the isotropic-sky view factors, and the device-frame sun/up vectors of an attitude.
The simulator and the solvers share it.
"""

from __future__ import annotations

import numpy as np

from ingest.flightlog import STREAM_COLUMNS
from ingest.sun_device import SunDevice

#: Current columns of the canonical ``sun`` stream, cell 1 (top) first.
CURRENT_COLUMNS = STREAM_COLUMNS["sun"]

_UP_BODY = np.array([0.0, 0.0, -1.0])


# ----------------------------------------------------------------------------------------------------------------
# Forward model
# ----------------------------------------------------------------------------------------------------------------
def default_up_device(device: SunDevice) -> np.ndarray:
    """Up direction in the device frame of a level vehicle, shape (3,) (``R_bd^T (0, 0, -1)``)."""
    return device.body_from_device.T @ _UP_BODY


def sky_view_factors(device: SunDevice, up_device=None) -> np.ndarray:
    """Fraction of the sky dome each cell sees, ``(1 + n_i . u) / 2``, shape (..., 7) [-].

    Parameters
    ----------
    device : SunDevice
        Cell geometry.
    up_device : array-like, shape (3,) or (N, 3), optional
        Unit up vector in the device frame; a level vehicle (:func:`default_up_device`) when omitted.
    """
    up = default_up_device(device) if up_device is None else np.asarray(up_device, dtype=float)
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    return 0.5 * (1.0 + up @ device.normals_device.T)


def photocell_currents(s_device, k_a, sky_a, device: SunDevice, up_device=None) -> np.ndarray:
    """Noise-free cell currents ``I_i = k max(0, n_i . s) + I_sky (1 + n_i . u) / 2`` [A].

    Parameters
    ----------
    s_device : array-like, shape (3,) or (N, 3)
        Unit vector towards the sun in the device frame [-].
    k_a : float or array-like, shape (N,)
        Current of a cell facing the sun [A] (0 at night or under thick cloud).
    sky_a : float or array-like, shape (N,)
        Sky-light current of a cell facing the zenith [A].
    device : SunDevice
        Cell geometry.
    up_device : array-like, shape (3,) or (N, 3), optional
        Unit up vector in the device frame; a level vehicle when omitted (:func:`device_sun_and_up` gives both
        vectors from an attitude).

    Returns
    -------
    numpy.ndarray, shape (7,) or (N, 7)
        Currents of cells 1..7 [A] (column order of the ``sun`` stream).
    """
    cos_incidence = np.asarray(s_device, dtype=float) @ device.normals_device.T
    direct = np.asarray(k_a, dtype=float)[..., None] * np.maximum(cos_incidence, 0.0)
    return direct + np.asarray(sky_a, dtype=float)[..., None] * sky_view_factors(device, up_device)


def device_sun_and_up(r_nb, s_ned, device: SunDevice) -> tuple[np.ndarray, np.ndarray]:
    """Sun and up unit vectors in the device frame for attitudes ``r_nb``.

    Parameters
    ----------
    r_nb : array-like, shape (3, 3) or (N, 3, 3)
        Body FRD -> NED rotations.
    s_ned : array-like, shape (3,) or (N, 3)
        Unit vector towards the sun in NED.
    device : SunDevice
        Provides the mounting ``R_bd``.

    Returns
    -------
    s_device, up_device : numpy.ndarray, shape (..., 3)
        ``R_bd^T R_nb^T s_n`` and ``R_bd^T R_nb^T (0, 0, -1)``.
    """
    r_nb = np.asarray(r_nb, dtype=float)
    r_bd = device.body_from_device
    s_body = np.einsum("...ji,...j->...i", r_nb, np.asarray(s_ned, dtype=float))
    up_body = -r_nb[..., 2, :]
    return s_body @ r_bd, up_body @ r_bd
