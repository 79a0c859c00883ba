"""Tests of the corner UNet."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from ccs_kornia.losses.heatmap_loss import HeatmapLoss
from ccs_kornia.modules.detection.learned.heatmap_unet import CornerUNet


def _num_params(net: torch.nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


class TestCornerUNet:
    def test_smoke_default_size(self) -> None:
        net = CornerUNet()
        # the shipped default must stay CPU sized (~0.5 M parameters)
        assert 400_000 < _num_params(net) < 600_000
        assert "base_channels=8" in repr(net)

    def test_device_and_dtype(self, device: torch.device, dtype: torch.dtype) -> None:
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4, depth=3).eval()
        x = torch.rand(2, 1, 33, 47, dtype=torch.float64)
        with torch.no_grad():
            ref = net.double()(x)
            y = net.to(device, dtype)(x.to(device, dtype))
        assert y.shape == (2, 1, 33, 47) and y.dtype == dtype and y.device.type == device.type
        torch.testing.assert_close(y.cpu().double(), ref, atol=1e-4, rtol=0)

    @pytest.mark.parametrize("size", [(61, 97), (16, 16), (1, 1), (33, 17)])
    def test_output_shape_odd_sizes(self, size: tuple[int, int]) -> None:
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4, depth=4).eval()
        x = torch.rand(3, 1, *size)
        with torch.no_grad():
            y = net(x)
        assert y.shape == (3, 1, *size)
        assert torch.isfinite(y).all()
        assert (y >= 0).all() and (y <= 1).all()

    def test_default_output_shape_and_initial_level(self) -> None:
        torch.manual_seed(0)
        net = CornerUNet().eval()
        with torch.no_grad():
            y = net(torch.rand(2, 1, 61, 97))
        assert y.shape == (2, 1, 61, 97)
        # the output bias starts the net near the all-background heatmap (sigmoid(-4) ~ 0.018)
        assert y.mean().item() < 0.1

    @pytest.mark.parametrize(
        "kwargs",
        [
            {"norm": "group"},
            {"norm": "none"},
            {"up_mode": "transposed"},
            {"depth": 2, "base_channels": 6},
            {"in_channels": 3},
        ],
    )
    def test_variants(self, kwargs: dict) -> None:
        torch.manual_seed(0)
        net = CornerUNet(**{"base_channels": 4, **kwargs}).eval()
        x = torch.rand(2, net.in_channels, 45, 50)
        with torch.no_grad():
            y = net(x)
        assert y.shape == (2, 1, 45, 50)
        assert (y >= 0).all() and (y <= 1).all()

    def test_logits_output(self) -> None:
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4, depth=2, out_activation="none").eval()
        with torch.no_grad():
            y = net(torch.rand(1, 1, 20, 20))
        # raw logits around the initial output bias, outside [0, 1]
        assert (y < 0).any()
        assert CornerUNet(out_activation=None).out_activation == "none"

    def test_batch_consistency(self) -> None:
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4).eval()
        x = torch.rand(3, 1, 37, 53)
        with torch.no_grad():
            batched = net(x)
            single = torch.cat([net(x[i : i + 1]) for i in range(3)])
        torch.testing.assert_close(batched, single, atol=1e-5, rtol=1e-5)

    def test_padding_is_cropped_back(self) -> None:
        # output pixel (x, y) is input pixel (x, y): the internal pad is right/bottom, edge-replicated
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4, depth=3).eval()
        x = torch.rand(1, 1, 21, 30)
        padded = F.pad(x, (0, 2, 0, 3), mode="replicate")  # 24 x 32, a multiple of 8
        with torch.no_grad():
            torch.testing.assert_close(net(x), net(padded)[..., :21, :30])

    def test_backward(self) -> None:
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4, depth=2).train()
        x = torch.rand(2, 1, 24, 24)
        loss = HeatmapLoss(pos_weight=5.0)(net(x), torch.rand(2, 1, 24, 24))
        loss.backward()
        grads = [p.grad for p in net.parameters()]
        assert all(g is not None and torch.isfinite(g).all() for g in grads)
        assert net.head.weight.grad.abs().sum() > 0

    def test_torch_compile(self) -> None:
        # fullgraph=True fails on any graph break; aot_eager traces forward through AOTAutograd without the slow
        # C++ code generation of inductor (checked by hand: inductor gives the same output to 1e-8)
        torch.manual_seed(0)
        net = CornerUNet(base_channels=4, depth=2).eval()
        x = torch.rand(2, 1, 21, 30)
        compiled = torch.compile(net, fullgraph=True, backend="aot_eager")
        with torch.no_grad():
            torch.testing.assert_close(compiled(x), net(x))

    def test_exceptions(self) -> None:
        net = CornerUNet(base_channels=4, depth=2)
        with pytest.raises(ValueError, match=r"image must be \(B, 1, H, W\), got \(1, 32, 32\)"):
            net(torch.rand(1, 32, 32))
        with pytest.raises(ValueError, match=r"image must be \(B, 1, H, W\), got \(1, 3, 32, 32\)"):
            net(torch.rand(1, 3, 32, 32))
        with pytest.raises(ValueError, match="norm"):
            CornerUNet(norm="layer")
        with pytest.raises(ValueError, match="out_activation"):
            CornerUNet(out_activation="relu")
        with pytest.raises(ValueError, match="up_mode"):
            CornerUNet(up_mode="nearest")
        with pytest.raises(ValueError, match="depth"):
            CornerUNet(depth=0)


def test_run_heatmap_in_tiles_equals_the_whole(monkeypatch):
    """Above ``tile_pixels`` the network runs in tiles with context on every side, aligned to its pooling grid: the
    output is the whole input's (checked with small tiles on an input of 3 x 3 tiles, uneven at the border)."""
    from ccs_kornia.modules.detection.learned import heatmap_unet
    from ccs_kornia.modules.detection.learned.heatmap_unet import run_heatmap

    torch.manual_seed(0)
    net = CornerUNet().eval()
    monkeypatch.setattr(heatmap_unet, "TILE_SIDE", 128)
    x = torch.rand(2, 1, 300, 340)
    with torch.inference_mode():
        whole = run_heatmap(net, x, tile_pixels=None)
        tiled = run_heatmap(net, x, tile_pixels=10_000)
    torch.testing.assert_close(tiled, whole, atol=1e-6, rtol=0)
    assert tiled.shape == (2, 1, 300, 340) and tiled.dtype == torch.float32


