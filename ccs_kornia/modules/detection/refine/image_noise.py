r"""How noisy an image is against a board's contrast: where the saddle fit needs a wider smoothing.

The saddle fit smooths the image around a corner (``smooth_sigma``) before it takes the Hessian; the default suits the
photographs a camera gives in good light, whose noise is a few per cent of the board's contrast at most (the shared
real sets as taken, reduced x0.4 or JPEG-compressed too: 0.1-2.5 %). A board photographed in the dark sits at 7-29 %
(the same photographs darkened x0.12 with Gaussian noise or as Poisson photo-electrons): there the Hessian of a low-contrast corner is the noise's, and the fit
finds no saddle where the board plainly has one. :func:`noise_sigma` measures the noise (Immerkær's estimator: the
mean absolute response of a filter that cancels any locally planar image, so edges weigh little),
:func:`noise_to_contrast` divides it by the board's contrast measured on its edges
(:func:`~ccs_kornia.modules.detection.refine.patch_refine.edge_blur`), and :data:`NOISY` is the ratio above which a
board counts as noisy.

Example:
    >>> g = torch.Generator().manual_seed(0)
    >>> img = torch.full((1, 1, 64, 64), 0.5) + 0.05 * torch.randn(1, 1, 64, 64, generator=g)
    >>> round(float(noise_sigma(img)), 2)
    0.05
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ccs_kornia.modules.detection.refine.patch_refine import edge_blur
from ccs_kornia.runtime.checks import check_grey_images

__all__ = ["NOISY", "noise_sigma", "noise_to_contrast"]

#: the noise-to-contrast ratio above which a board counts as noisy: the shared real photographs, as taken (blurred,
#: reduced or compressed too), are at 0.025 or less; darkened x0.12 with noise (Gaussian or shot noise) at 0.070 or more
NOISY = 0.04

# Immerkær's filter: the difference of two Laplacians, zero on any planar patch
_KERNEL = torch.tensor([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])


def noise_sigma(images: torch.Tensor) -> torch.Tensor:
    r"""Standard deviation of the images' additive noise, :math:`(B,)`, in the images' units.

    Immerkær's estimator (J. Immerkær, "Fast noise variance estimation", CVIU 1996): :math:`\sigma = \sqrt{\pi/2}
    \,/\, 6 \cdot \mathrm{mean}\, |I * N|` with :math:`N` the difference of two Laplacians; exact for white Gaussian
    noise on a planar image, a little high on images with many sharp edges.

    Args:
        images: :math:`(B, 1, H, W)` grey images (at least 8 x 8, as every detection stage's).

    Returns:
        :math:`(B,)` float32 noise sigma.

    Example:
        >>> noise_sigma(torch.ones(2, 1, 8, 8)).tolist()
        [0.0, 0.0]
    """
    check_grey_images(images)
    response = F.conv2d(images.float(), _KERNEL.to(images.device)[None, None])
    return response.abs().mean((1, 2, 3)) * (math.sqrt(0.5 * math.pi) / 6.0)


def noise_to_contrast(images: torch.Tensor, corners: torch.Tensor, board_size: tuple[int, int]) -> torch.Tensor:
    r"""The images' noise over the contrast of each found board's edges, :math:`(B,)` (compare with :data:`NOISY`).

    Args:
        images: :math:`(B, 1, H, W)` grey images.
        corners: :math:`(B, N, 2)` complete boards in grid order, ``N = cols * rows``.
        board_size: ``(cols, rows)``.

    Returns:
        :math:`(B,)` float32 ratio (NaN where no edge of the board could be measured).

    Example:
        >>> img = torch.zeros(1, 1, 96, 128)
        >>> for i in range(4):
        ...     for j in range(3):
        ...         img[..., 32 * j:32 * j + 32, 32 * i:32 * i + 32] = float((i + j) % 2)
        >>> pts = torch.tensor([[[32.0 * i - 0.5, 32.0 * j - 0.5] for j in (1, 2) for i in (1, 2, 3)]])
        >>> noisy = img + 0.1 * torch.randn(img.shape, generator=torch.Generator().manual_seed(0))
        >>> float(noise_to_contrast(img, pts, (3, 2))) < NOISY < float(noise_to_contrast(noisy, pts, (3, 2)))
        True
    """
    _, contrast = edge_blur(images, corners, board_size, return_contrast=True)
    return noise_sigma(images) / contrast.clamp_min(1e-6)
