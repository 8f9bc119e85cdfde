"""Training losses (DESIGN section 4).

Sequences are T = 5 frames. `preds` and `refs` are radiance (linear HDR, the remodulated
`output` of the model and the N-spp reference), [N, T, 3, H, W] or lists of T [N, 3, H, W].

    l_s   spatial: SMAPE(p_t, r_t), weighted over frames by FRAME_WEIGHTS
    l_t   temporal: SMAPE(p_t - p_{t-1}, r_t - r_{t-1}) for t >= 1, weighted by FRAME_WEIGHTS[t]
    l_e   relative edge loss (HFEN): mean |LoG(p_t) - LoG(r_t)| / (|LoG(r_t)| + eps), per
          channel, weighted by FRAME_WEIGHTS
    l_wt  warped temporal, last two frames only: with the motion of the last frame T-1,
          d_p = p_{T-1} - W(p_{T-2}), d_r = r_{T-1} - W(r_{T-2}); L1 of d_p - d_r over the
          pixels whose warp is valid, on log1p-compressed radiance (HDR-robust)
    l_m   brightness: SMAPE between the MEAN_BLOCK x MEAN_BLOCK block means of p_t and r_t,
          weighted by FRAME_WEIGHTS. The per-pixel terms are relative, so on a scene where
          few samples find light they leave the image's level loosely tied to the
          reference; this term ties the local mean radiance (issue 11; weight 5 took the
          val brightness error from 44.7 % to 30.7 %, training/README.md).
    l_mm  metal brightness: l_m over the metal pixels alone (metallic >= METAL_THRESHOLD, the
          region of ssr.brightness): per block, SMAPE between the means of p_t and of r_t over
          the block's metal pixels, averaged over the blocks of the whole batch weighted by
          their metal pixel counts (the metal's relative level error per metal pixel, so a
          frame with a little metal weighs little beside one with much),
          weighted by FRAME_WEIGHTS. Metal is the darkest region of every generic model's
          output (training/README.md, Generalisation 27): its samples are the most
          heavy-tailed of a frame, and the per-pixel terms reward a median. Weight 0 by
          default (not computed; needs aux `metallic`); `--lambda mm=W` turns it on.
    l_ssim structural: 1 - SSIM(tm(p_t), tm(r_t)), weighted by FRAME_WEIGHTS, where tm is the
          metric's tonemap (metrics.py: Hable filmic, exposure 2, white 11.2, gamma 2.2) in
          [0, 1] without the 8-bit rounding, and SSIM the metric's (11x11 Gaussian window,
          sigma 1.5, K1 0.01, K2 0.03, valid window positions, per channel, averaged). Weight
          0 by default (not computed); `--lambda ssim=W` turns it on.
    l_a   albedo loss, last frame only: L1 in the log-demodulated space where the network
          predicts, between its raw output o_{T-1} and the reference demodulated by the same
          albedo (and exposure s) the model remodulates with:
              l_a = mean | o - log(1 + (r / s) / (albedo_mod + 0.00316)) |
          (o = demodulate(r / s, albedo_mod) is exactly the prediction that remodulates to r;
          albedo_mod is the current albedo for config v2, the accumulated one for v1, s = 1
          without exposure normalisation).
          It supervises o directly, including where remodulation clamps exp(o) - 1 < 0 and
          radiance losses give no gradient, and it weighs dark-albedo regions fairly.

    l_n2n  mean-seeking relative L2 (Lehtinen et al. 2018, "Noise2Noise", their HDR loss):
          sum_t w_t mean((p_t - r_t)^2 / (sg(max(p_t, 0)) + N2N_EPS)^2), sg: no gradient
          through the denominator. Its expected gradient over a reference's Monte Carlo noise
          is its gradient at the noise-free reference (the noise is zero-mean and the
          denominator does not depend on it), so it can train on cheap noisy references
          where the relative L1 terms above, which seek a median, cannot. Weight 0 by
          default (not computed); `--lambda n2n=W` turns it on.

    l_tml2 mean-seeking L2 weighted as the metric weighs each pixel: the first-order
          expansion of the tonemapped L2 (DESIGN §7's tonemap, `tonemap_slope`) around the
          prediction, sum_t w_t mean((tm'(clamp(sg(p_t), TML2_LO, TML2_HI)) (p_t - r_t))^2).
          TML2_LO is where l_ssim's TONEMAP_FLOOR clamps the curve (darker, the gamma's
          slope grows without bound, and the weight is held at that value's); TML2_HI is
          just below the white point (brighter, the tonemap's slope is 0). Its weight does
          not depend on the reference, so like l_n2n it seeks the mean under a reference's
          noise, but it does not let the darkest pixels dominate. Weight 0 by default (not
          computed); `--lambda tml2=W` turns it on.

The frame-weighted terms are plain weighted sums sum_t w_t * l(t) (not normalised by
sum w_t). total = 0.7 l_s + 0.1 l_t + 0.2 l_e + 0.4 l_wt + 5.0 l_a + 5.0 l_m + 0 l_ssim
+ 0 l_mm + 0 l_n2n + 0 l_tml2 (LAMBDAS).
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple, Union

import torch
import torch.nn.functional as F

from .metrics import EXPOSURE, GAMMA, HABLE, WHITE, hable_curve, ssim_mean
from .model import demodulate, warp

FRAME_WEIGHTS: Tuple[float, ...] = (0.05, 0.25, 0.5, 0.75, 1.0)
LAMBDAS: Dict[str, float] = {"s": 0.7, "t": 0.1, "e": 0.2, "wt": 0.4, "a": 5.0, "m": 5.0, "ssim": 0.0, "mm": 0.0, "n2n": 0.0, "tml2": 0.0}
# Terms computed only where their weight is not 0 (their defaults are 0, so a run config
# written before one of them existed means it at 0: train.normalised_config).
OPTIONAL_TERMS: Tuple[str, ...] = ("ssim", "mm", "n2n", "tml2")
# Metal pixels for l_mm: metallic at least this (ssr.brightness's `metal` region).
METAL_THRESHOLD = 0.5
# Below this the tonemap's gamma 1/2.2 has an unbounded slope: l_ssim clamps its input there.
TONEMAP_FLOOR = 1e-4
MEAN_BLOCK = 16
SMAPE_EPS = 1e-2
HFEN_EPS = 1e-2
N2N_EPS = 1e-2
LOG_SIZE = 9
LOG_SIGMA = 1.5


def _hable_inverse(h: float) -> float:
    """The radiance x with hable(EXPOSURE x) / hable(WHITE) = h in (0, 1), the metric's
    tonemap before its gamma (bisection; the curve rises)."""
    lo, hi, white = 0.0, WHITE / EXPOSURE, hable_curve(WHITE, *HABLE)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if hable_curve(EXPOSURE * mid, *HABLE) / white < h else (lo, mid)
    return 0.5 * (lo + hi)


TML2_LO = _hable_inverse(TONEMAP_FLOOR)
"""l_tml2's slope is held below this radiance (about 1.3e-4, which the tonemap maps to
about 3.9 of 255): where l_ssim's TONEMAP_FLOOR clamps the curve, whose gamma slope is
unbounded at 0."""
TML2_HI = 0.99 * WHITE / EXPOSURE
"""l_tml2's slope is held above this radiance: just below the white point, where it is 0."""

