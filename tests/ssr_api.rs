//! The public SSR API: weight-file errors, padding of odd sizes, sanitising of NaN/Inf,
//! history reset and resize.

mod common;

use std::collections::HashMap;
use std::path::PathBuf;

use subpixel::nn::HostTensor;
use subpixel::ssr::{Denoiser, FrameInputs, HostFrame, Weights};

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

/// `t` with every pixel's vector scaled to unit length (the data contract's normals).
fn unit_normals(t: &HostTensor) -> HostTensor {
    HostTensor::from_fn(t.width, t.height, 3, |x, y, c| {
        let n = [t.at(x, y, 0), t.at(x, y, 1), t.at(x, y, 2)];
        let len = n.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-3);
        n[c as usize] / len
    })
}

fn random_frame(w: u32, h: u32, seed: u64) -> HostFrame {
    let r = |s: u64, c, lo, hi| common::random(seed * 100 + s, w, h, c, lo, hi);
    HostFrame {
        color: r(1, 3, 0.0, 4.0),
        mask: HostTensor::from_fn(w, h, 1, |x, y, _| ((x % 2 == 0) && (y % 2 == 0)) as u32 as f32),
        albedo: r(2, 3, 0.0, 1.0),
        normal: unit_normals(&r(3, 3, -1.0, 1.0)),
        shadow: r(4, 3, 0.0, 2.0),
        transparent: r(5, 3, 0.0, 1.0),
        depth: r(6, 1, 0.0, 1.0),
        metallic: r(7, 1, 0.0, 1.0),
        roughness: r(8, 1, 0.0, 1.0),
        motion: r(9, 2, -1.5, 1.5),
        background: None,
    }
}

/// Issue 13: transient tensors (hidden layers, pooled and resampled copies) share memory
/// by lifetime. Expectation from the graph's shapes alone: the network holds more than its
/// persistent tensors and less than all tensors apart; transient ones are not exposed.
#[test]
fn transient_tensors_share_memory() {
    use subpixel::ssr::graph::{Extent, TensorId};
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let (w, h) = (32u32, 24u32);
    let den = common::denoiser(&gpu, &weights, w, h).unwrap();
    let net = den.network();
    let bytes = |id: TensorId| {
        let (extent, c) = id.shape(&net.config);
        let px = match extent {
            Extent::Level(l) => ((w >> l) * (h >> l)) as u64,
            Extent::Single => 1,
            Extent::ExposureGroups => 0, // a few bytes; left out of both bounds
        };
        px * c.div_ceil(4) as u64 * 16
    };
    let all: u64 = TensorId::ALL.iter().map(|&id| bytes(id)).sum();
    let persistent: u64 = TensorId::ALL
        .iter()
        .filter(|id| !id.is_transient())
        .map(|&id| bytes(id))
        .sum();
    let held = net.memory_bytes();
    assert!(
        held > persistent && held < all,
        "held {held}, persistent {persistent}, all apart {all}"
    );
    // ref_hidden, emb_hidden_cur and emb_hidden_prev (same shape, one after the other)
    // take one buffer: at least two of them saved (`held` also has the 1-channel `ones`).
    let ones = (w * h) as u64 * 16;
    let hidden = bytes(TensorId::RefHidden);
    assert!(
        all + ones - held >= 2 * hidden,
        "held {held} of {all}, hidden {hidden}"
    );
    assert!(net.tensor("enc1_hidden").is_none() && net.tensor("enc1").is_some());
}

/// Issue 14: a fixed kernel runs every layer it can and the generic kernel the others; a
/// tiling no layer can run (too many accumulators) leaves every layer on the generic one.
/// Both give the autotuned denoiser's output (tuned among `common::TUNED_AMONG`) to the
/// parity tolerance.
#[test]
fn fixed_kernels_fall_back_to_generic_where_they_cannot_run() {
    use subpixel::nn::autotune::{EngineOptions, KernelChoice, Precision};
    use subpixel::nn::conv::ConvKernel;
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let frame = random_frame(20, 12, 3);
    let run = |kernels| {
        let options = EngineOptions {
            kernels,
            precision: Precision::F32,
            ..Default::default()
        };
        let mut den = Denoiser::with_options(&gpu, &weights, 20, 12, options).unwrap();
        let kernels: Vec<ConvKernel> = den.network().conv_kernels().into_iter().map(|(_, k)| k).collect();
        (kernels, den.denoise_host(&frame).unwrap())
    };
    let (auto, want) = run(common::tuned_kernels().kernels);
    assert!(!auto.is_empty());
    let too_big = ConvKernel::Blocked {
        px: 16,
        cob: 8,
        tex: false,
    };
    let (k, got) = run(KernelChoice::Fixed(too_big));
    assert!(k.iter().all(|&k| k == ConvKernel::Generic), "{k:?}");
    common::assert_close("fixed px16-cob8 (generic)", &got, &want, common::REDUCTION);
    let px4 = ConvKernel::Blocked {
        px: 4,
        cob: 1,
        tex: false,
    };
    let (k, got) = run(KernelChoice::Fixed(px4));
    assert!(k.iter().all(|&k| k == px4), "cob 1 fits every layer: {k:?}");
    common::assert_close("fixed px4-cob1", &got, &want, common::REDUCTION);
}

/// Issue 14: the kernels reading textures run on textures the network shares (each tensor
/// copied once a frame, or stored by the convolution producing it) and compute exactly
/// what the same tiling reading buffers computes: the same sums in the same order, so the
/// outputs of several frames (history included) are equal to the bit.
#[test]
fn texture_kernels_with_shared_textures_equal_buffer_kernels_to_the_bit() {
    use subpixel::nn::autotune::{EngineOptions, KernelChoice, Precision};
    use subpixel::nn::conv::ConvKernel;
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let frames: Vec<_> = (0..3).map(|i| random_frame(20, 12, 40 + i)).collect();
    let run = |kernel: ConvKernel| {
        let options = EngineOptions {
            kernels: KernelChoice::Fixed(kernel),
            precision: Precision::F32,
            ..Default::default()
        };
        let mut den = Denoiser::with_options(&gpu, &weights, 20, 12, options).unwrap();
        let used: Vec<ConvKernel> = den.network().conv_kernels().into_iter().map(|(_, k)| k).collect();
        // Layers whose weights the tiling's uniform array cannot hold run on the generic
        // kernel (whose outputs the texture readers then copy themselves).
        assert!(
            used.iter().all(|&k| k == kernel || k == ConvKernel::Generic),
            "{kernel}: {used:?}"
        );
        assert!(
            used.iter().filter(|&&k| k == kernel).count() >= used.len() / 2,
            "{kernel}: {used:?}"
        );
        frames
            .iter()
            .map(|f| den.denoise_host(f).unwrap())
            .collect::<Vec<_>>()
    };
    for (buffers, textures) in [
        ("px4-cob1", "px4-cob1-tex"),
        ("px2-cob2", "px2-cob2-tex"),
        ("wino-tx1-cob1", "wino-tx1-cob1-tex"),
    ] {
        let want = run(buffers.parse().unwrap());
        let got = run(textures.parse().unwrap());
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            let differ = g
                .data
                .iter()
                .zip(&w.data)
                .filter(|(a, b)| a.to_bits() != b.to_bits())
                .count();
            assert_eq!(
                differ, 0,
                "{textures} against {buffers}, frame {i}: {differ} values differ"
            );
        }
    }
}

#[test]
fn odd_sizes_are_padded_internally() {
    let gpu = common::gpu();
    // 3 levels pad to multiples of 4, a fourth level to multiples of 8
    let deep = golden_weights_path().with_file_name("golden_l4_weights.safetensors");
    for (path, m) in [(golden_weights_path(), 4), (deep, 8)] {
        let weights = Weights::load(&path).unwrap();
        assert_eq!(weights.config.pad_multiple(), m);
        for (w, h) in [(1, 1), (7, 5), (33, 17)] {
            let mut den = common::denoiser(&gpu, &weights, w, h).unwrap();
            let net = den.network();
            assert_eq!((net.width, net.height), (w.div_ceil(m) * m, h.div_ceil(m) * m));
            for t in 0..2 {
                let out = den.denoise_host(&random_frame(w, h, t)).unwrap();
                assert_eq!((out.width, out.height, out.channels), (w, h, 3));
                assert!(out.data.iter().all(|v| v.is_finite() && *v >= 0.0));
            }
        }
    }
}

#[test]
fn nan_and_inf_inputs_are_sanitised_and_counted() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let mut den = common::denoiser(&gpu, &weights, 12, 8).unwrap();
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
    // A normal with a non-finite component is no normal: it becomes 0 (as the sky's).
    let mut zeroed = clean.clone();
    zeroed.color.set(3, 2, 0, 0.0);
    for c in 0..3 {
        zeroed.normal.set(5, 5, c, 0.0);
    }
    zeroed.motion.set(0, 0, 0, 0.0);
    let mut fresh = common::denoiser(&gpu, &weights, 12, 8).unwrap();
    let want = fresh.denoise_host(&zeroed).unwrap();
    common::assert_close("sanitised == zeroed", &out, &want, common::EXACT);
}

