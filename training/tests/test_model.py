import math

import pytest
import torch
import torch.nn.functional as F

from ssr.export import random_model
from ssr.model import (
    ALBEDO_EPS,
    LEGACY_OPTIONS,
    SSRConfig,
    SSRModel,
    composite_background,
    conv_layers,
    demodulate,
    extra_buffers,
    flops_per_pixel,
    fold_emission,
    history_consistent,
    pool2x2,
    prepare_inputs,
    quarter_mask,
    remodulate,
    rescale_log,
    upsample2x,
    use_albedo,
    warp,
)

H, W = 24, 40


# ----------------------------------------------------------------------------- shapes


def test_intermediate_shapes(frames):
    model = random_model(0)
    cfg = model.cfg
    c1, c2, c3 = cfg.enc
    expected = {
        "a_cur": (1, 15, H, W),
        "mt": (1, 4, H, W),
        "warp_acc": (1, 15, H, W),
        "warp_valid": (1, 1, H, W),
        "ref_feat": (1, cfg.k, H, W),
        "emb_cur": (1, cfg.k, H, W),
        "emb_prev": (1, cfg.k, H, W),
        "tfa_weights": (1, 4, H, W),
        "a_acc": (1, 15, H, W),
        "warp_out": (1, 3, H, W),
        "enc1": (1, c1, H, W),
        "enc2": (1, c2, H // 2, W // 2),
        "enc3": (1, c3, H // 4, W // 4),
        "i3": (1, 3, H // 4, W // 4),
        "i2": (1, 3, H // 2, W // 2),
        "o": (1, 3, H, W),
        "output": (1, 3, H, W),
    }
    with torch.no_grad():
        results = model.run_sequence(frames)
    assert len(results) == 3
    for r in results:
        for name, shape in expected.items():
            assert tuple(r[name].shape) == shape, name
            assert r[name].dtype == torch.float32, name
            assert torch.isfinite(r[name]).all(), name
        a_acc, o, exposure = r["state"]
        assert a_acc is r["a_acc"] and o is r["o"] and exposure is r["exposure"]
        assert exposure.shape == (1, 9, 1, 1)  # s (6) and the ceiling's running max M (rgb)


def test_named_parameters_and_shapes():
    model = SSRModel()
    shapes = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    c1, c2, c3 = 16, 32, 28
    expected_w = {
        "tfa.ref.0": (8, 19),
        "tfa.ref.2": (8, 8),
        "tfa.emb.0": (8, 15),
        "tfa.emb.2": (8, 8),
        "unet.enc1.0": (c1, 37),
        "unet.enc1.2": (c1, c1),
        "unet.enc2.0": (c2, c1 + 3),
        "unet.enc2.2": (c2, c2),
        "unet.enc3.0": (c3, c2 + 3),
        "unet.enc3.2": (c3, c3),
        "unet.dec3.0": (c3, c3 + 3),
        "unet.dec3.2": (3, c3),
        "unet.dec2.0": (c2, c2 + 6),
        "unet.dec2.2": (3, c2),
        "unet.dec1.0": (c1, c1 + 6),
        "unet.dec1.2": (3, c1),
    }
    want = {}
    for name, (co, ci) in expected_w.items():
        want[name + ".weight"] = (co, ci, 3, 3)
        want[name + ".bias"] = (co,)
    assert shapes == want
    assert [n for n, *_ in conv_layers(model.cfg)] == list(expected_w)


def test_batched_equals_single(frames):
    # In float64, so that what is compared is the batching, not the float32 rounding of
    # convolution algorithms that sum in another order for another batch size (oneDNN on
    # AVX-512 CPUs: 1.7e-6 apart in float32).
    model = random_model(3).double()
    frames = [{k: v.double() for k, v in f.items()} for f in frames]
    batched = [{k: torch.cat([f[k], f[k].flip(-1)], 0) for k in f} for f in frames]
    with torch.no_grad():
        rb = model.run_sequence(batched)
        r0 = model.run_sequence(frames)
    for a, b in zip(rb, r0):
        torch.testing.assert_close(a["output"][:1], b["output"], rtol=1e-12, atol=1e-12)


def test_footprint_albedo_is_the_albedo_the_whole_pipeline_uses(frames):
    """Config albedo = "footprint" runs the pipeline of albedo = "centre" on frames whose
    albedo buffer holds the footprint albedo (demodulation, the network's input, history,
    remodulation alike), and says which buffer it needs when a frame lacks it."""
    fp = random_model(4, SSRConfig(albedo="footprint"))
    centre = random_model(4)
    assert extra_buffers(fp.cfg) == ("albedo_footprint",) and extra_buffers(centre.cfg) == ()
    g = torch.Generator().manual_seed(9)
    with_fp = [{**f, "albedo_footprint": torch.rand(f["albedo"].shape, generator=g)} for f in frames]
    swapped = [{**f, "albedo": f["albedo_footprint"]} for f in with_fp]
    with torch.no_grad():
        a = fp.run_sequence(with_fp)
        b = centre.run_sequence(swapped)
        c = centre.run_sequence(with_fp)
    for x, y, z in zip(a, b, c):
        assert torch.equal(x["output"], y["output"])
        assert not torch.equal(x["output"], z["output"])  # the centre model ignores the buffer
    with pytest.raises(KeyError, match="albedo_footprint.*subpixel dataset --background"):
        fp(frames[0])
    assert use_albedo(frames[0], centre.cfg) is frames[0]
    # the option is a version-2 key added late: absent it reads "centre"; version 1 has none
    d = SSRConfig(albedo="footprint").to_dict()
    assert d["albedo"] == "footprint" and SSRConfig.from_dict({k: v for k, v in d.items() if k != "albedo"}).albedo == "centre"
    with pytest.raises(ValueError, match="`albedo` must be one of"):
        SSRConfig(albedo="middle")


def test_size_must_be_multiple_of_4(frames):
    f = {k: v[:, :, :22] for k, v in frames[0].items()}
    with pytest.raises(ValueError, match="multiples of 4"):
        SSRModel()(f)


def test_missing_or_misshapen_buffer(frames):
    f = dict(frames[0])
    del f["shadow"]
    with pytest.raises(KeyError, match="shadow"):
        SSRModel()(f)
    f = dict(frames[0])
    f["motion"] = f["motion"][:, :1]
    with pytest.raises(ValueError, match="motion"):
        SSRModel()(f)


def test_gradients_flow_through_sequence(frames):
    model = random_model(0)
    results = model.run_sequence(frames)
    results[-1]["output"].mean().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        if name == "tfa.emb.2.bias":
            # b adds <b, R> to both s_cur and s_prev: it cancels in the softmax (a dead parameter);
            # its gradient is zero up to rounding (exactly zero only for some summation orders,
            # i.e. thread counts)
            assert p.grad.abs().max() < 1e-6
        else:
            assert p.grad.abs().sum() > 0, name


# ----------------------------------------------------------------------------- config / FLOPs


def test_config_json_round_trip():
    cfg = SSRConfig(tfa_hidden=4, k=4, enc=(8, 16, 24), feature_pool="avg")
    assert SSRConfig.from_json(cfg.to_json()) == cfg
    d = SSRConfig().to_dict()
    assert d == {
        "tfa_hidden": 8,
        "k": 8,
        "enc": [16, 32, 28],
        "feature_pool": "max",
        "upsample": "bilinear",
        "input_channels": 37,
        "version": 2,
        "exposure": "channel",
        "remodulation": "current",
        "history": "geometry",
        "ceiling": "max",
        "mean_correction": "none",
        "albedo": "centre",
        "emission": "network",
        "escaped": "network",
    }
    with pytest.raises(ValueError, match="feature_pool"):
        SSRConfig(feature_pool="median")
    with pytest.raises(ValueError, match="unknown key"):
        SSRConfig.from_dict({**d, "depth": 4})
    with pytest.raises(ValueError, match="input_channels"):
        SSRConfig.from_dict({**d, "input_channels": 36})
    with pytest.raises(ValueError, match="`exposure` must be one of"):
        SSRConfig.from_dict({**d, "exposure": "global"})
    with pytest.raises(ValueError, match=r"missing key\(s\) \['history'\]"):
        SSRConfig.from_dict({k: v for k, v in d.items() if k != "history"})
    with pytest.raises(ValueError, match="unsupported `version` 3"):
        SSRConfig.from_dict({**d, "version": 3})
    # version 1 (the shipped weights'): no option keys, the legacy pipeline
    v1 = {k: v for k, v in d.items() if k not in ("exposure", "remodulation", "history", "ceiling", "mean_correction", "albedo", "emission", "escaped")}
    v1["version"] = 1
    c1 = SSRConfig.from_dict(v1)
    assert (c1.exposure, c1.remodulation, c1.history, c1.ceiling) == ("none", "accumulated", "screen", "none")
    assert c1.to_dict() == v1 and SSRConfig.from_json(c1.to_json()) == c1
    with pytest.raises(ValueError, match="version 1 has no `exposure` option"):
        SSRConfig(version=1, exposure="channel", remodulation="accumulated", history="screen")


def test_flops_per_pixel_breakdown():
    total, per_layer = flops_per_pixel(SSRConfig())
    f = dict(per_layer)
    assert f["tfa.ref.0"] == 18 * 19 * 8
    assert f["tfa.emb.0"] == 2 * 18 * 15 * 8  # E runs on A_t and on W(A_acc)
    assert f["unet.enc1.0"] == 18 * 37 * 16
    assert f["unet.enc2.2"] == 18 * 32 * 32 / 4
    assert f["unet.enc3.0"] == 18 * 35 * 28 / 16
    assert f["unet.enc3.2"] == 18 * 28 * 28 / 16
    assert f["unet.dec3.0"] == 18 * 31 * 28 / 16
    assert f["unet.dec3.2"] == 18 * 28 * 3 / 16
    assert f["unet.dec1.2"] == 18 * 16 * 3
    # 18 * (584 TFA + 848 enc1 + 408 enc2 + 110.25 enc3 + 59.5 dec3 + 328 dec2 + 400 dec1)
    assert total == 49279.5


def test_flops_budget_decimal_50k():
    # DESIGN §4: <= 50,000 FLOP/pixel. enc = [16, 32, 28] gives 49,279.5 (the former
    # [16, 32, 32] cost 50,004, 4 over).
    total, _ = flops_per_pixel(SSRConfig())
    assert total <= 50_000


def test_parameter_count_default():
    assert sum(p.numel() for p in SSRModel().parameters()) == 66041


# ----------------------------------------------------------------------------- inputs


def test_prepare_inputs_layout(frames):
    f = frames[1]
    a, mt = prepare_inputs(f)
    torch.testing.assert_close(a[:, 0:3], torch.log(1 + f["color"] / (f["albedo"] + ALBEDO_EPS)))
    assert torch.equal(a[:, 3:6], f["albedo"])
    assert torch.equal(a[:, 6:9], f["normal"])
    torch.testing.assert_close(a[:, 9:12], torch.log1p(f["shadow"]))
    assert torch.equal(a[:, 12:13], f["depth"])
    assert torch.equal(a[:, 13:14], f["metallic"])
    assert torch.equal(a[:, 14:15], f["roughness"])
    assert torch.equal(mt, torch.cat([f["mask"], f["transparent"]], 1))


def test_demodulate_remodulate():
    color = torch.tensor([0.0, 1.0, 10.0, -1.0, float("nan"), float("inf")]).view(1, 6, 1, 1)
    albedo = torch.tensor([0.5, 0.5, 0.0, 0.5, 0.5, 0.5]).view(1, 6, 1, 1)
    e = demodulate(color, albedo)
    want = [0.0, math.log(1 + 1 / 0.50316), math.log(1 + 10 / 0.00316), 0.0, 0.0, 0.0]
    torch.testing.assert_close(e.flatten(), torch.tensor(want))
    back = remodulate(e, albedo)
    torch.testing.assert_close(back.flatten()[:3], torch.tensor([0.0, 1.0, 10.0]), rtol=1e-5, atol=1e-6)
    # exp(o) - 1 < 0 clamps to 0; negative albedo counts as 0
    assert remodulate(torch.tensor([-1.0]).view(1, 1, 1, 1), torch.ones(1, 1, 1, 1)).item() == 0.0
    torch.testing.assert_close(
        remodulate(torch.full((1, 1, 1, 1), math.log(3.0)), -torch.ones(1, 1, 1, 1)).flatten(),
        torch.tensor([2.0 * ALBEDO_EPS]),
    )


def test_quarter_mask_pattern():
    offsets = [(0, 0), (1, 1), (1, 0), (0, 1)]
    total = torch.zeros(1, 1, 8, 12)
    for t in range(8):
        m = quarter_mask(8, 12, t)
        dx, dy = offsets[t % 4]
        assert m.sum() == 8 * 12 / 4
        for ty in range(0, 8, 2):
            for tx in range(0, 12, 2):
                tile = m[0, 0, ty : ty + 2, tx : tx + 2]
                assert tile.sum() == 1 and tile[dy, dx] == 1
        total += m
    assert torch.equal(total, torch.full_like(total, 2.0))  # every pixel traced once per 4 frames


# ----------------------------------------------------------------------------- warp


def _motion(mx, my, h=6, w=8):
    m = torch.zeros(1, 2, h, w)
    m[:, 0] = mx
    m[:, 1] = my
    return m


def test_warp_zero_motion_is_identity():
    src = torch.randn(2, 5, 6, 8)
    out, valid = warp(src, torch.zeros(2, 2, 6, 8))
    assert torch.equal(out, src)
    assert torch.equal(valid, torch.ones(2, 1, 6, 8))


def test_warp_integer_shift():
    src = torch.randn(1, 3, 6, 8)
    out, valid = warp(src, _motion(2.0, -1.0))
    # out(x, y) = src(x + 2, y - 1) where inside, else invalid
    assert torch.equal(valid[0, 0, 1:, :6], torch.ones(5, 6))
    assert valid[0, 0, 0].sum() == 0 and valid[0, 0, :, 6:].sum() == 0
    assert torch.equal(out[:, :, 1:, :6], src[:, :, :5, 2:])
    assert out[:, :, 0].abs().sum() == 0 and out[:, :, :, 6:].abs().sum() == 0


def test_warp_half_pixel_is_average():
    src = torch.randn(1, 2, 6, 8)
    out, valid = warp(src, _motion(0.5, 0.0))
    torch.testing.assert_close(out[..., :7], 0.5 * (src[..., :7] + src[..., 1:]))
    assert torch.equal(valid[0, 0, :, :7], torch.ones(6, 7))
    assert valid[0, 0, :, 7].sum() == 0  # p.x = W: off screen
    # diagonal half pixel: average of the 4 neighbours
    out, _ = warp(src, _motion(0.5, 0.5))
    quad = 0.25 * (src[..., :5, :7] + src[..., :5, 1:] + src[..., 1:, :7] + src[..., 1:, 1:])
    torch.testing.assert_close(out[..., :5, :7], quad)
    # -0.5 at column 0: p.x = 0 is valid, both taps clamp to column 0
    out, valid = warp(src, _motion(-0.5, 0.0))
    assert valid[0, 0, :, 0].sum() == 6
    torch.testing.assert_close(out[..., 0], src[..., 0])
    torch.testing.assert_close(out[..., 1:], 0.5 * (src[..., :7] + src[..., 1:]))


def test_warp_bilinear_weights():
    src = torch.randn(1, 1, 6, 8)
    out, _ = warp(src, _motion(0.25, 0.75))
    # pixel (2, 1): p = (2.75, 2.25), s = (2.25, 1.75): x0 = 2, tx = .25, y0 = 1, ty = .75
    s = src[0, 0]
    top = s[1, 2] * 0.75 + s[1, 3] * 0.25
    bot = s[2, 2] * 0.75 + s[2, 3] * 0.25
    torch.testing.assert_close(out[0, 0, 1, 2], top * 0.25 + bot * 0.75)


def test_warp_off_screen_and_non_finite_invalid():
    src = torch.randn(1, 3, 6, 8) + 5.0
    m = torch.zeros(1, 2, 6, 8)
    m[0, 0, 0, 0] = -0.6  # p.x = -0.1
    m[0, 1, 1, 1] = 4.5  # p.y = 6.0 = H
    m[0, 0, 2, 2] = 100.0
    m[0, 1, 3, 3] = float("nan")
    m[0, 0, 4, 4] = float("-inf")
    m[0, 1, 5, 5] = -5.5  # p.y = 0.0: valid
    out, valid = warp(src, m)
    bad = [(0, 0), (1, 1), (2, 2), (3, 3), (4, 4)]
    for y, x in bad:
        assert valid[0, 0, y, x] == 0, (y, x)
        assert torch.equal(out[0, :, y, x], torch.zeros(3)), (y, x)
    assert valid.sum() == 6 * 8 - len(bad)
    torch.testing.assert_close(out[0, :, 5, 5], src[0, :, 0, 5])
    assert torch.isfinite(out).all()


# ----------------------------------------------------------------------------- pooling / upsampling


def test_pool2x2():
    x = torch.arange(16.0).view(1, 1, 4, 4)
    assert torch.equal(pool2x2(x, "max"), torch.tensor([[5.0, 7.0], [13.0, 15.0]]).view(1, 1, 2, 2))
    assert torch.equal(pool2x2(x, "avg"), torch.tensor([[2.5, 4.5], [10.5, 12.5]]).view(1, 1, 2, 2))


def _upsample_reference(x):
    """Per-pixel transcription of wgsl/nn/upsample2x.wgsl (bilinear)."""
    n, c, h, w = x.shape
    out = torch.zeros(n, c, 2 * h, 2 * w)
    for y in range(2 * h):
        for xx in range(2 * w):
            fx = max((xx + 0.5) * 0.5 - 0.5, 0.0)
            fy = max((y + 0.5) * 0.5 - 0.5, 0.0)
            x0, y0 = min(int(fx), w - 1), min(int(fy), h - 1)
            x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
            tx, ty = fx - x0, fy - y0
            a, b, d, e = x[..., y0, x0], x[..., y0, x1], x[..., y1, x0], x[..., y1, x1]
            top = a * (1 - tx) + b * tx
            bot = d * (1 - tx) + e * tx
            out[..., y, xx] = top * (1 - ty) + bot * ty
    return out


def test_upsample2x_bilinear_semantics():
    x = torch.randn(1, 2, 3, 5)
    up = upsample2x(x, "bilinear")
    torch.testing.assert_close(up, _upsample_reference(x))
    # interior pixel 2x+1 in 1D: 0.75 * x[i] + 0.25 * x[i+1]
    row = torch.tensor([0.0, 4.0, 8.0]).view(1, 1, 1, 3)
    torch.testing.assert_close(upsample2x(row, "bilinear")[0, 0, 0], torch.tensor([0.0, 1.0, 3.0, 5.0, 7.0, 8.0]))
    assert torch.equal(upsample2x(row, "nearest")[0, 0, 1], torch.tensor([0.0, 0.0, 4.0, 4.0, 8.0, 8.0]))


def test_unet_wiring_matches_contract(frames):
    """Recomputes the U-Net from the contract text: concat orders, average pooling of W(o),
    max pooling of features, bilinear upsampling, no activation on the RGB convs."""
    model = random_model(0)
    u = model.unet
    with torch.no_grad():
        for rgb in (u.dec3[2], u.dec1[2]):  # negative values, so a stray ReLU would show
            rgb.bias -= 1.0
        r0, r1 = model.run_sequence(frames[:2])
        a, mt, acc, wo = r1["a_cur"], r1["mt"], r1["a_acc"], r1["warp_out"]
        wo2 = F.avg_pool2d(wo, 2)
        wo4 = F.avg_pool2d(wo2, 2)
        relu = torch.relu
        e1 = relu(u.enc1[2](relu(u.enc1[0](torch.cat([a, mt, acc, wo], 1)))))
        e2 = relu(u.enc2[2](relu(u.enc2[0](torch.cat([F.max_pool2d(e1, 2), wo2], 1)))))
        e3 = relu(u.enc3[2](relu(u.enc3[0](torch.cat([F.max_pool2d(e2, 2), wo4], 1)))))
        i3 = u.dec3[2](relu(u.dec3[0](torch.cat([e3, wo4], 1))))
        up = lambda x: F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)  # noqa: E731
        i2 = u.dec2[2](relu(u.dec2[0](torch.cat([e2, up(i3), wo2], 1))))
        o = u.dec1[2](relu(u.dec1[0](torch.cat([e1, up(i2), wo], 1))))
        # remodulated with the current albedo (A_t channels 3..5), times the exposure
        out = torch.clamp(torch.exp(o) - 1, min=0) * (torch.clamp(a[:, 3:6], min=0) + ALBEDO_EPS) * r1["exposure"][:, :3]
    for name, v in [("enc1", e1), ("enc2", e2), ("enc3", e3), ("i3", i3), ("i2", i2), ("o", o), ("output", out)]:
        torch.testing.assert_close(r1[name], v, msg=name)
    assert (i3 < 0).any() and (o < 0).any()  # no activation on RGB outputs


def test_feature_pool_avg_config(frames):
    model = random_model(0, SSRConfig(feature_pool="avg"))
    with torch.no_grad():
        r = model(frames[0])
        e1 = r["enc1"]
        x = torch.cat([F.avg_pool2d(e1, 2), F.avg_pool2d(r["warp_out"], 2)], 1)
        torch.testing.assert_close(r["enc2"], model.unet.enc2(x))


# ----------------------------------------------------------------------------- TFA


def test_tfa_first_frame_and_invalid_history(frames):
    model = random_model(0)
    with torch.no_grad():
        r0, r1 = model.run_sequence(frames[:2])
    # first frame: no warp, valid everywhere, s_prev = s_cur, alpha = beta = 0.5, A_acc = A_t
    assert torch.equal(r0["warp_acc"], r0["a_cur"])
    assert torch.equal(r0["warp_valid"], torch.ones_like(r0["warp_valid"]))
    assert torch.equal(r0["warp_out"], torch.zeros_like(r0["warp_out"]))
    tw = r0["tfa_weights"]
    assert torch.equal(tw[:, 2], tw[:, 3])
    assert torch.equal(tw[:, 0], torch.full_like(tw[:, 0], 0.5))
    torch.testing.assert_close(r0["a_acc"], r0["a_cur"])
    # later frame: weights sum to 1; invalid history gives (beta, alpha) = (1, 0) and A_acc = A_t
    tw = r1["tfa_weights"]
    torch.testing.assert_close(tw[:, 0] + tw[:, 1], torch.ones_like(tw[:, 0]))
    inv = r1["warp_valid"][:, 0] == 0
    assert inv.any() and (~inv).any()
    assert torch.equal(tw[:, 1][inv], torch.zeros(int(inv.sum())))
    assert torch.equal(tw[:, 0][inv], torch.ones(int(inv.sum())))
    ia = inv.unsqueeze(1).expand_as(r1["a_acc"])
    assert torch.equal(r1["a_acc"][ia], r1["a_cur"][ia])
    # the scores are the per-pixel dot products of the embeddings with R
    torch.testing.assert_close(tw[:, 2:3], (r1["emb_cur"] * r1["ref_feat"]).sum(1, keepdim=True))
    torch.testing.assert_close(tw[:, 3:4], (r1["emb_prev"] * r1["ref_feat"]).sum(1, keepdim=True))
    # softmax
    torch.testing.assert_close(tw[:, 1][~inv], torch.sigmoid(tw[:, 3] - tw[:, 2])[~inv])
    # the warped history is the previous A_acc and o warped with this frame's motion, re-exposed
    # (e and shadow channels, o) and rejected where depth or normal disagree
    wa, wv = warp(r0["a_acc"], frames[1]["motion"])
    wo, _ = warp(r0["o"], frames[1]["motion"])
    ratio = r0["exposure"][:, :6] / r1["exposure"][:, :6]  # s_prev / s (channels 6..8: the running max)
    wa = torch.cat([rescale_log(wa[:, 0:3], ratio[:, :3]), wa[:, 3:9], rescale_log(wa[:, 9:12], ratio[:, 3:]), wa[:, 12:]], 1)
    wo = rescale_log(wo, ratio[:, :3])
    ok = (wv > 0.5) & history_consistent(wa, r1["a_cur"])
    assert torch.equal(r1["warp_valid"], ok.float())
    assert torch.equal(r1["warp_acc"], torch.where(ok, wa, torch.zeros_like(wa)))
    assert torch.equal(r1["warp_out"], torch.where(ok, wo, torch.zeros_like(wo)))
    # version 1: the plain warp
    legacy = random_model(0, SSRConfig(version=1, **LEGACY_OPTIONS))
    with torch.no_grad():
        q0, q1 = legacy.run_sequence(frames[:2])
    wa, wv = warp(q0["a_acc"], frames[1]["motion"])
    wo, _ = warp(q0["o"], frames[1]["motion"])
    assert torch.equal(q1["warp_acc"], wa) and torch.equal(q1["warp_valid"], wv)
    assert torch.equal(q1["warp_out"], wo)


def test_tfa_softmax_is_stable():
    cfg = SSRConfig()
    model = SSRModel(cfg)
    n = 1
    a = torch.zeros(n, 15, 4, 4)
    mt = torch.zeros(n, 4, 4, 4)
    with torch.no_grad():
        for p in model.tfa.parameters():
            p.fill_(0.0)
        model.tfa.ref[2].bias.fill_(100.0)
        model.tfa.emb[2].bias.fill_(100.0)
        r = model.tfa(a, mt, a, torch.ones(n, 1, 4, 4))
    assert torch.isfinite(r["tfa_weights"]).all()
    torch.testing.assert_close(r["tfa_weights"][:, 0], torch.full((1, 4, 4), 0.5))


def test_composite_background_mirrors_the_engines_output_pass():
    from ssr.model import composite_background

    out = torch.full((1, 3, 2, 3), 8.0, requires_grad=True)
    bg = torch.tensor([0.5, float("nan"), -1.0]).view(1, 3, 1, 1).expand(1, 3, 2, 3).clone()
    cov = torch.tensor([[1.0, 0.75, float("inf")], [2.0, float("nan"), 0.0]]).view(1, 1, 2, 3)
    got = composite_background(out, {"background": bg, "coverage": cov})
    # sanitised: background (0.5, 0, 0); coverage 1, 0.75, 0 (inf), 1 (2 clamped), 0 (nan), 0
    c = torch.tensor([[1.0, 0.75, 0.0], [1.0, 0.0, 0.0]]).view(1, 1, 2, 3)
    want = torch.tensor([0.5, 0.0, 0.0]).view(1, 3, 1, 1) + (1.0 - c) * 8.0
    assert torch.equal(got, want)
    got.sum().backward()  # the network's gradient is scaled by the uncovered part
    assert torch.equal(out.grad, (1.0 - c).expand(1, 3, 2, 3))
    assert composite_background(out, {}) is out


def test_fold_emission_moves_the_directly_seen_emission_into_the_background():
    """Config emission = "background": the model gets the colour without the traced samples'
    first-hit emission, and the output pass (`composite_background`, `MeanCorrection`) adds
    the footprint's, so an emitter wholly covering pixels comes back exactly whatever the
    network makes of the rest, and the mean correction compares the reconstruction with
    samples that hold no emission; "network" leaves the frame as it is; a frame without the
    buffers is a KeyError naming them."""
    from ssr.model import COMPOSITE_EMISSION, MeanCorrection
    from ssr.synth import EMITTER, make_sequence

    f = {k: torch.from_numpy(v)[None] for k, v in make_sequence(16, 16, 1, 3, background=True, emission=True)[0].items()}
    cfg = SSRConfig(emission="background")
    assert extra_buffers(cfg) == ("emission", "emission_footprint", "background", "coverage")
    assert fold_emission(f, SSRConfig()) is f and fold_emission(f, None) is f
    g = fold_emission(f, cfg)
    lamp = f["emission_footprint"][0, 0] > 0
    assert lamp.sum() == 36
    # the colour keeps only the reflected light (the lamp's traced pixels: what the light
    # makes of its base colour); the background is untouched
    torch.testing.assert_close(g["color"], (f["color"] - f["emission"]).clamp_min(0))
    assert torch.all(g["color"][0][:, lamp] < min(EMITTER))
    assert torch.equal(g["background"], f["background"]) and torch.equal(g[COMPOSITE_EMISSION], f["emission_footprint"])
    # the composite of any reconstruction adds exactly the lamp
    zero = torch.zeros_like(f["reference"])
    torch.testing.assert_close(composite_background(zero, g)[0][:, lamp], torch.tensor(EMITTER)[:, None].expand(3, 36))
    # the mean correction sees the same samples as on the scene without the lamp (the same
    # frame rendered without it) and adds the lamp after the correction
    bare = {k: torch.from_numpy(v)[None] for k, v in make_sequence(16, 16, 1, 3, background=True)[0].items()}
    torch.testing.assert_close(g["color"], bare["color"])
    recon = torch.rand(f["reference"].shape, generator=torch.Generator().manual_seed(4))
    torch.testing.assert_close(MeanCorrection(8)(recon, g), MeanCorrection(8)(recon, bare) + f["emission_footprint"])
    model = random_model(2, cfg)
    with torch.no_grad():
        out = model(g)["output"]
    assert torch.isfinite(out).all()
    with pytest.raises(KeyError, match=r"emission.*emission_footprint.*subpixel dataset --background"):
        fold_emission({k: v for k, v in f.items() if not k.startswith("emission")}, cfg)
    d = cfg.to_dict()
    assert d["emission"] == "background" and SSRConfig.from_dict({k: v for k, v in d.items() if k != "emission"}).emission == "network"
    with pytest.raises(ValueError, match="`emission` must be one of"):
        SSRConfig(emission="both")
