"""The pre-registered runs as `training/registered.sh` starts them (weights/README: F6 and F7
of the thirtieth session, F8 of the thirty-first, F9 of the thirty-fourth, F10 and F11 of
the thirty-ninth, F12 of the forty-second, F13 of the forty-sixth, F14 of the fiftieth):
their ssr.train arguments, printed by campaign.sh's DRY_RUN, parse and say what the
registrations say; the rolling runs' blocks, their roots, kept checkpoints and prequential
score as the registrations order them."""

import json
import os
import shutil
import subprocess
import sys

import pytest

from ssr.train import parse_args

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(HERE)
SCRIPT = os.path.join(HERE, "registered.sh")


def dry_run(work, run, restore=None):
    # An empty restore folder unless the test gives one: the registrations' own starts,
    # whatever restore points the repository holds now.
    restore = restore if restore is not None else work / "no-restore"
    out = subprocess.run(
        [SCRIPT, str(work), run], env={**os.environ, "DRY_RUN": "1", "RESTORE": str(restore)},
        capture_output=True, text=True, check=True,
    ).stdout
    return parse_args(out.splitlines())


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    work = tmp_path_factory.mktemp("work")
    return work, {r: dry_run(work, r) for r in ("F6", "F7", "F8", "F9", "F10", "F11")}