#[test]
fn reset_and_resize_restart_the_history() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let (f0, f1) = (random_frame(16, 12, 3), random_frame(16, 12, 4));
    let mut den = common::denoiser(&gpu, &weights, 16, 12).unwrap();
    let first = den.denoise_host(&f0).unwrap();
    let with_history = den.denoise_host(&f1).unwrap();
    den.reset();
    let after_reset = den.denoise_host(&f1).unwrap();
    let mut fresh = common::denoiser(&gpu, &weights, 16, 12).unwrap();
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

fn golden_v1_weights_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden_v1_weights.safetensors")
}

/// `frame` with colour and shadow channel c multiplied by `k[c]` (a brighter or dimmer,
/// differently coloured light).
fn exposed(frame: &HostFrame, k: [f32; 3]) -> HostFrame {
    let scale =
        |t: &HostTensor| HostTensor::from_fn(t.width, t.height, 3, |x, y, c| t.at(x, y, c) * k[c as usize]);
    HostFrame {
        color: scale(&frame.color),
        shadow: scale(&frame.shadow),
        ..frame.clone()
    }
}

/// Issue 11: the shipped (version-1) model's output brightness barely followed the light's
/// (16x the light gave 3.6x the output), so scenes brighter or dimmer than the training
/// scenes came out wrong. With exposure normalisation (version 2) the engine is exactly
/// equivariant: scaling channel c of every radiance input by k_c scales output channel c by
/// k_c, for any weights and across frames (history re-exposed).
#[test]
fn exposure_scaled_inputs_scale_the_output() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    assert_eq!(weights.config.version, 2);
    for k in [[7.0, 0.25, 40.0], [1e-3; 3], [300.0; 3]] {
        let mut base = common::denoiser(&gpu, &weights, 16, 12).unwrap();
        let mut scaled = common::denoiser(&gpu, &weights, 16, 12).unwrap();
        for t in 0..3 {
            let f = random_frame(16, 12, 10 + t);
            let want = base.denoise_host(&f).unwrap();
            let want = HostTensor::from_fn(16, 12, 3, |x, y, c| want.at(x, y, c) * k[c as usize]);
            let got = scaled.denoise_host(&exposed(&f, k)).unwrap();
            let peak = want.data.iter().fold(0f32, |m, v| m.max(v.abs()));
            common::assert_close(
                &format!("k {k:?} frame {t}"),
                &got,
                &want,
                common::Tol {
                    abs: 1e-5 * peak,
                    rel: 1e-3,
                },
            );
        }
    }
    // The shadow buffer holds the light's own radiance (an environment's sun: ~7e4, an area
    // light: ~20); it is normalised on its own, so its magnitude alone changes nothing.
    let mut base = common::denoiser(&gpu, &weights, 16, 12).unwrap();
    let mut sun = common::denoiser(&gpu, &weights, 16, 12).unwrap();
    for t in 0..2 {
        let f = random_frame(16, 12, 30 + t);
        let want = base.denoise_host(&f).unwrap();
        let s = &f.shadow;
        let bright = HostFrame {
            shadow: HostTensor::from_fn(16, 12, 3, |x, y, c| s.at(x, y, c) * 5000.0),
            ..f.clone()
        };
        let got = sun.denoise_host(&bright).unwrap();
        let peak = want.data.iter().fold(0f32, |m, v| m.max(v.abs()));
        let tol = common::Tol {
            abs: 1e-5 * peak,
            rel: 1e-3,
        };
        common::assert_close(&format!("shadow x 5000, frame {t}"), &got, &want, tol);
    }
    // The version-1 pipeline fails this: its output hardly follows the light.
    let v1 = Weights::load(golden_v1_weights_path()).unwrap();
    let f = random_frame(16, 12, 10);
    let base = common::denoiser(&gpu, &v1, 16, 12)
        .unwrap()
        .denoise_host(&f)
        .unwrap();
    let k = [7.0, 0.25, 40.0];
    let scaled = common::denoiser(&gpu, &v1, 16, 12)
        .unwrap()
        .denoise_host(&exposed(&f, k))
        .unwrap();
    let mean = |t: &HostTensor, c: u32| {
        (0..12)
            .flat_map(|y| (0..16).map(move |x| (x, y)))
            .map(|(x, y)| t.at(x, y, c) as f64)
            .sum::<f64>()
    };
    for c in 0..3 {
        let ratio = mean(&scaled, c) / mean(&base, c) / k[c as usize] as f64;
        assert!(
            !(0.9..1.1).contains(&ratio),
            "version 1, channel {c}: ratio {ratio}"
        );
    }
}

/// A camera cut without `reset()`: the new frame shows other geometry (depth halved) behind
/// the same colours, with zero motion, so every history sample stays on screen. Version-2
/// weights reject all of it (alpha 0, W(o) 0): the output is that of a fresh start. The
/// version-1 pipeline blended it in (issue 11: alpha 0.55-0.86 after cuts).
#[test]
fn history_of_other_geometry_is_rejected_after_a_cut() {
    let gpu = common::gpu();
    let a = random_frame(16, 12, 20);
    let mut b = a.clone();
    b.depth = HostTensor::from_fn(16, 12, 1, |x, y, _| 0.5 * a.depth.at(x, y, 0));
    b.motion = HostTensor::from_fn(16, 12, 2, |_, _, _| 0.0);
    for (path, rejected) in [(golden_weights_path(), true), (golden_v1_weights_path(), false)] {
        let weights = Weights::load(&path).unwrap();
        let mut den = common::denoiser(&gpu, &weights, 16, 12).unwrap();
        den.denoise_host(&a).unwrap();
        den.denoise_host(&a).unwrap();
        let after_cut = den.denoise_host(&b).unwrap();
        let alpha = den.network().tensor("tfa_weights").unwrap().read(&gpu).unwrap();
        let max_alpha = (0..12)
            .flat_map(|y| (0..16).map(move |x| (x, y)))
            .map(|(x, y)| alpha.at(x, y, 1))
            .fold(0f32, f32::max);
        let mut fresh = common::denoiser(&gpu, &weights, 16, 12).unwrap();
        let reset = fresh.denoise_host(&b).unwrap();
        if rejected {
            assert_eq!(
                max_alpha,
                0.0,
                "{}: history of other geometry kept",
                path.display()
            );
            common::assert_close(
                "after a cut == fresh start",
                &after_cut,
                &reset,
                common::Tol { abs: 1e-5, rel: 1e-4 },
            );
        } else {
            assert!(
                max_alpha > 0.3,
                "version 1 blends the old history in ({max_alpha})"
            );
            assert_ne!(after_cut, reset);
        }
    }
}

#[test]
fn weights_version_must_match_the_config() {
    let v1_meta_on_v2_config = edited(|_, m| {
        m.insert("version".into(), "1".into());
    });
    let e = load_err(&v1_meta_on_v2_config);
    assert!(e.contains("test.safetensors"), "{e}");
    assert!(
        e.contains("version 1 has no 'exposure' option") || e.contains("config is version 2"),
        "{e}"
    );
    let v1 = Weights::load(golden_v1_weights_path()).unwrap();
    assert_eq!(v1.metadata["version"], "1");
    assert_eq!(v1.config, v1.config.legacy());
}

/// Issue 12 item 2: finite values outside the data contract's ranges (a mask of 100 or
/// 1e30, albedo, depth or normal of -1000) put +Inf into the output. Each is brought into
/// its range and counted, and the output equals that of the frame holding the in-range
/// values (mask 1, albedo 0, depth 0, the normal scaled to unit length).
#[test]
fn out_of_range_inputs_are_clamped_and_counted() {
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let clean = random_frame(12, 8, 2);
    let mut dirty = clean.clone();
    let mut fixed = clean.clone();
    let mut set = |field: fn(&mut HostFrame) -> &mut HostTensor, x, y, c, bad: f32, good: f32| {
        field(&mut dirty).set(x, y, c, bad);
        field(&mut fixed).set(x, y, c, good);
    };
    set(|f| &mut f.mask, 1, 1, 0, 100.0, 1.0);
    set(|f| &mut f.mask, 2, 1, 0, 1e30, 1.0);
    set(|f| &mut f.mask, 3, 1, 0, -3.0, 0.0);
    set(|f| &mut f.albedo, 4, 2, 1, -1000.0, 0.0);
    set(|f| &mut f.albedo, 5, 2, 0, 7.0, 1.0);
    set(|f| &mut f.depth, 6, 3, 0, -1000.0, 0.0);
    set(|f| &mut f.color, 7, 3, 2, -5.0, 0.0);
    set(|f| &mut f.roughness, 8, 4, 0, 1e30, 1.0);
    for (c, (bad, good)) in [(-1000.0, -1.0), (0.0, 0.0), (0.0, 0.0)].into_iter().enumerate() {
        set(|f| &mut f.normal, 9, 5, c as u32, bad, good);
    }
    let n = [
        fixed.normal.at(9, 5, 0),
        fixed.normal.at(9, 5, 1),
        fixed.normal.at(9, 5, 2),
    ];
    assert_eq!(n, [-1.0, 0.0, 0.0]);
    let mut den = common::denoiser(&gpu, &weights, 12, 8).unwrap();
    let out = den.denoise_host(&dirty).unwrap();
    let bad = out.data.iter().filter(|v| !v.is_finite()).count();
    assert_eq!(bad, 0, "{bad} non-finite output values");
    assert_eq!(den.sanitized_count().unwrap(), 9, "one per value out of range");
    let mut fresh = common::denoiser(&gpu, &weights, 12, 8).unwrap();
    let want = fresh.denoise_host(&fixed).unwrap();
    common::assert_close("clamped == in-range frame", &out, &want, common::EXACT);
}

