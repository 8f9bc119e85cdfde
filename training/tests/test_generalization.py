"""Properties that make SSR hold up on scenes it never saw (issue 11, part 2).

Each test pins down one of the problems found in the shipped v1 model (training/README.md,
"Generalisation"); each fails on the v1 pipeline:

* exposure: the network saw absolute radiance, so its output brightness was a compressive
  function of the scene's light power (16x the light gave 3.6x the output on the training
  Cornell box) and carried the training scenes' warm light colour into grey scenes; the
  shadow buffer (the light's radiance, 1e4-1e5 for an environment's sun) was far outside
  anything seen in training. With per-channel exposure normalisation (colour and shadow
  each by their own) the whole pipeline is equivariant: scaling channel c of every
  radiance input by k_c scales output channel c by k_c, exactly, for any weights; scaling
  the shadow alone (a sun instead of an area light) changes nothing.
* remodulation: demodulating with the current albedo and remodulating with the accumulated
  one multiplied the output by (albedo_acc + eps) / (albedo + eps): up to 65x on black-albedo
  emitters. An identity U-Net must give back the input radiance at every traced pixel.
* history: after a camera cut the TFA kept 55-86 % of unrelated history. History whose
  depth or normal disagrees with the current frame is now rejected (alpha = 0, W(o) = 0).
"""

import pytest
import torch

from ssr.export import random_model
from ssr.golden import make_frames
from ssr.model import (
    ALBEDO_EPS,
    CEILING_DECAY,
    EXPOSURE_CHANNELS,
    HISTORY_DEPTH_TOL,
    HISTORY_NORMAL_TOL,
    SSRConfig,
    SSRModel,
    frame_exposure,
    rescale_log,
)

H, W = 24, 40


def _scaled(frames, k, ks=None):
    kk = k.view(1, 3, 1, 1)
    ks = kk if ks is None else ks.view(1, 3, 1, 1)
    return [{**f, "color": f["color"] * kk, "shadow": f["shadow"] * ks} for f in frames]


def _textured_frames(seed=5, count=4):
    """Random frames with the pixel classes of real scenes: textured albedo with near-black
    texels, black-albedo emitters (bright, albedo 0), sky (albedo 1, normal 0, depth 1)."""
    frames = make_frames(seed, H, W, count)
    g = torch.Generator().manual_seed(seed)
    emit = torch.rand(1, 1, H, W, generator=g) < 0.1
    sky = (torch.rand(1, 1, H, W, generator=g) < 0.1) & ~emit
    dark = (torch.rand(1, 3, H, W, generator=g) < 0.15) & ~(emit | sky)
    for f in frames:
        m = f["mask"]
        f["albedo"] = torch.where(emit, torch.zeros_like(f["albedo"]), f["albedo"])
        f["albedo"] = torch.where(sky, torch.ones_like(f["albedo"]), f["albedo"])
        f["albedo"] = torch.where(dark, f["albedo"] * 0.01, f["albedo"])
        f["color"] = torch.where(emit, torch.full_like(f["color"], 25.0) * m, f["color"])
        f["normal"] = torch.where(sky, torch.zeros_like(f["normal"]), f["normal"])
        f["depth"] = torch.where(sky, torch.ones_like(f["depth"]), f["depth"])
    return frames


def _identity_unet_(model: SSRModel) -> SSRModel:
    """U-Net weights that pass e (A_t channels 0..2) straight to o: o = e exactly.

    enc1.0 and enc1.2 copy the three e channels (e >= 0, so the ReLUs keep them), dec1.0 and
    dec1.2 copy them to the output; every other U-Net weight and bias is 0."""
    with torch.no_grad():
        for p in model.unet.parameters():
            p.zero_()
        u = model.unet
        for i in range(3):
            u.enc1[0].weight[i, i, 1, 1] = 1.0
            u.enc1[2].weight[i, i, 1, 1] = 1.0
            u.dec1[0].weight[i, i, 1, 1] = 1.0
            u.dec1[2].weight[i, i, 1, 1] = 1.0
    return model


