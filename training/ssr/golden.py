"""Golden cases for the Rust/WGSL parity test.

    cd training && python -m ssr.golden --out ../tests/data

writes
    golden_weights.safetensors   random-initialised weights (seed 6), see ssr.export, of the
                                 default config (version 2), red output bias pushed up
                                 (CEILING_PUSH) so the output ceiling clamps
    golden_frame{0,1,2}.safetensors
                                 three consecutive 40x24 frames: inputs, every intermediate
                                 and the output, run as one sequence (frame 0 has no history)
    golden_l4_weights.safetensors, golden_l4_frame{0,1,2}.safetensors
                                 the same for the default config with a fourth U-Net level
                                 (enc [16, 32, 28, 24]: L4_ENC), on the same inputs
    golden_shared_weights.safetensors, golden_shared_frame{0,1,2}.safetensors
                                 the same for the default config with one exposure per buffer
                                 (exposure "shared"), on the same inputs
    golden_v1_weights.safetensors, golden_v1_frame{0,1,2}.safetensors
                                 the same for a version-1 config (the pipeline of version-1
                                 weights files: no exposure normalisation, remodulation with the
                                 accumulated albedo, off-screen history test only) on the
                                 version-1 inputs (random per-pixel geometry): the files the
                                 version-1 code wrote, byte for byte but for their names

Every tensor in a frame file is float32, HWC ([H, W, C]) with the logical (unpadded)
channel count. Names: GOLDEN_INPUTS + GOLDEN_INTERMEDIATES (+ enc1/enc2/enc3, extras
that help to localise a mismatch). The frame metadata records the frame index, size,
tile offset, seeds and the weights file name.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Dict, List

import torch
import torch.nn.functional as F

from .export import RANDOM_INIT_SCHEME, RANDOM_PROVENANCE, export_random, export_weights, safetensors_bytes, write_bytes
from .model import FRAME_CHANNELS, LEGACY_OPTIONS, TILE_OFFSETS, SSRConfig, SSRModel, quarter_mask

WIDTH, HEIGHT, FRAMES = 40, 24, 3
# Seed 6, not 0: with enc = [16, 32, 28] seed 0 leaves o >= 0 everywhere in frame 0, so the
# remodulation clamp would go untested (the init draws every conv from one stream, so the
# seed's luck changes with the widths). Seed 6 clamps 12-24 % of the output per frame.
WEIGHTS_SEED = 6
CEILING_PUSH = 3.9
"""Added to the red output bias (`unet.dec1.2.bias[0]`) of the version-2 weights: random weights
keep o far below the output ceiling (config `ceiling`), so the clamp would go untested; pushed,
red is clamped on 2-67 % of the pixels per frame while green and blue keep the remodulation's
clamp at 0."""
INPUT_SEED = 1
WEIGHTS_FILE = "golden_weights.safetensors"
MAX_FILE_BYTES = 1 << 20
LEGACY_PREFIX = "golden_v1_"
"""File name prefix of the version-1 set (golden_v1_weights, golden_v1_frame{t})."""
L4_PREFIX = "golden_l4_"
"""File name prefix of the set with a fourth U-Net level."""
L4_ENC = [16, 32, 28, 24]
"""Its widths (the default's three, and a fourth at 1/8 resolution); WIDTH and HEIGHT are
multiples of 8, as a 4-level U-Net needs."""
SHARED_PREFIX = "golden_shared_"
"""File name prefix of the set with one exposure per buffer (config exposure "shared")."""

GOLDEN_INPUTS = list(FRAME_CHANNELS)  # color mask albedo normal shadow transparent depth metallic roughness motion
GOLDEN_INTERMEDIATES = [
    "a_cur",
    "warp_acc",
    "warp_valid",
    "ref_feat",
    "emb_cur",
    "emb_prev",
    "tfa_weights",
    "a_acc",
    "warp_out",
    "i3",
    "i2",
    "o",
    "output",
]
GOLDEN_EXTRAS = ["enc1", "enc2", "enc3"]
GOLDEN_L4 = ["enc4", "i4"]
"""A fourth U-Net level only: its encoder output and its decoder output I4."""
GOLDEN_V2 = ["exposure"]
"""Version 2 only: the frame's exposure state: s (colour rgb, shadow rgb) and the ceiling's running max M (rgb), [1, 1, 9]."""


def _smooth(g: torch.Generator, c: int, h: int, w: int) -> torch.Tensor:
    """A smooth random field [1, c, h, w] in [-1, 1]: a coarse grid, bilinearly upsampled."""
    coarse = torch.rand(1, c, max(2, h // 8), max(2, w // 8), generator=g) * 2.0 - 1.0
    return F.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=True)


def make_frames(
    seed: int = INPUT_SEED, height: int = HEIGHT, width: int = WIDTH, count: int = FRAMES, geometry: str = "coherent"
) -> List[Dict[str, torch.Tensor]]:
    """Random but plausible frames (NCHW, batch 1) following DESIGN section 3.

    color/shadow are HDR (log-normal) and 0 where mask = 0 (shadow also 0 at some traced
    pixels: occluded); albedo in [0, 1]; unit normals; transparent non-zero on ~40% of the
    pixels; depth/metallic/roughness in [0, 1]. Motion (pixels) is sub-pixel random, with a
    zero block, an integer block, ~10% of pixels thrown far off screen, and exact boundary
    cases (p.x = 0, valid; p.x = W, invalid) in rows 16..19.

    geometry "coherent" (default): depth and normal are smooth fields shared by every frame,
    so most warped history agrees with the current frame, except in a block per frame t >= 1
    (rows 2..9, 8 columns moving with t) whose depth is halved and normal turned:
    a disocclusion the history test must reject; and the light gets brighter every frame
    (colour and shadow x 1.5^t: within EXPOSURE_JUMP, so the exposure eases towards it), and
    the history is re-exposed. "random":
    per-pixel random depth and normal every frame, constant light (the version-1 golden inputs).
    """
    if geometry not in ("coherent", "random"):
        raise ValueError(f"make_frames: geometry must be 'coherent' or 'random', got {geometry!r}")
    g = torch.Generator().manual_seed(int(seed))
    h, w = height, width
    if geometry == "coherent":
        gg = torch.Generator().manual_seed(int(seed) + 1000)
        static_depth = 0.55 + 0.3 * _smooth(gg, 1, h, w)
        static_normal = F.normalize(_smooth(gg, 3, h, w) * 0.3 + torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1), dim=1)

    def u(c: int) -> torch.Tensor:
        return torch.rand(1, c, h, w, generator=g)

    def n(c: int) -> torch.Tensor:
        return torch.randn(1, c, h, w, generator=g)

    frames = []
    for t in range(count):
        mask = quarter_mask(h, w, t)
        color = torch.exp(n(3) * 1.5 - 0.5) * mask
        albedo = u(3)
        normal = F.normalize(n(3), dim=1)
        lit = (u(1) > 0.3).float()
        shadow = torch.exp(n(3)) * lit * mask
        transparent = u(3) * (u(1) < 0.4).float()
        depth, metallic, roughness = u(1), u(1), u(1)
        motion = (u(2) - 0.5) * 5.0
        far = u(1) < 0.1
        sign = torch.where(u(2) < 0.5, -1.0, 1.0)
        motion = torch.where(far, sign * (w + 20.0 * u(2)), motion)
        motion[:, :, 0:8, 0:10] = 0.0  # zero motion: identity
        motion[:, 0, 8:12, 0:10] = -1.0  # integer motion: exact taps
        motion[:, 1, 8:12, 0:10] = 2.0
        motion[:, :, 16:20, 0] = torch.tensor([-0.5, 0.0]).view(1, 2, 1)  # p.x = 0: valid
        motion[:, :, 16:20, w - 1] = torch.tensor([0.5, 0.0]).view(1, 2, 1)  # p.x = W: invalid
        if geometry == "coherent":
            color = color * 1.5**t
            shadow = shadow * 1.5**t
            depth = static_depth.clone()
            normal = static_normal.clone()
            if t >= 1:
                x0 = (12 + 6 * t) % max(1, w - 8)
                depth[:, :, 2:10, x0 : x0 + 8] *= 0.5
                normal[:, :, 2:10, x0 : x0 + 8] = F.normalize(normal[:, :, 2:10, x0 : x0 + 8] + torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1), dim=1)
        frames.append(
            {
                "color": color,
                "mask": mask,
                "albedo": albedo,
                "normal": normal,
                "shadow": shadow,
                "transparent": transparent,
                "depth": depth,
                "metallic": metallic,
                "roughness": roughness,
                "motion": motion,
            }
        )
    return frames


def hwc(t: torch.Tensor) -> torch.Tensor:
    """[1, C, H, W] -> [H, W, C], contiguous float32."""
    if t.dim() != 4 or t.shape[0] != 1:
        raise ValueError(f"hwc: expected [1, C, H, W], got {list(t.shape)}")
    return t[0].permute(1, 2, 0).contiguous().to(torch.float32)


def golden_names(cfg: SSRConfig) -> List[str]:
    """The intermediates a golden frame of this config holds (beyond the inputs)."""
    deep = GOLDEN_L4 if len(cfg.enc) == 4 else []
    return GOLDEN_INTERMEDIATES + GOLDEN_EXTRAS + deep + (GOLDEN_V2 if cfg.version >= 2 else [])


@torch.no_grad()
def golden_tensors(model: SSRModel, frames: List[Dict[str, torch.Tensor]]) -> List[Dict[str, torch.Tensor]]:
    """Runs the frames as one sequence; per frame, name -> HWC tensor."""
    model.eval()
    out = []
    for frame, r in zip(frames, model.run_sequence(frames)):
        d = {k: hwc(frame[k]) for k in GOLDEN_INPUTS}
        for k in golden_names(model.cfg):
            d[k] = hwc(r[k])
        out.append(d)
    return out


def frame_metadata(t: int, width: int, height: int, weights_seed: int, input_seed: int, prefix: str = "golden_", version: int = 2) -> Dict[str, str]:
    return {
        "format": "subpixel-ssr-golden",
        "version": str(version),
        "frame": str(t),
        "frames": str(FRAMES),
        "width": str(width),
        "height": str(height),
        "tile_offset": json.dumps(list(TILE_OFFSETS[t % 4])),
        "history": "none (first frame)" if t == 0 else f"{prefix}frame{t - 1}",
        "weights": f"{prefix}weights.safetensors",
        "weights_seed": str(weights_seed),
        "input_seed": str(input_seed),
        "layout": "HWC float32, logical (unpadded) channels",
    }


def spread_report(tensors: Dict[str, torch.Tensor]) -> str:
    o, out, tw = tensors["o"], tensors["output"], tensors["tfa_weights"]
    alpha = tw[..., 1]
    return (
        f"o std {o.std():.3f} [{o.min():.3f}, {o.max():.3f}], output std {out.std():.3f}, "
        f"output==0 {(out == 0).float().mean():.3f}, alpha std {alpha.std():.3f}, "
        f"enc1==0 {(tensors['enc1'] == 0).float().mean():.3f}"
    )


def check_spread(tensors: Dict[str, torch.Tensor], t: int) -> None:
    """Rejects degenerate goldens: a constant output or dead/saturated layers make a weak test."""
    out = tensors["output"]
    problems = []
    if out.std() < 0.05:
        problems.append(f"output std {out.std():.4f} < 0.05")
    if (out == 0).float().mean() > 0.5:
        problems.append("more than half of the output is clamped to 0")
    if not (out == 0).any():
        problems.append("no output pixel is clamped to 0 (the remodulation clamp goes untested)")
    for k in ("enc1", "enc2", "enc3", "ref_feat", "emb_cur"):
        if (tensors[k] == 0).float().mean() > 0.9:
            problems.append(f"{k} is > 90% zero")
    if t > 0 and tensors["tfa_weights"][..., 1].std() < 0.05:
        problems.append("alpha has no spread")
    if problems:
        raise RuntimeError(f"golden frame {t} is degenerate: " + "; ".join(problems))


def generate(out_dir: str, weights_seed: int = WEIGHTS_SEED, input_seed: int = INPUT_SEED, verbose: bool = True) -> List[str]:
    """Writes the three sets (version 2, with a fourth level, then the version-1 set) into
    out_dir; returns their paths."""
    paths = _generate_set(out_dir, "golden_", SSRConfig(), "coherent", weights_seed, input_seed, verbose)
    paths += _generate_set(out_dir, L4_PREFIX, SSRConfig(enc=L4_ENC), "coherent", weights_seed, input_seed, verbose)
    paths += generate_shared(out_dir, weights_seed, input_seed, verbose)
    legacy = SSRConfig(version=1, **LEGACY_OPTIONS)
    return paths + _generate_set(out_dir, LEGACY_PREFIX, legacy, "random", weights_seed, input_seed, verbose)


def generate_shared(out_dir: str, weights_seed: int = WEIGHTS_SEED, input_seed: int = INPUT_SEED, verbose: bool = True) -> List[str]:
    """The set of config exposure "shared" alone (SHARED_PREFIX)."""
    return _generate_set(out_dir, SHARED_PREFIX, SSRConfig(exposure="shared"), "coherent", weights_seed, input_seed, verbose)


def _generate_set(
    out_dir: str, prefix: str, cfg: SSRConfig, geometry: str, weights_seed: int, input_seed: int, verbose: bool
) -> List[str]:
    os.makedirs(out_dir, exist_ok=True)
    weights_path = os.path.join(out_dir, f"{prefix}weights.safetensors")
    model, _ = export_random(weights_path, weights_seed, cfg)
    if cfg.ceiling == "max":
        with torch.no_grad():
            model.unet.dec1[2].bias[0] += CEILING_PUSH
        init = {"scheme": RANDOM_INIT_SCHEME, "seed": int(weights_seed), "red_output_bias_push": CEILING_PUSH}
        export_weights(model, weights_path, RANDOM_PROVENANCE, {}, {"init": json.dumps(init, sort_keys=True, separators=(",", ":"))})
    frames = make_frames(input_seed, HEIGHT, WIDTH, FRAMES, geometry)
    paths = [weights_path]
    for t, tensors in enumerate(golden_tensors(model, frames)):
        check_spread(tensors, t)
        path = os.path.join(out_dir, f"{prefix}frame{t}.safetensors")
        data = safetensors_bytes(tensors, frame_metadata(t, WIDTH, HEIGHT, weights_seed, input_seed, prefix, cfg.version))
        if len(data) >= MAX_FILE_BYTES:
            raise RuntimeError(f"{path}: {len(data)} bytes, over the 1 MB limit")
        write_bytes(path, data)
        paths.append(path)
        if verbose:
            print(f"wrote {path}: {len(data)} bytes; {spread_report(tensors)}")
    if verbose:
        print(f"wrote {weights_path}: {os.path.getsize(weights_path)} bytes")
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.golden", description="Write golden parity cases.")
    ap.add_argument("--out", required=True, help="output folder (../tests/data from training/)")
    ap.add_argument("--weights-seed", type=int, default=WEIGHTS_SEED)
    ap.add_argument("--input-seed", type=int, default=INPUT_SEED)
    args = ap.parse_args(argv)
    generate(args.out, args.weights_seed, args.input_seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
