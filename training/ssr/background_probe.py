"""What a full-resolution background would be worth: each method's scores, and the same with
its background pixels replaced by the environment seen there. Two sources:
`--source full` (default): pixels whose primary ray escapes (depth 1, no transmissive
tint) take the dataset's 1-spp frame (`full`, one jittered lookup of the environment per
pixel); `--source background`: every pixel as the engine's output pass composites it with
the `background` and `coverage` channels (`subpixel dataset --background N`): background +
(1 - coverage) x the method's output (`model.composite_background`); the fraction printed is
then that of wholly sky pixels (coverage 1).

    python -m ssr.background_probe --data ROOT --pred PRED [--methods ssr oidn-a]
        [--scenes barn-lamp flight-helmet living-room] [--frames 8] [--split test]
        [--source full|background]

Prints, per scene, the fraction of background pixels and PSNR / SSIM (tonemapped 8-bit, as
everywhere) of each method as it is and with that background. A probe for deciding the data
contract's next step (training/README.md, "Generalisation" 9); it changes nothing.

    python -m ssr.background_probe --data ROOT --pred PRED --write METHOD [--split test]

instead writes METHOD's predictions composited with the background as the engine's output
pass does for SSR (`subpixel denoise`), as PRED/METHOD-background/SPLIT/SEQUENCE/
frame_NNNN.exr: the background given to another method (table1.sh's `oidn-a-background`).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Dict, List, Optional

import numpy as np

import torch

from .data import DatasetError, frame_name, list_sequences, read_exr, write_exr
from .model import composite_background
from .metrics import psnr, ssim

RGB = ("R", "G", "B")


def background_mask(depth: np.ndarray, transparent: np.ndarray) -> np.ndarray:
    """[H, W] bool: the primary ray escapes (depth 1) without crossing a transmissive surface."""
    return (depth[..., 0] >= 0.999) & (np.abs(transparent).sum(axis=-1) == 0)


def composite(pred: np.ndarray, background: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """[H, W, 3] `pred` composited with [H, W, 3] `background` and [H, W, 1] `coverage` as the
    engine's output pass does (`model.composite_background`)."""
    chw = lambda x: torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)))
    out = composite_background(chw(pred), {"background": chw(background), "coverage": chw(coverage)})
    return out.numpy().transpose(1, 2, 0)


def scores(pred: np.ndarray, ref: np.ndarray) -> tuple:
    """(PSNR, SSIM) of [H, W, 3] images (the metrics take channels first)."""
    p, r = np.ascontiguousarray(pred.transpose(2, 0, 1)), np.ascontiguousarray(ref.transpose(2, 0, 1))
    return psnr(p, r), ssim(p, r)


def probe(
    data: str, pred: str, methods: List[str], scenes: Optional[List[str]], frames: int, split: str, source: str = "full"
) -> Dict[str, dict]:
    """{scene: {"background": fraction, method: (psnr, ssim), method + "+bg": (psnr, ssim)}}, means
    over the scene's sequences and frames."""
    # One read per frame: reference, the environment's source, and what decides the mask.
    if source == "full":
        mask_channels = ["depth.Y"] + [f"transparent.{c}" for c in RGB]
    elif source == "background":
        mask_channels = ["coverage.Y"]
    else:
        raise ValueError(f"source must be full or background, got {source!r}")
    channels = [f"reference.{c}" for c in RGB] + [f"{source}.{c}" for c in RGB] + mask_channels
    rows: Dict[str, Dict[str, list]] = {}
    for seq in list_sequences(data, split, scenes):
        for t in range(min(frames, seq.frames)):
            a = read_exr(seq.frame_path(t), channels)
            ref, full = a[..., 0:3], a[..., 3:6]
            bg = background_mask(a[..., 6:7], a[..., 7:10]) if source == "full" else a[..., 6] >= 1.0
            r = rows.setdefault(seq.scene, {"background": []})
            r["background"].append(float(bg.mean()))
            for m in methods:
                p = read_exr(os.path.join(pred, m, split, seq.name, frame_name(t)), [f"pred.{c}" for c in RGB])
                mixed = np.where(bg[..., None], full, p) if source == "full" else composite(p, full, a[..., 6:7])
                r.setdefault(m, []).append(scores(p, ref))
                r.setdefault(m + "+bg", []).append(scores(mixed, ref))
    return {
        s: {k: (float(np.mean(v)) if k == "background" else tuple(np.mean(np.array(v), axis=0).tolist())) for k, v in r.items()}
        for s, r in sorted(rows.items())
    }


def write_composite(data: str, pred: str, method: str, split: str = "test") -> str:
    """Writes PRED/METHOD-background/SPLIT/...: METHOD's predictions composited with the
    background (`composite`; every frame of every SPLIT sequence). Returns the name."""
    from .evaluate import PRED_SUFFIXES

    out = f"{method}-background"
    for seq in list_sequences(data, split, None):
        for t in range(seq.frames):
            a = read_exr(seq.frame_path(t), [f"background.{c}" for c in RGB] + ["coverage.Y"])
            p = read_exr(os.path.join(pred, method, split, seq.name, frame_name(t)), [f"pred.{c}" for c in RGB])
            mixed = composite(p, a[..., 0:3], a[..., 3:4])
            dst = os.path.join(pred, out, split, seq.name, frame_name(t))
            write_exr(dst, {"pred": mixed.transpose(2, 0, 1)}, PRED_SUFFIXES)
    return out


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="dataset root (its frames need the `full` channels)")
    ap.add_argument("--pred", required=True, help="predictions root: PRED/METHOD/SPLIT/SEQUENCE/frame_NNNN.exr")
    ap.add_argument("--methods", nargs="+", default=["ssr", "oidn-a"])
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--split", default="test")
    ap.add_argument("--source", choices=["full", "background"], default="full",
                    help="where the background comes from (see the module doc)")
    ap.add_argument("--write", metavar="METHOD", default=None,
                    help="write METHOD's predictions composited with the background (see the module doc)")
    a = ap.parse_args(argv)
    if a.write:
        try:
            out = write_composite(a.data, a.pred, a.write, a.split)
        except DatasetError as err:
            print(f"error: {err}", file=sys.stderr)
            return 1
        print(f"wrote {os.path.join(a.pred, out, a.split)}")
        return 0
    try:
        res = probe(a.data, a.pred, a.methods, a.scenes, a.frames, a.split, a.source)
    except DatasetError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    if not res:
        print(f"error: no {a.split} sequences in {a.data}" + (f" of {a.scenes}" if a.scenes else ""), file=sys.stderr)
        return 1
    cols = [m for m in a.methods for m in (m, m + "+bg")]
    print("| scene | background | " + " | ".join(cols) + " |")
    print("|---|---|" + "---|" * len(cols))
    for s, r in res.items():
        cells = [f"{r[c][0]:.2f} / {r[c][1]:.4f}" for c in cols]
        print(f"| {s} | {100 * r['background']:.0f}% | " + " | ".join(cells) + " |")
    what = "the 1-spp frame" if a.source == "full" else "the background channels, composited as by the engine"
    print(f"\nPSNR (dB) / SSIM on tonemapped 8-bit images; +bg: background pixels from {what}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
