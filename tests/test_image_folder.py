"""Image folders with pose files (TUM, KITTI, CSV): pose-file parsing, stamps, pairing, and
``import_image_folder`` into a recording that ``Recording.samples`` reads back unchanged."""

from __future__ import annotations

import math
import re
from decimal import Decimal
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import one_error_line
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.app.importer import import_image_folder
from aslam.core.errors import InputError
from aslam.data_formats.image_folder import (
    START_STAMP_NS,
    SYNTHETIC_STEP_M,
    ImageFolderError,
    open_image_folder,
)
from aslam.data_formats.pose_files import (
    LAYOUTS,
    NANOSECOND_STAMP_MIN,
    PoseFileError,
    PoseFormat,
    detect_format,
    iter_poses,
    stamp_text_ns,
)
from aslam.data_formats.recording import Recording
from aslam.data_formats.ros_msgs import LAST_STAMP_NS

W, H = 16, 12


def write_images(folder: Path, n: int, name=lambda i: f"frame-{i:04d}.png", size=(W, H)) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        rng = np.random.default_rng(i)
        path = folder / name(i)
        image = rng.integers(0, 256, size=(size[1], size[0], 3), dtype=np.uint8)
        ok = cv2.imwrite(str(path), image, [cv2.IMWRITE_JPEG_QUALITY, 95] if path.suffix == ".jpg" else [])
        assert ok
        paths.append(path)
    return paths


def tum_line(t: float, pose: tuple[float, float, float], z: float = 0.0) -> str:
    x, y, yaw = pose
    return f"{t:.6f} {x!r} {y!r} {z!r} 0 0 {math.sin(yaw / 2)!r} {math.cos(yaw / 2)!r}"


def kitti_line(pose: tuple[float, float, float]) -> str:
    """The camera pose (x right, y down, z forward) of a robot at ``pose`` on the ground."""
    x, y, yaw = pose
    c, s = math.cos(-yaw), math.sin(-yaw)  # a rotation by yaw to the left is -yaw about camera y (down)
    rotation = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    matrix = np.hstack([rotation, np.array([[-y], [0.0], [x]])])
    return " ".join(repr(float(v)) for v in matrix.reshape(-1))


def csv_line(t: float, pose: tuple[float, float, float]) -> str:
    return f"{t!r},{pose[0]!r},{pose[1]!r},{pose[2]!r}"


def route(i: int) -> tuple[float, float, float]:
    return (0.5 * i, 0.1 * i * i, math.remainder(0.3 * i, 2 * math.pi))


poses = st.tuples(
    st.floats(-1e3, 1e3, allow_nan=False), st.floats(-1e3, 1e3, allow_nan=False), st.floats(-3.14, 3.14)
)


@settings(deadline=None)
@given(pose=poses, z=st.floats(-10, 10))
def test_tum_gives_x_y_and_yaw(tmp_path_factory, pose, z):
    path = tmp_path_factory.mktemp("tum") / "poses.txt"
    path.write_text(f"# timestamp tx ty tz qx qy qz qw\n{tum_line(12.5, pose, z)}\n")
    assert detect_format(path) is PoseFormat.TUM
    (row,) = iter_poses(path)
    assert row.line == 2 and row.stamp_ns == 12_500_000_000
    np.testing.assert_allclose(row.pose, pose, atol=1e-9)


@settings(deadline=None)
@given(pose=poses)
def test_kitti_camera_pose_becomes_the_ground_pose(tmp_path_factory, pose):
    path = tmp_path_factory.mktemp("kitti") / "00.txt"
    path.write_text(kitti_line(pose) + "\n")
    assert detect_format(path) is PoseFormat.KITTI
    (row,) = iter_poses(path)
    assert row.stamp_ns is None
    np.testing.assert_allclose(row.pose, pose, atol=1e-9)


@settings(deadline=None)
@given(pose=poses)
def test_csv_is_planar_already(tmp_path_factory, pose):
    path = tmp_path_factory.mktemp("csv") / "poses.csv"
    path.write_text("t,x,y,yaw\n" + csv_line(3.0, pose) + "\n")
    assert detect_format(path) is PoseFormat.CSV
    (row,) = iter_poses(path)
    assert row.stamp_ns == 3_000_000_000
    np.testing.assert_allclose(row.pose, pose, atol=1e-9)


