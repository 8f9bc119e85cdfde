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
    /// The paper's Table 1 layout: a row per method, a column per scene (PSNR / SSIM /
    /// temporal error, mean over the split's sequences), as markdown.
    #[arg(long)]
    table: bool,
    /// Split scored with `--table`.
    #[arg(long, default_value = "test")]
    split: String,
    /// With `--table`: only these columns (comma-separated scene names as in
    /// `sequence.json`, or `procedural` for the procedural scenes), in this order.
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// With `--table`: a column per sequence (its folder name) instead of per scene, e.g.
    /// to find the procedural seeds where a method falls behind; `--scenes` still picks
    /// which scenes' sequences are shown.
    #[arg(long, conflicts_with = "per_frame")]
    per_sequence: bool,
    /// With `--table`: a column per frame index (`frame N`: the mean over the sequences of
    /// that frame), e.g. to tell the first frames, without history, from the later ones;
    /// `--scenes` still picks the scenes whose sequences are averaged.
    #[arg(long)]
    per_frame: bool,
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
    /// Brightness error: the frames' mean of [`metrics::brightness_error`] (the worst
    /// channel's `|ln(mean / reference mean)|`).
    pub brightness: f64,
}

/// Scores the frames of `pred` against those of `reference`: the means of
/// [`score_frames`].
pub fn score(pred: &std::path::Path, reference: &std::path::Path) -> Result<Scores> {
    let frames = score_frames(pred, reference)?;
    let n = frames.len() as f64;
    let (mut psnr, mut ssim, mut rmse, mut relmse, mut brightness) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut temporal, mut nt) = (0.0, 0);
    for f in &frames {
        psnr += f.psnr;
        ssim += f.ssim;
        rmse += f.rmse;
        relmse += f.relmse;
        brightness += f.brightness;
        if let Some(t) = f.temporal {
            temporal += t;
            nt += 1;
        }
    }
    Ok(Scores {
        frames: frames.len(),
        psnr: psnr / n,
        ssim: ssim / n,
        rmse: rmse / n,
        relmse: relmse / n,
        temporal: (nt > 0).then(|| temporal / nt as f64),
        brightness: brightness / n,
    })
}

/// The scores of each frame of `pred` against the same frame of `reference` (each with
/// `frames` 1; the temporal error from the second frame on, against the frame before).
pub fn score_frames(pred: &std::path::Path, reference: &std::path::Path) -> Result<Vec<Scores>> {
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
    let mut out = Vec::with_capacity(pf.len());
    let mut prev: Option<(crate::nn::HostTensor, crate::nn::HostTensor)> = None;
    for (p, r) in pf.iter().zip(&rf) {
        let Some(pi) = read_frame(p)?.pred else {
            bail!("{}: no 'pred.R' channel", p.display())
        };
        let rfile = read_frame(r)?;
        let Some(ri) = rfile.reference else {
            bail!("{}: no 'reference.R' channel", r.display())
        };
        refuse_non_finite(p, "prediction", &pi)?;
        refuse_non_finite(r, "reference", &ri)?;
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
        let temporal = match (&prev, &rfile.frame) {
            (Some((pp, rp)), Some(frame)) => Some(metrics::temporal_error(&pi, pp, &ri, rp, &frame.motion)),
            _ => None,
        };
        out.push(Scores {
            frames: 1,
            psnr: if v.is_finite() { v } else { 100.0 },
            ssim: metrics::ssim(&pi, &ri),
            rmse: metrics::rmse(&pi, &ri),
            relmse: metrics::relmse(&pi, &ri),
            temporal,
            brightness: metrics::brightness_error(&pi, &ri),
        });
        prev = Some((pi, ri));
    }
    Ok(out)
}

/// An image with NaN or Inf pixels has no meaningful score (the metrics would turn them
/// into a plausible number): an error naming the file and how many pixels.
fn refuse_non_finite(path: &std::path::Path, what: &str, t: &crate::nn::HostTensor) -> Result<()> {
    let c = t.channels.max(1) as usize;
    let bad = t
        .data
        .chunks_exact(c)
        .filter(|px| px.iter().any(|v| !v.is_finite()))
        .count();
    if bad > 0 {
        bail!(
            "{}: the {what} has {bad} non-finite (NaN or Inf) pixels of {}; it cannot be scored",
            path.display(),
            t.data.len() / c
        );
    }
    Ok(())
}

