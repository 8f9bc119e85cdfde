//! The `subpixel` binary end to end on tiny data: denoise a folder, score it, and the
//! errors a user sees for bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use subpixel::io::exr::{FrameFile, read_frame, write_frame};
use subpixel::io::frames::frame_name;
use subpixel::nn::HostTensor;
use subpixel::ssr::HostFrame;

/// The binary on one fixed convolution tiling, [`FIXED_KERNEL`]: the tests below are about
/// what the commands do, not which kernels they pick (that is `bench kernels`' test here and
/// the autotuner's in tests/ssr_api.rs and tests/kernels.rs). A first autotuning of the
/// network compiles every candidate kernel of every layer shape, which on a CPU Vulkan
/// driver with a cold shader cache takes tens of minutes; one tiling is compiled once and
/// then found in the driver's shader cache by every later process. Its choices also follow
/// timings, which a loaded machine can flip between two processes, and another tiling sums
/// in another order: tests that compare two runs bit for bit need both on the same kernels.
fn bin() -> Command {
    bin_at(Path::new(env!("CARGO_BIN_EXE_subpixel")))
}

/// The tiling every command of these tests runs (`SUBPIXEL_CONV_KERNEL`) unless it says
/// otherwise.
const FIXED_KERNEL: &str = "px16-cob1";

/// The binary at `exe` (the test binary's, or a copy of it) on [`FIXED_KERNEL`].
fn bin_at(exe: &Path) -> Command {
    let mut c = Command::new(exe);
    c.env("SUBPIXEL_CONV_KERNEL", FIXED_KERNEL);
    c
}

/// `subpixel bench denoise` of the network alone at 16x16.
fn bench16() -> Command {
    let mut c = bin();
    c.args([
        "bench",
        "denoise",
        "--width",
        "16",
        "--height",
        "16",
        "--model-only",
    ]);
    c
}

/// The stderr of the run `o`, asserting that it succeeded.
fn succeeded(o: &Output) -> String {
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{stderr}");
    stderr
}

