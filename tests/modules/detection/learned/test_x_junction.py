"""x_junction_mask: the circle test of heatmap peaks."""

from __future__ import annotations

import torch

from ccs_kornia.modules.detection.learned.x_junction import x_junction_mask

SQ, MARGIN, OX, OY = 20, 6, 30, 30  # squares, white board margin, board origin (px)


def _board_on_dark(cols: int = 4, rows: int = 3):
    """A ``cols x rows``-square board with a thin white margin on a dark background, its inner corners, and the points
    where the edges between its outer squares meet its outer edge (L-junctions with a margin beyond)."""
    h, w = OY * 2 + rows * SQ, OX * 2 + cols * SQ
    img = torch.full((h, w), 0.05)
    img[OY - MARGIN:OY + rows * SQ + MARGIN, OX - MARGIN:OX + cols * SQ + MARGIN] = 0.95
    for j in range(rows):
        for i in range(cols):
            if (i + j) % 2 == 0:
                img[OY + j * SQ:OY + (j + 1) * SQ, OX + i * SQ:OX + (i + 1) * SQ] = 0.05
    inner = [(OX + i * SQ - 0.5, OY + j * SQ - 0.5) for j in range(1, rows) for i in range(1, cols)]
    edge = [(OX + i * SQ - 0.5, OY + rows * SQ - 0.5) for i in range(1, cols)]
    return img[None, None], torch.tensor(inner), torch.tensor(edge)


def test_inner_corners_kept_and_shapes():
    img, inner, _ = _board_on_dark()
    keep = x_junction_mask(img, inner[None], torch.ones(1, len(inner), dtype=torch.bool))
    assert keep.shape == (1, len(inner)) and keep.dtype == torch.bool and bool(keep.all())


def test_the_outer_edge_against_a_dark_background_is_no_corner():
    """From afar (the outer circle) the outer squares, the thin margin and the dark background cross the mean four
    times like a corner; the inner circle stays on the board and the margin and sees the L-junction it is."""
    img, inner, edge = _board_on_dark()
    pts = torch.cat([inner, edge])[None]
    keep = x_junction_mask(img, pts, torch.ones(1, pts.shape[1], dtype=torch.bool))
    assert keep[0, :len(inner)].all() and not keep[0, len(inner):].any()


def test_flat_and_masked_points_are_refused_and_batches_agree():
    img, inner, edge = _board_on_dark()
    pts = torch.cat([inner, edge, torch.tensor([[5.0, 5.0]])])[None]  # a point on the flat background
    mask = torch.ones(1, pts.shape[1], dtype=torch.bool)
    one = x_junction_mask(img, pts, mask)
    assert not bool(one[0, -1])
    masked = mask.clone()
    masked[0, 0] = False
    assert not bool(x_junction_mask(img, pts, masked)[0, 0])
    two = x_junction_mask(img.expand(2, -1, -1, -1), pts.expand(2, -1, -1), torch.cat([mask, masked]))
    assert torch.equal(two[0], one[0]) and torch.equal(two[1], x_junction_mask(img, pts, masked)[0])


def test_no_candidates():
    img, inner, _ = _board_on_dark()
    out = x_junction_mask(img, inner[None], torch.zeros(1, len(inner), dtype=torch.bool))
    assert not bool(out.any())
