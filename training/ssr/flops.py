"""Measured cost of a model: FLOPs per output pixel of one steady-state frame step.

Every `nn.Conv2d` evaluated during the step is counted with a forward hook as
2 * (cin / groups) * cout * kh * kw per output pixel (multiply-add = 2 FLOP), so the count
follows what the model really runs (its resolutions, its recomputed history features).
Biases, activations, warps, pooling and blends are not counted, as in
`ssr.model.flops_per_pixel` (the analytic count of the SSR network).

    python -m ssr.flops weights/ssr.safetensors runs/rae/weights.safetensors ...
"""

from __future__ import annotations

import argparse
import sys
from typing import List

import torch
from torch import nn

from .model import SSRConfig, fold_emission
from .synth import make_sequence


@torch.no_grad()
def measured_flops_per_pixel(model: nn.Module, width: int = 64, height: int = 64, steps: int = 2) -> float:
    """Conv FLOPs of the last of `steps` frame steps on a synthetic sequence, per pixel."""
    count = [0.0]

    def hook(mod: nn.Conv2d, _inp, out: torch.Tensor) -> None:
        kh, kw = mod.kernel_size
        per_px = 2.0 * (mod.in_channels // mod.groups) * mod.out_channels * kh * kw
        count[0] += per_px * out.shape[0] * out.shape[-2] * out.shape[-1]

    handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, nn.Conv2d)]
    try:
        # Every buffer a model may read (the background, the footprint albedo, the directly
        # seen emission), fed as the engine feeds it (fold_emission: a no-op for models
        # without an SSR config of emission "background").
        frames = make_sequence(width, height, steps, seed=0, background=True, emission=True)
        cfg = getattr(model, "cfg", None)
        state = None
        for t, f in enumerate(frames):
            count[0] = 0.0
            batch = {k: torch.from_numpy(v).unsqueeze(0) for k, v in f.items() if k != "reference"}
            if isinstance(cfg, SSRConfig):
                batch = fold_emission(batch, cfg)
            state = model(batch, state)["state"]
        return count[0] / (width * height)
    finally:
        for h in handles:
            h.remove()


def main(argv: List[str] | None = None) -> int:
    from .baselines import load_model

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("weights", nargs="+", help="SSR or baseline weights files")
    args = ap.parse_args(argv)
    for path in args.weights:
        model, meta = load_model(path)
        params = sum(p.numel() for p in model.parameters())
        print(f"{path}: {meta['format']}, {params} parameters, {measured_flops_per_pixel(model):,.0f} FLOP/px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
