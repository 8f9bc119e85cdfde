"""Brightness by region: where a method's output is too bright or too dark.

The held-out table's brightness error is one number per frame, and a frame's mean is
dominated by its brightest pixels (a window, the sky). This splits every frame of a split
into regions by the dataset's own buffers and gives, per sequence and method, the ratio of
the output's sum to the reference's sum over each region and colour channel, all frames
together:

* `metal`: geometry (coverage below 1/2) with metallic at least 1/2;
* `non-metal`: the rest of the geometry;
* `environment`: pixels whose coverage (the directly seen environment) is at least 1/2;
  absent where the dataset has no `coverage` buffer.

With `--silhouette`, the pixels whose footprint holds both (0 < coverage < 1: the outlines
of geometry against the sky, where the output pass adds the background to the
reconstruction) are a region of their own, `silhouette`, and `environment` holds the
wholly covered ones (coverage 1), the geometry regions the uncovered ones (coverage 0).

    python -m ssr.brightness --data ROOT --split test --pred PRED --methods ssr oidn-a \\
        [--sequences barn-lamp_test_000 ...] [--silhouette] [--json OUT.json]

PRED/METHOD/SPLIT/SEQUENCE/frame_NNNN.exr are predictions as `ssr.evaluate` and `subpixel
denoise` write them (`pred.R/G/B`). A reporting tool: it reads held-out references, so it
must never choose a model.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
from typing import Dict, List, Optional, Sequence

import numpy as np

from .data import DatasetError, exr_size, read_exr

REGIONS = ("metal", "non-metal", "silhouette", "environment")
RGB = ("R", "G", "B")


def region_masks(
    metallic: np.ndarray, coverage: Optional[np.ndarray], silhouette: bool = False
) -> Dict[str, np.ndarray]:
    """Boolean [H, W] masks of REGIONS, a partition of the frame, from metallic [H, W] and
    coverage [H, W] (or None: every pixel is geometry and there is no `environment` or
    `silhouette` region); `silhouette` splits out 0 < coverage < 1 (module doc)."""
    none = np.zeros(metallic.shape, dtype=bool)
    if coverage is None:
        env, sil = none, none
    elif silhouette:
        env, sil = coverage >= 1.0, (coverage > 0.0) & (coverage < 1.0)
    else:
        env, sil = coverage >= 0.5, none
    metal = (metallic >= 0.5) & ~env & ~sil
    out = {"metal": metal, "non-metal": ~metal & ~env & ~sil}
    if coverage is not None and silhouette:
        out["silhouette"] = sil
    if coverage is not None:
        out["environment"] = env
    return out


class RegionSums:
    """Per-region sums over frames of a reference and of each method's output."""

    def __init__(self, methods: Sequence[str]):
        self.methods = list(methods)
        self.pixels: Dict[str, int] = {}
        self.total = 0
        self.ref: Dict[str, np.ndarray] = {}
        self.out: Dict[str, Dict[str, np.ndarray]] = {m: {} for m in self.methods}

    def add(self, masks: Dict[str, np.ndarray], ref: np.ndarray, preds: Dict[str, np.ndarray]) -> None:
        """One frame: region masks [H, W], reference [H, W, 3], predictions {method: [H, W, 3]}."""
        self.total += ref.shape[0] * ref.shape[1]
        for r, m in masks.items():
            self.pixels[r] = self.pixels.get(r, 0) + int(m.sum())
            self.ref[r] = self.ref.get(r, np.zeros(3)) + ref[m].astype(np.float64).sum(axis=0)
            for k in self.methods:
                self.out[k][r] = self.out[k].get(r, np.zeros(3)) + preds[k][m].astype(np.float64).sum(axis=0)

    def ratios(self, eps: float = 1e-12) -> Dict[str, Dict[str, Optional[List[float]]]]:
        """{method: {region: [R, G, B] output sum / reference sum}}; None for an empty region
        or one whose reference sums to zero in a channel."""
        res: Dict[str, Dict[str, Optional[List[float]]]] = {}
        for k in self.methods:
            res[k] = {}
            for r in self.ref:
                ref = self.ref[r]
                if self.pixels[r] == 0 or np.any(ref <= eps):
                    res[k][r] = None
                else:
                    res[k][r] = [float(v) for v in self.out[k][r] / ref]
        return res

    def fractions(self) -> Dict[str, float]:
        """Each region's share of the pixels."""
        return {r: n / max(self.total, 1) for r, n in self.pixels.items()}


