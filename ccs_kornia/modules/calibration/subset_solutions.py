"""The solved halves and folds of a cross-validation, kept for a second cross-validation of the same calibration.

The pipeline cross-validates a camera twice on the same corners: :class:`~.model_selection.ModelSelection` to choose
its model, then :func:`~.diagnostics.diagnose` for the verdict. The costly part of
:func:`~.diagnostics.cross_validation`, one solver call on the halves and the k-fold training sets of the views,
depends only on the solver, the corners (their mask, weights and object points), the image size, the number of folds
and the calibration it starts from; :class:`SubsetSolutions` keeps it from the first and gives it back to the second
when all of these are the same (the same solver object; tensors compared exactly, NaN equal to NaN). The subsets'
solve is most of the diagnostics' time (``docs/measurements.md``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch
from torch import nn

from ccs_kornia.geometry.camera import Camera

__all__ = ["SubsetSolutions", "solve_subsets"]


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        if not (isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor)):
            return False
        if a.shape != b.shape or a.dtype != b.dtype or a.device != b.device:
            return False
        return bool(((a == b) | (a.isnan() & b.isnan()) if a.is_floating_point() else a == b).all())
    if isinstance(a, (tuple, list)) or isinstance(b, (tuple, list)):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


class SubsetSolutions:
    """Solutions of :func:`~.diagnostics.cross_validation`'s subsets, by their inputs (at most ``size``, the latest).

    Example:
        >>> from ccs_kornia.modules.calibration.solver import CalibrationSolver
        >>> solver, x = CalibrationSolver(), torch.full((1, 4, 6, 2), float("nan"))
        >>> kept = SubsetSolutions()
        >>> kept.put(kept.key(solver, x, x[..., 0] > 0, x[0, 0], (640, 480), None, 5, None), "solved")
        >>> kept.get(kept.key(solver, x.clone(), x[..., 0] > 0, x[0, 0], (640, 480), None, 5, None))
        'solved'
        >>> kept.get(kept.key(solver, x.clone(), x[..., 0] > 0, x[0, 0], (640, 480), None, 4, None)) is None
        True
        >>> kept.latest()
        'solved'
    """

    def __init__(self, size: int = 8) -> None:
        self.size = int(size)
        self._entries: list[tuple[tuple, Any]] = []

    @staticmethod
    def key(solver: nn.Module, corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
            image_size: tuple[int, int], result: Any, folds: int, weights: torch.Tensor | None) -> tuple:
        """What the subsets' solve depends on (the calibration: every tensor of ``result`` and its cameras)."""

        def value(v: Any) -> Any:
            return (v.params, tuple(str(m) for m in v.models), v.image_sizes) if isinstance(v, Camera) else v

        fields = () if result is None else tuple(sorted(
            ((k, value(v)) for k, v in vars(result).items() if isinstance(v, (torch.Tensor, Camera))),
            key=lambda kv: kv[0]))
        return (solver, corners, valid, object_points, (int(image_size[0]), int(image_size[1])), int(folds), weights,
                fields)

    def get(self, key: tuple) -> Any:
        """The solution kept for ``key`` (``None`` if none)."""
        for kept, solution in reversed(self._entries):
            if kept[0] is key[0] and _same(kept[1:], key[1:]):
                return solution
        return None

    def latest(self) -> Any:
        """The solution kept last (``None`` if none)."""
        return self._entries[-1][1] if self._entries else None

    def put(self, key: tuple, solution: Any) -> None:
        """Keep ``solution`` for ``key`` (copies of its tensors, so later in-place changes cannot make it match)."""
        copy = tuple(x.clone() if isinstance(x, torch.Tensor) else x for x in key[1:7])
        fields = tuple((k, _copy(v)) for k, v in key[7])
        self._entries = [*self._entries, ((key[0], *copy, fields), solution)][-self.size:]


def _copy(v: Any) -> Any:
    if isinstance(v, torch.Tensor):
        return v.clone()
    return tuple(_copy(x) for x in v) if isinstance(v, tuple) else v


def solve_subsets(solver: nn.Module, corners, valid, obj, image_size, subsets, result=None, warm=None, weights=None):
    """One solver call for every (camera, subset): cameras (C * S) with the other views masked out.

    A fisheye solver starts the subsets marked in ``warm`` (S,) from ``result`` (the calibration of all the views):
    its focal-length hypotheses cost more than the rest of the solve. Only for the k-fold training sets: their
    optima lie next to the full one; the two halves start
    cold, since where a model is barely constrained (k1..k4 of a fisheye model on a narrow lens) where its LM ends
    depends on where it starts (``docs/measurements.md``)."""
    C, S, V = subsets.shape
    N = corners.shape[2]

    def rep(x: torch.Tensor) -> torch.Tensor:
        """(C, ...) -> (C * S, ...): each camera's tensor once per subset."""
        return x[:, None].expand(C, S, *x.shape[1:]).reshape(C * S, *x.shape[1:])

    c, v = rep(corners), (valid[:, None] & subsets[..., None]).reshape(C * S, V, N)
    o = obj if obj.dim() == 2 else rep(obj)
    kw = {} if weights is None else {"weights": rep(weights) * v}
    model = getattr(solver, "model", None)
    fisheye = getattr(model, "is_fisheye", False) and result is not None and all(m == model for m in result.camera.models)
    if warm is None or not fisheye or not bool(warm.any()):
        return solver(c, v, o, image_size, **kw)
    each = torch.arange(C, device=result.camera.device).repeat_interleave(S)
    initial = result.map_tensors(lambda x: rep(x) if x.dim() and x.shape[0] == C else x, lambda cam: cam[each])
    cold = ~warm.to(initial.camera.device).bool().repeat(C)
    params = initial.camera.params
    # no finite camera: the hypotheses
    params = torch.cat([torch.where(cold[:, None], float("nan"), params[:, :4]), params[:, 4:]], -1)
    initial = replace(initial, camera=initial.camera.with_params(params),
                      used=initial.used.bool() & subsets.reshape(C * S, V))
    return solver(c, v, o, image_size, initial=initial, **kw)
