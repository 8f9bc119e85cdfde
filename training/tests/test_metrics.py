import math

import numpy as np
import pytest
import torch

from ssr.metrics import hable, image_metrics, mean_metrics, psnr, relmse, rmse, ssim, temporal_error, tonemap, tonemap_u8


def test_tonemap_anchors():
    # Hand-computed: hable(2) = (2 (0.3 + 0.05) + 0.004) / (2 (0.3 + 0.5) + 0.06) - 0.02 / 0.3
    #                         = 0.704 / 1.66 - 0.0666667 = 0.357430
    # hable(11.2) = (11.2 * 1.73 + 0.004) / (11.2 * 2.18 + 0.06) - 0.0666667
    #             = 19.38 / 24.476 - 0.0666667 = 0.725129
    # tonemap(1) = (0.357430 / 0.725129) ^ (1 / 2.2) = 0.492919 ^ 0.454545 = 0.725024 -> 185
    h2 = 0.704 / 1.66 - 0.02 / 0.3
    h11 = (11.2 * (0.15 * 11.2 + 0.05) + 0.004) / (11.2 * (0.15 * 11.2 + 0.5) + 0.06) - 0.02 / 0.3
    assert abs(float(hable(np.float32(2.0))) - h2) < 1e-6
    assert abs(h2 - 0.357430) < 1e-6 and abs(h11 - 0.725129) < 1e-6
    want = (h2 / h11) ** (1 / 2.2)
    assert abs(want - 0.725024) < 1e-6
    v = tonemap(np.array([0.0, 1.0, 1e9, -1.0, np.nan, np.inf], np.float32))
    # in float32 hable(0) = 0.004 / 0.060000002 - 0.06666666 = 7.45e-9, not 0: tonemap(0) = 2.3e-4,
    # which is still level 0 in 8 bits
    assert v[0] < 3e-4 and abs(v[1] - want) < 1e-6 and abs(v[2] - 1.0) < 1e-3
    assert v[3] == v[0] and v[4] == v[0] and v[5] == v[0]
    assert tonemap_u8(np.array([0.0, -1.0, np.nan], np.float32)).tolist() == [0, 0, 0]
    assert tonemap_u8(np.array([1.0], np.float32))[0] == 185
    # monotone
    x = np.linspace(0, 20, 1000, dtype=np.float32)
    assert np.all(np.diff(tonemap(x)) >= 0)


def _value_for_level(level: int) -> float:
    xs = np.arange(0, 100000, dtype=np.float32) * np.float32(1e-4)
    return float(xs[np.argmax(tonemap_u8(xs) == level)])


def test_psnr_known_values():
    a = np.fromfunction(lambda c, y, x: ((x + y + c) % 5) * 0.3, (3, 16, 16)).astype(np.float32)
    assert psnr(a, a) == math.inf
    # all zero vs a constant that tonemaps to 128: MSE = 128^2
    k = np.full((3, 16, 16), _value_for_level(128), np.float32)
    z = np.zeros_like(k)
    assert abs(psnr(z, k) - 20 * math.log10(255 / 128)) < 1e-9
    # one pixel of 48 off by 10 levels: MSE = 100 / 48
    r = np.full((3, 4, 4), _value_for_level(100), np.float32)
    p = r.copy()
    p[1, 2, 3] = _value_for_level(110)
    assert abs(psnr(p, r) - 10 * math.log10(255**2 / (100 / 48))) < 1e-9
    # torch tensors work the same
    assert psnr(torch.from_numpy(p), torch.from_numpy(r)) == psnr(p, r)


def test_ssim_known_values():
    a = np.fromfunction(lambda c, y, x: ((x + y + c) % 5) * 0.3, (3, 16, 16)).astype(np.float32)
    assert abs(ssim(a, a) - 1.0) < 1e-12
    # two different constants: only the luminance term, c1 / (128^2 + c1)
    k = np.full((3, 16, 16), _value_for_level(128), np.float32)
    c1 = (0.01 * 255) ** 2
    assert abs(ssim(np.zeros_like(k), k) - c1 / (128**2 + c1)) < 1e-9
    # hand-computed with a 1-pixel image: window 1, variance 0: (2 a b + c1) / (a^2 + b^2 + c1)
    p = np.full((1, 1, 1), _value_for_level(100), np.float32)
    r = np.full((1, 1, 1), _value_for_level(50), np.float32)
    assert abs(ssim(p, r) - (2 * 100 * 50 + c1) / (100**2 + 50**2 + c1)) < 1e-12
    # noise lowers it, symmetric
    rng = np.random.default_rng(0)
    n = (a + rng.normal(0, 0.2, a.shape)).astype(np.float32)
    assert 0 < ssim(n, a) < 0.99 and abs(ssim(n, a) - ssim(a, n)) < 1e-12


def test_hdr_errors():
    a = np.array([[[1.0, 3.0]]], np.float32)
    b = np.array([[[2.0, 3.0]]], np.float32)
    assert abs(rmse(a, b) - math.sqrt(0.5)) < 1e-12
    assert abs(relmse(a, b) - 0.5 / 4.01) < 1e-9
    with pytest.raises(ValueError, match="different shapes"):
        psnr(a, np.zeros((1, 1, 3), np.float32))


def test_temporal_error():
    def f(s):
        return np.fromfunction(lambda c, y, x: ((x + s) * 3 + y + c) * 0.1, (3, 7, 9)).astype(np.float32)

    motion = np.zeros((2, 7, 9), np.float32)
    motion[0] = -1.0
    assert temporal_error(f(1), f(0), f(1), f(0), motion) == 0.0
    assert temporal_error(f(1) + 0.5, f(0), f(1), f(0), motion) > 0.01
    assert temporal_error(f(1), f(0), f(1), f(0), np.full((2, 7, 9), 1e9, np.float32)) == 0.0


def test_image_and_mean_metrics():
    a = np.ones((3, 8, 8), np.float32)
    m = image_metrics(a, a)
    assert m["psnr"] == math.inf and m["rmse"] == 0 and m["relmse"] == 0 and abs(m["ssim"] - 1) < 1e-12
    avg = mean_metrics([m, {"psnr": 20.0, "ssim": 0.5, "rmse": 1.0, "relmse": 2.0}])
    assert avg == {"psnr": 60.0, "ssim": 0.75, "rmse": 0.5, "relmse": 1.0}
