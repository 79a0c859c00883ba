r"""A hand-eye calibration as ROS and MoveIt set-ups load it: a static transform and easy_handeye's YAML.

Both publish ``X``, the camera's pose in its robot frame, as the transform from the robot frame (the parent: the
flange frame for eye-in-hand, the base frame for eye-to-hand) to the camera's optical frame (the child: ``z`` along
the optical axis, ``x`` right, ``y`` down in the image, the frame the calibration's camera uses):

* :func:`ros_static_transform`: a ROS 1 launch file running ``tf2_ros static_transform_publisher``
  (:mod:`~ccs_kornia.outputs.ros_tf`), and the same transform as the ROS 2 command line in a comment;
* :func:`moveit_calibration_yaml`: the calibration YAML of easy_handeye (and easy_handeye2), the file its
  ``publish`` launch loads to broadcast the transform a MoveIt planning set-up then uses: ``eye_on_hand``, the frames,
  and ``transformation: {x, y, z, qx, qy, qz, qw}``.
"""

from __future__ import annotations

from typing import Any

from ccs_kornia.outputs.ros_tf import StaticTransform, static_transform_launch

__all__ = ["DEFAULT_FRAMES", "moveit_calibration_yaml", "ros_frames", "ros_static_transform"]

#: default frame names: (base, flange, camera)
DEFAULT_FRAMES = ("base_link", "tool0", "camera_optical_frame")


def ros_frames(data: dict[str, Any], frames: tuple[str, str, str] = DEFAULT_FRAMES) -> tuple[str, str]:
    """``(parent, child)`` of the calibration's transform: the flange (eye-in-hand) or base frame, and the camera's."""
    base, flange, camera = frames
    return (flange if data["setup"] == "eye-in-hand" else base), camera


def _tq(data: dict[str, Any]) -> tuple[list[float], list[float]]:
    return [float(v) for v in data["X_tq"]["t"]], [float(v) for v in data["X_tq"]["q"]]


def ros_static_transform(data: dict[str, Any], frames: tuple[str, str, str] = DEFAULT_FRAMES) -> str:
    """The launch file of ``--ros-tf`` (module doc) from ``handeye.json``'s dict.

    Example:
        >>> d = {"setup": "eye-in-hand", "X_tq": {"t": [0.1, 0.0, 0.05], "q": [0.0, 0.0, 0.0, 1.0]}}
        >>> "args=\\"0.1 0 0.05 0 0 0 1 tool0 camera_optical_frame\\"" in ros_static_transform(d)
        True
    """
    t, q = _tq(data)
    parent, child = ros_frames(data, frames)
    return static_transform_launch([StaticTransform(t, q, parent, child, "hand_eye_camera_broadcaster")],
                                   f"hand-eye calibration ({data['setup']}): the camera's optical frame in {parent}")


def moveit_calibration_yaml(data: dict[str, Any], frames: tuple[str, str, str] = DEFAULT_FRAMES) -> str:
    """The YAML of ``--moveit-yaml`` (module doc) from ``handeye.json``'s dict.

    Example:
        >>> d = {"setup": "eye-to-hand", "X_tq": {"t": [1.0, 0.0, 0.5], "q": [0.0, 0.0, 0.0, 1.0]}}
        >>> print(moveit_calibration_yaml(d).splitlines()[1])
        eye_on_hand: false
    """
    t, q = _tq(data)
    base, flange, camera = frames
    eye_in_hand = data["setup"] == "eye-in-hand"
    lines = ["# hand-eye calibration: the camera's optical frame in the robot frame (metres, unit quaternion)",
             f"eye_on_hand: {'true' if eye_in_hand else 'false'}",
             f"robot_base_frame: {base}",
             f"robot_effector_frame: {flange}",
             f"tracking_base_frame: {camera}",
             "transformation:"]
    lines += [f"  {k}: {v:.12g}" for k, v in zip(("x", "y", "z"), t)]
    lines += [f"  {k}: {v:.12g}" for k, v in zip(("qx", "qy", "qz", "qw"), q)]
    return "\n".join(lines) + "\n"
