"""SSR denoiser: input preparation, warp, temporal feature accumulator (TFA) and U-Net.

This is the PyTorch mirror of the WGSL engine (wgsl/nn/*.wgsl, DESIGN.md sections 3-4).
Every convention here is part of the contract with the engine; see training/README.md.

Tensors are NCHW float32. A frame is a dict of full-resolution buffers (DESIGN section 3):

    color(3) mask(1) albedo(3) normal(3) shadow(3) transparent(3)
    depth(1) metallic(1) roughness(1) motion(2)

`SSRModel.forward(frame, state)` denoises one frame given the recurrent state
`(a_acc_prev, o_prev, exposure_prev)` (or None for the first frame of a sequence) and returns
a dict with the output and every intermediate (the golden generator and training share it).

Config version 2 (the default) adds three things that version-1 weights did not have
(issue 11; version-1 files still load and run the version-1 pipeline):

* `exposure = "channel"`: per-channel exposure normalisation. Every frame measures
  g_c = exp(mean ln d_c) over the traced pixels with d_c > 0, d = color / (albedo + eps)
  (the geometric mean of the demodulated samples), and likewise for the shadow buffer
  (d = shadow), smooths both in log space over frames (`EXPOSURE_RATE`; a change beyond
  `EXPOSURE_JUMP` is taken at once: a cut or a light switched), divides colour and
  shadow by their exposure before the network and multiplies the output by the colour's;
  the history is re-expressed in the new exposure (`rescale_log`). The whole pipeline is
  then equivariant to per-channel radiance scaling (of lights, of colour and shadow
  together or apart).
  `exposure = "shared"` (a later value; a fine-tune option) does the same with one exposure
  per buffer: the mean of ln d over every traced pixel and channel with d > 0, the same
  for the three channels (`_log_exposure`), so the network sees the samples' colour as it
  is, and the pipeline is equivariant to scaling all three channels alike. Per channel, the
  geometric means of heavy-tailed samples can part from the colour of their means: in a
  room lit only through its windows, where most paths find no light, the dim samples'
  colour sets each channel's exposure while the rare bright ones carry the light; a
  network fed each channel on its own scale then gets the colour balance wrong
  (training/README, Generalisation 26).
* `remodulation = "current"`: remodulate with the albedo that demodulated (the current
  frame's), not the accumulated one.
* `history = "geometry"`: warped history whose depth or normal disagrees with the current
  frame is invalid like an off-screen sample (alpha = 0, W(o) = 0).
* `ceiling = "max"` (a later version-2 option; files without it read "none"): the network's
  log output o is clamped to ln(1 + M_c / s_c), M_c the running max of the demodulated traced
  samples of colour channel c (`update_exposure`, `CEILING_DECAY`), before remodulation and before it
  becomes the history. A network extrapolating far beyond its training range (a held-out
  scene's tiny directly visible emitter came out 24x too bright and tripled the frame's
  mean) cannot make a pixel brighter than anything sampled lately.
* `albedo = "footprint"` (a later version-2 option; files without it read "centre"): the
  albedo buffer the whole pipeline uses (demodulation, the network's albedo input, the
  history test's A, remodulation) is the first-hit base colour averaged over each pixel's
  footprint (`albedo_footprint`, written by `subpixel dataset --background N`) instead of
  the G-buffer's value at the pixel centre. The reference is the footprint's mean radiance,
  so where a pixel mixes surfaces (an albedo edge) remodulating with the centre's albedo
  cannot reach it (`ssr.albedo_ceiling`); with the footprint's it can. `use_albedo` below.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import torch
import torch.nn.functional as F
from torch import nn

# ----------------------------------------------------------------------------- constants

ALBEDO_EPS = 0.00316
"""Added to the albedo before (de)modulation (DESIGN section 3)."""

FINITE_MAX = 3.0e38
"""The engine's finiteness test: |v| <= 3e38 (NaN fails every comparison)."""

A_CHANNELS = 15
"""A_t = [e(3), albedo(3), normal(3), log1p(shadow)(3), depth(1), metallic(1), roughness(1)]."""

MT_CHANNELS = 4
"""MT = [mask(1), transparent(3)]."""

RGB = 3

ALBEDO_SLICE = slice(3, 6)
"""Channels of A (and A_acc) holding the albedo."""

FRAME_CHANNELS: Dict[str, int] = {
    "color": 3,
    "mask": 1,
    "albedo": 3,
    "normal": 3,
    "shadow": 3,
    "transparent": 3,
    "depth": 1,
    "metallic": 1,
    "roughness": 1,
    "motion": 2,
}
"""Per-frame input buffers and their channel counts (DESIGN section 3)."""

TILE_OFFSETS: Tuple[Tuple[int, int], ...] = ((0, 0), (1, 1), (1, 0), (0, 1))
"""(dx, dy) of the traced pixel inside each 2x2 tile for frame t: TILE_OFFSETS[t % 4]."""

CONFIG_VERSION = 2
"""Config (and weights file) version this code writes; version 1 is read as LEGACY_OPTIONS."""

LEGACY_OPTIONS: Dict[str, str] = {
    "exposure": "none", "remodulation": "accumulated", "history": "screen", "ceiling": "none", "mean_correction": "none",
    "albedo": "centre", "emission": "network", "escaped": "network",
}
"""What version-1 weights were trained with: absolute radiance in, output remodulated with the
accumulated albedo, history rejected only off screen, no output ceiling."""

OPTION_VALUES: Dict[str, Tuple[str, ...]] = {
    "exposure": ("none", "channel", "shared"),
    "remodulation": ("accumulated", "current"),
    "history": ("screen", "geometry"),
    "ceiling": ("none", "max"),
    "mean_correction": ("none", "tiles", "tiles16", "atrous"),
    "albedo": ("centre", "footprint"),
    "emission": ("network", "background"),
    "escaped": ("network", "background"),
}

LATE_OPTIONS: Dict[str, str] = {
    "ceiling": "none", "mean_correction": "none", "albedo": "centre", "emission": "network", "escaped": "network",
}
"""Version-2 options added after the first version-2 weights: absent, they take this value."""

FINE_TUNE_OPTIONS: Tuple[str, ...] = ("albedo", "emission", "escaped", "exposure")
"""Options that change what the network is fed but not its parameters: a run started from
weights (`ssr.train --init`) may set them differently from the file, fine-tuning it."""

OUTPUT_PASS_OPTIONS: Tuple[str, ...] = ("mean_correction",)
"""Options only the engine's output pass applies (after the network, outside its history):
the model's own output, hence a file's val metrics, is the same with any value."""

CEILING_GAIN = 1.0
"""Config `ceiling = "max"`: the demodulated output of channel c never exceeds CEILING_GAIN * M_c,
M the running max of the demodulated traced samples (below)."""

CEILING_DECAY = 0.9
"""M_t = max(m_t, CEILING_DECAY * M_{t-1}) per colour channel, m_t this frame's max over the traced
pixels of clean(color) / (clean(albedo) + 0.00316) (M_0 = m_0). Per channel, so the pipeline stays
equivariant to per-channel radiance scaling."""

EXPOSURE_RATE = 0.1
"""Per-frame rate of the exposure's exponential moving average in log space."""

EXPOSURE_JUMP = 0.6931471805599453
"""|ln g - ln s_prev| beyond this (a factor of 2) sets s = g at once instead of easing: after a
cut to a brighter or darker scene the network sees its usual range from the first frame
(the history is re-exposed either way)."""

HISTORY_DEPTH_TOL = 0.2
"""History is inconsistent where |W(depth_acc) - depth| > HISTORY_DEPTH_TOL * depth ..."""

HISTORY_NORMAL_TOL = 0.25
"""... or |W(normal_acc) - normal|^2 > HISTORY_NORMAL_TOL (cos < 0.875 for unit normals)."""

E_SLICE = slice(0, 3)
SHADOW_SLICE = slice(9, 12)
NORMAL_SLICE = slice(6, 9)
DEPTH_CHANNEL = 12