Frames = Union[torch.Tensor, Sequence[torch.Tensor]]


def _frames(x: Frames, name: str) -> List[torch.Tensor]:
    """The frames of `x` as a list of [N, C, H, W] (a [N, T, C, H, W] tensor unbound along T,
    one operation whose backward is one stack: indexing a stacked tensor per frame and term
    instead made each index's backward a zero-filled tensor of the whole sequence; the loss
    and its gradient are the same, and its forward and backward at batch 8, 8 frames of
    64x64, one thread, took 0.25 s against 0.28)."""
    if isinstance(x, torch.Tensor):
        frames = list(x.unbind(1)) if x.dim() == 5 else []
    else:
        frames = list(x)
    if not frames or any(f.dim() != 4 or f.shape != frames[0].shape for f in frames):
        got = list(x.shape) if isinstance(x, torch.Tensor) else [list(f.shape) for f in frames]
        raise ValueError(f"{name}: expected [N, T, C, H, W] (or a list of [N, C, H, W]), got {got}")
    return frames


def _shape(frames: List[torch.Tensor]) -> List[int]:
    """[N, T, C, H, W] of a list of frames."""
    n, c, h, w = frames[0].shape
    return [n, len(frames), c, h, w]


def smape(p: torch.Tensor, r: torch.Tensor, eps: float = SMAPE_EPS) -> torch.Tensor:
    """Symmetric mean absolute percentage error: mean(|p - r| / (|p| + |r| + eps))."""
    return ((p - r).abs() / (p.abs() + r.abs() + eps)).mean()


