"""ROS bags in at the boundary of the library: a recording's images and IMU samples, read without a ROS install.

ROS1 bags (``.bag``) and ROS2 bags (a folder holding ``metadata.yaml``, or one ``.db3`` / ``.mcap`` storage file) are
read with the pure-Python ``rosbags`` package. Decisions recorded here:

* a message's **time** is its header's stamp in seconds (the sensor's clock, what a camera-IMU calibration needs); a
  message whose stamp is zero (a driver that leaves it unset) gets the time the bag recorded it instead;
* ``sensor_msgs/Image`` is read for the encodings ``mono8``, ``mono16``, ``bgr8``, ``rgb8``, ``bgra8``, ``rgba8`` (and
  OpenCV's names of them, ``8UC1``, ``16UC1``, ``8UC3``, ``8UC4``); colour images come out in OpenCV's channel order
  (BGR, BGRA), 16-bit ones as ``uint16``; ``sensor_msgs/CompressedImage`` is decoded by OpenCV (JPEG, PNG, 16-bit PNG
  included);
* a topic the bag does not have, or one of another message type, is refused in one line that lists the topics the
  bag has (:class:`~ccs_kornia.runtime.errors.UserError`);
* messages come in the order the bag recorded them; their stamps are given as they are (a check that they increase
  belongs to the caller);
* an image topic is a recording wherever a video is one (:class:`BagTopicReader`, the interface of
  :class:`~ccs_kornia.io.video.VideoReader`; :mod:`~ccs_kornia.io.recordings` opens either): its path is ``BAG#TOPIC`` (:func:`bag_topic_path`), so its frames are
  named ``BAG#TOPIC#INDEX`` (``INDEX`` the message's position on the topic, from 0) with their header stamps as
  timestamps; the frames go to the detector as 8-bit grey images (colour converted, 16-bit scaled by 1/257), as a
  video's do.
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ccs_kornia.io.video import FrameSpan, VideoFrame, VideoInfo, scaled_frame
from ccs_kornia.runtime.errors import UserError

__all__ = ["IMAGE_ENCODINGS", "IMAGE_TYPES", "IMU_TYPES", "BagTopicReader", "bag_topic_path", "bag_topics",
           "grey8", "open_bag_topic", "read_bag_images", "read_bag_imu", "split_bag_topic"]

#: the ``sensor_msgs/Image`` encodings read, and the channels and bytes per channel of each
IMAGE_ENCODINGS: dict[str, tuple[int, int]] = {
    "mono8": (1, 1), "8uc1": (1, 1), "mono16": (1, 2), "16uc1": (1, 2), "bgr8": (3, 1), "8uc3": (3, 1),
    "rgb8": (3, 1), "bgra8": (4, 1), "8uc4": (4, 1), "rgba8": (4, 1),
}

#: message types of images (``rosbags`` names ROS1's types as ROS2's, ``pkg/msg/Name``)
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
#: message types of IMU samples
IMU_TYPES = ("sensor_msgs/msg/Imu",)


@contextlib.contextmanager
def _opened(path: str | Path) -> Iterator[Any]:
    """The bag open for reading (``rosbags``' ``AnyReader``); a one-line :class:`UserError` where it cannot be."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:  # pragma: no cover - a dependency of the package
        raise UserError("reading ROS bags needs the rosbags package (pip install rosbags)") from None
    bag = Path(path)
    if not bag.exists():
        raise UserError(f"--bag {path}: no such file or folder")
    ros1 = bag.suffix == ".bag"
    if not ros1 and bag.is_dir() and not (bag / "metadata.yaml").is_file():
        raise UserError(f"--bag {path}: a folder without metadata.yaml is no ROS2 bag (a ROS1 bag is one .bag file)")
    if not ros1 and bag.is_file() and bag.suffix not in (".db3", ".mcap"):
        raise UserError(f"--bag {path}: not a ROS bag (a ROS1 .bag file, or a ROS2 bag: its folder, .db3 or .mcap)")
    # ROS2 storage files need not hold their message definitions: the standard ones are known
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([bag], default_typestore=store)
        reader.open()
    except Exception as err:  # noqa: BLE001 - rosbags' reader errors, a damaged file: said in one line
        detail = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise UserError(f"--bag {path}: not a readable ROS bag ({detail})") from None
    try:
        yield reader
    finally:
        reader.close()


def _short(msgtype: str) -> str:
    """``sensor_msgs/Image`` for ``sensor_msgs/msg/Image``."""
    return msgtype.replace("/msg/", "/")


def _listing(reader: Any) -> str:
    topics = sorted(reader.topics.items())
    return ", ".join(f"{name} ({_short(info.msgtype)})" for name, info in topics) or "none"


def _connections(reader: Any, path: str | Path, topic: str, types: tuple[str, ...]) -> list[Any]:
    """The bag's connections of ``topic``, refused in one line where it has none or they hold another type."""
    found = [c for c in reader.connections if c.topic == topic]
    if not found:
        raise UserError(f"--bag {path}: no topic {topic}; the bag has: {_listing(reader)}")
    other = [c.msgtype for c in found if c.msgtype not in types]
    if other:
        wanted = " or ".join(_short(t) for t in types)
        raise UserError(f"--bag {path}: topic {topic} holds {_short(other[0])} messages, not {wanted}; the bag has: "
                        f"{_listing(reader)}")
    return found


def _stamp(msg: Any, recorded_ns: int) -> float:
    """The header's stamp in seconds (the recording time where the stamp is zero)."""
    stamp = msg.header.stamp
    sec, nsec = int(stamp.sec), int(stamp.nanosec)
    if sec == 0 and nsec == 0:
        return recorded_ns * 1e-9
    return sec + nsec * 1e-9


def _raw_image(msg: Any, topic: str) -> np.ndarray:
    """A ``sensor_msgs/Image`` as an array: grey :math:`(H, W)`, colour :math:`(H, W, 3|4)` in BGR(A) order."""
    encoding = str(msg.encoding).lower()
    if encoding not in IMAGE_ENCODINGS:
        raise UserError(f"topic {topic}: images of encoding {msg.encoding!r} are not read (it reads "
                        f"{', '.join(e for e in IMAGE_ENCODINGS if not e[0].isdigit())})")
    channels, depth = IMAGE_ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * channels * depth or data.size < h * step:
        raise UserError(f"topic {topic}: an image of {w}x{h} {msg.encoding} holds {data.size} bytes (step {step})")
    rows = data[: h * step].reshape(h, step)[:, : w * channels * depth]
    if depth == 2:
        image = np.ascontiguousarray(rows).view(">u2" if msg.is_bigendian else "<u2").astype(np.uint16)
    else:
        image = rows.copy()  # the image's own memory, not a view of the message's
    image = image.reshape(h, w, channels) if channels > 1 else image.reshape(h, w)
    if encoding == "rgb8":
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    elif encoding == "rgba8":
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA)
    return image


