//! Rust/WGSL vs PyTorch parity on the golden cases written by `training/ssr/golden.py`:
//! three consecutive 40x24 frames (so the history path runs), every intermediate compared
//! in execution order so a failure names the layer that diverged. Four sets: `golden_*`
//! (version-2 config: exposure normalisation, remodulation with the current albedo,
//! geometric history test; the light brightens 3x per frame and a block is disoccluded),
//! `golden_l4_*` (the same with a fourth U-Net level, enc [16, 32, 28, 24]), `golden_shared_*`
//! (the same with one exposure per buffer, config exposure "shared") and
//! `golden_v1_*` (a version-1 config: the pipeline of version-1 weights files).

mod common;

use std::path::PathBuf;

use subpixel::nn::autotune::{EngineOptions, KernelChoice, Pooling, Precision};
use subpixel::nn::{DType, HostTensor};
use subpixel::ssr::{Denoiser, HostFrame, INTERMEDIATES, Weights};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// Every tensor of a golden frame file, HWC.
fn load_frame(prefix: &str, i: usize) -> std::collections::HashMap<String, HostTensor> {
    let bytes = std::fs::read(data(&format!("{prefix}frame{i}.safetensors"))).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    st.tensors()
        .into_iter()
        .map(|(name, v)| {
            let s = v.shape();
            let vals: Vec<f32> = v
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            (
                name,
                HostTensor::from_vec(s[1] as u32, s[0] as u32, s[2] as u32, vals),
            )
        })
        .collect()
}

/// Tolerance of the final output: 1e-3 of its range (the bar). Intermediates use
/// a tighter 1e-4 of their own range: f32 sums in another order differ by ~1e-6.
const OUTPUT_TOL: f32 = 1e-3;
const INTERMEDIATE_TOL: f32 = 1e-4;

fn range(t: &HostTensor) -> f32 {
    let (lo, hi) = t
        .data
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    (hi - lo).max(1e-6)
}

/// Tolerance of f16 activations (issue 14), of the range as above, for the output and
/// every intermediate: f16 keeps 11 significant bits (relative rounding up to 2^-11 ~
/// 4.9e-4 per stored value) and a value passes through up to 7 stored activations
/// between the inputs and the output. Measured on these frames (lavapipe), with the TFA's
/// features and the accumulated history f16 too: worst 8.6e-4 (enc3), output 4.9e-4;
/// with the blocked and Winograd kernels' weights f16 as well (thirty-sixth session):
/// worst 1.07e-3 (enc2), output 5.4e-4 (`SUBPIXEL_PRINT_ERRORS=1` prints them).
const F16_TOL: f32 = 2e-3;

#[test]
fn denoiser_matches_pytorch_on_golden_frames() {
    golden_parity("golden_", 2, Precision::F32);
}

/// Both ways of reading the U-Net's pooled levels (pooled on load by the convolution, or
/// written by pooling passes: `Pooling`), forced, against the same golden frames.
#[test]
fn pooling_on_load_and_pooling_passes_match_pytorch() {
    for pooling in [Pooling::OnLoad, Pooling::Pass] {
        golden_parity_with("golden_", 2, Precision::F32, pooling);
    }
}

/// A fourth U-Net level (1/8 resolution; dec3 reads I4 upsampled), both ways of reading the
/// pooled levels.
#[test]
fn fourth_unet_level_matches_pytorch() {
    for pooling in [Pooling::OnLoad, Pooling::Pass] {
        golden_parity_with("golden_l4_", 2, Precision::F32, pooling);
    }
}

/// One exposure per buffer (config exposure "shared": `ExposureMode::Shared`, the SHARED
/// flag of `ssr/exposure_final`).
#[test]
fn shared_exposure_matches_pytorch() {
    golden_parity("golden_shared_", 2, Precision::F32);
}

#[test]
fn version_1_weights_run_the_version_1_pipeline() {
    golden_parity("golden_v1_", 1, Precision::F32);
}

/// The f16 activation path against the same golden frames, within the f16 tolerances.
#[test]
fn f16_activations_match_pytorch_within_f16_tolerance() {
    let gpu = common::gpu();
    if !gpu.has(wgpu::Features::SHADER_F16) {
        eprintln!("skipped: {} has no SHADER_F16", gpu.describe());
        return;
    }
    golden_parity("golden_", 2, Precision::F16);
}

/// Engine options of a golden run: `precision`, and for f16 one fixed tiling (every
/// tiling's f16 storage is checked against the CPU reference in the kernel tests; this
/// spares a fresh machine the tuning of f16 layer shapes); for f32 the kernels
/// `SUBPIXEL_CONV_KERNEL` names (e.g. `auto` for a full tuning), else a tuning among
/// `common::TUNED_AMONG` (every candidate's parity is tested in `tests/kernels.rs`; a full
/// tuning compiles them all for every layer shape, tens of minutes on a fresh CPU driver).
fn options(precision: Precision, pooling: Pooling) -> EngineOptions {
    let kernels = match precision {
        Precision::F16 => KernelChoice::Fixed("px4-cob2".parse().unwrap()),
        _ if std::env::var_os(subpixel::nn::autotune::ENV_KERNEL).is_some() => KernelChoice::FromEnv,
        _ => common::tuned_kernels().kernels,
    };
    EngineOptions {
        kernels,
        precision,
        pooling,
        ..Default::default()
    }
}