# ----------------------------------------------------------------------------- exposure


@pytest.mark.parametrize("k", [(7.0, 0.25, 40.0), (1e-3, 1e-3, 1e-3), (300.0, 300.0, 300.0)])
def test_pipeline_is_exposure_equivariant(k):
    """Scaling every radiance input of channel c by k_c scales output channel c by k_c."""
    model = random_model(0)
    frames = make_frames(count=4)
    k = torch.tensor(k)
    with torch.no_grad():
        base = model.run_sequence(frames)
        scaled = model.run_sequence(_scaled(frames, k))
    for t, (a, b) in enumerate(zip(base, scaled)):
        want = a["output"] * k.view(1, 3, 1, 1)
        torch.testing.assert_close(b["output"], want, rtol=2e-4, atol=1e-6 * float(want.abs().max()), msg=f"frame {t}")
        # the network itself sees the same normalised inputs
        torch.testing.assert_close(b["a_cur"], a["a_cur"], rtol=1e-4, atol=2e-5, msg=f"frame {t}")


def test_shadow_magnitude_does_not_matter():
    """The shadow buffer carries the light's own radiance: ~20 for an area light, ~7e4 for an
    environment map's sun. Its magnitude is normalised on its own, so the output is the same."""
    model = random_model(0)
    frames = make_frames(count=3)
    one = torch.ones(3)
    with torch.no_grad():
        base = model.run_sequence(frames)
        sun = model.run_sequence(_scaled(frames, one, torch.tensor([3000.0, 5000.0, 4000.0])))
    for t, (a, b) in enumerate(zip(base, sun)):
        torch.testing.assert_close(b["output"], a["output"], rtol=2e-4, atol=1e-6 * float(a["output"].abs().max()), msg=f"frame {t}")


def test_exposure_statistic():
    """s = geometric mean of the positive demodulated traced samples (colour) and of the positive
    traced shadow samples, per channel; 1 for a channel with no positive sample."""
    f = make_frames(count=1)[0]
    s = frame_exposure(f)
    assert s.shape == (1, 6, 1, 1)
    d = torch.cat([f["color"] / (f["albedo"] + ALBEDO_EPS), f["shadow"]], 1)
    for c in range(6):
        v = d[:, c][(f["mask"][:, 0] > 0.5) & (d[:, c] > 0)]
        torch.testing.assert_close(s[0, c, 0, 0], torch.exp(torch.log(v).mean()))
    black = {**f, "color": f["color"] * torch.tensor([1.0, 0.0, 1.0]).view(1, 3, 1, 1)}
    assert frame_exposure(black)[0, 1, 0, 0] == 1.0


def test_shared_exposure_statistic():
    """Config exposure "shared": one exposure per buffer, the geometric mean of every positive
    traced sample of its three channels (colour demodulated, shadow), the same for each
    channel; a black channel takes the buffer's value (not 1)."""
    f = make_frames(count=1)[0]
    d = torch.cat([f["color"] / (f["albedo"] + ALBEDO_EPS), f["shadow"]], 1)
    traced = (f["mask"][:, 0] > 0.5)[:, None].expand(-1, 3, -1, -1)
    for shared, black in ((frame_exposure(f, shared=True), False),
                          (frame_exposure({**f, "color": f["color"] * torch.tensor([1.0, 0.0, 1.0]).view(1, 3, 1, 1)}, shared=True), True)):  # fmt: skip
        for b in (0, 3):
            v = d[:, b : b + 3].clone()
            if black and b == 0:
                v[:, 1] = 0.0
            v = v[traced & (v > 0)]
            for c in range(b, b + 3):
                torch.testing.assert_close(shared[0, c, 0, 0], torch.exp(torch.log(v).mean()))


