import json
import os
import shutil

import pytest
import torch

from ssr import losses as L
from ssr import train as T
from ssr.baselines import load_model
from ssr.export import load_weights
from ssr.validation import validate


def args(data, out, *extra, iters=3):
    return [
        "--data", data, "--out", out, "--iters", str(iters), "--batch", "2", "--crop", "16",
        "--workers", "0", "--log-every", "1", "--val-frames", "2", "--val-every", "0",
        "--ckpt-every", "2", "--device", "cpu", *extra,
    ]  # fmt: skip


def test_lr_schedule_and_frame_weights():
    assert [T.lr_at(1.0, i, 9) for i in range(9)] == [1, 1, 1, 0.5, 0.5, 0.5, 0.25, 0.25, 0.25]
    assert T.lr_at(1e-4, 0, 3) == 1e-4 and T.lr_at(1e-4, 1, 3) == 5e-5 and T.lr_at(1e-4, 2, 3) == 2.5e-5
    assert T.frame_weights(5) == (0.05, 0.25, 0.5, 0.75, 1.0)
    assert T.frame_weights(3) == (0.5, 0.75, 1.0)
    assert T.frame_weights(6) == (0.05, 0.05, 0.25, 0.5, 0.75, 1.0)


def test_frame_weights_option():
    from ssr.train import parse_args

    base = ["--data", "d", "--out", "o"]
    assert parse_args(base).frame_weights == (0.05, 0.25, 0.5, 0.75, 1.0)
    assert parse_args([*base, "--window", "8"]).frame_weights == (0.05,) * 4 + (0.25, 0.5, 0.75, 1.0)
    w = parse_args([*base, "--window", "8", "--frame-weights", "0.05,0.25,0.5,0.75,1,1,1,1"]).frame_weights
    assert w == (0.05, 0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 1.0)
    for bad in ["1,1,1", "1,1,1,1,x", "1,1,1,1,-1", "0,0,0,0,0", "1,1,1,1,nan"]:
        with pytest.raises(SystemExit):
            parse_args([*base, "--frame-weights", bad])
    with pytest.raises(ValueError, match="3 weight.*window of 5"):
        T.parse_frame_weights("1,1,1", 5)


def test_loss_weight_overrides():
    from ssr.train import loss_weights, parse_args

    assert loss_weights([]) == L.LAMBDAS
    assert loss_weights(["m=1.5", "a=2"]) == {**L.LAMBDAS, "m": 1.5, "a": 2.0}
    for bad, msg in [("q=1", "TERM one of"), ("m", "TERM one of"), ("m=x", "not a number"), ("m=-1", ">= 0"), ("m=nan", "finite")]:
        with pytest.raises(ValueError, match=msg):
            loss_weights([bad])
    with pytest.raises(SystemExit):
        parse_args(["--data", "d", "--out", "o", "--lambda", "q=1"])
    assert parse_args(["--data", "d", "--out", "o", "--lambda", "m=1"]).lambdas["m"] == 1.0