/// The stderr of the run `o` (`what` names it), asserting that it failed.
fn failed(o: &Output, what: impl std::fmt::Display) -> String {
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(!o.status.success(), "{what} succeeded: {stdout}");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts that `text` contains each of `parts`.
fn assert_contains_all(text: &str, parts: &[&str]) {
    for part in parts {
        assert!(text.contains(part), "no '{part}' in: {text}");
    }
}

/// Copies frames `0..n` of the frame folder `from` into `to` (created if missing).
fn copy_frames(n: usize, from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for i in 0..n {
        let name = frame_name(i);
        std::fs::copy(from.join(&name), to.join(&name)).unwrap();
    }
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("subpixel-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `subpixel denoise` of the frame folder `input` into `out` with the golden weights.
fn golden_denoise(input: &Path, out: &Path) -> Command {
    denoise_cmd(&data("golden_weights.safetensors"), input, out)
}

/// `subpixel denoise --weights W --input I --out O`.
fn denoise_cmd(weights: &Path, input: &Path, out: &Path) -> Command {
    let mut c = bin();
    c.args(["denoise", "--weights"])
        .arg(weights)
        .arg("--input")
        .arg(input)
        .arg("--out")
        .arg(out);
    c
}

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// The golden frames as a frame folder, with the PyTorch output as the "reference".
/// Writes the three golden frames into `dir` (created if missing).
fn golden_folder(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    for i in 0..3 {
        let bytes = std::fs::read(data(&format!("golden_frame{i}.safetensors"))).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let t = |n: &str| {
            let v = st.tensor(n).unwrap();
            let s = v.shape();
            let vals = v
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            HostTensor::from_vec(s[1] as u32, s[0] as u32, s[2] as u32, vals)
        };
        let frame = HostFrame {
            color: t("color"),
            mask: t("mask"),
            albedo: t("albedo"),
            normal: t("normal"),
            shadow: t("shadow"),
            transparent: t("transparent"),
            depth: t("depth"),
            metallic: t("metallic"),
            roughness: t("roughness"),
            motion: t("motion"),
            background: None,
        };
        let f = FrameFile {
            frame: Some(frame),
            reference: Some(t("output")),
            ..Default::default()
        };
        write_frame(&dir.join(format!("frame_{i:04}.exr")), &f).unwrap();
    }
}

#[test]
fn denoise_then_eval_a_frame_folder() {
    let input = tmp("in");
    let out = tmp("out");
    golden_folder(&input);
    let o = golden_denoise(&input, &out).arg("--png").output().unwrap();
    let stderr = succeeded(&o);
    assert!(
        stderr.contains("random test weights"),
        "random weights must be flagged: {stderr}"
    );
    for i in 0..3 {
        let f = read_frame(&out.join(format!("frame_{i:04}.exr"))).unwrap();
        assert_eq!(f.pred.unwrap().width, 40);
        let png = image::open(out.join(format!("frame_{i:04}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (120, 24), "input | SSR | reference");
    }
    // The reference is PyTorch's output for the same weights: near-perfect scores.
    let o = bin()
        .args(["eval", "--json", "--pred"])
        .arg(&out)
        .arg("--ref")
        .arg(&input)
        .output()
        .unwrap();
    succeeded(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["frames"], 3);
    assert!(v["psnr"].as_f64().unwrap() > 50.0, "{v}");
    assert!(v["ssim"].as_f64().unwrap() > 0.999, "{v}");
    assert!(v["temporal"].as_f64().unwrap() < 1e-3, "{v}");
    assert!(v["brightness"].as_f64().unwrap() < 1e-3, "{v}");
    // The Table 1 layout over a dataset root with two methods.
    let root = tmp("table-root");
    let pred = tmp("table-pred");
    let seq = root.join("test/golden_test_000");
    std::fs::create_dir_all(&seq).unwrap();
    std::fs::write(seq.join("sequence.json"), r#"{"scene": "builtin:golden"}"#).unwrap();
    for i in 0..3 {
        let name = format!("frame_{i:04}.exr");
        std::fs::copy(input.join(&name), seq.join(&name)).unwrap();
        let ssr_dir = pred.join("ssr/test/golden_test_000");
        let in_dir = pred.join("input/test/golden_test_000");
        std::fs::create_dir_all(&ssr_dir).unwrap();
        std::fs::create_dir_all(&in_dir).unwrap();
        std::fs::copy(out.join(&name), ssr_dir.join(&name)).unwrap();
        let raw = read_frame(&input.join(&name)).unwrap().frame.unwrap().color;
        write_frame(
            &in_dir.join(&name),
            &FrameFile {
                pred: Some(raw),
                ..Default::default()
            },
        )
        .unwrap();
    }
    let o = bin()
        .args(["eval", "--table", "--json", "--pred"])
        .arg(&pred)
        .arg("--ref")
        .arg(&root)
        .output()
        .unwrap();
    succeeded(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let psnr = |m: usize| v[m]["scenes"]["golden"]["psnr"].as_f64().unwrap();
    assert_eq!(
        (v[0]["method"].as_str(), v[1]["method"].as_str()),
        (Some("input"), Some("ssr"))
    );
    assert!(
        psnr(1) > psnr(0) + 10.0,
        "the raw input scores far below the matching prediction: {v}"
    );
    // the 1/4-spp input holds a quarter of the light: a brightness error near ln 4
    let brightness = |m: usize| v[m]["scenes"]["golden"]["brightness"].as_f64().unwrap();
    assert!(brightness(1) < 1e-3 && brightness(0) > 0.5, "{v}");
    let o = bin()
        .args(["eval", "--table", "--pred"])
        .arg(&pred)
        .arg("--ref")
        .arg(&root)
        .output()
        .unwrap();
    let md = String::from_utf8_lossy(&o.stdout);
    assert_contains_all(&md, &["| method | golden | mean |", "| ssr |"]);
    // Procedural scenes (one per seed) share one column; --scenes picks and orders columns.
    for seed in [5, 9] {
        let name = format!("procedural_{seed}_test_000");
        let seq = root.join("test").join(&name);
        std::fs::create_dir_all(&seq).unwrap();
        std::fs::write(
            seq.join("sequence.json"),
            format!(r#"{{"scene": "procedural_{seed}"}}"#),
        )
        .unwrap();
        for m in ["ssr", "input"] {
            let dst = pred.join(m).join("test").join(&name);
            std::fs::create_dir_all(&dst).unwrap();
            for i in 0..3 {
                let f = format!("frame_{i:04}.exr");
                std::fs::copy(root.join("test/golden_test_000").join(&f), seq.join(&f)).unwrap();
                std::fs::copy(pred.join(m).join("test/golden_test_000").join(&f), dst.join(&f)).unwrap();
            }
        }
    }
    let table = |extra: &[&str]| {
        bin()
            .args(["eval", "--table", "--pred"])
            .arg(&pred)
            .arg("--ref")
            .arg(&root)
            .args(extra)
            .output()
            .unwrap()
    };
    let o = table(&[]);
    let md = String::from_utf8_lossy(&o.stdout);
    assert!(md.contains("| method | golden | procedural | mean |"), "{md}");
    let o = table(&["--scenes", "procedural,golden", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v[1]["scenes"]["procedural"]["sequences"], 2, "{v}");
    let same = |a: &str, b: &str| {
        (v[1]["scenes"][a]["psnr"].as_f64().unwrap() - v[1]["scenes"][b]["psnr"].as_f64().unwrap()).abs()
            < 1e-9
    };
    assert!(same("procedural", "golden"), "same frames, same score: {v}");
    let o = table(&["--scenes", "procedural,golden"]);
    let md = String::from_utf8_lossy(&o.stdout);
    assert!(md.contains("| method | procedural | golden | mean |"), "{md}");
    // --per-sequence: a column per sequence; --scenes still picks and orders the scenes.
    let o = table(&["--scenes", "procedural", "--per-sequence", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let cells = v[1]["scenes"].as_object().unwrap();
    assert_eq!(
        cells.keys().collect::<Vec<_>>(),
        ["procedural_5_test_000", "procedural_9_test_000"],
        "{v}"
    );
    assert_eq!(cells["procedural_9_test_000"]["sequences"], 1, "{v}");
    let o = table(&["--scenes", "procedural,golden", "--per-sequence"]);
    let md = String::from_utf8_lossy(&o.stdout);
    assert!(
        md.contains("| method | procedural_5_test_000 | procedural_9_test_000 | golden_test_000 | mean |"),
        "{md}"
    );
    // --per-frame: a column per frame index, the mean of that frame over the chosen scenes'
    // sequences; the frames' mean is the sequence's score (every frame weighs the same).
    let o = table(&["--scenes", "golden", "--per-frame", "--json"]);
    let f: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let o = table(&["--scenes", "golden", "--json"]);
    let g: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let frames = f[1]["scenes"].as_object().unwrap();
    assert_eq!(
        frames.keys().collect::<Vec<_>>(),
        ["frame 0", "frame 1", "frame 2"],
        "{f}"
    );
    let mean_psnr = frames.values().map(|c| c["psnr"].as_f64().unwrap()).sum::<f64>() / 3.0;
    assert!(
        (mean_psnr - g[1]["scenes"]["golden"]["psnr"].as_f64().unwrap()).abs() < 1e-9,
        "{f} {g}"
    );
    assert!(
        frames["frame 0"]["temporal"].is_null() && frames["frame 1"]["temporal"].is_f64(),
        "{f}"
    );
    assert_eq!(frames["frame 2"]["sequences"], 1, "{f}");
    let md = String::from_utf8_lossy(&table(&["--per-frame"]).stdout).to_string();
    assert!(
        md.contains("| method | frame 0 | frame 1 | frame 2 | mean |"),
        "{md}"
    );
    let o = table(&["--per-frame", "--per-sequence"]);
    assert!(!o.status.success(), "the two column choices exclude each other");
    // A method without predictions for some sequences: its cell says how many it covers,
    // the row's mean how many scenes, and a warning names the method.
    std::fs::remove_dir_all(pred.join("input/test/procedural_9_test_000")).unwrap();
    let o = table(&[]);
    let (md, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    let input_row = md
        .lines()
        .find(|l| l.starts_with("| input |"))
        .unwrap_or_default();
    let ssr_row = md.lines().find(|l| l.starts_with("| ssr |")).unwrap_or_default();
    assert!(input_row.contains("(1 of 2 sequences)"), "{md}");
    assert!(!ssr_row.contains(" of "), "{md}");
    assert!(
        err.contains("warning: input has predictions for 1 of the 2 test sequences of procedural"),
        "{err}"
    );
    std::fs::remove_dir_all(pred.join("input/test/golden_test_000")).unwrap();
    let md = String::from_utf8_lossy(&table(&[]).stdout).to_string();
    let input_row = md
        .lines()
        .find(|l| l.starts_with("| input |"))
        .unwrap_or_default();
    assert!(
        input_row.contains("| - |") && input_row.ends_with("(1 of 2 scenes) |"),
        "{md}"
    );
    let o = table(&["--scenes", "nope"]);
    let err = failed(&o, "--scenes nope");
    assert!(err.contains("no predictions for scene 'nope'"), "{err}");
    for d in [&root, &pred] {
        std::fs::remove_dir_all(d).ok();
    }
    std::fs::remove_dir_all(&input).ok();
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn bad_input_gives_clear_errors() {
    let input = tmp("bad");
    golden_folder(&input);
    std::fs::remove_file(input.join("frame_0001.exr")).unwrap();
    let o = golden_denoise(&input, &input.join("out")).output().unwrap();
    let stderr = failed(&o, "a missing frame");
    assert!(stderr.contains("frame_0001.exr is missing"), "{stderr}");
    let o = bin()
        .args(["denoise", "--weights", "/nonexistent.safetensors", "--input"])
        .arg(&input)
        .args(["--out", "/tmp/x"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent.safetensors"));
    std::fs::remove_dir_all(&input).ok();
}

/// Every command that loads a scene takes `--props` (one option, `SceneOptions`): a props
/// folder that does not exist is an error naming it, from each of them.
#[test]
fn every_command_that_loads_a_scene_takes_props() {
    let out = tmp("props-everywhere");
    let tiny = ["--width", "16", "--height", "16"];
    let props = [
        "--scene",
        "builtin:procedural:3",
        "--props",
        "/nonexistent/props-dir",
    ];
    let runs: [(&str, Vec<&str>); 4] = [
        ("render", vec!["render", "--frames", "1", "--backend", "cpu"]),
        (
            "dataset",
            vec!["dataset", "--split", "val", "--frames", "1", "--backend", "cpu"],
        ),
        (
            "bench render",
            vec!["bench", "render", "--backend", "cpu", "--spp", "1"],
        ),
        ("run", vec!["run", "--frames", "1", "--reference-spp", "1"]),
    ];
    for (what, args) in runs {
        let mut cmd = bin();
        cmd.args(&args).args(tiny).args(props);
        if what != "bench render" {
            cmd.arg("--out").arg(out.join(what.replace(' ', "-")));
        }
        let o = cmd.output().unwrap();
        let stderr = failed(&o, format!("{what} with a missing props folder"));
        assert!(stderr.contains("/nonexistent/props-dir"), "{what}: {stderr}");
    }
    std::fs::remove_dir_all(&out).ok();
}

/// On a machine without a Wayland session (no `XDG_RUNTIME_DIR`, as on CI and headless
/// servers) a command prints no display-probing noise: Mesa's device-select layer used to
/// make libwayland print "error: XDG_RUNTIME_DIR is invalid or not set" at every GPU
/// instance.
#[test]
fn a_headless_machine_sees_no_display_probing_errors() {
    let out = tmp("headless");
    let o = bin()
        .args([
            "render",
            "--scene",
            "builtin:cornell",
            "--frames",
            "1",
            "--width",
            "16",
        ])
        .args(["--height", "16", "--backend", "gpu", "--out"])
        .arg(&out)
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("WAYLAND_SOCKET")
        .env_remove("NODEVICE_SELECT")
        .output()
        .unwrap();
    let stderr = succeeded(&o);
    assert!(!stderr.contains("XDG_RUNTIME_DIR"), "{stderr}");
    assert!(!stderr.to_lowercase().contains("error"), "{stderr}");
    std::fs::remove_dir_all(&out).ok();
}

/// Runs `cmd`, asserts it succeeded and printed every one of `keys`; returns stdout.
fn prints_all(cmd: &mut Command, keys: &[&str]) -> String {
    let o = cmd.output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    succeeded(&o);
    for k in keys {
        assert!(out.contains(k), "missing {k} in\n{out}");
    }
    out
}

#[test]
fn bench_kernels_prints_a_table() {
    prints_all(
        bin().args([
            "bench",
            "kernels",
            "--width",
            "16",
            "--height",
            "16",
            "--channels",
            "8",
            "--iterations",
            "2",
        ]),
        &[
            "conv3x3 8->8 relu generic",
            "conv3x3 8->8 relu px8-cob2",
            "autotuner's choice for conv3x3 8->8 relu",
            "pool2x2 max",
            "upsample2x bilinear",
            "tfa_blend",
            "warp",
            "demodulate",
            "GFLOP/s",
        ],
    );
}

/// Issue 14: the roofline model alone (no timing) at a size the machine could not time
/// quickly, a fixed kernel through the environment, f16 activations; bad values are named
/// errors.
#[test]
fn bench_denoise_models_passes_and_takes_fixed_kernels() {
    prints_all(
        bin().env("SUBPIXEL_CONV_KERNEL", "px4-cob2").args([
            "bench",
            "denoise",
            "--width",
            "64",
            "--height",
            "48",
            "--model-only",
            "--model",
            "rtx4070",
        ]),
        &[
            "roofline model on NVIDIA RTX 4070",
            "unet.enc1.0",
            "compute",
            "memory",
            "not timed (--model-only)",
            "unet.enc2.2 px4-cob2",
            "f32 activations",
        ],
    );
    // f16 activations on the fixed kernel (a first tuning of every layer's f16 variant
    // takes minutes on a CPU driver with a cold shader cache).
    prints_all(
        bench16().args(["--precision", "f16"]),
        &["f16 activations", "modelled total"],
    );
    let o = bench16().env("SUBPIXEL_PRECISION", "half").output().unwrap();
    let err = failed(&o, "SUBPIXEL_PRECISION=half");
    assert_contains_all(&err, &["SUBPIXEL_PRECISION", "half"]);
    let o = bin()
        .env("SUBPIXEL_CONV_KERNEL", "fastest")
        .args([
            "bench", "denoise", "--width", "16", "--height", "16", "--frames", "1",
        ])
        .output()
        .unwrap();
    let err = failed(&o, "SUBPIXEL_CONV_KERNEL=fastest");
    assert_contains_all(&err, &["SUBPIXEL_CONV_KERNEL", "fastest"]);
}

#[test]
fn bench_denoise_prints_per_layer_flops() {
    let o = bin()
        .args([
            "bench", "denoise", "--width", "16", "--height", "12", "--frames", "2", "--warmup", "1", "--json",
        ])
        .output()
        .unwrap();
    succeeded(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let layers = v["layers"].as_array().unwrap();
    assert!(
        layers
            .iter()
            .any(|l| l["name"] == "unet.enc1.0" && l["flops"].as_u64().unwrap() > 0)
    );
    // The output stage's passes are timed one by one too, under the roofline model's names
    // (the shipped model filters its mean correction over five levels).
    let output: Vec<&str> = layers
        .iter()
        .filter(|l| l["stage"] == "output")
        .map(|l| l["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        output,
        [
            "mean history",
            "mean atrous 0",
            "mean atrous 1",
            "mean atrous 2",
            "mean atrous 3",
            "mean atrous 4",
            "store output"
        ]
    );
    let stages: Vec<&str> = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(stages, ["pack", "tfa", "unet", "output"]);
    let fpp = v["flops_per_pixel"].as_f64().unwrap();
    assert!(fpp > 40_000.0 && fpp <= 50_000.0, "{fpp}");
}

/// `subpixel dataset` of one val sequence of `scene` (`frames` frames of `size` x `size`,
/// 2-spp references) into `out`, with `extra` arguments.
fn dataset_val(scene: &str, frames: u32, size: u32, out: &Path, extra: &[&str]) -> Output {
    let (frames, size) = (frames.to_string(), size.to_string());
    bin()
        .args(["dataset", "--scene", scene, "--split", "val", "--sequences", "1"])
        .args([
            "--frames",
            &frames,
            "--width",
            &size,
            "--height",
            &size,
            "--reference-spp",
            "2",
        ])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn dataset_shards_resume_and_write_the_loader_keys() {
    let out = tmp("dataset");
    let run = |range: &str| dataset_val("builtin:cornell-empty", 2, 8, &out, &["--frame-range", range]);
    for range in ["1..2", "0..1"] {
        let o = run(range);
        succeeded(&o);
    }
    let seq = out.join("val/cornell-empty_val_000");
    for f in 0..2 {
        let file = read_frame(&seq.join(format!("frame_{f:04}.exr"))).unwrap();
        assert!(
            file.frame.is_some() && file.reference.is_some(),
            "frame {f} holds buffers and a reference"
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(seq.join("sequence.json")).unwrap()).unwrap();
    let want = serde_json::json!({
        "scene": "cornell-empty", "scene_source": "builtin:cornell-empty",
        "split": "val", "sequence": 0, "frames": 2, "width": 8, "spp": 2,
    });
    for (k, v) in want.as_object().unwrap() {
        assert_eq!(&json[k], v, "sequence.json key {k}");
    }
    let o = run("0..2");
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("skipped 2 frame(s)"),
        "resume skips finished frames"
    );
    let o = run("1..5");
    assert!(failed(&o, "--frames 1..5").contains("within 0..2"));
    std::fs::remove_dir_all(&out).ok();
}

/// `subpixel dataset --background N --resume` adds what frames written before lack: a frame
/// without the samples' escapes (`escaped`, written since the thirtieth session) gets them
/// back exactly as rendered, every other buffer untouched; a complete frame is left as it is.
#[test]
fn dataset_resume_adds_the_samples_escapes() {
    let out = tmp("dataset-escaped");
    let run = || dataset_val("builtin:furnace", 1, 16, &out, &["--background", "2"]);
    succeeded(&run());
    let file = out.join("val/furnace_val_000/frame_0000.exr");
    let full = read_frame(&file).unwrap();
    let escaped = |f: &FrameFile| {
        f.frame
            .as_ref()
            .unwrap()
            .direct_emission()
            .unwrap()
            .escaped
            .clone()
    };
    let esc = escaped(&full).expect("a new frame holds the samples' escapes");
    assert!(esc.data.contains(&1.0), "some sample sees the sky");
    let mut old = full.clone();
    old.frame.as_mut().unwrap().direct_emission_mut().unwrap().escaped = None;
    write_frame(&file, &old).unwrap();
    assert_eq!(escaped(&read_frame(&file).unwrap()), None);
    let o = run();
    succeeded(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("skipped 1 frame(s)"), "{said}");
    assert_eq!(
        read_frame(&file).unwrap(),
        full,
        "the escapes restored, the rest untouched"
    );
    let modified = std::fs::metadata(&file).unwrap().modified().unwrap();
    succeeded(&run());
    assert_eq!(
        std::fs::metadata(&file).unwrap().modified().unwrap(),
        modified,
        "a complete frame is not rewritten"
    );
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn bench_frame_times_every_stage_in_both_modes() {
    let o = bin()
        .args([
            "bench", "frame", "--sizes", "16x12", "--frames", "2", "--warmup", "1", "--json",
        ])
        .output()
        .unwrap();
    succeeded(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v["results"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    assert_eq!(
        (rows[0]["mode"].as_str(), rows[1]["mode"].as_str()),
        (Some("quarter"), Some("full"))
    );
    let names: Vec<&str> = rows[0]["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s[0].as_str().unwrap())
        .collect();
    // The shipped model uses the footprint albedo, so every frame has the background pass
    // (the box has no environment of its own).
    assert_eq!(
        names,
        ["gbuffer", "trace", "background", "pack", "tfa", "unet", "output"]
    );
    assert!(rows[0]["ssr_flops"].as_u64().unwrap() > 0);
}

/// Out-of-range arguments are clear errors, never a panic or a silently different render.
#[test]
fn range_arguments_are_refused() {
    let out = tmp("ranges");
    let o = |args: &[&str]| bin().args(args).output().unwrap();
    let out_s = out.to_str().unwrap();
    for (args, want) in [
        (vec!["bench", "frame", "--frames", "0"], "--frames"),
        (vec!["bench", "denoise", "--frames", "0"], "--frames"),
        (vec!["bench", "render", "--frames", "0"], "--frames"),
        (
            vec![
                "render",
                "--scene",
                "builtin:cornell",
                "--mode",
                "reference",
                "--spp",
                "0",
                "--out",
                out_s,
            ],
            "--spp must be at least 1",
        ),
        (
            vec![
                "render",
                "--scene",
                "builtin:cornell",
                "--reference-spp",
                "0",
                "--out",
                out_s,
            ],
            "--reference-spp must be at least 1",
        ),
        (
            vec![
                "render",
                "--scene",
                "builtin:cornell",
                "--max-depth",
                "0",
                "--out",
                out_s,
            ],
            "--max-depth",
        ),
        (
            vec![
                "render",
                "--scene",
                "builtin:cornell",
                "--first-frame",
                "4294967295",
                "--frames",
                "2",
                "--out",
                out_s,
            ],
            "--first-frame",
        ),
        (
            vec![
                "render",
                "--scene",
                "builtin:cornell",
                "--path",
                "orbit:1e38",
                "--frames",
                "4",
                "--out",
                out_s,
            ],
            "degrees_per_frame 100000000000000000000000000000000000000 must be finite",
        ),
        (
            vec![
                "dataset",
                "--scene",
                "builtin:cornell",
                "--split",
                "val",
                "--sequences",
                "2",
                "--first-sequence",
                "2",
                "--out",
                out_s,
            ],
            "--first-sequence",
        ),
        (
            vec![
                "render",
                "--scene",
                "builtin:cornell",
                "--backend",
                "cpu",
                "--width",
                "100000",
                "--height",
                "100000",
                "--out",
                out_s,
            ],
            "image size 100000x100000: 10000000000 pixels, more than the 67108864",
        ),
    ] {
        let r = o(&args);
        let stderr = failed(&r, format!("{args:?}"));
        assert!(stderr.contains(want), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn the_main_job_writes_previews_a_person_can_judge() {
    // A tiny run: its previews (input | SSR | reference) are upscaled pixel for pixel to at
    // least 256 pixels tall, and the per-frame scores and timings are still printed.
    let out = tmp("run");
    let o = bin()
        .args([
            "run",
            "--frames",
            "2",
            "--width",
            "24",
            "--height",
            "20",
            "--reference-spp",
            "4",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_contains_all(
        &stdout,
        &[
            "SSR PSNR",
            "time per frame at 24x20",
            "weights: ",
            "(version 2, enc [",
        ],
    );
    for f in 0..2 {
        let png = image::open(out.join(format!("frame_{f:04}.png")))
            .unwrap()
            .to_rgb8();
        // 20 px tall -> 13x (260 px); three 24-px images side by side.
        assert_eq!((png.width(), png.height()), (3 * 24 * 13, 20 * 13));
        for (x, y) in [(0, 0), (5 * 13 + 7, 3 * 13 + 12), (71 * 13 + 12, 19 * 13)] {
            assert_eq!(
                png.get_pixel(x, y),
                png.get_pixel(x / 13 * 13, y / 13 * 13),
                "every pixel is a 13x13 block"
            );
        }
    }
    std::fs::remove_dir_all(&out).ok();
}

/// Every file of `dir` (name -> bytes), sorted.
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().to_string(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

/// Issue 12 item 3: `denoise --out` on, inside or around `--input` is refused before
/// anything is written (paths resolved, symlinks followed); a folder of frames of
/// different sizes is refused naming the file; a run that fails part-way leaves the output
/// folder exactly as it was (no mix of new and stale frames, no temporaries).
#[test]
fn denoise_never_destroys_its_input() {
    let root = tmp("overlap");
    let input = root.join("in");
    golden_folder(&input);
    let before = snapshot(&input);
    let denoise = |input: &Path, out: &Path| golden_denoise(input, out).output().unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(&input, root.join("link")).unwrap();
    let mut cases = vec![
        (input.clone(), "is the same folder as"),
        (root.join("in/../in/."), "is the same folder as"),
        (input.join("sub/deeper"), "lies inside"),
        (root.clone(), "contains"),
    ];
    #[cfg(unix)]
    cases.push((root.join("link"), "is the same folder as"));
    for (out, want) in cases {
        let o = denoise(&input, &out);
        let stderr = failed(&o, format!("--out {}", out.display()));
        assert!(
            stderr.contains(want) && stderr.contains("--out") && stderr.contains("--input"),
            "--out {}: {stderr}",
            out.display()
        );
        assert_eq!(
            snapshot(&input),
            before,
            "--out {} touched the input",
            out.display()
        );
        assert!(!input.join("sub").exists(), "nothing created inside the input");
    }

    // Frames of different sizes: refused before any output, naming the odd file.
    let mixed = root.join("mixed");
    let out = root.join("out");
    std::fs::create_dir_all(&out).unwrap();
    copy_frames(2, &input, &mixed);
    let mut small = read_frame(&input.join("frame_0002.exr")).unwrap();
    let f = small.frame.as_mut().unwrap();
    for t in f.tensors_mut() {
        *t = HostTensor::from_fn(20, 12, t.channels, |x, y, c| t.at(x, y, c));
    }
    small.reference = None;
    write_frame(&mixed.join("frame_0002.exr"), &small).unwrap();
    let stale: Vec<(String, Vec<u8>)> = (0..3)
        .map(|i| (format!("frame_{i:04}.exr"), format!("stale {i}").into_bytes()))
        .collect();
    for (n, b) in &stale {
        std::fs::write(out.join(n), b).unwrap();
    }
    let o = denoise(&mixed, &out);
    let stderr = failed(&o, "mixed frame sizes");
    assert_contains_all(&stderr, &["frame_0002.exr", "20x12", "40x24"]);
    assert_eq!(snapshot(&out), stale);

    // A frame whose header is fine but whose pixels are cut off: frames 0 and 1 are
    // denoised, frame 2 fails, and the output folder still holds only the stale frames.
    let cut = root.join("cut");
    copy_frames(3, &input, &cut);
    let bytes = std::fs::read(cut.join("frame_0002.exr")).unwrap();
    std::fs::write(cut.join("frame_0002.exr"), &bytes[..bytes.len() - 200]).unwrap();
    let o = denoise(&cut, &out);
    let stderr = failed(&o, "a truncated frame");
    assert!(stderr.contains("frame_0002.exr"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(
        snapshot(&out),
        stale,
        "no mix of new and stale frames, no temporaries"
    );

    // The same folders that were refused above are fine once separate.
    let o = denoise(&input, &out);
    succeeded(&o);
    let names: Vec<String> = snapshot(&out).into_iter().map(|(n, _)| n).collect();
    assert_eq!(names, ["frame_0000.exr", "frame_0001.exr", "frame_0002.exr"]);
    assert!(read_frame(&out.join("frame_0001.exr")).unwrap().pred.is_some());
    std::fs::remove_dir_all(&root).ok();
}

/// Issue 12 item 5: a prediction with NaN or Inf pixels (some, or all) is not scored as a
/// plausible PSNR / SSIM: `eval` fails naming the file and the count, in text, JSON and
/// table modes.
#[test]
fn eval_refuses_non_finite_predictions() {
    let root = tmp("eval-nan");
    let input = root.join("ref");
    golden_folder(&input);
    let pred = root.join("pred");
    std::fs::create_dir_all(&pred).unwrap();
    let write_preds = |poison: &dyn Fn(usize, &mut HostTensor)| {
        for i in 0..3 {
            let name = format!("frame_{i:04}.exr");
            let mut p = read_frame(&input.join(&name)).unwrap().reference.unwrap();
            poison(i, &mut p);
            write_frame(
                &pred.join(&name),
                &FrameFile {
                    pred: Some(p),
                    ..Default::default()
                },
            )
            .unwrap();
        }
    };
    let eval = |extra: &[&str], p: &Path, r: &Path| {
        bin()
            .arg("eval")
            .args(extra)
            .arg("--pred")
            .arg(p)
            .arg("--ref")
            .arg(r)
            .output()
            .unwrap()
    };
    // Clean predictions score (the control).
    write_preds(&|_, _| {});
    let o = eval(&["--json"], &pred, &input);
    succeeded(&o);
    // Seven NaN / Inf pixels in frame 1 (two channels of one pixel count once).
    write_preds(&|i, t| {
        if i == 1 {
            for k in 0..7u32 {
                t.set(k, 3, 0, if k % 2 == 0 { f32::NAN } else { f32::INFINITY });
            }
            t.set(0, 3, 2, f32::NAN);
        }
    });
    for mode in [&[][..], &["--json"][..]] {
        let o = eval(mode, &pred, &input);
        let stderr = failed(&o, format!("{mode:?}"));
        assert!(
            stderr.contains("frame_0001.exr") && stderr.contains("7 non-finite") && stderr.contains("of 960"),
            "{mode:?}: {stderr}"
        );
        assert!(
            !String::from_utf8_lossy(&o.stdout).contains("psnr"),
            "no score printed"
        );
    }
    // An all-NaN prediction.
    write_preds(&|i, t| {
        if i == 2 {
            t.data.iter_mut().for_each(|v| *v = f32::NAN);
        }
    });
    let o = eval(&["--json"], &pred, &input);
    let stderr = failed(&o, "an all-NaN prediction");
    assert!(stderr.contains("960 non-finite"), "{stderr}");
    // The table over a dataset root.
    let droot = root.join("dataset");
    let seq = droot.join("test/golden_test_000");
    std::fs::create_dir_all(&seq).unwrap();
    std::fs::write(seq.join("sequence.json"), r#"{"scene": "builtin:golden"}"#).unwrap();
    copy_frames(3, &input, &seq);
    copy_frames(3, &pred, &root.join("methods/ssr/test/golden_test_000"));
    for mode in [&["--table"][..], &["--table", "--json"][..]] {
        let o = eval(mode, &root.join("methods"), &droot);
        let stderr = failed(&o, format!("{mode:?}"));
        assert_contains_all(&stderr, &["frame_0002.exr", "non-finite"]);
    }
    std::fs::remove_dir_all(&root).ok();
}

/// Issue 12 item 11: the default weights of a relocated binary are found next to it (its
/// `weights/`, or `../weights` as in `target/release/`), or through `SUBPIXEL_WEIGHTS`;
/// a `SUBPIXEL_WEIGHTS` naming a missing file is an error naming it.
#[test]
fn default_weights_follow_the_binary_and_the_environment() {
    let root = tmp("relocated");
    let frames = root.join("frames");
    golden_folder(&frames);
    let weights = data("golden_weights.safetensors");
    // A copy of the binary in bin/, the weights in ../weights relative to it.
    let bin_dir = root.join("app/bin");
    std::fs::create_dir_all(&bin_dir).unwrap();
    std::fs::create_dir_all(root.join("app/weights")).unwrap();
    let exe = bin_dir.join("subpixel");
    std::fs::copy(env!("CARGO_BIN_EXE_subpixel"), &exe).unwrap();
    let moved = root.join("app/weights/ssr.safetensors");
    std::fs::copy(&weights, &moved).unwrap();
    let denoise = |exe: &Path, env: Option<&Path>, out: &str| {
        let mut c = bin_at(exe);
        c.current_dir(&root).env_remove("SUBPIXEL_WEIGHTS");
        if let Some(e) = env {
            c.env("SUBPIXEL_WEIGHTS", e);
        }
        c.arg("denoise")
            .arg("--input")
            .arg(&frames)
            .arg("--out")
            .arg(root.join(out));
        // A test thread forking a child while the copy above was open for writing makes
        // the child hold it until its exec: the kernel then refuses to run the copy (text
        // file busy) for a moment. Retry that, nothing else.
        let mut tries = 0;
        loop {
            match c.output() {
                Err(e) if e.kind() == std::io::ErrorKind::ExecutableFileBusy && tries < 20 => {
                    tries += 1;
                    std::thread::sleep(std::time::Duration::from_millis(50));
                }
                r => break r.unwrap(),
            }
        }
    };
    // The golden weights are random test weights: the warning names the file in use.
    let o = denoise(&exe, None, "out1");
    let stderr = succeeded(&o);
    assert!(
        stderr.contains(&format!(
            "{} holds random test weights",
            bin_dir.join("../weights/ssr.safetensors").display()
        )),
        "{stderr}"
    );
    // The environment variable wins over the copy next to the binary.
    let elsewhere = root.join("elsewhere.safetensors");
    std::fs::copy(&weights, &elsewhere).unwrap();
    let o = denoise(&exe, Some(&elsewhere), "out2");
    let stderr = succeeded(&o);
    assert!(
        stderr.contains(&format!("{} holds random", elsewhere.display())),
        "{stderr}"
    );
    // An environment variable naming nothing is an error naming it, not a fallback.
    let o = denoise(&exe, Some(&root.join("nope.safetensors")), "out3");
    let stderr = failed(&o, "SUBPIXEL_WEIGHTS naming no file");
    assert_contains_all(&stderr, &["SUBPIXEL_WEIGHTS", "nope.safetensors"]);
    std::fs::remove_dir_all(&root).ok();
}

/// A background of coverage 1 on the left half of a `w x h` frame (radiance 0.5 + channel
/// there) and 0 on the right (radiance 0), with footprint albedo `albedo`.
fn half_sky_background(w: u32, h: u32, albedo: Option<HostTensor>) -> subpixel::frame::Background {
    subpixel::frame::Background {
        radiance: HostTensor::from_fn(w, h, 3, |x, _, c| if x < w / 2 { 0.5 + c as f32 } else { 0.0 }),
        coverage: HostTensor::from_fn(w, h, 1, |x, _, _| (x < w / 2) as u32 as f32),
        albedo,
        emission: None,
    }
}

/// `composited` (frame `i`) is [`half_sky_background`]'s value on the left half and exactly
/// `plain` on the right.
fn assert_half_sky_composite(composited: &HostTensor, plain: &HostTensor, i: usize) {
    for y in 0..plain.height {
        for x in 0..plain.width {
            for k in 0..3 {
                let want = if x < plain.width / 2 {
                    0.5 + k as f32
                } else {
                    plain.at(x, y, k)
                };
                assert_eq!(
                    composited.at(x, y, k),
                    want,
                    "frame {i} pixel ({x}, {y}) channel {k}"
                );
            }
        }
    }
}

/// `subpixel denoise` reads a frame's background channels and the engine composites them
/// (background + (1 - coverage) x reconstruction; `tests/ssr_api.rs` checks the rule), and
/// `--no-background` ignores them: the golden frames given a background with coverage 1 on
/// the left half (its value) and 0 on the right (background 0) come out as that value on
/// the left and exactly as without a background on the right.
#[test]
fn denoise_uses_the_frames_background() {
    let plain = tmp("bg-plain");
    golden_folder(&plain);
    let with = tmp("bg-with");
    for i in 0..3 {
        let name = format!("frame_{i:04}.exr");
        let mut f = read_frame(&plain.join(&name)).unwrap();
        let frame = f.frame.as_mut().unwrap();
        let (w, h) = frame.size().unwrap();
        frame.background = Some(half_sky_background(w, h, None));
        write_frame(&with.join(&name), &f).unwrap();
    }
    let denoise = |input: &Path, name: &str, extra: &[&str]| {
        let out = tmp(name);
        let o = golden_denoise(input, &out).args(extra).output().unwrap();
        succeeded(&o);
        (out, String::from_utf8_lossy(&o.stdout).to_string())
    };
    let (a, _) = denoise(&plain, "bg-out-plain", &[]);
    let (b, said) = denoise(&with, "bg-out-with", &[]);
    assert!(said.contains("background in 3 of them"), "{said}");
    let (c, said) = denoise(&with, "bg-out-ignored", &["--no-background"]);
    assert_contains_all(&said, &["background in 0 of them", "--no-background"]);
    for i in 0..3 {
        let pred = |d: &Path| {
            read_frame(&d.join(format!("frame_{i:04}.exr")))
                .unwrap()
                .pred
                .unwrap()
        };
        let (pa, pb, pc) = (pred(&a), pred(&b), pred(&c));
        assert_eq!(pc, pa, "--no-background: as without a background");
        assert_half_sky_composite(&pb, &pa, i);
    }
}

/// The golden weights rewritten with config albedo "footprint" (the same tensors), in `dir`.
fn footprint_weights(dir: &Path) -> PathBuf {
    weights_with(dir, "albedo", "footprint")
}

/// The golden weights rewritten with config option `key` = `value` (the same tensors), in
/// `dir`.
fn weights_with(dir: &Path, key: &str, value: &str) -> PathBuf {
    let bytes = std::fs::read(data("golden_weights.safetensors")).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let meta = header["__metadata__"].as_object_mut().unwrap();
    let mut config: serde_json::Value = serde_json::from_str(meta["config"].as_str().unwrap()).unwrap();
    config[key] = value.into();
    meta["config"] = config.to_string().into();
    let mut head = serde_json::to_vec(&header).unwrap();
    head.resize(head.len().next_multiple_of(8), b' ');
    let mut out = (head.len() as u64).to_le_bytes().to_vec();
    out.extend(head);
    out.extend(&bytes[8 + n..]);
    let path = dir.join(format!("{key}-{value}.safetensors"));
    std::fs::write(&path, out).unwrap();
    path
}

/// `subpixel denoise` with a model of config albedo "footprint": frames without the
/// footprint albedo are refused before anything is written, naming the file and the
/// channels; with it, the model runs on it: with `--no-background` exactly as the same
/// weights as a centre model run on the frames with their albedo replaced by the footprint
/// albedo (and no background), and by default composited with the frames' background.
#[test]
fn denoise_feeds_a_footprint_model_the_frames_footprint_albedo() {
    let dir = tmp("fp");
    let weights = footprint_weights(&dir);
    let plain = tmp("fp-plain");
    golden_folder(&plain);
    let run = |w: &Path, input: &Path, name: &str, extra: &[&str]| {
        let out = tmp(name);
        let o = denoise_cmd(w, input, &out).args(extra).output().unwrap();
        (out, o)
    };
    let (out, o) = run(&weights, &plain, "fp-out-bare", &[]);
    let e = failed(&o, "a footprint model on frames without the footprint albedo");
    assert_contains_all(&e, &["frame_0000.exr", "albedo_footprint", "--background"]);
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "nothing written");
    let (with, swapped) = (tmp("fp-with"), tmp("fp-swapped"));
    for i in 0..3 {
        let name = frame_name(i);
        let mut f = read_frame(&plain.join(&name)).unwrap();
        let (w, h) = f.frame.as_ref().unwrap().size().unwrap();
        let albedo = HostTensor::from_fn(w, h, 3, |x, y, c| {
            ((x * 7 + y * 3 + c * 5 + i as u32) % 11) as f32 / 10.0
        });
        let mut plain_swapped = f.clone();
        plain_swapped.frame.as_mut().unwrap().albedo = albedo.clone();
        write_frame(&swapped.join(&name), &plain_swapped).unwrap();
        f.frame.as_mut().unwrap().background = Some(half_sky_background(w, h, Some(albedo)));
        write_frame(&with.join(&name), &f).unwrap();
    }
    let (a, o) = run(&weights, &with, "fp-out-nobg", &["--no-background"]);
    succeeded(&o);
    let (b, o) = run(
        &data("golden_weights.safetensors"),
        &swapped,
        "fp-out-centre",
        &[],
    );
    succeeded(&o);
    let (c, o) = run(&weights, &with, "fp-out-bg", &[]);
    succeeded(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("background in 3 of them"));
    for i in 0..3 {
        let pred = |d: &Path| read_frame(&d.join(frame_name(i))).unwrap().pred.unwrap();
        let (pa, pb, pc) = (pred(&a), pred(&b), pred(&c));
        assert_eq!(
            pa, pb,
            "frame {i}: --no-background as the centre model on the swapped albedo"
        );
        assert_half_sky_composite(&pc, &pa, i);
    }
}

/// `subpixel denoise` with a model of config emission "background": frames without the
/// directly seen emission are refused before anything is written, naming the file and the
/// channels; with it, the model runs on the colour without the samples' emission and adds
/// the footprint's: what the same weights as an emission-"network" model (no mean
/// correction) give on frames folded by hand (colour less the samples' emission, background
/// plus the footprint's), up to the order of the sums, and with `--no-background` on frames
/// whose background is the footprint emission alone (no environment, coverage 0).
#[test]
fn denoise_folds_the_directly_seen_emission_for_an_emission_model() {
    use subpixel::frame::DirectEmission;
    let dir = tmp("em");
    let weights = weights_with(&dir, "emission", "background");
    let plain = tmp("em-plain");
    golden_folder(&plain);
    let run = |w: &Path, input: &Path, name: &str, extra: &[&str]| {
        let out = tmp(name);
        let o = denoise_cmd(w, input, &out).args(extra).output().unwrap();
        (out, o)
    };
    let (out, o) = run(&weights, &plain, "em-out-bare", &[]);
    let e = failed(
        &o,
        "an emission model on frames without the directly seen emission",
    );
    assert_contains_all(
        &e,
        &[
            "frame_0000.exr",
            "emission.RGB",
            "emission_footprint.RGB",
            "--background",
        ],
    );
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "nothing written");
    let (with, folded, folded_nobg) = (tmp("em-with"), tmp("em-folded"), tmp("em-folded-nobg"));
    for i in 0..3 {
        let name = frame_name(i);
        let mut f = read_frame(&plain.join(&name)).unwrap();
        let frame = f.frame.as_mut().unwrap();
        let (w, h) = frame.size().unwrap();
        let samples = HostTensor::from_fn(w, h, 3, |x, y, c| {
            if (x + 2 * y + i as u32).is_multiple_of(5) {
                0.25 * frame.color.at(x, y, c)
            } else {
                0.0
            }
        });
        let footprint = HostTensor::from_fn(w, h, 3, |x, y, c| ((x * 3 + y + c) % 7) as f32 * 0.5);
        let mut bg = half_sky_background(w, h, None);
        let mut by_hand = frame.clone();
        by_hand.color = HostTensor::from_fn(w, h, 3, |x, y, c| frame.color.at(x, y, c) - samples.at(x, y, c));
        let mut hand_bg = bg.clone();
        hand_bg.radiance =
            HostTensor::from_fn(w, h, 3, |x, y, c| bg.radiance.at(x, y, c) + footprint.at(x, y, c));
        let mut nobg = by_hand.clone();
        nobg.background = Some(subpixel::frame::Background {
            radiance: footprint.clone(),
            coverage: HostTensor::zeros(w, h, 1),
            albedo: None,
            emission: None,
        });
        by_hand.background = Some(hand_bg);
        bg.emission = Some(DirectEmission {
            footprint,
            samples,
            escaped: None,
        });
        frame.background = Some(bg);
        write_frame(&with.join(&name), &f).unwrap();
        for (folder, fr) in [(&folded, by_hand), (&folded_nobg, nobg)] {
            let file = subpixel::io::exr::FrameFile {
                frame: Some(fr),
                ..f.clone()
            };
            write_frame(&folder.join(&name), &file).unwrap();
        }
    }
    let golden = data("golden_weights.safetensors");
    let pairs = [
        (
            run(&weights, &with, "em-out", &[]),
            run(&golden, &folded, "em-out-hand", &[]),
        ),
        (
            run(&weights, &with, "em-out-nobg", &["--no-background"]),
            run(&golden, &folded_nobg, "em-out-hand-nobg", &[]),
        ),
    ];
    for (k, ((a, oa), (b, ob))) in pairs.iter().enumerate() {
        succeeded(oa);
        succeeded(ob);
        for i in 0..3 {
            let pred = |d: &Path| read_frame(&d.join(frame_name(i))).unwrap().pred.unwrap();
            let (pa, pb) = (pred(a), pred(b));
            // the same sums in another order (emission added after the composite)
            for (v, w) in pa.data.iter().zip(&pb.data) {
                assert!(
                    (v - w).abs() <= 1e-5 * (1.0 + w.abs()),
                    "case {k}, frame {i}: {v} against {w}, the network model on the frames folded by hand"
                );
            }
            assert_eq!(
                pred(a),
                pred(b),
                "case {k}, frame {i}: as the network model on the frames folded by hand"
            );
        }
    }
}
