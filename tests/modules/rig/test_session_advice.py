"""What a rig's recording should capture next, and the verdict on a recording: weak links, small boards, image
corners, a board moving between exposures, intrinsics the rig moved, a joint fit that did not converge."""

from __future__ import annotations

import torch
from _cameras import cameras

from ccs_kornia.data.scenes.rig import render_rig
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.schur_lm import LMStatus
from ccs_kornia.modules.rig import RigSolver, rig_verdict
from ccs_kornia.modules.rig.rig_state import RigState
from ccs_kornia.modules.rig.session_advice import (
    SMALL_BOARD,
    board_fraction,
    session_advice,
    shared_frames,
)

D = torch.float64
K = torch.tensor([[600.0, 0, 330], [0, 605, 245], [0, 0, 1]], dtype=D)
R_RIG = exp_so3(torch.tensor([[0.0, 0, 0], [0.01, -0.12, 0.0]], dtype=D))
T_RIG = torch.tensor([[0.0, 0, 0], [-0.2, 0.01, 0.0]], dtype=D)


def rig(frames=12, seed=3, **kw):
    cams = [(K1K2, K, torch.tensor([-0.12, 0.03], dtype=D))] * 2
    return render_rig(cameras(cams, [(640, 480)] * 2), R_RIG, T_RIG, num_frames=frames, seed=seed, noise_px=0.1, **kw)


def advice_of(s, res=None, weight=None, disagreement=None, motion=None, moved=None):
    """session_advice of a rendered rig at its true poses (figures of the frames as given)."""
    F = s.corners.shape[1]
    used = s.valid.sum(-1) >= 6
    m = K1K2
    p = m.params_from(K[None], torch.tensor([[-0.12, 0.03]], dtype=D))[0]
    weight = torch.ones(F, dtype=D) if weight is None else weight
    state = RigState([m, m], [p[None], p[None]], s.R[None], s.T[None], exp_so3(s.board_rvec)[None],
                     s.board_tvec[None])
    return session_advice(["a", "b"], s.image_sizes, state, s.object_points, s.corners, s.valid, used,
                          torch.zeros(F, dtype=D) if disagreement is None else disagreement, weight,
                          torch.full((F,), float("nan"), dtype=D) if motion is None else motion,
                          shared_frames(used, weight), moved or [torch.zeros(6, dtype=D)] * 2, [False, False])


def test_shared_frames():
    used = torch.tensor([[True, True, False, True], [True, False, True, True]])
    w = torch.tensor([1.0, 1.0, 1.0, 0.25], dtype=D)
    s = shared_frames(used, w)
    assert s.shape == (2, 2) and torch.equal(s, s.T)
    assert s.tolist() == [[2.25, 1.25], [1.25, 2.25]]
    assert float(shared_frames(used, torch.full((4,), float("nan"), dtype=D)).abs().sum()) == 0.0


def test_board_fraction_shrinks_with_distance():
    s = rig()
    m = K1K2
    p = m.params_from(K[None], torch.tensor([[-0.12, 0.03]], dtype=D))[0]
    Rf, tf = exp_so3(s.board_rvec), s.board_tvec
    near = board_fraction(m, p, Rf, tf, s.object_points, (640, 480))
    far = board_fraction(m, p, Rf, 2.0 * tf, s.object_points, (640, 480))
    assert near.shape == (12,) and bool((near > 0).all()) and bool((near <= 1).all())
    assert bool((far < 0.3 * near).all()) and bool((far > 0.2 * near).all())  # twice as far: about a quarter


def test_advice_for_small_boards_and_image_corners():
    near = advice_of(rig(distance=(0.45, 0.6)))
    far = advice_of(rig(distance=(3.0, 4.0)))
    assert not any("closer" in line for line in near)
    closer = [line for line in far if line.startswith("bring the board closer to a and b")]
    assert closer, far
    corners = [line for line in far if "corners and edges" in line]
    assert corners and "outer rings" in corners[0]


def test_advice_for_weak_links_and_moving_boards():
    s = rig(frames=12)
    w = torch.ones(12, dtype=D)
    w[:9] = 0.05  # three frames carry the pair
    d = torch.where(w < 0.5, 2.0, 0.1).to(D)
    lines = advice_of(s, weight=w, disagreement=d, motion=torch.full((12,), 20.0, dtype=D))
    assert "show the board to a and b together: their link rests on 3.5 frames that one board pose explains" in lines
    slow = [line for line in lines if line.startswith("move the board slowly")]
    assert slow and "9 of the 12 frames" in slow[0] and "board moving" in slow[0]
    sync = advice_of(s, weight=w, disagreement=d, motion=torch.full((12,), 0.5, dtype=D))
    assert any(line.startswith("check the cameras' synchronisation") for line in sync)


def test_advice_for_moved_intrinsics():
    moved = [torch.tensor([4.5, 0, 0, 0, 0, 0], dtype=D), torch.zeros(6, dtype=D)]
    lines = advice_of(rig(), moved=moved)
    assert any(line.startswith("record views of a alone") and "4.5 sigma" in line for line in lines)


def test_solver_gives_advice_for_far_boards():
    s = rig(frames=14, distance=(3.0, 4.0))
    res = RigSolver(K1K2, folds=0)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.success and isinstance(res.advice, list)
    assert any(line.startswith("bring the board closer") for line in res.advice), res.advice
    assert SMALL_BOARD > 0


def test_verdict_of_an_unconverged_fit():
    z = torch.zeros(2, 2)
    args = (["a", "b"], [(640, 480)] * 2, torch.tensor([0.2, 0.3]), z, z + 0.2, torch.tensor([0.0, 0.1]),
            torch.tensor([0.0, 1e-4]), torch.tensor([0.0, 0.01]))
    assert rig_verdict(*args)[0] == "good"
    verdict, reasons = rig_verdict(*args, converged=False, iterations=100)
    assert verdict.startswith("not reliable: the joint fit stopped unconverged after 100 iterations")
    assert "the joint fit stopped unconverged after 100 iterations" in reasons


def test_verdict_of_moved_intrinsics():
    z = torch.zeros(2, 2)
    args = (["a", "b"], [(640, 480)] * 2, torch.tensor([0.2, 0.3]), z, z + 0.2, torch.tensor([0.0, 0.1]),
            torch.tensor([0.0, 1e-4]), torch.tensor([0.0, 0.01]))
    verdict, reasons = rig_verdict(*args, moved_sigma=[1.0, 5.0])
    assert verdict == "usable"
    assert reasons == ["b: the joint fit moved its intrinsics up to 5.0 sigma from its own calibration"]
    assert rig_verdict(*args, moved_sigma=[1.0, 2.9])[0] == "good"


def test_solver_verdict_says_unconverged():
    s = rig(frames=10)
    res = RigSolver(K1K2, folds=0, max_iters=1)(s.corners, s.valid, s.object_points, s.image_sizes)
    assert res.lm_status == LMStatus.MAX_ITERATIONS and not res.converged and res.verdict.startswith("not reliable")
    assert any("unconverged" in r for r in res.reasons)