def test_a_kept_whole_checkpoint_is_where_a_new_machine_resumes(tmp_path):
    """`keep` copies a run's newest snapshot checkpoint into the restore folder and drops that
    run's older ones; the run then resumes from it (--resume-from, with the --init-at it began
    with) on a machine without the run's folder, and from its own checkpoint where there is one."""
    work, restore = tmp_path / "work", tmp_path / "restore"
    snaps = work / "runs" / "ssr-s30-F6" / "snapshots"
    snaps.mkdir(parents=True)
    env = {**os.environ, "RESTORE": str(restore), "PYTHON": sys.executable}
    keep = subprocess.run([SCRIPT, str(work), "keep", "F6"], env=env, capture_output=True, text=True)
    assert keep.returncode == 1 and "no checkpoint" in keep.stderr, keep.stderr
    for it in (5000, 5500):
        (snaps / f"it_{it:07d}.pt").write_bytes(b"checkpoint %d" % it)
    restore.mkdir()
    (restore / "ssr-s30-F6-it0004500.pt").write_bytes(b"older")
    (restore / "ssr-s30-F7-it0004500.pt").write_bytes(b"another run's")
    keep = subprocess.run([SCRIPT, str(work), "keep", "F6"], env=env, capture_output=True, text=True)
    assert keep.returncode == 0, keep.stderr
    assert sorted(p.name for p in restore.iterdir()) == ["ssr-s30-F6-it0005500.pt", "ssr-s30-F7-it0004500.pt"]
    assert (restore / "ssr-s30-F6-it0005500.pt").read_bytes() == b"checkpoint 5500"
    # a new machine: no run folder, the kept checkpoint
    fresh = tmp_path / "fresh"
    a = dry_run(fresh, "F6", restore)
    assert a.resume_from == str(restore / "ssr-s30-F6-it0005500.pt") and a.init_at == 4500
    assert dry_run(fresh, "F7", restore).resume_from == str(restore / "ssr-s30-F7-it0004500.pt")
    # F8 has none: its registered start
    f8 = dry_run(fresh, "F8", restore)
    assert f8.resume_from is None and f8.init_at == 0
    # the run's own checkpoint comes first
    (work / "runs" / "ssr-s30-F6" / "checkpoint.pt").write_bytes(b"own")
    own = dry_run(work, "F6", restore)
    assert own.resume and own.resume_from is None and own.init_at == 4500
    # the run's own checkpoint, when further on than its snapshots, is what is kept
    import torch

    torch.save({"iteration": 5750, "model": {}}, work / "runs" / "ssr-s30-F6" / "checkpoint.pt")
    keep = subprocess.run([SCRIPT, str(work), "keep", "F6"], env=env, capture_output=True, text=True)
    assert keep.returncode == 0, keep.stderr
    assert sorted(p.name for p in restore.iterdir()) == ["ssr-s30-F6-it0005750.pt", "ssr-s30-F7-it0004500.pt"]
    torch.save({"iteration": 5250, "model": {}}, work / "runs" / "ssr-s30-F6" / "checkpoint.pt")
    (restore / "ssr-s30-F6-it0005750.pt").unlink()
    subprocess.run([SCRIPT, str(work), "keep", "F6"], env=env, capture_output=True, text=True, check=True)
    assert (restore / "ssr-s30-F6-it0005500.pt").read_bytes() == b"checkpoint 5500"  # the snapshot is newer
    bad = subprocess.run([SCRIPT, str(work), "keep", "F5"], env=env, capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown run 'F5'" in bad.stderr


def test_every_registered_run_has_the_shared_options(runs):
    work, args = runs
    for name, a in args.items():
        root = "ds-s39" if name in ("F10", "F11") else "ds-s30"
        assert a.data == str(work / root), name
        assert a.iters == 6000 and a.seed == 17 and a.lr == 1.25e-4 and a.threads == 1, name
        assert a.window == 8 and a.frame_weights == (1.0,) * 8 and a.batch == 8 and a.crop == 64, name
        assert a.thin == 0.5 and a.thin_keep_min == 0.02 and a.min_reference_psnr == 22, name
        assert a.background == "loss" and a.mean_correction == "loss" and a.val_every == 0, name
        assert a.lambdas["ssim"] == 10 and a.lambdas["m"] == 0, name
        assert os.path.isfile(a.init), name


def test_each_run_differs_as_registered(runs):
    work, args = runs
    f6, f7, f8, f9 = (args[k] for k in ("F6", "F7", "F8", "F9"))
    assert f6.init == os.path.join(ROOT, "weights/baselines/ssr-s30-F6-it4500.safetensors") and f6.init_at == 4500
    assert f7.init == os.path.join(ROOT, "weights/baselines/ssr-s30-F7-it4000.safetensors") and f7.init_at == 4000
    assert json.loads(f6.model_config) == {"emission": "background"}
    assert json.loads(f7.model_config) == {"emission": "background", "escaped": "background"}
    assert json.loads(f8.model_config) == {"emission": "background", "escaped": "background", "exposure": "shared"}
    for a in (f8, f9):  # both start from F5 at iteration 0, committed as its own file
        assert a.init == os.path.join(ROOT, "weights/baselines/ssr-s29-F5.safetensors") and a.init_at == 0
    from safetensors import safe_open

    with safe_open(f8.init, "pt") as f:
        prov = json.loads(f.metadata()["provenance"])
    assert prov["campaign_iterations"] == 83500, "F5: the shipped model when F8 and F9 were registered"
    assert [a.lambdas["mm"] for a in (f6, f7, f8, f9)] == [0, 0, 0, 5]
    # F9 is F6 with the metal brightness term and nothing else (but its own run and start)
    differ = {k for k in vars(f6) if vars(f6)[k] != vars(f9)[k]}
    assert differ == {"out", "init", "init_at", "lambdas"}
    assert {k: v for k, v in f9.lambdas.items() if f6.lambdas[k] != v} == {"mm": 5.0}


def test_f10_and_f11_are_f6_and_f9_from_f5_on_the_larger_root(runs):
    """F10 and F11 (thirty-ninth session): F6's and F9's options, from F5 as F8 and F9 start,
    on ds-s39 (procedural seeds 0-279) instead of ds-s30; nothing else differs."""
    work, args = runs
    for new, old in (("F10", "F6"), ("F11", "F9")):
        a, b = vars(args[new]), vars(args[old])
        assert {k for k in a if a[k] != b[k]} - {"init", "init_at"} == {"out", "data"}, new
        assert args[new].data == str(work / "ds-s39") and args[new].out.endswith(f"ssr-s39-{new}")
        assert args[new].init == args["F9"].init and args[new].init_at == 0


def test_unknown_runs_and_parts_are_refused(tmp_path):
    for argv, msg in [(["F5"], "unknown 'F5'"), (["data", "everything"], "unknown part 'everything'")]:
        r = subprocess.run([SCRIPT, str(tmp_path), *argv], capture_output=True, text=True,
                           env={**os.environ, "SUBPIXEL": "/bin/true"})
        assert r.returncode == 2 and msg in r.stderr, r.stderr


def test_the_larger_root_refuses_an_incomplete_render(tmp_path):
    """`root s39` links the first sequence of procedural seeds 0-279 (and the fixed and
    sparse-light ones; never a second sequence or a seed past 279) and refuses, naming what
    to run, until all 280 are complete; an unknown root is refused."""
    train = tmp_path / "ds" / "train"
    for name in ("procedural_0_train_000", "procedural_0_train_001", "procedural_279_train_000",
                 "procedural_280_train_000", "procedural_300016_train_000", "cbox_train_003",
                 "procedural_5_train_000"):
        (train / name).mkdir(parents=True)
        (train / name / "sequence.json").write_text("{}")
        if name != "procedural_5_train_000":  # still rendering: no last frame
            (train / name / "frame_0007.exr").write_bytes(b"")
    (tmp_path / "ds" / "val").mkdir()
    env = {**os.environ, "PYTHON": sys.executable}
    r = subprocess.run([SCRIPT, str(tmp_path), "root", "s39"], env=env, capture_output=True, text=True)
    assert r.returncode == 1 and "registered.sh WORK data first" in r.stderr, r.stderr
    assert "2 of the 280 procedural seeds" in r.stdout, r.stdout
    linked = sorted(p.name for p in (tmp_path / "ds-s39" / "train").iterdir())
    assert linked == ["cbox_train_003", "procedural_0_train_000", "procedural_279_train_000",
                      "procedural_300016_train_000", "procedural_300016_train_000_x1",
                      "procedural_300016_train_000_x2", "procedural_300016_train_000_x3"]
    r = subprocess.run([SCRIPT, str(tmp_path), "root", "s40"], env=env, capture_output=True, text=True)
    assert r.returncode == 2 and "unknown root 's40'" in r.stderr, r.stderr


def _table(rows):
    """A table as `subpixel eval --table --json` prints it: {method: (procedural PSNR, SSIM,
    guard PSNR)}, every guard column at the guard PSNR."""
    from ssr.registered import GUARD_COLUMNS

    out = []
    for m, (p, s, g) in rows.items():
        scenes = {"procedural": {"psnr": p, "ssim": s}}
        scenes.update({c: {"psnr": g, "ssim": 0.9} for c in GUARD_COLUMNS})
        out.append({"method": m, "scenes": scenes})
    return out


def test_the_registered_chain_reads_the_rule_in_its_order():
    from ssr.registered import pick

    base = {"F5": (25.44, 0.7298, 27.0), "F6": (25.50, 0.7300, 27.0), "F7": (25.52, 0.7310, 27.0)}
    assert pick(_table(base))[0] == "F7"
    # F7 loses to F6 (lower SSIM), F6 beats F5
    assert pick(_table({**base, "F7": (25.60, 0.7299, 27.0)}))[0] == "F6"
    # the guard: F7's SSIM is higher but the fixed scenes drop 0.5 dB, so F6 stays
    assert pick(_table({**base, "F7": (25.52, 0.7310, 26.5)}))[0] == "F6"
    # neither beats F5: F5 stays
    assert pick(_table({**base, "F6": (25.40, 0.7290, 27.0), "F7": (25.41, 0.7289, 27.0)}))[0] == "F5"
    # F8 against the pick
    assert pick(_table({**base, "F8": (25.55, 0.7320, 27.0)}))[0] == "F8"
    assert pick(_table({**base, "F8": (25.55, 0.7305, 27.0)}))[0] == "F7"
    # F9 must beat F6 first, then the pick
    best, steps = pick(_table({**base, "F9": (25.56, 0.7330, 27.0)}))
    assert best == "F9" and len(steps) == 4
    best, steps = pick(_table({**base, "F9": (25.56, 0.7305, 27.0)}))  # beats F6, not F7
    assert best == "F7" and len(steps) == 4
    best, steps = pick(_table({**base, "F9": (25.56, 0.7299, 27.0)}))  # loses to F6: no 4th step
    assert best == "F7" and len(steps) == 3
    # F11 against F10, then the pick against the pick so far; F10 against F6 and F11 against
    # F9 are reported beside and decide nothing
    full = {**base, "F9": (25.56, 0.7299, 27.0), "F10": (25.70, 0.7350, 27.0), "F11": (25.75, 0.7340, 27.0)}
    best, steps = pick(_table(full))
    assert best == "F10" and steps[3].startswith("F10 against F6") and steps[4].startswith("F11 against F9")
    assert all("not deciding" in s for s in steps[3:5]) and steps[5].startswith("F11 against F10: F10")
    assert steps[6].startswith("F10 against F7: F10") and len(steps) == 7
    best, steps = pick(_table({**full, "F11": (25.75, 0.7360, 27.0)}))
    assert best == "F11" and steps[-1].startswith("F11 against F7: F11")
    # neither beats the pick so far: it stays, whatever F10 did against F6
    best, _ = pick(_table({**full, "F10": (25.70, 0.7305, 27.0), "F11": (25.75, 0.7300, 27.0)}))
    assert best == "F7"
    # only one of the two finished: no step 4
    assert len(pick(_table({**base, "F10": (25.70, 0.7350, 27.0)}))[1]) == 2


def test_the_registered_chain_names_what_is_missing(tmp_path):
    from ssr.registered import main

    path = tmp_path / "val.json"
    path.write_text(json.dumps(_table({"F5": (25.0, 0.7, 27.0), "F6": (25.1, 0.71, 27.0)})))
    assert main([str(path)]) == 2


def test_the_whole_chain_runs_in_the_registered_order(tmp_path):
    """`all` (DRY_RUN: the steps printed, nothing run): F6-F9 finished and are committed and
    F10 and F11 were withdrawn, so the chain sets up, rolls F12 over its blocks, then
    renders val, applies the rules and renders the rest."""
    for r in ("ssr-s30-F6", "ssr-s30-F7", "ssr-s31-F8", "ssr-s34-F9"):
        assert os.path.isfile(os.path.join(ROOT, "weights", "baselines", r + ".safetensors")), r
    out = subprocess.run([SCRIPT, str(tmp_path), "all"], env={**os.environ, "DRY_RUN": "1"},
                         capture_output=True, text=True, check=True).stdout
    steps = [line.split(" ", 3)[3] for line in out.splitlines() if line.startswith("== registered.sh")]
    assert steps == ["setup", "rolling", "data val", "rules", "data heldout rest"], out


# F12, the rolling run (forty-second session)


def run_script(work, *argv, restore=None, dry=True, roll=None):
    env = {**os.environ, "PYTHON": sys.executable, "RESTORE": str(restore or work / "no-restore")}
    if roll:
        env["ROLL"] = roll
    if dry:
        env["DRY_RUN"] = "1"
    return subprocess.run([SCRIPT, str(work), *argv], env=env, capture_output=True, text=True)


def block_names(k):
    """Block k's sequences as the recipe lists them (ONLY_LIST)."""
    out = subprocess.run([os.path.join(HERE, "dataset_recipe.sh"), "/nonexistent", "block"],
                         env={**os.environ, "ONLY_LIST": "1", "BLOCK": str(k)},
                         capture_output=True, text=True, check=True).stdout
    return out.split()


def test_each_block_holds_new_procedural_seeds_and_rotates_the_rest():
    """Block K: the six fixed scenes' train sequence K mod 5, four sparse-light seeds (group K
    mod 4) and the first sequences of procedural seeds 280 + 20K to 299 + 20K, seeds no
    earlier run rendered (ds-s30 and F5's roots: seeds 0-109; F10 and F11's: 0-279)."""
    b0, b3, b7 = block_names(0), block_names(3), block_names(7)
    assert len(b0) == len(b3) == 30 and all(n.startswith("train/") for n in b0)
    fixed3 = [n for n in b3 if not n.startswith("train/procedural_")]
    assert fixed3 == [f"train/{s}_train_003" for s in ("cornell", "room", "cbox", "cornell-box", "dining-room", "staircase2")]
    seeds = lambda b: [int(n.split("_")[1]) for n in b if n.startswith("train/procedural_")]  # noqa: E731
    assert [s for s in seeds(b3) if s < 300000] == list(range(340, 360))
    assert all(n.endswith("_train_000") for n in b3 if n.startswith("train/procedural_"))
    sparse = lambda b: [s for s in seeds(b) if s >= 300000]  # noqa: E731
    assert len(sparse(b0)) == 4 and sparse(b7) == sparse(b3) and not set(sparse(b0)) & set(sparse(b3))
    # every block's procedural seeds are new; none reaches the sparse-light range
    allp = [s for k in range(30) for s in seeds(block_names(k)) if s < 300000]
    assert len(allp) == len(set(allp)) == 600 and min(allp) == 280 and max(allp) == 879
    r = subprocess.run([os.path.join(HERE, "dataset_recipe.sh"), "/nonexistent", "block"],
                       env={**os.environ, "ONLY_LIST": "1", "BLOCK": "14986"}, capture_output=True, text=True)
    assert r.returncode == 2 and "sparse-light range" in r.stderr, r.stderr
    r = subprocess.run([os.path.join(HERE, "dataset_recipe.sh"), "/nonexistent", "block"],
                       env={**os.environ, "ONLY_LIST": "1"}, capture_output=True, text=True)
    assert r.returncode == 2 and "needs BLOCK=K" in r.stderr, r.stderr


def fake_sequences(ds, names, incomplete=()):
    for rel in names:
        d = ds / rel
        d.mkdir(parents=True, exist_ok=True)
        (d / "sequence.json").write_text("{}")
        if rel not in incomplete:
            (d / "frame_0007.exr").write_bytes(b"")


def test_a_block_root_links_the_whole_block_or_is_refused(tmp_path):
    """`block K` (DRY_RUN: nothing rendered) links block K's sequences into WORK/ds-block-K,
    the sparse-light ones four times, and refuses while one of them is incomplete; nothing
    of another block enters."""
    names = block_names(3)
    ds = tmp_path / "ds"
    fake_sequences(ds, names + ["train/procedural_360_train_000", "train/cbox_train_002"], incomplete=[names[-1]])
    r = run_script(tmp_path, "block", "3")
    assert r.returncode == 1 and "1 of the 30 sequences" in r.stderr, r.stderr
    fake_sequences(ds, [names[-1]])
    r = run_script(tmp_path, "block", "3")
    assert r.returncode == 0, r.stderr
    linked = sorted(p.name for p in (tmp_path / "ds-block-3" / "train").iterdir())
    base = sorted(os.path.basename(n) for n in names)
    sparse = [n for n in base if n.startswith("procedural_3") and len(n.split("_")[1]) == 6]
    assert linked == sorted(base + [f"{n}_x{k}" for n in sparse for k in (1, 2, 3)])
    r = run_script(tmp_path, "block", "30")
    assert r.returncode == 2 and "block must be 0-29" in r.stderr, r.stderr


def test_f12_is_f9_over_thirty_blocks_of_a_thousand_iterations(tmp_path):
    """F12: F9's options from F5 (the same start file), 30,000 iterations, block K on
    WORK/ds-block-K stopping at 1,000(K+1); nothing else differs from F9."""
    (tmp_path / "ds-block-0" / "train").mkdir(parents=True)
    r = run_script(tmp_path, "F12", "0")
    assert r.returncode == 0, r.stderr
    f12 = parse_args(r.stdout.splitlines())
    f9 = dry_run(tmp_path, "F9")
    differ = {k for k in vars(f12) if vars(f12)[k] != vars(f9)[k]}
    assert differ == {"out", "data", "iters", "stop_at"}, differ
    assert f12.iters == 30000 and f12.stop_at == 1000 and f12.data == str(tmp_path / "ds-block-0")
    assert f12.out.endswith("ssr-s42-F12") and f12.lambdas["mm"] == 5 and f12.init_at == 0


def test_f12_trains_only_the_block_where_its_checkpoint_stands(tmp_path):
    """A block is trained from a checkpoint inside it only: one past it has trained it
    (nothing to do), one before it must train the earlier block first; on a new machine the
    newest kept checkpoint says where F12 stands and is resumed from."""
    import torch

    for k in (0, 1, 2):
        (tmp_path / f"ds-block-{k}" / "train").mkdir(parents=True)
    run = tmp_path / "runs" / "ssr-s42-F12"
    run.mkdir(parents=True)
    torch.save({"iteration": 1500, "model": {}}, run / "checkpoint.pt")
    r = run_script(tmp_path, "F12", "1")
    assert r.returncode == 0, r.stderr
    a = parse_args(r.stdout.splitlines())
    assert a.resume and a.stop_at == 2000 and a.data == str(tmp_path / "ds-block-1")
    r = run_script(tmp_path, "F12", "0")
    assert r.returncode == 0 and "block 0 was trained before" in r.stdout and "--data" not in r.stdout
    r = run_script(tmp_path, "F12", "2")
    assert r.returncode == 1 and "block 1 comes before block 2" in r.stderr, r.stderr
    # a new machine: no run folder, the kept checkpoint at the end of block 1
    fresh, restore = tmp_path / "fresh", tmp_path / "restore"
    (fresh / "ds-block-2" / "train").mkdir(parents=True)
    restore.mkdir()
    (restore / "ssr-s42-F12-it0002000.pt").write_bytes(b"kept")
    a = parse_args(run_script(fresh, "F12", "2", restore=restore).stdout.splitlines())
    assert a.resume_from == str(restore / "ssr-s42-F12-it0002000.pt") and a.stop_at == 3000
    r = run_script(fresh, "F12", "1", restore=restore)
    assert "block 1 was trained before" in r.stdout, r.stdout + r.stderr
    # a block without its root is refused, naming what renders it
    r = run_script(fresh, "F12", "2", restore=restore)
    assert r.returncode == 0
    (restore / "ssr-s42-F12-it0003000.pt").write_bytes(b"kept")
    (restore / "ssr-s42-F12-it0002000.pt").unlink()
    r = run_script(fresh, "F12", "3", restore=restore)
    assert r.returncode == 1 and "registered.sh WORK block 3" in r.stderr, r.stderr


def test_keep_f12_keeps_the_weights_at_the_newest_block_boundary(tmp_path):
    work, restore = tmp_path / "work", tmp_path / "restore"
    snaps = work / "runs" / "ssr-s42-F12" / "snapshots"
    snaps.mkdir(parents=True)
    for it in (500, 1000, 1500):
        (snaps / f"it_{it:07d}.pt").write_bytes(b"checkpoint %d" % it)
        (snaps / f"it_{it:07d}.safetensors").write_bytes(b"weights %d" % it)
    restore.mkdir()
    (restore / "ssr-s42-F12-it0000000.safetensors").write_bytes(b"older")
    r = run_script(work, "keep", "F12", restore=restore, dry=False)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in restore.iterdir()) == ["ssr-s42-F12-it0001000.safetensors", "ssr-s42-F12-it0001500.pt"]
    assert (restore / "ssr-s42-F12-it0001000.safetensors").read_bytes() == b"weights 1000"


