"""Where a method's error is: its tonemapped error split into spatial frequency bands
(training/README "Generalisation" 20 and 22). Per frame, e = tonemap(pred) - tonemap(ref)
(DESIGN section 7's tonemap, unquantised), and G_s(e) that error blurred by a Gaussian of s
pixels (separable, reflected at the borders). Sigmas s1 < s2 < ... < sk cut it into k + 1
bands that add up to e: e - G_s1 (finer than s1), G_s1 - G_s2, ..., G_sk (coarser than sk,
the image mean included); one sigma gives the high and the low part. Squared errors are averaged
over the frames of each scene column (the procedural seeds together, as in the table) and
given as PSNR; beside them, the reference's own noise: the mean over frames of the squared
error between the reference's halves over 4 (what the full reference's noise is), from
`sequence.json`'s `reference_noise`.

    python -m ssr.error_bands --pred PRED --ref ROOT --split test \\
        --methods ssr,oidn-b-footprint --scenes living-room,flight-helmet,barn-lamp,procedural
    python -m ssr.error_bands ... --sigmas 2,8,24      # four bands

PRED/METHOD/SPLIT/SEQUENCE/frame_NNNN.exr hold `pred.R/G/B` (as `subpixel denoise` writes).
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import sys
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .data import read_exr
from .metrics import tonemap


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """[H, W, C] blurred by a normalised Gaussian of `sigma` pixels (radius 3 sigma),
    borders reflected (a pixel's neighbours mirrored about the edge pixel)."""
    r = max(1, int(math.ceil(3.0 * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-x * x / (2.0 * sigma * sigma))
    g /= g.sum()
    out = img.astype(np.float64)
    for axis in (0, 1):
        n = out.shape[axis]
        if n == 1:
            continue
        idx = np.arange(-r, n + r)
        # Reflect (numpy "reflect": the edge pixel is not repeated), folded until in range.
        period = 2 * (n - 1)
        idx = np.abs(idx) % period
        idx = np.where(idx >= n, period - idx, idx)
        padded = np.take(out, idx, axis=axis)
        acc = np.zeros_like(out)
        for k in range(2 * r + 1):
            sl = [slice(None)] * out.ndim
            sl[axis] = slice(k, k + n)
            acc += g[k] * padded[tuple(sl)]
        out = acc
    return out


def band_errors(e: np.ndarray, sigmas: Sequence[float]) -> List[float]:
    """Mean squares of the bands of an error image `e` ([H, W, C]) for increasing `sigmas`,
    from the finest (e - G_s1) to the coarsest (G_sk)."""
    out, finer = [], e
    for s in sigmas:
        coarser = gaussian_blur(e, s)
        out.append(float(((finer - coarser) ** 2).mean()))
        finer = coarser
    out.append(float((finer * finer).mean()))
    return out


def bands(pred: np.ndarray, ref: np.ndarray, sigmas: Sequence[float]) -> Tuple[float, List[float]]:
    """(all, per band) mean squared tonemapped error of one frame ([H, W, 3] HDR)."""
    e = tonemap(pred).astype(np.float64) - tonemap(ref).astype(np.float64)
    return float((e * e).mean()), band_errors(e, sigmas)


def band_names(sigmas: Sequence[float]) -> List[str]:
    """Column names of the bands of `sigmas` (pixels), finest first."""
    if len(sigmas) == 1:
        return [f"high (below sigma {sigmas[0]:g})", f"low (sigma {sigmas[0]:g})"]
    edges = [f"{s:g}" for s in sigmas]
    return [f"below {edges[0]}"] + [f"{a}-{b}" for a, b in zip(edges, edges[1:])] + [f"above {edges[-1]}"]


def psnr_of(mse: float) -> float:
    """PSNR (dB, peak 1) of a mean squared error; inf for 0."""
    return float("inf") if mse <= 0.0 else -10.0 * math.log10(mse)


def scene_column(sequence: str) -> str:
    """The table's column of a test sequence: `procedural` for every procedural seed, else
    the scene name (the folder name before `_test_`)."""
    return "procedural" if sequence.startswith("procedural_") else sequence.split("_test_")[0].split("_val_")[0]


def measure(pred_root: str, ref_root: str, split: str, methods: Sequence[str], scenes: Optional[Sequence[str]],
            sigmas: Sequence[float]) -> Dict[Tuple[str, str], Dict[str, object]]:
    """{(method, column): {all, bands, ref_noise, frames}} as PSNR (dB) over the frames of
    each column (`bands`: one per band of `sigmas`, finest first); a method without a
    prediction of some frame is an error naming the file."""
    sigmas = sorted(sigmas)
    split_dir = os.path.join(ref_root, split)
    if not os.path.isdir(split_dir):
        raise FileNotFoundError(f"{split_dir}: no such split folder (--ref ROOT --split {split})")
    sums: Dict[Tuple[str, str], Dict[str, object]] = {}
    for seq in sorted(os.listdir(split_dir)):
        seq_dir = os.path.join(split_dir, seq)
        if not os.path.isfile(os.path.join(seq_dir, "sequence.json")):
            continue
        column = scene_column(seq)
        if scenes and column not in scenes:
            continue
        info = json.load(open(os.path.join(seq_dir, "sequence.json")))
        halves = (info.get("reference_noise") or {}).get("per_frame") or {}
        for f in sorted(glob.glob(os.path.join(seq_dir, "frame_*.exr"))):
            name = os.path.splitext(os.path.basename(f))[0]
            ref = read_exr(f, ("reference.R", "reference.G", "reference.B"))
            noise = 10.0 ** (-halves[name] / 10.0) / 4.0 if name in halves else float("nan")
            for m in methods:
                p = os.path.join(pred_root, m, split, seq, os.path.basename(f))
                if not os.path.isfile(p):
                    raise FileNotFoundError(f"{p}: no prediction of method '{m}' for {seq}/{name}")
                a, per_band = bands(read_exr(p, ("pred.R", "pred.G", "pred.B")), ref, sigmas)
                acc = sums.setdefault((m, column), {"all": 0.0, "bands": np.zeros(len(per_band)), "noise": 0.0, "n": 0})
                acc["all"] += a
                acc["bands"] += np.asarray(per_band)
                acc["noise"] += noise
                acc["n"] += 1
    out = {}
    for key, acc in sums.items():
        n, noise = acc["n"], acc["noise"]
        out[key] = {"all": psnr_of(acc["all"] / n), "bands": [psnr_of(b / n) for b in acc["bands"]],
                    "ref_noise": psnr_of(noise / n) if noise == noise else float("nan"), "frames": n}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pred", required=True, help="PRED folder: PRED/METHOD/SPLIT/SEQUENCE/frame_NNNN.exr")
    ap.add_argument("--ref", required=True, help="dataset root with the references")
    ap.add_argument("--split", default="test")
    ap.add_argument("--methods", required=True, help="comma-separated method folders of PRED")
    ap.add_argument("--scenes", default=None, help="comma-separated columns (procedural: every procedural seed)")
    ap.add_argument("--sigmas", "--sigma", default="4", help="Gaussians (pixels, comma-separated) between the bands")
    args = ap.parse_args(argv)
    try:
        sigmas = sorted(float(s) for s in args.sigmas.split(","))
    except ValueError:
        ap.error(f"--sigmas {args.sigmas!r}: expected comma-separated numbers of pixels, e.g. 2,8,24")
    if not all(s > 0 and math.isfinite(s) for s in sigmas) or len(set(sigmas)) != len(sigmas):
        ap.error(f"--sigmas {args.sigmas!r}: each must be positive, finite and different")
    scenes = args.scenes.split(",") if args.scenes else None
    try:
        rows = measure(args.pred, args.ref, args.split, args.methods.split(","), scenes, sigmas)
    except (FileNotFoundError, KeyError, ValueError) as e:
        print(f"error_bands: {e}", file=sys.stderr)
        return 1
    names = band_names(sigmas)
    print(f"| column | method | all | {' | '.join(names)} | reference noise | frames |")
    print("|---|---|---|" + "---|" * len(names) + "---|---|")
    for (m, col), r in sorted(rows.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        cells = " | ".join(f"{b:.2f}" for b in r["bands"])
        print(f"| {col} | {m} | {r['all']:.2f} | {cells} | {r['ref_noise']:.2f} | {int(r['frames'])} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
