"""Tiny synthetic datasets in the `subpixel dataset` layout, for tests and smoke runs.

Each sequence pans a camera over an infinite procedural plane (textured albedo, smooth
lighting with a few HDR highlights) at a constant sub-pixel velocity v, so the motion of
every pixel is exactly v (prev_pos = pos + v) and warps matter. `reference` is the clean
radiance, `color` a 1/4-spp noisy sample of it (log-normal noise, mean 1) at the traced
pixels of the DESIGN pattern, `shadow` the light at the traced pixels. With `full`, frames
also get `full` (channels full.R full.G full.B): a 1-spp sample at every pixel (the same
noise model, from a separate generator, so the other buffers do not change), what OIDN (b)
denoises.

    python -m ssr.synth --out ROOT [--train 2 --val 1 --test 1 --frames 8 --width 32 --height 32] [--full]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Dict, List, Optional

import numpy as np

from .data import EXTRA_SUFFIXES, frame_name, write_exr
from .model import TILE_OFFSETS

EMITTER = (12.0, 9.0, 6.0)
"""Radiance of the synthetic emitter (`make_sequence(emission=True)`)."""


def make_sequence(
    width: int, height: int, frames: int, seed: int, scene_seed: int = 0, full: bool = False, background: bool = False,
    emission: bool = False,
) -> List[Dict[str, np.ndarray]]:
    """Frames as dicts of float32 [C, H, W] arrays with every buffer of data.BUFFERS (and
    `full`, the 1-spp colour, with `full`; with `background`, the background buffer: the top
    quarter of the rows wholly sky, `coverage` 1 and `background` the reference there, the
    next row half covered, the rest none, and the footprint albedo `albedo_footprint`: the
    albedo, as the reference here is the albedo times the light pixel by pixel); with
    `emission` too, an emitter of radiance EMITTER seen directly over a 6 x 6 square below
    the sky (whose pixels' reference and traced samples add it), with its directly seen
    emission buffers `emission` (the traced samples') and `emission_footprint`, and which
    traced samples escaped to the sky (`escaped`: those of the wholly sky rows and of half
    the half-covered row's pixels)."""
    rng = np.random.default_rng(seed)
    frng = np.random.default_rng(20_000 + seed)
    srng = np.random.default_rng(10_000 + scene_seed)
    palette = srng.uniform(0.1, 0.9, size=(4, 3)).astype(np.float32)
    period = float(srng.uniform(6.0, 10.0))
    lights = srng.uniform(0, 64, size=(3, 2))
    v = rng.uniform(-1.5, 1.5, size=2)
    origin = rng.uniform(0, 64, size=2)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    out = []
    for t in range(frames):
        ux = xs + 0.5 + origin[0] + v[0] * t
        uy = ys + 0.5 + origin[1] + v[1] * t
        cell = (np.floor(ux / period).astype(int) + 2 * np.floor(uy / period).astype(int)) % 4
        albedo = palette[cell].transpose(2, 0, 1)
        light = 0.6 + 0.4 * np.sin(ux * 0.11) * np.cos(uy * 0.07)
        for lx, ly in lights:
            light = light + 6.0 * np.exp(-(((ux % 64) - lx) ** 2 + ((uy % 64) - ly) ** 2) / 8.0)
        light = light.astype(np.float32)
        reference = albedo * light[None]
        dx, dy = TILE_OFFSETS[t % 4]
        mask = np.zeros((1, height, width), np.float32)
        mask[:, dy::2, dx::2] = 1.0
        noise = rng.lognormal(-0.125, 0.5, size=(3, height, width)).astype(np.float32)
        color = reference * noise * mask
        nx = 0.2 * np.sin(ux * 0.05)
        ny = 0.2 * np.cos(uy * 0.05)
        nz = np.sqrt(1.0 - nx * nx - ny * ny)
        normal = np.stack([nx, ny, nz]).astype(np.float32)
        depth = (0.4 + 0.1 * np.sin(uy * 0.03))[None].astype(np.float32)
        frame = {
            "color": color,
            "mask": mask,
            "albedo": albedo.astype(np.float32),
            "normal": normal,
            "shadow": (light[None].repeat(3, 0) * mask).astype(np.float32),
            "transparent": np.zeros((3, height, width), np.float32),
            "depth": depth,
            "metallic": (cell == 3).astype(np.float32)[None],
            "roughness": np.full((1, height, width), 0.5, np.float32),
            "motion": np.stack([np.full((height, width), v[0]), np.full((height, width), v[1])]).astype(np.float32),
            "reference": reference.astype(np.float32),
        }
        if full:
            frame["full"] = (reference * frng.lognormal(-0.125, 0.5, size=(3, height, width))).astype(np.float32)
        if background:
            sky = height // 4
            cov = np.zeros((1, height, width), np.float32)
            cov[:, :sky] = 1.0
            cov[:, sky] = 0.5
            frame["coverage"] = cov
            frame["background"] = (frame["reference"] * cov).astype(np.float32)
            frame["albedo_footprint"] = frame["albedo"].copy()
            if emission:
                lamp = np.zeros((3, height, width), np.float32)
                lamp[:, sky + 2 : sky + 8, 2:8] = np.asarray(EMITTER, np.float32)[:, None, None]
                frame["emission_footprint"] = lamp
                frame["emission"] = lamp * mask
                # the traced samples that escaped: all of the sky's, half of the row's
                escaped = (cov == 1.0) | ((cov == 0.5) & (xs[None] % 4 < 2))
                frame["escaped"] = (escaped * mask).astype(np.float32)
                frame["reference"] = frame["reference"] + lamp
                frame["color"] = frame["color"] + lamp * mask
        out.append(frame)
    return out


def write_sequence(
    folder: str,
    split: str,
    index: int,
    frames: int,
    width: int,
    height: int,
    seed: int,
    scene: str = "synthetic",
    scene_seed: int = 0,
    full: bool = False,
    background: bool = False,
    emission: bool = False,
) -> str:
    os.makedirs(folder, exist_ok=True)
    meta = {
        "scene": scene,
        "split": split,
        "sequence": index,
        "frames": frames,
        "width": width,
        "height": height,
        "spp": 1,
        "seed": seed,
        "camera_path": {"kind": "synthetic-pan", "seed": seed},
    }
    with open(os.path.join(folder, "sequence.json"), "w") as f:
        json.dump(meta, f, indent=2)
    for t, fr in enumerate(make_sequence(width, height, frames, seed, scene_seed, full, background, emission)):
        write_exr(os.path.join(folder, frame_name(t)), fr, EXTRA_SUFFIXES)
    return folder


def write_dataset(
    root: str,
    splits: Optional[Dict[str, int]] = None,
    frames: int = 8,
    width: int = 32,
    height: int = 32,
    scenes: Optional[List[str]] = None,
    seed: int = 0,
    full: bool = False,
    background: bool = False,
    emission: bool = False,
) -> str:
    """Writes ROOT/{split}/{scene}_{i:03d}/ for every scene and split; returns root."""
    splits = splits if splits is not None else {"train": 2, "val": 1, "test": 1}
    scenes = scenes or ["synthetic"]
    k = 0
    for si, scene in enumerate(scenes):
        for split, count in splits.items():
            for i in range(count):
                folder = os.path.join(root, split, f"{scene}_{i:03d}")
                write_sequence(folder, split, i, frames, width, height, seed * 1000 + k, scene, si, full, background, emission)
                k += 1
    return root


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.synth", description="Write a tiny synthetic dataset.")
    ap.add_argument("--out", required=True)
    ap.add_argument("--train", type=int, default=2)
    ap.add_argument("--val", type=int, default=1)
    ap.add_argument("--test", type=int, default=1)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--height", type=int, default=32)
    ap.add_argument("--scenes", nargs="+", default=["synthetic"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--full", action="store_true", help="also write the 1-spp colour (full.R full.G full.B)")
    a = ap.parse_args(argv)
    write_dataset(a.out, {"train": a.train, "val": a.val, "test": a.test}, a.frames, a.width, a.height, a.scenes, a.seed, a.full)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