def test_the_prequential_score_reads_f12_before_it_saw_the_block(tmp_path):
    """`prequential K` scores F12 at 1,000K (its snapshot, else the kept weights) and the
    shipped model on block K's procedural and fixed sequences (not the sparse-light ones,
    which come back every four blocks); refused for block 0 and without those weights."""
    names = block_names(2)
    fake_sequences(tmp_path / "ds", names)
    r = run_script(tmp_path, "prequential", "2", roll="F12")
    assert r.returncode == 1 and "no weights of F12 at iteration 2000" in r.stderr, r.stderr
    snaps = tmp_path / "runs" / "ssr-s42-F12" / "snapshots"
    snaps.mkdir(parents=True)
    (snaps / "it_0002000.safetensors").write_bytes(b"w")
    r = run_script(tmp_path, "prequential", "2", roll="F12")
    assert r.returncode == 0, r.stderr
    assert f"F12={snaps}/it_0002000.safetensors over 26 sequences" in r.stdout, r.stdout
    linked = sorted(p.name for p in (tmp_path / "preq-2" / "train").iterdir())
    assert len(linked) == 26 and not [n for n in linked if n.startswith("procedural_3") and len(n.split("_")[1]) == 6]
    assert "procedural_320_train_000" in linked and "staircase2_train_002" in linked
    r = run_script(tmp_path, "prequential", "0", roll="F12")
    assert r.returncode == 2 and "block 0 is not scored" in r.stderr, r.stderr


