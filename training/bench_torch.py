#!/usr/bin/env python
"""Times the SSR network in PyTorch from a weights file, to set beside `subpixel bench denoise`.

    cd training
    python bench_torch.py --weights ../weights/ssr.safetensors --width 1920 --height 1080 \\
        --frames 100 --device cuda [--modes eager,fp16,compile] [--json out.json]

Modes (issue 6, item 3):
  eager    fp32, NCHW, the model exactly as trained (ssr/model.py)
  fp16     channels-last memory format + torch.autocast(float16): convs in fp16, the warp,
           softmax blend and (de)modulation stay fp32 (an fp16 warp cannot address 1080p
           pixels exactly). CUDA only; skipped with a note on the CPU.
  compile  torch.compile of each stage (fp32), where torch.compile works (it needs a C++
           compiler on the CPU); the compile time is reported and excluded.

Each mode runs `--warmup` untimed frames, then `--frames` timed ones, in steady state (the
recurrent history of the previous frame is warped every frame; the synthetic inputs are
those of `subpixel bench`: four frames of the 1/4-spp pattern, constant 0.25 px motion).
On CUDA every stage is timed with CUDA events and the frame synchronised, as the Rust
benchmark waits for each frame; on the CPU with perf_counter.

Stages (rows) line up with `subpixel bench denoise`'s per-stage table:
  tfa    = exposure + pack (prepare_inputs: demodulate, log1p(shadow)) + warp of (A_acc, o)
           + history test and re-exposure + TFA (SSRModel.history, TFA)
  unet   = U-Net + remodulation (the Rust `unet` stage)
  output = the output pass: the model's mean correction (config `mean_correction`, its
           history carried over the frames) and composite, as the Rust `output` stage
           (ssr.model.output_pass; the synthetic frame has no background)
  network = tfa + unet (the network without the output pass; median of the per-frame sums)
  total  = one whole frame (median/p95 of the per-frame sums)
FLOPs count 18 Cin Cout per 3x3 conv per output pixel at the padded size (multiples of 4),
as `flops_per_pixel` and the Rust `step_flops` do; GFLOP/s = FLOPs / median time.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from typing import Callable, Dict, List, Optional, Tuple

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import torch  # noqa: E402

from ssr.export import load_weights  # noqa: E402
from ssr.train import device_name  # noqa: E402
from ssr.model import (  # noqa: E402
    A_CHANNELS,
    RGB,
    STATE_EXPOSURE_CHANNELS,
    TILE_OFFSETS,
    SSRModel,
    ceiling,
    conv_layers,
    mean_correction_of,
    output_pass,
    remodulate,
)

MODES = ("eager", "fp16", "compile")


def round_up4(n: int) -> int:
    return (n + 3) // 4 * 4


def synthetic_frame(w: int, h: int, t: int, device: torch.device) -> Dict[str, torch.Tensor]:
    """The frame of src/bench/denoise.rs `synthetic_frame` (NCHW, batch 1)."""
    dx, dy = TILE_OFFSETS[t % 4]
    ys = torch.arange(h).view(h, 1).expand(h, w)
    xs = torch.arange(w).view(1, w).expand(h, w)
    mask = ((xs % 2 == dx) & (ys % 2 == dy)).float()
    c = torch.arange(3).view(3, 1, 1)
    color = mask * ((xs + 3 * ys + c) % 7).float() * 0.3
    albedo = 0.2 + 0.2 * ((xs // 8 + c) % 4).float()
    normal = torch.zeros(3, h, w)
    normal[2] = 1.0
    frame = {
        "color": color,
        "mask": mask[None],
        "albedo": albedo,
        "normal": normal,
        "shadow": mask[None].expand(3, h, w).clone(),
        "transparent": torch.zeros(3, h, w),
        "depth": (0.5 + 0.001 * ys.float())[None],
        "metallic": torch.zeros(1, h, w),
        "roughness": torch.full((1, h, w), 0.5),
        "motion": torch.stack([torch.full((h, w), 0.25), torch.zeros(h, w)]),
    }
    return {k: v.unsqueeze(0).contiguous().to(device) for k, v in frame.items()}


def stage_flops(model: SSRModel, wp: int, hp: int) -> Dict[str, int]:
    out = {"tfa": 0, "unet": 0, "output": 0}
    for name, cin, cout, level, evals in conv_layers(model.cfg):
        f = 18 * cin * cout * evals * (wp >> level) * (hp >> level)
        out["tfa" if name.startswith("tfa.") else "unet"] += f
    out["network"] = out["total"] = out["tfa"] + out["unet"]
    return out


def make_stages(model: SSRModel) -> Tuple[Callable, Callable]:
    def tfa_stage(frame, a_acc_prev, o_prev, s_prev):
        # exposure, pack, warp of (A_acc, o), history test and re-exposure (model.history), TFA
        h = model.history(frame, (a_acc_prev, o_prev.to(a_acc_prev.dtype), s_prev))
        a_acc = model.tfa(h["a_cur"], h["mt"], h["warp_acc"], h["warp_valid"])["a_acc"]
        return h["a_cur"], h["mt"], a_acc, h["warp_out"], h["exposure"]

    def unet_stage(a_t, mt, a_acc, wo, s):
        o = model.unet(a_t, mt, a_acc, wo)["o"]
        if model.cfg.ceiling == "max":  # the output ceiling, as in SSRModel.forward
            o = torch.minimum(o, ceiling(s).to(o.dtype))
        albedo = model.remodulation_albedo(a_t, a_acc)
        return remodulate(o.float(), albedo.float()) * s[:, :RGB], o

    return tfa_stage, unet_stage


def percentile(xs: List[float], q: float) -> float:
    s = sorted(xs)
    if not s:
        return float("nan")
    k = min(len(s) - 1, max(0, int(round(q * (len(s) - 1)))))
    return s[k]


def bench_mode(
    mode: str, model: SSRModel, w: int, h: int, frames: int, warmup: int, device: torch.device, compile_mode: Optional[str]
) -> dict:
    """Times one mode; returns {"mode", "stages": {tfa, unet, total: {median_ms, p95_ms}}, ...}."""
    wp, hp = round_up4(w), round_up4(h)
    cuda = device.type == "cuda"
    m = model
    channels_last = mode == "fp16"
    if channels_last:
        m = model.to(memory_format=torch.channels_last)
    inputs = [synthetic_frame(wp, hp, t, device) for t in range(4)]
    if channels_last:
        inputs = [{k: v.contiguous(memory_format=torch.channels_last) for k, v in f.items()} for f in inputs]
    tfa_stage, unet_stage = make_stages(m)
    mc = mean_correction_of(model.cfg)
    compile_s = None
    if mode == "compile":
        kw = {"mode": compile_mode} if compile_mode else {}
        tfa_stage = torch.compile(tfa_stage, **kw)
        unet_stage = torch.compile(unet_stage, **kw)
    a_acc = torch.zeros(1, A_CHANNELS, hp, wp, device=device)
    o = torch.zeros(1, RGB, hp, wp, device=device)
    s = torch.ones(1, STATE_EXPOSURE_CHANNELS, 1, 1, device=device)
    if channels_last:
        a_acc = a_acc.contiguous(memory_format=torch.channels_last)
        o = o.contiguous(memory_format=torch.channels_last)

    def autocast():
        if mode == "fp16":
            return torch.autocast(device_type="cuda", dtype=torch.float16)
        return torch.autocast(device_type=device.type, enabled=False)

    sync = torch.cuda.synchronize if cuda else (lambda: None)
    times = {"tfa": [], "unet": [], "output": [], "network": [], "total": [], "wall": []}
    with torch.inference_mode():
        if mode == "compile":
            t0 = time.perf_counter()
            with autocast():
                r = tfa_stage(inputs[0], a_acc, o, s)
                unet_stage(*r)
            sync()
            compile_s = time.perf_counter() - t0
        for i in range(warmup + frames):
            f = inputs[i % 4]
            w0 = time.perf_counter()
            if cuda:
                ev = [torch.cuda.Event(enable_timing=True) for _ in range(4)]
                ev[0].record()
            with autocast():
                a_t, mt, a_acc2, wo, s2 = tfa_stage(f, a_acc, o, s)
                if cuda:
                    ev[1].record()
                else:
                    w1 = time.perf_counter()
                out, o2 = unet_stage(a_t, mt, a_acc2, wo, s2)
                if cuda:
                    ev[2].record()
                else:
                    w2 = time.perf_counter()
                out = output_pass(out, f, mc)
            if cuda:
                ev[3].record()
            sync()
            w3 = time.perf_counter()
            a_acc, o, s = a_acc2, o2, s2
            if i < warmup:
                continue
            if cuda:
                t_tfa, t_unet, t_out = (ev[k].elapsed_time(ev[k + 1]) for k in range(3))
            else:
                t_tfa, t_unet, t_out = (w1 - w0) * 1e3, (w2 - w1) * 1e3, (w3 - w2) * 1e3
            times["tfa"].append(t_tfa)
            times["unet"].append(t_unet)
            times["output"].append(t_out)
            times["network"].append(t_tfa + t_unet)
            times["total"].append(t_tfa + t_unet + t_out)
            times["wall"].append((w3 - w0) * 1e3)
        if not torch.isfinite(out).all():
            raise RuntimeError(f"{mode}: non-finite output")
    fl = stage_flops(model, wp, hp)
    stages = {}
    for s in ("tfa", "unet", "output", "network", "total"):
        med = statistics.median(times[s])
        stages[s] = {
            "median_ms": med,
            "p95_ms": percentile(times[s], 0.95),
            "flops": fl[s],
            "gflop_per_s": fl[s] / (med * 1e-3) * 1e-9 if med > 0 else float("nan"),
        }
    if channels_last:
        model.to(memory_format=torch.contiguous_format)
    return {
        "mode": mode,
        "stages": stages,
        "wall_median_ms": statistics.median(times["wall"]),
        "compile_s": compile_s,
    }


MODE_LABEL = {"eager": "eager fp32", "fp16": "channels-last fp16", "compile": "torch.compile fp32"}


def format_table(res: dict) -> str:
    lines = [
        f"device: {res['device_name']} (torch {res['torch']}{', CUDA ' + res['cuda'] if res['cuda'] else ''})",
        f"SSR (PyTorch) at {res['width']}x{res['height']} (padded {res['padded'][0]}x{res['padded'][1]}), "
        f"median over {res['frames']} frames after {res['warmup']} warm-up ({res['timer']})",
        f"{res['flops_per_pixel']:.1f} FLOP/px",
        "",
        f"{'mode':<20} {'stage':<7} {'MFLOP':>10} {'median ms':>10} {'p95 ms':>10} {'GFLOP/s':>10}",
    ]
    for r in res["results"]:
        label = MODE_LABEL[r["mode"]]
        for s in ("tfa", "unet", "output", "total"):
            st = r["stages"][s]
            lines.append(
                f"{label:<20} {s:<7} {st['flops'] * 1e-6:>10.1f} {st['median_ms']:>10.4f} {st['p95_ms']:>10.4f} {st['gflop_per_s']:>10.1f}"
            )
            label = ""
        if r.get("compile_s") is not None:
            lines.append(f"{'':<20} (compile {r['compile_s']:.1f} s, excluded)")
    for n in res["notes"]:
        lines.append(f"note: {n}")
    lines.append("stages: tfa = pack + warp + TFA; unet = U-Net + remodulate; output = mean correction + composite; "
                 "as in `subpixel bench denoise`")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Time the SSR network in PyTorch (eager fp32, channels-last fp16, torch.compile).")
    ap.add_argument("--weights", required=True, help="SSR weights (.safetensors)")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--frames", type=int, default=100, help="timed frames")
    ap.add_argument("--warmup", type=int, default=10, help="untimed frames first")
    ap.add_argument("--device", default="auto", choices=["auto", "cuda", "cpu"])
    ap.add_argument("--modes", default=",".join(MODES), help=f"comma-separated subset of {','.join(MODES)}")
    ap.add_argument("--compile-mode", default=None, help="torch.compile mode (e.g. max-autotune)")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args(argv)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in MODES]
    if bad:
        ap.error(f"unknown mode(s) {bad}; choose from {list(MODES)}")
    if args.width <= 0 or args.height <= 0 or args.frames <= 0 or args.warmup < 0:
        ap.error("width, height and frames must be positive, warmup non-negative")
    if args.device == "cuda" and not torch.cuda.is_available():
        ap.error("--device cuda but CUDA is not available")
    device = torch.device("cuda" if args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available()) else "cpu")
    model, _ = load_weights(args.weights)
    model = model.to(device).eval()
    wp, hp = round_up4(args.width), round_up4(args.height)
    fl = stage_flops(model, wp, hp)
    name = device_name(device)
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True
    else:
        name = f"CPU {name}"
    res = {
        "device": device.type,
        "device_name": name,
        "torch": torch.__version__,
        "cuda": torch.version.cuda if device.type == "cuda" else None,
        "weights": os.path.abspath(args.weights),
        "width": args.width,
        "height": args.height,
        "padded": [wp, hp],
        "frames": args.frames,
        "warmup": args.warmup,
        "timer": "CUDA events" if device.type == "cuda" else "CPU perf_counter",
        "flops_per_pixel": fl["total"] / (wp * hp),
        "results": [],
        "notes": [],
    }
    for mode in modes:
        if mode == "fp16" and device.type != "cuda":
            res["notes"].append("channels-last fp16 skipped: CUDA only (CPU fp16 convolutions are not a meaningful timing)")
            continue
        if mode == "compile" and not hasattr(torch, "compile"):
            res["notes"].append("torch.compile skipped: not in this PyTorch")
            continue
        try:
            res["results"].append(bench_mode(mode, model, args.width, args.height, args.frames, args.warmup, device, args.compile_mode))
        except Exception as err:  # torch.compile without a working toolchain, out of memory, ...
            if mode == "eager":
                raise
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            res["notes"].append(f"{MODE_LABEL[mode]} skipped: {type(err).__name__}: {first[:200]}")
            if device.type == "cuda":
                torch.cuda.empty_cache()
    print(format_table(res), end="")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
