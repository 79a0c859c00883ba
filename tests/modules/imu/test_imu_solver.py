import math

import pytest
import torch

from ccs_kornia.data.recordings.visual_inertial import visual_inertial_recording
from ccs_kornia.geometry.imu_intrinsics import ImuIntrinsics, ImuModel
from ccs_kornia.geometry.so3 import log_so3
from ccs_kornia.modules.calibration.schur_lm import schur_step
from ccs_kornia.modules.imu.initial import align_rates, board_poses, initial_unknowns
from ccs_kornia.modules.imu.problem import ImuCameraData, ImuCameraProblem, Weights
from ccs_kornia.modules.imu.result import imu_camera_verdict
from ccs_kornia.modules.imu.solver import ImuCameraSolver, calibrate_imu_camera
from ccs_kornia.runtime.errors import NoResult, UserError


def _data(rec):
    return ImuCameraData.from_corners(rec.imu_times, rec.gyro, rec.accel, rec.cameras, rec.object_points,
                                      rec.frame_times, rec.corners)


@pytest.fixture(scope="module")
def recording():
    return visual_inertial_recording(duration=10.0, seed=11)


@pytest.fixture(scope="module")
def solved(recording):
    return calibrate_imu_camera(_data(recording), noise=recording.noise)


class TestStart:
    def test_rate_alignment_finds_offset_and_rotation(self, recording):
        data = _data(recording)
        R, _t, ok = board_poses(data)
        al = align_rates(data.frame_times, R, ok, data.imu_times, data.gyro)
        assert abs(al.shift - float(recording.shift[0])) < 1e-3
        err = float(log_so3(al.R_cam_imu.T @ recording.T_cam_imu[0, :3, :3]).norm()) * 180 / math.pi
        assert err < 0.5 and al.correlation.max() > 0.9


class TestProblem:
    @pytest.mark.parametrize("rolling_shutter", [False, True])
    def test_normal_equations_are_the_costs_gradient(self, recording, rolling_shutter):
        # the gradient J^T r the problem assembles equals the cost's numerical derivative along a random step
        data = _data(visual_inertial_recording(duration=3.0, seed=12))
        solver_noise = recording.noise
        dt, t0 = 0.05, float(data.imu_times[0])
        M = int((float(data.imu_times[-1]) - t0) / dt) + 3
        w = Weights(gyro=1 / solver_noise.discrete_gyroscope_sigma**2, accel=1 / solver_noise.discrete_accelerometer_sigma**2,
                    pixel=4.0, gyro_walk=1e4, accel_walk=1e2)
        prob = ImuCameraProblem(data, t0, dt, M, w, rolling_shutter=rolling_shutter)
        # a realistic point: the fit's start (from the angular rates), with a row delay
        R, t, ok = board_poses(data)
        al = align_rates(data.frame_times, R, ok, data.imu_times, data.gyro)
        s = initial_unknowns(data, t0, dt, M, R, t, ok, [al])
        s["delay"] = torch.full((1, 1), 3e-5, dtype=torch.float64)
        g = torch.Generator().manual_seed(0)
        eq = prob.linearize(s)
        dg = torch.randn(1, prob.G, generator=g, dtype=torch.float64)
        dp = torch.randn(1, M, 12, generator=g, dtype=torch.float64)
        h = 1e-6
        plus = prob.linearize(prob.retract(s, h * dg, h * dp)).cost
        minus = prob.linearize(prob.retract(s, -h * dg, -h * dp)).cost
        numeric = float((plus - minus) / (2 * h))
        analytic = 2 * float((eq.eg * dg).sum() + (eq.ep * dp).sum())
        assert analytic == pytest.approx(numeric, rel=1e-5)
        # and the step solves the banded system
        d_g, d_p = schur_step(eq.U, eq.W, eq.V, eq.eg, eq.ep, prob.used, Vband=eq.Vband)
        assert torch.isfinite(d_g).all() and torch.isfinite(d_p).all()

    def test_held_rig_normal_equations_are_the_costs_gradient(self):
        # a held rig maps camera 0's step to every camera's: the reduced gradient is still the cost's derivative (the
        # cameras' parameters and the IMU's intrinsics estimated too)
        rec = visual_inertial_recording(duration=3.0, seed=15, num_cameras=2)
        data = _data(rec)
        dt, t0 = 0.05, float(data.imu_times[0])
        M = int((float(data.imu_times[-1]) - t0) / dt) + 3
        rig = rec.T_cam_imu.double() @ torch.linalg.inv(rec.T_cam_imu[0].double())
        prob = ImuCameraProblem(data, t0, dt, M, Weights(1e4, 1e2, 4.0, 1e4, 1e2), rig=rig, refine_intrinsics=True,
                                imu_model=ImuModel.SCALE_MISALIGNMENT)
        n = data.cameras.params.shape[1]
        assert prob.G == 6 + 2 * (1 + n) + 2 + 24 and prob.G_all == (7 + n) * 2 + 2 + 24
        R, t, ok = board_poses(data)
        sel = data.frame_camera == 0
        al = align_rates(data.frame_times[sel], R[sel], ok[sel], data.imu_times, data.gyro)
        s = initial_unknowns(data, t0, dt, M, R, t, ok, [al, al])
        s["Rci"] = (rig[:, :3, :3] @ s["Rci"][0, 0])[None]
        s["tci"] = (rig[:, :3, 3] + rig[:, :3, :3] @ s["tci"][0, 0])[None]
        g = torch.Generator().manual_seed(1)
        s["Tg"] = s["Tg"] + 0.01 * torch.randn(1, 3, 3, generator=g, dtype=torch.float64)
        s["Ta"] = s["Ta"] + 0.01 * torch.randn(1, 3, 3, generator=g, dtype=torch.float64).triu()
        s["Ag"] = 1e-3 * torch.randn(1, 3, 3, generator=g, dtype=torch.float64)
        eq = prob.linearize(s)
        dg = torch.randn(1, prob.G, generator=g, dtype=torch.float64)
        dg[:, 7:7 + n] *= 1e-2  # a lens coefficient's step of the size of the others' effect
        dg[:, 8 + n:8 + 2 * n] *= 1e-2
        dg[:, -24:] *= 1e-2  # the IMU's matrices: a step of their size
        dp = torch.randn(1, M, 12, generator=g, dtype=torch.float64)
        h = 1e-6
        plus = prob.linearize(prob.retract(s, h * dg, h * dp)).cost
        minus = prob.linearize(prob.retract(s, -h * dg, -h * dp)).cost
        assert 2 * float((eq.eg * dg).sum() + (eq.ep * dp).sum()) == pytest.approx(float((plus - minus) / (2 * h)),
                                                                                    rel=1e-5)
        # a step keeps the rig exactly
        moved = prob.retract(s, 1e-2 * dg, 0 * dp)
        T = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
        T[:, :3, :3], T[:, :3, 3] = moved["Rci"][0], moved["tci"][0]
        torch.testing.assert_close(T[1] @ torch.linalg.inv(T[0]), rig[1], atol=1e-12, rtol=0)

    def test_take_refuses_splitting(self, recording):
        data = _data(visual_inertial_recording(duration=2.0, seed=13))
        prob = ImuCameraProblem(data, 0.0, 0.05, 40, Weights(1.0, 1.0, 1.0, 1.0, 1.0))
        assert prob.take(torch.ones(1, dtype=torch.bool)) is prob
        with pytest.raises(ValueError):
            prob.take(torch.zeros(1, dtype=torch.bool))