# F13, the rolling run that replaced F12 (forty-sixth session)


def test_f13_trains_every_block_so_far_from_p46(tmp_path):
    """F13: from P46 (its committed start, at iteration 8,000), block K >= 8 on the links of
    blocks 1 to K's roots at once, P46's options (no mm, lr 3.125e-5) over F12's schedule;
    a missing block root is named, and blocks out of order are refused."""
    for j in range(1, 10):
        seq = tmp_path / f"ds-block-{j}-src" / "train" / f"procedural_{280 + 20 * j}_train_000"
        seq.mkdir(parents=True)
        (tmp_path / f"ds-block-{j}" / "train").mkdir(parents=True)
        os.symlink(seq, tmp_path / f"ds-block-{j}" / "train" / seq.name)
    r = run_script(tmp_path, "F13", "9")
    assert r.returncode == 1 and "block 8 comes before block 9" in r.stderr, r.stderr
    r = run_script(tmp_path, "F13", "8")
    assert r.returncode == 0, r.stderr
    f13 = parse_args(r.stdout.splitlines())
    assert f13.init == os.path.join(ROOT, "weights", "baselines", "ssr-s46-P46.safetensors")
    assert os.path.isfile(f13.init) and f13.init_at == 8000 and f13.stop_at == 9000 and f13.iters == 30000
    assert f13.lr == 3.125e-5 and f13.lambdas["mm"] == 0 and f13.out.endswith("ssr-s46-F13")
    assert f13.data == str(tmp_path / "ds-upto-8")
    linked = sorted(p.name for p in (tmp_path / "ds-upto-8" / "train").iterdir())
    assert linked == sorted(f"procedural_{280 + 20 * j}_train_000" for j in range(1, 9))
    (tmp_path / "ds-block-0" / "train").mkdir(parents=True)
    f12 = parse_args(run_script(tmp_path, "F12", "0").stdout.splitlines())
    differ = {k for k in vars(f13) if vars(f13)[k] != vars(f12)[k]}
    assert differ == {"out", "data", "init", "init_at", "stop_at", "lr", "lambdas"}, differ
    shutil.rmtree(tmp_path / "ds-block-5")
    r = run_script(tmp_path, "F13", "8")
    assert r.returncode == 1 and "registered.sh WORK block 5" in r.stderr, r.stderr


