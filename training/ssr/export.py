"""Weights files: safetensors with PyTorch names, OIHW conv layout and SSR metadata.

`__metadata__` (all values are strings, as safetensors requires):
    format      "subpixel-ssr"
    version     "2"                       (file format version = the config's `version`)
    config      JSON of SSRConfig         ({"enc":[16,32,28],"exposure":"channel",...})
    provenance  JSON: {"scenes": [...], "iterations": N, ...} for trained weights, or the
                JSON string "random-init: for tests only, not a denoiser"
    metrics     JSON object of validation metrics ({} when there are none)
    init        (random files only) JSON {"scheme": ..., "seed": N}

Version 2 (exposure normalisation, remodulation with the current albedo, geometric history
test: model.py) changed what the weights mean. Version-1 files still load: their config has
no option keys and runs the version-1 pipeline (model.LEGACY_OPTIONS), as they were trained.

Files are written by our own deterministic writer (sorted header keys, tensors in name
order, contiguous data) so the same model gives the same bytes; the `safetensors` package
is used to read them.

CLI:  python -m ssr.export --random --seed 0 --out FILE
      python -m ssr.export --from FILE --option ceiling=max [--val-data ROOT] --out FILE
            (a trained file with config options changed that do not touch its tensors,
            provenance noting the change, val metrics recomputed under the new config)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import sys
from typing import Dict, List, Optional, Tuple

import torch
from torch import nn

from .model import OPTION_VALUES, SSRConfig, SSRModel, flops_per_pixel

FORMAT = "subpixel-ssr"
FORMAT_VERSION = "2"
"""Version written for default configs; a file's version is its config's (1 or 2)."""
READ_VERSIONS = ("1", "2")
RANDOM_PROVENANCE = "random-init: for tests only, not a denoiser"
RANDOM_INIT_SCHEME = "he-normal(relu) weights, U(-0.1,0.1) biases; RGB convs: N(0,0.5/fan_in), U(0.5,1)"


class WeightsError(ValueError):
    """A weights file that does not match the expected format, names or shapes."""


# ----------------------------------------------------------------------------- writing


def safetensors_bytes(tensors: Dict[str, torch.Tensor], metadata: Dict[str, str]) -> bytes:
    """Serialises float32 tensors + string metadata to safetensors, deterministically."""
    header: Dict[str, object] = {}
    if metadata:
        for k, v in metadata.items():
            if not isinstance(v, str):
                raise TypeError(f"metadata `{k}` must be a string, got {type(v).__name__}")
        header["__metadata__"] = dict(sorted(metadata.items()))
    blobs = []
    offset = 0
    for name in sorted(tensors):
        t = tensors[name]
        if t.dtype != torch.float32:
            raise TypeError(f"tensor `{name}`: only float32 is written, got {t.dtype}")
        data = t.detach().cpu().contiguous().numpy().astype("<f4", copy=False).tobytes()
        header[name] = {"dtype": "F32", "shape": list(t.shape), "data_offsets": [offset, offset + len(data)]}
        blobs.append(data)
        offset += len(data)
    h = json.dumps(header, sort_keys=True, separators=(",", ":")).encode("utf-8")
    h += b" " * (-len(h) % 8)  # align the data section to 8 bytes (as the reference writer does)
    return struct.pack("<Q", len(h)) + h + b"".join(blobs)


def write_safetensors(path: str, tensors: Dict[str, torch.Tensor], metadata: Dict[str, str]) -> int:
    """Writes the file atomically (temp file + rename); returns its size in bytes."""
    return write_bytes(path, safetensors_bytes(tensors, metadata))


def write_bytes(path: str, data: bytes) -> int:
    """Writes `data` atomically (temp file + rename); returns its size."""
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)
    return len(data)


def weights_metadata(
    cfg: SSRConfig, provenance: object, metrics: Optional[dict] = None, extra: Optional[Dict[str, str]] = None
) -> Dict[str, str]:
    meta = {
        "format": FORMAT,
        "version": str(cfg.version),
        "config": cfg.to_json(),
        "provenance": json.dumps(provenance, sort_keys=True, separators=(",", ":")),
        "metrics": json.dumps(metrics if metrics is not None else {}, sort_keys=True, separators=(",", ":")),
    }
    if extra:
        meta.update(extra)
    return meta


def export_weights(
    model: SSRModel,
    path: str,
    provenance: object,
    metrics: Optional[dict] = None,
    extra_metadata: Optional[Dict[str, str]] = None,
) -> int:
    """Writes `model` to `path` (PyTorch parameter names, conv weights OIHW [Cout, Cin, 3, 3]).

    provenance: for trained weights a dict such as {"scenes": [...], "iterations": N};
    for random weights RANDOM_PROVENANCE. metrics: dict of validation metrics.
    """
    tensors = {k: v for k, v in model.state_dict().items()}
    meta = weights_metadata(model.cfg, provenance, metrics, extra_metadata)
    return write_safetensors(path, tensors, meta)


# ----------------------------------------------------------------------------- random init


def random_init_(model: nn.Module, seed: int) -> nn.Module:
    """Deterministic random initialisation giving non-trivial activations at every layer.

    Hidden convs: He-normal weights (std sqrt(2 / fan_in)), biases U(-0.1, 0.1). The convs
    producing RGB (3 outputs): std sqrt(0.5 / fan_in), biases U(0.5, 1), so that the
    log-space output o is mostly, but not always, positive (remodulation clamps negatives).
    PyTorch's default init shrinks activations layer by layer (output std ~0.01), which
    makes a weak parity test.
    """
    g = torch.Generator().manual_seed(int(seed))
    with torch.no_grad():
        for name, mod in model.named_modules():
            if not isinstance(mod, nn.Conv2d):
                continue
            fan_in = mod.in_channels * mod.kernel_size[0] * mod.kernel_size[1]
            w = torch.randn(mod.weight.shape, generator=g, dtype=torch.float32)
            b = torch.rand(mod.bias.shape, generator=g, dtype=torch.float32)
            if mod.out_channels == 3 and name.startswith("unet.dec"):
                mod.weight.copy_(w * math.sqrt(0.5 / fan_in))
                mod.bias.copy_(b * 0.5 + 0.5)
            else:
                mod.weight.copy_(w * math.sqrt(2.0 / fan_in))
                mod.bias.copy_(b * 0.2 - 0.1)
    return model


def random_model(seed: int = 0, cfg: Optional[SSRConfig] = None) -> SSRModel:
    return random_init_(SSRModel(cfg), seed)


def export_random(path: str, seed: int = 0, cfg: Optional[SSRConfig] = None) -> Tuple[SSRModel, int]:
    model = random_model(seed, cfg)
    extra = {"init": json.dumps({"scheme": RANDOM_INIT_SCHEME, "seed": int(seed)}, sort_keys=True, separators=(",", ":"))}
    size = export_weights(model, path, RANDOM_PROVENANCE, {}, extra)
    return model, size


# ----------------------------------------------------------------------------- loading


def _parse_json(meta: Dict[str, str], key: str, path: str) -> object:
    if key not in meta:
        raise WeightsError(f"{path}: metadata has no `{key}`")
    try:
        return json.loads(meta[key])
    except json.JSONDecodeError as err:
        raise WeightsError(f"{path}: metadata `{key}` is not valid JSON ({err})") from None


def read_state(f, model: torch.nn.Module, path) -> Dict[str, torch.Tensor]:
    """The tensors of the open safetensors file `f` as a state dict for `model`: every
    tensor the model has, float32, of its shape, and no other; else a `WeightsError` naming
    `path` and every mismatch."""
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    present = set(f.keys())
    errors = [f"missing tensor `{n}` (expected shape {list(expected[n])})" for n in sorted(set(expected) - present)]
    errors += [f"unexpected tensor `{n}`" for n in sorted(present - set(expected))]
    state = {}
    for name in sorted(present & set(expected)):
        t = f.get_tensor(name)
        if t.dtype != torch.float32:
            errors.append(f"tensor `{name}`: dtype {t.dtype}, expected float32")
        if tuple(t.shape) != expected[name]:
            errors.append(f"tensor `{name}`: shape {list(t.shape)}, expected {list(expected[name])}")
        state[name] = t
    if errors:
        raise WeightsError(f"{path}: " + "; ".join(errors))
    return state


def load_weights(path: str, device: str = "cpu") -> Tuple[SSRModel, dict]:
    """Loads a weights file, checking format, version and every tensor name and shape.

    Returns (model in eval mode, meta) with meta = {"format", "version", "config" (SSRConfig),
    "provenance", "metrics", "raw" (the metadata strings)}. Raises WeightsError naming the
    offending metadata key or tensor(s).
    """
    from safetensors import safe_open

    try:
        f = safe_open(path, framework="pt", device=device)
    except FileNotFoundError:
        raise
    except Exception as err:  # the safetensors parser's own errors
        raise WeightsError(f"{path}: not a readable safetensors file ({err})") from None
    with f:
        raw = f.metadata()
        if raw is None:
            raise WeightsError(f"{path}: no __metadata__ (expected format={FORMAT!r})")
        if raw.get("format") != FORMAT:
            raise WeightsError(f"{path}: metadata `format` is {raw.get('format')!r}, expected {FORMAT!r}")
        if raw.get("version") not in READ_VERSIONS:
            raise WeightsError(
                f"{path}: metadata `version` is {raw.get('version')!r}, this code reads versions {list(READ_VERSIONS)}"
            )
        if "config" not in raw:
            raise WeightsError(f"{path}: metadata has no `config`")
        try:
            cfg = SSRConfig.from_json(raw["config"])
        except ValueError as err:
            raise WeightsError(f"{path}: metadata `config`: {err}") from None
        if str(cfg.version) != raw["version"]:
            raise WeightsError(f"{path}: metadata `version` is {raw['version']!r} but its config is version {cfg.version}")
        provenance = _parse_json(raw, "provenance", path)
        metrics = _parse_json(raw, "metrics", path)

        model = SSRModel(cfg)
        state = read_state(f, model, path)
    model.load_state_dict(state, strict=True)
    model.eval()
    meta = {
        "format": raw["format"],
        "version": raw["version"],
        "config": cfg,
        "provenance": provenance,
        "metrics": metrics,
        "raw": dict(raw),
    }
    return model, meta


# ----------------------------------------------------------------------------- CLI


def set_options(src: str, options: List[str], out: str, val_data: Optional[str] = None, frames: int = 8) -> dict:
    """Rewrites weights file `src` as `out` with config `options` (KEY=VALUE) changed: the
    tensors are kept; provenance gains an `options_set` entry (what changed, from what, when);
    with `val_data` the val metrics are recomputed under the new config (validation.validate,
    with the background composited when the val frames have it, as the trainer validates),
    otherwise they are dropped: they described the old config (validation scores the
    engine's output, its output pass included, so even an option of the output pass changes
    them). Returns the new metrics."""
    import datetime

    model, meta = load_weights(src)
    if not isinstance(meta["provenance"], dict):
        raise WeightsError(f"{src}: only trained weights (provenance a JSON object) take --option")
    cfg = meta["config"].to_dict()
    changes = []
    for spec in options:
        key, sep, value = spec.partition("=")
        if not sep or key not in OPTION_VALUES:
            raise WeightsError(f"--option {spec!r}: expected KEY=VALUE with KEY one of {sorted(OPTION_VALUES)}")
        changes.append({"option": key, "from": cfg.get(key), "to": value})
        cfg[key] = value
    try:
        new_cfg = SSRConfig.from_dict(cfg)
    except ValueError as err:
        raise WeightsError(f"--option: {err}") from None
    changed = SSRModel(new_cfg)
    changed.load_state_dict(model.state_dict(), strict=True)
    changed.eval()
    metrics: dict = {}
    if val_data:
        from .data import SequenceDataset, exr_size
        from .validation import validate

        ds = SequenceDataset(val_data, "val", window=1, crop=None, flips=False)
        if ds.sequences and "coverage.Y" in exr_size(ds.sequences[0].frame_path(0))[2]:
            # composited with the background as the engine (and the trainer's validation) does
            ds = SequenceDataset(val_data, "val", window=1, crop=None, flips=False, extra=("background", "coverage"))
        with torch.no_grad():
            metrics = validate(changed, ds, torch.device("cpu"), frames)
    provenance = dict(meta["provenance"])
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d")
    provenance["options_set"] = list(provenance.get("options_set", [])) + [{**c, "date": when} for c in changes]
    export_weights(changed, out, provenance, metrics)
    return metrics


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.export", description="Write an SSR weights file.")
    ap.add_argument("--random", action="store_true", help="random-initialised model (for tests only)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random initialisation")
    ap.add_argument("--config", default=None, help="config JSON (default: the default config)")
    ap.add_argument("--from", dest="src", default=None, help="a trained weights file to rewrite with --option")
    ap.add_argument("--option", action="append", default=[], help="KEY=VALUE config option (with --from), e.g. ceiling=max")
    ap.add_argument("--val-data", default=None, help="dataset root: recompute the val metrics (with --from)")
    ap.add_argument("--out", required=True, help="output .safetensors path")
    args = ap.parse_args(argv)
    if args.src:
        if args.random or not args.option:
            ap.error("--from takes one or more --option and no --random")
        metrics = set_options(args.src, args.option, args.out, args.val_data)
        print(f"wrote {args.out}: options {args.option}; val {json.dumps({k: metrics[k] for k in ('psnr', 'ssim', 'rmse') if k in metrics})}")
        return 0
    if not args.random:
        ap.error("--random or --from: trained weights are exported by the trainer (export_weights)")
    cfg = SSRConfig.from_json(args.config) if args.config else SSRConfig()
    model, size = export_random(args.out, args.seed, cfg)
    n_params = sum(p.numel() for p in model.parameters())
    total, _ = flops_per_pixel(cfg)
    print(f"wrote {args.out}: {size} bytes, {n_params} parameters, {total:.0f} FLOP/pixel, config {cfg.to_json()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
