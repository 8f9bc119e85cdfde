"""Side-by-side strips for judging methods by eye: one PNG per scene, the same frame of one
test sequence through each method, tonemapped as the metrics (Uncharted 2 filmic, gamma 2.2)
and upscaled pixel for pixel.

    python -m ssr.strips --data ROOT --pred PRED --out weights/strips \\
        [--methods input ssr oidn-a] [--scenes living-room flight-helmet ...] [--frame 7] [--scale 2]

PRED is the prediction root of `ssr.evaluate` / `table1.sh`
(PRED/METHOD/test/SEQUENCE/frame_NNNN.exr with `pred.R/G/B`). For each scene (its first
test sequence; procedural scenes: the first `--procedural` of them) it writes
`OUT/SCENE.png`: the methods left to right, then the reference, each labelled with its
name and its PSNR on that frame.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import List, Optional

import numpy as np

from .data import DatasetError, frame_name, list_sequences, read_exr
from .metrics import psnr, tonemap_u8

LABEL_H = 12  # pixels of the label band above each image (after scaling)


def _label(img: np.ndarray, text: str) -> np.ndarray:
    """A band with `text` above `img` (HWC uint8), drawn with PIL's default bitmap font."""
    from PIL import Image, ImageDraw

    band = Image.new("RGB", (img.shape[1], LABEL_H + 2), (0, 0, 0))
    ImageDraw.Draw(band).text((2, 1), text, fill=(255, 255, 255))
    return np.concatenate([np.asarray(band), img], axis=0)


def strip(data: str, pred: str, seq_name: str, methods: List[str], frame: int, scale: int) -> np.ndarray:
    ref = read_exr(os.path.join(data, "test", seq_name, frame_name(frame)), ["reference.R", "reference.G", "reference.B"])
    tiles = []
    for m in methods:
        p = read_exr(os.path.join(pred, m, "test", seq_name, frame_name(frame)), ["pred.R", "pred.G", "pred.B"])
        tiles.append((f"{m} {psnr(p, ref):.1f} dB", p))
    tiles.append(("reference", ref))
    out = []
    for text, img in tiles:
        u8 = tonemap_u8(img)
        u8 = np.repeat(np.repeat(u8, scale, axis=0), scale, axis=1)
        out.append(_label(u8, text))
        out.append(np.zeros((out[-1].shape[0], 2, 3), np.uint8))  # a thin black gap
    return np.concatenate(out[:-1], axis=1)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.strips", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="dataset root (its test split)")
    ap.add_argument("--pred", required=True, help="prediction root: PRED/METHOD/test/SEQUENCE/")
    ap.add_argument("--out", required=True, help="folder for SCENE.png")
    ap.add_argument("--methods", nargs="+", default=["input", "ssr", "oidn-a"])
    ap.add_argument("--scenes", nargs="+", default=None, help="scenes (default: every test scene)")
    ap.add_argument("--procedural", type=int, default=2, help="strips of this many procedural scenes")
    ap.add_argument("--frame", type=int, default=7, help="frame of the sequence (default 7: history has built up)")
    ap.add_argument("--scale", type=int, default=2, help="pixel-for-pixel upscaling")
    a = ap.parse_args(argv)
    if a.scale < 1 or a.frame < 0:
        ap.error("--scale must be at least 1 and --frame not negative")
    from PIL import Image

    try:
        seqs = list_sequences(a.data, "test", None)
        chosen, seen, n_proc = [], set(), 0
        for s in seqs:
            if a.scenes and s.scene not in a.scenes and not ("procedural" in a.scenes and s.scene.startswith("procedural_")):
                continue
            if s.scene in seen:
                continue
            if s.scene.startswith("procedural_"):
                if n_proc >= a.procedural:
                    continue
                n_proc += 1
            seen.add(s.scene)
            chosen.append(s)
        if not chosen:
            raise DatasetError(f"{os.path.join(a.data, 'test')}: no test sequence of the scenes {a.scenes}")
        os.makedirs(a.out, exist_ok=True)
        for s in chosen:
            frame = min(a.frame, s.frames - 1)
            img = strip(a.data, a.pred, s.name, a.methods, frame, a.scale)
            path = os.path.join(a.out, f"{s.scene}.png")
            Image.fromarray(img).save(path, optimize=True)
            print(f"wrote {path} ({s.name} frame {frame}: {' | '.join(a.methods)} | reference)")
    except DatasetError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