def sequence_sums(
    data: str, split: str, sequence: str, pred: str, methods: Sequence[str], silhouette: bool = False
) -> RegionSums:
    """RegionSums of one sequence over all its frames; DatasetError naming the file for a
    missing frame, channel or prediction."""
    seq_dir = os.path.join(data, split, sequence)
    frames = sorted(glob.glob(os.path.join(seq_dir, "frame_*.exr")))
    if not frames:
        raise DatasetError(f"{seq_dir}: no frame_*.exr")
    sums = RegionSums(methods)
    has_cov = "coverage.Y" in exr_size(frames[0])[2]  # a sequence's frames share their buffers
    for f in frames:
        x = read_exr(f, [f"reference.{c}" for c in RGB] + ["metallic.Y"] + (["coverage.Y"] if has_cov else []))
        preds = {}
        for k in methods:
            pf = os.path.join(pred, k, split, sequence, os.path.basename(f))
            if not os.path.isfile(pf):
                raise DatasetError(f"{pf}: missing prediction of `{k}` (run ssr.evaluate or subpixel denoise first)")
            preds[k] = read_exr(pf, [f"pred.{c}" for c in RGB])
            if preds[k].shape[:2] != x.shape[:2]:
                raise DatasetError(f"{pf}: {preds[k].shape[1]}x{preds[k].shape[0]}, the frame is {x.shape[1]}x{x.shape[0]}")
        masks = region_masks(x[..., 3], x[..., 4] if has_cov else None, silhouette)
        sums.add(masks, x[..., :3], preds)
    return sums


def fmt(r: Optional[List[float]]) -> str:
    return "-" if r is None else " / ".join(f"{v:.2f}" for v in r)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="dataset root (ROOT/SPLIT/SEQUENCE/frame_NNNN.exr)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--pred", required=True, help="predictions root (PRED/METHOD/SPLIT/SEQUENCE/frame_NNNN.exr)")
    ap.add_argument("--methods", nargs="+", required=True)
    ap.add_argument("--sequences", nargs="*", help="sequence folder names (default: every one of the split)")
    ap.add_argument("--silhouette", action="store_true", help="0 < coverage < 1 as a region of its own (module doc)")
    ap.add_argument("--json", help="also write every ratio and region fraction to this file")
    a = ap.parse_args(argv)
    split_dir = os.path.join(a.data, a.split)
    seqs = a.sequences or sorted(os.path.basename(p.rstrip("/")) for p in glob.glob(os.path.join(split_dir, "*", "")))
    if not seqs:
        print(f"error: no sequences under {split_dir}", file=sys.stderr)
        return 1
    report = {}
    width = max(len(m) for m in a.methods)
    for s in seqs:
        try:
            sums = sequence_sums(a.data, a.split, s, a.pred, a.methods, a.silhouette)
        except DatasetError as err:
            print(f"error: {err}", file=sys.stderr)
            return 1
        fr, ratios = sums.fractions(), sums.ratios()
        report[s] = {"fractions": fr, "ratios": ratios}
        regions = [r for r in REGIONS if r in fr]
        print(f"{s}: output / reference per channel (R / G / B), all frames; " +
              ", ".join(f"{r} {100 * fr[r]:.1f} % of pixels" for r in regions))
        for k in a.methods:
            print(f"  {k:<{width}}  " + "  ".join(f"{r}: {fmt(ratios[k][r])}" for r in regions))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
