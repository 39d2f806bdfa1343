"""TUM and KITTI trajectory files: round trips, atomic writes, bad input, and evo's own console tools."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from aslam.app.metric_view import EmbedOptions, embed, score_trajectory
from aslam.core import se2
from aslam.data_formats.pose_files import PoseFormat, iter_poses
from aslam.data_formats.ros_msgs import LAST_STAMP_NS
from aslam.data_formats.trajectory import (
    TrajectoryError,
    TrajectoryFormat,
    sibling_paths,
    write_trajectory,
)

STAMP0_NS = 1_600_000_000_123_456_789


def random_walk(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0.5, 1.5, n), rng.normal(0, 0.1, n), rng.normal(0, 0.4, n)])
    poses = [np.zeros(3)]
    for step in steps[1:]:
        poses.append(se2.compose(poses[-1], step))
    return np.array(poses), STAMP0_NS + np.arange(n, dtype=np.int64) * 250_000_000


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read back as ``aslam import`` reads a pose file."""
    rows = list(iter_poses(path, PoseFormat.TUM))
    return np.array([r.stamp_ns for r in rows], dtype=np.int64), np.array([r.pose for r in rows])


def read_kitti(path: Path) -> np.ndarray:
    return np.array([r.pose for r in iter_poses(path, PoseFormat.KITTI)])


def same_poses(a: np.ndarray, b: np.ndarray, atol: float = 1e-9) -> None:
    np.testing.assert_allclose(a[:, :2], b[:, :2], atol=atol)
    np.testing.assert_allclose(se2.wrap_angle(a[:, 2] - b[:, 2]), 0.0, atol=atol)


def test_tum_round_trip(tmp_path: Path):
    poses, stamps = random_walk(50, seed=1)
    path = tmp_path / "est.tum"
    write_trajectory(path, poses, stamps)
    lines = path.read_text().splitlines()
    assert len(lines) == 50 and all(len(line.split()) == 8 for line in lines)  # stamp x y z qx qy qz qw
    read_stamps, read_poses = read_tum(path)
    same_poses(read_poses, poses)
    assert np.abs(read_stamps - stamps).max() < 1_000  # seconds as float64: within a microsecond


def test_kitti_round_trip(tmp_path: Path):
    poses, _ = random_walk(30, seed=2)
    path = tmp_path / "est.kitti"
    write_trajectory(path, poses, fmt=TrajectoryFormat.KITTI)
    rows = np.loadtxt(path)
    assert rows.shape == (30, 12)  # 3×4 row-major
    # KITTI's camera axes (x right, y down, z forward): forward is +z, left is −x, yaw about −y
    np.testing.assert_allclose(rows[:, 11], poses[:, 0])
    np.testing.assert_allclose(rows[:, 3], -poses[:, 1])
    np.testing.assert_allclose(rows[:, 7], 0.0)
    np.testing.assert_allclose(rows[:, 0], np.cos(poses[:, 2]))
    same_poses(read_kitti(path), poses)  # what aslam import reads of a KITTI poses file


@settings(max_examples=30, deadline=None)
@given(
    arrays(
        np.float64,
        st.tuples(st.integers(1, 20), st.just(3)),
        elements=st.floats(
            -3e3, 3e3, allow_nan=False, allow_infinity=False
        ),  # jumps under the 10 km the reader takes
    )
)
def test_any_planar_trajectory_survives_both_formats(poses: np.ndarray):
    import tempfile

    poses = poses.copy()
    poses[:, 2] = se2.wrap_angle(poses[:, 2] / 1e3)
    stamps = np.arange(len(poses), dtype=np.int64) * 1_000_000_000
    with tempfile.TemporaryDirectory() as folder:
        tum, kitti = Path(folder) / "a.tum", Path(folder) / "a.kitti"
        write_trajectory(tum, poses, stamps)
        write_trajectory(kitti, poses, fmt="kitti")
        same_poses(read_tum(tum)[1], poses, atol=1e-6)
        same_poses(read_kitti(kitti), poses, atol=1e-6)


def negative_zeros(values: np.ndarray) -> int:
    return int(np.count_nonzero((values == 0) & np.signbit(values)))


