"""The camera model recordings carry (``sensor_msgs/CameraInfo``), from a field of view."""

from __future__ import annotations

import math
from dataclasses import dataclass

DEFAULT_FOV_DEG = 60.0
"""The recorder's camera, and the field of view assumed for images whose dataset gives none."""


def fov_option_problem(fov_deg: float) -> str | None:
    """Why ``--fov-deg`` (``record``'s and ``import``'s) is refused, or None: 1–170 degrees, the
    lenses a pinhole model describes usefully."""
    if math.isfinite(fov_deg) and 1.0 <= fov_deg <= 170.0:
        return None
    return f"--fov-deg must be between 1 and 170 degrees, got {fov_deg}"


@dataclass(frozen=True)
class CameraIntrinsics:
    """A pinhole camera with square pixels, centred principal point and no distortion.

    ``fov_deg`` is the horizontal field of view. Pixel centres are at integer coordinates
    (OpenCV and ROS convention), so the principal point is ``((width - 1) / 2, (height - 1) / 2)``.
    """

    width_px: int
    height_px: int
    fov_deg: float

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"camera size must be positive, got {self.width_px}x{self.height_px}")
        if not 0.0 < self.fov_deg < 180.0:
            raise ValueError(f"horizontal field of view must be in (0, 180) degrees, got {self.fov_deg}")

    @property
    def fx(self) -> float:
        return (self.width_px / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width_px - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height_px - 1) / 2.0

    @property
    def K(self) -> tuple[float, ...]:
        """Row-major 3×3 camera matrix, as in ``sensor_msgs/CameraInfo.k``."""
        return (self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)

    @classmethod
    def from_camera_info(cls, width_px: int, height_px: int, fx: float) -> CameraIntrinsics:
        """The intrinsics whose horizontal field of view gives focal length ``fx``."""
        return cls(width_px, height_px, math.degrees(2.0 * math.atan((width_px / 2.0) / fx)))
