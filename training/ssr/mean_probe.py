"""A probe, not a feature: a mean-preserving correction after the network (training/README
"Generalisation" 12). Each predicted frame is scaled per `block` x `block` tile and channel
by the ratio of the traced samples' sum to the prediction's sum at the same pixels over the
last `frames` frames (no motion compensation), clamped to [lo, hi], optionally smoothed
over frames (`--smooth A`: the log of the factor is A times this frame's plus 1 - A times
the previous frame's), and interpolated bilinearly between tile centres.

    python -m ssr.mean_probe --data ROOT --split val --pred PRED/ssr --out PRED/meanfix \\
        [--block 32] [--frames 4] [--smooth 1] [--geometry] [--decay D]

`--composite` (fourteenth session) takes the predictions as the network's output before the
engine's output pass (what `ssr.evaluate` writes for a model without `mean_correction`;
with one it writes the output after the whole pass) and applies that pass first: B + (1 - a) x
prediction, with the dataset's `background` buffer B (the directly seen environment,
weighted by its coverage a) and `coverage`. `--geometry` (implies `--composite`) corrects
only the reconstructed part: B + (1 - a) x prediction x factor, the factor comparing the sums
of `sample - B` and `(1 - a) x prediction` (both estimate the geometry's share of a pixel).
`--lo 1 --hi 1` gives the uncorrected frames.
`--decay D` replaces the window of `--frames` frames by per-pixel sums carried along the
motion vectors: S_t = s_t + D W(S_{t-1}), W the backward warp of the network (invalid
history counts 0), for the samples and the predictions alike.

PRED/ssr/SPLIT/SEQUENCE/frame_NNNN.exr (`pred.R/G/B`, as `subpixel denoise` writes) become
PRED/meanfix/SPLIT/SEQUENCE/frame_NNNN.exr; score both with `subpixel eval --table --pred
PRED --ref ROOT --split SPLIT`.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
from typing import List, Optional, Tuple

import numpy as np

from .data import read_exr, write_exr


def block_sums(x: np.ndarray, block: int) -> np.ndarray:
    """[H, W, C] -> [ceil(H/block), ceil(W/block), C] sums (the image padded with zeros)."""
    h, w, c = x.shape
    hb, wb = -(-h // block), -(-w // block)
    p = np.zeros((hb * block, wb * block, c), dtype=np.float64)
    p[:h, :w] = x
    return p.reshape(hb, block, wb, block, c).sum(axis=(1, 3))


def upsample(c: np.ndarray, block: int, h: int, w: int) -> np.ndarray:
    """Tile values [hb, wb, C] bilinearly to pixels [h, w, C] (tile centres, edges held)."""
    hb, wb = c.shape[:2]
    ys = (np.arange(h) + 0.5) / block - 0.5
    xs = (np.arange(w) + 0.5) / block - 0.5
    y0 = np.clip(np.floor(ys).astype(int), 0, hb - 1)
    x0 = np.clip(np.floor(xs).astype(int), 0, wb - 1)
    y1, x1 = np.minimum(y0 + 1, hb - 1), np.minimum(x0 + 1, wb - 1)
    fy = np.clip(ys - y0, 0.0, 1.0)[:, None, None]
    fx = np.clip(xs - x0, 0.0, 1.0)[None, :, None]
    top = c[y0][:, x0] * (1 - fx) + c[y0][:, x1] * fx
    bottom = c[y1][:, x0] * (1 - fx) + c[y1][:, x1] * fx
    return top * (1 - fy) + bottom * fy


def tile_factors(s: np.ndarray, p: np.ndarray, h: int, w: int, block: int,
                 prev_log: Optional[np.ndarray] = None, smooth: float = 1.0,
                 lo: float = 0.5, hi: float = 2.0, eps: float = 1e-4) -> Tuple[np.ndarray, np.ndarray]:
    """Per-pixel factors [h, w, C] from tile sums of samples `s` and predictions `p`
    [tiles_y, tiles_x, C]: (s + eps) / (p + eps) clamped to [lo, hi], the log optionally
    blended with `prev_log` (`smooth` times this frame's), interpolated bilinearly. Returns
    the factors and the tiles' log factors."""
    log_c = np.log(np.clip((s + eps) / (p + eps), lo, hi))
    if prev_log is not None:
        log_c = smooth * log_c + (1.0 - smooth) * prev_log
    return upsample(np.exp(log_c), block, h, w), log_c


def correct(preds: List[np.ndarray], samples: List[np.ndarray], masks: List[np.ndarray], block: int,
            prev_log: Optional[np.ndarray] = None, smooth: float = 1.0,
            lo: float = 0.5, hi: float = 2.0, eps: float = 1e-4) -> Tuple[np.ndarray, np.ndarray]:
    """The last prediction [H, W, 3] scaled per tile and channel by the samples' sum over
    the prediction's sum at the traced pixels of the given frames (samples are colour times
    mask), clamped to [lo, hi]; with `prev_log` (the previous frame's log factors) the log
    factor is `smooth` times this frame's plus `1 - smooth` times it. Returns the corrected
    frame and its log factors [tiles_y, tiles_x, 3]."""
    s = sum(block_sums(x, block) for x in samples)
    p = sum(block_sums(pr * m, block) for pr, m in zip(preds, masks))
    h, w = preds[-1].shape[:2]
    fac, log_c = tile_factors(s, p, h, w, block, prev_log, smooth, lo, hi, eps)
    return preds[-1] * fac, log_c


def carry(acc: Optional[np.ndarray], x: np.ndarray, motion: np.ndarray, decay: float) -> np.ndarray:
    """x [H, W, C] plus `decay` times `acc` warped backwards by `motion` [H, W, 2] (pixels,
    prev_pos = pos + motion; the network's warp, history off screen counts 0)."""
    if acc is None:
        return x.astype(np.float64)
    import torch

    from .model import warp

    src = torch.from_numpy(np.ascontiguousarray(acc.transpose(2, 0, 1), dtype=np.float64)).unsqueeze(0)
    m = torch.from_numpy(np.ascontiguousarray(motion.transpose(2, 0, 1), dtype=np.float64)).unsqueeze(0)
    warped, valid = warp(src, m)
    w = (warped * valid)[0].numpy().transpose(1, 2, 0)
    return x + decay * w


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="val")
    ap.add_argument("--pred", required=True, help="folder of SPLIT/SEQUENCE/frame_NNNN.exr predictions")
    ap.add_argument("--out", required=True)
    ap.add_argument("--block", type=int, default=32)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--smooth", type=float, default=1.0, help="weight of this frame's log factor (1: no smoothing)")
    ap.add_argument("--composite", action="store_true", help="apply the engine's output pass (background) first")
    ap.add_argument("--geometry", action="store_true", help="correct only the reconstructed part (implies --composite)")
    ap.add_argument("--lo", type=float, default=0.5, help="smallest factor")
    ap.add_argument("--hi", type=float, default=2.0, help="largest factor")
    ap.add_argument("--decay", type=float, default=None, help="motion-compensated sums with this decay instead of a window")
    a = ap.parse_args(argv)
    if a.decay is not None and not 0.0 <= a.decay < 1.0:
        ap.error("--decay must be in [0, 1)")
    if not 0.0 < a.lo <= 1.0 <= a.hi:
        ap.error("--lo and --hi must satisfy 0 < lo <= 1 <= hi")
    a.composite = a.composite or a.geometry
    if a.block < 1 or a.frames < 1:
        ap.error("--block and --frames must be positive")
    if not 0.0 < a.smooth <= 1.0:
        ap.error("--smooth must be in (0, 1]")
    seqs = sorted(glob.glob(os.path.join(a.data, a.split, "*", "")))
    if not seqs:
        print(f"error: no sequences under {os.path.join(a.data, a.split)}", file=sys.stderr)
        return 1
    for seq in seqs:
        name = os.path.basename(seq.rstrip("/"))
        frames = sorted(glob.glob(os.path.join(seq, "frame_*.exr")))
        preds, samples, masks = [], [], []
        log_c = None
        acc_s = acc_p = None
        for f in frames:
            chans = ["color.R", "color.G", "color.B", "mask.Y", "motion.X", "motion.Y"]
            if a.composite:
                chans += ["background.R", "background.G", "background.B", "coverage.Y"]
            x = read_exr(f, chans)
            pred_file = os.path.join(a.pred, a.split, name, os.path.basename(f))
            if not os.path.isfile(pred_file):
                print(f"error: {pred_file}: missing prediction", file=sys.stderr)
                return 1
            pred = read_exr(pred_file, ["pred.R", "pred.G", "pred.B"])
            m = x[..., 3:4]
            if a.composite:
                bg, open_sky = np.maximum(np.nan_to_num(x[..., 6:9]), 0.0), np.clip(x[..., 9:10], 0.0, 1.0)
                pred = bg + (1.0 - open_sky) * pred
            if a.geometry:
                part, sample = pred - bg, (x[..., :3] - bg) * m
            else:
                bg, part, sample = np.zeros_like(pred), pred, x[..., :3] * m
            if a.decay is None:
                preds.append(part)
                samples.append(sample)
                masks.append(m)
                k = max(0, len(preds) - a.frames)
                fixed, log_c = correct(preds[k:], samples[k:], masks[k:], a.block, log_c, a.smooth, a.lo, a.hi)
            else:
                motion = np.nan_to_num(x[..., 4:6], nan=1e30, posinf=1e30, neginf=-1e30)
                acc_s = carry(acc_s, sample, motion, a.decay)
                acc_p = carry(acc_p, part * m, motion, a.decay)
                h, w = part.shape[:2]
                fac, log_c = tile_factors(block_sums(acc_s, a.block), block_sums(acc_p, a.block), h, w, a.block,
                                          log_c, a.smooth, a.lo, a.hi)
                fixed = part * fac
            d = os.path.join(a.out, a.split, name)
            os.makedirs(d, exist_ok=True)
            write_exr(os.path.join(d, os.path.basename(f)), {"pred": (bg + fixed).transpose(2, 0, 1).astype(np.float32)},
                      {"pred": ["R", "G", "B"]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
