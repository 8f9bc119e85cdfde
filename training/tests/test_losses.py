import pytest
import torch

from ssr import losses as L
from ssr.export import random_model
from ssr.golden import make_frames
from ssr.model import ALBEDO_EPS, demodulate

N, T, C, H, W = 2, 5, 3, 16, 16


def _seq(seed=0):
    g = torch.Generator().manual_seed(seed)
    refs = torch.exp(torch.randn(N, T, C, H, W, generator=g))
    motion = (torch.rand(N, T, 2, H, W, generator=g) - 0.5) * 3.0
    albedo = torch.rand(N, 3, H, W, generator=g)
    return refs, motion, albedo


def _aux(refs, motion, albedo):
    return {"motion": motion, "o": demodulate(refs[:, -1], albedo), "albedo_mod": albedo}


def test_constants():
    assert L.FRAME_WEIGHTS == (0.05, 0.25, 0.5, 0.75, 1.0)
    assert L.LAMBDAS == {"s": 0.7, "t": 0.1, "e": 0.2, "wt": 0.4, "a": 5.0, "m": 5.0, "ssim": 0.0, "mm": 0.0, "n2n": 0.0, "tml2": 0.0}


def test_zero_for_identical_inputs():
    refs, motion, albedo = _seq()
    total, parts = L.total_loss(refs.clone(), refs, _aux(refs, motion, albedo))
    assert total.item() == 0.0
    for k, v in parts.items():
        assert v.item() == 0.0, k


def test_positive_otherwise():
    refs, motion, albedo = _seq()
    g = torch.Generator().manual_seed(5)
    preds = refs * torch.exp(0.3 * torch.randn(refs.shape, generator=g))
    aux = _aux(refs, motion, albedo)
    aux["o"] = aux["o"] + 0.1
    total, parts = L.total_loss(preds, refs, aux)
    for k, v in parts.items():
        assert v.item() > 0, k
    lam = L.LAMBDAS
    want = (
        lam["s"] * parts["l_s"]
        + lam["t"] * parts["l_t"]
        + lam["e"] * parts["l_e"]
        + lam["wt"] * parts["l_wt"]
        + lam["a"] * parts["l_a"]
        + lam["m"] * parts["l_m"]
    )
    torch.testing.assert_close(total, want)
    torch.testing.assert_close(parts["l_a"], torch.tensor(0.1))
    # the brightness term's weight is honoured like the others'
    total_0, _ = L.total_loss(preds, refs, aux, lambdas={**lam, "m": 0.0})
    torch.testing.assert_close(total_0, want - lam["m"] * parts["l_m"])
    with pytest.raises(KeyError, match="unknown loss weight"):
        L.total_loss(preds, refs, aux, lambdas={**lam, "q": 1.0})


def test_mean_loss_sees_brightness_not_detail():
    """l_m is blind to how radiance is spread inside a block (a reference whose 16x16 blocks
    each hold one firefly carrying the block's energy gives 0) and sees a global gain: a
    prediction 2x too bright gives SMAPE(2, 1) = 1/3 per frame, sum of the frame weights."""
    refs, _, _ = _seq()
    flat = L.block_means(refs.flatten(0, 1)).repeat_interleave(16, -1).repeat_interleave(16, -2)
    fire = torch.zeros_like(refs.flatten(0, 1))
    fire[..., 3, 5] = flat[..., 3, 5] * 256.0
    fire = fire.view_as(refs)
    torch.testing.assert_close(L.mean_loss(fire, flat.view_as(refs)), torch.tensor(0.0), atol=1e-5, rtol=0)  # f32 sums; a gain of 2 gives ~0.8
    assert L.spatial_loss(fire, flat.view_as(refs)) > 0.5
    eps = L.SMAPE_EPS
    want = 0.0
    for t, w in enumerate(L.FRAME_WEIGHTS):
        m = L.block_means(refs[:, t])
        want = want + w * (m / (3 * m + eps)).mean()
    torch.testing.assert_close(L.mean_loss(2 * refs, refs), want)


