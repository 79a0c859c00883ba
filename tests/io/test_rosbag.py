"""ROS1 and ROS2 bags written with ``rosbags`` read back exactly: images of every encoding read, compressed images,
IMU samples, and one-line refusals."""

from __future__ import annotations

import numpy as np
import pytest
from _rosbags import content, write_bag

from ccs_kornia.io.rosbag import bag_topics, read_bag_images, read_bag_imu
from ccs_kornia.runtime.errors import UserError

KINDS = [("ros1", "rec.bag"), ("ros2 sqlite3", "rec"), ("ros2 mcap", "rec")]


@pytest.fixture(scope="module", params=KINDS, ids=[k for k, _ in KINDS])
def bag(request, tmp_path_factory):
    kind, name = request.param
    truth = content()
    path = write_bag(tmp_path_factory.mktemp(kind.replace(" ", "_")) / name, truth, ros1=kind == "ros1",
                     storage=kind.split()[-1])
    return path, truth


def test_topics_and_their_types(bag):
    path, truth = bag
    topics = bag_topics(path)
    assert topics["/imu0"] == "sensor_msgs/msg/Imu"
    assert topics["/cam/mono8"] == "sensor_msgs/msg/Image" and topics["/cam/jpeg"] == "sensor_msgs/msg/CompressedImage"
    assert set(topics) == {*truth.images, "/imu0"}


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8", "rgb8", "bgra8", "rgba8", "png16", "jpeg"])
def test_images_read_back_exactly(bag, encoding):
    path, truth = bag
    got = list(read_bag_images(path, f"/cam/{encoding}"))
    expected = truth.images[f"/cam/{encoding}"]
    assert len(got) == len(expected)
    for (t, image), (sec, nsec, true) in zip(got, expected):
        assert t == sec + nsec * 1e-9  # the header's stamp, not the time the bag recorded it
        assert image.dtype == true.dtype and image.shape == true.shape
        assert np.array_equal(image, true)


def test_imu_reads_back_exactly(bag):
    path, truth = bag
    t, gyro, accel = read_bag_imu(path, "/imu0")
    assert t.dtype == gyro.dtype == accel.dtype == np.float64
    assert t.shape == (20,) and gyro.shape == accel.shape == (20, 3)
    assert t.tolist() == [sec + nsec * 1e-9 for sec, nsec, _, _ in truth.imu]
    assert np.array_equal(gyro, np.array([g for _, _, g, _ in truth.imu]))
    assert np.array_equal(accel, np.array([a for _, _, _, a in truth.imu]))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_ros2_storage_file_reads_alone(tmp_path, storage):
    truth = content(frames=2, samples=3)
    path = write_bag(tmp_path / "rec", truth, ros1=False, storage=storage)
    file = next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
    assert [t for t, _ in read_bag_images(file, "/cam/mono8")] == [s + n * 1e-9 for s, n, _ in
                                                                   truth.images["/cam/mono8"]]


def test_a_missing_topic_lists_the_bags_topics(bag):
    path, _ = bag
    with pytest.raises(UserError) as err:
        list(read_bag_images(path, "/cam0/image_raw"))
    message = str(err.value)
    assert message.startswith(f"--bag {path}: no topic /cam0/image_raw; the bag has: /cam/bgr8 (sensor_msgs/Image)")
    assert "/imu0 (sensor_msgs/Imu)" in message and "\n" not in message
    with pytest.raises(UserError, match="topic /imu0 holds sensor_msgs/Imu messages, not sensor_msgs/Image or "
                                        "sensor_msgs/CompressedImage"):
        next(read_bag_images(path, "/imu0"))
    with pytest.raises(UserError, match="topic /cam/mono8 holds sensor_msgs/Image messages, not sensor_msgs/Imu"):
        read_bag_imu(path, "/cam/mono8")


def test_what_is_no_bag_is_one_line(tmp_path):
    with pytest.raises(UserError, match="no such file or folder"):
        bag_topics(tmp_path / "none.bag")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="a folder without metadata.yaml is no ROS2 bag"):
        bag_topics(tmp_path / "empty")
    broken = tmp_path / "broken.bag"
    broken.write_bytes(b"#ROSBAG V2.0\nnot really")
    with pytest.raises(UserError, match=r"broken.bag: not a readable ROS bag \("):
        bag_topics(broken)
    with pytest.raises(UserError, match="not a ROS bag"):
        bag_topics(__file__)
