"""ROS 2 bags in and out: a shared log written as a ROS 2 bag by rosbags (scans, odometry as
``nav_msgs/Odometry`` or as ``/tf``, the laser mount on ``/tf_static``) reads back as the
log it came from and maps like its CARMEN twin; the trajectory goes out as a
``nav_msgs/Path`` bag beside the TUM file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chizu.numeric.errors import InvalidInput
from chizu.numeric.slam.logs import (
    read_log,
    read_ros2_path,
    read_tum,
    write_ros2_bag,
    write_ros2_path,
)
from tests.conftest import ROOT

CLIP = ROOT / "examples" / "aces-clip.clf"


@pytest.fixture(scope="module")
def clip():  # type: ignore[no-untyped-def]
    return read_log(CLIP)


@pytest.mark.parametrize("odometry", ["topic", "tf"])
def test_a_ros2_bag_reads_back_as_its_log(clip, tmp_path: Path,  # type: ignore[no-untyped-def]
                                          odometry: str) -> None:
    bag = tmp_path / "clip"
    write_ros2_bag(bag, clip, odometry=odometry)  # type: ignore[arg-type]
    assert (bag / "metadata.yaml").exists() and list(bag.glob("*.mcap"))
    back = read_log(bag)
    assert len(back) == len(clip)
    for a, b in zip(clip.scans, back.scans, strict=True):
        assert abs(a.t - b.t) < 1e-6
        np.testing.assert_allclose(b.odom, a.odom, atol=1e-6)
        np.testing.assert_allclose(b.angles, a.angles, atol=1e-6)
        np.testing.assert_allclose(b.ranges, a.ranges, atol=1e-5)  # float32 on the wire
        np.testing.assert_allclose(b.sensor_pose, a.sensor_pose, atol=1e-6)
        assert b.max_range_m == pytest.approx(a.max_range_m)


def test_a_bag_without_odometry_is_refused_naming_it(clip, tmp_path: Path  # type: ignore[no-untyped-def]
                                                     ) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    s = clip.scans[0]
    scan = T["sensor_msgs/msg/LaserScan"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=1, nanosec=0), frame_id="laser"),
        angle_min=float(s.angles[0]), angle_max=float(s.angles[-1]),
        angle_increment=float(s.angles[1] - s.angles[0]), time_increment=0.0, scan_time=0.0,
        range_min=0.0, range_max=40.0, ranges=s.ranges.astype(np.float32),
        intensities=np.zeros(0, np.float32))
    bag = tmp_path / "scans-only"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        w.write(c, 10**9, ts.serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))
    with pytest.raises(InvalidInput) as e:
        read_log(bag)
    assert e.value.field == "odom_topic"
    with pytest.raises(InvalidInput):
        write_ros2_bag(bag, clip)  # a bag is written to a new directory only


def test_the_path_bag_round_trips(tmp_path: Path) -> None:
    t = np.array([10.0, 10.5, 11.25])
    p = np.array([[0.0, 0.0, 0.0], [1.0, -2.0, 3.0], [-4.5, 0.25, -1.5]])
    write_ros2_path(tmp_path / "traj", t, p)
    t2, p2 = read_ros2_path(tmp_path / "traj")
    np.testing.assert_allclose(t2, t, atol=1e-9)
    np.testing.assert_allclose(p2, p, atol=1e-9)


def test_a_ros2_bag_maps_like_its_carmen_twin(clip, tmp_path: Path  # type: ignore[no-untyped-def]
                                              ) -> None:
    """`chizu slam` on the CARMEN clip and on its ROS 2 twin: the same relation error,
    and the trajectory written as a ROS 2 path too, equal to the TUM file."""
    bag = tmp_path / "clip-ros2"
    write_ros2_bag(bag, clip, odometry="tf")  # type: ignore[arg-type]
    env = {**os.environ, "CHIZU_DATA_DIR": str(tmp_path / "data")}
    errors = []
    for name, log in (("carmen", CLIP), ("ros2", bag)):
        out = tmp_path / name
        r = subprocess.run([sys.executable, "-m", "chizu.service.cli", "slam", str(log),
                            "--out", str(out)], env=env, capture_output=True, text=True,
                           timeout=600, cwd=ROOT)
        assert r.returncode == 0, r.stdout + r.stderr
        t_tum, p_tum = read_tum(out / "trajectory.tum")
        t_bag, p_bag = read_ros2_path(out / "trajectory-ros2")
        np.testing.assert_allclose(t_bag, t_tum, atol=1e-6)
        np.testing.assert_allclose(p_bag, p_tum, atol=1e-5)  # TUM prints 6 decimals
        r = subprocess.run([sys.executable, "-m", "chizu.service.cli", "slam-eval",
                            str(out / "trajectory.tum"), str(CLIP.with_suffix(".relations"))],
                           env={**env, "COLUMNS": "120"}, capture_output=True, text=True,
                           timeout=120, cwd=ROOT)
        assert r.returncode == 0, r.stdout + r.stderr
        line = next(ln for ln in r.stdout.splitlines() if "abs trans (m)" in ln)
        errors.append(float(line.split("│")[2]))
    assert errors[0] < 0.05
    assert errors[1] == pytest.approx(errors[0], abs=0.002), errors
