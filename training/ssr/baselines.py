"""Baselines of the paper's comparison (DESIGN section 6, issue 5), on the same 1/4-spp data.

Learned (trainable with `python -m ssr.train --model rae|nsrr`, same losses as SSR):

  RAEModel   Chaitanya et al. 2017, "Interactive reconstruction of Monte Carlo image
             sequences using a recurrent denoising autoencoder", small: a U-Net on
             demodulated colour + features whose every encoder level (and the bottleneck)
             ends with a recurrent conv block h_t = conv(conv([x, h_{t-1}])) (no warping of
             the hidden state, as in the paper). Levels at 1/1, 1/2 and a bottleneck at 1/4
             (the paper has 5 levels; 2 pools keep crops at multiples of 4), LeakyReLU(0.1),
             nearest upsampling + skip concatenation. Input (9 ch): e = log(1 + c/(a+eps)) (3),
             the 1/4-spp mask (1, our addition for sparse input), normal (3), depth (1),
             roughness (1). Output: o in log-demodulated space, remodulated with the current
             albedo.

  NSRRModel  Xiao et al. 2020, "Neural supersampling for real-time rendering", adapted to
             1/4 spp: the traced pixels of a frame *are* a zero-upsampled image (one sample
             per 2x2 tile, zeros elsewhere), so NSRR's zero-upsampling step is the input
             itself. Per frame I_t = [e(3), mask, depth, albedo(3), normal(3)] (11 ch);
             feature extraction (shared) conv 32 - conv 32 - conv 8, F_t = [I_t, features]
             (19 ch). History: the F of the last `history` frames, each warped into the
             current frame by the current motion every frame (recursive backward warping,
             invalid samples 0; at a sequence start the history is F_t repeated). Feature
             reweighting: conv 32 - conv 32 - conv P over the RGB-D ([e, depth]) of the
             current and warped previous frames, tanh scaled to [0, 10], multiplies each
             previous F. Reconstruction: a 2-pool U-Net on [F_t, weighted F_{t-1..t-P}]
             producing o (log-demodulated), remodulated with the current albedo.

Non-learned references (evaluate.py only):

  InputBaseline         the raw 1/4-spp input: `color` as it is (0 at untraced pixels).
  HoldBaseline          "hold-filled": the 1/4-spp frame whose untraced pixels hold that
                        pixel's last traced sample (no reprojection: the value stays where it
                        was traced, whatever the camera did since). Traced pixels (mask 1)
                        show this frame's sample, a black sample included. A pixel not traced
                        yet in the sequence (frames 0-2) takes this frame's sample of its 2x2
                        tile (the mean of the tile's traced pixels: exactly one in a whole
                        tile); in a partial tile at the right/bottom edge of an odd-sized frame
                        with no traced pixel this frame, the mean of this frame's samples in
                        its 3x3 neighbourhood; with none there either, 0. From frame 3 on every
                        pixel of a whole tile has been traced. Works at any size (no padding).
                        This is also the colour OIDN (a) denoises (oidn.py).
  AccumulationBaseline  reprojected temporal accumulation, an exponential moving average
                        over the traced samples with alpha = 0.1, on demodulated radiance
                        d = color / (albedo + 0.00316), remodulated with the current albedo:
                            valid = warp valid and |depth - W(depth_prev)| <= 0.1 depth
                                    and (n . W(n_prev) >= 0.9, or both normals ~0 (sky))
                            C_t = valid (1 - alpha) W(C_{t-1}) + alpha mask d
                            S_t = valid (1 - alpha) W(S_{t-1}) + alpha mask
                            out = (C_t / S_t) (albedo + eps)      where S_t > 1e-6
                        i.e. each traced sample enters with weight alpha and every older one
                        decays by (1 - alpha) per frame; normalising by S_t makes the first
                        sample after a disocclusion count fully. Where no sample survives
                        (S_t ~ 0: a sequence start or a disocclusion not yet retraced) the
                        estimate is the 3x3 box average of this frame's samples (every 3x3
                        window holds at least two traced pixels of the 1/4-spp pattern).

Every model has `forward(frame, state) -> {"output", "state", ...}` and `run_sequence` like
SSRModel; the learned ones also return `o` and `albedo_mod` (for the albedo loss).

Weights files: safetensors like SSR's, metadata `format` = "subpixel-baseline-rae" or
"subpixel-baseline-nsrr", `version` = "1", `config` (JSON of the config below),
`provenance`, `metrics`. `load_model(path)` reads any of them (and SSR files).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import torch
import torch.nn.functional as F
from torch import nn

from .export import FORMAT as SSR_FORMAT
from .export import WeightsError, load_weights, read_state, write_safetensors
from .model import ALBEDO_EPS, OPTION_VALUES, SSRConfig, SSRModel, _check_frame, _clean, demodulate, remodulate, warp

BASELINE_VERSION = "1"


# ----------------------------------------------------------------------------- configs


@dataclass(frozen=True)
class RAEConfig:
    enc: Tuple[int, int] = (32, 48)
    bottleneck: int = 64
    version: int = 1

    def to_dict(self) -> dict:
        return {"bottleneck": self.bottleneck, "enc": list(self.enc), "version": self.version}


@dataclass(frozen=True)
class NSRRConfig:
    history: int = 2
    feat_hidden: int = 32
    feat_out: int = 8
    reweight_hidden: int = 32
    enc: Tuple[int, int] = (32, 64)
    bottleneck: int = 64
    version: int = 1

    def to_dict(self) -> dict:
        d = asdict(self)
        d["enc"] = list(self.enc)
        return dict(sorted(d.items()))


def _config_from_dict(cls, d: dict, path: str = "config"):
    if not isinstance(d, dict):
        raise WeightsError(f"{path}: config must be a JSON object")
    known = set(cls.__dataclass_fields__)
    unknown = sorted(set(d) - known)
    missing = sorted(known - set(d))
    if unknown or missing:
        raise WeightsError(f"{path}: config keys: unknown {unknown}, missing {missing}")
    kw = dict(d)
    if "enc" in kw:
        kw["enc"] = tuple(int(c) for c in kw["enc"])
    return cls(**kw)


# ----------------------------------------------------------------------------- helpers


def _conv(cin: int, cout: int) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, padding=1)


def _act() -> nn.Module:
    return nn.LeakyReLU(0.1)


def _log_demod(frame: Dict[str, torch.Tensor]) -> torch.Tensor:
    return demodulate(frame["color"], frame["albedo"])


class _Recurrent(nn.Module):
    """RAE recurrent block: h_t = act(conv(act(conv([x, h_{t-1}]))))."""

    def __init__(self, c: int):
        super().__init__()
        self.body = nn.Sequential(_conv(2 * c, c), _act(), _conv(c, c), _act())

    def forward(self, x: torch.Tensor, h: Optional[torch.Tensor]) -> torch.Tensor:
        if h is None:
            h = torch.zeros_like(x)
        return self.body(torch.cat([x, h], dim=1))


class _SequenceMixin:
    def run_sequence(self, frames, state=None, detach_state: bool = False) -> List[Dict[str, object]]:
        results = []
        for frame in frames:
            r = self.forward(frame, state)
            state = r["state"]
            if detach_state and state is not None:
                state = _detach(state)
            results.append(r)
        return results


def _detach(x):
    if isinstance(x, torch.Tensor):
        return x.detach()
    if isinstance(x, (list, tuple)):
        return type(x)(_detach(v) for v in x)
    return x


# ----------------------------------------------------------------------------- RAE


class RAEModel(_SequenceMixin, nn.Module):
    FORMAT = "subpixel-baseline-rae"
    NAME = "rae"
    IN_CHANNELS = 9

    def __init__(self, cfg: Optional[RAEConfig] = None):
        super().__init__()
        self.cfg = cfg if cfg is not None else RAEConfig()
        c1, c2 = self.cfg.enc
        cb = self.cfg.bottleneck
        self.in1 = nn.Sequential(_conv(self.IN_CHANNELS, c1), _act())
        self.rec1 = _Recurrent(c1)
        self.in2 = nn.Sequential(_conv(c1, c2), _act())
        self.rec2 = _Recurrent(c2)
        self.inb = nn.Sequential(_conv(c2, cb), _act())
        self.recb = _Recurrent(cb)
        self.dec2 = nn.Sequential(_conv(cb + c2, c2), _act(), _conv(c2, c2), _act())
        self.dec1 = nn.Sequential(_conv(c2 + c1, c1), _act(), _conv(c1, c1), _act())
        self.out = _conv(c1, 3)

    def forward(self, frame: Dict[str, torch.Tensor], state=None) -> Dict[str, object]:
        _check_frame(frame)
        x = torch.cat([_log_demod(frame), frame["mask"], frame["normal"], frame["depth"], frame["roughness"]], dim=1)
        h1p, h2p, hbp = state if state is not None else (None, None, None)
        h1 = self.rec1(self.in1(x), h1p)
        h2 = self.rec2(self.in2(F.max_pool2d(h1, 2)), h2p)
        hb = self.recb(self.inb(F.max_pool2d(h2, 2)), hbp)
        d2 = self.dec2(torch.cat([F.interpolate(hb, scale_factor=2, mode="nearest"), h2], dim=1))
        d1 = self.dec1(torch.cat([F.interpolate(d2, scale_factor=2, mode="nearest"), h1], dim=1))
        o = self.out(d1)
        albedo = frame["albedo"]
        return {"output": remodulate(o, albedo), "o": o, "albedo_mod": albedo, "state": (h1, h2, hb)}


# ----------------------------------------------------------------------------- NSRR


class NSRRModel(_SequenceMixin, nn.Module):
    FORMAT = "subpixel-baseline-nsrr"
    NAME = "nsrr"
    IN_CHANNELS = 11  # e(3) mask depth albedo(3) normal(3)

    def __init__(self, cfg: Optional[NSRRConfig] = None):
        super().__init__()
        self.cfg = cfg if cfg is not None else NSRRConfig()
        c = self.cfg
        self.feat_channels = self.IN_CHANNELS + c.feat_out
        self.features = nn.Sequential(
            _conv(self.IN_CHANNELS, c.feat_hidden), nn.ReLU(), _conv(c.feat_hidden, c.feat_hidden), nn.ReLU(),
            _conv(c.feat_hidden, c.feat_out), nn.ReLU(),
        )
        self.reweight = nn.Sequential(
            _conv(4 * (c.history + 1), c.reweight_hidden), nn.ReLU(), _conv(c.reweight_hidden, c.reweight_hidden),
            nn.ReLU(), _conv(c.reweight_hidden, c.history), nn.Tanh(),
        )
        e1, e2 = c.enc
        cin = self.feat_channels * (c.history + 1)
        self.enc1 = nn.Sequential(_conv(cin, e1), nn.ReLU(), _conv(e1, e1), nn.ReLU())
        self.enc2 = nn.Sequential(_conv(e1, e2), nn.ReLU(), _conv(e2, e2), nn.ReLU())
        self.bott = nn.Sequential(_conv(e2, c.bottleneck), nn.ReLU(), _conv(c.bottleneck, c.bottleneck), nn.ReLU())
        self.dec2 = nn.Sequential(_conv(c.bottleneck + e2, e2), nn.ReLU(), _conv(e2, e2), nn.ReLU())
        self.dec1 = nn.Sequential(_conv(e2 + e1, e1), nn.ReLU(), _conv(e1, e1), nn.ReLU())
        self.out = _conv(e1, 3)

    def forward(self, frame: Dict[str, torch.Tensor], state=None) -> Dict[str, object]:
        _check_frame(frame)
        p = self.cfg.history
        e = _log_demod(frame)
        x = torch.cat([e, frame["mask"], frame["depth"], frame["albedo"], frame["normal"]], dim=1)
        f_t = torch.cat([x, self.features(x)], dim=1)
        if state is None:
            hist = [f_t] * p
        else:
            if len(state) != p:
                raise ValueError(f"nsrr: state holds {len(state)} frames, expected {p}")
            warped, _ = warp(torch.cat(list(state), dim=1), frame["motion"])
            hist = list(torch.split(warped, self.feat_channels, dim=1))

        def rgbd(f: torch.Tensor) -> torch.Tensor:  # [e(3), depth] of a feature stack
            return torch.cat([f[:, 0:3], f[:, 4:5]], dim=1)

        w = (self.reweight(torch.cat([rgbd(f_t)] + [rgbd(h) for h in hist], dim=1)) + 1.0) * 5.0
        weighted = [h * w[:, i : i + 1] for i, h in enumerate(hist)]
        z = torch.cat([f_t] + weighted, dim=1)
        s1 = self.enc1(z)
        s2 = self.enc2(F.max_pool2d(s1, 2))
        b = self.bott(F.max_pool2d(s2, 2))
        d2 = self.dec2(torch.cat([F.interpolate(b, scale_factor=2, mode="bilinear", align_corners=False), s2], dim=1))
        d1 = self.dec1(torch.cat([F.interpolate(d2, scale_factor=2, mode="bilinear", align_corners=False), s1], dim=1))
        o = self.out(d1)
        albedo = frame["albedo"]
        new_state = tuple([f_t] + hist[: p - 1])
        return {"output": remodulate(o, albedo), "o": o, "albedo_mod": albedo, "reweight": w, "state": new_state}


# ----------------------------------------------------------------------------- non-learned


class InputBaseline(_SequenceMixin, nn.Module):
    """The raw 1/4-spp input (non-finite/negative values as 0)."""

    NAME = "input"

    def forward(self, frame: Dict[str, torch.Tensor], state=None) -> Dict[str, object]:
        return {"output": _clean(frame["color"]), "state": None}


def _tile_sum(x: torch.Tensor) -> torch.Tensor:
    """Sum over each 2x2 tile (tiles from the top-left corner; a partial tile at the
    right/bottom edge sums what it has), broadcast back to every pixel of the tile."""
    h, w = x.shape[-2:]
    xp = F.pad(x, (0, w % 2, 0, h % 2))
    s = F.avg_pool2d(xp, 2, stride=2) * 4.0
    return s.repeat_interleave(2, dim=-2).repeat_interleave(2, dim=-1)[..., :h, :w]


class HoldBaseline(_SequenceMixin, nn.Module):
    """Hold-filled 1/4-spp frame: every pixel shows its last traced sample (module doc)."""

    NAME = "hold"
    pad_multiple = 1  # works at any size: evaluate.py runs it on the unpadded frame

    def forward(self, frame: Dict[str, torch.Tensor], state=None) -> Dict[str, object]:
        color, mask = frame["color"], frame["mask"]
        if color.dim() != 4 or color.shape[1] != 3 or mask.shape != (color.shape[0], 1, *color.shape[2:]):
            raise ValueError(f"hold: `color` must be [N, 3, H, W] and `mask` [N, 1, H, W], got {list(color.shape)} and {list(mask.shape)}")
        traced = (mask > 0.5).to(color.dtype)
        sample = _clean(color) * traced
        if state is None:
            held, have = torch.zeros_like(sample), torch.zeros_like(traced)
        else:
            held, have = state
        held = torch.where(traced > 0, sample, held)
        have = torch.maximum(have, traced)
        # pixels never traced: this frame's sample of their tile, else of their 3x3 neighbourhood
        tile_n = _tile_sum(traced)
        tile = _tile_sum(sample) / torch.clamp(tile_n, min=1.0)
        box_n = F.avg_pool2d(F.pad(traced, (1, 1, 1, 1)), 3, stride=1)
        box = F.avg_pool2d(F.pad(sample, (1, 1, 1, 1)), 3, stride=1) / torch.clamp(box_n, min=1e-6)
        fill = torch.where(tile_n > 0, tile, torch.where(box_n > 0, box, torch.zeros_like(box)))
        out = torch.where(have > 0, held, fill)
        return {"output": out, "have": have, "state": (held, have)}


class AccumulationBaseline(_SequenceMixin, nn.Module):
    """Reprojected EMA of the traced samples with a depth/normal validity test (module doc)."""

    NAME = "accumulation"

    def __init__(self, alpha: float = 0.1, depth_tol: float = 0.1, normal_cos: float = 0.9):
        super().__init__()
        self.alpha, self.depth_tol, self.normal_cos = alpha, depth_tol, normal_cos

    def forward(self, frame: Dict[str, torch.Tensor], state=None) -> Dict[str, object]:
        _check_frame(frame)
        albedo = torch.clamp(_clean(frame["albedo"]), min=0.0)
        d = _clean(frame["color"]) / (albedo + ALBEDO_EPS)
        mask = (frame["mask"] > 0.5).to(d.dtype)
        depth, normal = frame["depth"], frame["normal"]
        a = self.alpha
        if state is None:
            hc = torch.zeros_like(d)
            hs = torch.zeros_like(mask)
            valid = torch.zeros_like(mask)
        else:
            pc, ps, pd, pn = state
            warped, wvalid = warp(torch.cat([pc, ps, pd, pn], dim=1), frame["motion"])
            hc, hs, wd, wn = warped[:, 0:3], warped[:, 3:4], warped[:, 4:5], warped[:, 5:8]
            depth_ok = (depth - wd).abs() <= self.depth_tol * depth.abs()
            dot = (normal * wn).sum(dim=1, keepdim=True)
            sky = (normal.norm(dim=1, keepdim=True) < 0.5) & (wn.norm(dim=1, keepdim=True) < 0.5)
            normal_ok = (dot >= self.normal_cos * normal.norm(dim=1, keepdim=True) * wn.norm(dim=1, keepdim=True)) | sky
            valid = wvalid * (depth_ok & normal_ok).to(d.dtype)
        c = valid * (1.0 - a) * hc + a * mask * d
        s = valid * (1.0 - a) * hs + a * mask
        have = s > 1e-6
        est = c / torch.clamp(s, min=1e-6)
        box_c = F.avg_pool2d(F.pad(d * mask, (1, 1, 1, 1)), 3, stride=1)
        box_s = F.avg_pool2d(F.pad(mask, (1, 1, 1, 1)), 3, stride=1)
        fill = box_c / torch.clamp(box_s, min=1e-6)
        est = torch.where(have, est, fill)
        out = est * (albedo + ALBEDO_EPS)
        return {"output": out, "valid": valid, "state": (c, s, depth, normal)}


# ----------------------------------------------------------------------------- registry, I/O

LEARNED = {"ssr": SSRModel, "rae": RAEModel, "nsrr": NSRRModel}
CONFIGS = {"ssr": SSRConfig, "rae": RAEConfig, "nsrr": NSRRConfig}
NON_LEARNED = {"input": InputBaseline, "hold": HoldBaseline, "accumulation": AccumulationBaseline}


def build_model(name: str, config: Optional[dict] = None) -> nn.Module:
    """A fresh model by name (ssr|rae|nsrr), with an optional config dict (defaults otherwise)."""
    if name not in LEARNED:
        raise ValueError(f"unknown model {name!r} (one of {sorted(LEARNED)})")
    if name == "ssr":
        base = SSRConfig().to_dict()
        if (config or {}).get("version") == 1:  # the version-1 pipeline: no option keys
            base = {k: v for k, v in base.items() if k not in OPTION_VALUES}
        cfg = SSRConfig.from_dict({**base, **(config or {})})
        return SSRModel(cfg)
    cls = CONFIGS[name]
    cfg = _config_from_dict(cls, {**cls().to_dict(), **(config or {})})
    return LEARNED[name](cfg)


def model_name(model: nn.Module) -> str:
    if isinstance(model, SSRModel):
        return "ssr"
    return model.NAME


def export_model(model: nn.Module, path: str, provenance: object, metrics: Optional[dict] = None) -> int:
    """Writes any learned model: SSR as `subpixel-ssr` (export.export_weights), baselines as
    `subpixel-baseline-{rae,nsrr}` with the same metadata keys."""
    from .export import export_weights

    if isinstance(model, SSRModel):
        return export_weights(model, path, provenance, metrics)
    meta = {
        "format": model.FORMAT,
        "version": BASELINE_VERSION,
        "config": json.dumps(model.cfg.to_dict(), sort_keys=True, separators=(",", ":")),
        "provenance": json.dumps(provenance, sort_keys=True, separators=(",", ":")),
        "metrics": json.dumps(metrics if metrics is not None else {}, sort_keys=True, separators=(",", ":")),
    }
    tensors = {k: v.detach().float() for k, v in model.state_dict().items()}
    return write_safetensors(path, tensors, meta)


def load_model(path: str, device: str = "cpu") -> Tuple[nn.Module, dict]:
    """Loads an SSR or baseline weights file (dispatching on `format`); checks every tensor.

    Returns (model in eval mode, meta with format/version/config/provenance/metrics/raw).
    """
    from safetensors import safe_open

    try:
        with safe_open(path, framework="pt", device=device) as f:
            raw = f.metadata() or {}
    except FileNotFoundError:
        raise
    except Exception as err:
        raise WeightsError(f"{path}: not a readable safetensors file ({err})") from None
    fmt = raw.get("format")
    if fmt == SSR_FORMAT:
        return load_weights(path, device)
    cls = {RAEModel.FORMAT: RAEModel, NSRRModel.FORMAT: NSRRModel}.get(fmt)
    if cls is None:
        known = [SSR_FORMAT, RAEModel.FORMAT, NSRRModel.FORMAT]
        raise WeightsError(f"{path}: metadata `format` is {fmt!r}, expected one of {known}")
    if raw.get("version") != BASELINE_VERSION:
        raise WeightsError(f"{path}: metadata `version` is {raw.get('version')!r}, expected {BASELINE_VERSION!r}")
    try:
        cfg_dict = json.loads(raw["config"])
        provenance = json.loads(raw.get("provenance", "null"))
        metrics = json.loads(raw.get("metrics", "{}"))
    except (KeyError, json.JSONDecodeError) as err:
        raise WeightsError(f"{path}: bad metadata ({err})") from None
    cfg = _config_from_dict(CONFIGS[cls.NAME], cfg_dict, f"{path}: metadata `config`")
    model = cls(cfg)
    with safe_open(path, framework="pt", device=device) as f:
        state = read_state(f, model, path)
    model.load_state_dict(state, strict=True)
    model.eval()
    return model, {"format": fmt, "version": raw["version"], "config": cfg, "provenance": provenance, "metrics": metrics, "raw": dict(raw)}


def loss_aux(results: Sequence[Dict[str, object]], frames: Sequence[Dict[str, torch.Tensor]]) -> Dict[str, object]:
    """`aux` for losses.total_loss from any learned model's run_sequence results."""
    last = results[-1]
    aux = {"motion": [f["motion"] for f in frames], "o": last["o"], "albedo_mod": last["albedo_mod"]}
    if all("metallic" in f for f in frames):
        aux["metallic"] = [f["metallic"] for f in frames]
    if "exposure" in last:
        aux["exposure"] = last["exposure"]
    return aux