def _compressed_image(msg: Any) -> np.ndarray | None:
    """A ``sensor_msgs/CompressedImage`` decoded by OpenCV (8- or 16-bit, grey or BGR(A)); ``None`` where it does
    not decode."""
    data = np.asarray(msg.data, dtype=np.uint8)
    if data.size == 0:
        return None
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        return None
    return image[..., 0] if image.ndim == 3 and image.shape[2] == 1 else image


def bag_topics(path: str | Path) -> dict[str, str]:
    """The bag's topics and their message types (``pkg/msg/Name``, as ``rosbags`` names ROS1's and ROS2's types).

    Args:
        path: a ROS1 ``.bag`` file, or a ROS2 bag (its folder, or a ``.db3`` / ``.mcap`` file).

    Returns:
        ``{topic: message type}``, topics sorted.

    Raises:
        UserError: the path is no readable bag (one line).

    Example:
        >>> bag_topics("/nonexistent.bag")
        Traceback (most recent call last):
        ...
        ccs_kornia.runtime.errors.UserError: --bag /nonexistent.bag: no such file or folder
    """
    with _opened(path) as reader:
        return {name: info.msgtype for name, info in sorted(reader.topics.items())}


def read_bag_images(path: str | Path, topic: str) -> Iterator[tuple[float, np.ndarray | None]]:
    """The images of one topic, in the order the bag recorded them, read one at a time.

    Args:
        path: the bag (see :func:`bag_topics`).
        topic: a topic of ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` messages.

    Yields:
        ``(timestamp, image)``: the header's stamp in seconds, and the image as ``uint8`` or ``uint16``, grey
        :math:`(H, W)` or colour :math:`(H, W, 3)` / :math:`(H, W, 4)` in OpenCV's BGR(A) order; ``None`` for a
        compressed image that does not decode.

    Raises:
        UserError: no such topic (the line lists the bag's topics), a topic of another type, an encoding not read.

    Example:
        >>> import os, tempfile
        >>> from rosbags.rosbag1 import Writer
        >>> from rosbags.typesys import Stores, get_typestore
        >>> store = get_typestore(Stores.ROS1_NOETIC)
        >>> T, Header, Image = (store.types[f"{p}/msg/{n}"] for p, n in
        ...                     (("builtin_interfaces", "Time"), ("std_msgs", "Header"), ("sensor_msgs", "Image")))
        >>> path = os.path.join(tempfile.mkdtemp(), "rec.bag")
        >>> with Writer(path) as bag:
        ...     topic = bag.add_connection("/cam0/image_raw", "sensor_msgs/msg/Image", typestore=store)
        ...     header = Header(seq=0, stamp=T(sec=12, nanosec=500_000_000), frame_id="cam0")
        ...     msg = Image(header=header, height=2, width=3, encoding="mono8", is_bigendian=0, step=3,
        ...                 data=np.arange(6, dtype=np.uint8))
        ...     bag.write(topic, 13 * 10**9, store.serialize_ros1(msg, "sensor_msgs/msg/Image"))
        >>> [(t, image.tolist()) for t, image in read_bag_images(path, "/cam0/image_raw")]
        [(12.5, [[0, 1, 2], [3, 4, 5]])]
    """
    with _opened(path) as reader:
        connections = _connections(reader, path, topic, IMAGE_TYPES)
        for connection, recorded, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            image = _compressed_image(msg) if connection.msgtype.endswith("CompressedImage") else _raw_image(msg, topic)
            yield _stamp(msg, recorded), image