def test_shared_exposure_keeps_the_samples_colour_and_uniform_equivariance():
    """With one exposure per buffer the network is fed the samples' colour as it is: the
    ratio between a traced sample's channels in its normalised input is the sample's own,
    where per-channel exposures rescale each channel by its own geometric mean (in a
    window-lit room, most samples dim and tinted by the walls and a few bright ones carrying
    the light, those means part from the light's colour: training/README, Generalisation 26).
    The pipeline stays equivariant to scaling the three channels alike, and no longer to
    scaling them apart."""
    frames = make_frames(count=3)
    # dim samples tinted blue, a few bright neutral ones: the means are about neutral
    g = torch.Generator().manual_seed(4)
    for f in frames:
        bright = torch.rand(f["mask"].shape, generator=g) < 0.02
        tint = torch.tensor([0.2, 0.5, 1.0]).view(1, 3, 1, 1)
        f["color"] = torch.where(bright, torch.full_like(f["color"], 60.0), 0.05 * tint * f["albedo"]) * f["mask"]
    e = lambda m, fr: m.history(fr, None)["a_cur"][:, :3]  # noqa: E731  (log1p(c / s / (albedo + eps)))
    shared = random_model(0, SSRConfig(exposure="shared"))
    channel = random_model(0, SSRConfig(exposure="channel"))
    f = frames[0]
    dim = (f["mask"][:, 0] > 0.5) & (f["color"][:, 2] < 1.0)
    with torch.no_grad():
        for model, keeps in ((shared, True), (channel, False)):
            x = torch.expm1(e(model, f))  # c / s / (albedo + eps) per channel
            ratio = (x[:, 0] / x[:, 2])[dim]
            want = (f["color"][:, 0] / (f["albedo"][:, 0] + ALBEDO_EPS) / (f["color"][:, 2] / (f["albedo"][:, 2] + ALBEDO_EPS)))[dim]
            close = torch.allclose(ratio, want, rtol=1e-3)
            assert close == keeps, (model.cfg.exposure, float(ratio.mean()), float(want.mean()))
        for k, same in ((torch.tensor([5.0, 5.0, 5.0]), True), (torch.tensor([7.0, 0.25, 40.0]), False)):
            base = shared.run_sequence(frames)
            scaled = shared.run_sequence(_scaled(frames, k))
            for a, b in zip(base, scaled):
                ok = torch.allclose(b["output"], a["output"] * k.view(1, 3, 1, 1), rtol=2e-3, atol=1e-5 * float(a["output"].abs().max()))
                assert ok == same, k


def test_exposure_follows_light_changes_and_rescales_history():
    """A light 1.5x brighter mid-sequence: the exposure eases towards it (EMA); 10x brighter (a
    cut, a light switched on): it jumps. The history is re-expressed in the new exposure so the
    radiance it stands for is unchanged."""
    model = random_model(0)
    frames = make_frames(count=4, geometry="random")  # a constant light
    with torch.no_grad():
        s0 = [x["exposure"] for x in model.run_sequence(frames)]
        s1 = [x["exposure"] for x in model.run_sequence(frames[:2] + _scaled(frames[2:], torch.full((3,), 1.5)))]
        s10 = [x["exposure"] for x in model.run_sequence(frames[:2] + _scaled(frames[2:], torch.full((3,), 10.0)))]
    s0, s1, s10 = ([x[:, :EXPOSURE_CHANNELS] for x in s] for s in (s0, s1, s10))  # s without the running max
    assert torch.allclose(s0[1], s0[0], rtol=0.3)
    eased = s1[2] / s0[2]
    assert (eased > 1.02).all() and (eased < 1.1).all()  # 1.5^0.1 = 1.04: eased
    torch.testing.assert_close(s10[2] / s0[2] / 10.0, torch.ones_like(s0[2]), rtol=0.35, atol=0)  # jumped
    # rescale_log keeps (exp(v) - 1) * s: the radiance a log value stands for
    v = torch.linspace(-0.5, 6.0, 50).view(1, 1, 50, 1).expand(1, 3, 50, 1)
    ratio = torch.tensor([0.1, 1.0, 7.0]).view(1, 3, 1, 1)  # per channel
    w = rescale_log(v, ratio)
    pos = v > 0
    torch.testing.assert_close(((torch.exp(w) - 1) / ratio)[pos], (torch.exp(v) - 1).expand_as(w)[pos], rtol=1e-5, atol=1e-6)
    assert torch.equal(w[~pos], v[~pos])  # non-positive log values (o < 0: radiance 0) are kept


