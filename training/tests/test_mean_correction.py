"""model.MeanCorrection, the PyTorch mirror of the engine's mean correction (config
`mean_correction = "tiles"`), against the numpy probe it was chosen with (ssr.mean_probe,
whose output the engine reproduced on val to the last digit)."""

import numpy as np
import pytest
import torch

from ssr.mean_probe import block_sums, tile_factors
from ssr.model import MEAN_EPS, MEAN_HI, MEAN_LO, MEAN_RING, MEAN_TILE, MEAN_TILES, MeanCorrection, SSRConfig, mean_correction_of


def frame(rng, h, w, t, background):
    mask = np.zeros((h, w, 1))
    mask[t % 2 :: 2, (t // 2) % 2 :: 2] = 1.0
    color = rng.gamma(0.5, 2.0, size=(h, w, 3)) * np.where(np.arange(w) < 20, 6.0, 1.0)[None, :, None]
    f = {"color": color, "mask": mask}
    if background:
        cov = rng.choice([0.0, 0.5, 1.0], size=(h, w, 1))
        f["coverage"] = cov
        f["background"] = 0.3 * cov * np.ones((1, 1, 3))
    return f


def torch_frame(f):
    return {k: torch.from_numpy(v.transpose(2, 0, 1)[None].copy()) for k, v in f.items()}


@pytest.mark.parametrize("background", [False, True])
@pytest.mark.parametrize("option", ["tiles", "tiles16"])
def test_mean_correction_matches_the_probe(background, option):
    rng = np.random.default_rng(3)
    h, w = 40, 72  # partial tiles on both axes
    mc = mean_correction_of(SSRConfig(mean_correction=option))
    tile = MEAN_TILES[option]
    assert mc.tile == tile
    ring = []
    clamped = between = 0
    for t in range(7):
        if t == 5:
            mc.reset()
            ring = []
        f = frame(rng, h, w, t, background)
        out = rng.gamma(1.0, 1.0, size=(h, w, 3))
        bg = f.get("background", np.zeros((h, w, 3)))
        cov = f.get("coverage", np.zeros((h, w, 1)))
        part = (1 - cov) * out
        ring = (ring + [(block_sums((f["color"] - bg) * f["mask"], tile), block_sums(part * f["mask"], tile))])[-MEAN_RING:]
        fac, log_c = tile_factors(sum(s for s, _ in ring), sum(r for _, r in ring), h, w, tile,
                                  lo=MEAN_LO, hi=MEAN_HI, eps=MEAN_EPS)
        c = np.exp(log_c)
        clamped += int(np.isclose(c, MEAN_LO).sum() + np.isclose(c, MEAN_HI).sum())
        between += int(((c > MEAN_LO + 1e-6) & (c < MEAN_HI - 1e-6)).sum())
        want = bg + part * fac
        got = mc(torch.from_numpy(out.transpose(2, 0, 1)[None].copy()), torch_frame(f))
        assert np.allclose(got[0].numpy().transpose(1, 2, 0), want, rtol=1e-9, atol=1e-9), t
    assert clamped > 0 and between > 0


def test_mean_correction_is_differentiable_and_follows_the_samples():
    rng = np.random.default_rng(4)
    h, w = 64, 64
    f = torch_frame(frame(rng, h, w, 0, False))
    out = torch.full((1, 3, h, w), 1.0, dtype=torch.float64, requires_grad=True)
    got = MeanCorrection()(out, f)
    got.sum().backward()
    assert out.grad is not None and torch.isfinite(out.grad).all()
    # A uniform output within the clamp's reach comes out at the samples' tile means.
    f["color"] = torch.full_like(f["color"], 1.25)
    got = MeanCorrection()(out.detach(), f)
    assert torch.allclose(got, torch.full_like(got, 1.25))


def test_mean_correction_of_each_config_value():
    assert mean_correction_of(SSRConfig(mean_correction="none")) is None
    assert mean_correction_of(SSRConfig(mean_correction="tiles")).tile == MEAN_TILE == 32
    assert mean_correction_of(SSRConfig(mean_correction="tiles16")).tile == 16
    assert type(mean_correction_of(SSRConfig(mean_correction="atrous"))).__name__ == "AtrousMeanCorrection"
    with pytest.raises(ValueError, match="mean_correction"):
        SSRConfig(mean_correction="tiles8")


def atrous_factors_naive(s, r, normal, depth):
    """The `"atrous"` factors [h, w, 3] by a plain per-pixel loop in float64 (taps outside the
    frame left out), the expectation AtrousMeanCorrection and the engine's mean_atrous are
    held to."""
    from ssr.model import ATROUS_DEPTH_SIGMA, ATROUS_EPS, ATROUS_LEVELS, ATROUS_NORMAL_SQUARINGS
    h, w = s.shape[:2]
    x = np.concatenate([s, r], axis=2)
    taps = [1 / 16, 1 / 4, 3 / 8, 1 / 4, 1 / 16]
    for level in range(ATROUS_LEVELS):
        step = 2 ** level
        nxt = np.zeros_like(x)
        for py in range(h):
            for px in range(w):
                acc, wsum = np.zeros(6), 0.0
                for j in range(5):
                    for i in range(5):
                        qy, qx = py + (j - 2) * step, px + (i - 2) * step
                        if not (0 <= qy < h and 0 <= qx < w):
                            continue
                        c = max(float(normal[py, px] @ normal[qy, qx]), 0.0) ** (2 ** ATROUS_NORMAL_SQUARINGS)
                        z, zq = depth[py, px, 0], depth[qy, qx, 0]
                        wt = taps[j] * taps[i] * c * np.exp(-abs(z - zq) / max(z, zq, 1e-4) / ATROUS_DEPTH_SIGMA)
                        acc += wt * x[qy, qx]
                        wsum += wt
                nxt[py, px] = acc / max(wsum, 1e-12)
        x = nxt
    return np.clip((x[..., :3] + ATROUS_EPS) / (x[..., 3:] + ATROUS_EPS), MEAN_LO, MEAN_HI)


def warp_naive(x, motion):
    """Backward bilinear warp [h, w, c] at the pixel centre plus `motion` [h, w, 2] by a plain
    loop (taps clamped at the edges; a position outside the frame gives 0)."""
    h, w = x.shape[:2]
    out = np.zeros_like(x)
    for py in range(h):
        for px in range(w):
            qx, qy = px + 0.5 + motion[py, px, 0], py + 0.5 + motion[py, px, 1]
            if not (0 <= qx < w and 0 <= qy < h):
                continue
            sx, sy = qx - 0.5, qy - 0.5
            fx, fy = np.floor(sx), np.floor(sy)
            tx, ty = sx - fx, sy - fy
            x0, x1 = int(np.clip(fx, 0, w - 1)), int(np.clip(fx + 1, 0, w - 1))
            y0, y1 = int(np.clip(fy, 0, h - 1)), int(np.clip(fy + 1, 0, h - 1))
            top = x[y0, x0] * (1 - tx) + x[y0, x1] * tx
            bottom = x[y1, x0] * (1 - tx) + x[y1, x1] * tx
            out[py, px] = top * (1 - ty) + bottom * ty
    return out


@pytest.mark.parametrize("background", [False, True])
def test_atrous_mean_correction_matches_a_per_pixel_loop(background):
    """Config `mean_correction = "atrous"`: each frame's per-pixel samples and reconstruction
    plus the last frame's sums warped along the motion times ATROUS_DECAY, filtered by the
    edge-aware a-trous filter of this frame's normals and depths (two surfaces meeting at
    x = 11 with jittered normals, depth steps between them; random motion, some of it off the
    frame), against the plain loops above; a reset forgets the sums."""
    from ssr.model import ATROUS_DECAY, AtrousMeanCorrection
    rng = np.random.default_rng(5)
    h, w = 18, 26
    mc = mean_correction_of(SSRConfig(mean_correction="atrous"))
    assert isinstance(mc, AtrousMeanCorrection)
    history = None
    clamped = between = 0
    for t in range(6):
        if t == 5:
            mc.reset()
            history = None
        f = frame(rng, h, w, t, background)
        f["motion"] = rng.uniform(-1.5, 1.5, size=(h, w, 2))
        left = (np.arange(w) < 11)[None, :, None]
        n = np.where(left, [0.0, 0.0, 1.0], [0.8, 0.0, 0.6]) + 0.2 * rng.normal(size=(h, w, 3))
        f["normal"] = n / np.linalg.norm(n, axis=2, keepdims=True)
        f["depth"] = np.where(left, 0.2, 0.5) + 0.01 * rng.random((h, w, 1))
        # Reconstructions near the samples' level (the frame's are 6x brighter left of x = 20),
        # so that some factors fall between the clamps.
        out = rng.gamma(4.0, 0.25, size=(h, w, 3)) * np.where(np.arange(w) < 20, 6.0, 1.0)[None, :, None]
        bg = f.get("background", np.zeros((h, w, 3)))
        cov = f.get("coverage", np.zeros((h, w, 1)))
        part = (1 - cov) * out
        sums = np.concatenate([(f["color"] - bg) * f["mask"], part * f["mask"]], axis=2)
        if history is not None:
            sums = sums + ATROUS_DECAY * warp_naive(history, f["motion"])
        history = sums
        fac = atrous_factors_naive(sums[..., :3], sums[..., 3:], f["normal"], f["depth"])
        clamped += int(np.isclose(fac, MEAN_LO).sum() + np.isclose(fac, MEAN_HI).sum())
        between += int(((fac > MEAN_LO + 1e-6) & (fac < MEAN_HI - 1e-6)).sum())
        want = bg + part * fac
        got = mc(torch.from_numpy(out.transpose(2, 0, 1)[None].copy()), torch_frame(f))
        assert np.allclose(got[0].numpy().transpose(1, 2, 0), want, rtol=1e-9, atol=1e-9), t
    assert clamped > 0 and between > 0


def test_atrous_filter_gradient_is_autograd_of_the_plain_filter():
    """The a-trous filter's own backward (the adjoint of its 25 shifts, `_AtrousTaps`)
    against autograd through the plain formulation (each tap a slice of the zero-padded
    input, summed), in float64 on a frame smaller than the widest taps (step 16: taps 32
    pixels out), with sky pixels (normal 0) and depth steps; the forward values are the same
    to the last bit in float32, and torch's numerical gradient check passes."""
    import torch.nn.functional as F
    from ssr.model import ATROUS_TAPS, atrous_filter, atrous_weights

    def plain(x, normal, depth, levels=5):
        h, w = x.shape[-2:]
        for lvl in range(levels):
            step = 2 ** lvl
            pad = 2 * step
            xp, np_, zp = (F.pad(t, (pad, pad, pad, pad)) for t in (x, normal, depth))
            acc, wsum = torch.zeros_like(x), torch.zeros_like(depth)
            for i, hy in enumerate(ATROUS_TAPS):
                for j, hx in enumerate(ATROUS_TAPS):
                    y0, x0 = pad + (i - 2) * step, pad + (j - 2) * step
                    win = (Ellipsis, slice(y0, y0 + h), slice(x0, x0 + w))
                    wt = (hy * hx) * atrous_weights(normal, depth, np_[win], zp[win])
                    acc = acc + wt * xp[win]
                    wsum = wsum + wt
            x = acc / wsum.clamp(min=1e-12)
        return x

    gen = torch.Generator().manual_seed(3)
    n, h, w = 2, 21, 30
    normal = F.normalize(torch.randn(n, 3, h, w, generator=gen, dtype=torch.float64), dim=1)
    normal[:, :, :4, :7] = 0.0
    depth = torch.rand(n, 1, h, w, generator=gen, dtype=torch.float64) * 0.1 + (torch.arange(w) > 13) * 0.5
    x = torch.rand(n, 6, h, w, generator=gen, dtype=torch.float64, requires_grad=True)
    g = torch.randn(n, 6, h, w, generator=gen, dtype=torch.float64)
    want, = torch.autograd.grad((plain(x, normal, depth) * g).sum(), x)
    got, = torch.autograd.grad((atrous_filter(x, normal, depth) * g).sum(), x)
    assert torch.allclose(got, want, rtol=1e-12, atol=1e-12)
    assert got.abs().max() > 0.1
    x32, n32, z32 = x.detach().float(), normal.float(), depth.float()
    assert torch.equal(atrous_filter(x32, n32, z32), plain(x32, n32, z32))
    small = x[:1, :2, :9, :11].detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: atrous_filter(t, normal[:1, :, :9, :11], depth[:1, :, :9, :11], levels=3), (small,))
