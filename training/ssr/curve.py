"""Learning curves of a training run: the training loss and the PSNR on a monitored split
(the held-out test scenes) against iterations, as a PNG and JSON.

    python -m ssr.curve --run RUN_DIR [RUN_DIR ...] --data ROOT [--split test] \\
        [--scenes S ...] [--frames 8] --out weights/ssr-training.png [--json curve.json] \\
        [--previous weights/ssr-training.json] [--point ITERATION=WEIGHTS ...]

Each run folder is one `ssr.train` run: its `log.jsonl` gives the training loss and the
validation PSNR (the val split, what the trainer sees), and its `snapshots/` (written with
`--snapshot-every`) are scored here on `--split` with the trainer's own validation routine
(every sequence from frame 0 with an empty history, whole frames padded like the engine,
PSNR on tonemapped 8-bit images). Several run folders are one campaign in order (a run
started with `--init` from the previous one's weights continues its iteration count).
Scores are cached per snapshot in `RUN_DIR/curve_cache.json` (keyed by split, frames, the
split's sequences and the snapshot's size and modification time: a split that gains
sequences is scored again), so re-plotting is cheap. A run started with
`--init` from an earlier session's weights continues its iteration count (the trainer logs
where it starts), and `--previous` draws that session's curve JSON in front. `--point`
scores a weights file at a campaign iteration as one more monitored point: the committed
weights of a run whose folder an earlier machine held (e.g. a rolling run's shipped
snapshots); `--run` may then be left out.

The monitored scores are for reporting only: nothing here feeds back into training or into
which weights are kept (held-out scenes never enter model selection).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from typing import Dict, List, Optional, Sequence

import torch

from .data import DatasetError, SequenceDataset
from .export import WeightsError, load_weights
from .validation import validate


def read_log(run: str) -> List[dict]:
    path = os.path.join(run, "log.jsonl")
    if not os.path.isfile(path):
        raise DatasetError(f"{path}: no training log (is {run} an ssr.train run folder?)")
    out = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError as err:
                raise DatasetError(f"{path}:{n}: not JSON ({err})") from err
    return out


def snapshots(run: str) -> List[str]:
    d = os.path.join(run, "snapshots")
    if not os.path.isdir(d):
        return []
    return sorted(os.path.join(d, f) for f in os.listdir(d) if f.startswith("it_") and f.endswith(".safetensors"))


def snapshot_iteration(path: str) -> int:
    return int(os.path.basename(path)[3:].split(".")[0])


def score_snapshot(path: str, ds: SequenceDataset, frames: int) -> dict:
    model, _ = load_weights(path)
    with torch.no_grad():
        # The network's own output, as every point since the first session (no output pass).
        m = validate(model, ds, torch.device("cpu"), frames, output_pass=False)
    return {
        "psnr": m["psnr"],
        "ssim": m["ssim"],
        "scenes": {k: {"psnr": v["psnr"], "ssim": v["ssim"]} for k, v in m["scenes"].items()},
    }


def group_of(scene: str) -> str:
    """Procedural scenes are reported as one group (their mean), named scenes by name."""
    return "procedural (mean)" if scene.startswith("procedural_") else scene


def monitored_point(iteration: int, s: dict) -> dict:
    """A monitored point from a snapshot's scores: the split's mean and each group's."""
    groups: Dict[str, List[float]] = {}
    for scene, m in s["scenes"].items():
        groups.setdefault(group_of(scene), []).append(m["psnr"])
    return {"iteration": iteration, "psnr": s["psnr"], "groups": {g: sum(v) / len(v) for g, v in sorted(groups.items())}}


def parse_point(spec: str) -> tuple:
    """`ITERATION=WEIGHTS` as (iteration, path), or ValueError naming the spec."""
    it, sep, path = spec.partition("=")
    if not sep or not it.strip().isdigit() or not path:
        raise ValueError(f"--point {spec!r}: expected ITERATION=WEIGHTS, e.g. 87500=weights/ssr.safetensors")
    return int(it), path


def curve(
    runs: List[str], data: str, split: str, scenes: Optional[List[str]], frames: int, say=print,
    points: Sequence[tuple] = (),
) -> dict:
    ds = SequenceDataset(data, split, window=1, crop=None, flips=False, scenes=scenes, cache="none")
    # the scored sequences belong to the cache key: a split that has grown is scored afresh
    seq_key = hashlib.sha256("\n".join(sorted(s.id for s in ds.sequences)).encode()).hexdigest()[:16]
    offset = 0
    train, val, monitored = [], [], []
    for run in runs:
        log = read_log(run)
        # a run started from an earlier run's weights continues that run's iteration count
        offset = max([offset] + [int(r.get("campaign_iterations", 0)) for r in log if r.get("event") == "init"])
        cache_path = os.path.join(run, "curve_cache.json")
        cache: Dict[str, dict] = {}
        if os.path.isfile(cache_path):
            try:
                cache = json.load(open(cache_path))
            except json.JSONDecodeError:
                cache = {}  # a broken cache is rebuilt
        for r in log:
            if r.get("event") == "train":
                train.append({"iteration": offset + r["iteration"], "loss": r["loss"]})
            elif r.get("event") == "val":
                val.append({"iteration": offset + r["iteration"], "psnr": r["psnr"]})
        last = max([r["iteration"] for r in log if "iteration" in r] or [0])
        for snap in snapshots(run):
            st = os.stat(snap)
            key = f"{split}|{frames}|{seq_key}|{os.path.basename(snap)}|{st.st_size}|{int(st.st_mtime)}"
            if key not in cache:
                say(f"scoring {snap} on {split} ({len(ds.sequences)} sequences)")
                cache[key] = score_snapshot(snap, ds, frames)
                tmp = cache_path + ".tmp"
                with open(tmp, "w") as f:
                    json.dump(cache, f)
                os.replace(tmp, cache_path)
            monitored.append(monitored_point(offset + snapshot_iteration(snap), cache[key]))
        offset += last
    for it, path in points:
        say(f"scoring {path} (iteration {it}) on {split} ({len(ds.sequences)} sequences)")
        monitored.append({**monitored_point(it, score_snapshot(path, ds, frames)), "weights": os.path.basename(path)})
    monitored.sort(key=lambda r: r["iteration"])
    return {"split": split, "frames": frames, "runs": runs, "train": train, "val": val, "monitored": monitored}