def test_train_checkpoint_resume_export(dataset, tmp_path, capsys):
    # straight 3 iterations
    a = str(tmp_path / "a")
    res = T.train(args(dataset, a))
    out = capsys.readouterr().out
    assert "it 3/3" in out and "val it 3: PSNR" in out and "wrote" in out
    assert os.path.isfile(os.path.join(a, "checkpoint.pt")) and res["iteration"] == 3
    ck = torch.load(os.path.join(a, "checkpoint.pt"), weights_only=False)
    assert ck["iteration"] == 3 and ck["config"]["lr"] == 1e-4 and len(ck["rng"]) == 1
    assert set(ck) >= {"model", "optimizer", "iteration", "config", "rng", "wall_time_s"}
    model, meta = load_weights(res["weights"])
    prov = meta["provenance"]
    assert prov["iterations"] == 3 and prov["scenes"] == ["synthetic"] and prov["model"] == "ssr"
    assert prov["sequences"]["train"] == ["train/synthetic_000", "train/synthetic_001"]
    assert prov["sequences"]["val"] == ["val/synthetic_000"]
    assert prov["hardware"]["device"] == "cpu" and prov["wall_time_s"] >= 0
    assert meta["metrics"]["split"] == "val" and meta["metrics"]["frames"] == 2 and meta["metrics"]["psnr"] > 0
    for k, v in ck["model"].items():
        assert torch.equal(model.state_dict()[k], v)
    log = [json.loads(l) for l in open(os.path.join(a, "log.jsonl"))]
    assert [r["iteration"] for r in log if r["event"] == "train"] == [1, 2, 3]
    assert [r["lr"] for r in log if r["event"] == "train"] == [1e-4, 5e-5, 2.5e-5]

    # interrupted at 2 (--stop-at), then resumed: the same weights as straight through
    b = str(tmp_path / "b")
    res_b = T.train(args(dataset, b, "--stop-at", "2"))
    assert res_b["iteration"] == 2 and res_b["weights"] is None
    assert torch.load(os.path.join(b, "checkpoint.pt"), weights_only=False)["iteration"] == 2
    with pytest.raises(SystemExit, match="pass --resume"):
        T.train(args(dataset, b))
    res_b = T.train(args(dataset, b, "--resume"))
    out = capsys.readouterr().out
    assert "resumed from" in out and "at iteration 2/3" in out
    assert res_b["iteration"] == 3
    mb, _ = load_weights(res_b["weights"])
    for k, v in model.state_dict().items():
        assert torch.equal(mb.state_dict()[k], v), k

    # resuming with another config names the file and the differing keys
    with pytest.raises(T.CheckpointError, match=r"b/checkpoint\.pt: checkpoint is from another config; differing keys: crop: 16 in the checkpoint, 32 now; lr: 0\.0001 in the checkpoint, 0\.001 now"):
        T.train(args(dataset, b, "--resume", "--lr", "1e-3", "--crop", "32"))
    with pytest.raises(T.CheckpointError, match="model_config"):
        T.train(args(dataset, b, "--resume", "--model-config", '{"enc": [8, 8, 8]}'))
    assert T.main(args(dataset, b, "--resume", "--lr", "1e-3")) == 1
    assert "differing keys: lr" in capsys.readouterr().err

    # a checkpoint written before a late option existed (here `escaped`) resumes: its absence
    # means the option's default
    ck_path = os.path.join(b, "checkpoint.pt")
    ck = torch.load(ck_path, weights_only=False)
    ck["config"]["model_config"].pop("escaped")
    torch.save(ck, ck_path)
    T.train(args(dataset, b, "--resume"))
    assert "resumed from" in capsys.readouterr().out
    # and so does one written before a loss term of weight 0 existed (here `mm`), but not
    # into a run that weighs it
    ck = torch.load(ck_path, weights_only=False)
    ck["config"]["lambdas"].pop("mm")
    torch.save(ck, ck_path)
    T.train(args(dataset, b, "--resume"))
    assert "resumed from" in capsys.readouterr().out
    with pytest.raises(T.CheckpointError, match="lambdas"):
        T.train(args(dataset, b, "--resume", "--lambda", "mm=5"))


def test_the_metal_brightness_term_trains_and_is_logged(dataset, tmp_path, capsys):
    """`--lambda mm=W` runs through the SSR model's sequence loss (the frames' metallic)."""
    res = T.train(args(dataset, str(tmp_path / "mm"), "--lambda", "mm=5", iters=2))
    log = [json.loads(l) for l in open(os.path.join(str(tmp_path / "mm"), "log.jsonl"))]
    train = [r for r in log if r["event"] == "train"]
    assert len(train) == 2 and all("l_mm" in json.dumps(r) for r in train)
    assert res["iteration"] == 2


