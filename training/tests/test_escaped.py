"""Config `escaped = "background"` (issue 11, the silhouettes against the sky): the traced
samples whose camera ray escaped to the environment are left out of what the network is fed
(model.fold_emission), since the background composite already holds the environment of each
footprint, and the mean correction compares the rest with the reconstruction
(model.traced_samples).

The property tests draw silhouette frames from their definition, independently of the
renderer: each pixel's footprint sees the sky (radiance S) over a fraction `coverage` and a
surface (radiance H) over the rest, so its reference is `coverage S + (1 - coverage) H`, the
background `coverage S`, and its one jittered sample is S with probability `coverage`, else
H. A reconstruction that averages the samples it is fed around each pixel, composited as the
engine does, must then keep the silhouettes' brightness, and does not when the escaped
samples are fed to it (what the twenty-ninth session measured on living-room: 15-39 % too
bright on its silhouettes)."""

import pytest
import torch
import torch.nn.functional as F

from ssr.model import (
    AtrousMeanCorrection,
    MeanCorrection,
    SSRConfig,
    composite_background,
    extra_buffers,
    fold_emission,
    mean_correction_of,
    traced_samples,
)

SKY, SURFACE = 4.0, 0.5


def silhouette_frame(gen: torch.Generator, h: int, w: int, t: int) -> dict:
    """One quarter-traced frame of a surface whose edge against the sky crosses every column:
    coverage ramps from 0 to 1 over 8 rows around a wavy edge. Radiances per pixel are S and
    H times a per-pixel texture in [0.5, 1.5] (the same for sky and surface, so the ratio of
    a region's means is what the composite gets wrong)."""
    y = torch.arange(h, dtype=torch.float64)[:, None]
    x = torch.arange(w, dtype=torch.float64)[None, :]
    edge = h / 2 + 4 * torch.sin(x / 5)
    cov = ((y - edge) / 8 + 0.5).clamp(0, 1)[None, None]
    tex = 0.5 + torch.rand((1, 3, h, w), generator=gen, dtype=torch.float64)
    sky, surface = SKY * tex, SURFACE * tex
    mask = torch.zeros((1, 1, h, w), dtype=torch.float64)
    dy, dx = ((0, 0), (1, 1), (1, 0), (0, 1))[t % 4]
    mask[..., dy::2, dx::2] = 1.0
    escaped = (torch.rand((1, 1, h, w), generator=gen, dtype=torch.float64) < cov).to(torch.float64) * mask
    color = torch.where(escaped > 0.5, sky, surface) * mask
    return {
        "color": color,
        "mask": mask,
        "background": cov * sky,
        "coverage": cov,
        "escaped": escaped,
        "emission": torch.zeros_like(color),
        "emission_footprint": torch.zeros_like(color),
        "reference": cov * sky + (1 - cov) * surface,
    }


def local_mean(frame: dict, radius: int = 3) -> torch.Tensor:
    """A reconstruction that trusts its samples: the mean of the traced samples within
    `radius` pixels (a box), where there are any."""
    k = 2 * radius + 1
    s = F.avg_pool2d(frame["color"] * frame["mask"], k, stride=1, padding=radius, count_include_pad=False)
    n = F.avg_pool2d(frame["mask"], k, stride=1, padding=radius, count_include_pad=False)
    return s / n.clamp_min(1e-9)


def silhouette_brightness(escaped: str, frames: int = 8) -> float:
    """Mean of the composited local-mean reconstruction over the silhouette pixels (0 <
    coverage < 1) against the reference's, over several frames."""
    gen = torch.Generator().manual_seed(5)
    cfg = SSRConfig(emission="background", escaped=escaped)
    got = want = 0.0
    for t in range(frames):
        f = silhouette_frame(gen, 64, 64, t)
        fed = fold_emission(f, cfg)
        out = composite_background(local_mean(fed), fed)
        rim = (f["coverage"] > 0) & (f["coverage"] < 1)
        got += out[rim.expand_as(out)].sum().item()
        want += f["reference"][rim.expand_as(out)].sum().item()
    return got / want


def test_silhouettes_keep_their_brightness_when_escaped_samples_are_left_to_the_background():
    assert abs(silhouette_brightness("background") - 1.0) < 0.03
    # what the shipped models do: the sky in the reconstruction and again in the composite
    assert silhouette_brightness("network") > 1.2


