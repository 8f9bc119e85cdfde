import json
import os
import shutil

from ssr import curve as C
from ssr import train as T


def test_curve_scores_snapshots_and_plots(dataset, tmp_path, capsys):
    run = str(tmp_path / "run")
    T.train([
        "--data", dataset, "--out", run, "--iters", "2", "--batch", "2", "--crop", "16", "--workers", "0",
        "--log-every", "1", "--val-frames", "2", "--val-every", "0", "--device", "cpu", "--snapshot-every", "1",
    ])  # fmt: skip
    png, js = str(tmp_path / "c.png"), str(tmp_path / "c.json")
    argv = ["--run", run, "--data", dataset, "--split", "val", "--frames", "2", "--out", png, "--json", js]
    assert C.main(argv) == 0
    assert "scoring" in capsys.readouterr().out
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    c = json.load(open(js))
    assert [r["iteration"] for r in c["train"]] == [1, 2]
    assert [r["iteration"] for r in c["monitored"]] == [1, 2]
    # the last snapshot is the final model: its score on the val split is the trainer's final val score
    final_val = [r for r in C.read_log(run) if r["event"] == "val"][-1]
    assert abs(c["monitored"][-1]["psnr"] - final_val["psnr"]) < 1e-9
    assert c["monitored"][-1]["groups"] == {"synthetic": c["monitored"][-1]["psnr"]}
    # cached: a second call scores nothing again
    assert C.main(argv) == 0
    assert "scoring" not in capsys.readouterr().out
    # a split that has gained a sequence is scored again (never old scores for a new split)
    grown = str(tmp_path / "grown")
    shutil.copytree(dataset, grown)
    shutil.copytree(os.path.join(grown, "val", "synthetic_000"), os.path.join(grown, "val", "synthetic_001"))
    assert C.main([*argv[:3], grown, *argv[4:]]) == 0
    assert "on val (2 sequences)" in capsys.readouterr().out
    # a missing log is a clear error naming the folder
    assert C.main(["--run", str(tmp_path), "--data", dataset, "--out", png]) == 1
    assert "no training log" in capsys.readouterr().err
    assert C.group_of("procedural_1000003") == "procedural (mean)" and C.group_of("living-room") == "living-room"


def test_curve_continues_a_campaign(dataset, tmp_path, capsys):
    common = ["--data", dataset, "--iters", "2", "--batch", "2", "--crop", "16", "--workers", "0", "--log-every", "1",
              "--val-frames", "2", "--val-every", "0", "--device", "cpu", "--snapshot-every", "2"]  # fmt: skip
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    res = T.train(["--out", a, *common])
    T.train(["--out", b, "--init", res["weights"], *common])
    ja, jb = str(tmp_path / "a.json"), str(tmp_path / "b.json")
    png = str(tmp_path / "c.png")
    base = ["--data", dataset, "--split", "val", "--frames", "2", "--out", png]
    assert C.main(["--run", a, *base, "--json", ja]) == 0
    # run b starts where a ended: its points are at iterations 3 and 4
    assert C.main(["--run", b, *base, "--json", jb, "--previous", ja]) == 0
    c = json.load(open(jb))
    assert [r["iteration"] for r in c["train"]] == [1, 2, 3, 4]
    assert [r["iteration"] for r in c["monitored"]] == [2, 4]
    # re-running with its own output as --previous adds nothing twice
    assert C.main(["--run", b, *base, "--json", jb, "--previous", jb]) == 0
    assert [r["iteration"] for r in json.load(open(jb))["train"]] == [1, 2, 3, 4]


def test_curve_scores_a_model_that_composites_the_emission(tmp_path, capsys):
    """A model of config emission "background" (the shipped one's) reads the background and
    coverage besides its own buffers: the curve, whose dataset is loaded without them, scores
    its snapshots all the same (it stopped with a KeyError before)."""
    from ssr.synth import write_dataset

    data = write_dataset(str(tmp_path / "d"), {"train": 1, "test": 1}, 6, 16, 16, seed=7, background=True, emission=True)
    run = str(tmp_path / "run")
    cfg = '{"emission": "background", "albedo": "footprint", "mean_correction": "atrous"}'
    T.train([
        "--data", data, "--out", run, "--iters", "1", "--batch", "1", "--crop", "16", "--workers", "0",
        "--log-every", "1", "--val-every", "0", "--device", "cpu", "--snapshot-every", "1",
        "--model-config", cfg, "--background", "loss",
    ])  # fmt: skip
    png, js = str(tmp_path / "c.png"), str(tmp_path / "c.json")
    assert C.main(["--run", run, "--data", data, "--split", "test", "--frames", "2", "--out", png, "--json", js]) == 0
    c = json.load(open(js))
    assert len(c["monitored"]) == 1 and c["monitored"][0]["psnr"] > 0


def test_curve_scores_committed_weights_as_points(dataset, tmp_path, capsys):
    """`--point ITERATION=WEIGHTS`: weights whose run folder is gone (a rolling run's committed
    snapshots) join the campaign's curve after an earlier session's, each scored exactly as
    a snapshot of a run folder is."""
    common = ["--data", dataset, "--iters", "2", "--batch", "2", "--crop", "16", "--workers", "0", "--log-every", "1",
              "--val-frames", "2", "--val-every", "0", "--device", "cpu", "--snapshot-every", "2"]  # fmt: skip
    a = str(tmp_path / "a")
    res = T.train(["--out", a, *common])
    ja, jp, png = str(tmp_path / "a.json"), str(tmp_path / "p.json"), str(tmp_path / "c.png")
    base = ["--data", dataset, "--split", "val", "--frames", "2", "--out", png]
    assert C.main(["--run", a, *base, "--json", ja]) == 0
    run_point = json.load(open(ja))["monitored"][-1]
    assert C.main([*base, "--json", jp, "--previous", ja, "--point", f"7={res['weights']}"]) == 0
    c = json.load(open(jp))
    assert [r["iteration"] for r in c["monitored"]] == [2, 7] and [r["iteration"] for r in c["train"]] == [1, 2]
    # the same weights score the same, whether a snapshot of a run or a point
    assert abs(c["monitored"][1]["psnr"] - run_point["psnr"]) < 1e-9
    assert c["monitored"][1]["weights"] == os.path.basename(res["weights"])
    capsys.readouterr()
    # bad specs and files are clear errors
    for bad in ("x=w.safetensors", "7"):
        try:
            C.main([*base, "--point", bad])
        except SystemExit as e:
            assert e.code == 2
        assert "expected ITERATION=WEIGHTS" in capsys.readouterr().err
    assert C.main([*base, "--point", f"7={tmp_path / 'missing.safetensors'}"]) == 1
    assert "missing.safetensors" in capsys.readouterr().err