def test_colour_permutation_trains_records_and_is_part_of_the_config(dataset, tmp_path, capsys):
    # --color-permute changes what the network is shown (other weights than the same run
    # without it), is recorded in the provenance, and a resume without it is refused.
    plain = T.train(args(dataset, str(tmp_path / "plain"), iters=2))
    perm_dir = str(tmp_path / "perm")
    perm = T.train(args(dataset, perm_dir, "--color-permute", iters=2))
    mp, _ = load_weights(plain["weights"])
    mc, meta = load_weights(perm["weights"])
    assert any(not torch.equal(mp.state_dict()[k], v) for k, v in mc.state_dict().items())
    assert meta["provenance"]["augmentation"]["color_permute"] is True
    assert load_weights(plain["weights"])[1]["provenance"]["augmentation"]["color_permute"] is False
    with pytest.raises(T.CheckpointError, match="color_permute"):
        T.train(args(dataset, perm_dir, "--resume", iters=4))


def test_a_signal_stops_after_the_iteration_with_a_checkpoint(dataset, tmp_path, capsys, monkeypatch):
    """kill (SIGTERM) during iteration 2 of 3: the run writes a checkpoint at 2 (not at the
    last --ckpt-every, 0) and returns; --resume ends with the weights of a straight run."""
    import signal

    a = str(tmp_path / "a")
    straight, _ = load_weights(T.train(args(dataset, a, "--ckpt-every", "100"))["weights"])

    calls = {"n": 0}
    real_loss = T.compute_loss

    def loss_then_kill(*a_, **k_):
        calls["n"] += 1
        if calls["n"] == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        return real_loss(*a_, **k_)

    monkeypatch.setattr(T, "compute_loss", loss_then_kill)
    b = str(tmp_path / "b")
    res = T.train(args(dataset, b, "--ckpt-every", "100"))
    monkeypatch.setattr(T, "compute_loss", real_loss)
    assert res["iteration"] == 2 and res["weights"] is None
    assert "stopped at iteration 2/3 (SIGTERM)" in capsys.readouterr().out
    assert torch.load(os.path.join(b, "checkpoint.pt"), weights_only=False)["iteration"] == 2
    # the handler is gone after the run: the default action is back
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    resumed, _ = load_weights(T.train(args(dataset, b, "--resume", "--ckpt-every", "100"))["weights"])
    for k, v in straight.state_dict().items():
        assert torch.equal(resumed.state_dict()[k], v), k


