"""Intel Open Image Denoise (OIDN 2.5, CPU) as a baseline (issue 11), for evaluate.py.

Two rows of the Table 1 command, both single-frame (no history of their own):

  oidn-a  OIDN on the hold-filled 1/4-spp colour (baselines.HoldBaseline: each untraced
          pixel holds its last traced sample): exactly the samples SSR gets.
  oidn-b  OIDN on a 1-spp full-resolution frame of the same camera (four times the
          samples): the channels `full.R full.G full.B` of each dataset frame. A frame
          without them is an error naming the file and the missing channels.

`oidn-a-footprint` and `oidn-b-footprint` are the same with the footprint albedo
(`albedo_footprint`, the first-hit albedo averaged over each pixel) as OIDN's albedo image:
OIDN wants its auxiliary images filtered over the pixel like the colour, and the shipped
SSR model runs on that albedo, so these are the like-for-like rows against it.

`oidn-a-footprint-escaped` is oidn-a-footprint given what an SSR model of config
`escaped = "background"` is given: the frame without its traced pixels whose samples
escaped to the environment (model.fold_emission: colour and mask 0, so the hold fill keeps
the pixel's last sample that hit the scene), and OIDN's output composited with the
background as the engine's output pass does, `background + (1 - coverage) x output`
(evaluate.py does both, from the model's `cfg`). Without the fold, a composited method
counts the sky of a silhouette twice (once in the background, once in the samples it
denoises), so `OIDN (a) + background` rows (background_probe.py) are too bright there;
this row is the fair one against such a model. It reads the frames' `escaped`,
`background` and `coverage` buffers (`subpixel dataset --background N`).

Both use OIDN's "RT" filter with the clean auxiliary images every dataset frame has: the
first-hit albedo (clamped to [0, 1], as OIDN expects) and the world-space shading normal
(in [-1, 1], as it is; 0 on the sky), `hdr=True` (linear HDR radiance, negative and
non-finite values as 0) and `cleanAux=True` (the G-buffers are traced at the pixel centre,
noise-free), quality "high", OIDN's automatic input scale. The images go to
`pyoidn.denoise` as NumPy float32 HWC arrays, which pyoidn runs on an OIDN CPU device (a
CUDA tensor would select its CUDA device: we never pass one). Frames are not padded.

Needs the `pyoidn` package (Python bindings bundling OIDN 2.5.1, a ~90 MB wheel, in
requirements.txt). Without it, building either model raises OIDNUnavailable naming the
package and the pip command.

CLI (for table1.sh):  python -m ssr.oidn --has-full FRAME.exr   exit 0 if the frame has the
                      `full` channels, 1 (with the missing ones on stderr) if not.
"""

from __future__ import annotations

import argparse
import sys
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
from torch import nn

from .baselines import HoldBaseline, _clean
from .data import EXTRA_SUFFIXES, DatasetError, exr_size, read_exr
from .model import ESCAPED, SSRConfig

FULL_CHANNELS = ("full.R", "full.G", "full.B")
"""Channels of the 1-spp full-resolution colour that oidn-b denoises."""

FOOTPRINT_CHANNELS = ("albedo_footprint.R", "albedo_footprint.G", "albedo_footprint.B")
"""Channels of the footprint albedo the `-footprint` rows give OIDN as its albedo image."""

ESCAPED_CHANNELS = tuple(f"{b}.{c}" for b in ESCAPED for c in EXTRA_SUFFIXES[b])
"""Channels the `-escaped` row reads: the samples' escapes, the background and its coverage."""

PIP_INSTALL = "~/.cache/subpixel/venv/bin/pip install pyoidn==2.5.1.0"
QUALITY = "high"


class OIDNUnavailable(ImportError):
    """`pyoidn` is not installed (or its OIDN library does not load)."""