@settings(max_examples=40, deadline=None)
@given(
    arrays(
        np.float64,
        st.tuples(st.integers(1, 8), st.just(3)),
        elements=st.one_of(st.sampled_from([0.0, -0.0, -5e-324, 5e-324, -1e-310]), st.floats(-3e3, 3e3)),
    )
)
def test_no_negative_zero_is_written(poses: np.ndarray):
    """A y or a heading of 0 (or −0.0, or a heading whose half underflows to −0.0) wrote
    ``-0.000000000000000000e+00`` in KITTI files (−t_x, −sin) and TUM files (the quaternion's z)."""
    import tempfile

    stamps = np.arange(len(poses), dtype=np.int64) * 1_000_000_000
    with tempfile.TemporaryDirectory() as folder:
        tum, kitti = Path(folder) / "a.tum", Path(folder) / "a.kitti"
        write_trajectory(tum, poses, stamps)
        write_trajectory(kitti, poses, fmt="kitti")
        assert negative_zeros(np.loadtxt(tum, ndmin=2)) == 0
        assert negative_zeros(np.loadtxt(kitti, ndmin=2)) == 0
        same_poses(read_tum(tum)[1], poses, atol=1e-6)


# The last stamp that survives: float64 seconds near 2³¹ s are 238 ns apart, so a stamp in the last
# few hundred ns a ROS time holds is written as 2147483648.0 s, after 2038, and refused when read.
LAST_ROUND_TRIP_NS = LAST_STAMP_NS - 1_000


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.one_of(st.integers(0, LAST_ROUND_TRIP_NS), st.sampled_from([0, 10**17, LAST_ROUND_TRIP_NS])),
        min_size=1,
        max_size=12,
        unique=True,
    ).map(sorted)
)
def test_tum_stamps_come_back_within_a_microsecond_and_in_order(stamps):
    """Any increasing stamps a ROS time holds: written as evo writes TUM (float64 seconds), read as
    ``aslam import`` reads it, each within a microsecond, and never going backwards (which the
    reader would refuse)."""
    import tempfile

    poses = np.zeros((len(stamps), 3))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "a.tum"
        write_trajectory(path, poses, np.array(stamps, dtype=np.int64))
        read_stamps, _ = read_tum(path)
    assert np.all(np.abs(read_stamps - np.array(stamps, dtype=np.int64)) < 1_000)
    assert np.all(np.diff(read_stamps) >= 0)


def test_same_input_same_bytes(tmp_path: Path):
    poses, stamps = random_walk(20, seed=3)
    write_trajectory(tmp_path / "a.tum", poses, stamps)
    write_trajectory(tmp_path / "b.tum", poses, stamps)
    assert (tmp_path / "a.tum").read_bytes() == (tmp_path / "b.tum").read_bytes()


def test_writes_are_atomic_and_checked(tmp_path: Path):
    poses, stamps = random_walk(10, seed=4)
    path = tmp_path / "est.tum"
    path.write_text("keep\n")
    with pytest.raises(TrajectoryError, match="already exists"):
        write_trajectory(path, poses, stamps, force=False)
    assert path.read_text() == "keep\n"
    with pytest.raises(TrajectoryError, match="one stamp per pose"):
        write_trajectory(tmp_path / "x.tum", poses, stamps[:-1])
    with pytest.raises(TrajectoryError, match="NaN"):
        write_trajectory(tmp_path / "x.tum", poses * np.nan, stamps)
    with pytest.raises(TrajectoryError, match="does not exist"):
        write_trajectory(tmp_path / "missing" / "x.tum", poses, stamps)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est.tum"]  # no partial files


def test_sibling_paths():
    paths = sibling_paths(Path("out/run.tum"))
    assert paths == (Path("out/run.tum"), Path("out/run.odometry.tum"), Path("out/run.truth.tum"))


# --- evo's own console tools read our files and agree with our scores ---------------------------