def test_the_prequential_score_of_f13_starts_at_block_9(tmp_path):
    """`prequential K` (ROLL defaults to F13) scores F13 at 1,000K from block 9 on (block 8,
    where P46's score was seen before F13 was registered, is refused)."""
    names = block_names(9)
    fake_sequences(tmp_path / "ds", names)
    r = run_script(tmp_path, "prequential", "8", roll="F13")
    assert r.returncode == 2 and "F13's ledger starts at block 9" in r.stderr, r.stderr
    r = run_script(tmp_path, "prequential", "9", roll="F13")
    assert r.returncode == 1 and "no weights of F13 at iteration 9000" in r.stderr, r.stderr
    snaps = tmp_path / "runs" / "ssr-s46-F13" / "snapshots"
    snaps.mkdir(parents=True)
    (snaps / "it_0009000.safetensors").write_bytes(b"w")
    r = run_script(tmp_path, "prequential", "9", roll="F13")
    assert r.returncode == 0 and f"F13={snaps}/it_0009000.safetensors over 26 sequences" in r.stdout, r.stdout
    r = run_script(tmp_path, "prequential", "9", roll="F15")
    assert r.returncode == 2 and "ROLL must be F12, F13 or F14" in r.stderr, r.stderr


# F14, F13 continued on blocks at 32 spp (fiftieth session)