/// Issue 12 item 2, the property: frames of random garbage (NaN, +-Inf, huge, tiny,
/// negative and merely out-of-range values in every channel) give a finite output, for
/// both pipelines, and the clean frames after them too (the history carries nothing
/// non-finite).
#[test]
fn garbage_frames_give_finite_output() {
    use rand::{Rng, SeedableRng, rngs::StdRng};
    const NASTY: [f32; 16] = [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        -f32::MAX,
        1e30,
        -1e30,
        1e12,
        -1000.0,
        100.0,
        2.0,
        -1.0,
        1e-40,
        -1e-40,
        1e-30,
        0.0,
    ];
    let gpu = common::gpu();
    let mut rng = StdRng::seed_from_u64(12);
    for path in [golden_weights_path(), golden_v1_weights_path()] {
        let weights = Weights::load(&path).unwrap();
        for (w, h) in [(12, 8), (5, 3)] {
            let mut den = common::denoiser(&gpu, &weights, w, h).unwrap();
            // Garbage with rising density (1 = every value), then clean frames.
            for (t, density) in [0.05, 0.3, 1.0, 0.5, 1.0, 0.0, 0.0].into_iter().enumerate() {
                let mut f = random_frame(w, h, 50 + t as u64);
                let garble = |t: &mut HostTensor, rng: &mut StdRng| {
                    for v in t.data.iter_mut() {
                        if rng.random_bool(density) {
                            *v = if rng.random_bool(0.7) {
                                NASTY[rng.random_range(0..NASTY.len())]
                            } else {
                                f32::from_bits(rng.random())
                            };
                        }
                    }
                };
                for t in f.tensors_mut() {
                    garble(t, &mut rng);
                }
                let out = den.denoise_host(&f).unwrap();
                let bad = out.data.iter().filter(|v| !v.is_finite()).count();
                assert_eq!(
                    bad,
                    0,
                    "{} {w}x{h} frame {t} (garbage density {density}): {bad} non-finite output values",
                    path.display()
                );
                assert!(out.data.iter().all(|v| *v >= 0.0), "radiance is never negative");
            }
            assert!(den.sanitized_count().unwrap() > 0);
        }
    }
}

/// Issue 12 item 10: the embedding API on a device with WebGPU's default limits (8 storage
/// buffers per stage, ...): every kernel of the denoiser fits, and a device below what a
/// kernel needs is refused by `Denoiser::new`, naming the kernel and the limit, instead of
/// failing at the first `denoise()`.
#[test]
fn denoiser_runs_on_default_limits_and_refuses_lower_ones() {
    use subpixel::nn::autotune::{EngineOptions, KernelChoice, Precision};
    use subpixel::nn::conv::ConvKernel;
    let weights = Weights::load(golden_weights_path()).unwrap();
    let frame = random_frame(12, 8, 7);
    // The same kernels on both devices, so that the outputs are equal to the bit: each
    // device is tuned on its own, and two tunings may pick kernels that sum in another
    // order (seen on a fresh machine: 1 ulp apart).
    let fixed = EngineOptions {
        kernels: KernelChoice::Fixed(ConvKernel::Blocked {
            px: 4,
            cob: 1,
            tex: false,
        }),
        precision: Precision::F32,
        ..Default::default()
    };
    let run = |gpu: &subpixel::gpu::Gpu, options| {
        Denoiser::with_options(gpu, &weights, 12, 8, options)
            .unwrap()
            .denoise_host(&frame)
            .unwrap()
    };
    let reference = run(&common::gpu(), fixed);
    let (device, queue) = device_with_limits(wgpu::Limits::default());
    let on_default = subpixel::gpu::Gpu::from_device(&device, &queue, device.adapter_info());
    common::assert_close(
        "default limits == adapter limits",
        &run(&on_default, fixed),
        &reference,
        common::EXACT,
    );
    // Tuned on default limits: the same output to the tolerance of kernels that sum in
    // another order (the API's own constructor, `Denoiser::new`, is refused below).
    let out = run(&on_default, common::tuned_kernels());
    common::assert_close("default limits, autotuned", &out, &reference, common::REDUCTION);
    // On lavapipe the parameters go in a storage buffer where the limits leave room for one
    // (gpu::ParamsBinding): with 8 storage buffers per stage, conv3x3 (7 + 1) does and
    // tfa_blend (8 + 1) keeps its uniform block; the output above is the same either way.
    let info = common::gpu().info.clone();
    let preferred = subpixel::gpu::ParamsBinding::for_adapter(&info);
    let small = subpixel::gpu::Gpu::from_device(&device, &queue, info);
    let big = common::gpu();
    for (kernel, on_default) in [
        ("nn/conv3x3", preferred),
        ("nn/tfa_blend", subpixel::gpu::ParamsBinding::Uniform),
    ] {
        assert_eq!(
            small.kernels.params_binding(kernel).unwrap(),
            on_default,
            "{kernel}"
        );
        assert_eq!(big.kernels.params_binding(kernel).unwrap(), preferred, "{kernel}");
    }

    let low = wgpu::Limits {
        max_storage_buffers_per_shader_stage: 5,
        ..wgpu::Limits::default()
    };
    let (device, queue) = device_with_limits(low);
    let e = Denoiser::new(&device, &queue, &weights, 12, 8)
        .err()
        .expect("a device with 5 storage buffers per stage is refused")
        .to_string();
    assert!(
        e.contains("max_storage_buffers_per_shader_stage") && e.contains("nn/conv3x3") && e.contains('5'),
        "{e}"
    );
}

/// The autotuner's scratch tensors stay within the device's buffer limits: a layer whose
/// own tensors fit is tuned at its own size where those of its tuning size (each side
/// rounded up to a power of two) would exceed the storage binding size, and tunes there.
#[test]
fn autotuning_stays_within_the_buffer_limits() {
    use subpixel::nn::autotune::{self, LayerStorage};
    use subpixel::nn::conv::Conv3x3;
    use subpixel::nn::ops::Activation;
    // The input, 13 channels (16 stored) of f32: 102,400 bytes at 40x40; 262,144 at 64x64,
    // the tuning size. The limit stays above the weights' 64 KiB buffer.
    let limits = wgpu::Limits {
        max_storage_buffer_binding_size: 150_000,
        ..wgpu::Limits::default()
    };
    let (device, queue) = device_with_limits(limits);
    let info = common::gpu().info.clone();
    let small = subpixel::gpu::Gpu::from_device(&device, &queue, info);
    let big = common::gpu();
    // An unusual shape, so that no earlier tuning is cached for it.
    let conv = |g: &subpixel::gpu::Gpu| {
        let w: Vec<f32> = (0..13 * 11 * 9).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect();
        Conv3x3::new(g, "limits", &w, &[0.0; 11], &[13], 11, Activation::Relu).unwrap()
    };
    let (cs, cb) = (conv(&small), conv(&big));
    let storage = LayerStorage::f32(&cs);
    assert_eq!(autotune::tuning_size(&big, &cb, 40, 40, &storage), (64, 64));
    assert_eq!(autotune::tuning_size(&small, &cs, 40, 40, &storage), (40, 40));
    // At its own size every candidate runs; at 64x64 none could.
    let own = autotune::measure(&small, &cs, 40, 40, &storage, None, 1, 1).unwrap();
    assert!(own.candidates.iter().all(|c| c.median_ms.is_some()), "{own:?}");
    let e = autotune::measure(&small, &cs, 64, 64, &storage, None, 1, 1).unwrap_err();
    assert!(e.to_string().contains("no candidate"), "{e}");
    let (tuning, _) = autotune::tune(&small, &cs, 40, 40, &storage, None).unwrap();
    assert!(own.candidates.iter().any(|c| c.kernel == tuning.choice));
}