def test_fold_leaves_out_exactly_the_escaped_traced_pixels():
    gen = torch.Generator().manual_seed(1)
    f = silhouette_frame(gen, 16, 20, 1)
    f["escaped"][0, 0, 1, 1] = 0.5  # half of a pixel's samples: left out
    f["escaped"][0, 0, 3, 3] = float("nan")  # not a number: kept, as the engine keeps it
    fed = fold_emission(f, SSRConfig(escaped="background"))
    out = ~(f["escaped"] >= 0.5)
    assert torch.equal(fed["mask"], f["mask"] * out)
    assert torch.equal(fed["color"], f["color"] * out)
    assert fed["mask"].sum() < f["mask"].sum()
    # the default leaves the frame as it is
    assert fold_emission(f, SSRConfig()) is f


def test_a_frame_without_escapes_is_refused_naming_the_buffer():
    gen = torch.Generator().manual_seed(2)
    f = silhouette_frame(gen, 8, 8, 0)
    del f["escaped"]
    with pytest.raises(KeyError, match="escaped.*--resume"):
        fold_emission(f, SSRConfig(escaped="background"))


def test_config_escaped_reads_the_escapes_and_the_background():
    assert extra_buffers(SSRConfig(escaped="background")) == ("escaped", "background", "coverage")
    both = extra_buffers(SSRConfig(emission="background", escaped="background", albedo="footprint"))
    assert sorted(both) == sorted(
        ["albedo_footprint", "emission", "emission_footprint", "background", "coverage", "escaped"]
    )
    cfg = SSRConfig.from_json('{"enc":[16,32,28],"feature_pool":"max","input_channels":37,"k":8,'
                              '"tfa_hidden":8,"upsample":"bilinear","version":2,"exposure":"channel",'
                              '"remodulation":"current","history":"geometry"}')
    assert cfg.escaped == "network"  # files before the option
    assert SSRConfig(escaped="background").to_dict()["escaped"] == "background"
    with pytest.raises(ValueError, match="escaped"):
        SSRConfig(escaped="sky")


@pytest.mark.parametrize("kind", ["tiles16", "atrous"])
def test_the_mean_correction_restores_a_dark_reconstruction_of_the_hit_part(kind):
    """A reconstruction of the hit part 20 % too dark everywhere: with the escaped samples left
    out, the correction, comparing `(1 - coverage) sample` with `(1 - coverage) output`,
    brings the silhouettes and the surface back to the reference; the statistic of the models
    that are fed the escaped samples (`sample - background`) would, on these samples, not."""
    cfg = SSRConfig(emission="background", escaped="background", mean_correction=kind)
    mc = mean_correction_of(cfg)
    assert mc.escaped
    wrong = AtrousMeanCorrection() if kind == "atrous" else MeanCorrection(16)
    gen = torch.Generator().manual_seed(7)
    h, w = 64, 64
    for t in range(8):
        f = silhouette_frame(gen, h, w, t)
        f["normal"] = torch.zeros((1, 3, h, w), dtype=torch.float64)
        f["normal"][:, 2] = 1.0
        f["depth"] = torch.full((1, 1, h, w), 0.5, dtype=torch.float64)
        f["motion"] = torch.zeros((1, 2, h, w), dtype=torch.float64)
        fed = fold_emission(f, cfg)
        # the hit part's radiance (known here; 0 where the footprint is all sky)
        cov = f["coverage"]
        hit = (f["reference"] - f["background"]) / (1 - cov).clamp_min(1e-9)
        dark = 0.8 * torch.where(cov < 1, hit, torch.zeros_like(hit))
        got = mc(dark, fed)
        bad = wrong(dark, fed)
    # the reconstructed part of the output (the background is composited exactly)
    rim = ((f["coverage"] > 0) & (f["coverage"] < 1)).expand_as(got)
    surface = (f["coverage"] == 0).expand_as(got)

    def part(out: torch.Tensor, region: torch.Tensor) -> float:
        return ((out - f["background"])[region].sum() / (f["reference"] - f["background"])[region].sum()).item()

    for region in (rim, surface):
        assert abs(part(got, region) - 1.0) < 0.05, part(got, region)
    assert abs(part(bad, rim) - 1.0) > 0.1, part(bad, rim)


def test_traced_samples_of_each_kind():
    color = torch.tensor([[[[2.0]]]], dtype=torch.float64)
    bg, cov = torch.tensor(0.5, dtype=torch.float64), torch.tensor(0.25, dtype=torch.float64)
    f = {"color": color}
    assert traced_samples(f, bg, cov, False, color).item() == 1.5
    assert traced_samples(f, bg, cov, True, color).item() == 1.5  # (1 - 0.25) * 2
    f = {"color": torch.tensor([[[[float("nan")]]]])}
    assert traced_samples(f, bg, cov, True, color).item() == 0.0
