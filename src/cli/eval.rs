//! `subpixel eval`: quality of predictions against references.

use std::path::PathBuf;

use anyhow::{Result, bail};

use crate::io::exr::read_frame;
use crate::io::frames::list_frames;
use crate::metrics;

#[derive(clap::Args)]
pub(super) struct EvalArgs {
    /// Folder of predictions: frame_NNNN.exr with `pred.R pred.G pred.B`. With `--table`, a
    /// root holding one folder per method: PRED/METHOD/SPLIT/SEQUENCE/frame_NNNN.exr.
    #[arg(long)]
    pred: PathBuf,
    /// Folder of references: frame_NNNN.exr with `reference.R..` (and `motion.X motion.Y`
    /// for the temporal error), e.g. a dataset sequence. With `--table`, the dataset root.
    #[arg(long = "ref")]
    reference: PathBuf,
    /// The paper's Table 1 layout: a row per method, a column per scene (PSNR / SSIM,
    /// mean over the split's sequences), as markdown.
    #[arg(long)]
    table: bool,
    /// Split scored with `--table`.
    #[arg(long, default_value = "test")]
    split: String,
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

/// Scores every method folder of `pred` on every sequence of `root/split`: rows (method,
/// scene -> (PSNR, SSIM, sequences)).
type TableRows = Vec<(String, std::collections::BTreeMap<String, (f64, f64, usize)>)>;

fn table(pred: &std::path::Path, root: &std::path::Path, split: &str) -> Result<(Vec<String>, TableRows)> {
    let seq_root = root.join(split);
    let mut seqs: Vec<PathBuf> = std::fs::read_dir(&seq_root)
        .map_err(|e| anyhow::anyhow!("{}: {e}", seq_root.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("sequence.json").is_file())
        .collect();
    seqs.sort();
    if seqs.is_empty() {
        bail!(
            "{}: no sequences (folders with sequence.json)",
            seq_root.display()
        );
    }
    let mut methods: Vec<PathBuf> = std::fs::read_dir(pred)
        .map_err(|e| anyhow::anyhow!("{}: {e}", pred.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join(split).is_dir())
        .collect();
    // The paper's row order, then any other method alphabetically.
    const ORDER: [&str; 5] = ["input", "accumulation", "rae", "nsrr", "ssr"];
    let rank = |p: &PathBuf| {
        let n = p
            .file_name()
            .map(|f| f.to_string_lossy().to_string())
            .unwrap_or_default();
        (ORDER.iter().position(|o| *o == n).unwrap_or(ORDER.len()), n)
    };
    methods.sort_by_key(rank);
    let mut scenes = std::collections::BTreeSet::new();
    let mut rows = Vec::new();
    for m in &methods {
        let mut per: std::collections::BTreeMap<String, (f64, f64, usize)> = Default::default();
        for s in &seqs {
            let p = m.join(split).join(s.file_name().expect("a folder"));
            if !p.is_dir() {
                continue;
            }
            let json: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(s.join("sequence.json"))?)?;
            let scene = json["scene"]
                .as_str()
                .unwrap_or("?")
                .trim_start_matches("builtin:")
                .to_string();
            let sc = score(&p, s)?;
            let e = per.entry(scene.clone()).or_default();
            e.0 += sc.psnr;
            e.1 += sc.ssim;
            e.2 += 1;
            scenes.insert(scene);
        }
        let name = m.file_name().expect("a folder").to_string_lossy().to_string();
        rows.push((name, per));
    }
    Ok((scenes.into_iter().collect(), rows))
}

pub(super) fn run(a: &EvalArgs) -> Result<()> {
    if a.table {
        let (scenes, rows) = table(&a.pred, &a.reference, &a.split)?;
        if a.json {
            let v: Vec<_> = rows
                .iter()
                .map(|(m, per)| {
                    let cells: serde_json::Map<String, serde_json::Value> = per
                        .iter()
                        .map(|(s, (p, q, n))| (s.clone(), serde_json::json!({"psnr": p / *n as f64, "ssim": q / *n as f64, "sequences": n})))
                        .collect();
                    serde_json::json!({"method": m, "scenes": cells})
                })
                .collect();
            println!("{}", serde_json::to_string_pretty(&v)?);
            return Ok(());
        }
        println!("| method | {} | mean |", scenes.join(" | "));
        println!("|---|{}---|", "---|".repeat(scenes.len()));
        for (m, per) in &rows {
            let mut cells = Vec::new();
            let (mut sp, mut ss, mut k) = (0.0, 0.0, 0);
            for sc in &scenes {
                match per.get(sc) {
                    Some((p, q, n)) => {
                        let (p, q) = (p / *n as f64, q / *n as f64);
                        cells.push(format!("{p:.2} / {q:.4}"));
                        sp += p;
                        ss += q;
                        k += 1;
                    }
                    None => cells.push("-".into()),
                }
            }
            let mean = if k > 0 {
                format!("{:.2} / {:.4}", sp / k as f64, ss / k as f64)
            } else {
                "-".into()
            };
            println!("| {m} | {} | {mean} |", cells.join(" | "));
        }
        println!(
            "\nPSNR (dB) / SSIM on tonemapped 8-bit images, mean over the {} sequences of each scene.",
            a.split
        );
        return Ok(());
    }
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