def import_pyoidn():
    """The `pyoidn` module, or OIDNUnavailable with the pip command."""
    try:
        import pyoidn
    except (ImportError, OSError) as err:
        raise OIDNUnavailable(
            f"the OIDN baselines need the Python package `pyoidn` (Intel Open Image Denoise 2.5): "
            f"{PIP_INSTALL}  (or: pip install -r training/requirements.txt)  [import failed: {err}]"
        ) from None
    return pyoidn


def pyoidn_versions() -> Dict[str, str]:
    """{"pyoidn": package version, "oidn": bundled library version} (after import_pyoidn)."""
    from importlib import metadata

    out = {}
    try:
        out["pyoidn"] = metadata.version("pyoidn")
    except metadata.PackageNotFoundError:
        out["pyoidn"] = "unknown"
    try:
        from pyoidn import version

        out["oidn"] = str(version.oidn_version)
    except ImportError:
        out["oidn"] = "unknown"
    return out


def missing_full_channels(path: str) -> List[str]:
    """The `full.*` channels a frame file lacks (header only; DatasetError if unreadable)."""
    _, _, names = exr_size(path)
    return [c for c in FULL_CHANNELS if c not in names]


def read_full(path: str) -> Dict[str, torch.Tensor]:
    """{"full": [3, H, W]} from a frame file, non-finite values as 0. DatasetError naming
    the file and the missing channels when it has no 1-spp frame."""
    missing = missing_full_channels(path)
    if missing:
        raise DatasetError(
            f"{path}: missing channel(s) {missing}: oidn-b denoises the 1-spp full-resolution frame "
            f"stored as {' '.join(FULL_CHANNELS)} (render the dataset with a `subpixel dataset` that writes them)"
        )
    arr = read_exr(path, FULL_CHANNELS)
    arr[~np.isfinite(arr)] = 0.0
    return {"full": torch.from_numpy(np.ascontiguousarray(arr.transpose(2, 0, 1)))}


def _hwc(x: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())


def denoise(color: torch.Tensor, albedo: torch.Tensor, normal: torch.Tensor, pyoidn=None) -> torch.Tensor:
    """OIDN (RT filter, CPU, HDR, clean albedo + normal, quality high) on NCHW tensors;
    returns the denoised colour on color's device."""
    pyoidn = pyoidn or import_pyoidn()
    color = _clean(color)
    albedo = torch.clamp(_clean(albedo), max=1.0)
    normal = torch.nan_to_num(normal, nan=0.0, posinf=0.0, neginf=0.0).clamp(-1.0, 1.0)
    out = []
    for i in range(color.shape[0]):
        res = pyoidn.denoise(_hwc(color[i]), _hwc(albedo[i]), _hwc(normal[i]), hdr=True, clean_aux=True, quality=QUALITY)
        out.append(torch.from_numpy(np.asarray(res, dtype=np.float32)).permute(2, 0, 1))
    return torch.stack(out).to(color.device)


