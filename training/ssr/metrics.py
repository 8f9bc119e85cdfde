"""Image quality metrics (DESIGN section 7), mirroring src/metrics.rs.

PSNR and SSIM are computed on tonemapped 8-bit images: Uncharted 2 filmic (Hable) with
exposure 2 and white point 11.2, clamped to [0, 1], gamma 2.2, then round(255 v). RMSE and
relative MSE are on the HDR values. The temporal error is the L1 difference between the
prediction's and the reference's warped frame differences on tonemapped [0, 1] values.

    tonemap(v) = clamp(hable(2 v) / hable(11.2), 0, 1) ^ (1 / 2.2),   v := max(v, 0), NaN/Inf := 0
    hable(x)   = (x (A x + C B) + D E) / (x (A x + B) + D F) - E / F
                 A = 0.15, B = 0.50, C = 0.10, D = 0.20, E = 0.02, F = 0.30
    psnr       = 10 log10(255^2 / MSE) over every value of the 8-bit images (inf if equal)
    ssim       = Wang et al. 2004: 11x11 Gaussian window (sigma 1.5, normalised), K1 = 0.01,
                 K2 = 0.03, L = 255, evaluated at every window position fully inside the
                 image ("valid"), per channel, averaged; images smaller than 11 use a window
                 of min(11, W, H)
    rmse       = sqrt(mean((p - r)^2))
    relmse     = mean((p - r)^2 / (r^2 + 0.01))

Images are [C, H, W] (numpy arrays or torch tensors); the tonemap is computed in float32,
as the Rust code does, and everything after it in float64.
"""

from __future__ import annotations

from typing import Dict, Union

import numpy as np
import torch
import torch.nn.functional as F

EXPOSURE = 2.0
WHITE = 11.2
GAMMA = 2.2
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
RELMSE_EPS = 0.01

Image = Union[np.ndarray, torch.Tensor]


def _np(x: Image) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


HABLE = (0.15, 0.50, 0.10, 0.20, 0.02, 0.30)


def hable_curve(x, a, b, c, d, e, f):
    """Hable's Uncharted 2 curve with constants A..F (numpy or torch values)."""
    return (x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f) - e / f


def hable(x):
    """Hable's Uncharted 2 curve; float32 constants as in the Rust code."""
    return hable_curve(x, *(np.float32(v) for v in HABLE))


def tonemap(v: Image) -> np.ndarray:
    """Uncharted 2 filmic + gamma 2.2, float32 in [0, 1]; negative/non-finite -> 0."""
    x = _np(v).astype(np.float32, copy=True)
    x[~np.isfinite(x)] = 0.0
    np.maximum(x, np.float32(0.0), out=x)
    white = hable(np.float32(WHITE))
    t = np.clip(hable(np.float32(EXPOSURE) * x) / white, np.float32(0.0), np.float32(1.0))
    return np.power(t, np.float32(1.0 / GAMMA)).astype(np.float32)


def tonemap_u8(v: Image) -> np.ndarray:
    """tonemap quantised to 8 bits (round half up, as Rust's f32::round for v >= 0)."""
    return np.floor(tonemap(v) * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)


def _same(p: np.ndarray, r: np.ndarray) -> None:
    if p.shape != r.shape:
        raise ValueError(f"metric on different shapes: {list(p.shape)} vs {list(r.shape)}")


def psnr(pred: Image, ref: Image) -> float:
    """PSNR (dB) of the tonemapped 8-bit images; inf when identical."""
    p, r = _np(pred), _np(ref)
    _same(p, r)
    d = tonemap_u8(p).astype(np.float64) - tonemap_u8(r).astype(np.float64)
    mse = float(np.mean(d * d))
    return float("inf") if mse == 0.0 else 10.0 * np.log10(255.0 * 255.0 / mse)


def _gaussian(win: int, sigma: float) -> torch.Tensor:
    half = (win - 1) / 2.0
    g = torch.exp(-((torch.arange(win, dtype=torch.float64) - half) ** 2) / (2.0 * sigma * sigma))
    return g / g.sum()


