"""Geometry of the 7-photocell sun device (seed 003).

The device is a frustum: cell 1 on the top face (outward normal straight up; device z points down, so
n1 = (0, 0, -1)), cells 2..7 on the six side faces at device azimuths 0, 60, ..., 300 deg, each side face
tilted ``tilt_deg`` from the bottom plane: n_i = (sin a cos az_i, sin a sin az_i, -cos a). The device frame is
mounted on the body by the rotation ``mount_rpy_deg`` (device -> body FRD, ZYX Euler, identity by default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ingest.frames import euler_to_matrix

N_CELLS = 7
#: Largest magnitude accepted for an azimuth or mounting angle [deg]; beyond a turn it is a typo, not geometry.
MAX_ANGLE_DEG = 360.0
#: Smallest singular value the 7 unit normals must reach [-]: below it the cells do not see all three axes and
#: no sun vector can be solved (e.g. all side cells at one azimuth).
MIN_NORMALS_SINGULAR_VALUE = 1e-3


@dataclass(frozen=True)
class SunDevice:
    """Photocell sun-device geometry.

    Attributes
    ----------
    tilt_deg : float
        Tilt of the six side faces from the bottom plane [deg] (alpha in seed 003).
    azimuths_deg : tuple of 6 float
        Device azimuths of the side cells 2..7 [deg], measured from device x towards device y.
    mount_rpy_deg : tuple of 3 float
        Device-to-body mounting rotation as ZYX Euler angles (roll, pitch, yaw) [deg].

    Raises
    ------
    ValueError
        Not 6 azimuths or 3 mounting angles, ``tilt_deg`` outside (0, 90) deg, an azimuth or mounting angle
        non-finite or beyond +-360 deg, or cell normals that do not span 3-D space (no sun vector could be
        solved).
    """

    tilt_deg: float = 45.0
    azimuths_deg: tuple[float, ...] = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if len(self.azimuths_deg) != N_CELLS - 1:
            raise ValueError(f"azimuths_deg must list {N_CELLS - 1} side-cell azimuths, "
                             f"got {len(self.azimuths_deg)}")
        if not 0.0 < self.tilt_deg < 90.0:
            raise ValueError(f"tilt_deg must be in (0, 90) deg, got {self.tilt_deg}")
        if len(self.mount_rpy_deg) != 3:
            raise ValueError(f"mount_rpy_deg must have 3 angles, got {len(self.mount_rpy_deg)}")
        for key in ("azimuths_deg", "mount_rpy_deg"):
            angles_deg = np.asarray(getattr(self, key), dtype=float)
            if not np.all(np.abs(angles_deg) <= MAX_ANGLE_DEG):  # also refuses NaN
                raise ValueError(f"{key} must be finite angles within +-{MAX_ANGLE_DEG:g} deg, "
                                 f"got {list(getattr(self, key))}")
        if np.linalg.svd(self.normals_device, compute_uv=False)[-1] < MIN_NORMALS_SINGULAR_VALUE:
            raise ValueError("the cell normals do not span 3-D space (side-cell azimuths too close together or "
                             f"opposite), got azimuths_deg {list(self.azimuths_deg)}")

    @property
    def normals_device(self) -> np.ndarray:
        """Outward unit normals of the 7 cells in the device frame, shape (7, 3)."""
        tilt = np.radians(self.tilt_deg)
        az = np.radians(np.asarray(self.azimuths_deg))
        side = np.column_stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az),
                                np.full(az.shape, -np.cos(tilt))])
        return np.vstack([[0.0, 0.0, -1.0], side])

    @property
    def body_from_device(self) -> np.ndarray:
        """Rotation matrix mapping device-frame vectors into body FRD, shape (3, 3)."""
        return euler_to_matrix(*np.radians(self.mount_rpy_deg))

    @property
    def normals_body(self) -> np.ndarray:
        """Outward unit normals of the 7 cells in body FRD, shape (7, 3)."""
        return self.normals_device @ self.body_from_device.T
