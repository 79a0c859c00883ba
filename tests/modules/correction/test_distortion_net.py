"""Tests of the distortion-correction CNN."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.correction.distortion_net import (
    CORRECTION_NODES,
    DistortionNet,
    correction_from_node_values,
    letterbox,
)

IDENTITY = torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def small_net() -> DistortionNet:
    torch.manual_seed(0)
    return DistortionNet(base_channels=4, input_size=64, hidden=(32, 16)).eval()


@pytest.mark.parametrize("shape", [(2, 1, 48, 64), (1, 1, 64, 48), (3, 1, 50, 50), (1, 3, 30, 90), (1, 1, 480, 640)])
def test_shapes_any_size_untrained_is_identity(small_net, shape):
    with torch.no_grad():
        out = small_net(torch.rand(*shape))
    assert out.shape == (shape[0], 5)
    torch.testing.assert_close(out, IDENTITY.expand(shape[0], 5))


def test_device_and_input_dtype(device, dtype):
    # the network runs in float32 (its input is converted), any input dtype on any device gives the same correction
    torch.manual_seed(0)
    net = DistortionNet(base_channels=4, input_size=64, hidden=(32, 16)).eval()
    with torch.no_grad():
        net.head[-1].weight.normal_(0, 0.1)
    x = torch.rand(2, 1, 48, 64)
    with torch.no_grad():
        ref = net(x)
        out = net.to(device)(x.to(device, dtype))
    assert out.shape == (2, 5) and out.device.type == device.type
    torch.testing.assert_close(out.cpu(), ref, atol=1e-5, rtol=1e-5)


def test_preprocess_channels_and_standardisation(small_net):
    x = small_net.preprocess(0.2 + 0.5 * torch.rand(2, 1, 40, 64))
    assert x.shape == (2, 4, 64, 64)
    mask = x[:, 1]
    assert mask[:, 32, 32].eq(1).all() and mask[:, 0, 32].lt(0.01).all()  # top rows are padding
    real = x[:, 0][mask > 0.99]
    assert abs(float(real.mean())) < 0.1 and abs(float(real.std()) - 1) < 0.2
    torch.testing.assert_close(x[0, 2, 0, [0, -1]], torch.tensor([-0.5, 0.5]))  # x coordinate channel
    torch.testing.assert_close(x[0, 3, [0, -1], 0], torch.tensor([-0.5, 0.5]))  # y coordinate channel


def test_preprocess_standardises_with_the_images_mean_and_std(small_net):
    """The standardisation (from the sum and the sum of squares) is ``torch.std_mean``'s within float rounding, also for
    a flat image (where the 1e-3 in the denominator keeps it finite)."""
    images = torch.cat([0.2 + 0.5 * torch.rand(2, 1, 40, 64), torch.full((1, 1, 40, 64), 0.7)])
    std, mean = torch.std_mean(images, dim=(-1, -2), keepdim=True)
    box, mask = letterbox(images, 64)
    expected = (box - mean * mask) / (std + 1e-3)
    got = small_net.preprocess(images)[:, :1]
    torch.testing.assert_close(got[:2], expected[:2], atol=2e-5, rtol=1e-5)
    # the flat image: zero up to its mean's rounding, amplified by 1 / 1e-3
    assert got[2].abs().max() < 1e-3 and expected[2].abs().max() < 1e-3


def test_letterbox_keeps_aspect_and_centre():
    img = torch.zeros(1, 1, 30, 60)
    img[..., 13:17, 28:32] = 1.0  # a blob at the image centre
    out, mask = letterbox(img, 60)
    assert out.shape == (1, 1, 60, 60)
    assert mask[0, 0, :, 30].sum() == 30 and mask[0, 0, 15:45].eq(1).all()
    ys, xs = torch.nonzero(out[0, 0] > 0.5, as_tuple=True)
    assert float(ys.float().mean()) == pytest.approx(29.5) and float(xs.float().mean()) == pytest.approx(29.5)
    small, _ = letterbox(img, 20)
    assert small.shape == (1, 1, 20, 20)
    with pytest.raises(ValueError):
        letterbox(torch.rand(30, 60), 20)


@pytest.mark.parametrize("size", [(480, 640), (960, 1280), (300, 200)])
def test_letterbox_is_kornias_antialiased_resize_of_the_padded_square(size):
    # the banded products must give what kornia gives on the materialised square (dense: 1e-7 apart as well)
    import torch.nn.functional as F
    from kornia.geometry.transform import resize

    h, w = size
    img = torch.rand(2, 1, h, w, generator=torch.Generator().manual_seed(3))
    side = max(h, w)
    left, top = (side - w) // 2, (side - h) // 2
    square = F.pad(img, (left, side - w - left, top, side - h - top))
    out, _ = letterbox(img, 256)
    assert torch.allclose(out, resize(square, (256, 256), antialias=True), atol=1e-6)


def test_node_parameterisation_round_trip():
    torch.manual_seed(1)
    values = 1 + 0.3 * torch.rand(4, 5, dtype=torch.float64)
    c = correction_from_node_values(values)
    r = torch.tensor(CORRECTION_NODES, dtype=torch.float64)
    f = sum(c[:, p : p + 1] * r**p for p in range(5))
    torch.testing.assert_close(f, values)
    assert max(CORRECTION_NODES) > 0.7071 * 0.95  # nodes cover the radius of a square image's corner
    with pytest.raises(ValueError):
        correction_from_node_values(torch.ones(2, 4))


def test_output_scale_moves_node_values():
    net = DistortionNet(base_channels=4, input_size=32, hidden=(8, 8), output_scale=0.25).eval()
    with torch.no_grad():
        net.head[-1].bias.copy_(torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0]))
        coeffs = net(torch.rand(1, 1, 32, 32)).double()
        nodes = net.node_values(torch.rand(1, 1, 32, 32))
    torch.testing.assert_close(nodes, torch.tensor([[1.0, 1.0, 1.25, 1.0, 1.0]]))
    r = torch.tensor(CORRECTION_NODES, dtype=torch.float64)
    f = sum(coeffs[:, p : p + 1] * r**p for p in range(5))
    torch.testing.assert_close(f, nodes.double(), atol=1e-4, rtol=0)


def test_gradients_reach_the_network():
    net = DistortionNet(base_channels=4, input_size=32, hidden=(8, 8)).train()
    out = net(torch.rand(4, 1, 24, 32))
    (out[:, 2] * 3 + out[:, 0]).sum().backward()
    assert net.head[-1].weight.grad.abs().sum() > 0  # zero-initialised last layer still learns
    # once the last layer is non-zero, the encoder gets gradients too
    with torch.no_grad():
        net.head[-1].weight.normal_(0, 0.1)
    net.zero_grad()
    net(torch.rand(4, 1, 24, 32)).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.encoder.parameters())


def test_batch_independent_in_eval(small_net):
    net = DistortionNet(base_channels=4, input_size=64, hidden=(32, 16))
    with torch.no_grad():
        net.head[-1].weight.normal_(0, 0.1)
    net.eval()
    x = torch.rand(3, 1, 48, 64)
    with torch.no_grad():
        torch.testing.assert_close(net(x)[1:2], net(x[1:2]), atol=1e-5, rtol=1e-5)


def test_export_round_trip(tmp_path):
    net = DistortionNet(base_channels=4, input_size=32, hidden=(8, 8), norm="group")
    with torch.no_grad():
        net.head[-1].weight.normal_(0, 0.1)
    payload = {"kind": "DistortionNet", "config": net.config, "state_dict": net.state_dict()}
    torch.save(payload, tmp_path / "w.pt")
    loaded = DistortionNet.from_export(tmp_path / "w.pt")
    x = torch.rand(2, 1, 24, 32)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), net.eval()(x))
    with pytest.raises(ValueError, match="DistortionNet"):
        DistortionNet.from_export({"kind": "CornerUNet", "config": {}, "state_dict": {}})


def test_default_size():
    # its CPU speed is measured by ccs_kornia/bench/micro/bench_distortion_net.py
    net = DistortionNet().eval()
    n = net.num_parameters()
    assert 0.5e6 < n < 2e6, n
    with torch.no_grad():
        assert net(torch.rand(1, 1, 480, 640)).shape == (1, 5)


def test_exceptions():
    with pytest.raises(ValueError, match="norm"):
        DistortionNet(norm="layer")
    with pytest.raises(ValueError, match="input_size"):
        DistortionNet(input_size=16)
    with pytest.raises(ValueError, match="hidden"):
        DistortionNet(hidden=(8,))
    net = DistortionNet(base_channels=4, input_size=32, hidden=(8, 8))
    with pytest.raises(ValueError, match="images"):
        net(torch.rand(1, 2, 32, 32))
    with pytest.raises(ValueError, match="images"):
        net(torch.rand(32, 32))
