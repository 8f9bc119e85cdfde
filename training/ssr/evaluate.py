"""Runs models over a dataset split and writes their predictions for `subpixel eval`.

    python -m ssr.evaluate --data ROOT --split test --out PRED \\
        --models input hold accumulation oidn-a ssr=runs/ssr/weights.safetensors rae=runs/rae/weights.safetensors

A model is `NAME=PATH` (an SSR or baseline weights file: the format is read from its
metadata) or one of the non-learned references `input` / `hold` / `accumulation` /
`oidn-a` / `oidn-b` (baselines.py, oidn.py; also as `NAME=input`). Every model runs over
every sequence of the split from frame 0 with an empty history, at full resolution (padded
to a multiple of 4 by edge replication, as the engine does, and cropped back; `hold` and
the OIDN rows run on the unpadded frame), and writes

    PRED/NAME/SPLIT/SEQUENCE/frame_NNNN.exr      channels pred.R pred.G pred.B (float32)
    PRED/NAME/SPLIT/SEQUENCE/sequence.json       a copy of the dataset's
    PRED/NAME/SPLIT/SEQUENCE/prediction.json     {"model", "weights", "format"}

so `subpixel eval --pred PRED/NAME --ref ROOT` scores them. It also prints its own table
(PSNR / SSIM / temporal error per scene, metrics.py) and, with --json, writes every
per-sequence metric (psnr, ssim, rmse, relmse, temporal) to a file.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
from torch import nn

from .baselines import NON_LEARNED, load_model
from .data import DatasetError, SequenceDataset, frame_name, pad_frame, read_extra_buffers, write_exr
from .export import WeightsError
from .metrics import image_metrics, mean_metrics, temporal_error
from .model import fold_emission, mean_correction_of, output_pass
from .oidn import OIDN_MODELS, OIDNUnavailable

REFERENCES = {**NON_LEARNED, **OIDN_MODELS}
"""The non-learned rows, by name: a callable returning the model."""

PRED_SUFFIXES = {"pred": ("R", "G", "B")}


def parse_model_spec(spec: str) -> Tuple[str, str]:
    """`NAME=PATH`, `NAME=REFERENCE`, or a bare REFERENCE (input, hold, accumulation, oidn-a,
    oidn-b)."""
    if "=" in spec:
        name, value = spec.split("=", 1)
    elif spec in REFERENCES:
        name, value = spec, spec
    else:
        raise ValueError(f"model spec {spec!r}: expected NAME=PATH or one of {sorted(REFERENCES)}")
    if not name or not value or "/" in name or name.startswith("."):
        raise ValueError(f"model spec {spec!r}: bad name or value")
    return name, value


def make_model(value: str, device: torch.device) -> Tuple[nn.Module, dict]:
    if value in REFERENCES:
        model = REFERENCES[value]().to(device).eval()
        info = model.info() if hasattr(model, "info") else {"format": f"non-learned-{value}", "weights": None}
        return model, info
    model, meta = load_model(value, device="cpu")
    return model.to(device).eval(), {"format": meta["format"], "weights": os.path.abspath(value), "provenance": meta["provenance"]}


@torch.no_grad()
def run_model(
    name: str,
    model: nn.Module,
    info: dict,
    ds: SequenceDataset,
    device: torch.device,
    out: Optional[str],
    frames: Optional[int] = None,
    metrics: bool = True,
    progress: bool = True,
) -> List[dict]:
    """Runs one model over every sequence; writes predictions under out/name (if out);
    returns per-sequence metric dicts {"sequence", "scene", "frames", psnr, ssim, ...}.

    A model may set `pad_multiple` (default 4: the engine's padding; 1: no padding) and
    `extra_buffers` (names of data.EXTRA_SUFFIXES) for buffers beyond data.BUFFERS, read from
    each frame file. An SSR model of config emission = "background" is fed its frames as the
    engine feeds it (model.fold_emission) and its output composited as the engine's output
    pass does (the emitters are added there); one with a `mean_correction` gets the whole
    output pass (model.MeanCorrection over each sequence from its first frame, with the
    background and the emitters), as the engine and the trainer's validation; other models'
    outputs are their own."""
    rows = []
    multiple = getattr(model, "pad_multiple", 4)
    cfg = getattr(model, "cfg", None)
    extra_buffers = tuple(getattr(model, "extra_buffers", ()))
    for si, seq in enumerate(ds.sequences):
        t0 = time.time()
        folder = os.path.join(out, name, seq.split, seq.name) if out else None
        if folder:
            os.makedirs(folder, exist_ok=True)
            shutil.copyfile(os.path.join(seq.path, "sequence.json"), os.path.join(folder, "sequence.json"))
            with open(os.path.join(folder, "prediction.json"), "w") as f:
                json.dump({"model": name, **{k: v for k, v in info.items() if k != "provenance"}}, f, indent=2)
        state = None
        mc = mean_correction_of(cfg)
        per_frame, temporal = [], []
        prev = None
        n = seq.frames if frames is None else min(frames, seq.frames)
        for t in range(n):
            f = ds.full_frame(si, t)
            if extra_buffers:
                f.update(read_extra_buffers(seq.frame_path(t), extra_buffers, f"{name} reads them"))
            fb = fold_emission({k: v.unsqueeze(0).to(device) for k, v in f.items()}, cfg)
            padded, (h, w) = pad_frame(fb, multiple)
            r = model(padded, state)
            state = r["state"]
            y = r["output"][:, :, :h, :w]
            # the engine's output pass (the emitters are its: without it they are missing); a
            # frame without a background (any model but emission = "background") passes unchanged
            y = output_pass(y, fb, mc)
            pred = y[0].float().cpu()
            if folder:
                write_exr(os.path.join(folder, frame_name(t)), {"pred": pred.numpy()}, PRED_SUFFIXES)
            if metrics:
                ref = f["reference"]
                per_frame.append(image_metrics(pred, ref))
                if prev is not None:
                    temporal.append(temporal_error(pred, prev[0], ref, prev[1], f["motion"]))
                prev = (pred, ref)
        row = {"model": name, "sequence": seq.id, "scene": seq.scene, "frames": n}
        if metrics:
            row.update(mean_metrics(per_frame))
            row["temporal"] = float(np.mean(temporal)) if temporal else 0.0
        rows.append(row)
        if progress:
            extra = f"  PSNR {row['psnr']:.2f}  SSIM {row['ssim']:.4f}  temporal {row['temporal']:.5f}" if metrics else ""
            print(f"  {name:14s} {seq.id:30s} {n:4d} frames {time.time() - t0:7.1f} s{extra}", flush=True)
    return rows


def summarise(rows: Sequence[dict]) -> Dict[str, Dict[str, dict]]:
    """{model: {scene: mean metrics over its sequences, "mean": mean over scenes}}."""
    out: Dict[str, Dict[str, dict]] = {}
    for model in dict.fromkeys(r["model"] for r in rows):
        mrows = [r for r in rows if r["model"] == model]
        keys = ["psnr", "ssim", "rmse", "relmse", "temporal"]
        scenes = {}
        for scene in sorted({r["scene"] for r in mrows}):
            srows = [r for r in mrows if r["scene"] == scene]
            scenes[scene] = {k: float(np.mean([r[k] for r in srows])) for k in keys}
        scenes["mean"] = {k: float(np.mean([s[k] for s in scenes.values()])) for k in keys}
        out[model] = scenes
    return out


def format_table(summary: Dict[str, Dict[str, dict]], split: str) -> str:
    models = list(summary)
    if not models:
        return "(no results)\n"
    scenes = [s for s in summary[models[0]] if s != "mean"] + ["mean"]
    width = max(26, *(len(s) + 2 for s in scenes))
    lines = [f"PSNR (dB) / SSIM / temporal error on {split}, tonemapped (Uncharted 2 filmic, gamma 2.2; PSNR, SSIM 8-bit)"]
    lines.append(f"{'model':14s}" + "".join(f"{s:>{width}s}" for s in scenes))
    for m in models:
        cells = []
        for s in scenes:
            v = summary[m].get(s)
            cells.append(f"{v['psnr']:.2f} / {v['ssim']:.4f} / {v['temporal']:.4f}" if v else "-")
        lines.append(f"{m:14s}" + "".join(f"{c:>{width}s}" for c in cells))
    lines.append("")
    lines.append(f"{'model':14s}{'RMSE':>12s}{'relMSE':>12s}{'temporal':>12s}   (HDR; temporal: tonemapped L1, mean of scenes)")
    for m in models:
        v = summary[m]["mean"]
        lines.append(f"{m:14s}{v['rmse']:12.5f}{v['relmse']:12.5f}{v['temporal']:12.5f}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.evaluate", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="dataset root")
    ap.add_argument("--split", default="test", choices=["train", "val", "test"])
    ap.add_argument("--models", nargs="+", required=True, help="NAME=WEIGHTS.safetensors, input, hold, accumulation, oidn-a, oidn-b, oidn-a-footprint, oidn-b-footprint, oidn-a-footprint-escaped")
    ap.add_argument("--out", default=None, help="prediction root (PRED/NAME/SPLIT/SEQ/frame_NNNN.exr); none: no files")
    ap.add_argument("--scenes", nargs="+", default=None)
    ap.add_argument("--frames", type=int, default=None, help="at most this many frames per sequence")
    ap.add_argument("--no-metrics", action="store_true", help="only write predictions")
    ap.add_argument("--json", default=None, help="write per-sequence and summary metrics here")
    ap.add_argument("--device", default="auto", choices=["auto", "cuda", "cpu"])
    args = ap.parse_args(argv)
    device = torch.device("cuda" if args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available()) else "cpu")
    try:
        specs = [parse_model_spec(s) for s in args.models]
    except ValueError as err:
        ap.error(str(err))
    names = [n for n, _ in specs]
    if len(set(names)) != len(names):
        ap.error(f"model names must be unique, got {names}")
    try:
        ds = SequenceDataset(args.data, args.split, window=1, crop=None, flips=False, scenes=args.scenes)
        models = [(n, *make_model(v, device)) for n, v in specs]
        frames = [s.frame_path(t) for s in ds.sequences for t in range(s.frames if args.frames is None else min(args.frames, s.frames))]
        for _, model, _ in models:
            if hasattr(model, "check_frames"):  # oidn-b: every frame has its 1-spp colour
                model.check_frames(frames)
    except (DatasetError, WeightsError, FileNotFoundError, OIDNUnavailable) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"{len(ds.sequences)} {args.split} sequences ({', '.join(ds.scenes)}), {len(models)} models, device {device}")
    rows = []
    try:
        for name, model, info in models:
            rows += run_model(name, model, info, ds, device, args.out, args.frames, not args.no_metrics)
    except DatasetError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    if not args.no_metrics:
        summary = summarise(rows)
        print()
        print(format_table(summary, args.split), end="")
        if args.json:
            with open(args.json, "w") as f:
                json.dump({"split": args.split, "sequences": rows, "summary": summary}, f, indent=2, sort_keys=True)
    if args.out:
        print(f"predictions in {args.out}/NAME/{args.split}/ (score with: subpixel eval --pred {args.out}/NAME --ref {args.data})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