/// `KernelChoice::Among`: a tuning among a set of kernels times those of them the layer
/// can run and the generic kernel, nothing else, picks one of them, and is cached apart
/// from a full tuning of the same shape; a kernel the autotuner does not know is refused
/// by name.
#[test]
fn tuning_among_a_set_times_only_its_kernels() {
    use subpixel::nn::autotune::{self, KernelChoice, KernelSet, LayerStorage};
    use subpixel::nn::conv::{Conv3x3, ConvKernel};
    use subpixel::nn::ops::Activation;
    let g = common::gpu();
    // An unusual shape, so that no earlier tuning is cached for it.
    let w: Vec<f32> = (0..7 * 9 * 9).map(|i| ((i % 7) as f32 - 3.0) * 0.02).collect();
    let conv = Conv3x3::new(&g, "among", &w, &[0.0; 9], &[7], 9, Activation::Relu).unwrap();
    let storage = LayerStorage::f32(&conv);
    let set: KernelSet = "px2-cob1,wino-tx1-cob1".parse().unwrap();
    assert_eq!(set.to_string(), "px2-cob1,wino-tx1-cob1");
    let want: Vec<ConvKernel> = ["generic", "px2-cob1", "wino-tx1-cob1"]
        .iter()
        .map(|k| k.parse().unwrap())
        .collect();
    // Measured now (never from a cache, which may hold this shape from an earlier run).
    let (tw, th) = autotune::tuning_size(&g, &conv, 20, 12, &storage);
    let m = autotune::measure(&g, &conv, tw, th, &storage, Some(set), 1, 1).unwrap();
    let timed: Vec<ConvKernel> = m.candidates.iter().map(|c| c.kernel).collect();
    assert_eq!(timed, want);
    assert!(want.contains(&m.choice), "{m:?}");
    // Tuned (measured, or read back from the disk cache), then held in memory.
    let (t, _) = autotune::tune(&g, &conv, 20, 12, &storage, Some(set)).unwrap();
    let timed: Vec<ConvKernel> = t.candidates.iter().map(|c| c.kernel).collect();
    assert_eq!(timed, want);
    assert!(want.contains(&t.choice), "{t:?}");
    assert!(autotune::tune(&g, &conv, 20, 12, &storage, Some(set)).unwrap().1);
    let (full, among) = (
        autotune::key(&g, &conv, tw, th, &storage, None),
        autotune::key(&g, &conv, tw, th, &storage, Some(set)),
    );
    assert!(
        among.ends_with(" among px2-cob1,wino-tx1-cob1") && among.starts_with(&full),
        "{among}"
    );
    // The denoiser's choice of every layer is among them.
    let weights = Weights::load(golden_weights_path()).unwrap();
    let options = subpixel::nn::autotune::EngineOptions {
        kernels: KernelChoice::Among(set),
        ..Default::default()
    };
    let den = Denoiser::with_options(&g, &weights, 20, 12, options).unwrap();
    for (layer, k) in den.network().conv_kernels() {
        assert!(want.contains(&k), "{layer}: {k}");
    }
    let e = "px4-cob1,px3-cob1".parse::<KernelSet>().unwrap_err().to_string();
    assert!(e.contains("px3-cob1"), "{e}");
}

/// A device on the test adapter created with exactly `limits`.
fn device_with_limits(limits: wgpu::Limits) -> (wgpu::Device, wgpu::Queue) {
    let adapter = common::gpu()
        .origin
        .expect("the test context made its own adapter")
        .1;
    pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("test.limits"),
        required_features: wgpu::Features::empty(),
        required_limits: limits,
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .expect("the adapter offers WebGPU's default limits")
}

/// Issue 13: `denoise_host` after `denoise` with the caller's buffers (which, like the
/// tracer's, may allow COPY_DST) uploads into the denoiser's own buffers and leaves the
/// caller's untouched; both calls give what a fresh denoiser gives for the same frames.
#[test]
fn denoise_host_never_writes_the_callers_buffers() {
    use wgpu::util::DeviceExt;
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let (w, h) = (12, 8);
    let (a, b) = (random_frame(w, h, 21), random_frame(w, h, 22));
    let packed = a.pack(subpixel::ssr::AlbedoSource::Centre).unwrap();
    let caller: Vec<wgpu::Buffer> = packed
        .iter()
        .map(|d| {
            gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("test.caller"),
                contents: bytemuck::cast_slice(d),
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::COPY_SRC,
            })
        })
        .collect();
    let inputs = FrameInputs::from_slice(&caller).unwrap();
    let mut den = common::denoiser(&gpu, &weights, w, h).unwrap();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    den.denoise(&mut enc, &inputs).unwrap();
    gpu.queue.submit([enc.finish()]);
    gpu.wait().unwrap();
    let out_a = den.read_output().unwrap();
    let out_b = den.denoise_host(&b).unwrap();
    for (buf, want) in caller.iter().zip(&packed) {
        let got = gpu.read_buffer(buf, 0, buf.size()).unwrap();
        assert_eq!(got, bytemuck::cast_slice::<[f32; 4], u8>(want), "{}", buf.size());
    }
    let e = FrameInputs::from_slice(&caller[..5]).unwrap_err().to_string();
    assert!(e.contains("5 buffers, expected 6 (color_mask,"), "{e}");
    let mut fresh = common::denoiser(&gpu, &weights, w, h).unwrap();
    common::assert_close("frame a", &out_a, &fresh.denoise_host(&a).unwrap(), common::EXACT);
    common::assert_close("frame b", &out_b, &fresh.denoise_host(&b).unwrap(), common::EXACT);
}

/// Issue 14 item 6: `Precision::Auto` keeps f16 activations only where the autotuner
/// measured them faster, and either way gives the f32 output to the f16 tolerance of
/// `tests/ssr_golden.rs` (2e-3 of the range); `Precision::F16` on a device without
/// SHADER_F16 is an error naming the feature.
#[test]
fn precision_auto_and_f16_need_and_follow_the_device() {
    use subpixel::nn::DType;
    use subpixel::nn::autotune::{EngineOptions, KernelChoice, Precision};
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let (w, h) = (20, 12);
    let run = |precision| {
        let options = EngineOptions {
            precision,
            ..common::tuned_kernels()
        };
        let mut den = Denoiser::with_options(&gpu, &weights, w, h, options).unwrap();
        let out = (0..2)
            .map(|t| den.denoise_host(&random_frame(w, h, t)).unwrap())
            .next_back()
            .unwrap();
        (den.network().activations(), out)
    };
    let (d32, want) = run(Precision::F32);
    assert_eq!(d32, DType::F32);
    let (auto, got) = run(Precision::Auto);
    if !gpu.has(wgpu::Features::SHADER_F16) {
        assert_eq!(auto, DType::F32);
    }
    let (lo, hi) = want
        .data
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let tol = common::Tol {
        abs: 2e-3 * (hi - lo).max(1e-6),
        rel: 0.0,
    };
    common::assert_close(&format!("auto ({})", auto.name()), &got, &want, tol);
    // A device created without SHADER_F16 refuses f16 activations by name.
    let (device, queue) = device_with_limits(wgpu::Limits::default());
    let bare = subpixel::gpu::Gpu::from_device(&device, &queue, device.adapter_info());
    let options = EngineOptions {
        kernels: KernelChoice::Fixed(subpixel::nn::conv::ConvKernel::Generic),
        precision: Precision::F16,
        ..Default::default()
    };
    let e = Denoiser::with_options(&bare, &weights, w, h, options)
        .err()
        .expect("f16 without SHADER_F16 is refused")
        .to_string();
    assert!(e.contains("f16") && e.contains("SHADER_F16"), "{e}");
    // ... and Auto there runs f32.
    let options = EngineOptions {
        kernels: KernelChoice::Fixed(subpixel::nn::conv::ConvKernel::Generic),
        precision: Precision::Auto,
        ..Default::default()
    };
    let den = Denoiser::with_options(&bare, &weights, w, h, options).unwrap();
    assert_eq!(den.network().activations(), DType::F32);
}

/// Issue 11 (sixth session): with config `ceiling = "max"` no output pixel exceeds
/// `M_c (albedo_c + 0.00316)`, M the running max over the traced pixels of the demodulated
/// colour (`M_t = max(m_t, CEILING_DECAY M_{t-1})`), whatever the network does. The bound is
/// computed here from the inputs alone; the golden weights (red output bias pushed up) reach
/// it, the shipped ones must respect it too. Odd size: the padding must not change M.
#[test]
fn output_never_exceeds_the_brightest_recent_sample() {
    use subpixel::frame::Background;
    use subpixel::ssr::{AlbedoSource, CEILING_DECAY, CEILING_GAIN, CeilingMode};
    let gpu = common::gpu();
    let shipped = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("weights/ssr.safetensors");
    let (w, h) = (15u32, 11u32);
    for (path, must_reach) in [(golden_weights_path(), true), (shipped, false)] {
        let weights = Weights::load(&path).unwrap();
        assert_eq!(
            weights.config.ceiling_mode().unwrap(),
            CeilingMode::Max,
            "{path:?}"
        );
        let mut den = common::denoiser(&gpu, &weights, w, h).unwrap();
        // The albedo the model demodulates with: the G-buffer's, or (config albedo
        // "footprint", the shipped model) the frame's footprint albedo, here another one.
        let footprint = weights.config.albedo_source().unwrap() == AlbedoSource::Footprint;
        let mut m = [0f32; 3];
        let mut reached = 0;
        for t in 0..4u64 {
            let mut f = random_frame(w, h, 70 + t);
            // no emitter seen directly (what a model of config emission "background" reads)
            f.background = Some(Background {
                radiance: HostTensor::zeros(w, h, 3),
                coverage: HostTensor::zeros(w, h, 1),
                albedo: Some(common::random(7_000 + t, w, h, 3, 0.0, 1.0)),
                emission: Some(subpixel::frame::DirectEmission {
                    footprint: HostTensor::zeros(w, h, 3),
                    samples: HostTensor::zeros(w, h, 3),
                    escaped: None,
                }),
            });
            let albedo = if footprint {
                f.background.as_ref().unwrap().albedo.clone().unwrap()
            } else {
                f.albedo.clone()
            };
            if t == 1 {
                // a tiny bright emitter on a traced pixel
                for c in 0..3 {
                    f.color.data[(2 * w as usize + 2) * 3 + c] = 5000.0;
                }
            }
            let mut frame_max = [0f32; 3];
            for y in 0..h {
                for x in 0..w {
                    if f.mask.at(x, y, 0) > 0.5 {
                        for c in 0..3 {
                            let d = f.color.at(x, y, c) / (albedo.at(x, y, c) + 0.00316);
                            frame_max[c as usize] = frame_max[c as usize].max(d);
                        }
                    }
                }
            }
            for c in 0..3 {
                m[c] = if t == 0 {
                    frame_max[c]
                } else {
                    frame_max[c].max(CEILING_DECAY * m[c])
                };
            }
            let out = den.denoise_host(&f).unwrap();
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        let bound = CEILING_GAIN * m[c as usize] * (albedo.at(x, y, c) + 0.00316);
                        let v = out.at(x, y, c);
                        assert!(
                            v.is_finite() && v <= bound * 1.0001,
                            "{path:?} frame {t} ({x}, {y}, {c}): {v} > {bound}"
                        );
                        reached += (v >= bound * 0.999) as u32;
                    }
                }
            }
        }
        if must_reach {
            assert!(reached > 0, "the golden weights reach the ceiling");
        }
    }
}