def test_smape_known_value():
    p = torch.tensor([1.0, 2.0, 0.0, -1.0])
    r = torch.tensor([1.0, 0.0, 0.0, 1.0])
    want = (0.0 + 2.0 / 2.01 + 0.0 + 2.0 / 2.01) / 4
    torch.testing.assert_close(L.smape(p, r), torch.tensor(want))
    torch.testing.assert_close(L.smape(p, r, eps=1e-9), torch.tensor(0.5))  # |p-r| / (|p|+|r|) = 1, 1


def test_log_kernel():
    k = L.log_kernel()
    assert k.shape == (9, 9)
    assert abs(k.sum().item()) < 1e-6
    assert torch.equal(k, k.flip(0)) and torch.equal(k, k.t())
    assert k[4, 4] < 0 and k[4, 4] == k.min()  # negative centre (LoG of a Gaussian blob)


def test_hfen_constant_image_is_zero():
    x = torch.full((1, 3, 12, 14), 3.7)
    assert L.log_filter(x).abs().max() < 1e-5
    y = torch.full((1, 3, 12, 14), 0.2)
    assert L.hfen_relative(x, y) < 1e-3
    # an edge is seen, also relative to the reference
    z = x.clone()
    z[..., 7:] = 10.0
    assert L.hfen_relative(z, x) > 1.0
    assert L.log_filter(z).abs().max() > 0.1


def test_frame_weights_applied():
    refs, _, _ = _seq()
    single = []
    for k in range(T):
        preds = refs.clone()
        preds[:, k] *= 1.5
        single.append(L.smape(preds[:, k], refs[:, k]))
        torch.testing.assert_close(L.spatial_loss(preds, refs), L.FRAME_WEIGHTS[k] * single[k])
        torch.testing.assert_close(
            L.edge_loss(preds, refs), L.FRAME_WEIGHTS[k] * L.hfen_relative(preds[:, k], refs[:, k])
        )
    # temporal: an error in the last frame shows in the last difference only
    preds = refs.clone()
    preds[:, -1] *= 1.5
    d = L.smape(preds[:, -1] - preds[:, -2], refs[:, -1] - refs[:, -2])
    torch.testing.assert_close(L.temporal_loss(preds, refs), L.FRAME_WEIGHTS[-1] * d)
    # custom weights and a mismatched count
    torch.testing.assert_close(L.spatial_loss(preds, refs, [0, 0, 0, 0, 2.0]), 2.0 * single[-1])
    with pytest.raises(ValueError, match="frame weights"):
        L.spatial_loss(preds[:, :3], refs[:, :3])


def test_lists_equal_stacked():
    refs, motion, albedo = _seq()
    preds = refs * 1.1
    a, pa = L.total_loss(preds, refs, _aux(refs, motion, albedo))
    aux = _aux(refs, motion, albedo)
    aux["motion"] = list(motion.unbind(1))
    b, pb = L.total_loss(list(preds.unbind(1)), list(refs.unbind(1)), aux)
    torch.testing.assert_close(a, b)


def test_warped_temporal_masked_and_stable():
    refs, motion, _ = _seq()
    # a temporally stable error (same offset in both warped frames, zero motion) is not penalised
    zero = torch.zeros_like(motion)
    preds = refs.clone()
    preds[:, -2:] = torch.expm1(torch.log1p(refs[:, -2:]) + 0.3)
    assert L.warped_temporal_loss(preds, refs, zero) < 1e-5
    assert L.spatial_loss(preds, refs) > 0.05
    # errors where the warp is invalid are masked out
    m = torch.zeros_like(motion)
    m[:, -1, 0, :, :4] = -100.0  # the first 4 columns point off screen
    preds = refs.clone()
    preds[:, -1, :, :, :4] += 5.0
    assert L.warped_temporal_loss(preds, refs, m) == 0.0
    preds[:, -1, :, :, 4] += 5.0
    assert L.warped_temporal_loss(preds, refs, m) > 0.0
    # only the last two frames count
    preds = refs.clone()
    preds[:, :3] *= 3.0
    assert L.warped_temporal_loss(preds, refs, motion) == 0.0
    # known value: zero motion, log-space flicker of d in the last frame
    preds = refs.clone()
    preds[:, -1] = torch.expm1(torch.log1p(refs[:, -1]) + 0.25)
    torch.testing.assert_close(L.warped_temporal_loss(preds, refs, zero), torch.tensor(0.25))