def log_kernel(size: int = LOG_SIZE, sigma: float = LOG_SIGMA) -> torch.Tensor:
    """Laplacian-of-Gaussian kernel [size, size], shifted to sum to zero (a constant maps to 0)."""
    c = (size - 1) / 2.0
    ax = torch.arange(size, dtype=torch.float64) - c
    yy, xx = torch.meshgrid(ax, ax, indexing="ij")
    r2 = (xx * xx + yy * yy) / (2.0 * sigma * sigma)
    k = -(1.0 / (math.pi * sigma**4)) * (1.0 - r2) * torch.exp(-r2)
    k = k - k.mean()
    return k.to(torch.float32)


def log_filter(x: torch.Tensor, size: int = LOG_SIZE, sigma: float = LOG_SIGMA) -> torch.Tensor:
    """Per-channel LoG of [N, C, H, W] with replicate padding (no false edges at the border)."""
    c = x.shape[1]
    k = log_kernel(size, sigma).to(device=x.device, dtype=x.dtype)
    w = k.view(1, 1, size, size).expand(c, 1, size, size)
    pad = size // 2
    return F.conv2d(F.pad(x, (pad, pad, pad, pad), mode="replicate"), w, groups=c)


def hfen_relative(p: torch.Tensor, r: torch.Tensor, eps: float = HFEN_EPS) -> torch.Tensor:
    """Relative high-frequency error norm: mean(|LoG(p) - LoG(r)| / (|LoG(r)| + eps)), per channel."""
    lp, lr = log_filter(p), log_filter(r)
    return ((lp - lr).abs() / (lr.abs() + eps)).mean()


def _weights(t: int, frame_weights: Optional[Sequence[float]]) -> Sequence[float]:
    w = FRAME_WEIGHTS if frame_weights is None else tuple(frame_weights)
    if len(w) != t:
        raise ValueError(f"frame weights {list(w)} do not match a sequence of {t} frames")
    return w


def spatial_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None) -> torch.Tensor:
    """l_s = sum_t w_t SMAPE(p_t, r_t)."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    return sum(w[t] * smape(p[t], r[t]) for t in range(len(p)))


def temporal_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None) -> torch.Tensor:
    """l_t = sum_{t>=1} w_t SMAPE(p_t - p_{t-1}, r_t - r_{t-1})."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    total = p[0].new_zeros(())
    for t in range(1, len(p)):
        total = total + w[t] * smape(p[t] - p[t - 1], r[t] - r[t - 1])
    return total


def edge_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None) -> torch.Tensor:
    """l_e = sum_t w_t HFEN_rel(p_t, r_t)."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    return sum(w[t] * hfen_relative(p[t], r[t]) for t in range(len(p)))


def block_means(x: torch.Tensor, block: int = MEAN_BLOCK) -> torch.Tensor:
    """Means of block x block tiles of x [N, C, H, W] (edge tiles over the pixels they hold)."""
    return F.avg_pool2d(x, block, ceil_mode=True)


def mean_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None, block: int = MEAN_BLOCK) -> torch.Tensor:
    """l_m: sum_t w_t SMAPE(block_means(p_t), block_means(r_t))."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    return sum(wt * smape(block_means(p[t], block), block_means(r[t], block)) for t, wt in enumerate(w))


def metal_mean_loss(
    preds: Frames, refs: Frames, metallic: Frames, frame_weights: Optional[Sequence[float]] = None, block: int = MEAN_BLOCK
) -> torch.Tensor:
    """l_mm: sum_t w_t of the metal-count-weighted mean, over the blocks of the whole batch, of
    SMAPE(mean of p_t, mean of r_t over the block's metal pixels); 0 for a frame without metal."""
    p, r, m = _frames(preds, "preds"), _frames(refs, "refs"), _frames(metallic, "metallic")
    ms, ps = _shape(m), _shape(p)
    if ms[:2] != ps[:2] or ms[2] != 1 or ms[3:] != ps[3:]:
        raise ValueError(f"metallic {ms} does not match preds {ps} (expected one channel)")
    w = _weights(len(p), frame_weights)
    total = p[0].new_zeros(())
    for t, wt in enumerate(w):
        metal = (m[t] >= METAL_THRESHOLD).to(p[0].dtype)
        count = F.avg_pool2d(metal, block, ceil_mode=True)  # metal fraction per block
        bp = F.avg_pool2d(p[t] * metal, block, ceil_mode=True)
        br = F.avg_pool2d(r[t] * metal, block, ceil_mode=True)
        # the block means of the metal's radiance, where a block holds metal
        cm = torch.clamp(count, min=1e-6)
        err = (bp - br).abs() / cm / ((bp.abs() + br.abs()) / cm + SMAPE_EPS)
        weight = count.expand_as(err)
        total = total + wt * (err * weight).sum() / torch.clamp(weight.sum(), min=1e-6)
    return total