# ----------------------------------------------------------------------------- remodulation


@pytest.mark.parametrize("ceiling", ["none", "max"])
def test_identity_unet_gives_back_the_input_radiance(ceiling):
    """o = e at every pixel must remodulate to the input colour: demodulation and remodulation
    use the same (current) albedo, on textured, near-black, emitter (albedo 0) and sky pixels,
    with camera motion and history (frames 1.., where the accumulated albedo differs). The
    ceiling lets every sample through (it may round the brightest one's o by an ulp)."""
    model = _identity_unet_(SSRModel(SSRConfig(ceiling=ceiling)))
    frames = _textured_frames()
    with torch.no_grad():
        res = model.run_sequence(frames)
    for t, (f, r) in enumerate(zip(frames, res)):
        if ceiling == "none":
            torch.testing.assert_close(r["o"], r["a_cur"][:, :3], rtol=0, atol=0)
        c = f["color"]
        torch.testing.assert_close(r["output"], c, rtol=1e-4, atol=1e-5 * float(c.max()), msg=f"frame {t}")
        # and so the mean over a frame is the input's
        torch.testing.assert_close(r["output"].mean((2, 3)), c.mean((2, 3)), rtol=1e-4, atol=0)


# ----------------------------------------------------------------------------- ceiling


def _brightest_demodulated(frame) -> torch.Tensor:
    """[3]: per channel, the max over traced pixels of color / (albedo + eps), computed directly."""
    d = frame["color"] / (frame["albedo"] + ALBEDO_EPS)
    return torch.stack([d[0, c][frame["mask"][0, 0] > 0.5].max() for c in range(3)])


def test_ceiling_stops_an_extrapolating_network_from_blowing_up_a_bright_pixel():
    """A held-out scene's tiny emitter once came out 24x brighter than any sample of it, tripling
    the frame's mean. With `ceiling = "max"` the output, demodulated, never exceeds the running max
    M of the demodulated samples, M_t = max(m_t, CEILING_DECAY M_{t-1}), whatever the network
    does; where the network stays below it nothing changes."""
    frames = _textured_frames()
    frames[1]["color"][:, :, 3, 5] = 5000.0  # a bright sample, traced or not
    frames[1]["mask"][:, :, 3, 5] = 1.0
    frames[1]["albedo"][:, :, 3, 5] = 0.8
    wild = _identity_unet_(random_model(0))
    with torch.no_grad():
        wild.unet.dec1[2].bias.fill_(3.0)  # o = e + 3: every pixel e^3 = 20x too bright
        res = wild.run_sequence(frames)
        free = SSRModel(SSRConfig(ceiling="none"))
        free.load_state_dict(wild.state_dict())
        res_free = free.run_sequence(frames)
    m = None
    for t, (f, r, rf) in enumerate(zip(frames, res, res_free)):
        m = _brightest_demodulated(f) if m is None else torch.maximum(_brightest_demodulated(f), CEILING_DECAY * m)
        torch.testing.assert_close(r["exposure"][0, EXPOSURE_CHANNELS:, 0, 0], m, rtol=1e-6, atol=0)
        mc = m.view(1, 3, 1, 1)
        demod = r["output"] / (f["albedo"] + ALBEDO_EPS)
        assert (demod <= mc * (1 + 1e-5)).all(), f"frame {t}"
        demod_free = rf["output"] / (f["albedo"] + ALBEDO_EPS)
        assert (demod_free.amax(dim=(2, 3)) > 5 * m).all()  # without the ceiling, the blow-up
        below = demod_free < mc * 0.999
        torch.testing.assert_close(r["output"][below], rf["output"][below], rtol=1e-5, atol=1e-6)
        # the history carries the clamped o
        torch.testing.assert_close(r["state"][1], r["o"], rtol=0, atol=0)


