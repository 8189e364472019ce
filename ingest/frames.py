"""Frame and attitude conversions shared by every layer (NED earth, FRD body, Hamilton w-x-y-z quaternions).

All functions are vectorised over a leading axis. Euler angles are ZYX (yaw psi, pitch theta, roll phi) with
R_nb = Rz(psi) Ry(theta) Rx(phi) mapping body vectors into NED.
"""

from __future__ import annotations

import numpy as np


def euler_to_matrix(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """R_nb for ZYX Euler angles [rad]; shape (..., 3, 3) (body -> NED)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    rows = [
        [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
        [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
        [-sp, sr * cp, cr * cp],
    ]
    matrix = np.array([[np.asarray(v, dtype=float) for v in row] for row in rows])
    return np.moveaxis(matrix, (0, 1), (-2, -1))


def quat_to_matrix(q) -> np.ndarray:
    """R_nb from unit quaternions (w, x, y, z), shape (..., 4) -> (..., 3, 3)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def matrix_to_euler(r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (roll, pitch, yaw) [rad] from R_nb, shape (..., 3, 3); yaw in (-pi, pi]."""
    r = np.asarray(r, dtype=float)
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = -np.arcsin(np.clip(r[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return roll, pitch, yaw


def quat_to_euler(q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (roll, pitch, yaw) [rad] from quaternions (w, x, y, z), shape (..., 4)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def euler_to_quat(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """Quaternions (w, x, y, z) for ZYX Euler angles [rad], shape (..., 4), with w >= 0."""
    cr, sr = np.cos(np.asarray(roll_rad) / 2), np.sin(np.asarray(roll_rad) / 2)
    cp, sp = np.cos(np.asarray(pitch_rad) / 2), np.sin(np.asarray(pitch_rad) / 2)
    cy, sy = np.cos(np.asarray(yaw_rad) / 2), np.sin(np.asarray(yaw_rad) / 2)
    q = np.stack([cr * cp * cy + sr * sp * sy,
                  sr * cp * cy - cr * sp * sy,
                  cr * sp * cy + sr * cp * sy,
                  cr * cp * sy - sr * sp * cy], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)


def wrap_angle_rad(angle_rad):
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2 * np.pi) - np.pi


def wrap_angle_deg(angle_deg):
    """Wrap angles to [-180, 180)."""
    return (np.asarray(angle_deg) + 180.0) % 360.0 - 180.0