def tonemap(x: torch.Tensor) -> torch.Tensor:
    """The metric's tonemap (metrics.tonemap), differentiable: [0, 1], no 8-bit rounding; the
    gamma's input is clamped to TONEMAP_FLOOR so that its slope stays finite."""
    v = torch.clamp(torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0), min=0.0)
    t = torch.clamp(hable_curve(EXPOSURE * v, *HABLE) / hable_curve(WHITE, *HABLE), TONEMAP_FLOOR, 1.0)
    return t ** (1.0 / GAMMA)


def ssim_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None) -> torch.Tensor:
    """l_ssim = sum_t w_t (1 - SSIM(tonemap(p_t), tonemap(r_t)))."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    return sum(wt * (1.0 - ssim_mean(tonemap(p[t]), tonemap(r[t]), 1.0)) for t, wt in enumerate(w))


def n2n_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None) -> torch.Tensor:
    """l_n2n = sum_t w_t mean((p_t - r_t)^2 / (sg(max(p_t, 0)) + N2N_EPS)^2)."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    return sum(wt * (((p[t] - r[t]) / (torch.clamp(p[t].detach(), min=0.0) + N2N_EPS)) ** 2).mean() for t, wt in enumerate(w))


def tonemap_slope(x: torch.Tensor) -> torch.Tensor:
    """d tonemap / d x of the metric's tonemap (metrics.tonemap: Hable's curve at EXPOSURE,
    over its value at WHITE, to the power 1 / GAMMA), analytic, for x in (0, WHITE /
    EXPOSURE); no gradient."""
    a, b, c, d, e, f = HABLE
    x = x.detach()
    u = EXPOSURE * x
    num, den = u * (a * u + c * b) + d * e, u * (a * u + b) + d * f
    dh = EXPOSURE * ((2 * a * u + c * b) * den - num * (2 * a * u + b)) / (den * den) / hable_curve(WHITE, *HABLE)
    h = hable_curve(u, *HABLE) / hable_curve(WHITE, *HABLE)
    return dh * h ** (1.0 / GAMMA - 1.0) / GAMMA


def tml2_loss(preds: Frames, refs: Frames, frame_weights: Optional[Sequence[float]] = None) -> torch.Tensor:
    """l_tml2 = sum_t w_t mean((tm'(clamp(sg(p_t), TML2_LO, TML2_HI)) (p_t - r_t))^2)."""
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    w = _weights(len(p), frame_weights)
    return sum(wt * ((tonemap_slope(p[t].clamp(TML2_LO, TML2_HI)) * (p[t] - r[t])) ** 2).mean() for t, wt in enumerate(w))


def warped_temporal_loss(preds: Frames, refs: Frames, motion: Frames) -> torch.Tensor:
    """l_wt on the last two frames, masked by the warp validity, on log1p(max(x, 0)).

    motion[:, T-1] maps frame T-1 to frame T-2 (prev_pos = pos + motion).
    """
    p, r, m = _frames(preds, "preds"), _frames(refs, "refs"), _frames(motion, "motion")
    if len(p) < 2:
        raise ValueError("warped temporal loss needs at least 2 frames")
    lp = [torch.log1p(torch.clamp(x, min=0.0)) for x in p[-2:]]
    lr = [torch.log1p(torch.clamp(x, min=0.0)) for x in r[-2:]]
    wp, valid = warp(lp[0], m[-1])
    wr, _ = warp(lr[0], m[-1])
    diff = ((lp[1] - wp) - (lr[1] - wr)).abs() * valid
    count = valid.sum() * p[0].shape[1]
    return diff.sum() / torch.clamp(count, min=1.0)