def test_albedo_loss_known_value():
    ref = torch.full((1, 3, 2, 2), 1.0)
    albedo = torch.full((1, 3, 2, 2), 0.5)
    o = torch.zeros(1, 3, 2, 2)
    want = torch.log(torch.tensor(1.0 + 1.0 / (0.5 + ALBEDO_EPS)))
    torch.testing.assert_close(L.albedo_loss(o, ref, albedo), want)


def test_sequence_loss_backprop_through_model():
    frames = make_frames(seed=3, height=16, width=16, count=5)
    model = random_model(0)
    results = model.run_sequence(frames)
    refs = [torch.rand(1, 3, 16, 16) for _ in range(5)]
    total, parts = L.sequence_loss(results, refs, frames)
    assert torch.isfinite(total) and total > 0
    total.backward()
    grads = [p.grad for p in model.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert model.unet.dec1[2].weight.grad.abs().sum() > 0
    assert model.tfa.ref[0].weight.grad.abs().sum() > 0


def test_tonemap_matches_the_metric():
    from ssr import metrics

    g = torch.Generator().manual_seed(3)
    x = torch.exp(2.0 * torch.randn(3, 20, 20, generator=g))
    x[0, 0, 0], x[1, 0, 0], x[2, 0, 0] = 0.0, -1.0, float("nan")
    want = torch.from_numpy(metrics.tonemap(x))
    got = L.tonemap(x)
    # Equal except where the metric's value lies below the gamma's floor (zero radiance).
    floor = L.TONEMAP_FLOOR ** (1.0 / 2.2)
    assert torch.allclose(got, torch.clamp(want, min=floor), atol=1e-6)


def test_ssim_term_against_the_metric():
    """1 - l_ssim of one frame equals the metric's SSIM (metrics.ssim, on the 8-bit images) up to
    the 8-bit rounding; identical frames give 0, and the gradient is finite, also at zero."""
    from ssr import metrics

    g = torch.Generator().manual_seed(4)
    r = torch.exp(torch.randn(1, 1, 3, 32, 32, generator=g))
    r[..., :4, :4] = 0.0
    p = r * torch.exp(0.4 * torch.randn(r.shape, generator=g))
    p.requires_grad_(True)
    loss = L.ssim_loss(p, r, frame_weights=[1.0])
    want = metrics.ssim(p[0, 0].detach(), r[0, 0])
    assert abs((1.0 - loss.item()) - want) < 5e-3, (1.0 - loss.item(), want)
    loss.backward()
    assert torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0
    assert L.ssim_loss(r, r.clone(), frame_weights=[1.0]).item() == pytest.approx(0.0, abs=1e-6)


def test_ssim_term_only_when_weighted():
    refs, motion, albedo = _seq()
    g = torch.Generator().manual_seed(5)
    preds = refs * torch.exp(0.3 * torch.randn(refs.shape, generator=g))
    _, parts = L.total_loss(preds, refs, _aux(refs, motion, albedo))
    assert "l_ssim" not in parts
    lam = dict(L.LAMBDAS, ssim=0.5)
    total, parts = L.total_loss(preds, refs, _aux(refs, motion, albedo), lambdas=lam)
    assert parts["l_ssim"].item() > 0
    base = sum(L.LAMBDAS[k[2:]] * v for k, v in parts.items() if k != "l_ssim")
    assert total.item() == pytest.approx(base.item() + 0.5 * parts["l_ssim"].item(), rel=1e-6)
    with pytest.raises(KeyError, match="unknown loss weight"):
        L.total_loss(preds, refs, _aux(refs, motion, albedo), lambdas={"q": 1.0})


def test_losses_do_not_see_a_colour_permutation():
    # What makes colour permutation (ssr/data.py) a label-preserving augmentation on the loss
    # side: every term treats the RGB channels alike, so permuting the channels of
    # prediction, reference, network output and albedo together leaves each term as it was
    # (the SSIM term included), while permuting the prediction alone changes it.
    refs, motion, albedo = _seq(3)
    g = torch.Generator().manual_seed(8)
    preds = refs * torch.exp(0.3 * torch.randn(refs.shape, generator=g))
    aux = _aux(refs, motion, albedo)
    aux["o"] = aux["o"] * (1.0 + 0.2 * torch.rand(aux["o"].shape, generator=g))
    lam = {**L.LAMBDAS, "ssim": 10.0}
    total, parts = L.total_loss(preds, refs, aux, lambdas=lam)
    for order in ([0, 2, 1], [1, 2, 0], [2, 1, 0]):
        pa = {"motion": motion, "o": aux["o"][:, order], "albedo_mod": albedo[:, order]}
        t_p, parts_p = L.total_loss(preds[:, :, order], refs[:, :, order], pa, lambdas=lam)
        for k in parts:
            torch.testing.assert_close(parts_p[k], parts[k], rtol=1e-5, atol=1e-7, msg=f"{k} {order}")
        torch.testing.assert_close(t_p, total, rtol=1e-5, atol=1e-7)
        wrong, _ = L.total_loss(preds[:, :, order], refs, aux, lambdas=lam)
        assert abs(wrong.item() - total.item()) > 1e-3 * total.item()


def _metal_scene(coverage_rows: int):
    """A sequence whose top `coverage_rows` rows are metal (metallic 1, the rest 0.2)."""
    refs, motion, albedo = _seq(3)
    metallic = torch.full((N, T, 1, H, W), 0.2)
    metallic[..., :coverage_rows, :] = 1.0
    return refs, motion, albedo, metallic


def test_metal_mean_loss_measures_the_metal_level_alone():
    """l_mm is 0 for the reference itself and for any change off the metal; a prediction
    whose metal is uniformly 2x too dark gives SMAPE(1/2, 1) = 1/3 per frame (eps aside),
    the sum of the frame weights, whatever the metal's coverage; no metal gives 0."""
    for rows in (2, 8, 16):
        refs, _, _, metallic = _metal_scene(rows)
        metal = metallic >= L.METAL_THRESHOLD
        assert L.metal_mean_loss(refs, refs, metallic).item() == 0.0
        off = torch.where(metal, refs, refs * 3.0)
        assert L.metal_mean_loss(off, refs, metallic).item() == 0.0
        dark = torch.where(metal, refs * 0.5, refs)
        want = sum(L.FRAME_WEIGHTS) / 3.0
        got = L.metal_mean_loss(dark, refs, metallic).item()
        assert abs(got - want) < 0.01 * want, (rows, got, want)
    refs, _, _, metallic = _metal_scene(0)
    zero = L.metal_mean_loss(refs * 0.5, refs, metallic)
    assert zero.item() == 0.0 and torch.isfinite(zero)


def test_metal_mean_loss_is_blind_to_detail_inside_a_block_and_gives_finite_gradients():
    refs, _, _, metallic = _metal_scene(16)
    # the metal's energy moved to one pixel per 16x16 block: the block sums are unchanged
    block = L.block_means(refs.flatten(0, 1)) * 256.0
    fire = torch.zeros_like(refs.flatten(0, 1))
    fire[..., ::16, ::16] = block
    fire = fire.view_as(refs)
    assert L.metal_mean_loss(fire, refs, metallic).item() < 1e-6
    preds = (refs * 0.7).requires_grad_()
    L.metal_mean_loss(preds, refs, metallic).backward()
    assert torch.isfinite(preds.grad).all() and preds.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="metallic"):
        L.metal_mean_loss(refs, refs, metallic[:, :, :, :8])