class OIDNBaseline(nn.Module):
    """OIDN per frame on the hold-filled 1/4-spp colour (`source="hold"`, oidn-a) or on the
    1-spp full-resolution colour (`source="full"`, oidn-b). forward(frame, state) like the
    other models; the frame of oidn-b needs a `full` buffer (`extra_buffers`)."""

    pad_multiple = 1  # OIDN takes any size: evaluate.py does not pad

    def __init__(self, source: str, albedo: str = "centre", escaped: bool = False):
        super().__init__()
        if source not in ("hold", "full"):
            raise ValueError(f"OIDN source must be 'hold' or 'full', got {source!r}")
        if albedo not in ("centre", "footprint"):
            raise ValueError(f"OIDN albedo must be 'centre' or 'footprint', got {albedo!r}")
        if escaped and source != "hold":
            raise ValueError("OIDN escaped: only the hold-filled 1/4-spp source has traced samples to leave out")
        self.source = source
        self.albedo = albedo
        self.escaped = escaped
        # evaluate.py folds the frame and composites the output by the model's config: the
        # escaped samples left out, the background composited (no emission fold, no mean
        # correction: the defaults)
        self.cfg = SSRConfig(escaped="background") if escaped else None
        self.NAME = (
            ("oidn-a" if source == "hold" else "oidn-b")
            + ("-footprint" if albedo == "footprint" else "")
            + ("-escaped" if escaped else "")
        )
        self.pyoidn = import_pyoidn()
        self.hold = HoldBaseline() if source == "hold" else None

    def info(self) -> dict:
        return {
            "format": f"non-learned-{self.NAME}",
            "weights": None,
            "oidn": {**pyoidn_versions(), "device": "cpu", "filter": "RT", "hdr": True, "cleanAux": True,
                     "quality": QUALITY, "aux": ["albedo" if self.albedo == "centre" else "albedo_footprint", "normal"],
                     "input": self.source, "escaped": "background" if self.escaped else "network"},
        }  # fmt: skip

    @property
    def extra_buffers(self) -> Tuple[str, ...]:
        """Buffers beyond the dataset's standard ones this model reads from each frame file:
        the 1-spp frame (oidn-b), the footprint albedo (the `-footprint` rows), the escapes,
        background and coverage (the `-escaped` row)."""
        return (
            (("full",) if self.source == "full" else ())
            + (("albedo_footprint",) if self.albedo == "footprint" else ())
            + (ESCAPED if self.escaped else ())
        )

    def check_frames(self, paths: List[str]) -> None:
        """Fails early (DatasetError naming the first file and its missing channels) when a
        frame lacks what this model reads."""
        want = (
            (FULL_CHANNELS if self.source == "full" else ())
            + (FOOTPRINT_CHANNELS if self.albedo == "footprint" else ())
            + (ESCAPED_CHANNELS if self.escaped else ())
        )
        if not want:
            return

        def lacking(p: str) -> List[str]:
            names = exr_size(p)[2]
            return [c for c in want if c not in names]

        for p in paths:
            missing = lacking(p)
            if missing:
                bad = sum(1 for q in paths if lacking(q))
                raise DatasetError(
                    f"{p}: missing channel(s) {missing} ({bad} of {len(paths)} frames lack them): {self.NAME} reads "
                    f"{' '.join(want)} (the 1-spp frame: `full`; the footprint albedo, background and escapes: "
                    "`subpixel dataset --background N`, escapes added to older frames with --resume)"
                )

    def forward(self, frame: Dict[str, torch.Tensor], state=None) -> Dict[str, object]:
        if self.source == "hold":
            h = self.hold(frame, state)
            color, new_state = h["output"], h["state"]
        else:
            if "full" not in frame:
                raise KeyError("oidn-b: the frame has no `full` buffer (the 1-spp colour, channels full.R full.G full.B)")
            color, new_state = frame["full"], None
        if color.dim() == 3:
            color = color.unsqueeze(0)
        albedo = frame["albedo_footprint"] if self.albedo == "footprint" else frame["albedo"]
        out = denoise(color, albedo, frame["normal"], self.pyoidn)
        return {"output": out, "input": color, "state": new_state}


def oidn_a() -> OIDNBaseline:
    return OIDNBaseline("hold")


def oidn_b() -> OIDNBaseline:
    return OIDNBaseline("full")


OIDN_MODELS = {
    "oidn-a": oidn_a,
    "oidn-b": oidn_b,
    "oidn-a-footprint": lambda: OIDNBaseline("hold", "footprint"),
    "oidn-b-footprint": lambda: OIDNBaseline("full", "footprint"),
    "oidn-a-footprint-escaped": lambda: OIDNBaseline("hold", "footprint", escaped=True),
}


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.oidn", description="OIDN baseline helpers.")
    ap.add_argument("--has-full", metavar="FRAME", required=True, help="exit 0 if FRAME has full.R full.G full.B")
    a = ap.parse_args(argv)
    try:
        missing = missing_full_channels(a.has_full)
    except DatasetError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if missing:
        print(f"{a.has_full}: no 1-spp frame (missing {' '.join(missing)})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
