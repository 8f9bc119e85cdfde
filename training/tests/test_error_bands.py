import json
import os

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from ssr.data import write_exr
from ssr.error_bands import band_errors, band_names, bands, gaussian_blur, main, measure, scene_column
from ssr.metrics import tonemap


def torch_blur(img, sigma):
    """The same blur by another route: torch's reflect padding and a 2-D convolution."""
    r = int(np.ceil(3 * sigma))
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    g = torch.exp(-x * x / (2 * sigma * sigma))
    g = g / g.sum()
    k = (g[:, None] * g[None, :])[None, None]
    t = torch.from_numpy(img).permute(2, 0, 1)[:, None]
    t = F.conv2d(F.pad(t, (r, r, r, r), mode="reflect"), k)
    return t[:, 0].permute(1, 2, 0).numpy()


def test_the_blur_is_a_normalised_gaussian_with_reflected_borders():
    rng = np.random.default_rng(1)
    img = rng.random((19, 23, 3))
    assert np.allclose(gaussian_blur(img, 2.0), torch_blur(img, 2.0), atol=1e-12)
    assert np.allclose(gaussian_blur(np.full((9, 11, 3), 0.7), 1.5), 0.7)


def test_a_flat_offset_is_all_low_and_a_checkerboard_all_high():
    h, w = 32, 32
    ref = np.full((h, w, 3), 0.2, dtype=np.float32)
    a, (hi, lo) = bands(np.full((h, w, 3), 0.3, dtype=np.float32), ref, [4.0])
    assert a > 0 and np.isclose(lo, a) and hi < 1e-20
    yy, xx = np.mgrid[0:h, 0:w]
    check = np.where((yy + xx)[..., None] % 2 == 0, 0.3, 0.1).astype(np.float32) * np.ones((1, 1, 3), np.float32)
    a, (hi, lo) = bands(check, ref, [4.0])
    # the checkerboard's mean error is small against its swing: nearly all of it is high
    e = tonemap(check) - tonemap(ref)
    assert np.isclose(a, (e.astype(np.float64) ** 2).mean())
    assert hi > 0.9 * a and lo < 0.1 * a


def test_a_sinusoid_lands_in_the_band_of_its_scale():
    # cos(w x) with extrema at both borders (81 pixels, period 40) continues exactly under the
    # reflection, so each blur scales it by the discrete Gaussian's response at w
    n, period = 81, 40.0
    w = 2 * np.pi / period
    x = np.arange(n)
    e = np.cos(w * x)[None, :, None] * np.ones((3, 1, 3))

    def response(sigma):
        r = int(np.ceil(3 * sigma))
        k = np.arange(-r, r + 1)
        g = np.exp(-k * k / (2 * sigma * sigma))
        return float((g * np.cos(w * k)).sum() / g.sum())

    fine, mid, coarse = band_errors(e, [2.0, 24.0])
    power = float((e * e).mean())
    r2, r24 = response(2.0), response(24.0)
    assert np.isclose(fine, power * (1 - r2) ** 2, rtol=1e-9)
    assert np.isclose(mid, power * (r2 - r24) ** 2, rtol=1e-9)
    assert np.isclose(coarse, power * r24 ** 2, rtol=1e-9, atol=1e-15)
    assert mid > 0.85 * power and fine < 0.01 * power and coarse < 1e-4 * power
    assert band_names([2, 8, 24]) == ["below 2", "2-8", "8-24", "above 24"]
    assert band_names([4]) == ["high (below sigma 4)", "low (sigma 4)"]


def test_bad_sigmas_are_refused(tmp_path, capsys):
    ref_root, pred_root = _dataset(tmp_path)
    for bad in ("0", "2,x", "4,4", "-1"):
        with pytest.raises(SystemExit):
            main(["--pred", str(pred_root), "--ref", str(ref_root), "--methods", "m", "--sigmas", bad])
        assert "--sigmas" in capsys.readouterr().err


def test_several_bands_print_a_column_each(tmp_path, capsys):
    ref_root, pred_root = _dataset(tmp_path)
    assert main(["--pred", str(pred_root), "--ref", str(ref_root), "--methods", "m", "--sigmas", "1,2"]) == 0
    out = capsys.readouterr().out
    assert "| below 1 | 1-2 | above 2 |" in out and "| living-room | m |" in out


def test_columns_group_the_procedural_seeds():
    assert scene_column("procedural_1000003_test_000") == "procedural"
    assert scene_column("living-room_test_000") == "living-room"
    assert scene_column("barn-lamp_test_001") == "barn-lamp"


def _dataset(tmp_path):
    ref_root, pred_root = tmp_path / "ds", tmp_path / "pred"
    rng = np.random.default_rng(3)
    for seq in ("living-room_test_000", "procedural_1000000_test_000", "procedural_1000001_test_000"):
        d = ref_root / "test" / seq
        d.mkdir(parents=True)
        json.dump({"reference_noise": {"per_frame": {"frame_0000": 30.0, "frame_0001": 40.0}}}, open(d / "sequence.json", "w"))
        for i in range(2):
            ref = rng.random((3, 8, 8)).astype(np.float32)
            write_exr(str(d / f"frame_{i:04d}.exr"), {"reference": ref})
            p = pred_root / "m" / "test" / seq
            p.mkdir(parents=True, exist_ok=True)
            write_exr(str(p / f"frame_{i:04d}.exr"), {"pred": ref * 1.1}, suffixes={"pred": ("R", "G", "B")})
    return ref_root, pred_root


def test_measure_averages_each_column_and_the_reference_noise(tmp_path):
    ref_root, pred_root = _dataset(tmp_path)
    rows = measure(str(pred_root), str(ref_root), "test", ["m"], None, [2.0])
    assert set(rows) == {("m", "living-room"), ("m", "procedural")}
    assert rows[("m", "procedural")]["frames"] == 4 and rows[("m", "living-room")]["frames"] == 2
    # halves at 30 and 40 dB: the full reference's noise is their mean squared error over 4
    want = -10 * np.log10((10 ** -3 + 10 ** -4) / 2 / 4)
    assert np.isclose(rows[("m", "living-room")]["ref_noise"], want)
    r = rows[("m", "procedural")]
    high, low = r["bands"]
    assert np.isfinite(r["all"]) and low > r["all"] and high > r["all"]
    only = measure(str(pred_root), str(ref_root), "test", ["m"], ["living-room"], [2.0])
    assert set(only) == {("m", "living-room")}


def test_a_missing_prediction_is_named(tmp_path, capsys):
    ref_root, pred_root = _dataset(tmp_path)
    os.remove(pred_root / "m" / "test" / "living-room_test_000" / "frame_0001.exr")
    with pytest.raises(FileNotFoundError, match="living-room_test_000/frame_0001"):
        measure(str(pred_root), str(ref_root), "test", ["m"], None, [2.0])
    assert main(["--pred", str(pred_root), "--ref", str(ref_root), "--methods", "m"]) == 1
    assert "frame_0001" in capsys.readouterr().err
