"""Shipping a rolling run by its ledger (ssr.ship): the tensors and config are the
snapshot's, the provenance names the run, its start and the blocks that shipped it, and a
ledger or snapshot that does not ship is refused naming the file."""

import json
import os

import pytest
from safetensors import safe_open

from ssr.export import export_random, export_weights, load_weights
from ssr.prequential import ROLLING
from ssr.ship import main


def won(block, winner="F13"):
    figures = {"psnr": 24.0, "ssim": 0.7, "guard_psnr": 27.0}
    return {"block": block, "iteration": 1000 * block, "winner": winner, "shipped": figures, "F13": figures}


def repo(tmp_path, blocks, iterations=11000, run="ssr-s46-F13"):
    """A repository root with F13's start and base files, a ledger and a snapshot."""
    reg = ROLLING["F13"]
    base, _ = export_random(str(tmp_path / "base.safetensors"), seed=1)
    for rel, camp in ((reg["start"]["base"], 83500), (reg["start"]["weights"], None)):
        path = tmp_path / rel
        os.makedirs(path.parent, exist_ok=True)
        prov = {"iterations": 1000, "model": "ssr"} if camp is None else {"campaign_iterations": camp, "dataset": "d"}
        export_weights(base, str(path), prov, {})
    model, _ = export_random(str(tmp_path / "m.safetensors"), seed=2)
    snap = tmp_path / "snap.safetensors"
    export_weights(model, str(snap), {"iterations": iterations, "model": "ssr", "snapshot_of": f"/x/runs/{run}"}, {})
    ledger = tmp_path / "weights" / "prequential-F13.json"
    ledger.write_text(json.dumps({"run": reg["run"], "blocks": blocks}))
    return str(ledger), str(snap)


def test_ships_the_snapshot_with_its_provenance(tmp_path):
    ledger, snap = repo(tmp_path, [won(9), won(10), won(11), won(12, "shipped")])
    out = str(tmp_path / "ssr.safetensors")
    assert main([ledger, snap, "--out", out, "--root", str(tmp_path)]) == 0
    a, b = safe_open(snap, "pt"), safe_open(out, "pt")
    assert sorted(a.keys()) == sorted(b.keys())
    assert all(a.get_tensor(k).equal(b.get_tensor(k)) for k in a.keys())
    _, meta = load_weights(out)
    _, snap_meta = load_weights(snap)
    assert meta["config"] == snap_meta["config"]
    prov = meta["provenance"]
    assert prov["name"] == "F13" and prov["iterations"] == 11000 and prov["blocks_trained"] == [8, 9, 10]
    # the base's 83,500, P46's 1,000 and F13's 3,000 from 8,000
    assert prov["campaign_iterations"] == 87500
    assert prov["init"]["provenance"] == {"iterations": 1000, "model": "ssr"}
    assert prov["shipped_by"] == {**prov["shipped_by"], "ledger": "weights/prequential-F13.json", "ships_at": 11000}
    metrics = json.loads(b.metadata()["metrics"])
    assert sorted(metrics["blocks"]) == ["10", "11", "9"]  # block 12 is after the shipped iteration


def test_refuses_what_does_not_ship(tmp_path, capsys):
    out = str(tmp_path / "ssr.safetensors")
    ledger, snap = repo(tmp_path, [won(9), won(10, "shipped"), won(11)])
    assert main([ledger, snap, "--out", out, "--root", str(tmp_path)]) == 2
    assert "does not ship" in capsys.readouterr().err and not os.path.exists(out)
    ledger, snap = repo(tmp_path, [won(9), won(10)])
    assert main([ledger, snap, "--out", out, "--root", str(tmp_path)]) == 2
    assert "snap.safetensors: weights at iteration 11000, the ledger ships F13 at 10000" in capsys.readouterr().err
    ledger, snap = repo(tmp_path, [won(9), won(10)], iterations=10000, run="ssr-s42-F12")
    assert main([ledger, snap, "--out", out, "--root", str(tmp_path)]) == 2
    assert "a snapshot of run 'ssr-s42-F12'" in capsys.readouterr().err
    with open(ledger, "w") as f:
        json.dump({"run": "other", "blocks": []}, f)
    assert main([ledger, snap, "--out", out, "--root", str(tmp_path)]) == 2
    assert "not a rolling run" in capsys.readouterr().err and not os.path.exists(out)
