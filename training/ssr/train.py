"""Training (DESIGN sections 4 and 6): SSR or a learned baseline on a `subpixel dataset` folder.

    python -m ssr.train --data ROOT --out RUN_DIR [--model ssr|rae|nsrr] [--iters N]
                        [--batch 8] [--crop 256] [--lr 1e-4] [--scenes S ...] [--resume]
    torchrun --nproc_per_node G -m ssr.train ...          (DistributedDataParallel)

* Loss: the five losses of losses.py with their weights over 5-frame windows (SSR:
  losses.sequence_loss; baselines: the same total_loss, l_a on their own o and albedo).
* Adam, lr halved at round(iters / 3) and round(2 iters / 3) (a pure function of the
  iteration, so resuming needs no scheduler state).
* Data: random windows, crops and flips from data.WindowSampler, seeded by (seed, rank,
  iteration): a resumed run sees the batches an uninterrupted one would have seen.
  --batch is the global batch; each of the WORLD_SIZE processes takes batch / WORLD_SIZE.
* Checkpoints: RUN_DIR/checkpoint.pt (model, optimizer, iteration, config, every rank's RNG
  states, wall time, validation history), written atomically every --ckpt-every iterations
  and at the end, and when SIGTERM or SIGINT arrives (`kill PID`, Ctrl-C: the run finishes
  the iteration in progress, checkpoints it and returns; a second signal stops at once).
  --resume continues from it; a checkpoint whose config differs (model,
  widths, batch, crop, lr, iters, window, scenes, flips, seed) is an error naming the file
  and the keys. Without --resume an existing checkpoint is an error (no silent overwrite).
* Progress: a line every --log-every iterations (loss and its parts, lr, it/s, ETA) and the
  validation metrics (PSNR/SSIM on tonemapped 8-bit images, metrics.py) on the val split
  every --val-every iterations; the same as JSON lines in RUN_DIR/log.jsonl.
* At the end: RUN_DIR/weights.safetensors with provenance (model, scenes, sequences,
  iterations, hardware, wall time, ...) and the final validation metrics.

Device: CUDA when available (else CPU), or --device. Under torchrun (env WORLD_SIZE > 1)
each process uses cuda:LOCAL_RANK with NCCL, or the CPU with gloo.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import random
import signal
import subprocess
import sys
import threading
import time
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from . import losses
from .baselines import build_model, export_model, loss_aux
from .data import THIN_KEEP_MIN, DatasetError, SequenceDataset, WindowSampler, collate
from .model import (
    FINE_TUNE_OPTIONS,
    OUTPUT_PASS_OPTIONS,
    MeanCorrection,
    SSRConfig,
    SSRModel,
    extra_buffers,
    fold_emission,
    grow_unet,
    leaves_escaped,
    mean_correction_of,
    output_pass,
)
from .validation import validate

CHECKPOINT_FORMAT = "subpixel-train-checkpoint"
CHECKPOINT_VERSION = 1
CHECKPOINT_FILE = "checkpoint.pt"
WEIGHTS_FILE = "weights.safetensors"


class CheckpointError(ValueError):
    """A checkpoint that cannot be resumed (other config, bad file): names the file."""


# ----------------------------------------------------------------------------- arguments


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m ssr.train", description="Train SSR (or a baseline) on a subpixel dataset.")
    ap.add_argument("--data", required=True, help="dataset root: ROOT/{train,val,test}/SEQUENCE/")
    ap.add_argument("--out", required=True, help="run folder (checkpoint, log, weights)")
    ap.add_argument("--model", default="ssr", choices=["ssr", "rae", "nsrr"])
    ap.add_argument("--model-config", default=None, help="JSON overriding the model's default config (e.g. widths)")
    ap.add_argument("--iters", type=int, default=60000, help="training iterations (default 60000)")
    ap.add_argument("--batch", type=int, default=8, help="global batch (split over torchrun processes)")
    ap.add_argument("--crop", type=int, default=256, help="crop size, a multiple of 4")
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--window", type=int, default=5, help="frames per training sequence")
    ap.add_argument(
        "--frame-weights", default=None,
        help="comma-separated loss weight of each frame of a window, first to last (as many as --window; "
        "default: the paper's 0.05,0.25,0.5,0.75,1 for 5 frames, its last ones for fewer, 0.05 prepended for more)",
    )
    ap.add_argument("--scenes", nargs="+", default=None, help="train (and validate) on these scenes only")
    ap.add_argument("--no-flips", action="store_true", help="no random flips")
    ap.add_argument(
        "--color-permute", action="store_true",
        help="permute each window's RGB channels (one of the six orders) in every RGB buffer alike "
        "(ssr/data.py: the render of a scene with permuted spectra; off by default)",
    )
    ap.add_argument(
        "--thin", type=float, default=0.0,
        help="probability of sample thinning per window (ssr/data.py: Russian roulette on the input samples; 0: off)",
    )
    ap.add_argument(
        "--thin-keep-min", type=float, default=THIN_KEEP_MIN,
        help=f"lowest keep probability of sample thinning (log-uniform in [this, 1]; default {THIN_KEEP_MIN})",
    )
    ap.add_argument(
        "--min-reference-psnr", type=float, default=None,
        help="leave out training sequences whose references are noisier than this: the mean PSNR (dB) between "
        "their two halves, as sequence.json records it (default: keep every sequence; validation is never filtered). "
        "Like --data it chooses data: a run may resume with another threshold",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resume", action="store_true", help="continue from RUN_DIR/checkpoint.pt")
    ap.add_argument(
        "--resume-from", default=None, metavar="CHECKPOINT",
        help="continue from this checkpoint file when RUN_DIR has none of its own (with one: as --resume), "
        "e.g. a restore point RUN_DIR/snapshots/it_NNNNNNN.pt of a run whose machine is gone, committed or copied: "
        "the run goes on exactly as from its own checkpoint (weights, Adam's moments, RNG, iteration); the other "
        "options must be the run's, --init and --init-at included for a run begun part-way through its schedule",
    )
    ap.add_argument("--ckpt-every", type=int, default=1000)
    ap.add_argument("--val-every", type=int, default=2000, help="0: only at the end")
    ap.add_argument("--val-frames", type=int, default=16, help="frames per val sequence (from frame 0)")
    ap.add_argument("--val-size", type=int, default=0, help="centre-crop val frames to at most this size (0: whole)")
    ap.add_argument("--log-every", type=int, default=50)
    ap.add_argument("--workers", type=int, default=4, help="DataLoader worker processes per GPU/process")
    ap.add_argument("--cache", default="none", choices=["none", "memory", "disk"], help="frame cache (see ssr/data.py)")
    ap.add_argument("--cache-mb", type=float, default=4096.0, help="memory cache size per process, MiB")
    ap.add_argument("--cache-dir", default=None, help="disk cache folder (default ROOT/.cache)")
    ap.add_argument("--device", default="auto", choices=["auto", "cuda", "cpu"])
    ap.add_argument("--clip", type=float, default=0.0, help="clip the gradient norm (0: off)")
    ap.add_argument("--stop-at", type=int, default=None, help="checkpoint and stop at this iteration (time-limited jobs)")
    ap.add_argument(
        "--init", default=None,
        help="start from this weights file (same model and config, but the albedo may differ; its output-pass "
        "options and albedo carry over unless --model-config sets them; e.g. the committed weights of an earlier "
        "session) with a fresh optimizer",
    )
    ap.add_argument(
        "--init-at", type=int, default=0, metavar="N",
        help="with --init: begin at iteration N of the --iters run (the learning-rate schedule and the "
        "sampled windows as if its first N iterations had run, e.g. to finish a run whose checkpoint was lost "
        "from its last committed snapshot; Adam's moments start fresh)",
    )
    ap.add_argument(
        "--snapshot-every", type=int, default=0,
        help="also export RUN_DIR/snapshots/it_NNNNNNN.safetensors every N iterations (for learning curves), with "
        "the checkpoint at that iteration as it_NNNNNNN.pt (a restore point for --resume-from; 0: off)",
    )
    ap.add_argument("--threads", type=int, default=0, help="PyTorch CPU threads (0: PyTorch's default)")
    ap.add_argument(
        "--background", default="none", choices=["none", "val", "loss"],
        help="the background buffer (frames need the background and coverage channels, `subpixel dataset "
        "--background N`): `val` scores validation on the engine's output (composited with the background, "
        "model.composite_background), `loss` also trains on it (no gradient from wholly sky pixels); default none",
    )
    ap.add_argument(
        "--mean-correction", default="none", choices=["none", "loss"],
        help="`loss`: train on the output after the engine's mean correction (model.MeanCorrection, over each "
        "window's frames; needs --background loss); the exported config's `mean_correction` is the initial "
        "weights' either way; default none",
    )
    ap.add_argument(
        "--lambda", dest="lambdas", action="append", default=[], metavar="TERM=WEIGHT",
        help=f"override a loss weight (repeatable; terms and defaults: {losses.LAMBDAS}), e.g. --lambda m=1",
    )
    args = ap.parse_args(argv)
    if args.mean_correction == "loss" and args.background != "loss":
        ap.error("--mean-correction loss needs --background loss (the correction of the engine's output uses the background)")
    try:
        args.lambdas = loss_weights(args.lambdas)
    except ValueError as err:
        ap.error(str(err))
    if args.iters <= 0:
        ap.error("--iters must be positive")
    if args.crop <= 0 or args.crop % 4:
        ap.error(f"--crop must be a positive multiple of 4, got {args.crop}")
    if args.window < 2:
        ap.error("--window must be at least 2 (the warped temporal loss uses the last two frames)")
    try:
        args.frame_weights = parse_frame_weights(args.frame_weights, args.window)
    except ValueError as err:
        ap.error(str(err))
    if args.snapshot_every < 0 or args.threads < 0:
        ap.error("--snapshot-every and --threads must not be negative")
    if args.init is not None and not os.path.isfile(args.init):
        ap.error(f"--init {args.init}: no such file")
    if args.resume_from is not None and not os.path.isfile(args.resume_from):
        ap.error(f"--resume-from {args.resume_from}: no such file")
    if args.init_at and args.init is None:
        ap.error("--init-at needs --init (the weights at that iteration)")
    if not 0 <= args.init_at < args.iters:
        ap.error(f"--init-at {args.init_at}: expected 0 <= N < --iters ({args.iters})")
    return args


def loss_weights(overrides: List[str]) -> Dict[str, float]:
    """losses.LAMBDAS with `TERM=WEIGHT` overrides applied; unknown terms and bad numbers are errors."""
    lam = dict(losses.LAMBDAS)
    for item in overrides:
        term, sep, value = item.partition("=")
        if not sep or term not in lam:
            raise ValueError(f"--lambda {item!r}: expected TERM=WEIGHT with TERM one of {sorted(lam)}")
        try:
            w = float(value)
        except ValueError:
            raise ValueError(f"--lambda {item!r}: {value!r} is not a number") from None
        if not math.isfinite(w) or w < 0:
            raise ValueError(f"--lambda {item!r}: the weight must be finite and >= 0")
        lam[term] = w
    return lam


def run_config(args: argparse.Namespace) -> dict:
    """The settings a checkpoint must share to be resumed (not paths, logging, workers, device)."""
    model_cfg = json.loads(args.model_config) if args.model_config else {}
    if args.init is not None:
        # Options of the engine's output pass and the albedo follow the initial weights
        # unless set here (continuing a model keeps its pipeline).
        model_cfg = {**init_inherited_options(args.init), **model_cfg}
    model = build_model(args.model, model_cfg)
    cfg_dict = model.cfg.to_dict()
    for option, why in (("emission", "the emitters are"), ("escaped", "the escaped samples' sky is")):
        if getattr(model.cfg, option, "network") == "background" and args.background != "loss":
            raise SystemExit(
                f'error: config {option} = "background" needs --background loss ({why} the '
                "background's: the loss must see the composited output)"
            )
    return {
        "model": args.model,
        "model_config": cfg_dict,
        "iters": args.iters,
        "batch": args.batch,
        "crop": args.crop,
        "lr": args.lr,
        "window": args.window,
        "scenes": sorted(args.scenes) if args.scenes else None,
        "flips": not args.no_flips,
        "seed": args.seed,
        "clip": args.clip,
        "frame_weights": list(args.frame_weights),
        "lambdas": dict(args.lambdas),
        # Only present for runs started from weights (older checkpoints have no such key).
        **({"init": init_identity(args.init)} if args.init is not None else {}),
        # Only present for runs begun part-way through their schedule (--init-at).
        **({"init_at": args.init_at} if args.init_at else {}),
        # Only present when the loss sees the background (older checkpoints have no such key).
        **({"background": "loss"} if args.background == "loss" else {}),
        # Only present when the loss sees the mean correction (older checkpoints have no such key).
        **({"mean_correction": "loss"} if args.mean_correction == "loss" else {}),
        # Only present when sample thinning is on (older checkpoints have no such key).
        **({"thin": args.thin} if args.thin > 0 else {}),
        **({"thin_keep_min": args.thin_keep_min} if args.thin > 0 and args.thin_keep_min != THIN_KEEP_MIN else {}),
        # Only present when colour permutation is on (older checkpoints have no such key).
        **({"color_permute": True} if args.color_permute else {}),
        # Not the reference-noise threshold (--min-reference-psnr): like --data, it chooses the
        # training sequences, which a run may change where it resumes (normalised_config).
    }


def init_identity(path: Optional[str]) -> Optional[dict]:
    """What a run started from: None, or the weights file's name and SHA-256 (so a resume
    with other starting weights is refused, and the provenance says where a run began)."""
    if path is None:
        return None
    import hashlib

    with open(path, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    return {"file": os.path.basename(path), "sha256": digest}


def init_inherited_options(path: str) -> dict:
    """The config options a run started from weights file `path` takes from it unless
    `--model-config` sets them: the engine's output pass (model.OUTPUT_PASS_OPTIONS) and the
    albedo (model.FINE_TUNE_OPTIONS), as the file sets them; {} for a file without them or
    not readable as such (load_init reports what is wrong with it)."""
    try:
        from safetensors import safe_open

        with safe_open(path, "pt") as f:
            cfg = json.loads((f.metadata() or {}).get("config", "{}"))
    except Exception:  # noqa: BLE001 - load_init names the problem
        return {}
    inherited = OUTPUT_PASS_OPTIONS + FINE_TUNE_OPTIONS
    return {k: cfg[k] for k in inherited if isinstance(cfg, dict) and k in cfg}


def load_init(model: nn.Module, path: str, model_name: str) -> dict:
    """Loads `path` into `model`: the weights loader checks the file (format, every tensor's
    name and shape); its config must equal the run's but for model.FINE_TUNE_OPTIONS (what
    the network is fed, not its parameters: the run fine-tunes the weights to the new
    value), but for model.OUTPUT_PASS_OPTIONS (applied after the network), and but for a
    fourth U-Net level the file lacks (its `enc` the run's first three widths: the file's
    tensors grown into the run's model by model.grow_unet, computing the same). Returns the
    file's metadata."""
    from .baselines import load_model
    from .export import WeightsError

    try:
        loaded, meta = load_model(path)
    except (WeightsError, ValueError, OSError) as err:
        raise CheckpointError(f"--init {path}: {err}") from err
    want, got = model.cfg.to_dict(), loaded.cfg.to_dict()
    free = FINE_TUNE_OPTIONS + OUTPUT_PASS_OPTIONS
    same = lambda d: {k: v for k, v in d.items() if k not in free + ("enc",)}  # noqa: E731
    # a 3-level file starts a 4-level run of the same first three widths (model.grow_unet)
    grow = len(got["enc"]) == 3 and len(want["enc"]) == 4 and want["enc"][:3] == got["enc"]
    if type(loaded) is not type(model) or same(got) != same(want) or (got["enc"] != want["enc"] and not grow):
        raise CheckpointError(
            f"--init {path}: its model config {json.dumps(got, sort_keys=True)} differs from the run's "
            f"{json.dumps(want, sort_keys=True)} (model {model_name})"
        )
    model.load_state_dict(grow_unet(loaded.state_dict(), model) if grow else loaded.state_dict())
    return meta


def config_diff(saved: dict, current: dict) -> List[str]:
    keys = sorted(set(saved) | set(current))
    out = []
    for k in keys:
        a, b = saved.get(k, "<absent>"), current.get(k, "<absent>")
        if a != b:
            out.append(f"{k}: {json.dumps(a)} in the checkpoint, {json.dumps(b)} now")
    return out


def frame_weights(window: int) -> Tuple[float, ...]:
    """FRAME_WEIGHTS for 5 frames; otherwise the last `window` of (…, 0.05, 0.25, 0.5, 0.75, 1)
    extended with 0.05 at the front (a documented generalisation)."""
    w = losses.FRAME_WEIGHTS
    if window == len(w):
        return tuple(w)
    if window < len(w):
        return tuple(w[-window:])
    return (w[0],) * (window - len(w)) + tuple(w)


def parse_frame_weights(text: Optional[str], window: int) -> Tuple[float, ...]:
    """`--frame-weights`: `window` comma-separated finite weights >= 0, not all 0; None gives
    frame_weights(window)."""
    if text is None:
        return frame_weights(window)
    try:
        w = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--frame-weights {text!r}: expected comma-separated numbers") from None
    if len(w) != window:
        raise ValueError(f"--frame-weights {text!r}: {len(w)} weight(s) for a --window of {window} frames")
    if not all(math.isfinite(x) and x >= 0 for x in w) or not any(w):
        raise ValueError(f"--frame-weights {text!r}: weights must be finite, >= 0 and not all 0")
    return w


def lr_at(base: float, iteration: int, iters: int) -> float:
    """base, halved at round(iters / 3) and again at round(2 iters / 3)."""
    m1, m2 = round(iters / 3), round(2 * iters / 3)
    return base * 0.5 ** ((iteration >= m1) + (iteration >= m2))


class StopOnSignal:
    """SIGTERM or SIGINT asks the run to stop after the iteration in progress: the loop
    then writes a checkpoint at that iteration and returns, so `kill` (or Ctrl-C) loses no
    work and --resume continues exactly. A second signal stops at once (default action).
    Installed for the run only, and only in the main thread (elsewhere it is inert)."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self) -> None:
        self.received: Optional[int] = None
        self._old: dict = {}

    def _handle(self, signum, _frame) -> None:
        self.received = signum
        signal.signal(signum, self._old.get(signum, signal.SIG_DFL))

    def __enter__(self) -> "StopOnSignal":
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)

    def requested(self, dd: "Dist") -> bool:
        """Whether any process of the run got a signal (every rank agrees)."""
        if not dd.enabled:
            return self.received is not None
        return any(dd.gather(self.received is not None))


def leave_stop_signals_to_main(_worker_id: int) -> None:
    """DataLoader workers ignore SIGTERM and SIGINT: a signal sent to the whole process
    group (`timeout`, `kill -- -PGID`, Ctrl-C in a terminal) reaches them too, and a worker
    that died of it would make the loader raise before the main process could checkpoint
    (StopOnSignal). The main process still ends them when the run stops."""
    for sig in StopOnSignal.SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


# ----------------------------------------------------------------------------- distributed


class Dist:
    def __init__(self, device_arg: str):
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.local_rank = int(os.environ.get("LOCAL_RANK", "0"))
        want_cuda = device_arg == "cuda" or (device_arg == "auto" and torch.cuda.is_available())
        if want_cuda and not torch.cuda.is_available():
            raise SystemExit("error: --device cuda but CUDA is not available")
        if want_cuda:
            torch.cuda.set_device(self.local_rank)
            self.device = torch.device("cuda", self.local_rank)
        else:
            self.device = torch.device("cpu")
        self.enabled = self.world > 1
        if self.enabled:
            dist.init_process_group("nccl" if want_cuda else "gloo")

    @property
    def main(self) -> bool:
        return self.rank == 0

    def barrier(self) -> None:
        if self.enabled:
            dist.barrier()

    def gather(self, obj) -> list:
        if not self.enabled:
            return [obj]
        out = [None] * self.world
        dist.all_gather_object(out, obj)
        return out

    def broadcast(self, obj):
        if not self.enabled:
            return obj
        box = [obj]
        dist.broadcast_object_list(box, src=0)
        return box[0]

    def close(self) -> None:
        if self.enabled:
            dist.destroy_process_group()


def device_name(device: torch.device) -> str:
    """The GPU's name, or the CPU model and torch's thread count."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    name = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    name = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{name} ({torch.get_num_threads()} threads)"


def hardware(device: torch.device, world: int) -> dict:
    return {
        "device": device.type,
        "name": device_name(device),
        "processes": world,
        "torch": torch.__version__,
        "cuda": torch.version.cuda if device.type == "cuda" else None,
        "host": platform.system(),
    }


def git_commit() -> Optional[str]:
    try:
        here = os.path.dirname(os.path.abspath(__file__))
        out = subprocess.run(["git", "-C", here, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
        return out.stdout.strip() or None
    except Exception:
        return None


# ----------------------------------------------------------------------------- RNG state


def rng_state() -> dict:
    np_state = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": [np_state[0], torch.from_numpy(np_state[1].astype(np.int64)), int(np_state[2]), int(np_state[3]), float(np_state[4])],
        "python": random.getstate(),
    }


def set_rng_state(s: dict) -> None:
    torch.set_rng_state(s["torch"])
    if s.get("cuda") and torch.cuda.is_available() and len(s["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(s["cuda"])
    n = s["numpy"]
    np.random.set_state((n[0], n[1].numpy().astype(np.uint32), n[2], n[3], n[4]))
    py = s["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))


# ----------------------------------------------------------------------------- checkpoints


def save_checkpoint(path: str, payload: dict) -> None:
    tmp = path + ".tmp"
    torch.save(payload, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str, config: dict) -> dict:
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:
        raise CheckpointError(f"{path}: not a readable checkpoint ({err})") from None
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a {CHECKPOINT_FORMAT} file")
    if ck.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: checkpoint version {ck.get('version')!r}, this trainer reads {CHECKPOINT_VERSION}")
    diff = config_diff(normalised_config(ck.get("config", {})), config)
    if diff:
        raise CheckpointError(f"{path}: checkpoint is from another config; differing keys: " + "; ".join(diff))
    return ck


def normalised_config(saved: dict) -> dict:
    """A checkpoint's run config as this code writes it: SSR model options added since the
    checkpoint was written (model.LATE_OPTIONS) take the value their absence means, and so do
    loss terms (losses.OPTIONAL_TERMS, weight 0), so a run begun before them resumes; the
    reference-noise threshold, which checkpoints held until the fiftieth session, is dropped
    (it chooses data, as --data does, and the provenance records it)."""
    saved = {k: v for k, v in saved.items() if k != "min_reference_psnr"}
    lam = saved.get("lambdas")
    if isinstance(lam, dict):
        saved = {**saved, "lambdas": {**{t: 0.0 for t in losses.OPTIONAL_TERMS if t not in lam}, **lam}}
    mc = saved.get("model_config")
    if saved.get("model") != "ssr" or not isinstance(mc, dict):
        return saved
    try:
        return {**saved, "model_config": SSRConfig.from_dict(mc).to_dict()}
    except ValueError:
        return saved  # config_diff then names what differs


# ----------------------------------------------------------------------------- training


class SequenceRunner(nn.Module):
    """Wraps a model so that one forward runs a whole window (one DDP forward per step)."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, frames: List[Dict[str, torch.Tensor]]):
        return self.model.run_sequence(frames)


def compute_loss(model: nn.Module, results, frames, weights, lambdas=None) -> Tuple[torch.Tensor, Dict[str, torch.Tensor]]:
    refs = [f["reference"] for f in frames]
    if isinstance(model, SSRModel):
        return losses.sequence_loss(results, refs, frames, frame_weights=weights, lambdas=lambdas)
    preds = [r["output"] for r in results]
    return losses.total_loss(preds, refs, loss_aux(results, frames), frame_weights=weights, lambdas=lambdas)


def fmt_time(s: float) -> str:
    s = int(max(0, s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{sec:02d}s"


def train(argv=None) -> dict:
    """Runs training; returns a summary dict (for tests). See the module doc."""
    args = parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    config = run_config(args)
    dd = Dist(args.device)
    try:
        return _train(args, config, dd)
    finally:
        dd.close()


def _write_run(args, config: dict) -> None:
    """RUN_DIR/run.json: the run's config and arguments."""
    with open(os.path.join(args.out, "run.json"), "w") as f:
        json.dump({"config": config, "args": vars(args)}, f, indent=2, sort_keys=True)


def _log(run_dir: str, record: dict) -> None:
    with open(os.path.join(run_dir, "log.jsonl"), "a") as f:
        f.write(json.dumps(record, sort_keys=True) + "\n")


def _train(args, config: dict, dd: Dist) -> dict:
    device = dd.device
    if args.batch % dd.world:
        raise SystemExit(f"error: --batch {args.batch} is not divisible by WORLD_SIZE {dd.world}")
    per_rank = args.batch // dd.world
    os.makedirs(args.out, exist_ok=True)
    ckpt_path = os.path.join(args.out, CHECKPOINT_FILE)
    tag = f"[{args.model}]"

    def say(msg: str) -> None:
        if dd.main:
            print(f"{tag} {msg}", flush=True)

    # data
    background = ("background", "coverage")
    # buffers the model itself reads (config albedo = "footprint": the footprint albedo)
    model_extra = extra_buffers(SSRConfig.from_dict(config["model_config"])) if args.model == "ssr" else ()
    train_ds = SequenceDataset(
        args.data, "train", window=args.window, crop=args.crop, flips=not args.no_flips, scenes=args.scenes,
        cache=args.cache, cache_mb=args.cache_mb, cache_dir=args.cache_dir, thin=args.thin,
        thin_keep_min=args.thin_keep_min, color_permute=args.color_permute, extra=tuple(dict.fromkeys((background if args.background == "loss" else ()) + model_extra)),
        min_reference_psnr=args.min_reference_psnr,
    )
    if train_ds.noisy:
        say(
            f"left out {len(train_ds.noisy)} training sequence(s) with references below {args.min_reference_psnr} dB "
            f"between halves: {', '.join(s.name for s in train_ds.noisy)}"
        )
    if tuple(train_ds.crop_hw) != (args.crop, args.crop):
        say(f"note: frames smaller than --crop {args.crop}: crops are {train_ds.crop_hw[1]}x{train_ds.crop_hw[0]}")
    val_ds = None
    try:
        val_ds = SequenceDataset(
            args.data, "val", window=1, crop=None, flips=False, scenes=args.scenes, cache="none",
            extra=background if args.background != "none" else (),
        )
    except DatasetError as err:
        say(f"note: no validation ({err})")

    # model, optimizer
    torch.manual_seed(args.seed)
    model = build_model(args.model, config["model_config"]).to(device)
    init_meta, init_iterations = None, 0
    if args.init is not None:
        init_meta = load_init(model, args.init, args.model)
        prov = _json_or_str(init_meta.get("provenance"))
        if isinstance(prov, dict):
            init_iterations = int(prov.get("campaign_iterations", prov.get("iterations", 0)) or 0)
        say(f"initialised from {args.init} ({init_iterations} iterations of training before this run)")
    multiple = getattr(model, "pad_multiple", 4)
    if any(c % multiple for c in train_ds.crop_hw):
        raise SystemExit(
            f"error: crops of {train_ds.crop_hw[1]}x{train_ds.crop_hw[0]} are not a multiple of {multiple}, which the "
            f"model's {len(model.cfg.enc)} U-Net levels need: choose --crop a multiple of {multiple}"
        )
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    start, wall, history = args.init_at, 0.0, []
    fresh = True
    # where a resumed run continues from: its own checkpoint, else a restore point (--resume-from)
    own = (args.resume or args.resume_from is not None) and os.path.isfile(ckpt_path)
    source = ckpt_path if own else args.resume_from
    if source is not None:
        fresh = False
        ck = load_checkpoint(source, config)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        start, wall, history = int(ck["iteration"]), float(ck.get("wall_time_s", 0.0)), list(ck.get("val_history", []))
        rngs = ck.get("rng", [])
        if len(rngs) == dd.world:
            set_rng_state(rngs[dd.rank])
        else:
            say(f"note: checkpoint has RNG states of {len(rngs)} process(es), now {dd.world}: reseeding")
            torch.manual_seed(args.seed + 1_000_003 * start + dd.rank)
        say(f"resumed from {source} at iteration {start}/{args.iters}")
        if dd.main and not own:  # a restore point in a new run folder: say so where the run's files are
            _write_run(args, config)
            _log(args.out, {"event": "restore", "checkpoint": os.path.abspath(source), "iteration": start})
    elif args.resume:
        say(f"note: --resume but no {ckpt_path}: starting from scratch")
    elif os.path.exists(ckpt_path):
        raise SystemExit(f"error: {ckpt_path} exists: pass --resume to continue it, or choose another --out")
    if dd.main and fresh:
        _write_run(args, config)
        if args.init is not None:
            # Where this run's iteration 0 sits in a campaign of runs continuing each other.
            _log(args.out, {"event": "init", "weights": args.init, "campaign_iterations": init_iterations})
        if args.init_at:
            say(f"beginning at iteration {start}/{args.iters} of the schedule (--init-at)")

    runner: nn.Module = SequenceRunner(model)
    if dd.enabled:
        runner = nn.parallel.DistributedDataParallel(runner, device_ids=[device.index] if device.type == "cuda" else None)
    n_params = sum(p.numel() for p in model.parameters())
    say(
        f"{n_params} parameters; {len(train_ds.sequences)} train sequences ({', '.join(train_ds.scenes)}), "
        f"{len(train_ds)} windows of {args.window}; crop {train_ds.crop_hw[1]}x{train_ds.crop_hw[0]}; "
        f"batch {args.batch} ({dd.world} x {per_rank}); device {device} ({hardware(device, dd.world)['name']})"
    )

    stop = min(args.iters, args.stop_at) if args.stop_at is not None else args.iters
    sampler = WindowSampler(train_ds, per_rank, start, stop, seed=args.seed, rank=dd.rank)
    loader = torch.utils.data.DataLoader(
        train_ds, batch_sampler=sampler, collate_fn=collate, num_workers=args.workers,
        pin_memory=device.type == "cuda", persistent_workers=False, worker_init_fn=leave_stop_signals_to_main,
    )
    weights = args.frame_weights

    def checkpoint(it: int, wall_now: float, path: str = ckpt_path) -> None:
        rngs = dd.gather(rng_state())
        if dd.main:
            save_checkpoint(
                path,
                {
                    "format": CHECKPOINT_FORMAT,
                    "version": CHECKPOINT_VERSION,
                    "iteration": it,
                    "config": config,
                    "model": model.state_dict(),
                    "optimizer": opt.state_dict(),
                    "rng": rngs,
                    "wall_time_s": wall_now,
                    "val_history": history,
                    "saved": datetime.datetime.now(datetime.timezone.utc).isoformat(),
                },
            )
        dd.barrier()

    def run_val(it: int) -> Optional[dict]:
        m = None
        if val_ds is not None and dd.main:
            m = validate(model, val_ds, device, args.val_frames, args.val_size)
            history.append({"iteration": it, **{k: v for k, v in m.items() if k != "scenes"}})
            say(
                f"val it {it}: PSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.4f}  RMSE {m['rmse']:.4g}  relMSE {m['relmse']:.4g}"
                f"  ({m['sequences']} seq, {m['frames']} frames)"
            )
            _log(args.out, {"event": "val", "iteration": it, **m})
        dd.barrier()
        return m

    model.train()
    t0 = time.time()
    t_log, it_log = t0, start
    acc: Dict[str, float] = {}
    n_acc, skipped = 0, 0
    it = start
    with StopOnSignal() as stopper:
        batches = iter(loader)
        while True:
            try:
                batch = next(batches)
            except StopIteration:
                break
            except RuntimeError:
                # A signal sent to the whole process group also ends the loader's workers.
                if stopper.received is None:
                    raise
                break
            lr = lr_at(args.lr, it, args.iters)
            for g in opt.param_groups:
                g["lr"] = lr
            frames = [{k: v.to(device, non_blocking=True) for k, v in f.items()} for f in batch]
            frames = [fold_emission(f, getattr(model, "cfg", None)) for f in frames]
            results = runner(frames)
            if args.mean_correction == "loss" or args.background == "loss":
                # one window: the ring starts empty, as after a reset; the tiles of the exported
                # config's correction (32-pixel ones when it has none)
                cfg = getattr(model, "cfg", None)
                mc = (mean_correction_of(cfg) or MeanCorrection(escaped=leaves_escaped(cfg))) if args.mean_correction == "loss" else None
                results = [{**r, "output": output_pass(r["output"], f, mc)} for r, f in zip(results, frames)]
            loss, parts = compute_loss(model, results, frames, weights, args.lambdas)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), args.clip if args.clip > 0 else float("inf"))
            if torch.isfinite(gnorm):  # identical on every rank (gradients are already averaged)
                opt.step()
            else:
                skipped += 1
                say(f"warning: non-finite gradient at iteration {it}: step skipped ({skipped} so far)")
                if skipped >= 100:
                    raise SystemExit("error: 100 non-finite gradients: giving up (lower --lr or check the data)")
            it += 1
            acc["loss"] = acc.get("loss", 0.0) + float(loss.detach())
            for k, v in parts.items():
                acc[k] = acc.get(k, 0.0) + float(v.detach())
            n_acc += 1
            if dd.main and (it % args.log_every == 0 or it == stop):
                now = time.time()
                rate = (it - it_log) / max(now - t_log, 1e-9)
                avg = {k: v / n_acc for k, v in acc.items()}
                eta = (stop - it) / max(rate, 1e-9)
                say(
                    f"it {it}/{args.iters} ({100.0 * it / args.iters:.1f}%) loss {avg['loss']:.4f} "
                    "[" + " ".join(f"{k[2:]} {v:.4f}" for k, v in avg.items() if k.startswith("l_")) + "] "
                    f"lr {lr:.2e} {rate:.2f} it/s eta {fmt_time(eta)}"
                )
                _log(args.out, {"event": "train", "iteration": it, "lr": lr, "it_per_s": rate, **avg})
                t_log, it_log, acc, n_acc = now, it, {}, 0
            if args.val_every and it % args.val_every == 0 and it < args.iters:
                run_val(it)
            if it % args.ckpt_every == 0 and it < stop:
                checkpoint(it, wall + time.time() - t0)
            if args.snapshot_every and it % args.snapshot_every == 0:
                snap = os.path.join(args.out, "snapshots", f"it_{it:07d}")
                if dd.main:
                    os.makedirs(os.path.dirname(snap), exist_ok=True)
                    export_model(model, snap + ".tmp", {"model": args.model, "iterations": it, "snapshot_of": args.out}, {})
                    os.replace(snap + ".tmp", snap + ".safetensors")
                # the restore point (every rank: the RNG states are gathered)
                checkpoint(it, wall + time.time() - t0, snap + ".pt")
            if stopper.requested(dd):
                break
    wall += time.time() - t0

    if it < args.iters:  # --stop-at, or a signal
        checkpoint(it, wall)
        why = "--stop-at" if stopper.received is None else signal.Signals(stopper.received).name
        say(f"stopped at iteration {it}/{args.iters} ({why}); checkpoint written, continue with --resume")
        return {"iteration": it, "checkpoint": ckpt_path, "weights": None, "metrics": None}

    t1 = time.time()
    final = run_val(it)
    wall += time.time() - t1
    checkpoint(it, wall)
    weights_path = os.path.join(args.out, WEIGHTS_FILE)
    if dd.main:
        provenance = {
            "model": args.model,
            "trainer": "training/ssr/train.py",
            "commit": git_commit(),
            "dataset": os.path.basename(os.path.normpath(os.path.abspath(args.data))),
            "scenes": train_ds.scenes,
            "sequences": {
                "train": [s.id for s in train_ds.sequences],
                "val": [s.id for s in val_ds.sequences] if val_ds is not None else [],
            },
            "train_frames": sum(s.frames for s in train_ds.sequences),
            **({"min_reference_psnr": args.min_reference_psnr} if args.min_reference_psnr is not None else {}),
            "resolution": sorted({f"{s.width}x{s.height}" for s in train_ds.sequences}),
            "iterations": it,
            "batch": args.batch,
            "crop": list(train_ds.crop_hw),
            "window": args.window,
            "augmentation": {
                "flips": not args.no_flips, "thin": args.thin, "thin_keep_min": args.thin_keep_min,
                "color_permute": args.color_permute,
            },
            "background": args.background,
            "mean_correction": args.mean_correction,
            "lr": args.lr,
            "lr_schedule": "Adam; halved at 1/3 and 2/3 of the iterations",
            "losses": {"frame_weights": list(weights), "lambdas": dict(args.lambdas)},
            "seed": args.seed,
            "campaign_iterations": init_iterations + it - args.init_at,
            **({"init_at": args.init_at} if args.init_at else {}),
            "init": None if args.init is None else {
                **config["init"],
                "provenance": _json_or_str(init_meta.get("provenance")) if init_meta else None,
            },
            "hardware": hardware(device, dd.world),
            "wall_time_s": round(wall, 1),
            "skipped_steps": skipped,
        }
        metrics = {}
        if final is not None:
            metrics = {
                "split": "val",
                "tonemap": "uncharted2 exposure 2 white 11.2, gamma 2.2, 8-bit",
                "frames_per_sequence": args.val_frames,
                **{k: v for k, v in final.items()},
            }
        size = export_model(model, weights_path, provenance, metrics)
        say(f"wrote {weights_path} ({size} bytes) after {it} iterations, {fmt_time(wall)} wall time")
        _log(args.out, {"event": "export", "iteration": it, "weights": weights_path, "wall_time_s": wall})
    dd.barrier()
    return {"iteration": it, "checkpoint": ckpt_path, "weights": weights_path, "metrics": final}


def _json_or_str(s):
    """Metadata as parsed by the weights loaders, or JSON text (parsed here)."""
    if not isinstance(s, str):
        return s
    try:
        return json.loads(s)
    except json.JSONDecodeError:
        return s


def main(argv=None) -> int:
    try:
        train(argv)
    except (DatasetError, CheckpointError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