/// One method x scene cell of the table: sums over the scene's sequences.
#[derive(Debug, Default, Clone, Copy)]
struct Cell {
    /// Sum of the sequences' PSNR (dB).
    psnr: f64,
    /// Sum of the sequences' SSIM.
    ssim: f64,
    /// Sum of the temporal errors of the sequences that have one.
    temporal: f64,
    /// Sequences with a temporal error (more than one frame, references with motion).
    temporal_n: usize,
    /// Sum of the sequences' brightness errors.
    brightness: f64,
    /// Sequences scored.
    sequences: usize,
}

impl Cell {
    /// Adds one sequence's (or, for the mean column, one scene's) scores.
    fn add(&mut self, m: CellMean) {
        let CellMean {
            psnr,
            ssim,
            temporal,
            brightness,
        } = m;
        self.psnr += psnr;
        self.ssim += ssim;
        self.brightness += brightness;
        if let Some(t) = temporal {
            self.temporal += t;
            self.temporal_n += 1;
        }
        self.sequences += 1;
    }

    /// Means over the scene's sequences (the temporal error over those that have one).
    fn mean(&self) -> CellMean {
        let n = self.sequences.max(1) as f64;
        CellMean {
            psnr: self.psnr / n,
            ssim: self.ssim / n,
            temporal: (self.temporal_n > 0).then(|| self.temporal / self.temporal_n as f64),
            brightness: self.brightness / n,
        }
    }
}

/// The scores of a table cell: one sequence's, or the mean over a scene's.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CellMean {
    psnr: f64,
    ssim: f64,
    temporal: Option<f64>,
    brightness: f64,
}

impl From<&Scores> for CellMean {
    fn from(s: &Scores) -> Self {
        Self {
            psnr: s.psnr,
            ssim: s.ssim,
            temporal: s.temporal,
            brightness: s.brightness,
        }
    }
}

/// `PSNR / SSIM / temporal / brightness` of a table cell (`-` for a missing temporal
/// error; the brightness error as the percentage `exp(b) - 1`).
fn cell_text(m: CellMean) -> String {
    let t = m.temporal.map_or_else(|| "-".into(), |t| format!("{t:.4}"));
    format!(
        "{:.2} / {:.4} / {t} / {:.1}%",
        m.psnr,
        m.ssim,
        100.0 * m.brightness.exp_m1()
    )
}

/// The table column of a scene: procedural scenes (`procedural_SEED`, one scene per seed)
/// share the column `procedural` (the mean over their sequences), other scenes have their own.
fn column_of(scene: &str) -> String {
    let scene = scene.trim_start_matches("builtin:");
    if scene.starts_with("procedural_") || scene.starts_with("procedural:") {
        "procedural".into()
    } else {
        scene.to_string()
    }
}

/// Scores every method folder of `pred` on every sequence of `root/split`: rows (method,
/// column -> cell).
type TableRows = Vec<(String, std::collections::BTreeMap<String, Cell>)>;

/// What a table column holds: a scene's sequences, one sequence, or one frame index of
/// every sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Columns {
    Scene,
    Sequence,
    Frame,
}

/// The column name of frame index `i` with `--per-frame`.
fn frame_column(i: usize) -> String {
    format!("frame {i}")
}

/// The table: its columns (scenes, sequences or frame indices, in display order), its
/// rows, and each column's number of sequences in the split (a cell over fewer, because a
/// method lacks predictions for some, is marked).
struct Table {
    scenes: Vec<String>,
    rows: TableRows,
    expected: std::collections::BTreeMap<String, usize>,
}

impl Table {
    /// `cell` with `(N of M sequences)` appended when the cell covers fewer than the split
    /// has, so that a partial row never passes for a complete one.
    fn covered(&self, scene: &str, c: &Cell, text: String) -> String {
        match self.expected.get(scene) {
            Some(&m) if c.sequences < m => format!("{text} ({} of {m} sequences)", c.sequences),
            _ => text,
        }
    }
}

