//! Issue 12: the soak test. Tracer + denoiser for 2,000 frames (`SUBPIXEL_SOAK_FRAMES`) at
//! 16x16 along an orbit, with the host's resident memory and the GPU allocator's total
//! (where the backend reports one) sampled every 100 frames: after a warm-up of 200 frames
//! neither may grow (on a CPU adapter the GPU's memory is host memory, in the RSS). Ignored
//! by `cargo test` (about 15 s on a 2-core lavapipe machine), run by `.ci/run`:
//! `cargo test --release --test soak -- --ignored --nocapture`.

mod common;

use subpixel::render::{CameraPath, FrameSettings, GpuScene, Mode, Tracer, load_scene};
use subpixel::ssr::Weights;

/// Resident set size of this process in bytes (Linux; 0 elsewhere).
fn rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1).and_then(|v| v.parse::<u64>().ok()))
        .map_or(0, |pages| pages * 4096)
}

#[test]
#[ignore]
fn tracer_and_denoiser_run_2000_frames_in_flat_memory() {
    let frames: u32 = std::env::var("SUBPIXEL_SOAK_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000);
    const WARMUP: u32 = 200;
    const EVERY: u32 = 100;
    assert!(frames > WARMUP + EVERY, "at least {} frames", WARMUP + EVERY + 1);
    let gpu = common::gpu();
    let (w, h) = (16, 16);
    let scene = load_scene("builtin:cornell").unwrap();
    let gs = GpuScene::new(&gpu, &scene).unwrap();
    let path = CameraPath::checked(&"orbit:0.5".parse().unwrap(), &scene.camera, 1, frames, &gs.bvh).unwrap();
    let far = scene.far_distance([&scene.camera.position]);
    let mut weights = Weights::load(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden_weights.safetensors"),
    )
    .unwrap();
    // The shipped model's output pass too: the edge-aware mean correction's history and
    // filter passes, with their buffers alternating from frame to frame.
    weights.config.mean_correction = Some("atrous".into());
    let mut tracer = Tracer::new(&gpu, w, h).unwrap();
    let mut den = common::denoiser(&gpu, &weights, w, h).unwrap();
    let mut samples: Vec<(u32, u64, Option<u64>)> = Vec::new();
    let t0 = std::time::Instant::now();
    for f in 0..frames {
        let settings = FrameSettings::along(&path, f, Mode::Quarter, 1, far);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        tracer.encode_frame(&mut enc, &gs, &settings, None).unwrap();
        let inputs = tracer.buffers.inputs();
        den.denoise(&mut enc, &inputs).unwrap();
        gpu.queue.submit([enc.finish()]);
        gpu.wait().unwrap();
        if (f + 1) % EVERY == 0 {
            let out = den.read_output().unwrap();
            assert!(
                out.data.iter().all(|v| v.is_finite()),
                "frame {f}: non-finite output"
            );
            let gpu_bytes = gpu
                .device
                .generate_allocator_report()
                .map(|r| r.total_allocated_bytes);
            samples.push((f + 1, rss_bytes(), gpu_bytes));
            println!(
                "frame {:>5}: host RSS {:>7.1} MiB, GPU allocated {}, {:.1} ms/frame",
                f + 1,
                rss_bytes() as f64 / (1 << 20) as f64,
                gpu_bytes.map_or("n/a".into(), |b| format!(
                    "{:.1} MiB",
                    b as f64 / (1 << 20) as f64
                )),
                t0.elapsed().as_secs_f64() * 1e3 / (f + 1) as f64
            );
        }
    }
    let after: Vec<_> = samples.iter().filter(|s| s.0 > WARMUP).collect();
    let (base_rss, base_gpu) = (after[0].1, after[0].2);
    for &&(f, rss, g) in &after {
        // A few pages of allocator noise are fine; a leak of even 1 KiB per frame is not
        // (2 MiB over the run).
        assert!(
            rss <= base_rss + (1 << 20),
            "host memory grew from {base_rss} to {rss} bytes by frame {f}"
        );
        if let (Some(b), Some(g)) = (base_gpu, g) {
            assert!(g <= b, "GPU allocations grew from {b} to {g} bytes by frame {f}");
        }
    }
}
