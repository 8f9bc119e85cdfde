//! Procedural scenes on the GPU tracer (any adapter; tiny images) and `subpixel scene`.

mod common;

use std::process::{Command, Output};

use subpixel::nn::Tensor;
use subpixel::render::{FrameSettings, GpuScene, Mode, Tracer, load_scene};

#[test]
fn procedural_scene_renders_finite_and_lit() {
    let g = common::gpu();
    for seed in [3u64, 7] {
        let scene = load_scene(&format!("builtin:procedural:{seed}")).unwrap();
        let gs = GpuScene::new(&g, &scene).unwrap();
        let (w, h) = (32, 32);
        let mut tracer = Tracer::new(&g, w, h).unwrap();
        let far = scene.far_distance([&scene.camera.position]);
        let settings = FrameSettings::new(scene.camera, Mode::Reference, far);
        let out = Tensor::new(&g, "reference", w, h, 4).unwrap();
        tracer.render_reference(&gs, &settings, 4, &out).unwrap();
        let img = out.read(&g).unwrap();
        let mut sum = 0.0f64;
        let mut lit = 0;
        for i in 0..(w * h) as usize {
            let px = &img.data[4 * i..4 * i + 3];
            assert!(
                px.iter().all(|v| v.is_finite() && *v >= 0.0),
                "seed {seed}: pixel {i} {px:?}"
            );
            let l = px.iter().sum::<f32>();
            sum += l as f64;
            lit += (l > 1e-4) as usize;
        }
        assert!(sum > 0.0, "seed {seed}: black image");
        assert!(lit * 4 > (w * h) as usize, "seed {seed}: only {lit} lit pixels");
        // A quarter-spp frame: its buffers are finite too.
        let f = {
            let s = FrameSettings {
                mode: Mode::Quarter,
                ..settings
            };
            tracer.render(&gs, &s).unwrap();
            tracer.buffers.download(&g).unwrap()
        };
        for (name, t, _) in f.fields() {
            assert!(t.data.iter().all(|v| v.is_finite()), "seed {seed}: {name}");
        }
    }
}

/// `subpixel scene --scene NAME ARGS..`.
fn scene(name: &str, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_subpixel"))
        .args(["scene", "--scene", name])
        .args(args)
        .output()
        .expect("run subpixel")
}

/// The stdout of [`scene`], asserting that it succeeded.
fn scene_ok(name: &str, args: &[&str]) -> String {
    let out = scene(name, args);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

#[test]
fn scene_command_summarises_and_previews() {
    let dir = std::env::temp_dir().join(format!("subpixel-scene-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("p.png");
    let p = png.to_str().unwrap();
    let args = ["--preview", p, "--width", "24", "--height", "16", "--spp", "2"];
    let stdout = scene_ok("builtin:procedural:7", &args);
    for key in [
        "builtin:procedural:7",
        "enclosure:",
        "triangles:",
        "materials:",
        "lights:",
        "environment:",
        "portal(s)",
        "camera path:",
        "preview:",
    ] {
        assert!(stdout.contains(key), "no '{key}' in:\n{stdout}");
    }
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (24, 16));
    // A broken prop: one warning naming it, and the scene still builds.
    std::fs::write(dir.join("broken.glb"), b"glTF but not really").unwrap();
    let stdout = scene_ok("builtin:procedural:2", &["--props", dir.to_str().unwrap()]);
    assert_eq!(stdout.matches("broken.glb").count(), 1, "{stdout}");
    // Bad input: a seed that is not a number, a props path that does not exist.
    let out = scene("builtin:procedural:abc", &[]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("procedural:abc"));
    let out = scene("builtin:procedural:1", &["--props", "/nonexistent/props-dir"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("props-dir"));
    std::fs::remove_dir_all(&dir).ok();
}