fn table(
    pred: &std::path::Path,
    root: &std::path::Path,
    split: &str,
    only: &[String],
    by: Columns,
) -> Result<Table> {
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
    // The row order (the paper's plus hold-filled and OIDN; the background buffer's
    // rows by the ones they change), then any other method alphabetically.
    const ORDER: [&str; 12] = [
        "input",
        "hold",
        "accumulation",
        "rae",
        "rae-background",
        "nsrr",
        "nsrr-background",
        "oidn-a",
        "oidn-a-background",
        "oidn-b",
        "ssr-no-background",
        "ssr",
    ];
    let rank = |p: &PathBuf| {
        let n = p
            .file_name()
            .map(|f| f.to_string_lossy().to_string())
            .unwrap_or_default();
        (ORDER.iter().position(|o| *o == n).unwrap_or(ORDER.len()), n)
    };
    methods.sort_by_key(rank);
    // The sequences of the chosen scenes, each with its scene and its columns (its scene's,
    // its own, or one per frame), and how many sequences each column has.
    let mut chosen = Vec::with_capacity(seqs.len());
    let mut expected = std::collections::BTreeMap::new();
    for s in &seqs {
        let file = s.join("sequence.json");
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file)?)
            .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
        let scene = column_of(json["scene"].as_str().unwrap_or("?"));
        if !only.is_empty() && !only.contains(&scene) {
            continue;
        }
        let columns = match by {
            Columns::Scene => vec![scene.clone()],
            Columns::Sequence => vec![s.file_name().expect("a folder").to_string_lossy().to_string()],
            Columns::Frame => (0..list_frames(s)?.len()).map(frame_column).collect(),
        };
        for c in &columns {
            *expected.entry(c.clone()).or_insert(0usize) += 1;
        }
        chosen.push((s, scene, columns));
    }
    // Columns in display order: frames by index; otherwise by the scene's place in `only`
    // (if given), then by name (a scene's sequences in folder order).
    let mut order = std::collections::BTreeSet::new();
    let mut scored = std::collections::BTreeSet::new();
    let mut rows = Vec::new();
    for m in &methods {
        let mut per: std::collections::BTreeMap<String, Cell> = Default::default();
        for (s, scene, columns) in &chosen {
            let p = m.join(split).join(s.file_name().expect("a folder"));
            if !p.is_dir() {
                continue;
            }
            let scores = match by {
                Columns::Frame => score_frames(&p, s)?,
                _ => vec![score(&p, s)?],
            };
            for (i, (c, sc)) in columns.iter().zip(&scores).enumerate() {
                per.entry(c.clone()).or_default().add(sc.into());
                let key = match by {
                    Columns::Frame => (i, String::new()),
                    _ => (only.iter().position(|o| o == scene).unwrap_or(0), c.clone()),
                };
                order.insert((key, c.clone()));
            }
            scored.insert(scene.clone());
        }
        let name = m.file_name().expect("a folder").to_string_lossy().to_string();
        for (column, c) in &per {
            if c.sequences < expected[column] {
                eprintln!(
                    "warning: {name} has predictions for {} of the {} {split} sequences of {column} \
                     (in {}): its cell covers those only",
                    c.sequences,
                    expected[column],
                    m.display()
                );
            }
        }
        rows.push((name, per));
    }
    if let Some(missing) = only.iter().find(|s| !scored.contains(*s)) {
        bail!(
            "--scenes: no predictions for scene '{missing}' in {} (scenes there: {})",
            seq_root.display(),
            scored.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(Table {
        scenes: order.into_iter().map(|(_, c)| c).collect(),
        rows,
        expected,
    })
}

pub(super) fn run(a: &EvalArgs) -> Result<()> {
    if a.table {
        let by = if a.per_sequence {
            Columns::Sequence
        } else if a.per_frame {
            Columns::Frame
        } else {
            Columns::Scene
        };
        let t = table(&a.pred, &a.reference, &a.split, &a.scenes, by)?;
        let (scenes, rows) = (&t.scenes, &t.rows);
        if a.json {
            let v: Vec<_> = rows
                .iter()
                .map(|(m, per)| {
                    let cells: serde_json::Map<String, serde_json::Value> = per
                        .iter()
                        .map(|(s, c)| {
                            let m = c.mean();
                            let v = serde_json::json!({"psnr": m.psnr, "ssim": m.ssim, "temporal": m.temporal, "brightness": m.brightness, "sequences": c.sequences, "of": t.expected.get(s)});
                            (s.clone(), v)
                        })
                        .collect();
                    serde_json::json!({"method": m, "scenes": cells})
                })
                .collect();
            println!("{}", serde_json::to_string_pretty(&v)?);
            return Ok(());
        }
        println!("| method | {} | mean |", scenes.join(" | "));
        println!("|---|{}---|", "---|".repeat(scenes.len()));
        for (m, per) in rows {
            let mut cells = Vec::new();
            // Means over the scenes: every scene for PSNR and SSIM, those with a temporal
            // error for it.
            let mut mean = Cell::default();
            for sc in scenes {
                match per.get(sc) {
                    Some(c) => {
                        cells.push(t.covered(sc, c, cell_text(c.mean())));
                        mean.add(c.mean());
                    }
                    None => cells.push("-".into()),
                }
            }
            let mean = if mean.sequences == scenes.len() {
                cell_text(mean.mean())
            } else if mean.sequences > 0 {
                format!(
                    "{} ({} of {} scenes)",
                    cell_text(mean.mean()),
                    mean.sequences,
                    scenes.len()
                )
            } else {
                "-".into()
            };
            println!("| {m} | {} | {mean} |", cells.join(" | "));
        }
        println!(
            "\nPSNR (dB) / SSIM on tonemapped 8-bit images / temporal error (mean |(p_t - W(p_t-1)) - \
             (r_t - W(r_t-1))| on tonemapped [0, 1] values) / brightness error (the worst RGB channel's \
             image mean against the reference's, exp|ln(P/R)| - 1 in percent, frame mean), {}; a temporal \
             error of - means a single frame or no motion vectors.",
            if a.per_sequence {
                format!("one {} sequence a column", a.split)
            } else if a.per_frame {
                format!(
                    "one frame index a column: the mean of that frame over the {} sequences{}",
                    a.split,
                    if a.scenes.is_empty() {
                        String::new()
                    } else {
                        format!(" of {}", a.scenes.join(", "))
                    }
                )
            } else {
                format!(
                    "mean over the {} sequences of each scene (procedural: of every procedural scene)",
                    a.split
                )
            }
        );
        return Ok(());
    }
    let s = score(&a.pred, &a.reference)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        println!(
            "{:>6} {:>8} {:>7} {:>10} {:>10} {:>10} {:>10}",
            "frames", "PSNR", "SSIM", "RMSE", "relMSE", "temporal", "brightness"
        );
        println!(
            "{:>6} {:>8.2} {:>7.4} {:>10.5} {:>10.5} {:>10} {:>9.1}%",
            s.frames,
            s.psnr,
            s.ssim,
            s.rmse,
            s.relmse,
            s.temporal
                .map(|t| format!("{t:.5}"))
                .unwrap_or_else(|| "-".into()),
            100.0 * s.brightness.exp_m1()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_average_psnr_ssim_and_the_temporal_errors_they_have() {
        let cm = |psnr, ssim, temporal, brightness| CellMean {
            psnr,
            ssim,
            temporal,
            brightness,
        };
        let mut c = Cell::default();
        c.add(cm(30.0, 0.9, Some(0.02), 0.0));
        c.add(cm(32.0, 0.8, None, 0.1));
        c.add(cm(34.0, 0.7, Some(0.04), 2f64.ln() * 3.0 - 0.1));
        let m = c.mean();
        assert!((m.psnr - 32.0).abs() < 1e-12 && (m.ssim - 0.8).abs() < 1e-12);
        assert!(
            (m.temporal.unwrap_or(0.0) - 0.03).abs() < 1e-12,
            "only sequences with one"
        );
        assert!((m.brightness - 2f64.ln()).abs() < 1e-12);
        assert_eq!(cell_text(m), "32.00 / 0.8000 / 0.0300 / 100.0%");
        let mut single = Cell::default();
        single.add(cm(25.0, 0.5, None, 0.0));
        assert_eq!(single.mean().temporal, None);
        assert_eq!(cell_text(single.mean()), "25.00 / 0.5000 / - / 0.0%");
    }

    #[test]
    fn procedural_scenes_share_one_column() {
        assert_eq!(column_of("procedural_1000003"), "procedural");
        assert_eq!(column_of("builtin:procedural:7"), "procedural");
        assert_eq!(column_of("builtin:cornell"), "cornell");
        assert_eq!(column_of("living-room"), "living-room");
    }
}
