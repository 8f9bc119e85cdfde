//! Helpers shared by the GPU integration tests.
#![allow(dead_code)]

pub mod twin;

use rand::{Rng, SeedableRng, rngs::StdRng};
use subpixel::gpu::Gpu;
use subpixel::nn::HostTensor;

/// The tolerances of every parity test, in one place. A GPU value `g` matches the CPU
/// reference `c` when `|g - c| <= abs + rel * |c|`.
#[derive(Debug, Clone, Copy)]
pub struct Tol {
    /// Absolute tolerance.
    pub abs: f32,
    /// Relative tolerance.
    pub rel: f32,
}

/// Data movement only (pooling max, nearest upsampling, copies): exact.
pub const EXACT: Tol = Tol { abs: 0.0, rel: 0.0 };
/// A few f32 operations (averages, lerps, blends, exp/log).
pub const ELEMENTWISE: Tol = Tol { abs: 1e-5, rel: 1e-5 };
/// Long f32 sums (convolutions: 9 * Cin terms of magnitude ~1), against an f64 reference.
pub const REDUCTION: Tol = Tol { abs: 1e-4, rel: 1e-4 };

/// Sizes every kernel is tested at (odd ones included).
pub const SIZES: &[(u32, u32)] = &[(1, 1), (7, 5), (33, 17), (64, 48)];
/// Channel counts every kernel is tested at.
pub const CHANNELS: &[u32] = &[3, 4, 13, 32];

/// One GPU context per test process.
pub fn gpu() -> Gpu {
    static GPU: std::sync::OnceLock<Gpu> = std::sync::OnceLock::new();
    GPU.get_or_init(|| Gpu::new().expect("a GPU adapter (the CPU Vulkan driver is enough)"))
        .clone()
}

/// Uniform random tensor in `[lo, hi)`.
pub fn random(seed: u64, w: u32, h: u32, c: u32, lo: f32, hi: f32) -> HostTensor {
    let mut rng = StdRng::seed_from_u64(seed);
    let data = (0..w * h * c).map(|_| rng.random_range(lo..hi)).collect();
    HostTensor::from_vec(w, h, c, data)
}

/// Random values in `[lo, hi)`.
pub fn random_vec(seed: u64, n: usize, lo: f32, hi: f32) -> Vec<f32> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

/// Asserts `gpu` matches `cpu` within `tol`, naming the case and the first mismatch.
pub fn assert_close(case: &str, gpu: &HostTensor, cpu: &HostTensor, tol: Tol) {
    assert_eq!(
        (gpu.width, gpu.height, gpu.channels),
        (cpu.width, cpu.height, cpu.channels),
        "{case}: shape"
    );
    let mut worst = (0.0f32, 0usize);
    for (i, (g, c)) in gpu.data.iter().zip(&cpu.data).enumerate() {
        let err = (g - c).abs();
        let bound = tol.abs + tol.rel * c.abs();
        if err.is_nan() || err > bound {
            let px = i / gpu.channels as usize;
            panic!(
                "{case}: mismatch at x={} y={} c={}: gpu {g} cpu {c} (|diff| {err} > {bound})",
                px as u32 % gpu.width,
                px as u32 / gpu.width,
                i % gpu.channels as usize
            );
        }
        if err > worst.0 {
            worst = (err, i);
        }
    }
}

/// Materials of the white-furnace tests, shared by the GPU and CPU-twin tests: smooth
/// materials that must converge to 1, and rough ones that must not gain energy.
pub mod furnace {
    use subpixel::frame::HostFrame;
    use subpixel::render::builtin;
    use subpixel::render::scene::{Material, Scene};

    /// `builtin:furnace` with its sphere made of `m`.
    pub fn scene(m: Material) -> Scene {
        let mut scene = builtin::furnace();
        scene.materials[0] = m;
        scene
    }

    /// The mean of colour channel `c` over the sphere's pixels (depth < 1) of a furnace
    /// frame, and their count.
    pub fn sphere_mean(f: &HostFrame, c: usize) -> (f64, usize) {
        let px: Vec<usize> = (0..f.depth.data.len())
            .filter(|&i| f.depth.data[i] < 1.0)
            .collect();
        let m = px.iter().map(|&i| f.color.data[3 * i + c] as f64).sum::<f64>() / px.len().max(1) as f64;
        (m, px.len())
    }

    /// A white metal of `roughness`.
    fn metal(roughness: f32) -> Material {
        Material {
            base_color: [1.0; 4],
            metallic: 1.0,
            roughness,
            ..Default::default()
        }
    }

    /// A solid (or `thin`-walled) clear glass of `roughness`.
    fn glass(roughness: f32, thin: bool) -> Material {
        Material {
            metallic: 0.0,
            roughness,
            transmission: 1.0,
            thin,
            ..Default::default()
        }
    }

    /// A smooth mirror, solid glass and thin glass (they converge to 1).
    pub fn smooth() -> Vec<(&'static str, Material)> {
        let thin = Material {
            double_sided: true,
            ..glass(0.0, true)
        };
        vec![
            ("mirror", metal(0.0)),
            ("solid glass", glass(0.0, false)),
            ("thin glass", thin),
        ]
    }

    /// Rough metal, rough glass and rough plastic (single-scattering GGX loses some).
    pub fn rough() -> Vec<(&'static str, Material)> {
        let plastic = Material {
            metallic: 0.0,
            roughness: 0.4,
            ..Material::diffuse("p", [1.0; 3])
        };
        vec![
            ("rough metal", metal(0.6)),
            ("rough glass", glass(0.5, false)),
            ("rough plastic", plastic),
        ]
    }
}