def test_total_loss_adds_the_metal_term_only_when_weighted():
    refs, motion, albedo, metallic = _metal_scene(8)
    preds = refs * 0.8
    aux = _aux(refs, motion, albedo)
    total, parts = L.total_loss(preds, refs, aux)
    assert "l_mm" not in parts
    with pytest.raises(KeyError, match="metallic"):
        L.total_loss(preds, refs, aux, lambdas={**L.LAMBDAS, "mm": 5.0})
    aux["metallic"] = metallic
    total_mm, parts_mm = L.total_loss(preds, refs, aux, lambdas={**L.LAMBDAS, "mm": 5.0})
    torch.testing.assert_close(parts_mm["l_mm"], L.metal_mean_loss(preds, refs, metallic))
    torch.testing.assert_close(total_mm, total + 5.0 * parts_mm["l_mm"])


def _grad(loss_fn, p0, r):
    p = p0.clone().requires_grad_(True)
    loss_fn(p, r).backward()
    return p.grad


def _noisy_refs(clean, draws=4000):
    """`draws` noisy references of `clean` [1, C, H, W]: each pixel the mean of 4 exponential
    samples scaled to the clean value (unbiased, skewed: rarely bright, mostly dark)."""
    return clean * torch.distributions.Gamma(4.0, 4.0).sample((draws,) + clean.shape[1:]).unsqueeze(1)


