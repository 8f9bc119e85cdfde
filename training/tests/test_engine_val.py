"""training/engine_val.sh with a stand-in `subpixel` (SUBPIXEL): which sequences it denoises
with which weights, where the outputs go, what it keeps on a second call, and its errors."""

import os
import stat
import subprocess

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "engine_val.sh")

# Records each call; `denoise` writes one output per input frame, `eval` prints its arguments.
FAKE = """#!/usr/bin/env bash
echo "$*" >> "$FAKE_LOG"
cmd="$1"; shift
case "$cmd" in
  denoise)
    while [ $# -gt 0 ]; do
      case "$1" in
        --weights) w="$2"; shift 2 ;;
        --input) i="$2"; shift 2 ;;
        --out) o="$2"; shift 2 ;;
        *) shift ;;
      esac
    done
    mkdir -p "$o"
    for f in "$i"/frame_*.exr; do echo "$w" > "$o/$(basename "$f")"; done
    ;;
  eval) echo "EVAL $*" ;;
esac
"""


def _dataset(root, names, frames=3, split="val"):
    for n in names:
        d = os.path.join(root, split, n)
        os.makedirs(d)
        for i in range(frames):
            open(os.path.join(d, f"frame_{i:04d}.exr"), "w").close()
        open(os.path.join(d, "sequence.json"), "w").write("{}")
    # A sequence still rendering (no sequence.json) is left out.
    os.makedirs(os.path.join(root, split, f"partial_{split}_000"))


def _env(tmp_path):
    fake = tmp_path / "subpixel"
    fake.write_text(FAKE)
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    return dict(os.environ, SUBPIXEL=str(fake), FAKE_LOG=str(tmp_path / "log"))


def _run(env, *args, **extra):
    return subprocess.run(["bash", SCRIPT, *args], capture_output=True, text=True, env=dict(env, **extra))


def _log(tmp_path):
    p = tmp_path / "log"
    return p.read_text().splitlines() if p.exists() else []


def test_denoises_every_val_sequence_per_weights_file_then_scores_them(tmp_path):
    data, pred = str(tmp_path / "ds"), str(tmp_path / "pred")
    _dataset(data, ["cbox_val_000", "procedural_500000_val_000"])
    env = _env(tmp_path)
    a, b = tmp_path / "a.safetensors", tmp_path / "b.safetensors"
    a.write_text("a")
    b.write_text("b")
    r = _run(env, data, pred, str(a), f"other={b}")
    assert r.returncode == 0, r.stderr
    for name, weights in [("a", a), ("other", b)]:
        for seq in ["cbox_val_000", "procedural_500000_val_000"]:
            out = os.path.join(pred, name, "val", seq)
            assert sorted(os.listdir(out)) == ["frame_0000.exr", "frame_0001.exr", "frame_0002.exr"]
            assert open(os.path.join(out, "frame_0002.exr")).read().strip() == str(weights)
    assert not os.path.exists(os.path.join(pred, "a", "val", "partial_val_000"))
    assert f"EVAL --table --pred {os.path.realpath(pred)} --ref {os.path.realpath(data)} --split val" in r.stdout
    assert sum(line.startswith("denoise") for line in _log(tmp_path)) == 4

    # A second call keeps what is complete, finishes what is not, and adds a row.
    os.remove(os.path.join(pred, "a", "val", "cbox_val_000", "frame_0001.exr"))
    c = tmp_path / "c.safetensors"
    c.write_text("c")
    (tmp_path / "log").unlink()
    r = _run(env, data, pred, str(a), str(b), str(c), PER_FRAME="1")
    assert r.returncode == 0, r.stderr
    calls = [line for line in _log(tmp_path) if line.startswith("denoise")]
    assert len(calls) == 1 + 2 + 2, calls  # a's damaged sequence, b (new name "b"), c
    assert len(os.listdir(os.path.join(pred, "a", "val", "cbox_val_000"))) == 3
    assert "--per-frame" in r.stdout


def test_extra_folders_join_the_table_as_links(tmp_path):
    data, pred = str(tmp_path / "ds"), str(tmp_path / "pred")
    _dataset(data, ["cbox_val_000"])
    env = _env(tmp_path)
    oidn = tmp_path / "oidn"
    (oidn / "oidn-b" / "val" / "cbox_val_000").mkdir(parents=True)
    (oidn / "notes").mkdir()  # no val split: not a method folder
    w = tmp_path / "w.safetensors"
    w.write_text("w")
    r = _run(env, data, pred, str(w), EXTRA=str(oidn))
    assert r.returncode == 0, r.stderr
    assert os.path.realpath(os.path.join(pred, "oidn-b")) == os.path.realpath(oidn / "oidn-b")
    assert not os.path.exists(os.path.join(pred, "notes"))


def test_missing_weights_and_datasets_are_named(tmp_path):
    data = str(tmp_path / "ds")
    _dataset(data, ["cbox_val_000"])
    env = _env(tmp_path)
    r = _run(env, data, str(tmp_path / "pred"), str(tmp_path / "none.safetensors"))
    assert r.returncode == 2 and "none.safetensors" in r.stderr
    r = _run(env, str(tmp_path), str(tmp_path / "pred"), "w.safetensors")
    assert r.returncode == 2 and "val" in r.stderr
    r = _run(env, data, str(tmp_path / "pred"))
    assert r.returncode == 2 and "weights" in r.stderr


def test_another_split_is_scored_the_same_way(tmp_path):
    # SPLIT=train: the train sequences are denoised into PRED/NAME/train and scored with
    # --split train; the val split is not touched (here there is none).
    data, pred = str(tmp_path / "ds"), str(tmp_path / "pred")
    _dataset(data, ["procedural_3_train_000", "cbox_train_000"], split="train")
    env = _env(tmp_path)
    w = tmp_path / "w.safetensors"
    w.write_text("w")
    r = _run(env, data, pred, str(w), SPLIT="train")
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(os.path.join(pred, "w", "train"))) == ["cbox_train_000", "procedural_3_train_000"]
    assert f"--split train" in r.stdout and "--split val" not in r.stdout
    r = _run(env, data, pred, str(w))
    assert r.returncode == 2 and f"{os.path.realpath(data)}/val" in r.stderr