def with_previous(c: dict, previous: dict) -> dict:
    """`previous` (an earlier session's curve JSON: the same campaign) in front of `c`: its
    points before `c`'s first iteration are kept, so re-running in one session adds nothing
    twice."""
    if previous.get("split") != c["split"] or previous.get("frames") != c["frames"]:
        return c
    first = min([r["iteration"] for k in ("train", "val", "monitored") for r in c[k]] or [0])
    out = dict(c)
    for k in ("train", "val", "monitored"):
        out[k] = [r for r in previous.get(k, []) if r["iteration"] < first] + c[k]
    out["runs"] = [r for r in previous.get("runs", []) if r not in c["runs"]] + c["runs"]
    return out


def smooth(values: List[float], n: int) -> List[float]:
    out, acc = [], []
    for v in values:
        acc.append(v)
        if len(acc) > n:
            acc.pop(0)
        out.append(sum(acc) / len(acc))
    return out


def plot(c: dict, out: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2), dpi=100)
    if c["train"]:
        it = [r["iteration"] for r in c["train"]]
        loss = [r["loss"] for r in c["train"]]
        a.plot(it, loss, color="0.75", lw=0.8, label="loss (per log step)")
        a.plot(it, smooth(loss, 10), color="C0", lw=1.5, label="loss (10-step mean)")
        a.set_yscale("log")
    a.set_xlabel("iteration")
    a.set_ylabel("training loss")
    a.set_title("training loss")
    a.grid(alpha=0.3)
    a.legend(fontsize=8)
    if c["monitored"]:
        it = [r["iteration"] for r in c["monitored"]]
        groups = sorted({g for r in c["monitored"] for g in r["groups"]})
        for i, g in enumerate(groups):
            b.plot(it, [r["groups"].get(g, float("nan")) for r in c["monitored"]], marker=".", lw=1, color=f"C{i + 1}", label=g)
        b.plot(it, [r["psnr"] for r in c["monitored"]], marker="o", lw=2, color="k", label=f"{c['split']} mean")
    if c["val"]:
        b.plot([r["iteration"] for r in c["val"]], [r["psnr"] for r in c["val"]], ls="--", color="0.4", label="val split (trainer)")
    b.set_xlabel("iteration")
    b.set_ylabel("PSNR (dB, tonemapped 8-bit)")
    b.set_title(f"held-out PSNR ({c['split']} split, {c['frames']} frames per sequence)")
    b.grid(alpha=0.3)
    b.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ssr.curve", description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", nargs="+", default=[], help="ssr.train run folder(s), in training order")
    ap.add_argument(
        "--point", action="append", default=[], metavar="ITERATION=WEIGHTS",
        help="also score this weights file as the campaign's point at ITERATION (repeatable)",
    )
    ap.add_argument("--data", required=True, help="dataset root")
    ap.add_argument("--split", default="test", help="the monitored split (default test)")
    ap.add_argument("--scenes", nargs="+", default=None, help="monitor only these scenes")
    ap.add_argument("--frames", type=int, default=8, help="frames per sequence (from frame 0)")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--json", default=None, help="also write the figures as JSON")
    ap.add_argument("--title", default="SSR training", help="figure title")
    ap.add_argument(
        "--previous", default=None,
        help="an earlier session's --json of the same campaign, drawn in front (missing file: ignored)",
    )
    ap.add_argument("--threads", type=int, default=0, help="PyTorch CPU threads (0: default)")
    a = ap.parse_args(argv)
    if a.frames <= 0:
        ap.error("--frames must be positive")
    try:
        points = [parse_point(p) for p in a.point]
    except ValueError as err:
        ap.error(str(err))
    if not a.run and not points:
        ap.error("--run or --point: nothing to plot")
    for it, path in points:
        if not os.path.isfile(path):
            print(f"error: --point {it}={path}: no such weights file", file=sys.stderr)
            return 1
    if a.threads:
        torch.set_num_threads(a.threads)
    try:
        c = curve(a.run, a.data, a.split, a.scenes, a.frames, points=points)
    except (DatasetError, WeightsError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    if a.previous and os.path.isfile(a.previous):
        with open(a.previous) as f:
            c = with_previous(c, json.load(f))
    plot(c, a.out, a.title)
    print(f"wrote {a.out} ({len(c['train'])} loss points, {len(c['monitored'])} snapshots scored)")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(c, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
