"""Robot pose files: each form (quaternion, rotation vector, matrix), each unit, headers, refusals, and the pairing
with images by name."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ccs_kornia.io.robot_poses import match_poses, parse_robot_poses, read_robot_poses
from ccs_kornia.runtime.errors import UserError

ROT = Rotation.from_rotvec([0.3, -0.2, 1.1])
T_M = np.array([0.4, -0.1, 0.35])


def _row(kind: str, scale: float = 1.0) -> str:
    t = T_M * scale
    if kind == "quat":
        return ",".join(f"{v:.12g}" for v in (*t, *ROT.as_quat()))
    if kind == "rotvec":
        return ",".join(f"{v:.12g}" for v in (*t, *ROT.as_rotvec()))
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = ROT.as_matrix(), t
    return ",".join(f"{v:.12g}" for v in M.ravel())


@pytest.mark.parametrize("kind", ["quat", "rotvec", "matrix"])
@pytest.mark.parametrize("units,scale", [("m", 1.0), ("mm", 1000.0)])
@pytest.mark.parametrize("explicit", [True, False])
def test_every_form_and_unit_gives_the_same_pose(kind, units, scale, explicit):
    text = f"image,pose\nimg_01.png,{_row(kind, scale)}\n"
    poses = parse_robot_poses(text, kind if explicit else "auto", units)
    assert poses.names == ["img_01.png"] and poses.format == kind
    np.testing.assert_allclose(poses.poses[0, :3, :3], ROT.as_matrix(), atol=1e-10)
    np.testing.assert_allclose(poses.poses[0, :3, 3], T_M, atol=1e-10)
    np.testing.assert_allclose(poses.poses[0, 3], [0, 0, 0, 1])


def test_separators_comments_and_no_header():
    text = "# a comment\n\na.png 1 2 3 0 0 0\nb.png;0;0;0;0;0;0.5\nc.png\t0\t0\t0\t0\t0\t0\n"
    poses = parse_robot_poses(text, units="mm")
    assert poses.names == ["a.png", "b.png", "c.png"] and poses.lines == [3, 4, 5]
    np.testing.assert_allclose(poses.poses[0, :3, 3], [0.001, 0.002, 0.003])


@pytest.mark.parametrize("text,phrase", [
    ("a.png,1,2,3,0,0,0\nb.png,1,2,3,0,0,0,1\n", "--pose-format rotvec has 6"),
    ("a.png,1,2,3,4\n", "a pose has 7"),
    ("a.png,1,2,x,0,0,0\n", "'x' is not a number"),
    ("a.png,0,0,0,1,2,3,4\n", "norm"),
    ("a.png,0,0,0,90,0,0\n", "degrees given?"),
    ("a.png," + ",".join(["1"] * 16) + "\n", "not a rigid transform"),
    ("a.png,0,0,0,0,0,0\na.png,0,0,0,0,0,0\n", "has a pose already"),
    ("image,x,y,z\n", "no pose found"),
])
def test_bad_files_are_refused_with_the_line(text, phrase):
    with pytest.raises(UserError, match=None) as err:
        parse_robot_poses(text)
    assert phrase in str(err.value)


def test_unknown_form_or_unit():
    with pytest.raises(UserError, match="--pose-format"):
        parse_robot_poses("a 0 0 0 0 0 0", "euler")
    with pytest.raises(UserError, match="--pose-units"):
        parse_robot_poses("a 0 0 0 0 0 0", units="cm")


def test_unreadable_file(tmp_path):
    with pytest.raises(UserError, match="cannot read"):
        read_robot_poses(str(tmp_path / "missing.csv"))
    (tmp_path / "p.csv").write_text("img.png 0 0 0 0 0 " + str(math.pi / 2))
    assert read_robot_poses(str(tmp_path / "p.csv")).names == ["img.png"]


def test_images_and_poses_pair_by_name_never_by_order():
    poses = parse_robot_poses("c.png 0 0 3 0 0 0\na 0 0 1 0 0 0\ndir/b.png 0 0 2 0 0 0\nextra.png 0 0 9 0 0 0\n")
    T, missing, unused = match_poses(["x/a.png", "x/b.png", "x/c.png", "x/d.png"], poses)
    assert T[:3, 2, 3].tolist() == [1.0, 2.0, 3.0]  # by name, whatever the rows' order
    assert np.isnan(T[3]).all() and missing == ["x/d.png"] and unused == ["extra.png"]
