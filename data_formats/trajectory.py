"""Trajectory files that evo and every other SLAM tool read: TUM and KITTI.

* TUM: one line per pose, ``stamp_s x y z qx qy qz qw`` (seconds, metres, unit quaternion).
* KITTI: one line per pose, the first three rows of the 4×4 pose matrix, row-major; no stamps;
  the camera's pose in KITTI's camera axes (x right, y down, z forward), as KITTI's own files.

Both are written by evo's own ``evo.tools.file_interface`` writers, so the files are evo's format
by construction, under a temporary name renamed when complete. Poses are SE(2) ``(x_m, y_m,
yaw_rad)``; in TUM in the z = 0 plane (REP 103: x forward, y left, z up). They are read back by
the one reader of pose files, ``data_formats.pose_files`` (what ``aslam import`` reads). TUM keeps
seconds as float64, so stamps come back to within a microsecond, not to the nanosecond. No zero
is written negative (``-0.000e+00``).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from aslam.core import se2
from aslam.data_formats import files
from aslam.data_formats.errors import TrajectoryError
from aslam.data_formats.format_names import TrajectoryFormat


class TrajectoryPaths(NamedTuple):
    """Where one export puts its three trajectories."""

    optimised: Path
    odometry: Path
    truth: Path


#: File names that say their format; any other name is written as the format asked for (TUM by default).
SUFFIX_FORMATS = {".tum": TrajectoryFormat.TUM, ".kitti": TrajectoryFormat.KITTI}


def export_plan(path: Path | str, fmt: TrajectoryFormat | None) -> tuple[TrajectoryPaths, TrajectoryFormat]:
    """Where an export of three trajectories goes, and in which format: the one asked for, else the
    one the name says (``.tum``, ``.kitti``), else TUM. Refused before any work: a stream or ``-``
    (three files cannot share one), no file name, and a name that says another format than the one
    asked for (evo would then misread every row). ``path`` as typed: ``out/`` names a folder."""
    given = str(path)
    path = Path(path)
    if str(path) == "-" or files.is_stream_output(path):
        raise TrajectoryError(
            "a trajectory export writes three files (NAME, NAME.odometry…, NAME.truth…): "
            "give a file name, not stdout or a stream",
            path=path,
        )
    if path.name in ("", ".", "..") or given.endswith(("/", os.sep)) or path.is_dir():
        raise TrajectoryError(f"--trajectory needs a file name, not a folder ({given!r})")
    named = SUFFIX_FORMATS.get(path.suffix.lower())
    if fmt is not None and named is not None and fmt is not named:
        raise TrajectoryError(f"the name says {named}, --trajectory-format says {fmt}", path=path)
    return sibling_paths(path), fmt or named or TrajectoryFormat.TUM


def sibling_paths(path: Path) -> TrajectoryPaths:
    """``OUT.tum`` → ``OUT.tum``, ``OUT.odometry.tum``, ``OUT.truth.tum`` (the same for any suffix)."""
    path = Path(path)
    return TrajectoryPaths(
        path,
        path.with_name(f"{path.stem}.odometry{path.suffix}"),
        path.with_name(f"{path.stem}.truth{path.suffix}"),
    )


def evo_trajectory(poses: np.ndarray, stamps_ns: Sequence[int] | np.ndarray | None = None) -> Any:
    """SE(2) poses (n, 3) as evo's ``PoseTrajectory3D`` (with stamps) or ``PosePath3D``, z = 0."""
    from evo.core.trajectory import PosePath3D, PoseTrajectory3D

    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    n = len(poses)
    xyz = np.zeros((n, 3))
    xyz[:, :2] = poses[:, :2]
    quat_wxyz = np.array([se2.yaw_quaternion(yaw) for yaw in poses[:, 2]]).reshape(n, 4)
    if stamps_ns is None:
        return PosePath3D(positions_xyz=xyz, orientations_quat_wxyz=quat_wxyz)
    stamps_s = np.asarray(stamps_ns, dtype=np.int64) / 1e9
    return PoseTrajectory3D(positions_xyz=xyz, orientations_quat_wxyz=quat_wxyz, timestamps=stamps_s)


def _checked_poses(poses: np.ndarray, path: Path) -> np.ndarray:
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise TrajectoryError(f"poses must have shape (n, 3), got {poses.shape}", path=path)
    if not np.isfinite(poses).all():
        raise TrajectoryError("poses contain NaN or infinity (unknown poses cannot be exported)", path=path)
    return poses


def write_trajectory(
    path: Path,
    poses: np.ndarray,
    stamps_ns: Sequence[int] | np.ndarray | None = None,
    fmt: TrajectoryFormat = TrajectoryFormat.TUM,
    *,
    force: bool = True,
) -> None:
    """Write SE(2) ``poses`` (n, 3) as TUM (needs ``stamps_ns``) or KITTI, atomically."""
    from evo.tools import file_interface

    path = Path(path)
    fmt = TrajectoryFormat(fmt)
    files.check_output_path(path, force=force, error=TrajectoryError)
    poses = _checked_poses(poses, path)
    if fmt is TrajectoryFormat.TUM:
        if stamps_ns is None or len(stamps_ns) != len(poses):
            got = "no" if stamps_ns is None else len(stamps_ns)
            raise TrajectoryError(
                f"TUM needs one stamp per pose: {len(poses)} poses, {got} stamps", path=path
            )
        built = evo_trajectory(poses, stamps_ns)
        trajectory = type(built)(  # + 0.0: no -0.0 in the file (see kitti_camera_path)
            positions_xyz=built.positions_xyz + 0.0,
            orientations_quat_wxyz=built.orientations_quat_wxyz + 0.0,
            timestamps=built.timestamps,
        )
        files.write_atomically(
            path, lambda tmp: file_interface.write_tum_trajectory_file(tmp, trajectory), error=TrajectoryError
        )
    else:
        trajectory = kitti_camera_path(poses)
        files.write_atomically(
            path, lambda tmp: file_interface.write_kitti_poses_file(tmp, trajectory), error=TrajectoryError
        )


def kitti_camera_path(poses: np.ndarray) -> Any:
    """SE(2) poses as KITTI writes its own: the camera's pose (x right, y down, z forward) in the
    first camera's frame, so an export compares with a KITTI ground truth and ``aslam import`` reads
    it back (``data_formats.pose_files``: forward ``z`` → ``x_m``, left ``−x`` → ``y_m``)."""
    from evo.core.trajectory import PosePath3D

    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    matrices = np.zeros((len(poses), 4, 4))
    matrices[:, 0, 0], matrices[:, 0, 2], matrices[:, 0, 3] = c, -s, -poses[:, 1]
    matrices[:, 1, 1] = 1.0
    matrices[:, 2, 0], matrices[:, 2, 2], matrices[:, 2, 3] = s, c, poses[:, 0]
    matrices[:, 3, 3] = 1.0
    # x + 0.0 is x, and 0.0 for -0.0: a y of 0 or a heading of 0 wrote "-0.000e+00" (−t_x, −sin),
    # a sign no pose has, which makes files of runs that agree differ.
    return PosePath3D(poses_se3=list(matrices + 0.0))