fn golden_parity(prefix: &str, version: u32, precision: Precision) {
    golden_parity_with(prefix, version, precision, Pooling::FromEnv);
}

fn golden_parity_with(prefix: &str, version: u32, precision: Precision, pooling: Pooling) {
    let gpu = common::gpu();
    let weights = Weights::load(data(&format!("{prefix}weights.safetensors"))).unwrap();
    assert!(
        weights.is_random_init(),
        "golden weights are random-initialised test weights"
    );
    assert_eq!(weights.config.version, version);
    let mut den = Denoiser::with_options(&gpu, &weights, 40, 24, options(precision, pooling)).unwrap();
    let f16 = precision == Precision::F16;
    assert_eq!(den.network().activations() == DType::F16, f16);
    let (output_tol, intermediate_tol) = if f16 {
        (F16_TOL, F16_TOL)
    } else {
        (OUTPUT_TOL, INTERMEDIATE_TOL)
    };
    for i in 0..3 {
        let g = load_frame(prefix, i);
        let frame = HostFrame {
            color: g["color"].clone(),
            mask: g["mask"].clone(),
            albedo: g["albedo"].clone(),
            normal: g["normal"].clone(),
            shadow: g["shadow"].clone(),
            transparent: g["transparent"].clone(),
            depth: g["depth"].clone(),
            metallic: g["metallic"].clone(),
            roughness: g["roughness"].clone(),
            motion: g["motion"].clone(),
            background: None,
        };
        let out = den.denoise_host(&frame).unwrap();
        // Every engine intermediate the golden file holds (the same names: checked by
        // `golden_names_are_engine_tensor_names`), in execution order.
        let inputs: Vec<&str> = frame.fields().iter().map(|f| f.0).collect();
        let mut compared = 0;
        for &golden in INTERMEDIATES.iter().filter(|n| !inputs.contains(n)) {
            let Some(want) = g.get(golden) else {
                continue;
            };
            compared += 1;
            let got = den.network().tensor(golden).unwrap().read(&gpu).unwrap();
            let rel = if golden == "output" {
                output_tol
            } else {
                intermediate_tol
            };
            if std::env::var_os("SUBPIXEL_PRINT_ERRORS").is_some() {
                let worst = got
                    .data
                    .iter()
                    .zip(&want.data)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                eprintln!(
                    "{precision:?} frame {i} {golden}: worst {:.2e} of range",
                    worst / range(want)
                );
            }
            let tol = common::Tol {
                abs: rel * range(want),
                rel: 0.0,
            };
            common::assert_close(&format!("{prefix} frame {i} layer '{golden}'"), &got, want, tol);
        }
        // Version 2 golden files hold 17 intermediates, version 1 16 (no exposure), and a
        // fourth level's two more (enc4, i4).
        let deep = 2 * (weights.config.levels() as usize - 3);
        assert_eq!(
            compared,
            if version == 1 { 16 } else { 17 } + deep,
            "{prefix}: intermediates compared"
        );
        let tol = common::Tol {
            abs: output_tol * range(&g["output"]),
            rel: 0.0,
        };
        common::assert_close(
            &format!("{prefix} frame {i} cropped output"),
            &out,
            &g["output"],
            tol,
        );
    }
    assert_eq!(den.sanitized_count().unwrap(), 0);
}

/// The PyTorch mirror and the engine name their tensors alike: every golden intermediate
/// that `training/ssr/golden.py` exports is a tensor of the engine's graph by that name.
#[test]
fn golden_names_are_engine_tensor_names() {
    let py = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/training/ssr/golden.py")).unwrap();
    let mut names = Vec::new();
    for list in [
        "GOLDEN_INTERMEDIATES = [",
        "GOLDEN_EXTRAS = [",
        "GOLDEN_L4 = [",
        "GOLDEN_V2 = [",
    ] {
        let start = py.find(list).unwrap_or_else(|| panic!("golden.py has no {list}")) + list.len();
        let body = &py[start..start + py[start..].find(']').unwrap()];
        names.extend(
            body.split(',')
                .map(|n| n.trim().trim_matches('"').to_string())
                .filter(|n| !n.is_empty()),
        );
    }
    assert!(names.len() >= 19, "{names:?}");
    let engine: Vec<&str> = subpixel::ssr::graph::TensorId::ALL
        .iter()
        .map(|t| t.name())
        .collect();
    for n in &names {
        assert!(
            engine.contains(&n.as_str()),
            "golden tensor '{n}' has no engine tensor of that name"
        );
        assert!(
            INTERMEDIATES.contains(&n.as_str()),
            "golden tensor '{n}' is not an exposed intermediate (so not compared)"
        );
    }
}