def read_bag_imu(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The IMU samples of one topic: times, angular velocities and linear accelerations.

    Args:
        path: the bag (see :func:`bag_topics`).
        topic: a topic of ``sensor_msgs/Imu`` messages.

    Returns:
        ``(t, gyro, accel)``: :math:`(N,)` the header stamps in seconds, :math:`(N, 3)` ``angular_velocity`` (rad/s)
        and :math:`(N, 3)` ``linear_acceleration`` (m/s^2), float64, in the order the bag recorded them.

    Raises:
        UserError: no such topic (the line lists the bag's topics), a topic of another type.

    Example:
        >>> import os, tempfile
        >>> from rosbags.rosbag2 import Writer
        >>> from rosbags.typesys import Stores, get_typestore
        >>> store = get_typestore(Stores.ROS2_HUMBLE)
        >>> T, Header, V, Q, Imu = (store.types[n] for n in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
        ...                         "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Quaternion", "sensor_msgs/msg/Imu"))
        >>> path = os.path.join(tempfile.mkdtemp(), "rec")
        >>> with Writer(path, version=9) as bag:
        ...     topic = bag.add_connection("/imu0", "sensor_msgs/msg/Imu", typestore=store)
        ...     for k in range(3):
        ...         msg = Imu(header=Header(stamp=T(sec=7, nanosec=5_000_000 * k), frame_id="imu"),
        ...                   orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
        ...                   angular_velocity=V(x=0.1 * k, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
        ...                   linear_acceleration=V(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))
        ...         bag.write(topic, 7 * 10**9 + 5_000_000 * k, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
        >>> t, gyro, accel = read_bag_imu(path, "/imu0")
        >>> t.tolist(), gyro[:, 0].tolist(), accel[0].tolist()
        ([7.0, 7.005, 7.01], [0.0, 0.1, 0.2], [0.0, 0.0, 9.81])
    """
    times, gyro, accel = [], [], []
    with _opened(path) as reader:
        connections = _connections(reader, path, topic, IMU_TYPES)
        for connection, recorded, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            w, a = msg.angular_velocity, msg.linear_acceleration
            times.append(_stamp(msg, recorded))
            gyro.append((w.x, w.y, w.z))
            accel.append((a.x, a.y, a.z))
    return (np.asarray(times, dtype=np.float64), np.asarray(gyro, dtype=np.float64).reshape(-1, 3),
            np.asarray(accel, dtype=np.float64).reshape(-1, 3))


# ------------------------------------------------------------------------------------------------
# an image topic as a recording
# ------------------------------------------------------------------------------------------------


def bag_topic_path(bag: str | Path, topic: str) -> str:
    """The path of an image topic as a recording: ``BAG#TOPIC``.

    Example:
        >>> bag_topic_path("rec.bag", "/cam0/image_raw")
        'rec.bag#/cam0/image_raw'
    """
    return f"{bag}#{topic}"


def split_bag_topic(path: str) -> tuple[str, str] | None:
    """``(bag, topic)`` of a path made by :func:`bag_topic_path`, ``None`` for other paths.

    Example:
        >>> split_bag_topic("rec.bag#/cam0/image_raw"), split_bag_topic("cam0.mp4")
        (('rec.bag', '/cam0/image_raw'), None)
    """
    bag, sep, topic = str(path).partition("#/")
    return (bag, "/" + topic) if sep and bag and "#" not in topic else None


def grey8(image: np.ndarray) -> np.ndarray:
    """An image as the detector reads a video's frame: grey ``uint8`` (colour converted from BGR(A), 16-bit scaled by
    1/257).

    Example:
        >>> grey8(np.full((2, 3), 65535, np.uint16)).tolist()
        [[255, 255, 255], [255, 255, 255]]
    """
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if image.dtype == np.uint16:
        image = np.round(image.astype(np.float32) / 257.0).astype(np.uint8)
    return np.ascontiguousarray(image)


def _decoded(reader: Any, connection: Any, raw: bytes, topic: str) -> tuple[Any, np.ndarray | None]:
    msg = reader.deserialize(raw, connection.msgtype)
    image = _compressed_image(msg) if connection.msgtype.endswith("CompressedImage") else _raw_image(msg, topic)
    return msg, image


def open_bag_topic(path: str) -> tuple[VideoInfo | None, str]:
    """An image topic's description as a recording's (:class:`~ccs_kornia.io.video.VideoInfo`: the first image's
    size, the frame rate from the stamps' median step, the topic's message count), without raising:
    ``(info, "")`` or ``(None, reason)``."""
    bag, topic = split_bag_topic(path) or (path, "")
    try:
        with _opened(bag) as reader:
            connections = _connections(reader, bag, topic, IMAGE_TYPES)
            count = sum(int(c.msgcount) for c in connections)
            size, stamps = None, []
            for connection, recorded, raw in reader.messages(connections=connections):
                msg, image = _decoded(reader, connection, raw, topic)
                stamps.append(_stamp(msg, recorded))
                if size is None and image is not None:
                    size = (int(image.shape[1]), int(image.shape[0]))
                if size is not None and len(stamps) >= 32:
                    break
    except UserError as err:
        return None, str(err).removeprefix(f"--bag {bag}: ")
    if size is None:
        return None, f"topic {topic}: no image decodes"
    steps = sorted(b - a for a, b in itertools.pairwise(stamps) if b > a)
    fps = 1.0 / steps[len(steps) // 2] if steps else 0.0
    return VideoInfo(path, size[0], size[1], fps if 0 < fps < 10_000 else 0.0, count), ""


class BagTopicReader:
    """An image topic of a bag read as a recording (the interface of :class:`~ccs_kornia.io.video.VideoReader`):
    frames in order, each with its index on the topic and its header stamp (s), and frames got back by index.

    The bag is opened by each call (its storage may not be shared between threads) and closed after it; the messages'
    recording times, learnt by the first pass, find a frame again without reading the ones before it.

    Args:
        path: ``BAG#TOPIC`` (:func:`bag_topic_path`).
        info: its :class:`~ccs_kornia.io.video.VideoInfo` (:func:`open_bag_topic` when not given).

    Raises:
        ValueError: the topic is not a readable image topic (one line).
    """

    def __init__(self, path: str, info: VideoInfo | None = None) -> None:
        self.path = str(path)
        self.bag, self.topic = split_bag_topic(self.path) or (self.path, "")
        if info is None:
            info, reason = open_bag_topic(self.path)
            if info is None:
                raise ValueError(f"{self.path}: {reason}")
        self.info = info
        self.stopped = ""
        self.decoded = 0
        self.length: int | None = None
        self._recorded: list[int] | None = None

    def close(self) -> None:
        """Nothing stays open between calls."""

    def __enter__(self) -> BagTopicReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def frames(self, span: FrameSpan | None = None, max_side: int | None = None) -> Iterator[VideoFrame]:
        """The frames ``span`` asks for, in order (``--start`` / ``--end`` in seconds from the topic's first stamp);
        a compressed image that does not decode is left out, and :attr:`stopped` says how many were."""
        span = FrameSpan() if span is None else span
        recorded: list[int] = []
        first: int | None = None
        t0: float | None = None
        lost = 0
        with _opened(self.bag) as reader:
            connections = _connections(reader, self.bag, self.topic, IMAGE_TYPES)
            for index, (connection, at, raw) in enumerate(reader.messages(connections=connections)):
                recorded.append(at)
                self.decoded += 1
                msg = reader.deserialize(raw, connection.msgtype)
                t = _stamp(msg, at)
                t0 = t if t0 is None else t0
                if span.past_end(t - t0):
                    break
                if span.before_start(t - t0):
                    continue
                first = index if first is None else first
                if not span.wants(index, t - t0, first):
                    continue
                image = _compressed_image(msg) if connection.msgtype.endswith("CompressedImage") \
                    else _raw_image(msg, self.topic)
                if image is None:
                    lost += 1
                    continue
                yield VideoFrame(index, t, scaled_frame(grey8(image), max_side))
            else:
                self.length = len(recorded)
                self._recorded = recorded
        self.stopped = f"{lost} compressed images did not decode and were left out" if lost else ""

    def _recording_times(self) -> list[int]:
        if self._recorded is None:
            with _opened(self.bag) as reader:
                connections = _connections(reader, self.bag, self.topic, IMAGE_TYPES)
                self._recorded = [at for _, at, _ in reader.messages(connections=connections)]
        return self._recorded

    def read(self, index: int, timestamp: float | None = None) -> VideoFrame | None:
        """Frame ``index`` at full size (grey ``uint8``), ``None`` where the topic has no such frame or it does not
        decode; ``timestamp``: the stamp :meth:`frames` saw (a frame whose stamp differs is not it: ``None``)."""
        index = int(index)
        if index < 0:
            raise ValueError(f"index must be >= 0, got {index}.")
        times = self._recording_times()
        if index >= len(times):
            return None
        at = times[index]
        skip = index - times.index(at)  # messages recorded at the same time before it
        with _opened(self.bag) as reader:
            connections = _connections(reader, self.bag, self.topic, IMAGE_TYPES)
            for k, (connection, got, raw) in enumerate(reader.messages(connections=connections, start=at,
                                                                       stop=at + 1)):
                if k < skip:
                    continue
                msg, image = _decoded(reader, connection, raw, self.topic)
                t = _stamp(msg, got)
                if image is None or (timestamp is not None and abs(t - timestamp) > 1e-6):
                    return None
                return VideoFrame(index, t, grey8(image))
        return None
