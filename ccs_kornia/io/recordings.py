"""A recording, whatever holds it: a video file (:class:`~ccs_kornia.io.video.VideoReader`) or an image topic of a ROS
bag (``BAG#TOPIC``, :class:`~ccs_kornia.io.rosbag.BagTopicReader`), opened and read the same way.

The screening pass, the frame choice and the full detector's look at the chosen frames
(:class:`~ccs_kornia.pipeline.sources.VideoSource`) read every recording through :func:`open_recording` and
:func:`recording_reader`, so a bag's topic is calibrated as a video is, its frames named ``BAG#TOPIC#INDEX``.
"""

from __future__ import annotations

import os

from ccs_kornia.io.rosbag import BagTopicReader, open_bag_topic, split_bag_topic
from ccs_kornia.io.video import VideoInfo, VideoReader, open_video

__all__ = ["is_bag_topic", "open_recording", "recording_reader"]


def is_bag_topic(path: str | os.PathLike) -> bool:
    """``path`` names a bag's image topic (``BAG#TOPIC``, no file of that name).

    Example:
        >>> is_bag_topic("rec.bag#/cam0/image_raw"), is_bag_topic("cam0.mp4")
        (True, False)
    """
    path = os.fspath(path)
    return split_bag_topic(path) is not None and not os.path.exists(path)


def open_recording(path: str | os.PathLike) -> tuple[VideoInfo | None, str]:
    """The recording's description (:func:`~ccs_kornia.io.video.open_video`,
    :func:`~ccs_kornia.io.rosbag.open_bag_topic`), without raising: ``(info, "")`` or ``(None, reason)``."""
    return open_bag_topic(os.fspath(path)) if is_bag_topic(path) else open_video(path)


def recording_reader(path: str | os.PathLike, info: VideoInfo | None = None) -> VideoReader | BagTopicReader:
    """The reader of a recording (``info``: its description, probed when not given).

    Raises:
        ValueError: not a readable recording (one line).
    """
    return BagTopicReader(os.fspath(path), info) if is_bag_topic(path) else VideoReader(path, info)