# ----------------------------------------------------------------------------- config


@dataclass(frozen=True)
class SSRConfig:
    """Network widths and options; stored as JSON in the weights file (`config`)."""

    tfa_hidden: int = 8
    k: int = 8
    # encoder widths, one per U-Net level: 3 levels (the default), or 4 (a fourth level at
    # 1/8 resolution, UNet below; the engine runs both)
    enc: Tuple[int, ...] = (16, 32, 28)
    feature_pool: str = "max"  # "max" | "avg": pooling of encoder features
    upsample: str = "bilinear"  # "bilinear" | "nearest": upsampling of I3, I2
    input_channels: int = A_CHANNELS + MT_CHANNELS + A_CHANNELS + RGB  # 37
    version: int = CONFIG_VERSION
    exposure: str = "channel"  # "none" | "channel" | "shared": exposure normalisation per channel or per buffer
    remodulation: str = "current"  # "accumulated" | "current": albedo of the remodulation
    history: str = "geometry"  # "screen" | "geometry": which warped history is invalid
    ceiling: str = "max"  # "none" | "max": clamp the output to the brightest recent sample
    # "none" | "tiles" | "tiles16": the engine's output pass scales each 32x32 (16x16) tile of
    # the reconstruction to the traced samples' sum over the last 4 frames (`MeanCorrection`
    # below, applied after the model like `composite_background`)
    mean_correction: str = "none"
    # "centre" | "footprint": which albedo buffer the pipeline uses (`use_albedo`)
    albedo: str = "centre"
    # "network" | "background": who reconstructs the emission of the surfaces the camera sees
    # directly: the network, from the samples, or the background composite, from the
    # footprint (`fold_emission`)
    emission: str = "network"
    # "network" | "background": who reconstructs the traced samples whose camera ray escaped
    # to the environment: the network, fed them as any other, or the background composite,
    # which holds the environment of the whole footprint (`fold_emission` leaves them out)
    escaped: str = "network"

    def __post_init__(self) -> None:
        object.__setattr__(self, "enc", tuple(int(c) for c in self.enc))
        self.validate()

    def validate(self) -> None:
        def positive(name: str, v: object) -> None:
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
                raise ValueError(f"config: `{name}` must be a positive integer, got {v!r}")

        positive("tfa_hidden", self.tfa_hidden)
        positive("k", self.k)
        if len(self.enc) not in (3, 4):
            raise ValueError(f"config: `enc` must hold 3 widths [c1, c2, c3] (or 4, a fourth level), got {list(self.enc)}")
        for i, c in enumerate(self.enc):
            positive(f"enc[{i}]", c)
        if self.feature_pool not in ("max", "avg"):
            raise ValueError(f"config: `feature_pool` must be \"max\" or \"avg\", got {self.feature_pool!r}")
        if self.upsample not in ("bilinear", "nearest"):
            raise ValueError(f"config: `upsample` must be \"bilinear\" or \"nearest\", got {self.upsample!r}")
        expected = A_CHANNELS + MT_CHANNELS + A_CHANNELS + RGB
        if self.input_channels != expected:
            raise ValueError(f"config: `input_channels` must be {expected}, got {self.input_channels!r}")
        if self.version not in (1, CONFIG_VERSION):
            raise ValueError(f"config: unsupported `version` {self.version!r} (this code reads 1 and {CONFIG_VERSION})")
        for key, values in OPTION_VALUES.items():
            v = getattr(self, key)
            if v not in values:
                raise ValueError(f"config: `{key}` must be one of {list(values)}, got {v!r}")
            if self.version == 1 and v != LEGACY_OPTIONS[key]:
                raise ValueError(f"config: version 1 has no `{key}` option (it means {LEGACY_OPTIONS[key]!r}), got {v!r}")
        if self.ceiling == "max" and self.exposure == "none":
            raise ValueError('config: `ceiling` "max" needs `exposure` "channel" or "shared" (the running max lives in the exposure state)')

    def to_dict(self) -> dict:
        d = {
            "enc": list(self.enc),
            "feature_pool": self.feature_pool,
            "input_channels": self.input_channels,
            "k": self.k,
            "tfa_hidden": self.tfa_hidden,
            "upsample": self.upsample,
            "version": self.version,
        }
        if self.version >= 2:
            d.update({k: getattr(self, k) for k in OPTION_VALUES})
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_dict(cls, d: dict) -> "SSRConfig":
        if not isinstance(d, dict):
            raise ValueError(f"config: expected a JSON object, got {type(d).__name__}")
        known = {"tfa_hidden", "k", "enc", "feature_pool", "upsample", "input_channels", "version"}
        version = d.get("version")
        if version == 1:
            options = dict(LEGACY_OPTIONS)
            present = sorted(set(OPTION_VALUES) & set(d))
            if present:
                raise ValueError(f"config: version 1 has no option(s) {present} (they came with version 2)")
        else:
            known |= set(OPTION_VALUES)
            options = {k: d.get(k, LATE_OPTIONS.get(k)) for k in OPTION_VALUES}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"config: unknown key(s) {unknown}")
        missing = sorted(known - set(d) - set(LATE_OPTIONS))
        if missing:
            raise ValueError(f"config: missing key(s) {missing}")
        enc = d["enc"]
        if not isinstance(enc, (list, tuple)):
            raise ValueError(f"config: `enc` must be a list [c1, c2, c3], got {enc!r}")
        return cls(
            tfa_hidden=d["tfa_hidden"],
            k=d["k"],
            enc=tuple(enc),
            feature_pool=d["feature_pool"],
            upsample=d["upsample"],
            input_channels=d["input_channels"],
            version=version,
            **options,
        )

    @classmethod
    def from_json(cls, s: str) -> "SSRConfig":
        try:
            d = json.loads(s)
        except json.JSONDecodeError as err:
            raise ValueError(f"config: not valid JSON ({err})") from None
        return cls.from_dict(d)


FOOTPRINT_ALBEDO = "albedo_footprint"
"""The frame buffer (data.EXTRA_SUFFIXES) config `albedo = "footprint"` uses as the albedo."""


DIRECT_EMISSION = ("emission", "emission_footprint")
"""The frame buffers (data.EXTRA_SUFFIXES) config `emission = "background"` folds into the
colour and the background (`fold_emission`)."""

ESCAPED = ("escaped", "background", "coverage")
"""The frame buffers config `escaped = "background"` reads: which traced samples escaped to
the environment (`fold_emission` leaves them out), and the background that holds it."""


def leaves_escaped(cfg: Optional[SSRConfig]) -> bool:
    """Whether a model of config `cfg` leaves the samples that escaped to the environment to
    the background (`escaped = "background"`)."""
    return getattr(cfg, "escaped", "network") == "background"


def fold_buffers(cfg: Optional[SSRConfig]) -> Tuple[str, ...]:
    """The frame buffers `fold_emission` reads for a model of config `cfg`, each once: with
    emission "background" the directly seen emission, with escaped "background" the samples'
    escapes, and with either the background and coverage the composite reads too."""
    emission = DIRECT_EMISSION + ("background", "coverage") if getattr(cfg, "emission", "network") == "background" else ()
    escaped = ESCAPED if leaves_escaped(cfg) else ()
    return tuple(dict.fromkeys(emission + escaped))


def extra_buffers(cfg: SSRConfig) -> Tuple[str, ...]:
    """Buffers beyond data.BUFFERS a model of config `cfg` reads (load them with
    `SequenceDataset(extra=...)`, or per frame file with data.read_extra_buffers), each once:
    the footprint albedo of albedo "footprint", and `fold_buffers`."""
    albedo = (FOOTPRINT_ALBEDO,) if cfg.albedo == "footprint" else ()
    return albedo + fold_buffers(cfg)


COMPOSITE_EMISSION = "composite_emission"
"""The frame key `fold_emission` sets: the emission the output pass adds (the engine's
`FrameInputs::emission`)."""