def _mean_grad(loss_fn, p0, noisy):
    """The mean over the noisy references of loss_fn's gradient at p0."""
    return sum(_grad(loss_fn, p0, r) for r in noisy) / len(noisy)


def test_n2n_expected_gradient_is_the_clean_references():
    """The analytic property the term exists for: over zero-mean, heavy-tailed Monte Carlo
    noise (a reference that is the mean of a few exponential samples: rarely bright, mostly
    dark), the mean gradient of l_n2n is its gradient at the noise-free reference, while
    SMAPE's (the spatial term's) is not."""
    g = torch.Generator().manual_seed(3)
    shape = (1, 3, 8, 8)
    clean = torch.exp(torch.randn(shape, generator=g))
    pred = clean * torch.exp(0.4 * torch.randn(shape, generator=g))
    n2n = lambda p, r: L.n2n_loss([p], [r], [1.0])  # noqa: E731
    smape = lambda p, r: L.smape(p, r)  # noqa: E731
    noisy = _noisy_refs(clean)
    want_n2n, want_smape = _grad(n2n, pred, clean), _grad(smape, pred, clean)
    got_n2n, got_smape = _mean_grad(n2n, pred, noisy), _mean_grad(smape, pred, noisy)
    err = lambda got, want: ((got - want).norm() / want.norm()).item()  # noqa: E731
    # The n2n gradient's Monte Carlo error: var of (p - r) per draw is clean^2 / 4
    assert err(got_n2n, want_n2n) < 0.05
    assert err(got_smape, want_smape) > 0.2


def _check_optional_term(term, weight, per_pixel):
    """An optional loss term: absent at weight 0, 0 at the reference, and at preds = 1.1 refs
    the frame-weighted sum of the means of per_pixel(refs[:, t]) and weighted into the total."""
    refs, motion, albedo = _seq()
    key = "l_" + term
    _, parts = L.total_loss(refs, refs, _aux(refs, motion, albedo))
    assert key not in parts
    lam = dict(L.LAMBDAS, **{term: weight})
    _, parts = L.total_loss(refs, refs, _aux(refs, motion, albedo), lambdas=lam)
    assert parts[key].item() == 0.0
    total, parts = L.total_loss(refs * 1.1, refs, _aux(refs, motion, albedo), lambdas=lam)
    want = sum(w * per_pixel(refs[:, t]).mean() for t, w in enumerate(L.FRAME_WEIGHTS))
    assert parts[key].item() == pytest.approx(want.item(), rel=1e-5)
    base = sum(L.LAMBDAS[k[2:]] * v for k, v in parts.items() if k != key)
    assert total.item() == pytest.approx(base.item() + weight * parts[key].item(), rel=1e-6)


