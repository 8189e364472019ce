"""The sun vector as an attitude measurement, used by all three filters (docs/sun.md, 'Measurement model'):
``z = s_b``, ``h = R_nb^T s_n``, ``dh/dTheta = [h]x W(Theta)`` for ZYX Euler angles, ``dh/d(dtheta) = [h]x`` for
the body-axes error angle of the error-state filter; fused as two scalars on the tangent plane of the prediction;
noise ``sigma_rad^2`` per tangent axis.
"""

from __future__ import annotations

import numpy as np
from numba import njit


# ----------------------------------------------------------------------------------------------------------------
# Measurement model for the filters (numba leaf functions; plain float64 arrays in, new arrays out)
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def sun_measurement(r_nb, s_ned):
    """Predicted body-frame sun vector ``h = C_bn s_n = R_nb^T s_n``, shape (3,).

    Parameters
    ----------
    r_nb : numpy.ndarray, shape (3, 3)
        Body FRD -> NED rotation.
    s_ned : numpy.ndarray, shape (3,)
        Unit vector towards the sun in NED (``estimators.environment.sun_direction_ned``).
    """
    return r_nb.T @ s_ned


@njit(cache=True)
def _cross_matrix_times(h, w):
    """[h]x w for a 3x3 matrix w: column j is h x w[:, j]."""
    out = np.empty((3, 3))
    for j in range(3):
        out[0, j] = h[1] * w[2, j] - h[2] * w[1, j]
        out[1, j] = h[2] * w[0, j] - h[0] * w[2, j]
        out[2, j] = h[0] * w[1, j] - h[1] * w[0, j]
    return out


@njit(cache=True)
def sun_jacobian_euler(r_nb, s_ned):
    """``dh/dTheta = [h]x W(Theta)`` for ZYX Euler angles Theta = (roll, pitch, yaw), shape (3, 3) [1/rad].

    ``W = [[1, 0, -s_th], [0, c_ph, s_ph c_th], [0, -s_ph, c_ph c_th]]`` (omega = W Theta_dot, docs/estimators.md,
    'Frames and attitude identities') is built
    from ``r_nb`` itself (``R31 = -s_th``, ``R32 = s_ph c_th``, ``R33 = c_ph c_th``); singular at pitch +-90 deg.

    Parameters
    ----------
    r_nb : numpy.ndarray, shape (3, 3)
        Body FRD -> NED rotation of the state's Euler angles.
    s_ned : numpy.ndarray, shape (3,)
        Unit vector towards the sun in NED.
    """
    cos_pitch = np.hypot(r_nb[2, 1], r_nb[2, 2])
    w = np.zeros((3, 3))
    w[0, 0] = 1.0
    w[0, 2] = r_nb[2, 0]
    w[1, 1] = r_nb[2, 2] / cos_pitch
    w[1, 2] = r_nb[2, 1]
    w[2, 1] = -r_nb[2, 1] / cos_pitch
    w[2, 2] = r_nb[2, 2]
    return _cross_matrix_times(r_nb.T @ s_ned, w)


@njit(cache=True)
def sun_jacobian_error_angle(r_nb, s_ned):
    """``dh/d(dtheta) = [h]x`` for the body-axes error angle ``R = R_hat Exp(dtheta)``, shape (3, 3) [1/rad].

    Parameters
    ----------
    r_nb : numpy.ndarray, shape (3, 3)
        Nominal body FRD -> NED rotation.
    s_ned : numpy.ndarray, shape (3,)
        Unit vector towards the sun in NED.
    """
    return _cross_matrix_times(r_nb.T @ s_ned, np.eye(3))


@njit(cache=True)
def sun_tangent_basis(h):
    """Orthonormal basis of the plane perpendicular to ``h`` (normalised first), shape (3, 2), columns
    ``(t1, u x t1)`` with ``u = h / |h|``; the one tangent basis of the three filters' sun updates.

    For the 2-DOF form of the update (docs/sun.md, 'Measurement model'): ``nu = T^T z``, ``H' = T^T H``, ``R' =
    sigma_rad^2 I_2``.
    """
    norm = np.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    u0, u1, u2 = h[0] / norm, h[1] / norm, h[2] / norm
    if abs(u0) < 0.9:
        a0, a1, a2 = 1.0, 0.0, 0.0
    else:
        a0, a1, a2 = 0.0, 1.0, 0.0
    d = a0 * u0 + a1 * u1 + a2 * u2
    t0, t1, t2 = a0 - d * u0, a1 - d * u1, a2 - d * u2
    tn = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    t0, t1, t2 = t0 / tn, t1 / tn, t2 / tn
    basis = np.empty((3, 2))
    basis[0, 0], basis[1, 0], basis[2, 0] = t0, t1, t2
    basis[0, 1] = u1 * t2 - u2 * t1
    basis[1, 1] = u2 * t0 - u0 * t2
    basis[2, 1] = u0 * t1 - u1 * t0
    return basis


@njit(cache=True)
def tangent_projection(basis, axis, z, h3, H3, H):
    """One scalar of the 2-DOF sun update (docs/sun.md, 'Measurement model'): the innovation ``nu = t^T (z - h)`` along
    the tangent axis
    ``t = basis[:, axis]`` and its Jacobian row ``H = t^T H3`` (written into ``H``, length n).

    ``z``: measured body-frame unit vector (its first 3 entries); ``h3`` (3,) and ``H3`` (3, n): predicted vector
    and its Jacobian.
    """
    nu = 0.0
    for c in range(3):
        nu += basis[c, axis] * (z[c] - h3[c])
    for i in range(H.shape[0]):
        H[i] = basis[0, axis] * H3[0, i] + basis[1, axis] * H3[1, i] + basis[2, axis] * H3[2, i]
    return nu


@njit(cache=True)
def sun_measurement_noise(sigma_rad):
    """Measurement covariance of the 3-vector form, ``sigma_rad^2 I_3`` [-], from the solver's ``sigma_rad``."""
    return sigma_rad * sigma_rad * np.eye(3)