def fold_emission(frame: Dict[str, torch.Tensor], cfg: Optional[SSRConfig]) -> Dict[str, torch.Tensor]:
    """`frame` as a model of config `cfg` is fed it (the engine's frame loop, and `subpixel
    denoise` on frame files, feed the same; WGSL ssr/fold_emission): itself for `emission =
    "network"` and `escaped = "network"`; for emission "background", the colour without each
    traced sample's first-hit emission (`emission`, the part of `color` that is emission seen
    directly), and the first-hit emission averaged over the background's footprint
    (`emission_footprint`) under COMPOSITE_EMISSION, which the output pass adds
    (`composite_background`, `MeanCorrection`): the network then reconstructs only reflected
    light, and the emitters come back without noise; for escaped "background", the traced
    pixels at least half of whose samples escaped to the environment (`escaped` >= 1/2) left
    out (colour and mask 0, as untraced pixels): the background holds the environment of the
    whole footprint, and the network reconstructs the part that hits the scene. A KeyError
    names a missing buffer and the command that writes it. Call it once per frame, before the
    model and the output pass."""
    need = fold_buffers(cfg)
    if not need:
        return frame
    emission, escaped = DIRECT_EMISSION[0] in need, leaves_escaped(cfg)
    missing = [b for b in need if b not in frame]
    if missing:
        which = "emission" if emission and any(b in DIRECT_EMISSION for b in missing) else "escaped"
        raise KeyError(
            f"config {which} = \"background\" needs the frames' {missing} buffer(s) (written by "
            "`subpixel dataset --background N`, `escaped` added to older frames by re-running it with "
            "--resume; load them with SequenceDataset(extra=...))"
        )
    out = dict(frame)
    if emission:
        out["color"] = (frame["color"] - frame["emission"]).clamp_min(0.0)
        out[COMPOSITE_EMISSION] = frame["emission_footprint"]
    if escaped:
        keep = ~(frame["escaped"] >= 0.5)
        out["color"] = torch.where(keep, out["color"], torch.zeros_like(out["color"]))
        out["mask"] = torch.where(keep, frame["mask"], torch.zeros_like(frame["mask"]))
    return out


def use_albedo(frame: Dict[str, torch.Tensor], cfg: SSRConfig) -> Dict[str, torch.Tensor]:
    """`frame` with the albedo config `cfg.albedo` asks for in its `albedo` buffer: itself
    for "centre", the footprint albedo for "footprint" (a KeyError naming the buffer and the
    command that writes it when the frame lacks it)."""
    if cfg.albedo == "centre":
        return frame
    if FOOTPRINT_ALBEDO not in frame:
        raise KeyError(
            f"config albedo = \"footprint\" needs the frames' `{FOOTPRINT_ALBEDO}` buffer (written by "
            "`subpixel dataset --background N`; load it with SequenceDataset(extra=model.extra_buffers(cfg)))"
        )
    return {**frame, "albedo": frame[FOOTPRINT_ALBEDO]}


# ----------------------------------------------------------------------------- elementwise ops


def _clean(x: torch.Tensor) -> torch.Tensor:
    """NaN, negative and infinite values become 0 (the engine's `clean`)."""
    return torch.where((x >= 0) & (x <= FINITE_MAX), x, torch.zeros_like(x))