def test_n2n_term_only_when_weighted_and_zero_at_the_reference():
    # (1.1 r - r)^2 / (1.1 r + eps)^2 per pixel
    _check_optional_term("n2n", 2.0, lambda r: ((0.1 * r) / (1.1 * r + L.N2N_EPS)) ** 2)


def test_tonemap_slope_is_the_metrics_tonemaps_derivative():
    """tonemap_slope against central differences of the metric's tonemap curve (float64
    numpy through metrics.hable_curve, independent of the analytic quotient rule), over the
    range the term uses."""
    import numpy as np

    from ssr import metrics

    def tm(x):
        h = metrics.hable_curve(metrics.EXPOSURE * x, *metrics.HABLE) / metrics.hable_curve(metrics.WHITE, *metrics.HABLE)
        t = np.clip(h, 0.0, 1.0)
        return t ** (1.0 / metrics.GAMMA)

    xs = np.geomspace(L.TML2_LO, L.TML2_HI, 40)
    got = L.tonemap_slope(torch.tensor(xs, dtype=torch.float64)).numpy()
    h = xs * 1e-5
    want = (tm(xs + h) - tm(xs - h)) / (2 * h)
    assert np.allclose(got, want, rtol=1e-4)
    # the bounds: the floor l_ssim clamps at, and just below the white point
    assert tm(np.array(L.TML2_LO)) ** metrics.GAMMA == pytest.approx(L.TONEMAP_FLOOR, rel=1e-6)
    assert tm(np.array(L.TML2_HI)) < 1.0 and tm(np.array(L.WHITE / L.EXPOSURE)) == pytest.approx(1.0)


def test_tml2_expected_gradient_is_the_clean_references():
    """Like l_n2n (test above), l_tml2 seeks the mean: over zero-mean, heavy-tailed noise in
    the reference its mean gradient is its gradient at the noise-free reference."""
    g = torch.Generator().manual_seed(5)
    shape = (1, 3, 8, 8)
    clean = torch.exp(torch.randn(shape, generator=g)) * 0.3
    pred = clean * torch.exp(0.4 * torch.randn(shape, generator=g))
    tml2 = lambda p, r: L.tml2_loss([p], [r], [1.0])  # noqa: E731
    want, got = _grad(tml2, pred, clean), _mean_grad(tml2, pred, _noisy_refs(clean))
    assert ((got - want).norm() / want.norm()).item() < 0.05


def test_tml2_weighs_pixels_by_the_tonemaps_slope_held_at_its_bounds():
    slope = lambda x: L.tonemap_slope(x.clamp(L.TML2_LO, L.TML2_HI))  # noqa: E731
    _check_optional_term("tml2", 3.0, lambda r: (slope(1.1 * r) * 0.1 * r) ** 2)
    # outside [TML2_LO, TML2_HI] the weight is the bound's: a black and a very bright
    # prediction weigh their errors as at the bounds (and a negative one as black)
    p = torch.tensor([[[[-1.0, 0.0, 1e-9, 50.0]]]])
    r = torch.zeros_like(p) + 0.5
    got = L.tml2_loss([p], [r], [1.0])
    lo, hi = L.tonemap_slope(torch.tensor(L.TML2_LO)), L.tonemap_slope(torch.tensor(L.TML2_HI))
    want = ((lo * 1.5) ** 2 + (lo * 0.5) ** 2 + (lo * 0.5) ** 2 + (hi * 49.5) ** 2) / 4
    assert got.item() == pytest.approx(want.item(), rel=1e-5)
