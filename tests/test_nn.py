"""Networks of uavturb.nn: shapes, streaming GRU, torch phi against numpy phi."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from uavturb.nn import Decoder, DepthEncoder, HeightHead, phi_alpha_beta
from uavturb.physics import ground_effect as ge


@pytest.mark.parametrize("size", [128, 32, 48])
def test_encoder_embeds_any_size(size):
    enc = DepthEncoder()
    depth = torch.rand(3, 1, size, size) * 12.0
    depth[0, 0, :5] = 0.0
    depth[1, 0, 0, 0] = float("nan")
    e = enc(depth)
    assert e.shape == (3, 50)
    assert torch.isfinite(e).all()
    assert enc.n_features == 64


def test_encoder_paper_layers():
    enc = DepthEncoder()
    convs = [m for m in enc.convs if isinstance(m, torch.nn.Conv2d)]
    assert [c.out_channels for c in convs] == [16, 32, 64, 64, 32, 4]
    assert [c.kernel_size[0] for c in convs] == [7, 3, 3, 3, 3, 3]
    assert sum(isinstance(m, torch.nn.BatchNorm2d) for m in enc.convs) == 6
    # 128x128 -> 4x4x4 before the (then identity) pooling
    assert enc.convs(torch.zeros(1, 1, 128, 128)).shape == (1, 4, 4, 4)


@pytest.mark.parametrize("size", [(128, 128), (32, 32), (30, 40)])
def test_decoder_outputs(size):
    e = torch.randn(2, 50)
    n = Decoder("normals")(e, size=size)
    assert n.shape == (2, 3, *size)
    assert torch.allclose(n.norm(dim=1), torch.ones(2, *size), atol=1e-5)
    d = Decoder("depth")(e, size=size)
    assert d.shape == (2, 1, *size) and (d >= 0).all() and (d <= 1).all()


@pytest.mark.parametrize("use_gru", [True, False])
def test_height_head_streaming_equals_full(use_gru):
    torch.manual_seed(0)
    head = HeightHead(use_gru=use_gru).eval()
    e = torch.randn(4, 10, 50)
    d_full, h_full = head(e)
    assert d_full.shape == (4, 10) and (d_full > 0).all()
    h = None
    parts = []
    for k in range(0, 10, 3):
        d_k, h = head(e[:, k:k + 3], h)
        parts.append(d_k)
    assert torch.allclose(torch.cat(parts, 1), d_full, atol=1e-6)
    if use_gru:
        assert h_full.shape == (2, 4, 50)
        assert torch.allclose(h, h_full, atol=1e-6)
    else:
        assert h is None and h_full is None


def test_no_gru_head_is_per_frame():
    head = HeightHead(use_gru=False).eval()
    e = torch.randn(2, 5, 50)
    d, _ = head(e)
    d_rev, _ = head(e.flip(1))
    assert torch.allclose(d, d_rev.flip(1))


def test_phi_torch_matches_numpy():
    rng = np.random.default_rng(0)
    alpha, beta = 6.8125e-11, 1.25e-5
    d = np.concatenate([rng.uniform(0.0, 3.0, 500), [np.sqrt(beta), np.sqrt(beta) * 0.5, 0.0035, 1e-3, np.inf]])
    S = rng.uniform(5e4, 1.5e5, d.size)
    ref = ge.phi_alpha_beta(d, S, alpha, beta)
    got = phi_alpha_beta(torch.tensor(d), torch.tensor(S), alpha, beta).numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=0)
    # and the Cheeseman-Bennett form with the paper's quadrotor: alpha = k_T beta, beta = mu r^2 / 16
    np.testing.assert_allclose(got[:500], ge.phi(d[:500], 5.45e-6 * S[:500], 2.0, 0.01), rtol=1e-6)
    # float32 away from the pole
    d32 = torch.tensor(rng.uniform(0.05, 3.0, 200), dtype=torch.float32)
    S32 = torch.tensor(rng.uniform(5e4, 1.5e5, 200), dtype=torch.float32)
    np.testing.assert_allclose(phi_alpha_beta(d32, S32, alpha, beta).numpy(),
                               ge.phi_alpha_beta(d32.double().numpy(), S32.double().numpy(), alpha, beta), rtol=1e-5)


def test_phi_gradient_finite_at_clip():
    d = torch.tensor([0.001, 0.1, 1.0], requires_grad=True)
    f = phi_alpha_beta(d, torch.full((3,), 9e4), 6.8125e-11, 1.25e-5)
    f.sum().backward()
    assert torch.isfinite(d.grad).all() and d.grad[0] == 0 and (d.grad[1:] < 0).all()


def test_phi_slope_is_the_laws_derivative_and_zero_where_clipped():
    """The slope equals autograd's derivative of the law (and a finite difference), 0 where the paper's
    clip holds the law constant and where there is no surface below."""
    from uavturb.nn import phi_alpha_beta_slope

    alpha, beta = 8.54858e-6 * 1.25e-3, 1.25e-3  # the hexarotor, mu = 2, r = 0.1 m
    d = torch.tensor([0.02, 0.16, 0.25, 0.355, 1.0, float("inf")], dtype=torch.float64, requires_grad=True)
    S = torch.full((6,), 6 * 413.0**2, dtype=torch.float64)
    phi_alpha_beta(d, S, alpha, beta).sum().backward()
    slope = phi_alpha_beta_slope(d.detach(), S, alpha, beta)
    torch.testing.assert_close(slope[:5], d.grad[:5])
    assert slope[0] == 0 and slope[5] == 0  # clipped (d^2 <= beta); no surface
    # known answer at 0.16 m: -2 alpha S d / (d^2 - beta)^2
    assert float(slope[1]) == pytest.approx(-2 * alpha * 6 * 413.0**2 * 0.16 / (0.16**2 - beta) ** 2, rel=1e-12)
    h = 1e-6
    fd = (phi_alpha_beta(torch.tensor(0.25 + h, dtype=torch.float64), S[:1], alpha, beta)
          - phi_alpha_beta(torch.tensor(0.25 - h, dtype=torch.float64), S[:1], alpha, beta)) / (2 * h)
    assert float(slope[2]) == pytest.approx(float(fd), rel=1e-6)


def test_encoder_on_a_one_pixel_map_gives_finite_bf16_gradients():
    """16 px images reach the fifth (stride-2) convolution as a 1x1 map, where oneDNN's bfloat16 weight
    gradient is NaN about a quarter of the time on AMX CPUs: the encoder runs such a convolution with stride 1,
    the same output to the bit, and its gradients stay finite under bf16 autocast."""
    torch.manual_seed(0)
    enc = DepthEncoder()
    x = torch.rand(8, 1, 16, 16) * 5.0
    plain = enc.mlp(enc.pool(enc.convs(x / enc.max_depth)).flatten(1))
    assert torch.equal(enc(x), plain)
    for trial in range(20):
        enc.zero_grad()
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = enc(torch.rand(8, 1, 16, 16) * (1 + trial % 5))
        (out.float() * torch.randn(out.shape)).sum().backward()
        assert all(torch.isfinite(p.grad).all() for p in enc.parameters() if p.grad is not None), trial