/// The optional background of the frame contract (DESIGN §3): the output is background +
/// (1 - coverage) x the network's reconstruction (the background alone where the coverage is
/// 1, the reconstruction alone where it is 0), with the background sanitised as colour is
/// and the coverage brought into [0, 1] (non-finite: 0), every value changed counted. The
/// history stays the network's own, so a later frame without a background comes out
/// exactly as if none had ever been given.
#[test]
fn background_composites_by_coverage() {
    use subpixel::frame::Background;
    let gpu = common::gpu();
    let weights = Weights::load(golden_weights_path()).unwrap();
    let (w, h) = (16, 12);
    let mut plain = common::denoiser(&gpu, &weights, w, h).unwrap();
    let mut with = common::denoiser(&gpu, &weights, w, h).unwrap();
    let mut coverage = HostTensor::from_fn(w, h, 1, |x, y, _| {
        [1.0, 0.75, 0.0, 1.0][((x + 3 * y) % 4) as usize]
    });
    coverage.set(1, 0, 0, f32::NAN);
    coverage.set(2, 0, 0, f32::INFINITY);
    let mut radiance = HostTensor::from_fn(w, h, 3, |x, y, c| {
        (0.1 * (x + y + c) as f32 + 0.05) * coverage.at(x, y, 0)
    });
    radiance.set(0, 0, 0, f32::NAN); // output 0 there, counted
    radiance.set(3, 0, 2, -2.0); // output 0 there, counted
    // (Pixels (1, 0) and (2, 0), of NaN and infinite coverage, get non-finite radiance from
    // the premultiplication: all counted, all 0.)
    let f0 = random_frame(w, h, 50);
    let want = plain.denoise_host(&f0).unwrap();
    let bg = HostFrame {
        background: Some(Background {
            radiance: radiance.clone(),
            coverage: coverage.clone(),
            albedo: None,
            emission: None,
        }),
        ..f0.clone()
    };
    let got = with.denoise_host(&bg).unwrap();
    let (mut sky, mut mixed, mut changed) = (0, 0, 0);
    let out_of_range = |v: f32, lo: f32, hi: f32| !(lo..=hi).contains(&v) as u64;
    for y in 0..h {
        for x in 0..w {
            let c = coverage.at(x, y, 0);
            changed += out_of_range(c, 0.0, 1.0);
            let c = if c.is_finite() { c.clamp(0.0, 1.0) } else { 0.0 };
            sky += (c == 1.0) as u32;
            mixed += (c > 0.0 && c < 1.0) as u32;
            for k in 0..3 {
                let r = radiance.at(x, y, k);
                changed += out_of_range(r, 0.0, 1e12);
                let r = if r.is_finite() { r.max(0.0) } else { 0.0 };
                let expect = r + (1.0 - c) * want.at(x, y, k);
                let g = got.at(x, y, k);
                assert!(
                    (g - expect).abs() <= 1e-6 * (1.0 + expect.abs()),
                    "pixel ({x}, {y}) channel {k}: {g} vs {expect}"
                );
                if c == 1.0 {
                    assert_eq!(g, r, "wholly sky pixel ({x}, {y}): the background alone");
                }
            }
        }
    }
    assert!(sky > 40 && mixed > 40, "{sky} wholly sky, {mixed} mixed pixels");
    let counted = with.sanitized_count().unwrap() - plain.sanitized_count().unwrap();
    assert_eq!(changed, 10); // the four pixels above: 1 + 4 (NaN coverage) + 4 (Inf) + 1
    assert_eq!(counted, changed, "background values sanitised");
    // The next frame, without a background: the same on both.
    let f1 = random_frame(w, h, 51);
    assert_eq!(with.denoise_host(&f1).unwrap(), plain.denoise_host(&f1).unwrap());
    // A background of the wrong size is refused, naming it.
    let small = HostFrame {
        background: Some(Background {
            radiance: HostTensor::zeros(w - 1, h, 3),
            coverage: HostTensor::zeros(w - 1, h, 1),
            albedo: None,
            emission: None,
        }),
        ..f1
    };
    let e = with.denoise_host(&small).unwrap_err().to_string();
    assert!(e.contains("background"), "{e}");
}

/// The mean correction (config `mean_correction = "tiles"`): per 32x32 tile and channel, the
/// reconstruction is scaled by the traced samples' sum over its own at the same pixels over
/// the last 4 frames (clamped, interpolated between tile centres), against the CPU reference
/// (`nn::reference::mean_tile_*`) applied to the output of the same weights without the
/// option. With a background only the reconstructed part is scaled (the background stays);
/// a reset forgets the earlier frames' sums. The history is the network's own, so the
/// uncorrected denoiser gives the reconstruction on every frame.
#[test]
fn mean_correction_scales_each_tile_to_its_samples() {
    check_mean_correction("tiles", subpixel::ssr::MEAN_TILE, (2, 2));
}

/// The same with config `mean_correction = "tiles16"`: 16-pixel tiles (4 x 3 of them).
#[test]
fn mean_correction_tiles16_scales_each_16_pixel_tile() {
    check_mean_correction("tiles16", 16, (4, 3));
}

fn check_mean_correction(option: &str, side: u32, tiles: (u32, u32)) {
    use subpixel::nn::reference::{mean_factor_at, mean_tile_factors, mean_tile_sums};
    use subpixel::ssr::{MEAN_EPS, MEAN_HI, MEAN_LO, MEAN_RING, MeanCorrection};
    let mut weights = Weights::load(golden_weights_path()).unwrap();
    weights.config.mean_correction = Some(option.into());
    assert_eq!(
        weights.config.mean_correction().unwrap(),
        MeanCorrection::Tiles { side }
    );
    let (w, h) = (64, 40);
    let mut sums: Vec<HostTensor> = Vec::new();
    let frame = |t: u64| {
        let mut f = random_frame(w, h, 70 + t);
        // Brighter samples on the left: the tiles' factors differ.
        f.color = HostTensor::from_fn(w, h, 3, |x, y, c| {
            f.color.at(x, y, c) * if x < 24 { 8.0 } else { 1.0 }
        });
        f
    };
    let factors = |f: &HostFrame, part: &HostTensor, sample: &HostTensor, reset: bool| {
        if reset {
            sums.clear();
        }
        sums.push(mean_tile_sums(part, sample, &f.mask, side));
        let recent = &sums[sums.len().saturating_sub(MEAN_RING as usize)..];
        let factors = mean_tile_factors(recent, MEAN_EPS, MEAN_LO, MEAN_HI);
        assert_eq!((factors.width, factors.height), tiles);
        let per_pixel = HostTensor::from_fn(w, h, 3, |x, y, c| mean_factor_at(&factors, side, x, y, c));
        (per_pixel, factors.data)
    };
    check_corrected_output(&weights, (w, h), 2e-5, common::fixed_kernels(), frame, factors);
}

