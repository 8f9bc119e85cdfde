//! The public SSR API: weight-file errors, padding of odd sizes, sanitising of NaN/Inf,
//! history reset and resize.

mod common;

use std::collections::HashMap;
use std::path::PathBuf;

use subpixel::nn::HostTensor;
use subpixel::ssr::{Denoiser, HostFrame, Weights};

fn golden_weights_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden_weights.safetensors")
}

/// Rewrites the golden weights with `edit` applied to (tensors, metadata).
fn edited(
    edit: impl FnOnce(&mut Vec<(String, Vec<usize>, Vec<u8>)>, &mut HashMap<String, String>),
) -> Vec<u8> {
    let bytes = std::fs::read(golden_weights_path()).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.shape().to_vec(), v.data().to_vec()))
        .collect();
    edit(&mut tensors, &mut meta);
    let views: Vec<(String, safetensors::tensor::TensorView<'_>)> = tensors
        .iter()
        .map(|(n, s, d)| {
            (
                n.clone(),
                safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), d).unwrap(),
            )
        })
        .collect();
    safetensors::serialize(views, Some(meta)).unwrap()
}

fn load_err(bytes: &[u8]) -> String {
    Weights::from_bytes(bytes, "test.safetensors")
        .unwrap_err()
        .to_string()
}

#[test]
fn weights_errors_name_the_file_and_the_tensor() {
    let missing = edited(|t, _| t.retain(|(n, _, _)| n != "unet.dec2.0.weight"));
    let e = load_err(&missing);
    assert!(
        e.contains("test.safetensors") && e.contains("'unet.dec2.0.weight' is missing"),
        "{e}"
    );

    let misshapen = edited(|t, _| {
        let x = t.iter_mut().find(|(n, _, _)| n == "tfa.ref.0.bias").unwrap();
        x.1 = vec![x.1[0] - 1];
        x.2.truncate(x.2.len() - 4);
    });
    let e = load_err(&misshapen);
    assert!(e.contains("'tfa.ref.0.bias' has shape [7], expected [8]"), "{e}");

    let extra = edited(|t, _| t.push(("unet.dec0.0.bias".into(), vec![1], vec![0; 4])));
    assert!(load_err(&extra).contains("unexpected tensors [\"unet.dec0.0.bias\"]"));

    let format = edited(|_, m| {
        m.insert("format".into(), "oidn".into());
    });
    assert!(load_err(&format).contains("format is 'oidn', expected 'subpixel-ssr'"));

    let version = edited(|_, m| {
        m.insert("version".into(), "7".into());
    });
    assert!(load_err(&version).contains("version 7"));

    let config = edited(|_, m| {
        m.insert("config".into(), "{\"k\": 8}".into());
    });
    assert!(load_err(&config).contains("'config' is not a valid SSR config"));

    let ok = std::fs::read(golden_weights_path()).unwrap();
    let e = load_err(&ok[..ok.len() / 2]);
    assert!(e.contains("truncated"), "{e}");

    let e = Weights::load("/nonexistent/ssr.safetensors")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("/nonexistent/ssr.safetensors") && e.contains("cannot read"),
        "{e}"
    );
}

fn random_frame(w: u32, h: u32, seed: u64) -> HostFrame {
    let r = |s: u64, c, lo, hi| common::random(seed * 100 + s, w, h, c, lo, hi);
    HostFrame {
        color: r(1, 3, 0.0, 4.0),
        mask: HostTensor::from_fn(w, h, 1, |x, y, _| ((x % 2 == 0) && (y % 2 == 0)) as u32 as f32),
        albedo: r(2, 3, 0.0, 1.0),
        normal: r(3, 3, -1.0, 1.0),
        shadow: r(4, 3, 0.0, 2.0),
        transparent: r(5, 3, 0.0, 1.0),
        depth: r(6, 1, 0.0, 1.0),
        metallic: r(7, 1, 0.0, 1.0),
        roughness: r(8, 1, 0.0, 1.0),
        motion: r(9, 2, -1.5, 1.5),
    }
}

#[test]
fn odd_sizes_are_padded_internally() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    for (w, h) in [(1, 1), (7, 5), (33, 17)] {
        let mut den = Denoiser::with_gpu(&gpu, &weights, w, h).unwrap();
        assert_eq!((den.network().width % 4, den.network().height % 4), (0, 0));
        for t in 0..2 {
            let out = den.denoise_host(&random_frame(w, h, t)).unwrap();
            assert_eq!((out.width, out.height, out.channels), (w, h, 3));
            assert!(out.data.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
    }
}

#[test]
fn nan_and_inf_inputs_are_sanitised_and_counted() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let mut den = Denoiser::with_gpu(&gpu, &weights, 12, 8).unwrap();
    let clean = random_frame(12, 8, 1);
    let mut dirty = clean.clone();
    dirty.color.set(3, 2, 0, f32::NAN);
    dirty.normal.set(5, 5, 1, f32::INFINITY);
    dirty.motion.set(0, 0, 0, f32::NEG_INFINITY);
    let out = den.denoise_host(&dirty).unwrap();
    assert!(
        out.data.iter().all(|v| v.is_finite()),
        "non-finite input leaked into the output"
    );
    assert_eq!(den.sanitized_count().unwrap(), 3);
    // The sanitised frame equals the frame with zeros in those places.
    let mut zeroed = clean.clone();
    zeroed.color.set(3, 2, 0, 0.0);
    zeroed.normal.set(5, 5, 1, 0.0);
    zeroed.motion.set(0, 0, 0, 0.0);
    let mut fresh = Denoiser::with_gpu(&gpu, &weights, 12, 8).unwrap();
    let want = fresh.denoise_host(&zeroed).unwrap();
    common::assert_close("sanitised == zeroed", &out, &want, common::EXACT);
}

#[test]
fn reset_and_resize_restart_the_history() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let (f0, f1) = (random_frame(16, 12, 3), random_frame(16, 12, 4));
    let mut den = Denoiser::with_gpu(&gpu, &weights, 16, 12).unwrap();
    let first = den.denoise_host(&f0).unwrap();
    let with_history = den.denoise_host(&f1).unwrap();
    den.reset();
    let after_reset = den.denoise_host(&f1).unwrap();
    let mut fresh = Denoiser::with_gpu(&gpu, &weights, 16, 12).unwrap();
    let fresh_f1 = fresh.denoise_host(&f1).unwrap();
    common::assert_close("reset == fresh", &after_reset, &fresh_f1, common::EXACT);
    assert_ne!(with_history, after_reset, "history must matter");
    // Resize to another size and back: history restarts, output matches a fresh run.
    den.resize(20, 12).unwrap();
    assert_eq!(den.denoise_host(&random_frame(20, 12, 5)).unwrap().width, 20);
    den.resize(16, 12).unwrap();
    common::assert_close(
        "resize == fresh",
        &den.denoise_host(&f0).unwrap(),
        &first,
        common::EXACT,
    );
    let e = den.denoise_host(&random_frame(8, 8, 1)).unwrap_err().to_string();
    assert!(e.contains("8x8") && e.contains("16x12"), "{e}");
}
