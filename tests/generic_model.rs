//! The shipped generic model (`weights/ssr.safetensors`) on scenes it never saw.
//!
//! Issue 11 found the version-1 model's output tens of percent brighter than the reference
//! on unseen scenes. Here the CPU twin renders a few procedural scenes whose seeds are held
//! out of training and model selection (the recipe's test seeds, without props), the engine
//! denoises their 1/4-spp frames with the shipped weights, and the image means are compared
//! with the CPU twin's references of the same frames: the independent expectation is the
//! reference, not a stored figure.
//!
//! **Known to fail with the shipped weights** (ignored by `cargo test`; run it with
//! `cargo test --release --test generic_model -- --ignored --nocapture`): on
//! procedural:1000000 (a dim scene where most 1/4-spp samples carry no light) the output is
//! 1.18-1.27x the reference's mean with the weights of the third session, trained with
//! sample thinning (1.9-3.2x with the second session's, 2.2-3.3x with the first generic
//! model); the other two seeds are within 1.05-1.23x (worst channel: 27.4 % against the
//! 12 % allowed; 31.7 % with the seventh session's weights; 32.2 % with the twelfth
//! session's, trained with the SSIM term, on which procedural:1000000 comes out darker,
//! 0.73-0.78x, and procedural:1000002's green channel 1.32x; 24.1-24.5 % with that
//! session's arms C and E; 22.8 % with the thirteenth session's, 0.77-0.83x and 1.17x;
//! 33.5 % with the same network and the fourteenth session's mean correction: procedural:
//! 1000000 0.90-1.02x, 1000001 1.01x, 1000002 1.08 / 1.23 / 1.33x; 30.0 % with the
//! eighteenth session's Y: 1000000 0.93-0.99x, 1000001 1.02x, 1000002 1.15 / 1.30 /
//! 1.21x; 29.0 % with the twentieth session's F0, Y on the footprint albedo, the frames
//! rendered with the 2 x 2 background pass and composited: 1000000 0.92-0.98x, 1000001
//! 1.01-1.02x, 1000002 1.15 / 1.29 / 1.19x; 16.1 % with the twenty-first session's F1t16,
//! the mean correction over 16-pixel tiles: 1000000 0.85 / 0.85 / 0.91x, 1000001
//! 1.00-1.02x, 1000002 1.14 / 1.16 / 1.03x; 15.2 % with the twenty-second session's F1t16e,
//! the directly seen emission drawn by the output pass: 1000000 0.86 / 0.85 / 0.91x,
//! 1000001 1.00-1.02x, 1000002 0.92 / 0.97 / 0.93x; 26.3 % with F13 at 11,000, shipped in
//! the forty-seventh session and measured in the fiftieth: 1000000 0.78 / 0.74 / 0.78x,
//! 1000001 1.00-1.01x, 1000002 0.92 / 0.95 / 0.91x). The mean correction
//! follows the 1/4-spp samples, and on procedural:1000002 at 32x32 those are themselves far
//! from the reference: the sum of a frame's samples (times 4) over the reference's is
//! 0.69-1.95x per frame and channel, above 1 on 21 of its 24 frame-channels (heavy-tailed
//! light: a few bright samples carry it), 1.05 / 1.10 / 1.22x on average over the last four
//! frames, so the samples alone do not say this scene's brightness to within 12 % there.
//! What was measured (training/README.md, "Generalisation" 4 and 6): the
//! relative losses are minimised below the mean where the network is unsure, and the
//! network filled traced samples that carry no light like untraced ones; a brightness term
//! in the loss and sample thinning (Russian roulette on the training inputs) each narrowed
//! the gap without closing it. This test is the acceptance test of the fix (issue 11).

mod common;

use subpixel::nn::HostTensor;
use subpixel::render::{Backend, CameraPath, FrameRenderer, FrameSettings, Mode, load_scene};
use subpixel::ssr::{Denoiser, Weights};

/// Per-channel sums over the pixels of `t` (3 channels).
fn channel_sums(t: &HostTensor) -> [f64; 3] {
    let mut s = [0f64; 3];
    for px in t.data.chunks_exact(t.channels as usize) {
        for c in 0..3 {
            s[c] += px[c] as f64;
        }
    }
    s
}

/// The largest relative error of the per-channel image mean allowed on an unseen scene,
/// over the last frames of a sequence (once the temporal accumulator has history). The
/// version-1 model missed by tens of percent; the reference's own noise at 256 spp and 32x32
/// moves its mean by about a percent.
const BRIGHTNESS_TOLERANCE: f64 = 0.12;

#[test]
#[ignore = "known failure of the shipped generic model on sparse-light scenes (issue 11): see the module doc"]
fn shipped_model_keeps_the_brightness_of_unseen_scenes() {
    let gpu = common::gpu();
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/weights/ssr.safetensors");
    let weights = Weights::load(path).unwrap();
    assert_eq!(
        weights.config.version, 2,
        "the shipped model is the generic version-2 model"
    );
    let (w, h, frames, spp) = (32u32, 32u32, 8u32, 256u32);
    let mut worst: f64 = 0.0;
    for seed in [1_000_000u64, 1_000_001, 1_000_002] {
        let scene = load_scene(&format!("builtin:procedural:{seed}")).unwrap();
        let mut twin = FrameRenderer::new(&scene, Backend::Cpu, None, w, h).unwrap();
        let spec = scene
            .camera_path
            .clone()
            .unwrap_or(subpixel::render::CameraPathSpec::Static);
        let cams = CameraPath::checked(&spec, &scene.camera, seed, frames, &twin.packed().bvh).unwrap();
        let eyes: Vec<_> = (0..frames).map(|f| cams.camera(f).position).collect();
        let far = scene.far_distance(eyes.iter().chain([&scene.camera.position]));
        let mut den = Denoiser::with_gpu(&gpu, &weights, w, h).unwrap();
        let (mut out, mut reference) = ([0f64; 3], [0f64; 3]);
        for f in 0..frames {
            // The background pass (2 x 2 rays, as the frame loop runs it) gives a model of
            // config albedo "footprint" its footprint albedo.
            let settings = FrameSettings {
                background: 2,
                ..FrameSettings::along(&cams, f, Mode::Quarter, seed as u32, far)
            };
            let (frame, _) = twin.frame(&settings).unwrap();
            let denoised = den.denoise_host(&frame).unwrap();
            assert!(
                denoised.data.iter().all(|v| v.is_finite() && *v >= 0.0),
                "procedural:{seed} frame {f}: non-finite or negative output"
            );
            if f >= frames / 2 {
                let r = twin.reference(&settings, spp).unwrap().mean(spp);
                for c in 0..3 {
                    out[c] += channel_sums(&denoised)[c];
                    reference[c] += channel_sums(&r)[c];
                }
            }
        }
        for c in 0..3 {
            let rel = (out[c] - reference[c]) / reference[c].max(1e-9);
            eprintln!(
                "procedural:{seed} channel {c}: SSR mean / reference mean = {:.4}",
                out[c] / reference[c].max(1e-9)
            );
            worst = worst.max(rel.abs());
        }
    }
    assert!(
        worst <= BRIGHTNESS_TOLERANCE,
        "the shipped model changes an unseen scene's brightness by {:.1} % (at most {:.0} %)",
        worst * 100.0,
        BRIGHTNESS_TOLERANCE * 100.0
    );
}