def demodulate(color: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """e = log(1 + clamp(color, min=0) / (clamp(albedo, min=0) + 0.00316)), per channel.

    Like wgsl/nn/demodulate.wgsl, non-finite colour/albedo values also count as 0.
    """
    return torch.log(1.0 + _clean(color) / (_clean(albedo) + ALBEDO_EPS))


def remodulate(o: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """out = clamp(exp(o) - 1, min=0) * (clamp(albedo, min=0) + 0.00316) (SSRModel multiplies by
    the exposure after this)."""
    return torch.clamp(torch.exp(o) - 1.0, min=0.0) * (torch.clamp(albedo, min=0.0) + ALBEDO_EPS)


def traced_samples(frame: Dict[str, torch.Tensor], bg: torch.Tensor, cov: torch.Tensor, escaped: bool,
                   like: torch.Tensor) -> torch.Tensor:
    """The mean correction's samples at the traced pixels (wgsl/ssr/lib/traced.wgsl), what the
    reconstruction's share `(1 - coverage) output` is compared with: each sample's share the
    network reconstructs, `color - background`; for a model of config escaped "background",
    whose samples that escaped to the environment `fold_emission` left out, the rest are of
    the part of the footprint that hits the scene, so `(1 - coverage) color`. In `like`'s
    dtype (the colour sanitised as the engine does)."""
    color = _clean(frame["color"]).to(like.dtype)
    return (1.0 - cov) * color if escaped else color - bg


MEAN_TILE, MEAN_RING, MEAN_EPS, MEAN_LO, MEAN_HI = 32, 4, 1e-4, 0.67, 1.5
"""Config `mean_correction = "tiles"` (src/ssr/config.rs): tile side, frames of the ring, the
epsilon of both sums, the clamp of the factor."""

MEAN_TILES: Dict[str, int] = {"tiles": MEAN_TILE, "tiles16": 16}
"""Tile side of each value of config `mean_correction` that corrects (src/ssr/config.rs
`MeanCorrection::Tiles`)."""


def tile_sums(x: torch.Tensor, tile: int = MEAN_TILE) -> torch.Tensor:
    """[N, C, H, W] -> [N, C, ceil(H / tile), ceil(W / tile)]: sums over tiles (zero-padded)."""
    n, c, h, w = x.shape
    th, tw = -(-h // tile), -(-w // tile)
    x = F.pad(x, (0, tw * tile - w, 0, th * tile - h))
    return x.reshape(n, c, th, tile, tw, tile).sum(dim=(3, 5))


class MeanCorrection:
    """The engine's output pass with config `mean_correction = "tiles"` (wgsl/ssr/tile_means.wgsl,
    store_output.wgsl), frame by frame: per tile of `tile`^2 pixels (MEAN_TILE; "tiles16": 16,
    `mean_correction_of`) and channel, over the
    traced pixels (mask > 1/2) of the last MEAN_RING frames, the factor
    `clamp((sum(color - B) + eps) / (sum((1 - a) output) + eps), MEAN_LO, MEAN_HI)`, interpolated
    bilinearly between tile centres (edges held), scales the reconstructed part:
    `B + (1 - a) output factor + E` (B, a the background and coverage, 0 without them; E the
    directly seen emission of `fold_emission`, which the samples `color` no longer hold). The
    factor is differentiable in `output` (training through it sees the whole pass). A new
    instance (or `reset`) starts with an empty ring, as the engine after a reset."""

    def __init__(self, tile: int = MEAN_TILE, escaped: bool = False) -> None:
        self.tile = int(tile)
        self.escaped = bool(escaped)
        self.ring: List[Tuple[torch.Tensor, torch.Tensor]] = []

    def reset(self) -> None:
        self.ring = []

    def __call__(self, output: torch.Tensor, frame: Dict[str, torch.Tensor]) -> torch.Tensor:
        bg, cov = background_parts(frame, output)
        part = (1.0 - cov) * output
        traced = (frame["mask"] > 0.5).to(output.dtype)
        sample = traced_samples(frame, bg, cov, self.escaped, output) * traced
        self.ring = (self.ring + [(tile_sums(sample, self.tile), tile_sums(part * traced, self.tile))])[-MEAN_RING:]
        s = sum(x for x, _ in self.ring)
        r = sum(x for _, x in self.ring)
        f = ((s + MEAN_EPS) / (r + MEAN_EPS)).clamp(MEAN_LO, MEAN_HI)
        h, w = output.shape[-2:]
        up = F.interpolate(f, scale_factor=self.tile, mode="bilinear", align_corners=False)[..., :h, :w]
        return bg + part * up + emission_part(frame, output)


ATROUS_LEVELS, ATROUS_NORMAL_SQUARINGS, ATROUS_DEPTH_SIGMA = 5, 3, 0.2
ATROUS_EPS = MEAN_EPS / 256.0
ATROUS_DECAY = 0.7
"""Config `mean_correction = "atrous"` (src/ssr/config.rs): filter levels (steps 1, 2, 4, 8,
16 pixels), the normal weight's power as squarings (cos^8), the depth weight's scale, the
epsilon added to both filtered means of a factor, and the weight of the warped earlier
frames' sums in each frame's (`AtrousMeanCorrection`)."""

ATROUS_TAPS = (1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0)
"""The 5-tap B-spline of each a-trous level (per axis)."""


def atrous_weights(normal: torch.Tensor, depth: torch.Tensor, n_q: torch.Tensor, z_q: torch.Tensor) -> torch.Tensor:
    """Edge-stopping weight [N, 1, H, W] between each pixel (normal, depth) and its tap q
    (n_q, z_q; zero outside the frame, which gives weight 0): max(n . n_q, 0)^8 times
    exp(-|z - z_q| / max(z, z_q, 1e-4) / ATROUS_DEPTH_SIGMA). The inputs are data (no
    gradient): the arithmetic runs in place on the intermediates."""
    c = (normal * n_q).sum(dim=-3, keepdim=True).clamp_(min=0.0)
    for _ in range(ATROUS_NORMAL_SQUARINGS):
        c.mul_(c)
    rel = (depth - z_q).abs_().div_(torch.maximum(depth, z_q).clamp_(min=1e-4))
    return c.mul_(rel.neg_().div_(ATROUS_DEPTH_SIGMA).exp_())


def _tap_windows(step: int):
    """The 25 taps of an a-trous level with taps `step` pixels apart, in the engine's order
    (rows outer): (index, row offset, column offset) of each within a frame padded by
    2 * step on every side."""
    pad = 2 * step
    return [(k, pad + (k // 5 - 2) * step, pad + (k % 5 - 2) * step) for k in range(25)]


class _AtrousTaps(torch.autograd.Function):
    """sum_k weights[k] * x shifted by tap k (zero outside the frame), the sums in tap order as
    the engine's; its gradient in x is the adjoint (each weighted gradient shifted back),
    written into one padded buffer (autograd through 25 slices of a padded x would zero and
    add a padded-size buffer per tap: most of the trainer's time in this filter). The
    weights are constants (no gradient)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, step: int, *weights: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        pad = 2 * step
        xp = F.pad(x, (pad, pad, pad, pad))
        acc = torch.zeros_like(x)
        for k, y0, x0 in _tap_windows(step):
            acc += weights[k] * xp[..., y0 : y0 + h, x0 : x0 + w]
        ctx.save_for_backward(*weights)
        ctx.step = step
        return acc

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        weights = ctx.saved_tensors
        h, w = grad.shape[-2:]
        pad = 2 * ctx.step
        gp = grad.new_zeros(grad.shape[:-2] + (h + 2 * pad, w + 2 * pad))
        for k, y0, x0 in _tap_windows(ctx.step):
            gp[..., y0 : y0 + h, x0 : x0 + w] += weights[k] * grad
        return (gp[..., pad : pad + h, pad : pad + w], None) + (None,) * len(weights)


def atrous_filter(x: torch.Tensor, normal: torch.Tensor, depth: torch.Tensor,
                  levels: int = ATROUS_LEVELS) -> torch.Tensor:
    """The mean correction's edge-aware filter (wgsl/ssr/mean_atrous.wgsl): `levels` a-trous
    levels of the 5x5 B-spline, level l with taps 2^l pixels apart, each tap weighted by
    `atrous_weights` against the centre's normal and depth (the current frame's), each level
    normalised by its weights' sum (at least 1e-12). x [N, C, H, W]; normal [N, 3, H, W],
    depth [N, 1, H, W]. Differentiable in x (normal and depth are data)."""
    h, w = x.shape[-2:]
    for lvl in range(levels):
        step = 2 ** lvl
        pad = 2 * step
        with torch.no_grad():
            np_ = F.pad(normal, (pad, pad, pad, pad))
            zp = F.pad(depth, (pad, pad, pad, pad))
            weights = []
            wsum = torch.zeros_like(depth)
            for k, y0, x0 in _tap_windows(step):
                n_q, z_q = np_[..., y0 : y0 + h, x0 : x0 + w], zp[..., y0 : y0 + h, x0 : x0 + w]
                wt = (ATROUS_TAPS[k // 5] * ATROUS_TAPS[k % 5]) * atrous_weights(normal, depth, n_q, z_q)
                weights.append(wt)
                wsum += wt
        x = _AtrousTaps.apply(x, step, *weights) / wsum.clamp(min=1e-12)
    return x


class AtrousMeanCorrection(MeanCorrection):
    """Config `mean_correction = "atrous"` (wgsl/ssr/mean_history.wgsl, mean_atrous.wgsl,
    store_output.wgsl): as MeanCorrection, the reconstruction is scaled towards the traced
    samples of recent frames, but per pixel and along the motion: each frame's per-pixel
    samples and reconstruction at the traced pixels (0 elsewhere) are added to the earlier
    frames' sums warped to this frame (`warp` by the motion vectors, invalid history 0) times
    ATROUS_DECAY, S_t = s_t + ATROUS_DECAY W(S_{t-1}) (the same for R; `self.ring` holds the
    last sums), both filtered alike by `atrous_filter`, guided by this frame's normals and
    depths (so a factor averages over its own surface, not across silhouettes and creases),
    and each pixel's factor is `clamp((S + ATROUS_EPS) / (R + ATROUS_EPS), MEAN_LO, MEAN_HI)`."""

    def __init__(self, escaped: bool = False) -> None:
        super().__init__(1, escaped)

    def __call__(self, output: torch.Tensor, frame: Dict[str, torch.Tensor]) -> torch.Tensor:
        bg, cov = background_parts(frame, output)
        part = (1.0 - cov) * output
        traced = (frame["mask"] > 0.5).to(output.dtype)
        sample = traced_samples(frame, bg, cov, self.escaped, output) * traced
        batched = output.dim() == 4
        sr = torch.cat([sample, part * traced], dim=-3)
        normal, depth = frame["normal"].to(output.dtype), frame["depth"].to(output.dtype)
        motion = frame["motion"].to(output.dtype)
        if not batched:
            sr, normal, depth, motion = sr[None], normal[None], depth[None], motion[None]
        if self.ring:
            sr = sr + ATROUS_DECAY * warp(self.ring[0], motion)[0]
        self.ring = [sr]
        sr = atrous_filter(sr, normal, depth)
        if not batched:
            sr = sr[0]
        f = ((sr[..., :RGB, :, :] + ATROUS_EPS) / (sr[..., RGB:, :, :] + ATROUS_EPS)).clamp(MEAN_LO, MEAN_HI)
        return bg + part * f + emission_part(frame, output)


def mean_correction_of(cfg: "SSRConfig") -> Optional[MeanCorrection]:
    """A fresh mean correction of config `cfg` (MeanCorrection of its tile side, or
    AtrousMeanCorrection; for `escaped = "background"` comparing the samples as
    `traced_samples` says), or None for `mean_correction = "none"`."""
    kind = getattr(cfg, "mean_correction", "none")
    escaped = leaves_escaped(cfg)
    if kind == "atrous":
        return AtrousMeanCorrection(escaped)
    tile = MEAN_TILES.get(kind)
    return None if tile is None else MeanCorrection(tile, escaped)


def background_parts(frame: Dict[str, torch.Tensor], like: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
    """(background, coverage) of a frame, sanitised as the engine does (background values
    non-finite or negative 0, at most 1e12; coverage in [0, 1], non-finite 0), in `like`'s
    dtype; zeros without those buffers."""
    if "background" not in frame or "coverage" not in frame:
        return torch.zeros_like(like), torch.zeros_like(like[:, :1] if like.dim() == 4 else like[:1])
    bg = torch.nan_to_num(frame["background"], nan=0.0, posinf=0.0, neginf=0.0).clamp(0.0, 1e12)
    cov = torch.nan_to_num(frame["coverage"], nan=0.0, posinf=0.0, neginf=0.0).clamp(0.0, 1.0)
    return bg.to(like.dtype), cov.to(like.dtype)


def composite_background(output: torch.Tensor, frame: Dict[str, torch.Tensor]) -> torch.Tensor:
    """The engine's output pass with the optional background buffer (wgsl/ssr/store_output.wgsl):
    `background + (1 - coverage) * output`, the directly seen environment over the part of the
    footprint that escapes (premultiplied by it) plus the reconstruction of the rest; the
    background alone where the coverage is 1. Sanitised as the engine does: background values
    non-finite or negative 0 (at most 1e12), coverage into [0, 1] (non-finite 0). Without those
    buffers, `output` unchanged. [N, 3, H, W] (or [3, H, W]) like the frame."""
    if "background" not in frame or "coverage" not in frame:
        return output
    bg, cov = background_parts(frame, output)
    return bg + (1.0 - cov) * output + emission_part(frame, output)


def output_pass(output: torch.Tensor, frame: Dict[str, torch.Tensor], mc: Optional[MeanCorrection]) -> torch.Tensor:
    """The engine's output pass over the network's output: with a mean correction `mc` (a
    fresh one per sequence, its ring carried over the frames) the correction with the
    background and the emitters; without, `composite_background` (the output unchanged where
    the frame has no background)."""
    return mc(output, frame) if mc is not None else composite_background(output, frame)


def emission_part(frame: Dict[str, torch.Tensor], like: torch.Tensor) -> torch.Tensor:
    """The directly seen emission the output pass adds (COMPOSITE_EMISSION, set by
    `fold_emission`; sanitised as the background), 0 without it, in `like`'s dtype."""
    e = frame.get(COMPOSITE_EMISSION)
    if e is None:
        return torch.zeros((), dtype=like.dtype, device=like.device)
    return torch.nan_to_num(e, nan=0.0, posinf=0.0, neginf=0.0).clamp(0.0, 1e12).to(like.dtype)


def quarter_mask(height: int, width: int, t: int, *, dtype=torch.float32) -> torch.Tensor:
    """The 1/4-spp mask of frame t, [1, 1, H, W]: 1 at (2i+dx, 2j+dy), (dx, dy) = TILE_OFFSETS[t % 4]."""
    dx, dy = TILE_OFFSETS[t % 4]
    m = torch.zeros(1, 1, height, width, dtype=dtype)
    m[:, :, dy::2, dx::2] = 1.0
    return m


def _check_frame(frame: Dict[str, torch.Tensor]) -> Tuple[int, int, int]:
    n = h = w = None
    for name, c in FRAME_CHANNELS.items():
        if name not in frame:
            raise KeyError(f"frame: missing buffer `{name}`")
        t = frame[name]
        if t.dim() != 4 or t.shape[1] != c:
            raise ValueError(f"frame: `{name}` must be [N, {c}, H, W], got {list(t.shape)}")
        if n is None:
            n, h, w = t.shape[0], t.shape[2], t.shape[3]
        elif (t.shape[0], t.shape[2], t.shape[3]) != (n, h, w):
            raise ValueError(f"frame: `{name}` is {list(t.shape)}, other buffers are [{n}, C, {h}, {w}]")
    if h % 4 or w % 4:
        raise ValueError(f"frame: height and width must be multiples of 4 (the engine pads), got {h}x{w}")
    return n, h, w


EXPOSURE_CHANNELS = 6
"""The exposure s: [colour r, g, b, shadow r, g, b]."""

STATE_EXPOSURE_CHANNELS = EXPOSURE_CHANNELS + RGB
"""The exposure state carried between frames: s (EXPOSURE_CHANNELS), then the ceiling's running
max M (rgb) of the demodulated traced samples (CEILING_DECAY)."""


def _demodulated_samples(frame: Dict[str, torch.Tensor]) -> Tuple[torch.Tensor, torch.Tensor]:
    """(d = [clean(color) / (clean(albedo) + eps), clean(shadow)] [N, 6, H, W], traced [N, 1, H, W])."""
    d = torch.cat([_clean(frame["color"]) / (_clean(frame["albedo"]) + ALBEDO_EPS), _clean(frame["shadow"])], dim=1)
    return d, _clean(frame["mask"]) > 0.5


def _log_exposure(frame: Dict[str, torch.Tensor], shared: bool = False) -> Tuple[torch.Tensor, torch.Tensor]:
    """(mean ln d_c over the traced pixels with d_c > 0, whether there is one), [N, 6, 1, 1] each,
    d = [clean(color) / (clean(albedo) + eps), clean(shadow)] (wgsl/ssr/exposure_*.wgsl). With
    `shared` (config exposure "shared"), the mean over every channel of the buffer (colour,
    shadow) and those pixels, the same value for its three channels."""
    d, traced = _demodulated_samples(frame)
    pos = traced & (d > 0)
    ln = torch.where(pos, torch.log(torch.where(pos, d, torch.ones_like(d))), torch.zeros_like(d))
    total = ln.sum(dim=(2, 3), keepdim=True)
    count = pos.to(d.dtype).sum(dim=(2, 3), keepdim=True)
    if shared:  # per buffer: colour channels 0..2, shadow 3..5
        pool = lambda x: torch.cat([x[:, i : i + RGB].sum(dim=1, keepdim=True).expand(-1, RGB, -1, -1) for i in (0, RGB)], 1)  # noqa: E731
        total, count = pool(total), pool(count)
    have = count > 0
    return torch.where(have, total / torch.clamp(count, min=1.0), torch.zeros_like(total)), have


def frame_sample_max(frame: Dict[str, torch.Tensor]) -> torch.Tensor:
    """m [N, 3, 1, 1]: per colour channel, the max over the traced pixels of the demodulated
    colour clean(color) / (clean(albedo) + eps); 0 where nothing is traced."""
    d, traced = _demodulated_samples(frame)
    return torch.where(traced, d[:, :RGB], torch.zeros_like(d[:, :RGB])).amax(dim=(2, 3), keepdim=True)


def frame_exposure(frame: Dict[str, torch.Tensor], shared: bool = False) -> torch.Tensor:
    """g_c = exp(mean ln d_c) over the traced pixels with d_c > 0 (1 where there is none),
    [N, 6, 1, 1]: demodulated colour rgb, shadow rgb (`shared`: per buffer, `_log_exposure`)."""
    lg, _ = _log_exposure(frame, shared)
    return torch.exp(lg)


def update_exposure(frame: Dict[str, torch.Tensor], prev: Optional[torch.Tensor], shared: bool = False) -> torch.Tensor:
    """This frame's exposure state [N, 9, 1, 1] (STATE_EXPOSURE_CHANNELS); `shared`: g per
    buffer (config exposure "shared", `_log_exposure`), the running max still per channel.

    Exposure s (channels 0..5): g on the first frame (prev None), then exp(ln s_prev +
    EXPOSURE_RATE (ln g - ln s_prev)), or g where |ln g - ln s_prev| > EXPOSURE_JUMP; a channel
    without a positive traced sample keeps s_prev (1 on a first frame).
    Running max M (channels 6..8): m (`frame_sample_max`) on the first frame, then
    max(m, CEILING_DECAY M_prev)."""
    lg, have = _log_exposure(frame, shared)
    m = frame_sample_max(frame)
    if prev is None:
        return torch.cat([torch.exp(lg), m], dim=1)
    lp = torch.log(prev[:, :EXPOSURE_CHANNELS])
    d = lg - lp
    ls = torch.where(d.abs() > EXPOSURE_JUMP, lg, lp + EXPOSURE_RATE * d)
    running = torch.maximum(m, CEILING_DECAY * prev[:, EXPOSURE_CHANNELS:])
    return torch.cat([torch.exp(torch.where(have, ls, lp)), running], dim=1)


def ceiling(exposure: torch.Tensor) -> torch.Tensor:
    """[N, 3, 1, 1]: the largest o the output may take (config `ceiling = "max"`),
    ln(1 + CEILING_GAIN M_c / s_c) for the colour exposure s and running max M of the state."""
    return torch.log1p(CEILING_GAIN * exposure[:, EXPOSURE_CHANNELS:] / exposure[:, :RGB])


def rescale_log(v: torch.Tensor, ratio: torch.Tensor) -> torch.Tensor:
    """Re-expresses log values v = ln(1 + x / s_prev) in the exposure s: ln(1 + (exp(v) - 1) ratio),
    ratio = s_prev / s (per channel, broadcast). Values v <= 0 (radiance 0 after remodulation's
    clamp) are kept as they are."""
    pos = torch.clamp(v, min=0.0)  # the unused branch stays finite (no NaN gradients)
    return torch.where(v > 0, torch.log(1.0 + (torch.exp(pos) - 1.0) * ratio), v)


def history_consistent(warp_acc: torch.Tensor, a_t: torch.Tensor) -> torch.Tensor:
    """[N, 1, H, W] bool: the warped accumulated depth and normal agree with this frame's
    (|dd| <= HISTORY_DEPTH_TOL depth and |dn|^2 <= HISTORY_NORMAL_TOL)."""
    d = a_t[:, DEPTH_CHANNEL : DEPTH_CHANNEL + 1]
    dd = (warp_acc[:, DEPTH_CHANNEL : DEPTH_CHANNEL + 1] - d).abs()
    dn = ((warp_acc[:, NORMAL_SLICE] - a_t[:, NORMAL_SLICE]) ** 2).sum(dim=1, keepdim=True)
    return (dd <= HISTORY_DEPTH_TOL * d) & (dn <= HISTORY_NORMAL_TOL)


def prepare_inputs(frame: Dict[str, torch.Tensor], exposure: Optional[torch.Tensor] = None) -> Tuple[torch.Tensor, torch.Tensor]:
    """Builds A_t (15 ch) and MT (4 ch) from a frame's buffers.

    A_t = [e(3), albedo(3), normal(3), log1p(clamp(shadow, min=0))(3), depth, metallic, roughness]
    MT  = [mask(1), transparent(3)]
    With `exposure` s ([N, 6 or 9, 1, 1]), colour is divided by s[:, :3] and shadow by s[:, 3:6] first.
    """
    _check_frame(frame)
    color, shadow = frame["color"], frame["shadow"]
    if exposure is not None:
        color = _clean(color) / exposure[:, :RGB]
        shadow = _clean(shadow) / exposure[:, RGB:EXPOSURE_CHANNELS]
    e = demodulate(color, frame["albedo"])
    shadow = torch.log1p(torch.clamp(shadow, min=0.0))
    a_t = torch.cat(
        [e, frame["albedo"], frame["normal"], shadow, frame["depth"], frame["metallic"], frame["roughness"]],
        dim=1,
    )
    mt = torch.cat([frame["mask"], frame["transparent"]], dim=1)
    return a_t, mt


# ----------------------------------------------------------------------------- warp


def _mix(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """WGSL mix(a, b, t) = a * (1 - t) + b * t."""
    return a * (1.0 - t) + b * t


def warp(src: torch.Tensor, motion: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
    """Backward warp of `src` [N, C, H, W] by `motion` [N, 2, H, W] (pixels; prev_pos = pos + motion).

    For pixel (x, y) the sample position is p = (x + 0.5 + mx, y + 0.5 + my). It is valid when
    the motion is finite (|m| <= 3e38) and 0 <= p.x < W, 0 <= p.y < H; invalid samples are 0.
    Valid samples are bilinear: s = p - 0.5, x0 = floor(s.x), tx = s.x - x0 (same for y); the
    taps x0, x0 + 1 / y0, y0 + 1 are clamped to the image; out = mix(mix(a, b, tx), mix(d, e, tx), ty)
    with a = (x0, y0), b = (x1, y0), d = (x0, y1), e = (x1, y1).

    Returns (warped [N, C, H, W], valid [N, 1, H, W] as 0/1 float). An explicit gather,
    mirroring wgsl/nn/warp.wgsl (not grid_sample).
    """
    if src.dim() != 4 or motion.dim() != 4 or motion.shape[1] != 2:
        raise ValueError(f"warp: expected src [N, C, H, W] and motion [N, 2, H, W], got {list(src.shape)}, {list(motion.shape)}")
    n, c, h, w = src.shape
    if (motion.shape[0], motion.shape[2], motion.shape[3]) != (n, h, w):
        raise ValueError(f"warp: motion {list(motion.shape)} does not match src {list(src.shape)}")
    dev, dt = src.device, src.dtype
    mx, my = motion[:, 0].to(dt), motion[:, 1].to(dt)  # [N, H, W]
    finite = (mx.abs() <= FINITE_MAX) & (my.abs() <= FINITE_MAX)
    mx = torch.where(finite, mx, torch.zeros_like(mx))
    my = torch.where(finite, my, torch.zeros_like(my))
    xs = torch.arange(w, device=dev, dtype=dt).view(1, 1, w)
    ys = torch.arange(h, device=dev, dtype=dt).view(1, h, 1)
    px = (xs + 0.5) + mx
    py = (ys + 0.5) + my
    valid = finite & (px >= 0) & (py >= 0) & (px < w) & (py < h)
    sx = px - 0.5
    sy = py - 0.5
    fx = torch.floor(sx)
    fy = torch.floor(sy)
    tx = (sx - fx).unsqueeze(1)
    ty = (sy - fy).unsqueeze(1)
    x0 = torch.clamp(fx, 0, w - 1).long()
    x1 = torch.clamp(fx + 1, 0, w - 1).long()
    y0 = torch.clamp(fy, 0, h - 1).long()
    y1 = torch.clamp(fy + 1, 0, h - 1).long()
    flat = src.reshape(n, c, h * w)

    def tap(yi: torch.Tensor, xi: torch.Tensor) -> torch.Tensor:
        idx = (yi * w + xi).reshape(n, 1, h * w).expand(n, c, h * w)
        return torch.gather(flat, 2, idx).reshape(n, c, h, w)

    out = _mix(_mix(tap(y0, x0), tap(y0, x1), tx), _mix(tap(y1, x0), tap(y1, x1), tx), ty)
    valid = valid.unsqueeze(1)
    out = torch.where(valid, out, torch.zeros_like(out))
    return out, valid.to(dt)


# ----------------------------------------------------------------------------- pooling / upsampling


def pool2x2(x: torch.Tensor, mode: str) -> torch.Tensor:
    """2x2 pooling, stride 2 ("max" or "avg"); H and W are even here."""
    if mode == "max":
        return F.max_pool2d(x, 2)
    if mode == "avg":
        return F.avg_pool2d(x, 2)
    raise ValueError(f"pool2x2: unknown mode {mode!r}")


def upsample2x(x: torch.Tensor, mode: str) -> torch.Tensor:
    """2x upsampling, F.interpolate(scale_factor=2, align_corners=False) semantics."""
    if mode == "bilinear":
        return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
    if mode == "nearest":
        return F.interpolate(x, scale_factor=2, mode="nearest")
    raise ValueError(f"upsample2x: unknown mode {mode!r}")


# ----------------------------------------------------------------------------- networks


def _conv(cin: int, cout: int) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, padding=1)


class TFA(nn.Module):
    """Temporal feature accumulator: reference net R, shared embedding net E, softmax blend."""

    def __init__(self, cfg: SSRConfig):
        super().__init__()
        h, k = cfg.tfa_hidden, cfg.k
        self.ref = nn.Sequential(_conv(A_CHANNELS + MT_CHANNELS, h), nn.ReLU(), _conv(h, k))
        self.emb = nn.Sequential(_conv(A_CHANNELS, h), nn.ReLU(), _conv(h, k))

    def forward(
        self, a_t: torch.Tensor, mt: torch.Tensor, warp_acc: torch.Tensor, warp_valid: torch.Tensor
    ) -> Dict[str, torch.Tensor]:
        r = self.ref(torch.cat([a_t, mt], dim=1))
        n = a_t.shape[0]
        emb = self.emb(torch.cat([a_t, warp_acc], dim=0))  # one pass over both (shared weights)
        emb_cur, emb_prev = emb[:n], emb[n:]
        s_cur = (emb_cur * r).sum(dim=1, keepdim=True)
        s_prev = (emb_prev * r).sum(dim=1, keepdim=True)
        m = torch.maximum(s_cur, s_prev)
        ea = torch.exp(s_prev - m)
        eb = torch.exp(s_cur - m)
        alpha = ea / (ea + eb)
        beta = eb / (ea + eb)
        ok = warp_valid > 0.5
        alpha = torch.where(ok, alpha, torch.zeros_like(alpha))
        beta = torch.where(ok, beta, torch.ones_like(beta))
        a_acc = alpha * warp_acc + beta * a_t
        return {
            "ref_feat": r,
            "emb_cur": emb_cur,
            "emb_prev": emb_prev,
            "tfa_weights": torch.cat([beta, alpha, s_cur, s_prev], dim=1),
            "a_acc": a_acc,
        }


class UNet(nn.Module):
    """3-level U-Net fed with the warped previous output at every scale. With a fourth width
    in `enc`, a fourth level at 1/8 resolution below the third, built alike:
    enc4 on the pooled enc3 and W(o) at 1/8, dec4 giving I4, and dec3 reading I4 upsampled
    between enc3 and W(o) at 1/4 (as dec2 reads I3); `grow_unet` makes one from a 3-level
    model's tensors that computes the same."""

    def __init__(self, cfg: SSRConfig):
        super().__init__()
        c1, c2, c3 = cfg.enc[:3]
        self.levels = len(cfg.enc)
        self.feature_pool = cfg.feature_pool
        self.upsample = cfg.upsample
        relu = nn.ReLU
        self.enc1 = nn.Sequential(_conv(cfg.input_channels, c1), relu(), _conv(c1, c1), relu())
        self.enc2 = nn.Sequential(_conv(c1 + RGB, c2), relu(), _conv(c2, c2), relu())
        self.enc3 = nn.Sequential(_conv(c2 + RGB, c3), relu(), _conv(c3, c3), relu())
        if self.levels == 4:
            c4 = cfg.enc[3]
            self.enc4 = nn.Sequential(_conv(c3 + RGB, c4), relu(), _conv(c4, c4), relu())
            self.dec4 = nn.Sequential(_conv(c4 + RGB, c4), relu(), _conv(c4, RGB))
        self.dec3 = nn.Sequential(_conv(c3 + RGB * (self.levels - 2), c3), relu(), _conv(c3, RGB))
        self.dec2 = nn.Sequential(_conv(c2 + RGB + RGB, c2), relu(), _conv(c2, RGB))
        self.dec1 = nn.Sequential(_conv(c1 + RGB + RGB, c1), relu(), _conv(c1, RGB))

    def forward(
        self, a_t: torch.Tensor, mt: torch.Tensor, a_acc: torch.Tensor, wo: torch.Tensor
    ) -> Dict[str, torch.Tensor]:
        wo2 = F.avg_pool2d(wo, 2)
        wo4 = F.avg_pool2d(wo2, 2)
        enc1 = self.enc1(torch.cat([a_t, mt, a_acc, wo], dim=1))
        enc2 = self.enc2(torch.cat([pool2x2(enc1, self.feature_pool), wo2], dim=1))
        enc3 = self.enc3(torch.cat([pool2x2(enc2, self.feature_pool), wo4], dim=1))
        deep: Dict[str, torch.Tensor] = {}
        if self.levels == 4:
            wo8 = F.avg_pool2d(wo4, 2)
            enc4 = self.enc4(torch.cat([pool2x2(enc3, self.feature_pool), wo8], dim=1))
            i4 = self.dec4(torch.cat([enc4, wo8], dim=1))
            deep = {"enc4": enc4, "i4": i4}
            i3 = self.dec3(torch.cat([enc3, upsample2x(i4, self.upsample), wo4], dim=1))
        else:
            i3 = self.dec3(torch.cat([enc3, wo4], dim=1))
        i2 = self.dec2(torch.cat([enc2, upsample2x(i3, self.upsample), wo2], dim=1))
        o = self.dec1(torch.cat([enc1, upsample2x(i2, self.upsample), wo], dim=1))
        return {"enc1": enc1, "enc2": enc2, "enc3": enc3, **deep, "i3": i3, "i2": i2, "o": o}


def grow_unet(state: Dict[str, torch.Tensor], model: "SSRModel") -> Dict[str, torch.Tensor]:
    """A 3-level model's `state` (state_dict) as a state_dict for 4-level `model` that computes
    the same: every tensor kept, the new level's as `model` has them, and dec3's first conv
    given zero weights for the upsampled I4 it now reads (its other input channels keep
    theirs), so the fourth level starts without effect and training brings it in."""
    if getattr(model.unet, "levels", 3) != 4:
        raise ValueError("grow_unet: the model has no fourth U-Net level (config `enc` with 4 widths)")
    out = {k: v.clone() for k, v in model.state_dict().items()}
    for k, v in state.items():
        if k not in out:
            raise ValueError(f"grow_unet: tensor {k} of the 3-level weights has no place in the 4-level model")
        if k == "unet.dec3.0.weight":
            c3 = model.cfg.enc[2]
            want = out[k].shape
            if v.shape != (want[0], c3 + RGB, *want[2:]):
                raise ValueError(f"grow_unet: {k} is {list(v.shape)}, expected {[want[0], c3 + RGB, *want[2:]]}")
            w = torch.zeros(want, dtype=v.dtype)
            w[:, :c3] = v[:, :c3]  # enc3
            w[:, c3 + RGB :] = v[:, c3:]  # W(o) at 1/4; the upsampled I4 between them stays 0
            out[k] = w
        elif v.shape != out[k].shape:
            raise ValueError(f"grow_unet: {k} is {list(v.shape)} in the 3-level weights, {list(out[k].shape)} here")
        else:
            out[k] = v.clone()
    return out


State = Tuple[torch.Tensor, torch.Tensor, torch.Tensor]
"""Recurrent state carried between frames: (A_acc_t [N, 15, H, W], o_t [N, 3, H, W],
exposure state [N, 9, 1, 1]: s_t and the ceiling's running max M_t, update_exposure)."""


class SSRModel(nn.Module):
    """TFA + U-Net. Parameter names: tfa.{ref,emb}.{0,2}.*, unet.{enc1..3,dec3..1}.{0,2}.*"""

    def __init__(self, cfg: Optional[SSRConfig] = None):
        super().__init__()
        self.cfg = cfg if cfg is not None else SSRConfig()
        self.tfa = TFA(self.cfg)
        self.unet = UNet(self.cfg)

    @property
    def pad_multiple(self) -> int:
        """What frame sides must be a multiple of (each U-Net level halves them): 4 with 3
        levels (as the engine pads), 8 with 4; `ssr.evaluate` and validation pad to it."""
        return 2 ** (len(self.cfg.enc) - 1)

    @property
    def extra_buffers(self) -> Tuple[str, ...]:
        """The buffers beyond data.BUFFERS this model reads (`extra_buffers`): `ssr.evaluate`
        and validation read them from each frame file (data.read_extra_buffers)."""
        return extra_buffers(self.cfg)

    def forward(self, frame: Dict[str, torch.Tensor], state: Optional[State] = None) -> Dict[str, object]:
        """Denoises one frame.

        frame: dict of NCHW buffers (FRAME_CHANNELS); state: (a_acc_prev, o_prev, exposure_prev)
        or None for the first frame of a sequence (then W(A_acc_prev) := A_t, valid := 1,
        W(o_prev) := 0).

        Returns a dict with `output` (radiance, [N, 3, H, W]), `state` (the next frame's state)
        and every intermediate: exposure, a_cur, mt, warp_acc, warp_valid, ref_feat, emb_cur,
        emb_prev, tfa_weights, a_acc, warp_out, enc1, enc2, enc3, i3, i2, o, albedo_mod. With config
        `ceiling = "max"`, o is the decoder's output clamped to `ceiling(exposure)`: the output
        (and the history) never exceeds the brightest demodulated sample of recent frames, so a
        tiny bright emitter cannot be extrapolated into a blown-up one.
        """
        frame = use_albedo(frame, self.cfg)
        h = self.history(frame, state)
        tfa = self.tfa(h["a_cur"], h["mt"], h["warp_acc"], h["warp_valid"])
        a_acc = tfa["a_acc"]
        net = self.unet(h["a_cur"], h["mt"], a_acc, h["warp_out"])
        if self.cfg.ceiling == "max":
            net["o"] = torch.minimum(net["o"], ceiling(h["exposure"]))
        albedo_mod = self.remodulation_albedo(h["a_cur"], a_acc)
        output = remodulate(net["o"], albedo_mod) * h["exposure"][:, :RGB]
        out: Dict[str, object] = {
            **h,
            **tfa,
            **net,
            "albedo_mod": albedo_mod,
            "output": output,
            "state": (a_acc, net["o"], h["exposure"]),
        }
        return out

    def remodulation_albedo(self, a_t: torch.Tensor, a_acc: torch.Tensor) -> torch.Tensor:
        """The albedo the output is remodulated with (config `remodulation`)."""
        return (a_t if self.cfg.remodulation == "current" else a_acc)[:, ALBEDO_SLICE]

    def history(self, frame: Dict[str, torch.Tensor], state: Optional[State]) -> Dict[str, torch.Tensor]:
        """Exposure, network inputs and the warped, checked, re-exposed history:
        {exposure, a_cur, mt, warp_acc, warp_valid, warp_out}."""
        _check_frame(frame)
        prev = None
        if state is not None:
            if len(state) != 3:
                raise ValueError(f"state: expected (a_acc, o, exposure), got a tuple of {len(state)}")
            a_acc_prev, o_prev, prev = state
        normalised = self.cfg.exposure != "none"
        if normalised:
            exposure = update_exposure(frame, prev, self.cfg.exposure == "shared")
        else:
            c = frame["color"]
            exposure = torch.ones(c.shape[0], STATE_EXPOSURE_CHANNELS, 1, 1, dtype=c.dtype, device=c.device)
        a_t, mt = prepare_inputs(frame, exposure if normalised else None)
        if state is None:
            warp_acc = a_t
            warp_valid = torch.ones_like(a_t[:, :1])
            wo = torch.zeros_like(a_t[:, :RGB])
        else:
            if a_acc_prev.shape != a_t.shape or o_prev.shape != a_t[:, :RGB].shape or prev.shape != exposure.shape:
                raise ValueError(
                    f"state: expected a_acc {list(a_t.shape)}, o {list(a_t[:, :RGB].shape)} and exposure "
                    f"{list(exposure.shape)}, got {list(a_acc_prev.shape)}, {list(o_prev.shape)} and {list(prev.shape)}"
                )
            # One warp of both histories: same motion, hence the same validity.
            warped, warp_valid = warp(torch.cat([a_acc_prev, o_prev], dim=1), frame["motion"])
            warp_acc, wo = warped[:, :A_CHANNELS], warped[:, A_CHANNELS:]
            if normalised:
                ratio = prev[:, :EXPOSURE_CHANNELS] / exposure[:, :EXPOSURE_CHANNELS]
                warp_acc = torch.cat(
                    [
                        rescale_log(warp_acc[:, E_SLICE], ratio[:, :RGB]),
                        warp_acc[:, E_SLICE.stop : SHADOW_SLICE.start],
                        rescale_log(warp_acc[:, SHADOW_SLICE], ratio[:, RGB:]),
                        warp_acc[:, SHADOW_SLICE.stop :],
                    ],
                    dim=1,
                )
                wo = rescale_log(wo, ratio[:, :RGB])
            if self.cfg.history == "geometry":
                ok = (warp_valid > 0.5) & history_consistent(warp_acc, a_t)
                warp_valid = ok.to(warp_valid.dtype)
                warp_acc = torch.where(ok, warp_acc, torch.zeros_like(warp_acc))
                wo = torch.where(ok, wo, torch.zeros_like(wo))
        return {"exposure": exposure, "a_cur": a_t, "mt": mt, "warp_acc": warp_acc, "warp_valid": warp_valid, "warp_out": wo}

    def run_sequence(
        self,
        frames: Sequence[Dict[str, torch.Tensor]],
        state: Optional[State] = None,
        detach_state: bool = False,
    ) -> List[Dict[str, object]]:
        """Runs consecutive frames (e.g. a 5-frame training sequence), carrying the state.

        Gradients flow through the state across frames unless `detach_state`.
        Returns the per-frame result dicts of `forward`.
        """
        results = []
        for frame in frames:
            r = self.forward(frame, state)
            state = r["state"]
            if detach_state:
                state = tuple(x.detach() for x in state)
            results.append(r)
        return results


# ----------------------------------------------------------------------------- cost


def conv_layers(cfg: SSRConfig) -> List[Tuple[str, int, int, int, int]]:
    """Every 3x3 conv evaluation per frame: (name, cin, cout, level, evaluations).

    level: 0 full resolution, 1 half, 2 quarter, 3 eighth. The embedding net runs twice per frame
    (on A_t and on W(A_acc_prev)).
    """
    h, k = cfg.tfa_hidden, cfg.k
    c1, c2, c3 = cfg.enc[:3]
    deep = cfg.enc[3:]
    level4 = [("unet.enc4.0", c3 + RGB, deep[0], 3, 1), ("unet.enc4.2", deep[0], deep[0], 3, 1),
              ("unet.dec4.0", deep[0] + RGB, deep[0], 3, 1), ("unet.dec4.2", deep[0], RGB, 3, 1)] if deep else []
    return [
        ("tfa.ref.0", A_CHANNELS + MT_CHANNELS, h, 0, 1),
        ("tfa.ref.2", h, k, 0, 1),
        ("tfa.emb.0", A_CHANNELS, h, 0, 2),
        ("tfa.emb.2", h, k, 0, 2),
        ("unet.enc1.0", cfg.input_channels, c1, 0, 1),
        ("unet.enc1.2", c1, c1, 0, 1),
        ("unet.enc2.0", c1 + RGB, c2, 1, 1),
        ("unet.enc2.2", c2, c2, 1, 1),
        ("unet.enc3.0", c2 + RGB, c3, 2, 1),
        ("unet.enc3.2", c3, c3, 2, 1),
        *level4,
        ("unet.dec3.0", c3 + RGB + (RGB if deep else 0), c3, 2, 1),
        ("unet.dec3.2", c3, RGB, 2, 1),
        ("unet.dec2.0", c2 + RGB + RGB, c2, 1, 1),
        ("unet.dec2.2", c2, RGB, 1, 1),
        ("unet.dec1.0", c1 + RGB + RGB, c1, 0, 1),
        ("unet.dec1.2", c1, RGB, 0, 1),
    ]


def flops_per_pixel(cfg: Optional[SSRConfig] = None) -> Tuple[float, List[Tuple[str, float]]]:
    """FLOPs per full-resolution pixel: 18 * cin * cout per 3x3 conv per output pixel
    (9 taps x multiply-add), divided by 4**level, times the evaluations per frame.
    Biases, activations, warps, pooling and the blend are not counted.

    Returns (total, [(layer name, flops per pixel), ...]).
    """
    cfg = cfg if cfg is not None else SSRConfig()
    per_layer = [(name, 18.0 * cin * cout * evals / 4**level) for name, cin, cout, level, evals in conv_layers(cfg)]
    return sum(f for _, f in per_layer), per_layer