def ssim_mean(x: torch.Tensor, y: torch.Tensor, data_range: float) -> torch.Tensor:
    """Mean SSIM of images [N, C, H, W] whose values span `data_range` (255 for 8-bit values,
    1 for [0, 1]): the window and constants of the module doc, differentiable (the training
    loss's l_ssim uses it too)."""
    c, h, w = x.shape[1:]
    win = min(SSIM_WINDOW, w, h)
    g = _gaussian(win, SSIM_SIGMA).to(dtype=x.dtype, device=x.device)
    k = (g[:, None] * g[None, :]).view(1, 1, win, win).expand(c, 1, win, win)

    def filt(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(t, k, groups=c)

    mx, my = filt(x), filt(y)
    vx = filt(x * x) - mx * mx
    vy = filt(y * y) - my * my
    cov = filt(x * y) - mx * my
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    return (((2 * mx * my + c1) * (2 * cov + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))).mean()


def ssim(pred: Image, ref: Image) -> float:
    """SSIM of the tonemapped 8-bit images [C, H, W] (see the module doc)."""
    p, r = _np(pred), _np(ref)
    _same(p, r)
    if p.ndim == 2:
        p, r = p[None], r[None]
    x = torch.from_numpy(tonemap_u8(p).astype(np.float64)).unsqueeze(0)
    y = torch.from_numpy(tonemap_u8(r).astype(np.float64)).unsqueeze(0)
    return float(ssim_mean(x, y, 255.0))


def rmse(pred: Image, ref: Image) -> float:
    p, r = _np(pred).astype(np.float64), _np(ref).astype(np.float64)
    _same(p, r)
    return float(np.sqrt(np.mean((p - r) ** 2)))


def relmse(pred: Image, ref: Image) -> float:
    p, r = _np(pred).astype(np.float64), _np(ref).astype(np.float64)
    _same(p, r)
    return float(np.mean((p - r) ** 2 / (r * r + RELMSE_EPS)))


def temporal_error(pred: Image, pred_prev: Image, ref: Image, ref_prev: Image, motion: Image) -> float:
    """Mean |(p_t - W(p_{t-1})) - (r_t - W(r_{t-1}))| over valid pixels and channels, on
    tonemapped [0, 1] values; `motion` [2, H, W] is frame t's motion (0 if nothing is valid)."""
    from .model import warp

    def tm(x: Image) -> torch.Tensor:
        return torch.from_numpy(tonemap(x)).unsqueeze(0)

    p, pp, r, rp = tm(pred), tm(pred_prev), tm(ref), tm(ref_prev)
    if p.shape != r.shape:
        raise ValueError(f"metric on different shapes: {list(p.shape)} vs {list(r.shape)}")
    m = torch.from_numpy(np.ascontiguousarray(_np(motion), dtype=np.float32)).unsqueeze(0)
    wp, valid = warp(pp, m)
    wr, _ = warp(rp, m)
    d = ((p - wp) - (r - wr)).abs() * valid
    n = float(valid.sum()) * p.shape[1]
    return 0.0 if n == 0 else float(d.sum()) / n


def image_metrics(pred: Image, ref: Image) -> Dict[str, float]:
    """psnr, ssim, rmse, relmse of one [C, H, W] image pair."""
    return {"psnr": psnr(pred, ref), "ssim": ssim(pred, ref), "rmse": rmse(pred, ref), "relmse": relmse(pred, ref)}


def mean_metrics(rows) -> Dict[str, float]:
    """Average of a list of metric dicts (PSNR averaged in dB; an inf PSNR is capped at 100)."""
    rows = list(rows)
    if not rows:
        return {}
    out = {}
    for k in rows[0]:
        vals = [min(r[k], 100.0) if k == "psnr" else r[k] for r in rows]
        out[k] = float(np.mean(vals))
    return out