def albedo_loss(o: torch.Tensor, ref: torch.Tensor, albedo_mod: torch.Tensor, exposure: Optional[torch.Tensor] = None) -> torch.Tensor:
    """l_a = mean |o - log(1 + (ref / s) / (albedo_mod + 0.00316))| (last frame, log-demodulated
    space; s = the colour exposure, channels 0..2 of `exposure` [N, 9, 1, 1], 1 when None)."""
    if exposure is not None:
        ref = ref / exposure[:, :3]  # the colour exposure (channels 3..5 are the shadow's)
    return (o - demodulate(ref, albedo_mod)).abs().mean()


def total_loss(
    preds: Frames,
    refs: Frames,
    aux: Dict[str, object],
    frame_weights: Optional[Sequence[float]] = None,
    lambdas: Optional[Dict[str, float]] = None,
) -> Tuple[torch.Tensor, Dict[str, torch.Tensor]]:
    """Combined loss of a sequence. Returns (total, {"l_s", "l_t", "l_e", "l_wt", "l_a", "l_m"}, and
    "l_ssim", "l_mm", "l_n2n" and "l_tml2" where their weights are not 0).

    preds, refs: radiance [N, T, 3, H, W] (or lists). aux:
        motion      [N, T, 2, H, W] (or list): each frame's motion
        o           [N, 3, H, W]: the last frame's log-demodulated prediction
        albedo_mod  [N, 3, H, W]: the albedo the last frame was remodulated with
        exposure    (optional) [N, 9, 1, 1]: the last frame's exposure state (output = remodulate(o) * s[:, :3])
        metallic    [N, T, 1, H, W] (or list; needed where the weight of `mm` is not 0)
    """
    lam = dict(LAMBDAS if lambdas is None else lambdas)
    p, r = _frames(preds, "preds"), _frames(refs, "refs")
    if _shape(p) != _shape(r):
        raise ValueError(f"preds {_shape(p)} and refs {_shape(r)} differ")
    for key in ("motion", "o", "albedo_mod"):
        if key not in aux:
            raise KeyError(f"total_loss: aux has no `{key}`")
    parts = {
        "l_s": spatial_loss(p, r, frame_weights),
        "l_t": temporal_loss(p, r, frame_weights),
        "l_e": edge_loss(p, r, frame_weights),
        "l_wt": warped_temporal_loss(p, r, aux["motion"]),
        "l_a": albedo_loss(aux["o"], r[-1], aux["albedo_mod"], aux.get("exposure")),
        "l_m": mean_loss(p, r, frame_weights),
    }
    if lam.get("ssim", 0.0) != 0.0:
        parts["l_ssim"] = ssim_loss(p, r, frame_weights)
    if lam.get("mm", 0.0) != 0.0:
        if "metallic" not in aux:
            raise KeyError("total_loss: the metal brightness term (lambda mm) needs aux `metallic`")
        parts["l_mm"] = metal_mean_loss(p, r, aux["metallic"], frame_weights)
    if lam.get("n2n", 0.0) != 0.0:
        parts["l_n2n"] = n2n_loss(p, r, frame_weights)
    if lam.get("tml2", 0.0) != 0.0:
        parts["l_tml2"] = tml2_loss(p, r, frame_weights)
    unknown = set(lam) - set(LAMBDAS)
    if unknown:
        raise KeyError(f"total_loss: unknown loss weight(s) {sorted(unknown)}, expected {sorted(LAMBDAS)}")
    total = sum(lam.get(k[2:], 0.0) * v for k, v in parts.items())
    return total, parts


def sequence_loss(
    results: Sequence[Dict[str, object]],
    refs: Frames,
    frames: Sequence[Dict[str, torch.Tensor]],
    frame_weights: Optional[Sequence[float]] = None,
    lambdas: Optional[Dict[str, float]] = None,
) -> Tuple[torch.Tensor, Dict[str, torch.Tensor]]:
    """total_loss from SSRModel.run_sequence results and the input frames (for the motion)."""
    preds = [res["output"] for res in results]
    aux = {
        "motion": [f["motion"] for f in frames],
        "o": results[-1]["o"],
        "albedo_mod": results[-1]["albedo_mod"],
        "exposure": results[-1]["exposure"],
        "metallic": [f["metallic"] for f in frames],
    }
    return total_loss(preds, refs, aux, frame_weights, lambdas)
