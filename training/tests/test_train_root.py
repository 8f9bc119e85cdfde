import os
import subprocess

import pytest

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "train_root.sh")


def _sequence(root, name, frames=8, json=True):
    d = os.path.join(root, "train", name)
    os.makedirs(d)
    for i in range(frames):
        open(os.path.join(d, f"frame_{i:04d}.exr"), "w").close()
    if json:
        open(os.path.join(d, "sequence.json"), "w").write("{}")
    return d


def _run(*args):
    return subprocess.run(["bash", SCRIPT, *args], capture_output=True, text=True)


def test_links_complete_sequences_and_repeats_the_sparse_light_ones(tmp_path):
    src = str(tmp_path / "ds")
    done = _sequence(src, "procedural_7_train_000")
    sparse = _sequence(src, "procedural_300656_train_000")
    _sequence(src, "procedural_8_train_000", frames=5)  # still rendering
    _sequence(src, "cbox_train_000", json=False)  # no sequence.json yet
    os.makedirs(os.path.join(src, "val"))
    out = str(tmp_path / "root")
    r = _run(src, out, "3")
    assert r.returncode == 0, r.stderr
    names = sorted(os.listdir(os.path.join(out, "train")))
    assert names == [
        "procedural_300656_train_000",
        "procedural_300656_train_000_x1",
        "procedural_300656_train_000_x2",
        "procedural_7_train_000",
    ]
    assert os.path.realpath(os.path.join(out, "train", "procedural_7_train_000")) == os.path.realpath(done)
    assert os.path.realpath(os.path.join(out, "train", "procedural_300656_train_000_x2")) == os.path.realpath(sparse)
    assert os.path.realpath(os.path.join(out, "val")) == os.path.realpath(os.path.join(src, "val"))
    # Run again: the root of links is replaced, the dataset untouched.
    assert _run(src, out, "1").returncode == 0
    assert len(os.listdir(os.path.join(out, "train"))) == 2
    assert os.path.isdir(done) and os.listdir(done)


@pytest.mark.parametrize("bad", ["0", "two"])
def test_bad_repeat_is_refused(tmp_path, bad):
    src = str(tmp_path / "ds")
    _sequence(src, "procedural_7_train_000")
    r = _run(src, str(tmp_path / "root"), bad)
    assert r.returncode == 2 and "REPEAT" in r.stderr


def test_never_replaces_a_folder_that_is_not_a_root_of_links(tmp_path):
    src = str(tmp_path / "ds")
    _sequence(src, "procedural_7_train_000")
    # OUT is itself a dataset (real folders, not links): refused, left as it was.
    r = _run(src, src)
    assert r.returncode == 2 and "not replacing" in r.stderr
    assert os.path.isdir(os.path.join(src, "train", "procedural_7_train_000"))
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("x")
    r = _run(src, str(other))
    assert r.returncode == 2 and (other / "keep.txt").exists()