/// Runs seven frames (`frame(t)`, given a background on the odd ones) through a denoiser of
/// `weights` and one of the same weights without the mean correction, resetting both before
/// frame 5, and checks every output pixel against the background plus the uncorrected
/// reconstruction's part times its factor from `factors(frame, part, sample, reset)` (the
/// per-pixel factors and the values the correction computes, counted: some must be clamped
/// and some between the clamps and away from 1), within `tol` relative to `1 + |expect|`.
/// For weights of config escaped "background" every frame has a background, and a third of
/// the traced pixels' samples escaped: the factors see the frame as the model is fed it
/// (those pixels left out) and, as samples, the rest times `1 - coverage`. `options` run
/// both denoisers.
fn check_corrected_output(
    weights: &Weights,
    (w, h): (u32, u32),
    tol: f32,
    options: subpixel::nn::autotune::EngineOptions,
    mut frame: impl FnMut(u64) -> HostFrame,
    mut factors: impl FnMut(&HostFrame, &HostTensor, &HostTensor, bool) -> (HostTensor, Vec<f32>),
) {
    use subpixel::frame::{Background, DirectEmission, EmissionSource, EscapedSource};
    use subpixel::ssr::{MEAN_HI, MEAN_LO};
    let escaped = weights.config.escaped_source().unwrap() == EscapedSource::Background;
    let gpu = common::gpu();
    let mut uncorrected = weights.clone();
    uncorrected.config.mean_correction = Some("none".into());
    let mut plain = Denoiser::with_options(&gpu, &uncorrected, w, h, options).unwrap();
    let mut corrected = Denoiser::with_options(&gpu, weights, w, h, options).unwrap();
    let (mut clamped, mut between) = (0, 0);
    for t in 0..7u64 {
        if t == 5 {
            plain.reset();
            corrected.reset();
        }
        let mut f = frame(t);
        let background = (escaped || t % 2 == 1).then(|| {
            let coverage = HostTensor::from_fn(w, h, 1, |x, y, _| [0.0, 0.5, 1.0][((x + y) % 3) as usize]);
            let radiance =
                HostTensor::from_fn(w, h, 3, |x, y, c| 0.3 * (c + 1) as f32 * coverage.at(x, y, 0));
            let emission = escaped.then(|| DirectEmission {
                footprint: HostTensor::zeros(w, h, 3),
                samples: HostTensor::zeros(w, h, 3),
                escaped: Some(HostTensor::from_fn(w, h, 1, |x, y, _| {
                    (x / 2 + 2 * (y / 2) + t as u32).is_multiple_of(3) as u32 as f32
                })),
            });
            Background {
                radiance,
                coverage,
                albedo: None,
                emission,
            }
        });
        f.background = background.clone();
        let want = plain.denoise_host(&f).unwrap();
        let got = corrected.denoise_host(&f).unwrap();
        let bg = |x, y, c| background.as_ref().map_or(0.0, |b| b.radiance.at(x, y, c));
        let part = HostTensor::from_fn(w, h, 3, |x, y, c| want.at(x, y, c) - bg(x, y, c));
        let fed = if escaped {
            let fed = f
                .fold_directly_seen(EmissionSource::Network, EscapedSource::Background)
                .unwrap();
            assert!(fed.mask.data.iter().sum::<f32>() < f.mask.data.iter().sum::<f32>());
            fed
        } else {
            f.clone()
        };
        let sample = HostTensor::from_fn(w, h, 3, |x, y, c| {
            let cov = background.as_ref().map_or(0.0, |b| b.coverage.at(x, y, 0));
            if escaped {
                (1.0 - cov) * fed.color.at(x, y, c)
            } else {
                fed.color.at(x, y, c) - bg(x, y, c)
            }
        });
        let (fac, values) = factors(&fed, &part, &sample, t == 5);
        for v in values {
            if v == MEAN_LO || v == MEAN_HI {
                clamped += 1;
            } else if (v - 1.0).abs() > 0.02 {
                between += 1;
            }
        }
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let expect = bg(x, y, c) + part.at(x, y, c) * fac.at(x, y, c);
                    let g = got.at(x, y, c);
                    assert!(
                        (g - expect).abs() <= tol * (1.0 + expect.abs()),
                        "frame {t} pixel ({x}, {y}) channel {c}: {g} vs {expect}"
                    );
                }
            }
        }
    }
    assert!(
        clamped > 0 && between > 0,
        "{clamped} clamped and {between} other factors"
    );
}

/// Config `mean_correction = "atrous"`: per pixel and channel, the reconstruction is scaled
/// by the ratio of the traced samples to its own values at the same pixels, each summed over
/// the frames along the motion (the last frame's sums warped and decayed), both filtered by
/// the edge-aware a-trous filter of the frame's normals and depths, against the CPU
/// reference (`nn::reference::mean_pixel_sums`, `mean_history_sums`, `mean_atrous_factors`)
/// applied to the output of the same weights without the option. The frame holds two
/// surfaces (left: facing the camera, near; right: turned away, farther) with samples
/// brighter on the left, and noisy normals within each, and random motion (some of it off
/// the frame); with a background only the reconstructed part is scaled; a reset forgets the
/// earlier frames' sums. The filter gives these factors at any number of pixels per
/// invocation (`AtrousPixels`: the one chosen by default, 1, 4, and 5, which does not
/// divide the frame's width at any level's step).
#[test]
fn mean_correction_atrous_follows_each_surfaces_samples() {
    use subpixel::nn::autotune::AtrousPixels;
    for px in [
        AtrousPixels::FromEnv,
        AtrousPixels::Fixed(1),
        AtrousPixels::Fixed(4),
        AtrousPixels::Fixed(5),
    ] {
        check_atrous_correction("network", px);
    }
}

/// The same for a model of config escaped "background": the samples that escaped to the
/// environment are left out of what it is fed, and the factors compare the rest, weighted by
/// `1 - coverage`, with the reconstruction's share of the output.
#[test]
fn mean_correction_atrous_leaves_escaped_samples_to_the_background() {
    use subpixel::nn::autotune::{ATROUS_PIXELS_MAX, AtrousPixels};
    for px in [AtrousPixels::FromEnv, AtrousPixels::Fixed(ATROUS_PIXELS_MAX)] {
        check_atrous_correction("background", px);
    }
}

/// Pixels per invocation outside 1 to `ATROUS_PIXELS_MAX` are refused when the denoiser is
/// made, naming the number.
#[test]
fn atrous_pixels_out_of_range_are_refused() {
    use subpixel::nn::autotune::{ATROUS_PIXELS_MAX, AtrousPixels, EngineOptions};
    let gpu = common::gpu();
    let mut weights = Weights::load(golden_weights_path()).unwrap();
    weights.config.mean_correction = Some("atrous".into());
    for px in [0, ATROUS_PIXELS_MAX + 1] {
        let options = EngineOptions {
            atrous_pixels: AtrousPixels::Fixed(px),
            ..Default::default()
        };
        let e = Denoiser::with_options(&gpu, &weights, 16, 8, options)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains(&format!("{px} pixels per invocation")), "{e}");
    }
}

fn check_atrous_correction(escaped: &str, atrous_pixels: subpixel::nn::autotune::AtrousPixels) {
    use subpixel::nn::autotune::{AtrousPixels, EngineOptions};
    use subpixel::nn::reference::{mean_atrous_factors, mean_history_sums, mean_pixel_sums};
    use subpixel::ssr::{
        ATROUS_DECAY, ATROUS_DEPTH_SIGMA, ATROUS_EPS, ATROUS_LEVELS, ATROUS_NORMAL_SQUARINGS, MEAN_HI,
        MEAN_LO, MeanCorrection,
    };
    let mut weights = Weights::load(golden_weights_path()).unwrap();
    weights.config.mean_correction = Some("atrous".into());
    weights.config.escaped = Some(escaped.into());
    assert_eq!(weights.config.mean_correction().unwrap(), MeanCorrection::Atrous);
    let (w, h) = (48, 36);
    let left = |x: u32| x < 20;
    let frame = |t: u64| {
        let mut f = random_frame(w, h, 90 + t);
        let jitter = f.normal.clone();
        f.normal = unit_normals(&HostTensor::from_fn(w, h, 3, |x, y, c| {
            let base = if left(x) { [0.0, 0.0, 1.0] } else { [0.8, 0.0, 0.6] };
            base[c as usize] + 0.3 * jitter.at(x, y, c)
        }));
        f.depth = HostTensor::from_fn(w, h, 1, |x, y, _| {
            if left(x) {
                0.2 + 0.002 * y as f32
            } else {
                0.5 + 0.01 * x as f32
            }
        });
        // Samples brighter on the left: the two surfaces' factors differ.
        f.color = HostTensor::from_fn(w, h, 3, |x, y, c| {
            f.color.at(x, y, c) * if left(x) { 8.0 } else { 1.0 }
        });
        // Every pixel traced once over 4 frames, as the tracer's quarter pattern.
        let (ox, oy) = [(0, 0), (1, 1), (1, 0), (0, 1)][(t % 4) as usize];
        f.mask = HostTensor::from_fn(w, h, 1, |x, y, _| (x % 2 == ox && y % 2 == oy) as u32 as f32);
        f
    };
    let mut history: Option<HostTensor> = None;
    let factors = |f: &HostFrame, part: &HostTensor, sample: &HostTensor, reset: bool| {
        if reset {
            history = None;
        }
        let own = mean_pixel_sums(part, sample, &f.mask);
        let sums = mean_history_sums(&own, history.as_ref(), &f.motion, ATROUS_DECAY);
        let factors = mean_atrous_factors(
            &sums,
            &f.normal,
            &f.depth,
            ATROUS_LEVELS,
            ATROUS_NORMAL_SQUARINGS,
            ATROUS_DEPTH_SIGMA,
            ATROUS_EPS,
            MEAN_LO,
            MEAN_HI,
        );
        history = Some(sums);
        let values = factors.data.clone();
        (factors, values)
    };
    // The default (timed, FromEnv) on tuned kernels, as a user's denoiser chooses it; a
    // fixed count on fixed kernels (nothing timed).
    let options = match atrous_pixels {
        AtrousPixels::FromEnv => common::tuned_kernels(),
        _ => common::fixed_kernels(),
    };
    let options = EngineOptions {
        atrous_pixels,
        ..options
    };
    check_corrected_output(&weights, (w, h), 2e-5, options, frame, factors);
}

