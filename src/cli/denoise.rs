//! `subpixel denoise`: a folder of frame EXRs through SSR.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use crate::gpu::Gpu;
use crate::io::exr::{FrameFile, read_frame, read_header, write_frame};
use crate::io::frames::list_frames;
use crate::io::png::write_png_row;
use crate::ssr::{AlbedoSource, Denoiser, EmissionSource, EscapedSource, Weights};

#[derive(clap::Args)]
pub(super) struct DenoiseArgs {
    /// Weights file (safetensors; default: $SUBPIXEL_WEIGHTS, else the shipped
    /// weights/ssr.safetensors next to the executable, in the working directory or at the
    /// build's path).
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
    /// Ignore the frames' background channels (`background`, `coverage`): reconstruct
    /// every pixel, the wholly sky ones included. By default a frame that has them is
    /// composited with its background (`background + (1 - coverage) x reconstruction`).
    /// A model of config albedo "footprint" still takes the footprint albedo from them,
    /// and one of config emission "background" the directly seen emission.
    #[arg(long)]
    no_background: bool,
}

pub(super) fn run(a: &DenoiseArgs) -> Result<()> {
    let wpath = super::weights_path(a.weights.as_deref())?;
    let weights = Weights::load(&wpath)?;
    if weights.is_random_init() {
        eprintln!(
            "warning: {} holds random test weights: this is not a denoiser",
            wpath.display()
        );
    }
    let frames = list_frames(&a.input)?;
    super::refuse_overlap("--input", &a.input, "--out", &a.out)?;
    let footprint = weights.config.albedo_source()? == AlbedoSource::Footprint;
    let emission = weights.config.emission_source()? == EmissionSource::Background;
    let (w, h) = check_frames(&frames, footprint, emission)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let gpu = Gpu::new()?;
    let mut den = Denoiser::with_gpu(&gpu, &weights, w, h)?;
    let pb = super::progress(frames.len() as u64, "denoise");
    let t0 = std::time::Instant::now();
    // Every output goes to a temporary name first; they are renamed only once every frame
    // has been denoised, so a run that fails part-way leaves the output folder as it was
    // (no mix of new and stale frames).
    let mut staged: Vec<(PathBuf, PathBuf)> = Vec::new();
    let result = denoise_all(a, &frames, &mut den, &mut staged, &pb);
    let with_background = match result {
        Ok(n) => n,
        Err(e) => {
            for (tmp, _) in &staged {
                let _ = std::fs::remove_file(tmp);
            }
            return Err(e);
        }
    };
    for (tmp, dst) in &staged {
        std::fs::rename(tmp, dst)
            .with_context(|| format!("cannot rename {} to {}", tmp.display(), dst.display()))?;
    }
    pb.finish();
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "denoised {} frames into {} ({:.1} ms per frame including I/O, on {}; background in {} of them{})",
        frames.len(),
        a.out.display(),
        1e3 * secs / frames.len() as f64,
        gpu.info.name,
        with_background,
        if a.no_background { ", --no-background" } else { "" }
    );
    let n = den.sanitized_count()?;
    if n > 0 {
        eprintln!(
            "warning: {n} input values were non-finite (replaced by 0) or outside their range (clamped to it)"
        );
    }
    Ok(())
}

