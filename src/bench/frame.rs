//! `subpixel bench` (and `bench frame`): the whole frame, path tracer + SSR, per stage.

use crate::error::Result;
use crate::frame_loop::FrameLoop;
use crate::gpu::{Gpu, Profiler, Stats};
use crate::render::{FrameSettings, GpuScene, Mode, Scene};
use crate::ssr::Weights;

pub use crate::frame_loop::STAGES;

/// One (size, mode) measurement.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameBench {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Sampling mode of the tracer.
    pub mode: Mode,
    /// Timed frames.
    pub frames: u32,
    /// Per-stage statistics (GPU timestamps, or CPU wall time for the whole frame).
    pub stages: Vec<(String, Stats)>,
    /// Median of the per-frame sum of the stages (ms).
    pub total_ms: f64,
    /// CPU wall time per frame, submit to completion.
    pub wall: Stats,
    /// SSR FLOPs per frame.
    pub ssr_flops: u64,
    /// Achieved SSR GFLOP/s (TFA + U-Net time).
    pub ssr_gflop_per_s: f64,
}

/// Times `frames` frames (after `warmup` untimed ones) of `scene` at `w x h` in `mode`: G-buffer and
/// trace of the path tracer, then SSR, all in one command buffer per frame.
pub fn bench_frame(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    weights: &Weights,
    (w, h): (u32, u32),
    mode: Mode,
    (warmup, frames): (u32, u32),
) -> Result<FrameBench> {
    let mut fl = FrameLoop::new(gpu, weights, w, h)?;
    fl.tracer.compile()?;
    let n = warmup + frames;
    let (path, far) = scene.camera_path(&"orbit".parse().expect("known path"), 1, n, 0, &gs.bvh)?;
    let mut prof = Profiler::new(gpu, 16);
    let mut walls = Vec::new();
    for f in 0..n {
        let s = FrameSettings {
            background: scene.default_background(),
            ..FrameSettings::along(&path, f, mode, 1, far)
        };
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        fl.encode(&mut enc, gs, &s, Some(&mut prof))?;
        let wall = prof.submit(gpu, enc, None)?;
        if f + 1 == warmup {
            prof.clear();
        } else if f >= warmup {
            walls.push(wall);
        }
    }
    let stages: Vec<(String, Stats)> = STAGES
        .iter()
        .filter_map(|s| prof.stat(s).map(|st| (s.to_string(), st)))
        .collect();
    let total_ms = if prof.gpu_timed() {
        stages.iter().map(|(_, s)| s.median_ms).sum()
    } else {
        Stats::from_samples(&walls).map(|s| s.median_ms).unwrap_or(0.0)
    };
    let ssr_flops: u64 = fl.denoiser.network().step_costs().iter().map(|c| c.flops).sum();
    let ssr_ms: f64 = stages
        .iter()
        .filter(|(n, _)| n == "tfa" || n == "unet")
        .map(|(_, s)| s.median_ms)
        .sum();
    Ok(FrameBench {
        width: w,
        height: h,
        mode,
        frames,
        stages,
        total_ms,
        wall: Stats::from_samples(&walls).expect("timed frames ran"),
        ssr_flops,
        ssr_gflop_per_s: if ssr_ms > 0.0 {
            ssr_flops as f64 / (ssr_ms * 1e-3) * 1e-9
        } else {
            0.0
        },
    })
}

/// Formats the results as one table.
pub fn table(adapter: &str, rows: &[FrameBench]) -> String {
    let mut s = format!("adapter: {adapter}\n");
    s += &format!("{:<11} {:<8}", "size", "mode");
    for st in STAGES {
        s += &format!(" {st:>9}");
    }
    s += &format!(" {:>9} {:>9} {:>10}\n", "total", "p95 wall", "SSR GF/s");
    for r in rows {
        s += &format!(
            "{:<11} {:<8}",
            format!("{}x{}", r.width, r.height),
            format!("{:?}", r.mode).to_lowercase()
        );
        for st in STAGES {
            let v = r
                .stages
                .iter()
                .find(|(n, _)| n == st)
                .map(|(_, x)| format!("{:.3}", x.median_ms));
            s += &format!(" {:>9}", v.unwrap_or_else(|| "-".into()));
        }
        s += &format!(
            " {:>9.3} {:>9.3} {:>10.1}\n",
            r.total_ms, r.wall.p95_ms, r.ssr_gflop_per_s
        );
    }
    s += "GPU ms, median per stage (p95 wall: CPU submit-to-done, ms). Quarter vs full shows the\n\
          saving of 1/4-spp sampling; SSR runs the same in both.\n";
    s
}
