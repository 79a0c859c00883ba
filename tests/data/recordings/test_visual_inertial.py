import math

import torch

from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
from ccs_kornia.geometry.so3 import log_so3


def test_seeded_and_shaped():
    a = visual_inertial_recording(duration=3.0, seed=5, num_cameras=2)
    b = visual_inertial_recording(duration=3.0, seed=5, num_cameras=2)
    torch.testing.assert_close(a.gyro, b.gyro)
    assert a.gyro.shape == (600, 3) and len(a.corners) == 2 and a.corners[1].shape[1:] == (42, 2)
    assert a.T_cam_imu.shape == (2, 4, 4) and bool((a.shift.abs() <= 0.03).all())


def test_imu_truth_is_the_motions_derivative():
    rec = visual_inertial_recording(duration=2.0, seed=1)
    m = rec.motion
    t = torch.linspace(0.5, 1.5, 7, dtype=torch.float64)
    h = 1e-6
    Ra, _ = m.imu_pose(t - h)
    Rb, _ = m.imu_pose(t + h)
    torch.testing.assert_close(log_so3(Ra.mT @ Rb) / (2 * h), m.angular_velocity(t), atol=1e-7, rtol=1e-6)
    # at rest the accelerometer reads minus gravity in the body frame; here: its norm stays plausible
    assert 0 < float(rec.accel.norm(dim=-1).min()) and float(rec.accel.norm(dim=-1).max()) < 40


def test_corners_are_the_projection_at_the_shifted_time():
    rec = visual_inertial_recording(duration=2.0, seed=2, pixel_noise=0.0, shift=0.01)
    t = rec.frame_times[0][:3] + 0.01
    R, p = rec.motion.camera_pose(t)
    xc = (R.mT[:, None] @ (rec.object_points[None] - p[:, None])[..., None])[..., 0]
    uv = rec.cameras.project(xc.reshape(1, -1, 3))[0].view(3, -1, 2)
    seen = rec.corners[0][:3].isfinite().all(-1)
    assert float((uv[seen] - rec.corners[0][:3][seen]).abs().max()) < 1e-9 and math.isclose(float(rec.shift[0]), 0.01)