def test_a_signal_to_the_process_group_stops_with_a_checkpoint(dataset, tmp_path):
    """SIGTERM to the whole process group (as `timeout` sends it) while DataLoader workers
    run: the workers leave it to the main process, which checkpoints and exits cleanly."""
    import signal
    import subprocess
    import sys

    out = str(tmp_path / "run")
    cmd = [sys.executable, "-u", "-m", "ssr.train", *args(dataset, out, "--workers", "2", "--ckpt-every", "100000", iters=100000)]
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.Popen(cmd, cwd=here, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines = []
    for line in p.stdout:
        lines.append(line)
        if "it 3/" in line:  # the workers are running
            os.killpg(p.pid, signal.SIGTERM)
            break
    rest, _ = p.communicate(timeout=120)
    text = "".join(lines) + rest
    assert p.returncode == 0, text
    assert "(SIGTERM)" in text and "stopped at iteration" in text, text
    ck = torch.load(os.path.join(out, "checkpoint.pt"), weights_only=False)
    assert ck["iteration"] >= 3


def test_init_from_weights_and_snapshots(dataset, tmp_path, capsys):
    # a run of 2 iterations with snapshots every iteration
    a = str(tmp_path / "a")
    res = T.train(args(dataset, a, "--snapshot-every", "1", iters=2))
    snaps = sorted(os.listdir(os.path.join(a, "snapshots")))
    assert snaps == ["it_0000001.pt", "it_0000001.safetensors", "it_0000002.pt", "it_0000002.safetensors"]
    snaps = [s for s in snaps if s.endswith(".safetensors")]
    final, _ = load_weights(res["weights"])
    snap2, meta2 = load_weights(os.path.join(a, "snapshots", snaps[-1]))
    assert meta2["provenance"]["iterations"] == 2
    for k, v in final.state_dict().items():
        assert torch.equal(snap2.state_dict()[k], v), k

    # a new run starting from those weights begins exactly there (fresh optimizer) and says so
    b = str(tmp_path / "b")
    res_b = T.train(args(dataset, b, "--init", res["weights"], "--stop-at", "1", iters=3))
    assert "initialised from" in capsys.readouterr().out
    ck = torch.load(os.path.join(b, "checkpoint.pt"), weights_only=False)
    assert ck["config"]["init"]["file"] == "weights.safetensors" and len(ck["config"]["init"]["sha256"]) == 64
    moved = [k for k, v in final.state_dict().items() if not torch.equal(ck["model"][k], v)]
    assert moved, "one step from the initial weights changes them"
    res_b = T.train(args(dataset, b, "--init", res["weights"], "--resume", iters=3))
    _, meta_b = load_weights(res_b["weights"])
    assert meta_b["provenance"]["init"]["file"] == "weights.safetensors"
    assert meta_b["provenance"]["init"]["provenance"]["iterations"] == 2

    # resuming without the init it started from is refused (another config)
    with pytest.raises(T.CheckpointError, match="init"):
        T.train(args(dataset, b, "--resume", iters=3))
    # weights of another config are refused, naming the file
    other = str(tmp_path / "other")
    res_o = T.train(args(dataset, other, "--model-config", '{"enc": [8, 8, 8]}', iters=1))
    assert T.main(args(dataset, str(tmp_path / "c"), "--init", res_o["weights"])) == 1
    err = capsys.readouterr().err
    assert "--init" in err and "other/weights.safetensors" in err and "config" in err


def test_init_at_continues_a_schedule_from_its_snapshot(dataset, tmp_path, capsys):
    # A 6-iteration run, and its snapshot at iteration 4 continued with --init-at 4: the second
    # run does iterations 4..6 at the first run's learning rates (lr halved at 2 and 4), samples
    # the windows the first run sampled there, and records where it began.
    a = str(tmp_path / "a")
    T.train(args(dataset, a, "--snapshot-every", "2", "--lr", "1e-3", iters=6))
    lrs_a = {e["iteration"]: e["lr"] for e in map(json.loads, open(os.path.join(a, "log.jsonl"))) if e.get("event") == "train"}
    b = str(tmp_path / "b")
    snap = os.path.join(a, "snapshots", "it_0000004.safetensors")
    res = T.train(args(dataset, b, "--init", snap, "--init-at", "4", "--lr", "1e-3", iters=6))
    assert "beginning at iteration 4/6" in capsys.readouterr().out
    lrs_b = {e["iteration"]: e["lr"] for e in map(json.loads, open(os.path.join(b, "log.jsonl"))) if e.get("event") == "train"}
    assert sorted(lrs_b) == [5, 6] and all(lrs_b[i] == lrs_a[i] for i in lrs_b), (lrs_a, lrs_b)
    _, meta = load_weights(res["weights"])
    prov = meta["provenance"]
    assert prov["iterations"] == 6 and prov["init_at"] == 4 and prov["campaign_iterations"] == 6
    # it resumes like any run, and is refused without --init or past the end
    T.train(args(dataset, b, "--init", snap, "--init-at", "4", "--lr", "1e-3", "--resume", iters=6))
    # a restore point of such a run continues it exactly in a new folder, given the run's
    # options (its --init and --init-at), and is refused without them
    b2 = str(tmp_path / "b2")
    T.train(args(dataset, b2, "--init", snap, "--init-at", "4", "--lr", "1e-3", "--snapshot-every", "5", iters=6))
    straight, _ = load_weights(os.path.join(b2, "weights.safetensors"))
    point = os.path.join(b2, "snapshots", "it_0000005.pt")
    c2 = str(tmp_path / "c2")
    res = T.train(args(dataset, c2, "--resume-from", point, "--init", snap, "--init-at", "4", "--lr", "1e-3", iters=6))
    restored, meta = load_weights(res["weights"])
    for k, v in straight.state_dict().items():
        assert torch.equal(restored.state_dict()[k], v), k
    assert meta["provenance"]["init_at"] == 4 and meta["provenance"]["campaign_iterations"] == 6
    with pytest.raises(T.CheckpointError, match=r"differing keys: init_at: 4 in the checkpoint"):
        T.train(args(dataset, str(tmp_path / "c3"), "--resume-from", point, "--init", snap, "--lr", "1e-3", iters=6))
    with pytest.raises(SystemExit):
        T.train(args(dataset, str(tmp_path / "c"), "--init-at", "2"))
    assert "--init-at needs --init" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        T.train(args(dataset, str(tmp_path / "c"), "--init", snap, "--init-at", "3", iters=3))
    assert "0 <= N < --iters" in capsys.readouterr().err


def test_train_baseline_exports(dataset, tmp_path):
    out = str(tmp_path / "rae")
    res = T.train(args(dataset, out, "--model", "rae", "--model-config", '{"enc": [8, 8], "bottleneck": 8}', iters=1))
    model, meta = load_model(res["weights"])
    assert meta["format"] == "subpixel-baseline-rae" and meta["provenance"]["model"] == "rae"
    assert model.cfg.enc == (8, 8) and meta["metrics"]["frames"] == 2


def test_dataset_errors_are_reported(dataset, tmp_path, capsys):
    broken = str(tmp_path / "ds")
    shutil.copytree(dataset, broken)
    os.remove(os.path.join(broken, "train", "synthetic_001", "frame_0004.exr"))
    assert T.main(args(broken, str(tmp_path / "run"))) == 1
    assert "synthetic_001/frame_0004.exr: missing frame" in capsys.readouterr().err


@pytest.mark.skipif(not os.environ.get("SUBPIXEL_SLOW_TESTS"), reason="starts 2 processes (~20 s); set SUBPIXEL_SLOW_TESTS=1")
def test_torchrun_ddp_two_cpu_processes(dataset, tmp_path):
    import subprocess
    import sys

    out = str(tmp_path / "ddp")
    training = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", "-m", "ssr.train",
           *args(dataset, out, "--batch", "4")]  # fmt: skip
    env = dict(os.environ, OMP_NUM_THREADS="1")
    p = subprocess.run(cmd, cwd=training, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "batch 4 (2 x 2)" in p.stdout and p.stdout.count("it 3/3") == 1  # rank 0 prints
    ck = torch.load(os.path.join(out, "checkpoint.pt"), weights_only=False)
    assert len(ck["rng"]) == 2 and ck["iteration"] == 3
    _, meta = load_weights(os.path.join(out, "weights.safetensors"))
    assert meta["provenance"]["hardware"]["processes"] == 2


def test_background_scores_val_and_trains_on_the_engines_output(tmp_path, capsys):
    """--background val: validation scores the engine's output (the background where coverage
    is 1; here the synthetic sky's background is its reference, so the score rises and nothing
    else changes); --background loss: the loss sees it too, recorded in the config and the
    provenance; frames without the channels are an error naming one."""
    from ssr.synth import write_dataset

    root = write_dataset(str(tmp_path / "d"), {"train": 2, "val": 1}, 6, 16, 16, background=True)
    plain = T.train(args(root, str(tmp_path / "plain"), iters=1))
    val = T.train(args(root, str(tmp_path / "val"), "--background", "val", iters=1))
    mp, _ = load_weights(plain["weights"])
    mv, _ = load_weights(val["weights"])
    for k, v in mp.state_dict().items():
        assert torch.equal(mv.state_dict()[k], v), k
    assert val["metrics"]["psnr"] > plain["metrics"]["psnr"]
    loss = T.train(args(root, str(tmp_path / "loss"), "--background", "loss", iters=2))
    _, meta = load_weights(loss["weights"])
    assert meta["provenance"]["background"] == "loss"
    ck = torch.load(os.path.join(str(tmp_path / "loss"), "checkpoint.pt"), weights_only=False)
    assert ck["config"]["background"] == "loss"
    bare = write_dataset(str(tmp_path / "bare"), {"train": 1, "val": 1}, 6, 16, 16)
    capsys.readouterr()
    assert T.main(args(bare, str(tmp_path / "e"), "--background", "loss")) == 1
    err = capsys.readouterr().err
    assert "background" in err and "frame_0000.exr" in err, err


def test_mean_correction_in_the_loss_and_in_val(tmp_path, capsys, monkeypatch):
    """Weights with the engine's mean correction (`mean_correction = "tiles"`) start a run
    whose config, validation (model.MeanCorrection after the composite) and exported file keep
    it; `--mean-correction loss` trains through it, recorded in the checkpoint's config and the
    provenance, and needs `--background loss`."""
    from ssr.export import set_options
    from ssr.synth import write_dataset

    root = write_dataset(str(tmp_path / "d"), {"train": 2, "val": 1}, 6, 16, 16, background=True)
    base = T.train(args(root, str(tmp_path / "base"), "--background", "val", iters=1))
    tiles = str(tmp_path / "tiles.safetensors")
    set_options(base["weights"], ["mean_correction=tiles"], tiles)
    plain = T.train(args(root, str(tmp_path / "plain"), "--background", "val", "--init", base["weights"], iters=1))
    run = T.train(args(root, str(tmp_path / "run"), "--background", "val", "--init", tiles, iters=1))
    m_plain, _ = load_weights(plain["weights"])
    m_run, meta = load_weights(run["weights"])
    assert meta["config"].mean_correction == "tiles"
    for k, v in m_plain.state_dict().items():
        assert torch.equal(m_run.state_dict()[k], v), k  # the loss did not see it: same weights
    assert run["metrics"]["psnr"] != plain["metrics"]["psnr"]  # val did
    # ... unless told to score the network's own output (the learning curves)
    from ssr.data import SequenceDataset

    ds = SequenceDataset(root, "val", window=1, crop=None, flips=False, extra=("background", "coverage"))
    own = [validate(m, ds, torch.device("cpu"), 2, output_pass=False)["psnr"] for m in (m_plain, m_run)]
    assert own[0] == own[1]
    loss = T.train(args(root, str(tmp_path / "loss"), "--background", "loss", "--mean-correction", "loss",
                        "--init", tiles, iters=1))
    _, meta = load_weights(loss["weights"])
    assert meta["provenance"]["mean_correction"] == "loss" and meta["config"].mean_correction == "tiles"
    ck = torch.load(os.path.join(str(tmp_path / "loss"), "checkpoint.pt"), weights_only=False)
    assert ck["config"]["mean_correction"] == "loss"
    m_loss, _ = load_weights(loss["weights"])
    assert any(not torch.equal(m_loss.state_dict()[k], v) for k, v in m_run.state_dict().items())
    # An output-pass option may differ from the initial weights' (it is applied after the
    # network): 16-pixel tiles, in the file and in the loss.
    used = []
    real = T.mean_correction_of

    def spy(cfg):
        mc = real(cfg)
        used.append(mc.tile)
        return mc

    monkeypatch.setattr(T, "mean_correction_of", spy)
    sixteen = T.train(args(root, str(tmp_path / "sixteen"), "--background", "loss", "--mean-correction", "loss",
                           "--init", tiles, "--model-config", '{"mean_correction": "tiles16"}', iters=1))
    _, meta = load_weights(sixteen["weights"])
    assert meta["config"].mean_correction == "tiles16"
    assert used and set(used) == {16}, used
    capsys.readouterr()
    with pytest.raises(SystemExit):
        T.main(args(root, str(tmp_path / "e"), "--mean-correction", "loss"))
    assert "--background loss" in capsys.readouterr().err


def test_footprint_albedo_fine_tune_from_centre_weights(tmp_path, capsys):
    """A run with config albedo = "footprint" loads the frames' footprint albedo, may start
    from weights trained with the centre albedo (the option changes what the network is fed,
    not its parameters), validates with it and writes it into its weights; on a dataset
    without the buffer it stops naming it."""
    from ssr.synth import write_dataset

    data = write_dataset(str(tmp_path / "d"), {"train": 1, "val": 1}, 6, 16, 16, seed=5, background=True)
    centre = T.train(args(data, str(tmp_path / "c"), iters=1))
    fp = '{"albedo": "footprint"}'
    res = T.train(args(data, str(tmp_path / "f"), "--init", centre["weights"], "--model-config", fp, "--val-every", "1", iters=2))
    model, meta = load_weights(res["weights"])
    assert model.cfg.albedo == "footprint" and meta["provenance"]["init"]["file"] == "weights.safetensors"
    assert "initialised from" in capsys.readouterr().out
    # another option than the albedo still has to match the initial weights
    assert T.main(args(data, str(tmp_path / "g"), "--init", centre["weights"], "--model-config", '{"history": "screen"}')) == 1
    assert "differs from the run's" in capsys.readouterr().err
    bare = write_dataset(str(tmp_path / "bare"), {"train": 1, "val": 1}, 6, 16, 16, seed=5)
    assert T.main(args(bare, str(tmp_path / "h"), "--model-config", fp, iters=1)) == 1
    err = capsys.readouterr().err
    assert "frame_0000.exr: missing channel(s) ['albedo_footprint.R'" in err, err


def test_a_run_from_weights_keeps_their_albedo_unless_told(tmp_path):
    """Continuing weights of config albedo = "footprint" (the shipped model) trains on the
    footprint albedo without saying so; --model-config can still set it back."""
    from ssr.synth import write_dataset

    data = write_dataset(str(tmp_path / "d"), {"train": 1, "val": 1}, 6, 16, 16, seed=6, background=True)
    fp = T.train(args(data, str(tmp_path / "f"), "--model-config", '{"albedo": "footprint"}', iters=1))
    cont = T.train(args(data, str(tmp_path / "c"), "--init", fp["weights"], iters=1))
    assert load_weights(cont["weights"])[0].cfg.albedo == "footprint"
    back = T.train(args(data, str(tmp_path / "b"), "--init", fp["weights"], "--model-config", '{"albedo": "centre"}', iters=1))
    assert load_weights(back["weights"])[0].cfg.albedo == "centre"


def test_emission_fine_tune_from_weights(tmp_path, capsys):
    """A run with config emission = "background" may start from weights trained with the
    emission left to the network (the option changes what the network is fed, not its
    parameters), loads the frames' directly seen emission, trains and validates on the
    composited output and writes the option into its weights; without --background loss it
    stops saying so; on a dataset without the buffers it stops naming them."""
    from ssr.synth import write_dataset

    data = write_dataset(str(tmp_path / "d"), {"train": 1, "val": 1}, 6, 16, 16, seed=7, background=True, emission=True)
    plain = T.train(args(data, str(tmp_path / "p"), "--background", "loss", iters=1))
    em = '{"emission": "background"}'
    res = T.train(
        args(data, str(tmp_path / "e"), "--init", plain["weights"], "--model-config", em, "--background", "loss", "--val-every", "1", iters=2)
    )
    model, meta = load_weights(res["weights"])
    assert model.cfg.emission == "background" and meta["provenance"]["init"]["file"] == "weights.safetensors"
    capsys.readouterr()
    with pytest.raises(SystemExit, match="--background loss"):
        T.train(args(data, str(tmp_path / "n"), "--model-config", em, iters=1))
    bare = write_dataset(str(tmp_path / "bare"), {"train": 1, "val": 1}, 6, 16, 16, seed=7, background=True)
    assert T.main(args(bare, str(tmp_path / "h"), "--model-config", em, "--background", "loss", iters=1)) == 1
    err = capsys.readouterr().err
    assert "missing channel(s) ['emission.R'" in err, err


def test_a_restore_point_resumes_the_run_exactly_in_a_new_folder(dataset, tmp_path, capsys):
    # The snapshot's checkpoint (it_NNNNNNN.pt beside the weights) is a restore point: a run
    # in another folder (another machine) continued from it with --resume-from ends with the
    # straight run's weights to the bit (Adam's moments, RNG and iteration carried over).
    a = str(tmp_path / "a")
    T.train(args(dataset, a, "--snapshot-every", "2", "--lr", "1e-3", iters=6))
    straight, _ = load_weights(os.path.join(a, "weights.safetensors"))
    point = os.path.join(a, "snapshots", "it_0000004.pt")
    ck = torch.load(point, weights_only=False)
    assert ck["iteration"] == 4 and ck["optimizer"]["state"], "the restore point holds Adam's moments"
    assert os.path.isfile(os.path.join(a, "snapshots", "it_0000004.safetensors"))
    c = str(tmp_path / "c")
    # stopped part-way, then the same command again: it goes on from its own checkpoint
    T.train(args(dataset, c, "--resume-from", point, "--lr", "1e-3", "--stop-at", "5", iters=6))
    out = capsys.readouterr().out
    assert f"resumed from {point} at iteration 4/6" in out
    events = [json.loads(l) for l in open(os.path.join(c, "log.jsonl"))]
    assert events[0]["event"] == "restore" and events[0]["iteration"] == 4
    assert os.path.isfile(os.path.join(c, "run.json"))
    res = T.train(args(dataset, c, "--resume-from", point, "--lr", "1e-3", iters=6))
    assert "resumed from " + os.path.join(c, "checkpoint.pt") + " at iteration 5/6" in capsys.readouterr().out
    restored, meta = load_weights(res["weights"])
    for k, v in straight.state_dict().items():
        assert torch.equal(restored.state_dict()[k], v), k
    assert meta["provenance"]["iterations"] == 6
    # another config is refused, naming the file and the keys (a start part-way through the
    # schedule is part of the run's options)
    with pytest.raises(T.CheckpointError, match=r"it_0000004\.pt: checkpoint is from another config; differing keys: lr"):
        T.train(args(dataset, str(tmp_path / "d"), "--resume-from", point, iters=6))
    snap = os.path.join(a, "snapshots", "it_0000004.safetensors")
    with pytest.raises(T.CheckpointError, match=r"differing keys: init: .*; init_at: "):
        T.train(args(dataset, str(tmp_path / "e"), "--resume-from", point, "--init", snap, "--init-at", "4",
                     "--lr", "1e-3", iters=6))
    with pytest.raises(SystemExit):
        T.train(args(dataset, str(tmp_path / "e"), "--resume-from", str(tmp_path / "none.pt"), iters=6))
    assert "no such file" in capsys.readouterr().err


def test_the_reference_noise_threshold_is_not_part_of_the_resume_config(tmp_path):
    # --min-reference-psnr chooses training sequences, as --data does: a run may resume with
    # another threshold (F14 resumes F13's checkpoint, written with 22 dB, with 0), and a
    # checkpoint that still holds the key compares as one without it; other keys still count.
    base = args(str(tmp_path / "data"), str(tmp_path / "out"))
    cfg = T.run_config(T.parse_args(base))
    assert T.run_config(T.parse_args(base + ["--min-reference-psnr", "22"])) == cfg
    assert "min_reference_psnr" not in cfg
    path = str(tmp_path / "checkpoint.pt")
    old = {**cfg, "min_reference_psnr": 22.0}
    T.save_checkpoint(path, {"format": T.CHECKPOINT_FORMAT, "version": T.CHECKPOINT_VERSION, "config": old, "iteration": 3})
    assert T.load_checkpoint(path, cfg)["iteration"] == 3
    with pytest.raises(T.CheckpointError, match="differing keys: crop: 16 in the checkpoint, 32 now$"):
        T.load_checkpoint(path, {**cfg, "crop": 32})
