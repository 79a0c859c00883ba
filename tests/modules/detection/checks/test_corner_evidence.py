"""CornerEvidence and its policy (decide_corners): every rule of the policy is switched on by one test here."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.checks.corner_evidence import (
    CornerEvidence,
    decide_corners,
    measure_corner_evidence,
)
from ccs_kornia.modules.detection.checks.hidden_corners import (
    HIDDEN_CONTRAST_FRACTION,
    UNCONFIRMED_CONTRAST_FRACTION,
)

N = 20  # a 5 x 4 board


def _board(square: int = 24):
    """A synthetic 5 x 4 (inner corners) chessboard on a grey margin and its corners in grid order."""
    cols, rows = 5, 4
    h, w = (rows + 3) * square, (cols + 3) * square
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    i, j = xx // square - 1, yy // square - 1
    inside = (i >= 0) & (i <= cols) & (j >= 0) & (j <= rows)
    img = torch.where(inside, ((i + j) % 2).float(), torch.full((h, w), 0.8))
    g = (torch.arange(cols) + 2.0) * square - 0.5, (torch.arange(rows) + 2.0) * square - 0.5
    pts = torch.stack(torch.meshgrid(*g, indexing="xy"), -1).reshape(1, -1, 2)
    return 0.1 + 0.8 * img[None, None], pts


def _evidence(contrast, predicted=(), ok=None, spans=True, batch=1):
    """Evidence of a 5 x 4 board: every corner seen and confirmed but ``predicted`` (unconfirmed unless in ``ok``)."""
    pred = torch.zeros(batch, N, dtype=torch.bool)
    pred[:, list(predicted)] = True
    saddle = ~pred
    if ok:
        saddle[:, list(ok)] = True
    rel = None if contrast is None else torch.as_tensor(contrast, dtype=torch.float64).expand(batch, N).clone()
    return CornerEvidence(torch.ones(batch, N, dtype=torch.bool), pred, saddle, rel, torch.full((batch,), spans))


def _contrast(**at):
    c = torch.ones(N, dtype=torch.float64)
    for k, v in at.items():
        c[int(k[1:])] = v
    return c


def test_measure_smoke_shapes_and_batch(device):
    img, pts = _board()
    img[..., 60:84, 84:108] = 1.0  # flatten a quarter square around corner 7
    img, pts = torch.cat([img, _board()[0]]).to(device), pts.expand(2, -1, -1).to(device)
    cells = torch.ones(2, N, dtype=torch.bool, device=device)
    none = torch.zeros_like(cells)
    ev = measure_corner_evidence(img, pts, cells, none, cells, cells, (5, 4))
    assert ev.contrast.shape == (2, N) and ev.spans_board.shape == (2,) and ev.unconfirmed.shape == (2, N)
    assert float(ev.contrast[0, 7]) < HIDDEN_CONTRAST_FRACTION and bool((ev.contrast[1] > 0.99).all())
    hidden, refusing = decide_corners(ev, (5, 4))
    assert hidden.tolist() == [[k == 7 for k in range(N)], [False] * N] and not bool(refusing.any())
    # the same board alone gives the same evidence
    one = measure_corner_evidence(img[:1], pts[:1], cells[:1], none[:1], cells[:1], cells[:1], (5, 4))
    torch.testing.assert_close(one.contrast, ev.contrast[:1])
    assert measure_corner_evidence(img, pts, cells, none, cells, cells, (5, 4), contrast=False).contrast is None


def test_a_flat_corner_is_hidden():
    hidden, refusing = decide_corners(_evidence(_contrast(c7=0.1)), (5, 4))
    assert hidden[0].nonzero().flatten().tolist() == [7] and not bool(refusing.any())


def test_an_unconfirmed_predicted_corner_refuses_its_board_where_the_checker_shows():
    hidden, refusing = decide_corners(_evidence(_contrast(), predicted=[12]), (5, 4))
    assert not bool(hidden.any()) and refusing[0].nonzero().flatten().tolist() == [12]


def test_an_unconfirmed_predicted_corner_is_hidden_where_the_checker_faded():
    c = 0.5 * (HIDDEN_CONTRAST_FRACTION + UNCONFIRMED_CONTRAST_FRACTION)
    hidden, refusing = decide_corners(_evidence(_contrast(c12=c), predicted=[12]), (5, 4))
    assert hidden[0].nonzero().flatten().tolist() == [12] and not bool(refusing.any())
    # a confirmed corner at that contrast is kept
    hidden, _ = decide_corners(_evidence(_contrast(c12=c), predicted=[12], ok=[12]), (5, 4))
    assert not bool(hidden.any())


def test_at_a_glare_rim_a_faded_confirmed_corner_is_hidden():
    c = 0.5 * (HIDDEN_CONTRAST_FRACTION + UNCONFIRMED_CONTRAST_FRACTION)
    hidden, _ = decide_corners(_evidence(_contrast(c7=0.0, c8=c)), (5, 4))  # 8 is next to 7
    assert hidden[0].nonzero().flatten().tolist() == [7, 8]
    hidden, _ = decide_corners(_evidence(_contrast(c7=0.0, c9=c)), (5, 4))  # 9 is not
    assert hidden[0].nonzero().flatten().tolist() == [7]


@pytest.mark.parametrize("spans", [True, False])
def test_at_a_glare_rim_an_unconfirmed_corner_is_excused_only_where_the_peaks_span_the_board(spans):
    hidden, refusing = decide_corners(_evidence(_contrast(c7=0.0), predicted=[8], spans=spans), (5, 4))
    assert bool(hidden[0, 8]) == spans and bool(refusing[0, 8]) == (not spans)


def test_without_contrast_nothing_is_hidden():
    hidden, refusing = decide_corners(_evidence(None, predicted=[3]), (5, 4))
    assert not bool(hidden.any()) and refusing[0].nonzero().flatten().tolist() == [3]


def test_boards_of_a_batch_are_decided_alike():
    ev = _evidence(_contrast(c7=0.0, c8=0.5), predicted=[8], batch=3)
    hidden, refusing = decide_corners(ev, (5, 4))
    assert hidden.shape == refusing.shape == (3, N) and bool((hidden == hidden[:1]).all())