def test_f14_is_f13_on_blocks_at_32_spp(tmp_path):
    """F14's block K: F13's options, start and schedule, resumed from its kept checkpoint,
    on the links of blocks 1 to K rendered at 32 spp (WORK/ds-spp32-block-J), no sequence
    left out for its references' noise; nothing else differs from F13's block K."""
    for spp_root in ("ds-spp32-block", "ds-block"):
        for j in range(1, 12):
            seq = tmp_path / f"{spp_root}-{j}-src" / "train" / f"procedural_{280 + 20 * j}_train_000"
            seq.mkdir(parents=True)
            (tmp_path / f"{spp_root}-{j}" / "train").mkdir(parents=True)
            os.symlink(seq, tmp_path / f"{spp_root}-{j}" / "train" / seq.name)
    # where F14 began: F13's whole checkpoint at 11,250, kept under F14's name
    restore = tmp_path / "restore"
    restore.mkdir()
    for run in ("ssr-s46-F13", "ssr-s50-F14"):
        (restore / f"{run}-it0011250.pt").write_bytes(b"F13 at 11250")
    r = run_script(tmp_path, "F14", "11", restore=restore)
    assert r.returncode == 0, r.stderr
    f14 = parse_args(r.stdout.splitlines())
    assert f14.resume_from == str(restore / "ssr-s50-F14-it0011250.pt") and f14.init_at == 8000
    assert f14.stop_at == 12000 and f14.min_reference_psnr == 0 and f14.out.endswith("ssr-s50-F14")
    assert f14.data == str(tmp_path / "ds-spp32-upto-11")
    linked = {p.name: os.path.realpath(p) for p in (tmp_path / "ds-spp32-upto-11" / "train").iterdir()}
    assert sorted(linked) == sorted(f"procedural_{280 + 20 * j}_train_000" for j in range(1, 12))
    assert all("/ds-spp32-block-" in t for t in linked.values()), linked
    f13 = parse_args(run_script(tmp_path, "F13", "11", restore=restore).stdout.splitlines())
    differ = {k for k in vars(f14) if vars(f14)[k] != vars(f13)[k]}
    assert differ == {"out", "data", "resume_from", "min_reference_psnr"}, differ
    assert f13.min_reference_psnr == 22 and f13.data == str(tmp_path / "ds-upto-11")
    r = run_script(tmp_path, "F14", "12", restore=restore)
    assert r.returncode == 1 and "block 11 comes before block 12" in r.stderr, r.stderr
    shutil.rmtree(tmp_path / "ds-spp32-block-4")
    r = run_script(tmp_path, "F14", "11", restore=restore)
    assert r.returncode == 1 and "registered.sh WORK block 4 32" in r.stderr, r.stderr


