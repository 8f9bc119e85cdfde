"""How far remodulating with the pixel-centre albedo can get, even with perfect irradiance.

SSR demodulates by the G-buffer albedo and remodulates its output with it (DESIGN §3,
`remodulation: "current"`). The G-buffer is sampled at the pixel centre, while the reference
is the mean over the pixel's footprint: where a pixel holds an albedo edge or texture detail,
no irradiance times the centre albedo equals the reference. This module measures that
ceiling on a dataset split: with E = reference / (footprint albedo + eps), the irradiance a
perfect network would predict where the irradiance is constant over the pixel, it scores
E x (centre albedo + eps) against the reference with the metrics' PSNR (`ssr.metrics`).

The footprint albedo comes from the frames' own `albedo_footprint` channels (`subpixel
dataset --background N`: the mean over N x N points of each pixel), or with `--fine` from
the same split rendered at K times the width and height (`subpixel dataset ... --width K*W
--height K*H`: the camera paths do not depend on the size), box-filtered K x K: the mean
albedo over K^2 points of each pixel, as the traced sample's jitter is uniform over the
pixel. The two estimate the same box filter, so they cross-check each other.

    python -m ssr.albedo_ceiling --data ROOT [--fine FINE_ROOT] [--split val]

Prints, per sequence, the share of "mixed" pixels (footprint albedo more than 0.05 from the
centre albedo in some channel) and the ceiling PSNR, and their means over the sequences.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Dict, List, Optional, Sequence

import numpy as np

from .data import DatasetError, frame_name, list_sequences, read_exr
from .metrics import psnr
from .model import ALBEDO_EPS

RGB = ("R", "G", "B")
MIXED = 0.05


def footprint(fine: np.ndarray, width: int, height: int) -> np.ndarray:
    """The K x K box filter of `fine` [K*H, K*W, C] down to [H, W, C]; an error unless the
    sizes are whole multiples with the same K on both axes."""
    fh, fw = fine.shape[:2]
    if fw % width or fh % height or fw // width != fh // height:
        raise DatasetError(f"the fine render is {fw}x{fh}, not the same whole multiple of {width}x{height} on both axes")
    k = fw // width
    return fine.reshape(height, k, width, k, -1).mean(axis=(1, 3))


def frame_ceiling(reference: np.ndarray, centre: np.ndarray, foot: np.ndarray) -> Dict[str, float]:
    """The ceiling PSNR of one frame and its share of mixed pixels."""
    irradiance = reference / (foot + ALBEDO_EPS)
    out = irradiance * (centre + ALBEDO_EPS)
    mixed = float(np.mean(np.abs(foot - centre).max(axis=-1) > MIXED))
    return {"psnr": psnr(out, reference), "mixed": mixed}


def sequence_ceiling(coarse_dir: str, fine_dir: Optional[str], frames: int, width: int, height: int) -> Dict[str, float]:
    """Mean of `frame_ceiling` over a sequence's frames (an infinite PSNR, where centre and
    footprint agree everywhere, counts as 100 dB); the footprint albedo from `fine_dir`'s
    frames box-filtered, or without it from the frames' `albedo_footprint` channels."""
    rows = []
    for i in range(frames):
        ch = tuple(f"albedo.{c}" for c in RGB) + tuple(f"reference.{c}" for c in RGB)
        if fine_dir is None:
            ch += tuple(f"albedo_footprint.{c}" for c in RGB)
        coarse = read_exr(os.path.join(coarse_dir, frame_name(i)), ch).astype(np.float64)
        if fine_dir is None:
            foot = coarse[..., 6:9]
        else:
            fine = read_exr(os.path.join(fine_dir, frame_name(i)), ch[:3]).astype(np.float64)
            foot = footprint(fine, width, height)
        r = frame_ceiling(coarse[..., 3:6], coarse[..., :3], foot)
        r["psnr"] = min(r["psnr"], 100.0)
        rows.append(r)
    return {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="dataset root (its references and G-buffers)")
    ap.add_argument("--fine", help="the same split rendered at K times the size (default: the frames' albedo_footprint)")
    ap.add_argument("--split", default="val")
    a = ap.parse_args(argv)
    try:
        seqs = list_sequences(a.data, a.split)
        results: List[tuple] = []
        for s in seqs:
            fine_dir = os.path.join(a.fine, a.split, s.name) if a.fine else None
            if fine_dir is not None and not os.path.isdir(fine_dir):
                continue
            results.append((s.name, sequence_ceiling(s.path, fine_dir, s.frames, s.width, s.height)))
    except DatasetError as err:
        print(f"albedo_ceiling: {err}", file=sys.stderr)
        return 2
    if not results:
        print(f"albedo_ceiling: no sequence of {a.data}/{a.split} has a fine render in {a.fine}/{a.split}", file=sys.stderr)
        return 2
    print("| sequence | mixed pixels | ceiling PSNR (dB) |\n|---|---|---|")
    for name, r in results:
        print(f"| {name} | {100 * r['mixed']:.1f} % | {r['psnr']:.2f} |")
    mixed = np.mean([r["mixed"] for _, r in results])
    ceiling = np.mean([r["psnr"] for _, r in results])
    print(f"| mean of {len(results)} | {100 * mixed:.1f} % | {ceiling:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
