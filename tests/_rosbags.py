"""Small ROS1 and ROS2 bags written with ``rosbags``' writers for the tests: images of every encoding read, compressed
images and IMU samples, each message stamped."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from rosbags.typesys import Stores, get_typestore

__all__ = ["BagContent", "content", "write_bag", "write_frames_bag"]

#: the recording's start, as a sensor clock gives it (s since the epoch)
T0 = 1_403_636_579


class BagContent:
    """What a test bag holds: per image topic its ``(sec, nanosec, image as read back)``, and the IMU samples."""

    def __init__(self, images: dict[str, list[tuple[int, int, np.ndarray]]], imu: list[tuple[int, int, tuple, tuple]]):
        self.images = images
        self.imu = imu


def content(frames: int = 3, samples: int = 20, size: tuple[int, int] = (40, 30)) -> BagContent:
    """Images of each encoding (grey, 16-bit, colour in each channel order, compressed JPEG and 16-bit PNG) and IMU
    samples with distinct values."""
    rng = np.random.default_rng(0)
    w, h = size
    images: dict[str, list[tuple[int, int, np.ndarray]]] = {}
    for encoding in ("mono8", "mono16", "bgr8", "rgb8", "bgra8", "rgba8", "png16", "jpeg"):
        rows = []
        for k in range(frames):
            sec, nsec = T0 + k // 10, (k % 10) * 100_000_000 + 1234
            if encoding in ("mono16", "png16"):
                image = rng.integers(0, 65536, (h, w), dtype=np.uint16)
            elif encoding in ("mono8", "jpeg"):
                image = rng.integers(0, 256, (h, w), dtype=np.uint8)
            else:
                image = rng.integers(0, 256, (h, w, 4 if "a" in encoding[3:] else 3), dtype=np.uint8)
            rows.append((sec, nsec, image))
        images[f"/cam/{encoding}"] = rows
    imu = [(T0, 5_000_000 * k + 7, tuple(rng.normal(size=3)), tuple(rng.normal(size=3) + (0, 0, 9.81)))
           for k in range(samples)]
    return BagContent(images, imu)


def _header(store, ros1: bool, sec: int, nsec: int):
    stamp = store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    header = store.types["std_msgs/msg/Header"]
    return header(seq=0, stamp=stamp, frame_id="cam") if ros1 else header(stamp=stamp, frame_id="cam")


def _image_message(store, ros1: bool, topic: str, sec: int, nsec: int, image: np.ndarray):
    """The message of ``image`` as its topic's encoding stores it (``image`` being what the reader gives back: BGR)."""
    header = _header(store, ros1, sec, nsec)
    encoding = topic.rsplit("/", 1)[-1]
    if encoding in ("jpeg", "png16"):
        ok, data = cv2.imencode(".png", image)  # lossless, so the image reads back exactly (a PNG in a "jpeg" topic
        assert ok                               # too: the format field is a hint, the bytes are decoded)
        return store.types["sensor_msgs/msg/CompressedImage"](header=header, format=encoding,
                                                              data=np.frombuffer(data.tobytes(), np.uint8)), \
            "sensor_msgs/msg/CompressedImage"
    stored = image
    if encoding == "rgb8":
        stored = image[..., ::-1]
    elif encoding == "rgba8":
        stored = image[..., [2, 1, 0, 3]]
    big = encoding == "mono16"  # a big-endian 16-bit image, with a padded row
    raw = stored.astype(">u2") if big else stored
    h, w = image.shape[:2]
    row = np.ascontiguousarray(raw).view(np.uint8).reshape(h, -1)
    pad = 4 if big else 0
    data = np.concatenate([row, np.zeros((h, pad), np.uint8)], 1).reshape(-1)
    msg = store.types["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding=encoding,
                                               is_bigendian=int(big), step=row.shape[1] + pad, data=data)
    return msg, "sensor_msgs/msg/Image"


def _imu_message(store, ros1: bool, sec: int, nsec: int, gyro: tuple, accel: tuple):
    vector = store.types["geometry_msgs/msg/Vector3"]
    quaternion = store.types["geometry_msgs/msg/Quaternion"]
    return store.types["sensor_msgs/msg/Imu"](
        header=_header(store, ros1, sec, nsec), orientation=quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.zeros(9), angular_velocity=vector(x=gyro[0], y=gyro[1], z=gyro[2]),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=vector(x=accel[0], y=accel[1], z=accel[2]),
        linear_acceleration_covariance=np.zeros(9))


def write_frames_bag(path: Path, topics: dict[str, tuple[np.ndarray, list[float]]], ros1: bool = True) -> Path:
    """Grey ``uint8`` frames :math:`(V, H, W)` per image topic as ``mono8`` images stamped at their times (s, added
    to :data:`T0`), written as a ROS1 ``.bag`` or a ROS2 bag folder."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    messages = []
    for topic, (frames, times) in topics.items():
        for frame, t in zip(frames, times):
            ns = T0 * 10**9 + round(t * 1e9)
            header = _header(store, ros1, ns // 10**9, ns % 10**9)
            h, w = frame.shape
            msg = store.types["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding="mono8",
                                                       is_bigendian=0, step=w, data=frame.reshape(-1).copy())
            messages.append((ns + 2 * 10**6, topic, msg))
    messages.sort(key=lambda m: m[0])
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import Writer
        writer = Writer(path, version=9)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    kind = "sensor_msgs/msg/Image"
    with writer:
        connections = {}
        for recorded, topic, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=store)
            writer.write(connections[topic], recorded, serialize(msg, kind))
    return path


def write_bag(path: Path, bag: BagContent, ros1: bool, storage: str = "sqlite3") -> Path:
    """Write ``bag`` as a ROS1 ``.bag`` (``path`` ends in .bag) or a ROS2 bag folder (``storage``: sqlite3 or mcap);
    messages are recorded 1 ms after their stamps."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    messages = []
    for topic, rows in bag.images.items():
        for sec, nsec, image in rows:
            msg, kind = _image_message(store, ros1, topic, sec, nsec, image)
            messages.append((sec * 10**9 + nsec + 10**6, topic, kind, msg))
    for sec, nsec, gyro, accel in bag.imu:
        messages.append((sec * 10**9 + nsec + 10**6, "/imu0", "sensor_msgs/msg/Imu",
                         _imu_message(store, ros1, sec, nsec, gyro, accel)))
    messages.sort(key=lambda m: m[0])
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if storage == "mcap"
                        else StoragePlugin.SQLITE3)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        connections = {}
        for recorded, topic, kind, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=store)
            writer.write(connections[topic], recorded, serialize(msg, kind))
    return path