/// Config albedo "footprint": the whole pipeline runs on the frame's footprint albedo
/// instead of the G-buffer's, so a footprint model on a frame gives exactly what the same
/// weights as a centre model give on that frame with its albedo replaced by the footprint
/// albedo (over several frames: the history too), and not what they give on the frame as
/// it is; a frame without a footprint albedo is refused, naming it.
#[test]
fn footprint_albedo_models_take_the_frames_footprint_albedo() {
    use subpixel::frame::Background;
    let gpu = common::gpu();
    let centre = Weights::load(golden_weights_path()).unwrap();
    let mut footprint = centre.clone();
    footprint.config.albedo = Some("footprint".into());
    let (w, h) = (20u32, 12u32);
    let mut a = common::denoiser(&gpu, &footprint, w, h).unwrap();
    let mut b = common::denoiser(&gpu, &centre, w, h).unwrap();
    let mut c = common::denoiser(&gpu, &centre, w, h).unwrap();
    for t in 0..3 {
        let mut f = random_frame(w, h, 90 + t);
        let albedo = common::random(9_000 + t, w, h, 3, 0.0, 1.0);
        f.background = Some(Background {
            radiance: HostTensor::zeros(w, h, 3),
            coverage: HostTensor::zeros(w, h, 1),
            albedo: Some(albedo.clone()),
            emission: None,
        });
        let swapped = HostFrame {
            albedo: albedo.clone(),
            ..f.clone()
        };
        let got = a.denoise_host(&f).unwrap();
        assert_eq!(got, b.denoise_host(&swapped).unwrap(), "frame {t}");
        assert_ne!(got, c.denoise_host(&f).unwrap(), "frame {t}");
    }
    let mut bare = random_frame(w, h, 99);
    let e = a.denoise_host(&bare).unwrap_err().to_string();
    assert!(
        e.contains("footprint albedo") && e.contains("albedo_footprint"),
        "{e}"
    );
    bare.background = Some(Background {
        radiance: HostTensor::zeros(w, h, 3),
        coverage: HostTensor::zeros(w, h, 1),
        albedo: None,
        emission: None,
    });
    assert!(a.denoise_host(&bare).is_err());
}

/// Config emission "background": the model is fed the colour without the traced samples'
/// first-hit emission and the output pass adds the footprint's, so (the golden weights have
/// no mean correction) it gives what the same weights as an emission-"network" model give
/// on that frame folded by hand, the footprint's emission added to the background (over
/// several frames: the history too), up to the order of the sums, and not what they give
/// on the frame as it is; a frame without the directly seen emission is refused, naming it.
#[test]
fn emission_background_models_take_the_emission_from_the_background() {
    use subpixel::frame::{Background, DirectEmission};
    let gpu = common::gpu();
    let network = Weights::load(golden_weights_path()).unwrap();
    let mut em = network.clone();
    em.config.emission = Some("background".into());
    let (w, h) = (20u32, 12u32);
    let mut a = common::denoiser(&gpu, &em, w, h).unwrap();
    let mut b = common::denoiser(&gpu, &network, w, h).unwrap();
    let mut c = common::denoiser(&gpu, &network, w, h).unwrap();
    for t in 0..3 {
        let mut f = random_frame(w, h, 120 + t);
        // part of each traced sample is emission; an emitter's footprint spills around it
        let samples = HostTensor::from_fn(w, h, 3, |x, y, k| {
            if (x + y) % 3 == 0 {
                0.5 * f.color.at(x, y, k)
            } else {
                0.0
            }
        });
        let footprint = common::random(7_000 + t, w, h, 3, 0.0, 4.0);
        let radiance = common::random(7_100 + t, w, h, 3, 0.0, 1.0);
        let coverage = HostTensor::from_fn(w, h, 1, |x, _, _| if x < 3 { 1.0 } else { 0.0 });
        f.background = Some(Background {
            radiance: radiance.clone(),
            coverage: coverage.clone(),
            albedo: None,
            emission: Some(DirectEmission {
                footprint: footprint.clone(),
                samples: samples.clone(),
                escaped: None,
            }),
        });
        let folded = HostFrame {
            color: HostTensor::from_fn(w, h, 3, |x, y, k| f.color.at(x, y, k) - samples.at(x, y, k)),
            background: Some(Background {
                radiance: HostTensor::from_fn(w, h, 3, |x, y, k| {
                    radiance.at(x, y, k) + footprint.at(x, y, k)
                }),
                coverage,
                albedo: None,
                emission: None,
            }),
            ..f.clone()
        };
        let got = a.denoise_host(&f).unwrap();
        // background + emission + (1 - coverage) x reconstruction, summed in another order
        let want = b.denoise_host(&folded).unwrap();
        for (i, (g, w)) in got.data.iter().zip(&want.data).enumerate() {
            assert!(
                (g - w).abs() <= 1e-5 * (1.0 + w.abs()),
                "frame {t} value {i}: {g} against {w}"
            );
        }
        assert_ne!(got, c.denoise_host(&f).unwrap(), "frame {t}");
    }
    let bare = random_frame(w, h, 129);
    let e = a.denoise_host(&bare).unwrap_err().to_string();
    assert!(e.contains("emission") && e.contains("emission_footprint"), "{e}");
}

/// `Config::input_names` is the embedding contract: the caller's own buffers, one per name in
/// that order (six for a model whose network reconstructs the emission, eight with the
/// background and the emission for one of config emission "background"), give exactly what
/// the host API gives on the same frame; the six alone are refused by the emission model,
/// naming the emission.
#[test]
fn a_configs_input_names_are_the_buffers_its_denoiser_takes() {
    use subpixel::frame::{AlbedoSource, Background, DirectEmission};
    use wgpu::util::DeviceExt;
    let gpu = common::gpu();
    let network = Weights::load(golden_weights_path()).unwrap();
    let mut em = network.clone();
    em.config.emission = Some("background".into());
    let (w, h) = (20u32, 12u32);
    for (weights, n, seed) in [(&network, 6, 140u64), (&em, 8, 150)] {
        let names = weights.config.input_names().unwrap();
        assert_eq!(names, &FrameInputs::ALL_NAMES[..n]);
        let mut host = common::denoiser(&gpu, weights, w, h).unwrap();
        let mut own = common::denoiser(&gpu, weights, w, h).unwrap();
        for t in 0..2 {
            let mut f = random_frame(w, h, seed + t);
            let radiance = common::random(7_200 + seed + t, w, h, 3, 0.0, 1.0);
            let coverage = HostTensor::from_fn(w, h, 1, |x, _, _| if x < 3 { 1.0 } else { 0.0 });
            let footprint = common::random(7_300 + seed + t, w, h, 3, 0.0, 4.0);
            let mut data: Vec<Vec<[f32; 4]>> = f.pack(AlbedoSource::Centre).unwrap().into();
            if n == 8 {
                f.background = Some(Background {
                    radiance,
                    coverage,
                    albedo: None,
                    emission: Some(DirectEmission {
                        footprint,
                        samples: HostTensor::zeros(w, h, 3),
                        escaped: None,
                    }),
                });
                data.push(f.pack_background().unwrap().unwrap());
                data.push(f.pack_emission().unwrap());
            }
            assert_eq!(data.len(), names.len());
            let bufs: Vec<wgpu::Buffer> = names
                .iter()
                .zip(&data)
                .map(|(name, d)| {
                    gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some(name),
                        contents: bytemuck::cast_slice(d),
                        usage: wgpu::BufferUsages::STORAGE,
                    })
                })
                .collect();
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            own.denoise(&mut enc, &FrameInputs::from_slice(&bufs).unwrap())
                .unwrap();
            gpu.queue.submit([enc.finish()]);
            let want = host.denoise_host(&f).unwrap();
            assert_eq!(own.read_output().unwrap(), want, "{n} buffers, frame {t}");
            if n == 8 && t == 1 {
                let mut fresh = common::denoiser(&gpu, weights, w, h).unwrap();
                let mut enc = gpu.device.create_command_encoder(&Default::default());
                let six = FrameInputs::from_slice(&bufs[..6]).unwrap();
                let e = fresh.denoise(&mut enc, &six).unwrap_err().to_string();
                assert!(e.contains("FrameInputs::emission"), "{e}");
            }
        }
    }
}

/// The frame loop with a footprint model (what `subpixel run` and the viewer run): on a
/// scene without an environment (no background of its own) it still runs the background
/// pass and feeds the pass's footprint albedo, with the G-buffer's depth, in place of the
/// G-buffer's albedo: its output equals a second denoiser's given the frames it traced
/// (downloaded, background and footprint albedo included) through `denoise_host`.
#[test]
fn the_frame_loop_feeds_a_footprint_model_its_footprint_albedo() {
    use subpixel::frame_loop::FrameLoop;
    use subpixel::render::{CameraPathSpec, FrameSettings, GpuScene, Mode, load_scene};
    let gpu = common::gpu();
    let mut weights = Weights::load(golden_weights_path()).unwrap();
    weights.config.albedo = Some("footprint".into());
    let scene = load_scene("builtin:cornell").unwrap();
    let gs = GpuScene::new(&gpu, &scene).unwrap();
    let (w, h) = (16u32, 12u32);
    let (path, far) = scene
        .camera_path(&CameraPathSpec::Static, 1, 3, 0, &gs.bvh)
        .unwrap();
    let mut frames = FrameLoop::with_options(&gpu, &weights, w, h, common::fixed_kernels()).unwrap();
    let mut host = common::denoiser(&gpu, &weights, w, h).unwrap();
    for f in 0..3 {
        let s = FrameSettings::along(&path, f, Mode::Quarter, 1, far);
        assert_eq!(s.background, 0);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        frames.encode(&mut enc, &gs, &s, None).unwrap();
        gpu.queue.submit([enc.finish()]);
        gpu.wait().unwrap();
        let traced = frames.tracer.buffers.download(&gpu).unwrap();
        let fp = traced
            .background
            .as_ref()
            .and_then(|b| b.albedo.as_ref())
            .expect("footprint albedo");
        assert_ne!(fp, &traced.albedo, "frame {f}: edges mix surfaces");
        assert_eq!(
            frames.denoiser.read_output().unwrap(),
            host.denoise_host(&traced).unwrap(),
            "frame {f}"
        );
    }
}