class TestSolver:
    def test_recovers_the_truth(self, recording, solved):
        err_r = float(log_so3(solved.T_cam_imu[0, :3, :3] @ recording.T_cam_imu[0, :3, :3].T).norm()) * 180 / math.pi
        err_t = float((solved.T_cam_imu[0, :3, 3] - recording.T_cam_imu[0, :3, 3]).norm())
        err_s = abs(float(solved.timeshift_cam_imu[0] - recording.shift[0]))
        assert err_r < 0.02 and err_t < 0.002 and err_s < 5e-5
        # the 1-sigma are of the errors' size (not 100x off either way)
        assert 0.01 < err_t / float(solved.translation_std[0].norm()) < 10
        torch.testing.assert_close(solved.gravity, recording.gravity, atol=0.02, rtol=0)
        assert solved.verdict == "good" and solved.status in (1, 2)
        # an ideal IMU's residuals do not follow its readings
        assert all(z < 6 for _, z in solved.residual_scale.values())

    def test_noise_measured_when_stated_wrong(self, recording):
        res = calibrate_imu_camera(_data(recording), noise=recording.noise.scaled(10.0))
        ratio = res.noise_measured.gyroscope_noise_density / recording.noise.gyroscope_noise_density
        assert 0.5 < ratio < 2.0
        err_t = float((res.T_cam_imu[0, :3, 3] - recording.T_cam_imu[0, :3, 3]).norm())
        assert err_t < 0.003
        assert any("stated noise density" in r for r in res.verdict_reasons)

    def test_stereo_rig(self):
        rec = visual_inertial_recording(duration=8.0, seed=14, num_cameras=2)
        res = ImuCameraSolver(noise=rec.noise)(_data(rec))
        assert res.T_cam_imu.shape == (2, 4, 4)
        for c in range(2):
            assert float((res.T_cam_imu[c, :3, 3] - rec.T_cam_imu[c, :3, 3]).norm()) < 0.003
            assert abs(float(res.timeshift_cam_imu[c] - rec.shift[c])) < 1e-4
        # the rig's extrinsics held: camera 1 follows camera 0 exactly, each keeps its own time shift
        rig = rec.T_cam_imu.double() @ torch.linalg.inv(rec.T_cam_imu[0].double())
        held = ImuCameraSolver(noise=rec.noise, rig=rig)(_data(rec))
        assert held.rig_held and held.covariance.shape == (16, 16)
        torch.testing.assert_close(held.T_cam_imu[1] @ torch.linalg.inv(held.T_cam_imu[0]), rig[1], atol=1e-9, rtol=0)
        for c in range(2):
            assert float((held.T_cam_imu[c, :3, 3] - rec.T_cam_imu[c, :3, 3]).norm()) < 0.003
            assert abs(float(held.timeshift_cam_imu[c] - rec.shift[c])) < 1e-4
        # one T_cam_imu from both cameras' corners: its 1-sigma is the same for both and below the free fit's
        torch.testing.assert_close(held.translation_std[0].norm(), held.translation_std[1].norm(), rtol=1e-6, atol=0)
        assert float(held.translation_std[0].norm()) < float(res.translation_std[0].norm())

    def test_refined_intrinsics(self, recording):
        # a camera 1 % off in focal length and 3 px in its centre: held, it moves T_cam_imu by millimetres; refined,
        # the camera and T_cam_imu come back
        truth = recording.cameras
        p = truth.params.clone()
        p[0, :2] *= 1.01
        p[0, 2:4] += torch.tensor([3.0, -2.0], dtype=p.dtype)
        data = _data(recording)
        data.cameras = truth.with_params(p)
        res = calibrate_imu_camera(data, noise=recording.noise, refine_intrinsics=True)
        err_t = float((res.T_cam_imu[0, :3, 3] - recording.T_cam_imu[0, :3, 3]).norm())
        assert err_t < 0.002
        assert float((res.cameras.params[0, :4] - truth.params[0, :4]).abs().max()) < 0.5
        assert res.intrinsics_std.shape == (1, truth.params.shape[1]) and bool((res.intrinsics_std > 0).all())
        assert float(res.pixel_rms[0]) < 0.4

    def test_imu_intrinsics(self):
        # an IMU 1-2 % off in scale, misaligned by a few mrad and sensitive to acceleration: the ideal model moves
        # T_cam_imu by millimetres, scale-misalignment recovers it and the IMU's matrices
        eye = torch.eye(3, dtype=torch.float64)
        imu = ImuIntrinsics(eye + torch.tensor([[0.01, 0.003, -0.004], [0.002, -0.015, 0.003], [0.004, -0.005, 0.02]],
                                               dtype=torch.float64),
                            eye + torch.tensor([[-0.01, 0.004, 0.004], [0.0, 0.012, 0.004], [0.0, 0.0, 0.008]],
                                               dtype=torch.float64),
                            2e-4 * torch.tensor([[1.0, -1.0, 0.5], [0.3, 1.0, -0.7], [-0.2, 0.6, 1.0]], dtype=torch.float64))
        rec = visual_inertial_recording(duration=12.0, seed=16, imu_intrinsics=imu)
        # fitted as an ideal IMU, the residuals follow the readings: the verdict asks for the intrinsics
        ideal = calibrate_imu_camera(_data(rec), noise=rec.noise, max_iters=10)
        assert any("--imu-model scale-misalignment" in r for r in ideal.verdict_reasons)
        assert ideal.residual_scale["accelerometer"][1] > 6
        res = ImuCameraSolver(noise=rec.noise, imu_model=ImuModel.SCALE_MISALIGNMENT)(_data(rec))
        assert res.residual_scale == {}
        assert float((res.T_cam_imu[0, :3, 3] - rec.T_cam_imu[0, :3, 3]).norm()) < 0.002
        est = res.imu_intrinsics
        assert float((est.gyro_matrix - imu.gyro_matrix).abs().max()) < 2e-3
        assert float((est.accel_matrix - imu.accel_matrix).abs().max()) < 2e-3
        assert float((est.g_sensitivity - imu.g_sensitivity).abs().max()) < 2e-4
        assert res.imu_intrinsics_std.shape == (24,) and bool((res.imu_intrinsics_std > 0).all())

    def test_weak_motion_is_named(self, recording, solved):
        import dataclasses

        weak = dataclasses.replace(solved, translation_std=torch.tensor([[0.02, 0.001, 0.001]], dtype=torch.float64))
        verdict, _reasons = imu_camera_verdict(weak)
        assert verdict.startswith("not reliable") and "X (left-right)" in verdict


class TestRefusals:
    def test_clocks_that_do_not_overlap(self, recording):
        data = _data(recording)
        data.frame_times = data.frame_times + 1000.0
        with pytest.raises(UserError, match="overlap"):
            calibrate_imu_camera(data)

    def test_timestamps_backwards(self, recording):
        data = _data(recording)
        data.imu_times = data.imu_times.clone()
        data.imu_times[50] = data.imu_times[10]
        with pytest.raises(UserError, match="do not increase at sample 50"):
            calibrate_imu_camera(data)

    def test_offset_beyond_the_search(self):
        rec = visual_inertial_recording(duration=10.0, seed=15, shift=0.15)
        with pytest.raises(NoResult, match="search's edge"):
            calibrate_imu_camera(_data(rec), max_shift=0.1)

    def test_too_short(self, recording):
        data = _data(recording)
        data.imu_times, data.gyro, data.accel = data.imu_times[:50], data.gyro[:50], data.accel[:50]
        with pytest.raises(UserError, match="too short"):
            calibrate_imu_camera(data)