def test_run_heatmap_runs_a_large_batch_a_few_images_at_a_time(monkeypatch):
    """A batch of more pixels than ``tile_pixels`` runs in chunks of whole images (memory bounded): same heatmaps,
    and the network never sees more than the budget at once."""
    from ccs_kornia.modules.detection.learned.heatmap_unet import run_heatmap

    torch.manual_seed(0)
    net = CornerUNet().eval()
    x = torch.rand(5, 1, 64, 80)
    seen = []
    with torch.inference_mode():
        whole = run_heatmap(net, x, tile_pixels=None)
        hook = net.register_forward_pre_hook(lambda m, inp: seen.append(inp[0].shape[0]))
        chunked = run_heatmap(net, x, tile_pixels=2 * 64 * 80)
        hook.remove()
    torch.testing.assert_close(chunked, whole, atol=1e-6, rtol=0)  # float rounding of other batch shapes
    assert seen == [2, 2, 1]


def test_run_heatmap_runs_a_batch_above_batch_pixels_in_chunks_on_cpu():
    """On CPU a batch of more than ``batch_pixels`` pixels runs a few whole images at a time (its activations stay in
    the cache): the same heatmaps as in one call; ``None`` runs it whole."""
    from ccs_kornia.modules.detection.learned.heatmap_unet import run_heatmap

    torch.manual_seed(0)
    net = CornerUNet().eval()
    x = torch.rand(7, 1, 48, 64)
    seen = []
    with torch.inference_mode():
        hook = net.register_forward_pre_hook(lambda m, inp: seen.append(inp[0].shape[0]))
        whole = run_heatmap(net, x, batch_pixels=None)
        chunked = run_heatmap(net, x, batch_pixels=3 * 48 * 64 + 10)
        single = run_heatmap(net, x[:2], batch_pixels=10)  # fewer pixels than one image: one image at a time
        hook.remove()
    torch.testing.assert_close(chunked, whole, atol=1e-6, rtol=0)  # float rounding of other batch shapes
    torch.testing.assert_close(single, whole[:2], atol=1e-6, rtol=0)
    assert seen == [7, 3, 2, 2, 1, 1]  # as few chunks as allowed, as even as can be



@pytest.mark.parametrize("norm", ["batch", "none"])
def test_inference_splits_the_first_up_convolution_exactly(norm):
    """At inference on CPU each up level convolves the skip connection and the upsampled features separately and adds
    (no channels-last concatenation): the heatmap of the concatenating path (autograd on) up to float rounding."""
    torch.manual_seed(0)
    net = CornerUNet(norm=norm).eval()
    for m in net.modules():  # non-trivial normalisation statistics
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 1.5)
    x = torch.rand(2, 1, 45, 70).contiguous(memory_format=torch.channels_last)
    net = net.to(memory_format=torch.channels_last)
    with torch.enable_grad():
        concatenated = net(x).detach()
    with torch.inference_mode():
        split = net(x)
    torch.testing.assert_close(split, concatenated, atol=1e-6, rtol=0)
    assert not torch.equal(split, torch.zeros_like(split))