/// With the mean correction, an emission-"background" model's output is the same weights'
/// output as an emission-"network" model on the colour without the samples' emission (the
/// background as it is), plus the footprint's emission: the correction compares the
/// reconstruction with samples that hold no directly seen emission, so an emitter's tile is
/// not darkened by its own emission.
#[test]
fn the_mean_correction_sees_no_directly_seen_emission() {
    use subpixel::frame::{Background, DirectEmission};
    let gpu = common::gpu();
    let mut network = Weights::load(golden_weights_path()).unwrap();
    network.config.mean_correction = Some("tiles16".into());
    let mut em = network.clone();
    em.config.emission = Some("background".into());
    let (w, h) = (40u32, 24u32);
    let mut a = common::denoiser(&gpu, &em, w, h).unwrap();
    let mut b = common::denoiser(&gpu, &network, w, h).unwrap();
    for t in 0..3 {
        let mut f = random_frame(w, h, 140 + t);
        // a bright emitter over the left third, seen by some samples
        let lamp = |x: u32| x < 14;
        let samples = HostTensor::from_fn(w, h, 3, |x, y, k| {
            if lamp(x) && f.mask.at(x, y, 0) > 0.5 {
                40.0 + k as f32
            } else {
                0.0
            }
        });
        let footprint = HostTensor::from_fn(w, h, 3, |x, _, k| if lamp(x) { 40.0 + k as f32 } else { 0.0 });
        let background = Background {
            radiance: common::random(7_200 + t, w, h, 3, 0.0, 1.0),
            coverage: HostTensor::from_fn(w, h, 1, |x, _, _| if x >= 36 { 1.0 } else { 0.0 }),
            albedo: None,
            emission: None,
        };
        let plain = HostFrame {
            background: Some(background.clone()),
            ..f.clone()
        };
        f.color = HostTensor::from_fn(w, h, 3, |x, y, k| f.color.at(x, y, k) + samples.at(x, y, k));
        f.background = Some(Background {
            emission: Some(DirectEmission {
                footprint: footprint.clone(),
                samples,
                escaped: None,
            }),
            ..background
        });
        let got = a.denoise_host(&f).unwrap();
        let want = b.denoise_host(&plain).unwrap();
        for (i, (g, r)) in got.data.iter().zip(&want.data).enumerate() {
            let e = footprint.data[i];
            assert!(
                (g - (r + e)).abs() <= 1e-4 * (1.0 + r.abs() + e),
                "frame {t} value {i}: {g} against {r} + {e}"
            );
        }
    }
}

/// The frame loop with a model of config emission "background" (what `subpixel run` and the
/// viewer run): on the Cornell box (its light in view, no environment: no background of its
/// own) it runs the background pass and folds the tracer's directly seen emission into the
/// frame the model is fed, on the GPU (`ssr/fold_emission`): its output equals a second
/// denoiser's given the frames it traced (downloaded, directly seen emission included)
/// through `denoise_host`, which folds them on the CPU.
#[test]
fn the_frame_loop_feeds_an_emission_model_the_folded_frame() {
    check_frame_loop_fold("builtin:cornell", "background", "network");
}

/// The same for the shipped combination, config emission and escaped "background", on the
/// white furnace (a sphere against a uniform sky; no emitter): the traced pixels whose
/// sample escaped are left out of the frame the model is fed on the GPU as `denoise_host`
/// leaves them out on the CPU, and some are.
#[test]
fn the_frame_loop_leaves_escaped_samples_to_the_background() {
    check_frame_loop_fold("builtin:furnace", "background", "background");
}

fn check_frame_loop_fold(scene: &str, emission: &str, escaped: &str) {
    use subpixel::frame_loop::FrameLoop;
    use subpixel::render::{CameraPathSpec, FrameSettings, GpuScene, Mode, load_scene};
    let gpu = common::gpu();
    let mut weights = Weights::load(golden_weights_path()).unwrap();
    weights.config.emission = Some(emission.into());
    weights.config.escaped = Some(escaped.into());
    let scene = load_scene(scene).unwrap();
    let gs = GpuScene::new(&gpu, &scene).unwrap();
    let (w, h) = (32u32, 24u32);
    let (path, far) = scene
        .camera_path(&CameraPathSpec::Static, 1, 3, 0, &gs.bvh)
        .unwrap();
    let mut frames = FrameLoop::with_options(&gpu, &weights, w, h, common::fixed_kernels()).unwrap();
    let mut host = common::denoiser(&gpu, &weights, w, h).unwrap();
    let mut sampled = 0;
    for f in 0..4 {
        let s = FrameSettings::along(&path, f, Mode::Quarter, 1, far);
        assert_eq!(s.background, 0);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        frames.encode(&mut enc, &gs, &s, None).unwrap();
        gpu.queue.submit([enc.finish()]);
        gpu.wait().unwrap();
        let traced = frames.tracer.buffers.download(&gpu).unwrap();
        let e = traced
            .background
            .as_ref()
            .and_then(|b| b.emission.as_ref())
            .expect("directly seen emission");
        let lit = |t: &HostTensor| t.data.iter().filter(|&&v| v > 0.0).count();
        if escaped == "background" {
            sampled += lit(e.escaped.as_ref().expect("the samples' escapes"));
        } else {
            assert!(lit(&e.footprint) > 0, "frame {f}: the light is in view");
            sampled += lit(&e.samples);
        }
        assert_eq!(
            frames.denoiser.read_output().unwrap(),
            host.denoise_host(&traced).unwrap(),
            "frame {f}"
        );
    }
    assert!(
        sampled > 0,
        "no traced sample met the light (or the sky) in 4 frames"
    );
}

/// Config escaped "background" on the host (`HostFrame::fold_directly_seen`, what
/// `denoise_host` and `subpixel denoise` feed): exactly the traced pixels at least half of
/// whose samples escaped are left out (colour and mask 0; a non-finite value keeps the
/// pixel, as the GPU fold does), the directly seen emission folded as before; a frame that
/// does not say which samples escaped, or has no background, is refused naming the buffer
/// and the command that adds it, by the fold and by a denoiser of such weights.
#[test]
fn escaped_samples_are_left_out_or_the_frame_refused() {
    use subpixel::frame::{Background, DirectEmission, EmissionSource, EscapedSource};
    let (w, h) = (12u32, 10u32);
    let mut f = random_frame(w, h, 160);
    let escaped = HostTensor::from_fn(w, h, 1, |x, y, _| match (x + 3 * y) % 4 {
        0 => 1.0,
        1 => 0.5,
        2 => 0.25,
        _ => f32::NAN,
    });
    let samples = common::random(9_100, w, h, 3, 0.0, 0.5);
    f.background = Some(Background {
        radiance: common::random(9_101, w, h, 3, 0.0, 1.0),
        coverage: common::random(9_102, w, h, 1, 0.0, 1.0),
        albedo: None,
        emission: Some(DirectEmission {
            footprint: HostTensor::zeros(w, h, 3),
            samples: samples.clone(),
            escaped: Some(escaped.clone()),
        }),
    });
    let fed = f
        .fold_directly_seen(EmissionSource::Background, EscapedSource::Background)
        .unwrap();
    let mut left_out = 0;
    for i in 0..(w * h) as usize {
        let out = escaped.data[i] >= 0.5;
        left_out += (out && f.mask.data[i] > 0.5) as usize;
        let want_mask = if out { 0.0 } else { f.mask.data[i] };
        assert_eq!(fed.mask.data[i], want_mask, "pixel {i}");
        for c in 0..3 {
            let want = if out {
                0.0
            } else {
                (f.color.data[3 * i + c] - samples.data[3 * i + c]).max(0.0)
            };
            assert_eq!(fed.color.data[3 * i + c], want, "pixel {i} channel {c}");
        }
    }
    assert!(left_out > 0, "no traced pixel left out");
    let (a, b) = (fed.background.as_ref().unwrap(), f.background.as_ref().unwrap());
    assert!(
        a.radiance == b.radiance && a.coverage == b.coverage,
        "the background is left as it is"
    );
    // the escapes missing (a frame written before them), then the background
    let mut old = f.clone();
    old.direct_emission_mut().unwrap().escaped = None;
    let e = old
        .fold_directly_seen(EmissionSource::Network, EscapedSource::Background)
        .unwrap_err()
        .to_string();
    assert!(e.contains("'escaped'") && e.contains("--resume"), "{e}");
    let bare = random_frame(w, h, 161);
    let e = bare
        .fold_directly_seen(EmissionSource::Network, EscapedSource::Background)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("config escaped \"background\"") && e.contains("--background N"),
        "{e}"
    );
    let mut weights = Weights::load(golden_weights_path()).unwrap();
    weights.config.escaped = Some("background".into());
    let mut den = common::denoiser(&common::gpu(), &weights, w, h).unwrap();
    let e = den.denoise_host(&old).unwrap_err().to_string();
    assert!(e.contains("'escaped'"), "{e}");
    assert!(den.denoise_host(&f).is_ok());
}