def test_ceiling_needs_exposure_and_old_files_read_none():
    with pytest.raises(ValueError, match="ceiling"):
        SSRConfig(exposure="none")
    d = SSRConfig().to_dict()
    assert d["ceiling"] == "max"
    del d["ceiling"]  # a version-2 file written before the option
    assert SSRConfig.from_dict(d).ceiling == "none"


# ----------------------------------------------------------------------------- history


def test_history_with_other_geometry_is_rejected():
    """A camera cut without reset: the previous frames show another scene, the motion keeps
    the history on screen. Where depth or normal disagree the TFA must not blend (alpha 0,
    A_acc = A_t) and the U-Net must not see the old output (W(o) = 0); where they agree
    the history is used."""
    model = random_model(0)
    a = make_frames(1, H, W, 3)
    b = make_frames(2, H, W, 4, "random")[3]
    b["motion"] = torch.zeros_like(b["motion"])
    with torch.no_grad():
        r2 = model.run_sequence(a)[-1]
        # a block of the new frame keeps the old geometry (same surfaces, seen again)
        acc = r2["a_acc"]
        b["depth"][:, :, :8, :] = acc[:, 12:13, :8, :]
        b["normal"][:, :, :8, :] = acc[:, 6:9, :8, :]
        r = model(b, r2["state"])
    wa, at = r["warp_acc"], r["a_cur"]
    acc_prev = r2["a_acc"]
    depth_bad = (acc_prev[:, 12] - at[:, 12]).abs() > HISTORY_DEPTH_TOL * at[:, 12]
    normal_bad = ((acc_prev[:, 6:9] - at[:, 6:9]) ** 2).sum(1) > HISTORY_NORMAL_TOL
    bad = depth_bad | normal_bad
    assert bad.float().mean() > 0.5 and (~bad).any()
    alpha = r["tfa_weights"][:, 1]
    assert torch.equal(alpha[bad], torch.zeros(int(bad.sum())))
    assert torch.equal(r["warp_valid"][:, 0][bad], torch.zeros(int(bad.sum())))
    badc = bad.unsqueeze(1)
    assert torch.equal(r["warp_out"].masked_select(badc.expand_as(r["warp_out"])), torch.zeros(3 * int(bad.sum())))
    assert torch.equal(r["a_acc"].masked_select(badc.expand_as(at)), at.masked_select(badc.expand_as(at)))
    assert (alpha[~bad] > 0).all()
    del wa


def test_legacy_config_keeps_v1_behaviour():
    """Version-1 weights run the v1 pipeline: no exposure, accumulated albedo, on-screen test only."""
    legacy = SSRConfig.from_dict(
        {"enc": [16, 32, 28], "feature_pool": "max", "input_channels": 37, "k": 8, "tfa_hidden": 8, "upsample": "bilinear", "version": 1}
    )
    assert (legacy.exposure, legacy.remodulation, legacy.history) == ("none", "accumulated", "screen")
    assert legacy.to_dict()["version"] == 1 and "exposure" not in legacy.to_dict()
    model = random_model(0, legacy)
    frames = make_frames(count=2)
    with torch.no_grad():
        r = model.run_sequence(frames)
    assert torch.equal(r[1]["exposure"], torch.ones_like(r[1]["exposure"]))
    from ssr.model import remodulate

    torch.testing.assert_close(r[1]["output"], remodulate(r[1]["o"], r[1]["a_acc"][:, 3:6]))
