"""The board's sag in the camera-IMU fit: its derivatives against finite differences, recovered from a rendered bent
board and kept, left out on a flat one, and written as the ``board_flatness`` block every fit of a board writes."""

import pytest
import torch

from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
from ccs_kornia.modules.imu.imu_flatness import heldout_frames
from ccs_kornia.modules.imu.initial import align_rates, board_poses, initial_unknowns
from ccs_kornia.modules.imu.problem import ImuCameraData, ImuCameraProblem, Weights
from ccs_kornia.modules.imu.solver import calibrate_imu_camera
from ccs_kornia.outputs.imu_records import imu_camera_record
from ccs_kornia.outputs.report.drawing import board_bend_line

#: the rendered board's sag (m): 2 mm and 1 mm at the centre of a 0.48 x 0.40 m board
SAG = (-0.002, 0.001)


def _data(rec):
    return ImuCameraData.from_corners(rec.imu_times, rec.gyro, rec.accel, rec.cameras, rec.object_points,
                                      rec.frame_times, rec.corners)


def _solve(warp, seed):
    # a short recording, the IMU at 100 Hz and the noise as given: the fit and the judgement in a few seconds
    rec = visual_inertial_recording(duration=3.0, seed=seed, imu_rate=100.0, board_warp=warp)
    return rec, calibrate_imu_camera(_data(rec), noise=rec.noise, knot_spacing=0.05, estimate_noise=False,
                                     board_flatness=True)


class TestProblem:
    @pytest.mark.parametrize("rolling_shutter", [False, True])
    def test_sag_derivatives_match_finite_differences(self, rolling_shutter):
        rec = visual_inertial_recording(duration=2.0, seed=12, imu_rate=100.0, board_warp=SAG)
        data = _data(rec)
        dt, t0 = 0.05, float(data.imu_times[0])
        M = int((float(data.imu_times[-1]) - t0) / dt) + 3
        prob = ImuCameraProblem(data, t0, dt, M, Weights(1e4, 1e2, 4.0, 1e4, 1e2), rolling_shutter=rolling_shutter,
                                board_warp=True)
        assert prob.G == 8 + rolling_shutter + 2 + 1
        R, t, ok = board_poses(data)
        s = initial_unknowns(data, t0, dt, M, R, t, ok, [align_rates(data.frame_times, R, ok, data.imu_times,
                                                                     data.gyro)])
        s["delay"] = torch.full((1, 1), 3e-5, dtype=torch.float64)
        s["warp"] = torch.tensor([[-0.001, 0.0015]], dtype=torch.float64)
        eq = prob.linearize(s)
        g = torch.Generator().manual_seed(0)
        dg = torch.randn(1, prob.G, generator=g, dtype=torch.float64)
        dp = torch.randn(1, M, 12, generator=g, dtype=torch.float64)
        h = 1e-6

        def corners(dg_, dp_):
            return prob.residuals(prob.retract(s, dg_, dp_))[2][data.seen].flatten()

        # the sag's columns of the Jacobian, and the whole Jacobian along a random step, by central differences
        only = torch.zeros_like(dg)
        Jw = torch.stack([(corners(h * e, 0 * dp) - corners(-h * e, 0 * dp)) / (2 * h)
                          for e in torch.eye(prob.G, dtype=torch.float64)[-2:, None]], -1)
        Jd = (corners(h * dg, h * dp) - corners(-h * dg, -h * dp)) / (2 * h)
        r = corners(only, 0 * dp)
        # the sag's rows of the normal equations: J_w^T W r, J_w^T W J_w and J_w^T W J d (the cross terms)
        torch.testing.assert_close(eq.eg[0, -2:], 4.0 * Jw.T @ r, rtol=1e-6, atol=0)
        torch.testing.assert_close(eq.U[0, -2:, -2:], 4.0 * Jw.T @ Jw, rtol=1e-6, atol=0)
        cross = eq.U[0, -2:] @ dg[0] + torch.einsum("mgk,mk->g", eq.W[0, :, -2:], dp[0])
        torch.testing.assert_close(cross, 4.0 * Jw.T @ Jd, rtol=1e-5, atol=0)

    def test_heldout_frames_alternate_per_camera(self):
        rec = visual_inertial_recording(duration=2.0, seed=3, num_cameras=2, imu_rate=100.0)
        data = _data(rec)
        held = heldout_frames(data)
        for c in range(2):
            h = held[data.frame_camera == c]
            assert not bool(h[0::2].any()) and bool(h[1::2].all())


class TestSolver:
    def test_bent_board_recovered_and_kept(self):
        rec, res = _solve(SAG, seed=22)
        block = res.board_flatness
        assert block["kept"] is True
        truth = torch.tensor(SAG, dtype=torch.float64)
        # within 4 sigma of the truth, and the 1-sigma a tenth of a millimetre or less
        assert bool(((res.board_warp - truth).abs() < 4 * res.board_warp_std).all()), block
        assert bool((res.board_warp_std < 2.5e-4).all())
        held = block["heldout_median_px"]
        assert held["warp"] < 0.95 * held["flat"]
        # the JSON's block and the report's line, as every fit of a board writes them
        record = imu_camera_record(res, ["cam0"])
        assert record["board_flatness"] == block and record["board_flatness"]["warp_m"] == res.board_warp.tolist()
        assert "kept (held-out median" in board_bend_line(record["board_flatness"], 0.08)
        # T_cam_imu as good as the rendered corners allow
        assert float((res.T_cam_imu[0, :3, 3] - rec.T_cam_imu[0, :3, 3]).norm()) < 0.002

    def test_flat_board_not_kept(self):
        _, res = _solve(None, seed=22)
        block = res.board_flatness
        assert block["kept"] is False and res.board_warp is None and res.board_warp_std is None
        # the fitted sag is zero within its 1-sigma's reach
        warp, std = torch.tensor(block["warp_m"]), torch.tensor(block["std_m"])
        assert bool((warp.abs() < 3 * std).all()) and bool((std < 2.5e-4).all())
        assert "not kept" in board_bend_line(imu_camera_record(res, ["cam0"])["board_flatness"], 0.08)