def test_stamps_are_exact_decimals(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("1305031102.175304 0 0 0 0 0 0 1\n")
    assert next(iter_poses(path)).stamp_ns == 1305031102_175304000


@given(
    st.one_of(st.integers(0, LAST_STAMP_NS), st.sampled_from([0, NANOSECOND_STAMP_MIN, LAST_STAMP_NS])),
    st.text("0123456789", max_size=9),
)
def test_a_stamp_reads_to_the_nanosecond_however_it_is_written(stamp_ns, below):
    """Decimal seconds however written (all nine digits, fewer, trailing zeros, an exponent; digits
    below the nanosecond cut), or whole nanoseconds of 18 or more digits: the nanosecond exactly,
    and one nanosecond past the last ROS time is refused, as seconds or as nanoseconds."""
    seconds, fraction = divmod(stamp_ns, 10**9)
    exact = Decimal(stamp_ns).scaleb(-9)
    for text in (
        f"{seconds}.{fraction:09d}",
        f"{seconds}.{fraction:09d}".rstrip("0").rstrip("."),
        f"{seconds}.{fraction:09d}000",
        f"{exact:E}",
        str(exact.normalize()),
        f"{seconds}.{fraction:09d}{below}",
    ):
        assert stamp_text_ns(text) == stamp_ns, text
    if stamp_ns >= NANOSECOND_STAMP_MIN:
        assert stamp_text_ns(str(stamp_ns)) == stamp_ns
    if stamp_ns == LAST_STAMP_NS:
        for text in (f"{Decimal(stamp_ns + 1).scaleb(-9):f}", str(stamp_ns + 1)):
            with pytest.raises(ValueError, match="after 2038"):
                stamp_text_ns(text)


def test_whole_nanosecond_stamps_are_read_as_euroc_writes_them(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("1403636579763555584 0 0 0 0 0 0 1\n1403636579813555456 1 0 0 0 0 0 1\n")
    assert [row.stamp_ns for row in iter_poses(path)] == [1403636579763555584, 1403636579813555456]


def test_euroc_file_names_are_nanosecond_stamps(tmp_path):
    stamps = [1403636579763555584, 1403636579813555456, 1403636579863555584]
    for stamp in stamps:
        write_images(tmp_path / "data", 1, name=lambda _i, stamp=stamp: f"{stamp}.png")
    folder = open_image_folder(tmp_path / "data")
    assert folder.stamps == "file names" and [s.stamp_ns for s in folder.samples()] == stamps
    result = import_image_folder(tmp_path / "data", tmp_path / "euroc.mcap")
    assert result.frames == 3
    assert [s.stamp_ns for s in Recording(tmp_path / "euroc.mcap").samples()] == stamps


def test_millisecond_file_names_are_one_line_naming_the_file(tmp_path):
    write_images(tmp_path / "ms", 2, name=lambda i: f"{1403636579763 + 50 * i}.png")
    with pytest.raises(
        InputError, match=r"1403636579763\.png: file name: stamp '1403636579763' is after 2038"
    ):
        open_image_folder(tmp_path / "ms")


# --- the unit of the stamps -------------------------------------------------------------------------

NS_PER = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}


@settings(deadline=None)
@given(unit=st.sampled_from(["s", "ms", "us", "ns"]), value=st.integers(0, 2**31 - 1))
def test_a_stamp_unit_is_taken_at_its_word(unit, value):
    from aslam.data_formats.pose_files import stamp_text_ns

    assert stamp_text_ns(str(value), unit) == value * NS_PER[unit]


@settings(deadline=None)
@given(
    rate_hz=st.floats(0.21, 1000.0),
    start_s=st.one_of(st.just(0.0), st.floats(0.0, 2.0e9)),
    n=st.integers(2, 200),
)
def test_stamps_in_seconds_are_never_doubted(rate_hz, start_s, n):
    """TUM RGB-D's Unix seconds, relative seconds from 0: whatever the rate of a camera or odometry
    (a pose every 4.8 s up to 1 kHz), the default reading stands, with no word."""
    from aslam.data_formats.pose_files import spacing_doubt, stamp_text_ns

    stamps = [stamp_text_ns(f"{start_s + i / rate_hz:.6f}") for i in range(n)]
    assert spacing_doubt(stamps) is None


@settings(deadline=None)
@given(unit=st.sampled_from(["ms", "us", "ns"]), rate_hz=st.floats(1.0, 200.0), n=st.integers(3, 200))
def test_relative_stamps_of_another_unit_are_never_taken_for_seconds_in_silence(unit, rate_hz, n):
    """0, 33333333, 66666666 ns (or µs, ms) from a start are below 2³¹ and pass for seconds: their
    spacing gives them away, refused (ns, µs) or at least a warning (ms)."""
    from aslam.data_formats.pose_files import spacing_doubt, stamp_text_ns

    raw = [round(i * NS_PER["s"] / NS_PER[unit] / rate_hz) for i in range(n)]
    assert spacing_doubt([stamp_text_ns(str(v), unit) for v in raw]) is None
    try:
        as_seconds = [stamp_text_ns(str(v)) for v in raw]
    except ValueError as err:  # past 2038 as seconds: refused line by line, as before
        assert "give --stamp-unit ms, us or ns" in str(err)
        return
    doubt = spacing_doubt(as_seconds)
    assert doubt is not None and "give --stamp-unit ms, us or ns" in doubt.message
    assert doubt.refused == (unit != "ms")


def _relative_pose_file(path: Path, step: int, n: int) -> Path:
    path.write_text("\n".join(f"{i * step} {0.1 * i} 0 0 0 0 0 1" for i in range(n)) + "\n")
    return path


@pytest.mark.parametrize(("unit", "step"), [("ns", 33_333_333), ("us", 33_333)])
def test_relative_nanoseconds_or_microseconds_are_refused_unless_the_unit_is_given(
    tmp_path, capsys, unit, step
):
    """They were read as seconds: frames a year (ns) or 9 hours (µs) apart, exit 0."""
    from aslam.cli.app import main

    write_images(tmp_path / "imgs", 4)
    odometry = _relative_pose_file(tmp_path / "odom.txt", step, 4)
    out = tmp_path / "rec.mcap"
    assert main(["import", str(tmp_path / "imgs"), "-o", str(out), "--odometry", str(odometry)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{odometry}: stamps a median" in line and "give --stamp-unit ms, us or ns" in line
    assert not out.exists()
    args = [
        "import",
        str(tmp_path / "imgs"),
        "-o",
        str(out),
        "--odometry",
        str(odometry),
        "--stamp-unit",
        unit,
    ]
    assert main(args) == 0
    assert "warning" not in capsys.readouterr().err
    assert [s.stamp_ns for s in Recording(out).samples()] == [i * step * NS_PER[unit] for i in range(4)]
    assert Recording(out).metadata()["stamps"] == f"pose file odom.txt ({unit})"


def test_relative_milliseconds_get_a_warning_and_the_unit_reads_them(tmp_path, capsys):
    """0, 33, 66 ms as seconds are 33 s apart: possible, so a warning naming the file and the
    option; with ``--stamp-unit ms`` the frames are 33 ms apart."""
    from aslam.cli.app import main

    write_images(tmp_path / "imgs", 4)
    odometry = _relative_pose_file(tmp_path / "odom.txt", 33, 4)
    out = tmp_path / "rec.mcap"
    assert main(["import", str(tmp_path / "imgs"), "-o", str(out), "--odometry", str(odometry)]) == 0
    err = capsys.readouterr().err
    assert f"aslam: warning: {odometry}: stamps a median 33 s apart read as seconds" in err
    assert "--stamp-unit ms" in err
    args = ["import", str(tmp_path / "imgs"), "-o", str(out), "--odometry", str(odometry), "--force"]
    assert main([*args, "--stamp-unit", "ms"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert [s.stamp_ns for s in Recording(out).samples()] == [i * 33_000_000 for i in range(4)]


def test_the_stamp_unit_reads_file_names_too(tmp_path):
    """Microseconds since 1970 in the names (16 digits) are past 2038 as seconds: refused, or read."""
    stamps_us = [1403636579763555, 1403636579813555, 1403636579863555]
    for stamp in stamps_us:
        write_images(tmp_path / "us", 1, name=lambda _i, stamp=stamp: f"{stamp}.png")
    with pytest.raises(
        InputError, match=r"1403636579763555\.png: file name: .* give --stamp-unit ms, us or ns"
    ):
        open_image_folder(tmp_path / "us")
    folder = open_image_folder(tmp_path / "us", stamp_unit="us")
    assert folder.stamps == "file names (us)"
    assert [s.stamp_ns for s in folder.samples()] == [v * 1000 for v in stamps_us]


@pytest.mark.parametrize("unit", ["s", "ms", "us"])
def test_a_name_past_any_time_in_a_unit_is_one_line(tmp_path, unit):
    """1e999999.png with --stamp-unit: past 2038 in the unit, not an overflow of Decimal (exit 70)."""
    write_images(tmp_path / "huge", 2, name=lambda i: f"{i + 1}e999999.png")
    with pytest.raises(InputError, match=rf"1e999999\.png: file name: stamp '1e999999' {unit} is after 2038"):
        open_image_folder(tmp_path / "huge", stamp_unit=unit)


@pytest.mark.parametrize(
    ("text", "fmt", "needle"),
    [
        (
            "t,x,y,yaw\n1403636579763,0,0,0\n",
            None,
            "line 2: stamp '1403636579763' is after 2038 read as seconds",
        ),
        ("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", None, "line 2: 7 fields, a TUM line has 8"),
        ("1 0 0 0 0 0 0 1\n\n# c\n2 0 0 0 0 zero 0 1\n", None, "line 4: 'zero' is not a number"),
        ("2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", None, "line 2: stamp 1 s is before the previous line's"),
        ("1 0 0 0 0 0 0 1\n2 nan 0 0 0 0 0 1\n", None, "line 2: not finite"),
        ("1 0 0 0 0 0 0 0\n", None, "line 1: the quaternion is zero"),
        ("t,x,y,yaw\n0,0,0,0\n1,0,0\n", None, "line 3: 3 fields, a CSV line has 4"),
        ("1 2 3\n", None, "line 1: cannot tell the format from 3 fields"),
        ("# only a comment\n", None, "has no pose lines"),
        # a line of numbers and something else is a bad line, not a header (was "has no pose lines",
        # or the line skipped as a header and the import made without it)
        ("t,x,y,yaw\n1,a,b,c\n", None, "line 2: 'a' is not a number"),
        ("1,a,b,c\n2,1,0,0\n", None, "line 1: 'a' is not a number"),
        ("100.0,0,0,0,\n101.0,1,0,0,\n", None, "line 1: cannot tell the format from 5 fields"),
        ('"100.0","0","0","0"\n"101.0","1","0","0"\n', None, "line 2: '\"101.0\"' is not a number"),
        ("1 0 0 0 0 0 0 1\n", "kitti", "line 1: 8 fields, a KITTI line has 12"),
    ],
)
def test_a_malformed_pose_file_is_one_line_naming_file_and_line(tmp_path, text, fmt, needle):
    path = tmp_path / "poses.txt"
    path.write_text(text)
    with pytest.raises(PoseFileError) as caught:
        list(iter_poses(path, fmt))
    message = str(caught.value)
    assert isinstance(caught.value, InputError)
    assert message.startswith(f"{path}: ") and needle in message and "\n" not in message


# --- folders ------------------------------------------------------------------------------------


def gray(path: Path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def test_no_poses_synthetic_odometry_and_rate_stamps(tmp_path):
    paths = write_images(tmp_path / "imgs", 5)
    folder = open_image_folder(tmp_path / "imgs", rate_hz=4.0)
    assert not folder.odometry_known and folder.stamps == "rate 4 Hz"
    samples = list(folder.samples())
    assert [s.stamp_ns for s in samples] == [START_STAMP_NS + i * 250_000_000 for i in range(5)]
    for i, (sample, path) in enumerate(zip(samples, paths, strict=True)):
        np.testing.assert_array_equal(sample.odometry_pose, [i * SYNTHETIC_STEP_M, 0, 0])
        assert sample.ground_truth_pose is None
        assert sample.image.data == path.read_bytes()  # the file's bytes, untouched
        np.testing.assert_array_equal(sample.image.decode_gray(), gray(path))


def test_natural_order_and_stamps_from_file_names(tmp_path):
    names = ["2.5.png", "10.25.png", "3.png"]
    for name in names:
        write_images(tmp_path / "imgs", 1, name=lambda _i, name=name: name)
    folder = open_image_folder(tmp_path / "imgs")
    assert [p.name for p in folder.images] == ["2.5.png", "3.png", "10.25.png"]
    assert folder.stamps == "file names"
    assert [s.stamp_ns for s in folder.samples()] == [2_500_000_000, 3_000_000_000, 10_250_000_000]


def test_two_file_names_of_one_time_are_refused_not_stamped_at_one_hertz(tmp_path):
    """Names of one value (``1.0.png`` and ``1.00.png``) gave every frame the default 1 Hz stamps,
    all the names' times dropped without a word."""
    for name in ("1305031102.175304.png", "1305031102.1753040.png", "1305031102.275304.png"):
        write_images(tmp_path / "imgs", 1, name=lambda _i, name=name: name)
    with pytest.raises(ImageFolderError) as caught:
        open_image_folder(tmp_path / "imgs")
    assert str(caught.value) == (
        f"{tmp_path / 'imgs'}: file names 1305031102.175304.png and 1305031102.1753040.png are the same"
        " time (1305031102175304000 ns): rename one, or give --rate HZ to stamp the images in name order"
    )
    assert open_image_folder(tmp_path / "imgs", rate_hz=10.0).stamps == "rate 10 Hz"


def test_file_names_read_in_two_units_are_said_to_be_so_not_one_time(tmp_path):
    """Whole numbers of 10^17 or more are nanoseconds, smaller ones seconds: names of both kinds are
    in value order but not in time order, which is not "the same time"."""
    for name in ("1600000000.png", "1600000001.png", "1600000000500000000.png"):
        write_images(tmp_path / "imgs", 1, name=lambda _i, name=name: name)
    two_units = r"1600000001\.png and 1600000000500000000\.png read as times in two units"
    with pytest.raises(ImageFolderError, match=two_units):
        open_image_folder(tmp_path / "imgs")


# File names as datasets and people write them, from pieces: numbers (zero-padded too, other
# scripts' digits, a superscript ², which str.isdigit takes for a digit and int refuses),
# separators, letters, and any other characters.
name_text = st.lists(
    st.one_of(
        st.sampled_from(["0", "1", "01", "2", "10", "0.5", "²", "①", "٣", "a", "B", ".", "_", "-", " "]),
        st.text(st.characters(exclude_categories=("Cs",), exclude_characters="/\0"), min_size=1, max_size=3),
    ),
    min_size=1,
    max_size=5,
).map("".join)


@settings(max_examples=200)
@given(st.lists(name_text, min_size=1, max_size=8, unique=True))
def test_frames_take_one_order_whatever_the_folder_lists_first(names):
    """Any names (never an error), and one order from any listing order (here: reversed, which swaps
    every two): frame i is paired with pose row i, so an order that followed the listing (``a1.png``
    against ``a01.png``) would pair the frames differently from one disk to the next."""
    from aslam.data_formats.image_folder import frame_order

    twins = [re.sub(r"(\d+)", r"0\1", name, count=1) for name in names]  # "a1" → "a01": numbers alike
    images = [Path(f"{name}.png") for name in dict.fromkeys(names + twins)]
    ordered = frame_order(images)
    assert frame_order(images[::-1]) == ordered
    assert sorted(ordered) == sorted(images)


@given(
    st.lists(st.integers(0, 10**6), min_size=1, max_size=8, unique=True),
    st.sampled_from(["", "frame", "img_", "KITTI-00-"]),
    st.sampled_from(["", "_left", ".cam0"]),
    st.integers(0, 8),
)
def test_numbers_in_names_are_compared_as_numbers(numbers, prefix, suffix, padding):
    from aslam.data_formats.image_folder import frame_order

    images = [Path(f"{prefix}{n:0{padding}d}{suffix}.png") for n in numbers]
    assert frame_order(images[::-1]) == [images[numbers.index(n)] for n in sorted(numbers)]


def test_names_that_only_python_reads_as_numbers_are_names(tmp_path):
    """``1_0`` is no number to aslam (``Decimal`` alone reads it as 10): the folder is read in name
    order at the default rate, not refused because "stamp '1_0' is not a number"."""
    names = ["1_0.png", "2.png", "3.png"]
    write_images(tmp_path / "imgs", 3, name=lambda i: names[i])
    folder = open_image_folder(tmp_path / "imgs")
    assert folder.stamps == "default 1 Hz"
    assert [s.image.path.name for s in folder.samples()] == names


def test_default_stamps_without_anything(tmp_path):
    write_images(tmp_path / "imgs", 2, name=lambda i: f"img_{i}.jpg")
    folder = open_image_folder(tmp_path / "imgs")
    assert folder.stamps == "default 1 Hz"
    samples = list(folder.samples())
    assert [s.stamp_ns for s in samples] == [START_STAMP_NS, START_STAMP_NS + 1_000_000_000]
    assert {s.image.encoding for s in samples} == {"jpeg"}


@pytest.mark.parametrize("fmt", PoseFormat)
def test_one_pose_per_image_in_each_format(tmp_path, fmt):
    """Every format ``--format`` offers (a line of each written here) is detected and read."""
    assert fmt in LAYOUTS  # a PoseFormat without its layout was a KeyError, exit 70, on `--format`
    n = 6
    write_images(tmp_path / "imgs", n)
    stamps = [100.0 + 0.5 * i for i in range(n)]
    line = {
        "tum": lambda i: tum_line(stamps[i], route(i)),
        "kitti": lambda i: kitti_line(route(i)),
        "csv": lambda i: csv_line(stamps[i], route(i)),
    }[fmt]
    truth = tmp_path / "truth.txt"
    truth.write_text("\n".join(line(i) for i in range(n)) + "\n")
    assert detect_format(truth) == fmt
    folder = open_image_folder(tmp_path / "imgs", ground_truth=truth, rate_hz=2.0)
    samples = list(folder.samples())
    assert len(samples) == n
    if fmt == "kitti":
        assert folder.stamps == "rate 2 Hz"
    else:  # the file's stamps win over --rate
        assert folder.stamps == "pose file truth.txt"
        assert [s.stamp_ns for s in samples] == [round(t * 1e9) for t in stamps]
    for i, sample in enumerate(samples):
        np.testing.assert_allclose(sample.ground_truth_pose, route(i), atol=1e-9)
        np.testing.assert_array_equal(sample.odometry_pose, [i, 0, 0])


def test_a_stamp_unit_no_stamp_is_read_in_says_so(tmp_path):
    """KITTI poses (no stamps) and names that are no times: --stamp-unit changes nothing, and the
    user hears it rather than believing the frames were timed in that unit."""
    write_images(tmp_path / "imgs", 3)
    truth = tmp_path / "00.txt"
    truth.write_text("\n".join(kitti_line(route(i)) for i in range(3)) + "\n")
    warnings: list[str] = []
    folder = open_image_folder(tmp_path / "imgs", ground_truth=truth, stamp_unit="ms")
    assert len(list(folder.samples(on_warning=warnings.append))) == 3
    assert warnings == [
        f"{tmp_path / 'imgs'}: --stamp-unit ms is not used: no pose file has stamps (KITTI's have none)"
        " and the images are stamped by default 1 Hz"
    ]
    stamped = tmp_path / "gt.txt"  # a pose file in that unit: used, no word
    stamped.write_text("\n".join(tum_line(100 * i, route(i)) for i in range(3)) + "\n")
    folder = open_image_folder(tmp_path / "imgs", ground_truth=stamped, stamp_unit="ms")
    warnings.clear()
    assert [s.stamp_ns for s in folder.samples(on_warning=warnings.append)] == [0, 100_000_000, 200_000_000]
    assert warnings == []


def test_a_faster_pose_file_is_interpolated_to_the_images(tmp_path):
    """Ground truth at 10 Hz, images at 2 Hz from its first stamp: linear motion interpolates exactly."""
    write_images(tmp_path / "imgs", 4)
    truth = tmp_path / "gt.csv"
    truth.write_text(
        "\n".join(csv_line(50 + 0.1 * k, (0.3 * k, -0.2 * k, 0.01 * k)) for k in range(16)) + "\n"
    )
    odometry = tmp_path / "odom.txt"
    odometry.write_text("\n".join(tum_line(50 + 0.05 * k, (0.1 * k, 0.0, 0.0)) for k in range(40)) + "\n")
    warnings: list[str] = []
    folder = open_image_folder(tmp_path / "imgs", ground_truth=truth, odometry=odometry, rate_hz=2.0)
    assert folder.odometry_known
    samples = list(folder.samples(on_warning=warnings.append))
    assert [s.stamp_ns for s in samples] == [50_000_000_000 + i * 500_000_000 for i in range(4)]
    for i, sample in enumerate(samples):
        k = 5 * i  # 0.5 s is 5 ground-truth rows and 10 odometry rows
        np.testing.assert_allclose(sample.ground_truth_pose, (0.3 * k, -0.2 * k, 0.01 * k), atol=1e-9)
        np.testing.assert_allclose(sample.odometry_pose, (0.1 * 2 * k, 0, 0), atol=1e-9)
    assert warnings == []


def test_images_outside_the_odometry_span_are_dropped_with_a_warning(tmp_path):
    write_images(tmp_path / "imgs", 5)
    odometry = tmp_path / "odom.csv"
    odometry.write_text("\n".join(csv_line(10 + 0.5 * k, (k, 0, 0)) for k in range(4)) + "\n")  # 1.5 s
    folder = open_image_folder(tmp_path / "imgs", odometry=odometry, rate_hz=1.0)  # 4 s of images
    warnings: list[str] = []
    assert [s.stamp_ns for s in folder.samples(on_warning=warnings.append)] == [
        10_000_000_000,
        11_000_000_000,
    ]
    assert any("3 image(s) stamped after the last odometry message" in w for w in warnings)


def test_stamped_file_of_another_count_needs_image_stamps(tmp_path):
    write_images(tmp_path / "imgs", 3)
    truth = tmp_path / "gt.txt"
    truth.write_text("\n".join(tum_line(k, (k, 0, 0)) for k in range(5)) + "\n")
    with pytest.raises(PoseFileError, match=r"5 poses for 3 images .* give --rate HZ"):
        open_image_folder(tmp_path / "imgs", ground_truth=truth)


@pytest.mark.parametrize("start_s", [0.0, 1305031102.0])
def test_numbered_frames_and_a_pose_file_of_another_length_need_a_rate(tmp_path, capsys, start_s):
    """``0000.png`` … are frame numbers, not stamps: they were read as seconds since 1970, so frame
    i took the poses of second i (relative stamps), or none at all (Unix stamps), exit 0."""
    from aslam.cli.app import main

    write_images(tmp_path / "imgs", 4, name=lambda i: f"{i:04d}.png")
    truth = tmp_path / "gt.txt"
    truth.write_text("\n".join(tum_line(start_s + 0.05 * k, (0.05 * k, 0, 0)) for k in range(25)) + "\n")
    out = tmp_path / "rec.mcap"
    assert main(["import", str(tmp_path / "imgs"), "-o", str(out), "--ground-truth", str(truth)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{truth}: 25 poses for 4 images" in line and "their names are frame numbers" in line
    assert "give --rate HZ" in line and "--stamp-unit" in line
    assert not out.exists()
    args = ["import", str(tmp_path / "imgs"), "-o", str(out), "--ground-truth", str(truth), "--rate", "10"]
    assert main(args) == 0
    samples = list(Recording(out).samples())
    start_ns = round(start_s * 1e9)
    assert [s.stamp_ns for s in samples] == [start_ns + i * 100_000_000 for i in range(4)]
    for i, sample in enumerate(samples):  # 0.1 s is two rows of the truth
        np.testing.assert_allclose(sample.ground_truth_pose, (0.1 * i, 0, 0), atol=1e-9)


@settings(deadline=None, max_examples=25)
@given(numbers=st.sets(st.integers(0, 10**9 - 1), min_size=1, max_size=4), width=st.integers(1, 10))
def test_frame_numbers_are_never_stamps(tmp_path_factory, numbers, width):
    """Whole-number names below 10⁹, zero-padded or not (KITTI's six digits, KITTI raw's ten), order
    the frames and give no stamps; with a stamp unit they are stamps of that unit."""
    folder = tmp_path_factory.mktemp("numbered")
    for number in numbers:
        write_images(folder, 1, name=lambda _i, number=number: f"{number:0{width}d}.png")
    opened = open_image_folder(folder)
    assert opened.stamps == "default 1 Hz"
    assert [int(p.stem) for p in opened.images] == sorted(numbers)
    assert [s.stamp_ns for s in opened.samples()] == [START_STAMP_NS + i * 10**9 for i in range(len(numbers))]
    assert [s.stamp_ns for s in open_image_folder(folder, stamp_unit="ms").samples()] == [
        n * 10**6 for n in sorted(numbers)
    ]


def test_an_import_that_pairs_no_image_is_refused(tmp_path, capsys):
    """EuRoC's names and an odometry file on another clock: every image dropped, and a recording of
    no frames written, exit 0 (which ``estimate`` then refused: no image topic)."""
    from aslam.cli.app import main

    for stamp in (1403636579763555584, 1403636579813555456):
        write_images(tmp_path / "imgs", 1, name=lambda _i, stamp=stamp: f"{stamp}.png")
    odometry = tmp_path / "odom.txt"
    odometry.write_text("\n".join(tum_line(1305031102 + 0.05 * k, (0.05 * k, 0, 0)) for k in range(9)) + "\n")
    out = tmp_path / "rec.mcap"
    assert main(["import", str(tmp_path / "imgs"), "-o", str(out), "--odometry", str(odometry)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "dropped 2 image(s) stamped after the last odometry message" in err[0]
    assert err[1] == (
        f"aslam: error: {tmp_path / 'imgs'}: none of its 2 images is stamped within odom.txt (the images'"
        " stamps: file names); nothing to import"
    )
    assert not out.exists() and list(tmp_path.glob(".rec.mcap*")) == []


def test_kitti_odometry_times_stamp_the_frames(tmp_path, capsys, monkeypatch):
    """``sequences/00/times.txt`` beside ``image_0/``: the frames took 1 Hz (or a guessed --rate)."""
    from aslam.cli.app import main

    images = tmp_path / "sequences" / "00" / "image_0"
    write_images(images, 4, name=lambda i: f"{i:06d}.png")
    (images.parent / "times.txt").write_text("0.000000e+00\n1.036000e-01\n2.072000e-01\n3.108000e-01\n")
    truth = tmp_path / "poses" / "00.txt"
    truth.parent.mkdir()
    truth.write_text("\n".join(kitti_line(route(i)) for i in range(4)) + "\n")
    out = tmp_path / "rec.mcap"
    assert main(["import", str(images), "-o", str(out), "--ground-truth", str(truth), "-q"]) == 0
    assert capsys.readouterr().err == ""
    samples = list(Recording(out).samples())
    assert [s.stamp_ns for s in samples] == [0, 103_600_000, 207_200_000, 310_800_000]
    np.testing.assert_allclose(samples[3].ground_truth_pose, route(3), atol=1e-9)
    assert Recording(out).metadata()["stamps"] == "KITTI 00/times.txt"
    monkeypatch.chdir(images)  # the folder typed as "." is in 00/ all the same
    assert open_image_folder(Path(".")).stamps == "KITTI 00/times.txt"


def test_kitti_stamps_are_found_through_a_symlinked_image_folder(tmp_path):
    """``cam0 -> …/sequences/00/image_0``: the stamps beside the folder the link points to were not
    looked for, and the frames took 1 Hz in silence."""
    images = tmp_path / "sequences" / "00" / "image_0"
    write_images(images, 3, name=lambda i: f"{i:06d}.png")
    (images.parent / "times.txt").write_text("0.000000e+00\r\n1.036000e-01\r\n2.072000e-01\r\n\r\n")
    link = tmp_path / "cam0"
    link.symlink_to(images)
    for folder in (link, Path(f"{link}/")):
        opened = open_image_folder(folder)
        assert opened.stamps == "KITTI 00/times.txt" and opened.warnings == ()
        assert [s.stamp_ns for s in opened.samples()] == [0, 103_600_000, 207_200_000]


def test_kitti_raw_timestamps_stamp_the_frames_to_the_nanosecond(tmp_path):
    """``image_02/timestamps.txt`` beside ``image_02/data/``: dates and times, read as UTC."""
    images = tmp_path / "2011_09_26_drive_0001_sync" / "image_02" / "data"
    write_images(images, 3, name=lambda i: f"{i:010d}.png")
    (images.parent / "timestamps.txt").write_text(
        "2011-09-26 13:02:25.964389445\n2011-09-26 13:02:26.067389445\n2011-09-26 13:02:26.170\n"
    )
    folder = open_image_folder(images)
    assert folder.stamps == "KITTI image_02/timestamps.txt"
    start_ns = 1317042145_964389445  # date -u -d '2011-09-26 13:02:25.964389445' +%s%N
    assert [s.stamp_ns for s in folder.samples()] == [start_ns, start_ns + 103_000_000, 1317042146_170000000]


@pytest.mark.parametrize(
    ("name", "text", "problem"),
    [
        ("times.txt", "0\n0.1\n", "not used: 2 stamps for 3 images in {images}"),
        ("times.txt", "0\n0.1\n0.2\n0.3\n", "not used: 4 stamps for 3 images in {images}"),
        ("times.txt", "0\n0.1\nnan\n", "not used: line 3: stamp 'nan' is not a finite, non-negative time"),
        ("times.txt", "0\n0.2\n0.1\n", "not used: line 3: not after the line before"),
        ("timestamps.txt", "2011-09-26 13:02:25\n2011-09-31 13:02:26\nx\n", "not used: line 2: '2011-09-31"),
        ("timestamps.txt", "1\n2\n3\n", "not used: line 1: '1' is not a date and time"),
    ],
)
def test_a_kitti_stamp_file_that_cannot_stamp_the_images_says_so_and_is_not_used(
    tmp_path, name, text, problem
):
    images = tmp_path / "image_0"
    write_images(images, 3, name=lambda i: f"{i:06d}.png")
    (tmp_path / name).write_text(text)
    warnings: list[str] = []
    folder = open_image_folder(images)
    assert folder.stamps == "default 1 Hz" and len(list(folder.samples(on_warning=warnings.append))) == 3
    assert len(warnings) == 1 and warnings[0].startswith(
        f"{tmp_path / name}: {problem.format(images=images)}"
    )


def test_kitti_stamps_give_way_to_the_user_and_to_pose_files_and_two_are_ambiguous(tmp_path):
    images = tmp_path / "image_0"
    write_images(images, 3, name=lambda i: f"{i:06d}.png")
    (tmp_path / "times.txt").write_text("0\n0.1\n0.2\n")
    folder = open_image_folder(images, rate_hz=5.0)
    assert folder.stamps == "rate 5 Hz"
    assert folder.warnings == (f"{tmp_path / 'times.txt'}: not used: --rate 5 Hz gives the stamps",)
    truth = tmp_path / "gt.txt"  # one stamped row per image: its stamps, as before
    truth.write_text("\n".join(tum_line(7 + i, route(i)) for i in range(3)) + "\n")
    folder = open_image_folder(images, ground_truth=truth)
    assert folder.stamps == "pose file gt.txt" and folder.warnings == ()
    (tmp_path / "timestamps.txt").write_text(
        "2011-09-26 13:02:25\n2011-09-26 13:02:26\n2011-09-26 13:02:27\n"
    )
    folder = open_image_folder(images)
    assert folder.stamps == "default 1 Hz"
    both = f"{tmp_path / 'times.txt'} and {tmp_path / 'timestamps.txt'}"
    assert folder.warnings == (f"{both} are not used: which one stamps {images}?",)


def test_kitti_stamps_pair_the_frames_with_a_stamped_pose_file_of_another_count(tmp_path):
    """A TUM ground truth on the sequence's clock (times.txt's, made by evo from poses/00.txt, say)
    at twice the frame rate: interpolated to the frames, as with any stamps."""
    images = tmp_path / "image_0"
    write_images(images, 3, name=lambda i: f"{i:06d}.png")
    (tmp_path / "times.txt").write_text("0\n0.1\n0.2\n")
    truth = tmp_path / "gt.txt"
    truth.write_text("\n".join(tum_line(0.05 * k, (0.05 * k, 0, 0)) for k in range(5)) + "\n")
    samples = list(open_image_folder(images, ground_truth=truth).samples())
    assert [s.stamp_ns for s in samples] == [0, 100_000_000, 200_000_000]
    np.testing.assert_allclose([s.ground_truth_pose[0] for s in samples], [0, 0.1, 0.2], atol=1e-9)


@pytest.mark.parametrize(("rows", "line"), [(4, 4), (6, 6)])
def test_kitti_count_mismatch_names_file_and_line(tmp_path, rows, line):
    write_images(tmp_path / "imgs", 5)
    poses_file = tmp_path / "00.txt"
    poses_file.write_text("\n".join(kitti_line(route(i)) for i in range(rows)) + "\n")
    with pytest.raises(PoseFileError) as caught:
        open_image_folder(tmp_path / "imgs", odometry=poses_file)
    message = str(caught.value)
    assert message.startswith(f"{poses_file}: line {line}: {rows} poses for 5 images")
    assert "\n" not in message


def test_a_kitti_rotation_with_no_heading_is_refused(tmp_path):
    """A zero rotation matrix was read as a heading of 0, where a zero quaternion is refused."""
    poses_file = tmp_path / "00.txt"
    poses_file.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n0 0 0 1 0 0 0 0 0 0 0 2\n")
    with pytest.raises(PoseFileError, match=r"line 2: .*the rotation gives no heading"):
        list(iter_poses(poses_file, "kitti"))


def test_duplicate_stamps_in_a_per_image_file(tmp_path):
    write_images(tmp_path / "imgs", 3)
    truth = tmp_path / "gt.txt"
    truth.write_text("\n".join(tum_line(t, (0, 0, 0)) for t in (1, 2, 2)) + "\n")
    with pytest.raises(PoseFileError, match=r"gt.txt: line 3: the same stamp as the line before"):
        open_image_folder(tmp_path / "imgs", ground_truth=truth)


def test_folder_problems(tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        open_image_folder(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"has no \.png or \.jpg images"):
        open_image_folder(tmp_path / "empty")
    write_images(tmp_path / "imgs", 1)
    with pytest.raises(InputError, match="--rate must be a positive number"):
        open_image_folder(tmp_path / "imgs", rate_hz=0.0)


@pytest.mark.parametrize(
    ("option", "needle"),
    [
        (["--fov-deg", "nan"], "--fov-deg must be between 1 and 170 degrees, got nan"),
        (["--fov-deg", "180"], "--fov-deg must be between 1 and 170"),
        (["--fov-deg", "1e-300"], "--fov-deg must be between 1 and 170"),
        (["--fov-deg", "-5"], "--fov-deg must be between 1 and 170"),
        (["--rate", "1e-300"], "too slow: 3 images would run past 2038"),
    ],
)
def test_import_option_values_out_of_range_are_bad_input(tmp_path, capsys, option, needle):
    """Exit 2 and one line (they were exit 70: a camera model refusing the value, an overflow)."""
    from aslam.cli.app import main

    write_images(tmp_path / "imgs", 3)
    out = tmp_path / "x.mcap"
    assert main(["import", str(tmp_path / "imgs"), "-o", str(out), *option]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err
    assert not out.exists()


# --- import -------------------------------------------------------------------------------------


@pytest.mark.parametrize("pitch_deg", [0.0, 30.0])
def test_a_kitti_path_out_of_its_plane_is_said(tmp_path, pitch_deg):
    """KITTI's poses are in the first camera's axes; a camera pitched down on a level car puts the
    path out of that plane, and read as planar it was shortened, its turns bent, in silence."""
    pitch = math.radians(pitch_deg)
    c, s = math.cos(pitch), math.sin(pitch)
    tilt = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    lines = []
    for i in range(8):  # a level 2 × 2 m square, seen from the pitched camera's first axes
        level = np.array([float(v) for v in kitti_line(SQUARE[i % 4]).split()]).reshape(3, 4)
        lines.append(" ".join(repr(float(v)) for v in (tilt.T @ level).reshape(-1)))
    poses = tmp_path / "poses.txt"
    poses.write_text("\n".join(lines) + "\n")
    write_images(tmp_path / "imgs", 8)
    folder = open_image_folder(tmp_path / "imgs", odometry=poses)
    said = [w for w in folder.warnings if "read in the plane of the file's own axes" in w]
    if pitch_deg == 0:
        assert said == []
    else:
        assert len(said) == 1
        assert said[0].startswith(f"{poses}: its t_y (the camera's down axis) spans 1.00 m")


SQUARE = [(0.0, 0.0, 0.0), (2.0, 0.0, math.pi / 2), (2.0, 2.0, math.pi), (0.0, 2.0, -math.pi / 2)]


def test_import_writes_a_recording_read_back_unchanged(tmp_path, capsys):
    paths = write_images(tmp_path / "imgs", 7)
    truth = tmp_path / "truth.txt"
    truth.write_text("\n".join(kitti_line(route(i)) for i in range(7)) + "\n")
    progress: list[tuple[int, int]] = []
    out = tmp_path / "rec.mcap"
    result = import_image_folder(
        tmp_path / "imgs",
        out,
        ground_truth=truth,
        rate_hz=5.0,
        on_progress=lambda d, t: progress.append((d, t)),
    )
    assert (result.frames, result.images, result.width_px, result.height_px) == (7, 7, W, H)
    assert not result.odometry_known and result.ground_truth
    assert progress[-1] == (7, 7) and len(progress) == 7
    samples = list(Recording(out).samples())
    assert [s.stamp_ns for s in samples] == [START_STAMP_NS + i * 200_000_000 for i in range(7)]
    for i, (sample, path) in enumerate(zip(samples, paths, strict=True)):
        assert sample.image.data == path.read_bytes() and sample.image.encoding == "png"
        np.testing.assert_array_equal(sample.image.decode_gray(), gray(path))
        np.testing.assert_allclose(sample.odometry_pose, [i, 0, 0], atol=1e-12)
        np.testing.assert_allclose(sample.ground_truth_pose, route(i), atol=1e-9)
    metadata = Recording(out).metadata()
    assert metadata["odometry_known"] == "false" and metadata["odometry_step_m"] == "1"
    assert metadata["source"] == "image-folder" and metadata["stamps"] == "rate 5 Hz"
    # ``info`` says the path is assumed, not measured: the camera of an import without odometry
    # may never have moved.
    from aslam.cli.app import main

    assert main(["info", str(out)]) == 0
    assert "odometry path  6.00 m (assumed: equal steps, no odometry imported)" in capsys.readouterr().out
    # Same arguments, same bytes.
    again = tmp_path / "again.mcap"
    import_image_folder(tmp_path / "imgs", again, ground_truth=truth, rate_hz=5.0)
    assert again.read_bytes() == out.read_bytes()


def test_the_same_folder_spelled_another_way_gives_the_same_recording(tmp_path, monkeypatch):
    """The metadata names the folder and the pose files absolute, ``..`` folded (as an estimate
    names its recording): imported from another folder through ``../`` the bytes are the same.
    They were recorded as typed (``data/imgs`` against ``../data/imgs``), so they differed."""
    write_images(tmp_path / "data" / "imgs", 3)
    odometry = tmp_path / "data" / "odom.csv"
    odometry.write_text("\n".join(csv_line(1 + i, route(i)) for i in range(3)) + "\n")
    monkeypatch.chdir(tmp_path)
    import_image_folder(Path("data/imgs"), Path("a.mcap"), odometry=Path("data/odom.csv"))
    monkeypatch.chdir(tmp_path / "data")
    import_image_folder(Path("../data/./imgs/"), Path("../b.mcap"), odometry=Path("odom.csv"))
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    metadata = Recording(tmp_path / "a.mcap").metadata()
    assert metadata["folder"] == str(tmp_path / "data" / "imgs")
    assert metadata["odometry"] == f"{odometry} (csv, 3 poses)"


def test_import_with_odometry_says_it_is_known(tmp_path):
    write_images(tmp_path / "imgs", 3, name=lambda i: f"{i}.jpg")
    odometry = tmp_path / "odom.csv"
    odometry.write_text(
        "stamp_s,x_m,y_m,yaw_rad\n" + "\n".join(csv_line(1 + i, route(i)) for i in range(3)) + "\n"
    )
    out = tmp_path / "rec.mcap"
    result = import_image_folder(tmp_path / "imgs", out, odometry=odometry, fov_deg=90.0)
    assert result.odometry_known and result.stamps == "pose file odom.csv"
    metadata = Recording(out).metadata()
    assert metadata["odometry_known"] == "true" and "odometry_step_m" not in metadata
    samples = list(Recording(out).samples())
    assert [s.image.encoding for s in samples] == ["jpeg"] * 3
    np.testing.assert_allclose(samples[2].odometry_pose, route(2), atol=1e-12)


@pytest.mark.parametrize("damage", ["corrupt", "not-an-image", "other-size", "empty"])
def test_a_bad_image_fails_the_import_naming_the_file(tmp_path, damage):
    paths = write_images(tmp_path / "imgs", 4)
    bad = paths[2]
    if damage == "corrupt":
        data = bad.read_bytes()
        bad.write_bytes(data[:40] + bytes(len(data) - 40))
    elif damage == "not-an-image":
        bad.write_text("hello")
    elif damage == "empty":
        bad.write_bytes(b"")
    else:
        write_images(tmp_path / "imgs", 1, name=lambda _i: bad.name, size=(W + 2, H))
    out = tmp_path / "rec.mcap"
    with pytest.raises(InputError) as caught:
        import_image_folder(tmp_path / "imgs", out)
    message = str(caught.value)
    assert message.startswith(f"{bad}: ") and "\n" not in message
    assert not out.exists() and list(tmp_path.glob(".rec.mcap*")) == []


@pytest.mark.parametrize("frame", [0, 2])
def test_a_damaged_frame_is_named_by_its_file_alone(tmp_path, frame):
    """A frame's stamp may be made up (here the default 1 Hz), and the first frame, decoded for the
    recording's size before any stamp is known, was said to be 'at stamp 0 ns': the file names it."""
    paths = write_images(tmp_path / "imgs", 4)
    data = paths[frame].read_bytes()
    paths[frame].write_bytes(data[:-20])
    with pytest.raises(InputError) as caught:
        import_image_folder(tmp_path / "imgs", tmp_path / "rec.mcap")
    assert str(caught.value) == f"{paths[frame]}: corrupt PNG data ({len(data) - 20} bytes)"


def test_import_refuses_to_overwrite(tmp_path):
    write_images(tmp_path / "imgs", 1)
    out = tmp_path / "rec.mcap"
    out.write_text("keep me")
    with pytest.raises(InputError, match="already exists"):
        import_image_folder(tmp_path / "imgs", out)
    assert out.read_text() == "keep me"
    import_image_folder(tmp_path / "imgs", out, force=True)
    assert len(list(Recording(out).samples())) == 1


def test_hidden_files_are_not_frames_and_an_unreadable_or_unstorable_frame_is_refused(tmp_path):
    """A skipped frame would shift every later frame's pose: refused, not skipped; macOS's ``._``
    files are not frames at all."""
    write_images(tmp_path / "imgs", 3)
    (tmp_path / "imgs" / "._frame-0001.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    assert len(open_image_folder(tmp_path / "imgs")) == 3
    (tmp_path / "imgs" / "frame-0003.png").symlink_to(tmp_path / "unmounted" / "frame-0003.png")
    with pytest.raises(InputError, match=r"frame-0003\.png: cannot read: a broken symbolic link"):
        open_image_folder(tmp_path / "imgs")
    (tmp_path / "imgs" / "frame-0003.png").unlink()
    cv2.imwrite(str(tmp_path / "imgs" / "frame-0003.bmp"), np.zeros((H, W), np.uint8))
    with pytest.raises(InputError, match=r"frame-0003\.bmp: a \.bmp image among the frames"):
        open_image_folder(tmp_path / "imgs")


def test_of_several_frames_refused_the_first_by_name_is_named(tmp_path):
    """The error names the same frame on every file system (each lists a folder in its own order):
    a folder exported as BMP from frame 0 on is refused at frame 0."""
    for i in range(12):
        cv2.imwrite(str(tmp_path / f"{i}.bmp"), np.zeros((H, W), np.uint8))
    (tmp_path / "12.png").symlink_to(tmp_path / "unmounted" / "12.png")
    with pytest.raises(InputError) as caught:
        open_image_folder(tmp_path)
    assert str(caught.value).startswith(f"{tmp_path / '0.bmp'}: a .bmp image among the frames")


def test_frames_named_by_time_are_in_time_order_and_odd_entries_are_not_frames(tmp_path):
    """``str(t)`` names (0.05, 0.1, 0.15) sort by value, not as text; a folder named like an image
    is no frame; a pipe or a HEIC among the frames is refused by name."""
    import os

    for name in ("0.1.png", "0.05.png", "0.15.png", "1.png"):
        write_images(tmp_path / "t", 1, name=lambda _i, name=name: name)
    (tmp_path / "t" / "old.bmp").mkdir()
    folder = open_image_folder(tmp_path / "t")
    assert [p.name for p in folder.images] == ["0.05.png", "0.1.png", "0.15.png", "1.png"]
    assert folder.stamps == "file names"
    os.mkfifo(tmp_path / "t" / "2.png")
    with pytest.raises(InputError, match=r"2\.png: is not a regular file"):
        open_image_folder(tmp_path / "t")
    (tmp_path / "t" / "2.png").unlink()
    (tmp_path / "t" / "2.heic").write_bytes(b"\x00")
    with pytest.raises(InputError, match=r"2\.heic: a \.heic image among the frames"):
        open_image_folder(tmp_path / "t")


def test_import_never_overwrites_its_own_inputs_even_with_force(tmp_path):
    """As estimate, report and record refuse: the pose file or a frame under -o is a typo that
    would destroy the dataset."""
    paths = write_images(tmp_path / "imgs", 2)
    poses = tmp_path / "gt.txt"
    poses.write_text("1 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1\n")
    before = poses.read_bytes(), paths[0].read_bytes()
    for output in (poses, paths[0]):
        with pytest.raises(InputError, match="input"):
            import_image_folder(tmp_path / "imgs", output, ground_truth=poses, force=True)
    assert (poses.read_bytes(), paths[0].read_bytes()) == before
    link = tmp_path / "out.mcap"
    link.symlink_to(paths[1])  # another name, resolving to a frame
    with pytest.raises(InputError, match="input"):
        import_image_folder(tmp_path / "imgs", link, ground_truth=poses, force=True)
    assert paths[1].read_bytes().startswith(b"\x89PNG")
    beside = tmp_path / "imgs" / "rec.mcap"
    import_image_folder(tmp_path / "imgs", beside, ground_truth=poses)  # beside them: fine


def test_a_byte_order_mark_is_not_part_of_the_first_number(tmp_path: Path):
    path = tmp_path / "poses.txt"
    path.write_bytes("\ufeff0.5 1 2 0 0 0 0 1\n".encode())
    (row,) = iter_poses(path)
    assert row.stamp_ns == 500_000_000 and row.pose[0] == 1.0


def test_an_implausible_pose_is_refused_at_import(tmp_path: Path):
    """The recording reader would refuse it at `estimate`: the pose file names the line now."""
    path = tmp_path / "poses.txt"
    path.write_text("0 0 0 0 0 0 0 1\n1 1e300 0 0 0 0 0 1\n")
    with pytest.raises(PoseFileError, match=r"line 2: the pose is at x=1e\+300 m"):
        list(iter_poses(path))
    path.write_text("0 0 0 0 0 0 0 1\n1 50000 0 0 0 0 0 1\n")
    with pytest.raises(PoseFileError, match=r"line 2: the pose jumps 50000 m"):
        list(iter_poses(path))


@pytest.mark.parametrize("scale", [1.0, 1.1, 2.0, 0.5, 1e200, 1e-5])  # 1e200: its square overflows
def test_a_quaternion_not_of_unit_length_gives_its_rotation(scale: float):
    from aslam.data_formats.ros_msgs import yaw_of_quaternion

    half = math.radians(90.0) / 2
    yaw = yaw_of_quaternion(0.0, 0.0, scale * math.sin(half), scale * math.cos(half))
    assert yaw == pytest.approx(math.radians(90.0), abs=1e-12)
    with pytest.raises(ValueError, match="zero"):
        yaw_of_quaternion(0.0, 0.0, 0.0, 0.0)


#: Folder entries, and whether each is a frame: hidden names (macOS's ``._``), suffixes in any case,
#: ``.jfif``, a folder named like an image, a link to a frame and a name that only holds ``png``.
HOSTILE_ENTRIES = {
    "._0.png": False,
    ".hidden.png": False,
    "UPPER.PNG": True,
    "shout.JPG": True,
    "mixed.JpEg": True,
    "photo.jfif": True,
    "PHOTO.JFIF": True,
    "x.png": False,  # a folder
    "linked.png": True,  # a link to a frame elsewhere
    "notes.png.txt": False,
    "png": False,
}


def _hostile_entry(folder: Path, name: str) -> None:
    if name == "x.png":
        (folder / name).mkdir()
    elif name == "linked.png":
        write_images(folder.parent / f"{folder.name}-elsewhere", 1, name=lambda _i: "frame.png")
        (folder / name).symlink_to(folder.parent / f"{folder.name}-elsewhere" / "frame.png")
    else:
        (folder / name).write_bytes(b"\xff\xd8\xff")


@pytest.mark.parametrize(("name", "frame"), sorted(HOSTILE_ENTRIES.items()))
def test_estimate_tells_an_image_folder_by_the_frames_import_takes(tmp_path, name, frame):
    """Which entries of a folder are frames is one rule (``image_folder.is_frame``): the folder
    ``estimate`` and ``info`` tell to import (``holds_frames``) is one whose frames ``import`` lists
    (``list_images``), each odd name alone in its folder and all of them in one."""
    from aslam.data_formats.image_folder import holds_frames, list_images

    alone = tmp_path / "alone"
    alone.mkdir()
    _hostile_entry(alone, name)
    assert holds_frames(alone) is frame
    if frame:
        assert list_images(alone) == [alone / name]
    else:
        with pytest.raises(ImageFolderError, match=r"has no \.png or \.jpg images"):
            list_images(alone)


def test_the_frames_of_a_folder_of_odd_names_are_those_import_lists(tmp_path):
    from aslam.data_formats.image_folder import holds_frames, list_images

    folder = tmp_path / "all"
    folder.mkdir()
    for name in HOSTILE_ENTRIES:
        _hostile_entry(folder, name)
    assert holds_frames(folder)
    assert sorted(p.name for p in list_images(folder)) == sorted(
        n for n, frame in HOSTILE_ENTRIES.items() if frame
    )


@pytest.mark.parametrize("text", ["1_0", "\u0661", "0x10", "1e", "--1"])
def test_a_pose_file_number_is_written_as_numbers_are(tmp_path, text):
    """Python's float() took ``1_0`` as 10 and Arabic-Indic digits as digits."""
    path = tmp_path / "p.txt"
    path.write_text(f"0 0 0 0 0 0 0 1\n1 {text} 0 0 0 0 0 1\n", encoding="utf-8")
    with pytest.raises(PoseFileError, match=rf"line 2: '{re.escape(text)}' is not a number"):
        list(iter_poses(path, "tum"))
    with pytest.raises(ValueError, match="is not a number"):
        stamp_text_ns(text)
