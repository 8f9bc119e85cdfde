"""Datasets rendered by `subpixel dataset` (DESIGN section 6): loading, windows, crops, flips.

Layout (the contract with the Rust renderer):

    ROOT/{train,val,test}/{sequence}/sequence.json
    ROOT/{train,val,test}/{sequence}/frame_NNNN.exr      (4 digits, from 0000)

`sequence.json` = {"scene", "split", "sequence", "frames", "width", "height", "spp", "seed",
"camera_path"}; `scene` is the scene's short name (`cornell` for `builtin:cornell`,
`staircase2` for `.../staircase2/scene.json`), the name `--scenes` selects. Every frame is one float32 multi-channel EXR with the channels of
EXR_CHANNELS (the buffers of DESIGN section 3 plus `reference`, the N-spp radiance).

`SequenceDataset` is a map-style torch Dataset whose index is a `WindowKey`
(sequence, first frame, crop origin, flips): the random choice of windows, crops and flips
is made by `WindowSampler` from (seed, rank, iteration) alone, so a resumed run sees exactly
the batches an uninterrupted one would, whatever DataLoader workers prefetch. An item is a
list of `window` per-frame dicts of CHW float32 tensors: the SSRModel.forward inputs
(FRAME_CHANNELS) plus `reference` [3, h, w]; the DataLoader's default collate makes them
NCHW.

Augmentation:
  * crops are `crop` x `crop` (a multiple of 4); a frame smaller than that is used whole,
    cut down to a multiple of 4. Crop origins are even, so the 2x2 tile grid of the 1/4-spp
    pattern stays aligned with the image (the pattern order the engine sees at run time).
  * a horizontal flip mirrors x and negates motion.x; a vertical flip mirrors y and negates
    motion.y (prev_pos = pos + motion holds in the flipped image, exactly, for the warp's
    pixel-centre convention). Normals are world-space and stay as they are. A flip permutes
    the tile pattern into one of its cyclic shifts (h) or its reverse (v); both keep the
    "diagonal, then vertical step" structure of the sequence.
  * sample thinning (`thin`, off by default): a window drawn with probability `thin` keeps
    each traced pixel's sample with probability `keep` (log-uniform in [THIN_KEEP_MIN, 1],
    one value per window) and divides a kept sample by `keep`; a dropped one becomes a
    traced pixel that found no light (color and shadow 0, mask still 1). The expectation of
    every pixel is unchanged, so the reference stays right: this is Russian roulette on the
    input samples. It shows the network scenes where most traced samples carry no light
    (an interior lit through its windows), which the rendered scenes rarely are.
  * colour permutation (`color_permute`, off by default): each window's RGB channels are
    permuted (one of the six orders, uniformly, one per window) in every RGB buffer alike
    (colour, albedo, shadow, tint, reference and the extra RGB buffers), the other buffers
    unchanged. Rendering is linear and per channel, so a permuted window is the render of a
    scene whose spectra are permuted: the reference stays right, and the network sees
    every colour of wall, light and sky in every channel (the losses and the tonemap treat
    the channels alike, `test_losses_do_not_see_a_colour_permutation`).

Non-finite values in every buffer but `motion` become 0 (the engine sanitises its inputs
the same way); non-finite motion is kept (the warp treats it as invalid).

Caching (`cache`):
  "none"    every read decodes the EXR (the whole frame, even for a crop);
  "memory"  decoded frames are kept in an LRU of `cache_mb` MiB per process (and per
            DataLoader worker);
  "disk"    each frame is decoded once into `cache_dir` (default ROOT/.cache) as an HWC
            float32 .npy that later reads memory-map, reading only the crop's rows. The
            right choice for large frames: decoding a 1080p EXR for a 256x256 crop is slow.
            A cache file older than its EXR is rebuilt.

CLI:  python -m ssr.data --data ROOT [--split S] [--check]    (summary; --check reads every
      frame header and reports every problem)
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import json
import os
import re
import sys
from dataclasses import dataclass
from typing import Dict, Iterator, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np
import torch

from .model import FRAME_CHANNELS

SPLITS = ("train", "val", "test")

SUFFIXES: Dict[str, Tuple[str, ...]] = {
    "color": ("R", "G", "B"),
    "mask": ("Y",),
    "albedo": ("R", "G", "B"),
    "normal": ("X", "Y", "Z"),
    "shadow": ("R", "G", "B"),
    "transparent": ("R", "G", "B"),
    "depth": ("Y",),
    "metallic": ("Y",),
    "roughness": ("Y",),
    "motion": ("X", "Y"),
    "reference": ("R", "G", "B"),
}
"""Buffer -> EXR channel suffixes, in order (channel name = f"{buffer}.{suffix}")."""

BUFFERS: Tuple[str, ...] = tuple(SUFFIXES)
"""Every buffer of a dataset frame: the model inputs (FRAME_CHANNELS) and `reference`."""

EXR_CHANNELS: Tuple[str, ...] = tuple(f"{b}.{s}" for b in BUFFERS for s in SUFFIXES[b])
"""The 24 channels of a dataset frame, in buffer order."""

CHANNEL_OFFSETS: Dict[str, Tuple[int, int]] = {}
_o = 0
for _b in BUFFERS:
    CHANNEL_OFFSETS[_b] = (_o, _o + len(SUFFIXES[_b]))
    _o += len(SUFFIXES[_b])
NUM_CHANNELS = _o
del _o, _b

EXTRA_SUFFIXES: Dict[str, Tuple[str, ...]] = {
    "full": ("R", "G", "B"),
    "reference_half": ("R", "G", "B"),
    "background": ("R", "G", "B"),
    "coverage": ("Y",),
    "albedo_footprint": ("R", "G", "B"),
    "emission": ("R", "G", "B"),
    "emission_footprint": ("R", "G", "B"),
    "escaped": ("Y",),
}
"""Buffers some datasets also hold, loaded on request (`SequenceDataset(extra=...)`): `full`
(the 1-spp frame of the recipe), `reference_half` (the mean of the reference's first half
of samples), `background` and `coverage` (the directly seen environment over each pixel's
footprint and the fraction that escapes: `subpixel dataset --background N`), and
`albedo_footprint` (the first-hit base colour averaged over the same footprint, sky 1:
written with the background since it existed, added to older frames by re-running the
same `dataset --background N` command), `emission` (the first-hit emission of each traced
pixel's own samples: the part of `color` that is emission seen directly) and
`emission_footprint` (the first-hit emission averaged over the background's footprint),
written with the background, added to older frames the same way, and `escaped` (the
fraction of each traced pixel's samples whose camera ray escaped to the environment, 0
where not traced), added to frames written before it by the same command with `--resume`
(`dataset_recipe.sh` with ONLY_EXISTING=1)."""


RGB_BUFFERS = frozenset(b for b, s in {**SUFFIXES, **EXTRA_SUFFIXES}.items() if s == ("R", "G", "B"))
"""The buffers that hold colours (R, G, B), which a colour permutation permutes."""

RGB_PERMUTATIONS: Tuple[Tuple[int, int, int], ...] = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))
"""The six channel orders of a colour permutation; index 0 is the identity."""


def read_extra_buffers(path: str, buffers: Sequence[str], why: str) -> Dict[str, "torch.Tensor"]:
    """{buffer: CHW float32 tensor} of the EXTRA_SUFFIXES `buffers` in frame file `path`,
    non-finite values as 0; a DatasetError naming the file, the missing channels and `why`
    (what reads them) when it lacks some."""
    import torch

    out = {}
    names = exr_size(path)[2] if buffers else []
    for b in buffers:
        channels = [f"{b}.{c}" for c in EXTRA_SUFFIXES[b]]
        missing = [c for c in channels if c not in names]
        if missing:
            raise DatasetError(f"{path}: missing channel(s) {missing}: {why}")
        arr = read_exr(path, channels)
        arr[~np.isfinite(arr)] = 0.0
        out[b] = torch.from_numpy(np.ascontiguousarray(arr.transpose(2, 0, 1)))
    return out


def layout(extra: Sequence[str] = ()) -> Tuple[Tuple[str, ...], Dict[str, Tuple[int, int]]]:
    """(EXR channels, buffer -> channel range) of frames with BUFFERS and then `extra`
    (names of EXTRA_SUFFIXES; a ValueError names an unknown one)."""
    unknown = [b for b in extra if b not in EXTRA_SUFFIXES]
    if unknown:
        raise ValueError(f"extra buffers must be among {sorted(EXTRA_SUFFIXES)}, got {unknown}")
    channels, offsets, o = list(EXR_CHANNELS), dict(CHANNEL_OFFSETS), NUM_CHANNELS
    for b in extra:
        sfx = EXTRA_SUFFIXES[b]
        channels += [f"{b}.{c}" for c in sfx]
        offsets[b] = (o, o + len(sfx))
        o += len(sfx)
    return tuple(channels), offsets

assert all(len(SUFFIXES[k]) == c for k, c in FRAME_CHANNELS.items())

SEQUENCE_KEYS = ("scene", "split", "sequence", "frames", "width", "height", "spp", "seed", "camera_path")
FRAME_RE = re.compile(r"^frame_(\d{4})\.exr$")


class DatasetError(ValueError):
    """A dataset folder that does not follow the layout: names the file and what is wrong."""


def frame_name(i: int) -> str:
    return f"frame_{i:04d}.exr"


# ----------------------------------------------------------------------------- EXR I/O


def _openexr():
    try:
        import OpenEXR  # noqa: F401
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("reading and writing EXR needs the `OpenEXR` package (pip install -r requirements.txt)") from err
    return OpenEXR


def write_exr(path: str, buffers: Dict[str, np.ndarray], suffixes: Optional[Dict[str, Sequence[str]]] = None, compression: str = "zip") -> None:
    """Writes float32 buffers [C, H, W] (or [H, W] for one channel) as one multi-channel EXR.

    Channel names are f"{buffer}.{suffix}" with the suffixes of `suffixes` (default SUFFIXES;
    a buffer not listed there needs them). Written atomically (temp file + rename).
    """
    OpenEXR = _openexr()
    sfx = dict(SUFFIXES)
    if suffixes:
        sfx.update({k: tuple(v) for k, v in suffixes.items()})
    channels = {}
    size = None
    for name, arr in buffers.items():
        a = np.asarray(arr, dtype=np.float32)
        if a.ndim == 2:
            a = a[None]
        if a.ndim != 3:
            raise ValueError(f"write_exr: `{name}` must be [C, H, W], got shape {list(a.shape)}")
        if name not in sfx or len(sfx[name]) != a.shape[0]:
            raise ValueError(f"write_exr: no channel suffixes for `{name}` with {a.shape[0]} channel(s)")
        if size is None:
            size = a.shape[1:]
        elif a.shape[1:] != size:
            raise ValueError(f"write_exr: `{name}` is {a.shape[2]}x{a.shape[1]}, other buffers {size[1]}x{size[0]}")
        for c, s in enumerate(sfx[name]):
            channels[f"{name}.{s}"] = np.ascontiguousarray(a[c])
    comp = {"zip": OpenEXR.ZIP_COMPRESSION, "none": OpenEXR.NO_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION}[compression]
    header = {"compression": comp, "type": OpenEXR.scanlineimage}
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    tmp = f"{path}.tmp{os.getpid()}.exr"
    with OpenEXR.File(header, channels) as f:
        f.write(tmp)
    os.replace(tmp, path)


def exr_size(path: str) -> Tuple[int, int, List[str]]:
    """(width, height, channel names) from the header only."""
    OpenEXR = _openexr()
    if not os.path.isfile(path):
        raise DatasetError(f"{path}: missing frame")
    try:
        with OpenEXR.File(path, separate_channels=True, header_only=True) as f:
            h = f.header()
            (x0, y0), (x1, y1) = h["dataWindow"]
            names = sorted(c.name for c in h["channels"]) if "channels" in h else []
    except DatasetError:
        raise
    except Exception as err:
        raise DatasetError(f"{path}: not a readable EXR ({err})") from None
    return int(x1 - x0 + 1), int(y1 - y0 + 1), names


def read_exr(path: str, channels: Sequence[str] = EXR_CHANNELS) -> np.ndarray:
    """Reads the named channels of an EXR into one float32 array [H, W, len(channels)].

    Raises DatasetError naming the file for a missing file, an unreadable file, or missing
    channels (all of them listed).
    """
    OpenEXR = _openexr()
    if not os.path.isfile(path):
        raise DatasetError(f"{path}: missing frame")
    try:
        with OpenEXR.File(path, separate_channels=True) as f:
            chans = f.channels()
            data = {k: v.pixels for k, v in chans.items()}
    except Exception as err:
        raise DatasetError(f"{path}: not a readable EXR ({err})") from None
    missing = [c for c in channels if c not in data]
    if missing:
        raise DatasetError(f"{path}: missing channel(s) {missing}")
    first = data[channels[0]]
    out = np.empty(first.shape + (len(channels),), dtype=np.float32)
    for i, c in enumerate(channels):
        px = data[c]
        if px.shape != first.shape:  # subsampled channels: not something we write
            raise DatasetError(f"{path}: channel `{c}` is {px.shape}, `{channels[0]}` is {first.shape}")
        out[..., i] = px
    return out


def sanitize_(frame: np.ndarray) -> np.ndarray:
    """In place: non-finite values of every buffer but motion become 0."""
    m0, m1 = CHANNEL_OFFSETS["motion"]
    for lo, hi in ((0, m0), (m1, frame.shape[-1])):
        part = frame[..., lo:hi]
        bad = ~np.isfinite(part)
        if bad.any():
            part[bad] = 0.0
    return frame


# ----------------------------------------------------------------------------- sequences


@dataclass
class SequenceInfo:
    """One sequence folder."""

    path: str
    split: str
    name: str  # folder name
    scene: str
    frames: int
    width: int
    height: int
    meta: dict

    def frame_path(self, i: int) -> str:
        return os.path.join(self.path, frame_name(i))

    @property
    def id(self) -> str:
        return f"{self.split}/{self.name}"


def read_sequence(path: str, split: Optional[str] = None) -> SequenceInfo:
    """Reads and checks `sequence.json` and that every frame file exists."""
    jpath = os.path.join(path, "sequence.json")
    if not os.path.isfile(jpath):
        raise DatasetError(f"{jpath}: missing sequence.json")
    try:
        with open(jpath) as f:
            meta = json.load(f)
    except (OSError, json.JSONDecodeError) as err:
        raise DatasetError(f"{jpath}: not valid JSON ({err})") from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{jpath}: expected a JSON object")
    missing = [k for k in SEQUENCE_KEYS if k not in meta]
    if missing:
        raise DatasetError(f"{jpath}: missing key(s) {missing}")
    for k in ("frames", "width", "height"):
        v = meta[k]
        if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
            raise DatasetError(f"{jpath}: `{k}` must be a positive integer, got {v!r}")
    if split is not None and meta["split"] != split:
        raise DatasetError(f"{jpath}: `split` is {meta['split']!r} but the folder is in {split!r}")
    absent = [frame_name(i) for i in range(meta["frames"]) if not os.path.isfile(os.path.join(path, frame_name(i)))]
    if absent:
        shown = ", ".join(absent[:5]) + (f" and {len(absent) - 5} more" if len(absent) > 5 else "")
        raise DatasetError(
            f"{os.path.join(path, absent[0])}: missing frame ({len(absent)} of {meta['frames']} missing in {path}: {shown})"
        )
    return SequenceInfo(
        path=path,
        split=str(meta["split"]),
        name=os.path.basename(os.path.normpath(path)),
        scene=str(meta["scene"]),
        frames=int(meta["frames"]),
        width=int(meta["width"]),
        height=int(meta["height"]),
        meta=meta,
    )


def reference_psnr(seq: SequenceInfo) -> float:
    """The mean PSNR between the two halves of a sequence's references (`reference_noise`
    of its sequence.json, written by `subpixel dataset`): how clean its references are.
    Raises DatasetError naming the file when it is missing or not a number."""
    rn = seq.meta.get("reference_noise")
    v = rn.get("mean_psnr_db") if isinstance(rn, dict) else None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise DatasetError(
            f"{os.path.join(seq.path, 'sequence.json')}: no `reference_noise.mean_psnr_db` (render it with a "
            "current `subpixel dataset`, or leave out the reference-noise threshold)"
        )
    return float(v)


def list_sequences(root: str, split: str, scenes: Optional[Sequence[str]] = None) -> List[SequenceInfo]:
    """Every sequence of ROOT/split (sorted by folder name), optionally only of `scenes`."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    d = os.path.join(root, split)
    if not os.path.isdir(d):
        raise DatasetError(f"{d}: no such split folder")
    seqs = []
    for name in sorted(os.listdir(d)):
        p = os.path.join(d, name)
        if os.path.isdir(p) and not name.startswith("."):
            seqs.append(read_sequence(p, split))
    if scenes:
        known = sorted({s.scene for s in seqs})
        unknown = [s for s in scenes if s not in known]
        if unknown:
            raise DatasetError(f"{d}: no sequences of scene(s) {unknown} (scenes here: {known})")
        seqs = [s for s in seqs if s.scene in set(scenes)]
    return seqs


# ----------------------------------------------------------------------------- frame store


class FrameStore:
    """Reads frames as HWC float32 arrays (EXR_CHANNELS), with the optional caches."""

    def __init__(
        self, root: str, cache: str = "none", cache_mb: float = 4096.0, cache_dir: Optional[str] = None, extra: Sequence[str] = ()
    ):
        if cache not in ("none", "memory", "disk"):
            raise ValueError(f"cache must be none|memory|disk, got {cache!r}")
        self.extra = tuple(extra)
        self.channels, self.offsets = layout(self.extra)
        self.root = root
        self.cache = cache
        self.cache_bytes = int(cache_mb * (1 << 20))
        self.cache_dir = cache_dir or os.path.join(root, ".cache")
        self._lru: "collections.OrderedDict[str, np.ndarray]" = collections.OrderedDict()
        self._lru_bytes = 0

    def _decode(self, seq: SequenceInfo, i: int) -> np.ndarray:
        path = seq.frame_path(i)
        arr = read_exr(path, self.channels)
        h, w = arr.shape[:2]
        if (w, h) != (seq.width, seq.height):
            raise DatasetError(
                f"{path}: frame is {w}x{h} but {os.path.join(seq.path, 'sequence.json')} says {seq.width}x{seq.height}"
            )
        return sanitize_(arr)

    def _disk_path(self, seq: SequenceInfo, i: int) -> str:
        tag = "".join(f"+{b}" for b in self.extra)
        return os.path.join(self.cache_dir, seq.split, seq.name, f"frame_{i:04d}{tag}.npy")

    def read(self, seq: SequenceInfo, i: int, rows: Optional[Tuple[int, int]] = None) -> np.ndarray:
        """Frame i as [H, W, 24 + extra channels] (or only rows[0]:rows[1] of it)."""
        if self.cache == "memory":
            key = seq.frame_path(i)
            arr = self._lru.get(key)
            if arr is None:
                arr = self._decode(seq, i)
                self._lru[key] = arr
                self._lru_bytes += arr.nbytes
                while self._lru_bytes > self.cache_bytes and len(self._lru) > 1:
                    _, old = self._lru.popitem(last=False)
                    self._lru_bytes -= old.nbytes
            else:
                self._lru.move_to_end(key)
        elif self.cache == "disk":
            arr = self._read_disk(seq, i)
        else:
            arr = self._decode(seq, i)
        return arr if rows is None else arr[rows[0] : rows[1]]

    def _read_disk(self, seq: SequenceInfo, i: int) -> np.ndarray:
        src = seq.frame_path(i)
        dst = self._disk_path(seq, i)
        try:
            fresh = os.path.getmtime(dst) >= os.path.getmtime(src)
        except OSError:
            fresh = False
        if fresh:
            try:
                arr = np.load(dst, mmap_mode="r")
                if arr.shape == (seq.height, seq.width, len(self.channels)) and arr.dtype == np.float32:
                    return arr
            except (OSError, ValueError):
                pass
        arr = self._decode(seq, i)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        tmp = f"{dst}.tmp{os.getpid()}.npy"
        np.save(tmp, arr)
        os.replace(tmp, dst)
        return np.load(dst, mmap_mode="r")


# ----------------------------------------------------------------------------- frames as tensors


def to_frame(arr: np.ndarray, offsets: Optional[Dict[str, Tuple[int, int]]] = None) -> Dict[str, torch.Tensor]:
    """HWC [h, w, 24 (+ extra)] -> dict of CHW float32 tensors (every buffer of BUFFERS, and
    the extra buffers of `offsets`, from `layout`)."""
    t = torch.from_numpy(np.ascontiguousarray(np.asarray(arr, dtype=np.float32).transpose(2, 0, 1)))
    return {b: t[lo:hi] for b, (lo, hi) in (offsets or CHANNEL_OFFSETS).items()}


def flip_frame(frame: Dict[str, torch.Tensor], hflip: bool, vflip: bool) -> Dict[str, torch.Tensor]:
    """Mirrors every CHW (or NCHW) buffer; negates motion.x (hflip) / motion.y (vflip)."""
    if not (hflip or vflip):
        return frame
    dims = ([-1] if hflip else []) + ([-2] if vflip else [])
    out = {k: torch.flip(v, dims) for k, v in frame.items()}
    if "motion" in out:
        m = out["motion"]
        sign = torch.tensor([-1.0 if hflip else 1.0, -1.0 if vflip else 1.0], dtype=m.dtype, device=m.device)
        out["motion"] = m * sign.view(*([1] * (m.dim() - 3)), 2, 1, 1)
    return out


def permute_colors(frame: Dict[str, torch.Tensor], perm: int) -> Dict[str, torch.Tensor]:
    """Reorders the channels of every RGB buffer (RGB_BUFFERS) of a CHW (or NCHW) frame by
    RGB_PERMUTATIONS[perm] (channel c of the result is channel order[c] of the input); the
    other buffers are returned as they are."""
    if perm == 0:
        return frame
    order = list(RGB_PERMUTATIONS[perm])
    return {k: (v[..., order, :, :] if k in RGB_BUFFERS else v) for k, v in frame.items()}


def pad_frame(frame: Dict[str, torch.Tensor], multiple: int = 4) -> Tuple[Dict[str, torch.Tensor], Tuple[int, int]]:
    """Pads NCHW buffers on the right/bottom to a multiple of `multiple` by replicating the edge
    (as wgsl/ssr/pack_inputs.wgsl does). Returns (padded frame, (h, w) of the original)."""
    any_t = next(iter(frame.values()))
    h, w = any_t.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph == 0 and pw == 0:
        return frame, (h, w)
    out = {}
    for k, v in frame.items():
        x = v if v.dim() == 4 else v.unsqueeze(0)
        x = torch.nn.functional.pad(x, (0, pw, 0, ph), mode="replicate")
        out[k] = x if v.dim() == 4 else x[0]
    return out, (h, w)


# ----------------------------------------------------------------------------- windows


class WindowKey(NamedTuple):
    seq: int  # index into the dataset's sequences
    start: int  # first frame of the window
    y0: int
    x0: int
    hflip: bool
    vflip: bool
    keep: float = 1.0  # sample thinning: probability of keeping a traced sample (1: off)
    thin_seed: int = 0  # seeds the keep/drop choices of a thinned window
    perm: int = 0  # colour permutation: index into RGB_PERMUTATIONS (0: none)


# Smallest fraction of traced samples a thinned window keeps.
THIN_KEEP_MIN = 0.1


def thin_frame(frame: Dict[str, torch.Tensor], keep: float, g: torch.Generator) -> Dict[str, torch.Tensor]:
    """Russian roulette on the traced samples of one CHW frame: each traced pixel (mask >
    0.5) keeps its sample with probability `keep`, divided by `keep`; a dropped one gets
    color 0 and shadow 0 (a traced path that found no light). Other buffers unchanged."""
    if keep >= 1.0:
        return frame
    if not (0.0 < keep):
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    traced = frame["mask"] > 0.5
    u = torch.rand(traced.shape, generator=g)
    kept = (u < keep) & traced
    dropped = traced & ~kept
    out = dict(frame)
    out["color"] = torch.where(kept, frame["color"] / keep, torch.where(dropped, torch.zeros_like(frame["color"]), frame["color"]))
    out["shadow"] = torch.where(dropped, torch.zeros_like(frame["shadow"]), frame["shadow"])
    return out


def effective_crop(seqs: Sequence[SequenceInfo], crop: Optional[int]) -> Tuple[int, int]:
    """(crop_h, crop_w): `crop` (a multiple of 4) or, where a frame is smaller, the largest
    multiple of 4 that fits every sequence (one size per batch). crop None: whole frames."""
    if crop is not None and (crop <= 0 or crop % 4):
        raise ValueError(f"crop must be a positive multiple of 4, got {crop}")
    min_h = min(s.height for s in seqs)
    min_w = min(s.width for s in seqs)
    if min_h < 4 or min_w < 4:
        small = min(seqs, key=lambda s: min(s.width, s.height))
        raise DatasetError(f"{small.path}: frames of {small.width}x{small.height} are smaller than 4x4")
    ch, cw = min_h // 4 * 4, min_w // 4 * 4
    if crop is not None:
        ch, cw = min(crop, ch), min(crop, cw)
    return ch, cw


def check_uniform(seqs: Sequence[SequenceInfo], whole_frames: bool) -> None:
    """One split is one kind of data: every sequence's reference has the same sample count
    (`spp`), and with whole frames (no crop) every frame has the same size. Raises
    DatasetError naming the two `sequence.json` files that differ."""
    if not seqs:
        return
    first = seqs[0]
    for s in seqs[1:]:
        if s.meta.get("spp") != first.meta.get("spp"):
            raise DatasetError(
                f"{os.path.join(s.path, 'sequence.json')}: spp {s.meta.get('spp')}, but "
                f"{os.path.join(first.path, 'sequence.json')} has spp {first.meta.get('spp')}: "
                f"one split must not mix reference sample counts"
            )
        if whole_frames and (s.width, s.height) != (first.width, first.height):
            raise DatasetError(
                f"{os.path.join(s.path, 'sequence.json')}: {s.width}x{s.height} frames, but "
                f"{os.path.join(first.path, 'sequence.json')} has {first.width}x{first.height}: "
                f"whole-frame splits must not mix sizes"
            )


class SequenceDataset(torch.utils.data.Dataset):
    """Windows of `window` consecutive frames of the sequences in ROOT/split.

    Index with a WindowKey (see WindowSampler) or an int (deterministic: window i of the
    list of every window, top-left crop, no flips). Items are lists of per-frame dicts of
    CHW float32 tensors (FRAME_CHANNELS + `reference`, + the `extra` buffers asked for:
    names of EXTRA_SUFFIXES; a frame without them is a DatasetError naming it).
    """

    def __init__(
        self,
        root: str,
        split: str = "train",
        window: int = 5,
        crop: Optional[int] = 256,
        flips: bool = True,
        scenes: Optional[Sequence[str]] = None,
        cache: str = "none",
        cache_mb: float = 4096.0,
        cache_dir: Optional[str] = None,
        thin: float = 0.0,
        thin_keep_min: float = THIN_KEEP_MIN,
        extra: Sequence[str] = (),
        min_reference_psnr: Optional[float] = None,
        color_permute: bool = False,
    ):
        self.root = root
        self.color_permute = bool(color_permute)
        self.split = split
        self.window = int(window)
        self.flips = flips
        if not (0.0 <= thin <= 1.0):
            raise ValueError(f"thin must be a probability in [0, 1], got {thin}")
        self.thin = float(thin)
        if not (0.0 < thin_keep_min <= 1.0):
            raise ValueError(f"thin_keep_min must be in (0, 1], got {thin_keep_min}")
        self.thin_keep_min = float(thin_keep_min)
        self.sequences = list_sequences(root, split, scenes)
        if not self.sequences:
            raise DatasetError(f"{os.path.join(root, split)}: no sequences")
        # Sequences left out for their reference noise (sequence.json's `reference_noise`).
        self.noisy: List[SequenceInfo] = []
        if min_reference_psnr is not None:
            kept = []
            for s in self.sequences:
                if reference_psnr(s) < min_reference_psnr:
                    self.noisy.append(s)
                else:
                    kept.append(s)
            if not kept:
                raise DatasetError(
                    f"{os.path.join(root, split)}: every sequence's reference noise is below {min_reference_psnr} dB"
                )
            self.sequences = kept
        short = [s for s in self.sequences if s.frames < self.window]
        if short:
            raise DatasetError(
                f"{os.path.join(short[0].path, 'sequence.json')}: {short[0].frames} frame(s), fewer than the window of {self.window}"
            )
        check_uniform(self.sequences, whole_frames=crop is None)
        self.crop_hw = effective_crop(self.sequences, crop)
        self.store = FrameStore(root, cache, cache_mb, cache_dir, extra)
        # (seq index, start) of every window, for int indexing and sampling proportional to length
        self.windows: List[Tuple[int, int]] = [
            (si, t) for si, s in enumerate(self.sequences) for t in range(s.frames - self.window + 1)
        ]

    @property
    def scenes(self) -> List[str]:
        return sorted({s.scene for s in self.sequences})

    def __len__(self) -> int:
        return len(self.windows)

    def random_key(self, g: torch.Generator) -> WindowKey:
        """A uniformly random window (over every window of every sequence), crop, flips and,
        with `thin` > 0, sample thinning, then with `color_permute` a colour permutation
        (each drawn after the rest, so with them off the draws are exactly what they always
        were)."""
        si, start = self.windows[int(torch.randint(len(self.windows), (1,), generator=g))]
        s = self.sequences[si]
        ch, cw = self.crop_hw
        # even origins keep the 2x2 tile grid aligned
        y0 = 2 * int(torch.randint((s.height - ch) // 2 + 1, (1,), generator=g))
        x0 = 2 * int(torch.randint((s.width - cw) // 2 + 1, (1,), generator=g))
        hf = vf = False
        if self.flips:
            hf, vf = (bool(v) for v in torch.randint(2, (2,), generator=g))
        keep, thin_seed = 1.0, 0
        if self.thin > 0.0:
            u, v = torch.rand(2, generator=g, dtype=torch.float64).tolist()
            if u < self.thin:
                keep = float(self.thin_keep_min ** (1.0 - v))  # log-uniform in [thin_keep_min, 1]
                thin_seed = int(torch.randint(1 << 62, (1,), generator=g))
        perm = int(torch.randint(len(RGB_PERMUTATIONS), (1,), generator=g)) if self.color_permute else 0
        return WindowKey(si, start, y0, x0, hf, vf, keep, thin_seed, perm)

    def load(self, key: WindowKey) -> List[Dict[str, torch.Tensor]]:
        s = self.sequences[key.seq]
        ch, cw = self.crop_hw
        if not (0 <= key.start and key.start + self.window <= s.frames):
            raise IndexError(f"{s.path}: window {key.start}..{key.start + self.window} out of {s.frames} frames")
        if key.y0 + ch > s.height or key.x0 + cw > s.width or key.y0 < 0 or key.x0 < 0:
            raise IndexError(f"{s.path}: crop {cw}x{ch} at ({key.x0}, {key.y0}) outside {s.width}x{s.height}")
        frames = []
        g = torch.Generator().manual_seed(key.thin_seed) if key.keep < 1.0 else None
        for t in range(key.start, key.start + self.window):
            arr = self.store.read(s, t, rows=(key.y0, key.y0 + ch))[:, key.x0 : key.x0 + cw]
            frame = to_frame(arr, self.store.offsets)
            if g is not None:
                frame = thin_frame(frame, key.keep, g)
            frame = permute_colors(frame, key.perm)
            frames.append(flip_frame(frame, key.hflip, key.vflip))
        return frames

    def __getitem__(self, index) -> List[Dict[str, torch.Tensor]]:
        if isinstance(index, WindowKey):
            return self.load(index)
        if isinstance(index, (tuple, list)) and len(index) in (6, 8, 9):
            return self.load(WindowKey(*index))
        si, start = self.windows[int(index)]
        return self.load(WindowKey(si, start, 0, 0, False, False))

    def full_frame(self, seq: int, t: int) -> Dict[str, torch.Tensor]:
        """Frame t of sequence `seq`, whole (uncropped, unflipped), CHW tensors."""
        return to_frame(self.store.read(self.sequences[seq], t), self.store.offsets)


def window_seed(seed: int, rank: int, iteration: int) -> int:
    """A 63-bit seed from (seed, rank, iteration), independent of the process or Python."""
    h = hashlib.blake2b(f"subpixel/{seed}/{rank}/{iteration}".encode(), digest_size=8).digest()
    return int.from_bytes(h, "little") & ((1 << 63) - 1)


class WindowSampler(torch.utils.data.Sampler):
    """Batch sampler: for iterations start..stop-1 yields `batch` WindowKeys each, drawn
    from a generator seeded by (seed, rank, iteration) only (see window_seed)."""

    def __init__(self, dataset: SequenceDataset, batch: int, start: int, stop: int, seed: int = 0, rank: int = 0):
        self.dataset = dataset
        self.batch = int(batch)
        self.start, self.stop = int(start), int(stop)
        self.seed, self.rank = int(seed), int(rank)

    def keys(self, iteration: int) -> List[WindowKey]:
        g = torch.Generator().manual_seed(window_seed(self.seed, self.rank, iteration))
        return [self.dataset.random_key(g) for _ in range(self.batch)]

    def __iter__(self) -> Iterator[List[WindowKey]]:
        for it in range(self.start, self.stop):
            yield self.keys(it)

    def __len__(self) -> int:
        return max(0, self.stop - self.start)


def collate(items: List[List[Dict[str, torch.Tensor]]]) -> List[Dict[str, torch.Tensor]]:
    """Stacks a batch of windows into a list of per-frame dicts of NCHW tensors."""
    return [{k: torch.stack([it[t][k] for it in items]) for k in items[0][t]} for t in range(len(items[0]))]


def check_dataset(root: str, splits: Sequence[str] = SPLITS) -> List[str]:
    """Reads every frame header; returns a list of problems (empty when the dataset is sound)."""
    problems = []
    for split in splits:
        if not os.path.isdir(os.path.join(root, split)):
            continue
        d = os.path.join(root, split)
        for name in sorted(os.listdir(d)):
            p = os.path.join(d, name)
            if not os.path.isdir(p) or name.startswith("."):
                continue
            try:
                s = read_sequence(p, split)
            except DatasetError as err:
                problems.append(str(err))
                continue
            for i in range(s.frames):
                fp = s.frame_path(i)
                try:
                    w, h, names = exr_size(fp)
                except DatasetError as err:
                    problems.append(str(err))
                    continue
                missing = [c for c in EXR_CHANNELS if c not in names]
                if missing:
                    problems.append(f"{fp}: missing channel(s) {missing}")
                if (w, h) != (s.width, s.height):
                    problems.append(f"{fp}: frame is {w}x{h} but sequence.json says {s.width}x{s.height}")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.data", description="Summarise (and check) a dataset.")
    ap.add_argument("--data", required=True, help="dataset root (ROOT/{train,val,test}/SEQUENCE/)")
    ap.add_argument("--check", action="store_true", help="read every frame header and report every problem")
    args = ap.parse_args(argv)
    for split in SPLITS:
        if not os.path.isdir(os.path.join(args.data, split)):
            print(f"{split:5s}: (none)")
            continue
        try:
            seqs = list_sequences(args.data, split)
        except DatasetError as err:
            print(f"{split:5s}: error: {err}")
            continue
        scenes = collections.Counter(s.scene for s in seqs)
        frames = sum(s.frames for s in seqs)
        sizes = sorted({f"{s.width}x{s.height}" for s in seqs})
        print(f"{split:5s}: {len(seqs)} sequences, {frames} frames, sizes {sizes}, scenes {dict(sorted(scenes.items()))}")
    if args.check:
        problems = check_dataset(args.data)
        for p in problems:
            print(f"error: {p}")
        print("ok" if not problems else f"{len(problems)} problem(s)")
        return 1 if problems else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
