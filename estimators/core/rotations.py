"""Rotation leaf functions shared by the filters (numba, allocation-free): angle wrapping, quaternion product and
exponential, rotation of a vector by a quaternion, the SO(3) right Jacobian, 3x3 helpers.

Quaternions are Hamilton (w, x, y, z), body FRD -> NED; Euler angles ZYX (roll, pitch, yaw) [rad].
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def wrap_pi(angle_rad):
    """Wrap an angle [rad] to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


_SMALL_ANGLE_RAD = 1e-6

# ----------------------------------------------------------------------------------------------------------------
# Rotation helpers (Hamilton quaternions, scalar first). Scalar in, scalars out: the time loop calls them per
# sample, and a 3-vector or 3 x 3 array per call would cost a heap allocation each.
# ----------------------------------------------------------------------------------------------------------------
@njit(cache=True)
def dcm_into(w, x, y, z, out):
    """Rotation matrix R(q) of the unit quaternion (w, x, y, z) (maps body vectors into NED for the attitude
    quaternion) written into ``out`` (3, 3)."""
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def rotate(w, x, y, z, vx, vy, vz):
    """R(q) v for the unit quaternion q = (w, x, y, z): ``v + 2 w (u x v) + 2 u x (u x v)`` with ``u = (x, y, z)``
    (pass the conjugate ``(w, -x, -y, -z)`` for ``R^T v``)."""
    cx = y * vz - z * vy
    cy = z * vx - x * vz
    cz = x * vy - y * vx
    return (vx + 2.0 * (w * cx + y * cz - z * cy),
            vy + 2.0 * (w * cy + z * cx - x * cz),
            vz + 2.0 * (w * cz + x * cy - y * cx))


@njit(cache=True)
def quat_exp(rx, ry, rz):
    """Unit quaternion Exp(phi) = (cos(|phi|/2), sin(|phi|/2) phi/|phi|) of a rotation vector [rad], as (w, x, y, z)."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < _SMALL_ANGLE_RAD:
        w = 1.0 - angle * angle / 8.0
        scale = 0.5 - angle * angle / 48.0
    else:
        w = math.cos(0.5 * angle)
        scale = math.sin(0.5 * angle) / angle
    return w, scale * rx, scale * ry, scale * rz


@njit(cache=True)
def quat_multiply(aw, ax, ay, az, bw, bx, by, bz):
    """Hamilton product a (x) b of two quaternions given as scalars, as (w, x, y, z)."""
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


@njit(cache=True)
def right_jacobian_into(rx, ry, rz, out):
    """Right Jacobian of SO(3) at ``phi = (rx, ry, rz)`` [rad] into ``out`` (3, 3):
    ``Exp(phi + d) ~ Exp(phi) Exp(J_r d)``, ``J_r = I - c1 [phi]x + c2 [phi]x^2`` with ``c1 = (1 - cos a)/a^2``,
    ``c2 = (a - sin a)/a^3``, ``a = |phi|`` (``[phi]x^2 = phi phi^T - a^2 I``)."""
    angle2 = rx * rx + ry * ry + rz * rz
    angle = math.sqrt(angle2)
    if angle < 1e-4:
        c1 = 0.5 - angle2 / 24.0
        c2 = 1.0 / 6.0 - angle2 / 120.0
    else:
        c1 = (1.0 - math.cos(angle)) / angle2
        c2 = (angle - math.sin(angle)) / (angle2 * angle)
    out[0, 0] = 1.0 + c2 * (rx * rx - angle2)
    out[1, 1] = 1.0 + c2 * (ry * ry - angle2)
    out[2, 2] = 1.0 + c2 * (rz * rz - angle2)
    out[0, 1] = c1 * rz + c2 * rx * ry
    out[1, 0] = -c1 * rz + c2 * rx * ry
    out[0, 2] = -c1 * ry + c2 * rx * rz
    out[2, 0] = c1 * ry + c2 * rx * rz
    out[1, 2] = c1 * rx + c2 * ry * rz
    out[2, 1] = -c1 * rx + c2 * ry * rz


@njit(cache=True)
def matmul3_into(A, B, out):
    """out = A B for (3, 3) matrices (plain loops: no BLAS call overhead for 3 x 3)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def skew_into(vx, vy, vz, out):
    """[v]x into ``out`` (3, 3)."""
    out[0, 0] = 0.0
    out[0, 1] = -vz
    out[0, 2] = vy
    out[1, 0] = vz
    out[1, 1] = 0.0
    out[1, 2] = -vx
    out[2, 0] = -vy
    out[2, 1] = vx
    out[2, 2] = 0.0
