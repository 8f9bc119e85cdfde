//! `subpixel denoise`: a folder of frame EXRs through SSR.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use crate::gpu::Gpu;
use crate::io::exr::{FrameFile, read_frame, write_frame};
use crate::io::frames::list_frames;
use crate::io::png::write_png_row;
use crate::ssr::{Denoiser, Weights};

#[derive(clap::Args)]
pub(super) struct DenoiseArgs {
    /// Weights file (safetensors).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Folder of frame_NNNN.exr files holding the renderer's buffers (DESIGN §3).
    #[arg(long)]
    input: PathBuf,
    /// Output folder: frame_NNNN.exr with `pred.R pred.G pred.B`.
    #[arg(long)]
    out: PathBuf,
    /// Also write PNG previews: input | SSR (| reference when the frames hold one).
    #[arg(long)]
    png: bool,
}

pub(super) fn run(a: &DenoiseArgs) -> Result<()> {
    let wpath = a.weights.clone().unwrap_or_else(super::shipped_weights_path);
    let weights = Weights::load(&wpath)?;
    if weights.is_random_init() {
        eprintln!(
            "warning: {} holds random test weights: this is not a denoiser",
            wpath.display()
        );
    }
    let frames = list_frames(&a.input)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let gpu = Gpu::new()?;
    let mut den: Option<Denoiser> = None;
    let pb = super::progress(frames.len() as u64, "denoise");
    let t0 = std::time::Instant::now();
    for path in &frames {
        let file = read_frame(path)?;
        let Some(frame) = &file.frame else {
            bail!(
                "{}: holds no renderer buffers (color.R, mask.Y, ...)",
                path.display()
            );
        };
        let (w, h) = frame.size().with_context(|| path.display().to_string())?;
        let d = match &mut den {
            Some(d) if (d.width(), d.height()) == (w, h) => d,
            _ => den.insert(Denoiser::with_gpu(&gpu, &weights, w, h)?),
        };
        let pred = d.denoise_host(frame)?;
        let name = path.file_name().expect("a frame file");
        write_frame(
            &a.out.join(name),
            &FrameFile {
                pred: Some(pred.clone()),
                ..Default::default()
            },
        )?;
        if a.png {
            let mut row = vec![&frame.color, &pred];
            if let Some(r) = &file.reference {
                row.push(r);
            }
            write_png_row(&a.out.join(name).with_extension("png"), &row)?;
        }
        pb.inc(1);
    }
    pb.finish();
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "denoised {} frames into {} ({:.1} ms per frame including I/O, on {})",
        frames.len(),
        a.out.display(),
        1e3 * secs / frames.len() as f64,
        gpu.info.name
    );
    if let Some(d) = &den {
        let n = d.sanitized_count()?;
        if n > 0 {
            eprintln!(
                "warning: {n} input values were non-finite (replaced by 0) or outside their range (clamped to it)"
            );
        }
    }
    Ok(())
}