def test_f14_resumes_f13s_kept_checkpoint_under_its_own_options(tmp_path):
    """F13's newest kept whole checkpoint, where F14 begins, loads under the options F14's
    block trains with (the trainer's resume check: model, schedule, start, losses)."""
    import glob

    from ssr import train as T

    kept = sorted(glob.glob(os.path.join(ROOT, "weights", "restore", "ssr-s46-F13-it*.pt")))[-1]
    restore = tmp_path / "restore"
    restore.mkdir()
    n = os.path.basename(kept).split("-it")[1]
    os.symlink(kept, restore / f"ssr-s50-F14-it{n}")
    at = int(n.split(".")[0])
    k = at // 1000
    for j in range(1, k + 1):
        (tmp_path / f"ds-spp32-block-{j}" / "train").mkdir(parents=True)
    r = run_script(tmp_path, "F14", str(k), restore=restore)
    assert r.returncode == 0, r.stderr
    f14 = parse_args(r.stdout.splitlines())
    ck = T.load_checkpoint(f14.resume_from, T.run_config(f14))
    assert ck["iteration"] == at


def test_a_block_at_32_spp_has_its_own_folder_and_root(tmp_path):
    """`block K 32` links block K's sequences from WORK/ds-spp32 into WORK/ds-spp32-block-K,
    never the 512-spp ones of WORK/ds; a count that is not one is refused."""
    names = block_names(3)
    fake_sequences(tmp_path / "ds", names)
    r = run_script(tmp_path, "block", "3", "32")
    assert r.returncode == 1 and "30 of the 30 sequences" in r.stderr, r.stderr
    fake_sequences(tmp_path / "ds-spp32", names)
    r = run_script(tmp_path, "block", "3", "32")
    assert r.returncode == 0, r.stderr
    targets = [os.path.realpath(p) for p in (tmp_path / "ds-spp32-block-3" / "train").iterdir()]
    assert len(targets) == 30 + 4 * 3 and all(t.startswith(str(tmp_path / "ds-spp32") + "/") for t in targets)
    assert not (tmp_path / "ds-block-3").exists()
    r = run_script(tmp_path, "block", "3", "0")
    assert r.returncode == 2 and "positive count" in r.stderr, r.stderr


def test_the_prequential_score_of_f14_reads_the_512_spp_blocks_from_block_12(tmp_path):
    """`prequential K` (ROLL defaults to F14) scores F14 at 1,000K from block 12 on, the
    first block F13's ledger has not scored, over block K's 512-spp sequences."""
    names = block_names(12)
    fake_sequences(tmp_path / "ds", names)
    r = run_script(tmp_path, "prequential", "11")
    assert r.returncode == 2 and "F14's ledger starts at block 12" in r.stderr, r.stderr
    snaps = tmp_path / "runs" / "ssr-s50-F14" / "snapshots"
    snaps.mkdir(parents=True)
    (snaps / "it_0012000.safetensors").write_bytes(b"w")
    r = run_script(tmp_path, "prequential", "12")
    assert r.returncode == 0 and f"F14={snaps}/it_0012000.safetensors over 26 sequences" in r.stdout, r.stdout
    targets = [os.path.realpath(p) for p in (tmp_path / "preq-12" / "train").iterdir()]
    assert all(t.startswith(str(tmp_path / "ds") + "/") for t in targets), targets
