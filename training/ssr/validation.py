"""Validation of a model the way the engine runs it: whole val sequences from frame 0, the
output pass (background composite, mean correction) applied as the engine applies it, the
per-frame metrics averaged overall and per scene. Used by the trainer, the learning curve and
`ssr.export --option`."""

from __future__ import annotations

import torch
from torch import nn

from .data import SequenceDataset, pad_frame, read_extra_buffers
from .metrics import image_metrics, mean_metrics
from .model import fold_emission, mean_correction_of
from .model import output_pass as engine_output_pass  # `output_pass` is validate's flag


@torch.no_grad()
def validate(model: nn.Module, ds: SequenceDataset, device: torch.device, frames: int, size: int = 0,
             output_pass: bool = True) -> dict:
    """Runs every val sequence from frame 0 for `frames` frames (whole frames, padded to a
    multiple of 4 like the engine, optionally centre-cropped to `size`) and averages the
    per-frame metrics (PSNR/SSIM tonemapped 8-bit, RMSE/relMSE HDR). With the background
    buffers loaded (`ds.store.extra`), the output is composited as the engine does, and with
    config `mean_correction = "tiles"` (or "tiles16") corrected as the engine does (model.MeanCorrection);
    `output_pass=False` scores the network's own output (neither). Buffers the model reads
    beyond the dataset's (`model.extra_buffers`: config albedo = "footprint") come from each
    frame's file; config emission = "background" folds the directly seen emission into the
    background (model.fold_emission) as the engine's frame loop does."""
    was_training = model.training
    model.eval()
    rows, per_scene = [], {}
    cfg = getattr(model, "cfg", None)
    # (with config emission or escaped "background" the background and coverage too, which a
    # dataset loaded without them, e.g. by ssr.curve, lacks)
    extra = tuple(getattr(model, "extra_buffers", ()))
    for si, seq in enumerate(ds.sequences):
        state = None
        mc = mean_correction_of(cfg) if output_pass else None
        for t in range(min(frames, seq.frames)):
            f = ds.full_frame(si, t)
            missing = [b for b in extra if b not in f]
            if missing:
                why = "the model reads them (config albedo \"footprint\" or emission \"background\": `subpixel dataset --background N` adds them)"
                f.update(read_extra_buffers(seq.frame_path(t), missing, why))
            f = fold_emission(f, cfg)
            if size:
                h, w = f["color"].shape[-2:]
                ch, cw = min(h, size), min(w, size)
                y0, x0 = (h - ch) // 2, (w - cw) // 2
                f = {k: v[:, y0 : y0 + ch, x0 : x0 + cw] for k, v in f.items()}
            f = {k: v.unsqueeze(0).to(device) for k, v in f.items()}
            padded, (h, w) = pad_frame(f, getattr(model, "pad_multiple", 4))
            r = model(padded, state)
            state = r["state"]
            out = r["output"][:, :, :h, :w]
            if output_pass:
                out = engine_output_pass(out, f, mc)
            pred = out[0].float().cpu()
            m = image_metrics(pred, f["reference"][0].cpu())
            rows.append(m)
            per_scene.setdefault(seq.scene, []).append(m)
    model.train(was_training)
    out = mean_metrics(rows)
    out["frames"] = len(rows)
    out["sequences"] = len(ds.sequences)
    out["scenes"] = {k: mean_metrics(v) for k, v in sorted(per_scene.items())}
    return out