/// Checks every frame's header before anything is written: each holds the renderer's
/// buffers (and with `footprint`, a model of config albedo "footprint", the footprint
/// albedo; with `emission`, a model of config emission "background", the directly seen
/// emission), all of one size. Returns that size.
fn check_frames(frames: &[PathBuf], footprint: bool, emission: bool) -> Result<(u32, u32)> {
    let mut size: Option<(u32, u32, &PathBuf)> = None;
    for path in frames {
        let header = read_header(path)?;
        if !header.has_frame(path)? {
            bail!(
                "{}: holds no renderer buffers (color.R, mask.Y, ...)",
                path.display()
            );
        }
        if footprint && !header.channels.iter().any(|c| c == "albedo_footprint.R") {
            bail!(
                "{}: no footprint albedo (albedo_footprint.RGB), which this model uses (config albedo \"footprint\"); \
                 `subpixel dataset --background N` over the same folder adds it",
                path.display()
            );
        }
        let has = |c: &str| header.channels.iter().any(|h| h == c);
        if emission && !(has("emission.R") && has("emission_footprint.R")) {
            bail!(
                "{}: no directly seen emission (emission.RGB, emission_footprint.RGB), which this model takes \
                 from the background (config emission \"background\"); `subpixel dataset --background N` over the \
                 same folder adds it",
                path.display()
            );
        }
        let (w, h) = (header.width, header.height);
        match size {
            None => size = Some((w, h, path)),
            Some((w0, h0, first)) if (w0, h0) != (w, h) => bail!(
                "{}: frame is {w}x{h}, but {} is {w0}x{h0}; every frame of a sequence must have one size",
                path.display(),
                first.display()
            ),
            Some(_) => {}
        }
    }
    let (w, h, _) = size.context("no frames")?;
    Ok((w, h))
}

/// `dst`'s temporary name in its folder (hidden, same file system: renamed atomically;
/// same extension: the PNG writer picks the format by it).
fn staging_name(dst: &std::path::Path) -> PathBuf {
    let stem = dst.file_stem().expect("a file name").to_string_lossy();
    let ext = dst.extension().map(|e| e.to_string_lossy()).unwrap_or_default();
    dst.with_file_name(format!(".{stem}.partial.{ext}"))
}

fn denoise_all(
    a: &DenoiseArgs,
    frames: &[PathBuf],
    den: &mut Denoiser,
    staged: &mut Vec<(PathBuf, PathBuf)>,
    pb: &indicatif::ProgressBar,
) -> Result<usize> {
    let mut with_background = 0;
    // With --no-background a footprint model keeps the background's albedo, and a model of
    // emission or escaped "background" its directly seen emission, composited with no
    // environment (radiance, coverage and the samples' escapes 0: every sample is fed to the
    // network); any other model drops the background.
    let config = &den.network().config;
    let keep_albedo = config.albedo_source()? == AlbedoSource::Footprint
        || config.emission_source()? == EmissionSource::Background
        || config.escaped_source()? == EscapedSource::Background;
    for path in frames {
        let mut file = read_frame(path)?;
        if let (true, Some(f)) = (a.no_background, file.frame.as_mut()) {
            match &mut f.background {
                Some(b) if keep_albedo => {
                    b.radiance.data.fill(0.0);
                    b.coverage.data.fill(0.0);
                    if let Some(e) = b.emission.as_mut().and_then(|e| e.escaped.as_mut()) {
                        e.data.fill(0.0);
                    }
                }
                _ => f.background = None,
            }
        }
        let Some(frame) = &file.frame else {
            bail!(
                "{}: holds no renderer buffers (color.R, mask.Y, ...)",
                path.display()
            );
        };
        let (w, h) = frame.size().with_context(|| path.display().to_string())?;
        if (w, h) != (den.width(), den.height()) {
            bail!(
                "{}: frame is {w}x{h}, its header said {}x{}",
                path.display(),
                den.width(),
                den.height()
            );
        }
        with_background += (frame.background.is_some() && !a.no_background) as usize;
        let pred = den.denoise_host(frame)?;
        let name = path.file_name().expect("a frame file");
        let dst = a.out.join(name);
        let tmp = staging_name(&dst);
        staged.push((tmp.clone(), dst.clone()));
        write_frame(
            &tmp,
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
            let png = dst.with_extension("png");
            let tmp = staging_name(&png);
            staged.push((tmp.clone(), png));
            write_png_row(&tmp, &row)?;
        }
        pb.inc(1);
    }
    Ok(with_background)
}
