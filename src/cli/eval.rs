//! `subpixel eval`: quality of predictions against references.

use std::path::PathBuf;

use anyhow::{Result, bail};

use crate::io::exr::read_frame;
use crate::io::frames::list_frames;
use crate::metrics;

#[derive(clap::Args)]
pub(super) struct EvalArgs {
    /// Folder of predictions: frame_NNNN.exr with `pred.R pred.G pred.B`.
    #[arg(long)]
    pred: PathBuf,
    /// Folder of references: frame_NNNN.exr with `reference.R..` (and `motion.X motion.Y`
    /// for the temporal error), e.g. a dataset sequence.
    #[arg(long = "ref")]
    reference: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

/// Mean scores over a sequence.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Scores {
    /// Frames scored.
    pub frames: usize,
    /// PSNR (dB) on tonemapped 8-bit images.
    pub psnr: f64,
    /// SSIM on tonemapped 8-bit images.
    pub ssim: f64,
    /// RMSE on HDR.
    pub rmse: f64,
    /// Relative MSE on HDR.
    pub relmse: f64,
    /// Temporal error (None without motion or with one frame).
    pub temporal: Option<f64>,
}

/// Scores the frames of `pred` against those of `reference`.
pub fn score(pred: &std::path::Path, reference: &std::path::Path) -> Result<Scores> {
    let pf = list_frames(pred)?;
    let rf = list_frames(reference)?;
    if pf.len() != rf.len() {
        bail!(
            "{} has {} frames but {} has {}",
            pred.display(),
            pf.len(),
            reference.display(),
            rf.len()
        );
    }
    let (mut psnr, mut ssim, mut rmse, mut relmse) = (0.0, 0.0, 0.0, 0.0);
    let (mut temporal, mut nt) = (0.0, 0);
    let mut prev: Option<(crate::nn::HostTensor, crate::nn::HostTensor)> = None;
    for (p, r) in pf.iter().zip(&rf) {
        let Some(pi) = read_frame(p)?.pred else {
            bail!("{}: no 'pred.R' channel", p.display())
        };
        let rfile = read_frame(r)?;
        let Some(ri) = rfile.reference else {
            bail!("{}: no 'reference.R' channel", r.display())
        };
        if (pi.width, pi.height) != (ri.width, ri.height) {
            bail!(
                "{} is {}x{} but {} is {}x{}",
                p.display(),
                pi.width,
                pi.height,
                r.display(),
                ri.width,
                ri.height
            );
        }
        let v = metrics::psnr(&pi, &ri);
        psnr += if v.is_finite() { v } else { 100.0 };
        ssim += metrics::ssim(&pi, &ri);
        rmse += metrics::rmse(&pi, &ri);
        relmse += metrics::relmse(&pi, &ri);
        if let (Some((pp, rp)), Some(frame)) = (&prev, &rfile.frame) {
            temporal += metrics::temporal_error(&pi, pp, &ri, rp, &frame.motion);
            nt += 1;
        }
        prev = Some((pi, ri));
    }
    let n = pf.len() as f64;
    Ok(Scores {
        frames: pf.len(),
        psnr: psnr / n,
        ssim: ssim / n,
        rmse: rmse / n,
        relmse: relmse / n,
        temporal: (nt > 0).then(|| temporal / nt as f64),
    })
}

pub(super) fn run(a: &EvalArgs) -> Result<()> {
    let s = score(&a.pred, &a.reference)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        println!(
            "{:>6} {:>8} {:>7} {:>10} {:>10} {:>10}",
            "frames", "PSNR", "SSIM", "RMSE", "relMSE", "temporal"
        );
        println!(
            "{:>6} {:>8.2} {:>7.4} {:>10.5} {:>10.5} {:>10}",
            s.frames,
            s.psnr,
            s.ssim,
            s.rmse,
            s.relmse,
            s.temporal
                .map(|t| format!("{t:.5}"))
                .unwrap_or_else(|| "-".into())
        );
    }
    Ok(())
}