def evo(tool: str, *args: str, home: Path) -> str:
    """Run an evo console script from this environment (HOME isolated: evo writes ~/.evo/settings)."""
    executable = Path(sys.executable).parent / tool
    env = {**os.environ, "HOME": str(home), "MPLBACKEND": "Agg"}
    done = subprocess.run([str(executable), *args], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout


def statistic(output: str, name: str) -> float:
    match = re.search(rf"^\s*{name}\s+([-+0-9.eE]+)\s*$", output, re.MULTILINE)
    assert match, output
    return float(match.group(1))


def test_evo_ape_and_rpe_on_exported_files_agree_with_our_scores(tmp_path: Path):
    truth, stamps = random_walk(60, seed=5)
    rng = np.random.default_rng(5)
    # An estimate: the truth seen from elsewhere (alignment has work to do) plus noise and drift.
    estimate = se2.compose(np.array([2.0, -1.0, 0.7]), truth)
    estimate[:, :2] += rng.normal(0, 0.05, (60, 2)) + np.linspace(0, 0.8, 60)[:, None]
    ours = score_trajectory(estimate, truth, stamps)
    write_trajectory(tmp_path / "truth.tum", truth, stamps)
    write_trajectory(tmp_path / "est.tum", estimate, stamps)
    ape = evo("evo_ape", "tum", str(tmp_path / "truth.tum"), str(tmp_path / "est.tum"), "-a", home=tmp_path)
    assert "Umeyama" in ape
    assert statistic(ape, "rmse") == pytest.approx(ours.ape_m.rmse, abs=2e-6)
    assert statistic(ape, "max") == pytest.approx(ours.ape_m.max, abs=2e-6)
    rpe = evo("evo_rpe", "tum", str(tmp_path / "truth.tum"), str(tmp_path / "est.tum"), home=tmp_path)
    assert statistic(rpe, "rmse") == pytest.approx(ours.rpe_m.rmse, abs=2e-6)
    assert ours.ape_m.rmse > 0.1  # a test that can fail: the estimate is not the truth


def test_evo_ape_scores_an_exported_embedding(tmp_path: Path):
    truth, stamps = random_walk(40, seed=6)
    actions = np.vstack([np.zeros(3), se2.between(truth[:-1], truth[1:]) * [1.03, 1.0, 1.02]])
    embedding = embed(actions, np.arange(40), EmbedOptions())
    ours = score_trajectory(embedding.poses, truth, stamps)
    paths = sibling_paths(tmp_path / "run.tum")
    write_trajectory(paths.optimised, embedding.poses, stamps)
    write_trajectory(paths.truth, truth, stamps)
    ape = evo("evo_ape", "tum", str(paths.truth), str(paths.optimised), "-a", home=tmp_path)
    assert statistic(ape, "rmse") == pytest.approx(ours.ape_m.rmse, abs=2e-6)


def test_export_writes_three_files_evo_can_pair(tmp_path: Path):
    from aslam.app.metric_view import export_trajectories

    truth, stamps = random_walk(30, seed=7)
    actions = np.vstack([np.zeros(3), se2.between(truth[:-1], truth[1:]) * [1.02, 1.0, 1.0]])
    embedding = embed(actions, np.arange(30), EmbedOptions())
    partial = truth.copy()
    partial[[0, 10]] = np.nan  # keyframes without truth are left out of the TUM truth file
    written = export_trajectories(tmp_path / "run.tum", embedding, stamps, partial)
    assert sorted(p.name for p in written.values()) == ["run.odometry.tum", "run.truth.tum", "run.tum"]
    assert len(read_tum(written["truth"])[0]) == 28
    same_poses(read_tum(written["odometry"])[1], embedding.odometry)
    ape = evo("evo_ape", "tum", str(written["truth"]), str(written["optimised"]), "-a", home=tmp_path)
    ours = score_trajectory(embedding.poses, partial, stamps)
    assert statistic(ape, "rmse") == pytest.approx(ours.ape_m.rmse, abs=2e-6)
    with pytest.raises(TrajectoryError, match="already exists"):
        export_trajectories(tmp_path / "run.tum", embedding, stamps, partial)
    said: list[str] = []
    kitti = export_trajectories(tmp_path / "run.kitti", embedding, stamps, partial, on_warning=said.append)
    assert set(kitti) == {"optimised", "odometry"}  # no stamps: a partial truth cannot be paired
    assert len(said) == 1 and "run.truth.kitti: not written: 2 of 30 keyframes" in said[0]
    assert len(kitti["optimised"].read_text().split("\n")[0].split()) == 12  # the name chose KITTI


@pytest.mark.parametrize(
    ("name", "fmt", "problem"),
    [
        ("-", None, "give a file name, not stdout"),
        ("/dev/null", None, "give a file name, not stdout or a stream"),
        ("", None, "--trajectory needs a file name"),
        ("newdir/", None, "--trajectory needs a file name, not a folder ('newdir/')"),
        ("run.kitti", "tum", "the name says kitti, --trajectory-format says tum"),
    ],
)
def test_an_export_that_cannot_be_three_files_is_refused_before_any_work(name, fmt, problem):
    from aslam.data_formats.trajectory import export_plan

    with pytest.raises(TrajectoryError, match=re.escape(problem)):
        export_plan(name, None if fmt is None else TrajectoryFormat(fmt))  # as typed


def test_an_export_takes_its_format_from_the_option_then_the_name():
    from aslam.data_formats.trajectory import export_plan

    assert export_plan(Path("a.KITTI"), None)[1] is TrajectoryFormat.KITTI
    assert export_plan(Path("a.txt"), None)[1] is TrajectoryFormat.TUM
    assert export_plan(Path("a.txt"), TrajectoryFormat.KITTI)[1] is TrajectoryFormat.KITTI
