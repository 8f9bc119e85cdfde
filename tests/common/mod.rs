//! Helpers shared by the GPU integration tests.
#![allow(dead_code)]

pub mod twin;

use rand::{Rng, SeedableRng, rngs::StdRng};
use subpixel::gpu::Gpu;
use subpixel::nn::HostTensor;
use subpixel::nn::autotune::{EngineOptions, KernelChoice};
use subpixel::ssr::{Denoiser, Weights};

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

/// The one convolution tiling the denoiser tests run unless they test the engine's own
/// choices: autotuning compiles every candidate kernel of every layer shape at every frame
/// size, which on a fresh CPU driver takes tens of minutes, while each tiling's parity with
/// the CPU reference is tested on its own (`tests/kernels.rs`) and the autotuned network's
/// in `tests/ssr_golden.rs`; the tests of the engine's timed choices tune among a few
/// kernels ([`tuned_kernels`]).
pub const FIXED_KERNEL: &str = "px16-cob1";

/// Engine options that tune and time nothing: [`FIXED_KERNEL`] wherever it can run a layer
/// (the generic kernel elsewhere), pooling and the a-trous filter at their defaults.
pub fn fixed_kernels() -> EngineOptions {
    EngineOptions {
        kernels: KernelChoice::Fixed(FIXED_KERNEL.parse().expect("a tiling name")),
        ..Default::default()
    }
}

/// The kernels the tests of the engine's measured choices (the autotuner, `Precision::Auto`,
/// `Pooling::Auto`, `AtrousPixels::Auto`) tune among (`KernelChoice::Among`, the generic
/// kernel always with them): the same choices made by timing, at a few compiles per layer.
pub const TUNED_AMONG: &str = "px4-cob1,px16-cob1";

/// Engine options that tune among [`TUNED_AMONG`].
pub fn tuned_kernels() -> EngineOptions {
    EngineOptions {
        kernels: KernelChoice::Among(TUNED_AMONG.parse().expect("kernel names")),
        ..Default::default()
    }
}

/// A denoiser for `w x h` frames on [`fixed_kernels`].
pub fn denoiser(gpu: &Gpu, weights: &Weights, w: u32, h: u32) -> subpixel::Result<Denoiser> {
    Denoiser::with_options(gpu, weights, w, h, fixed_kernels())
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

/// A closed room lit only through an open window by a non-uniform environment (a sky
/// gradient with a bright patch): the case environment portals are for. `portals` gives the
/// environment the window as its one portal.
pub mod window_room {
    use glam::{Mat3, Vec3};
    use subpixel::render::Camera;
    use subpixel::render::scene::{Environment, Geometry, Material, Portal, Scene};

    /// The window in the back wall (`z = -1`): `x` in [-0.4, 0.4], `y` in [0.6, 1.4].
    pub const WINDOW: Portal = Portal {
        corner: Vec3::new(-0.4, 0.6, -1.0),
        u: Vec3::new(0.8, 0.0, 0.0),
        v: Vec3::new(0.0, 0.8, 0.0),
    };

    /// A pane in the window, just inside: smooth thin glass, part diffuse (transmission
    /// 0.6) and tinted, so that light both passes it straight through and scatters on it.
    pub fn pane() -> Material {
        Material {
            transmission: 0.6,
            ..Material::glass("pane", [0.9, 0.8, 0.7], 0.0, 1.5, true)
        }
    }

    /// The room, with or without the window as a portal, and with a [`pane`] in it or not.
    pub fn scene(portals: bool, paned: bool) -> Scene {
        let v = Vec3::new;
        let mut g = Geometry::default();
        let quad = |g: &mut Geometry, o: Vec3, a: Vec3, b: Vec3| g.push_quad([o, o + a, o + a + b, o + b], 0);
        quad(&mut g, v(-1.0, 0.0, -1.0), v(2.0, 0.0, 0.0), v(0.0, 0.0, 2.0)); // floor
        quad(&mut g, v(-1.0, 2.0, -1.0), v(2.0, 0.0, 0.0), v(0.0, 0.0, 2.0)); // ceiling
        quad(&mut g, v(-1.0, 0.0, -1.0), v(0.0, 2.0, 0.0), v(0.0, 0.0, 2.0)); // left
        quad(&mut g, v(1.0, 0.0, -1.0), v(0.0, 2.0, 0.0), v(0.0, 0.0, 2.0)); // right
        quad(&mut g, v(-1.0, 0.0, 1.0), v(2.0, 0.0, 0.0), v(0.0, 2.0, 0.0)); // front
        // The back wall around the window.
        quad(&mut g, v(-1.0, 0.0, -1.0), v(2.0, 0.0, 0.0), v(0.0, 0.6, 0.0));
        quad(&mut g, v(-1.0, 1.4, -1.0), v(2.0, 0.0, 0.0), v(0.0, 0.6, 0.0));
        quad(&mut g, v(-1.0, 0.6, -1.0), v(0.6, 0.0, 0.0), v(0.0, 0.8, 0.0));
        quad(&mut g, v(0.4, 0.6, -1.0), v(0.6, 0.0, 0.0), v(0.0, 0.8, 0.0));
        if paned {
            quad(&mut g, v(-0.4, 0.6, -0.98), v(0.8, 0.0, 0.0), v(0.0, 0.8, 0.0));
            let n = g.triangles.len();
            g.materials[n - 2..].fill(1);
        }
        let (w, h) = (16u32, 8u32);
        let pixels = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if (x, y) == (7, 3) {
                    [40.0, 36.0, 30.0]
                } else {
                    let t = y as f32 / h as f32;
                    [0.4 + 1.2 * t, 0.6 + 0.8 * t, 1.2 - 0.4 * t]
                }
            })
            .collect();
        let environment = Environment {
            source: "window room sky".into(),
            width: w,
            height: h,
            pixels,
            scale: 1.0,
            to_world: Mat3::IDENTITY,
            portals: if portals { vec![WINDOW] } else { vec![] },
        };
        Scene {
            name: format!("window room (portals: {portals}, pane: {paned})"),
            geometry: g,
            materials: vec![
                Material {
                    double_sided: true,
                    ..Material::diffuse("walls", [0.7, 0.6, 0.5])
                },
                pane(),
            ],
            textures: vec![],
            environment: Some(environment),
            camera: Camera {
                position: v(0.3, 1.2, 0.9),
                target: v(-0.1, 0.5, -1.0),
                up: Vec3::Y,
                yfov: 1.2,
            },
            film: (24, 24),
            camera_path: None,
            approximations: vec![],
        }
    }
}
