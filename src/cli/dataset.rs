//! `subpixel dataset`: training / validation / test sequences for SSR (DESIGN §6).
//!
//! Layout: `OUT/{split}/{scene}_{split}_{NNN}/frame_NNNN.exr` (1/4-spp inputs, every buffer
//! of DESIGN §3, the `reference` channels, `reference_half` (the mean of the reference's first
//! half of samples, whose PSNR against the second half is recorded as `reference_noise` in
//! `sequence.json`) and `full` (a 1-spp frame of the same camera)) plus `sequence.json`. Each sequence follows
//! its own fly-through camera path, generated from a seed that depends on the scene, the
//! split and the sequence number, so the splits never share a camera path.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use super::render::{RenderArgs, render_command};
use crate::render::{Backend, DEFAULT_MAX_DEPTH, Mode};

#[derive(clap::Args)]
pub(super) struct DatasetArgs {
    /// Scene: builtin:NAME, a scene.json, a scene folder or a .gltf/.glb.
    #[arg(long)]
    scene: String,
    /// Split: train, val or test.
    #[arg(long, value_parser = ["train", "val", "test"])]
    split: String,
    /// Number of sequences.
    #[arg(long, default_value_t = 4)]
    sequences: u32,
    /// Render only sequences FIRST..SEQUENCES (to share sequences between machines).
    #[arg(long, default_value_t = 0)]
    first_sequence: u32,
    /// Frames per sequence.
    #[arg(long, default_value_t = 16)]
    frames: u32,
    /// Image width.
    #[arg(long, default_value_t = 256)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 256)]
    height: u32,
    /// Samples per pixel of the reference.
    #[arg(long, default_value_t = 1024)]
    reference_spp: u32,
    /// Double each reference's samples until the PSNR between its halves reaches DB, up to
    /// `--reference-spp-max` (as for `render`).
    #[arg(long, value_name = "DB")]
    reference_noise_target: Option<f64>,
    /// Most samples a reference may take under `--reference-noise-target` (default: 16
    /// times `--reference-spp`).
    #[arg(long, value_name = "SPP", requires = "reference_noise_target")]
    reference_spp_max: Option<u32>,
    /// Also store each frame's directly seen environment (`background`, `coverage`) and
    /// footprint albedo (`albedo_footprint`) from N x N camera rays per pixel; frames
    /// already rendered without them get them added.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    background: Option<u32>,
    /// Largest number of path segments.
    #[arg(long, default_value_t = DEFAULT_MAX_DEPTH)]
    max_depth: u32,
    /// Only render frames A..B (end exclusive) of every sequence, to share a dataset
    /// between machines.
    #[arg(long)]
    frame_range: Option<String>,
    /// Renderer: auto (the WGSL tracer on a real GPU, its CPU twin when the adapter is a
    /// CPU driver or there is none), cpu or gpu.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    backend: Backend,
    /// How the scene is built (`--props`: name only scenes allowed in training).
    #[command(flatten)]
    scene_options: crate::render::SceneOptions,
    /// Output root.
    #[arg(long)]
    out: PathBuf,
}

/// A short name for folder names: `builtin:cornell` -> `cornell`, `.../living-room/scene.json`
/// -> `living-room`.
pub fn scene_slug(scene: &str) -> String {
    let p = std::path::Path::new(scene);
    let stem = if let Some(b) = scene.strip_prefix("builtin:") {
        // `builtin:procedural:7` -> `procedural_7` (no ':' in folder names).
        Some(b.to_string())
    } else if p.file_name().is_some_and(|f| f == "scene.json") || p.is_dir() {
        p.components()
            .rev()
            .find(|c| c.as_os_str() != "scene.json")
            .map(|c| c.as_os_str().to_string_lossy().to_string())
    } else {
        p.file_stem().map(|s| s.to_string_lossy().to_string())
    };
    stem.unwrap_or_else(|| "scene".into())
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Seed of sequence `index` of `split` of `scene`: distinct across scenes, splits and
/// sequences (FNV-1a over the three).
pub fn sequence_seed(scene: &str, split: &str, index: u32) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in scene
        .bytes()
        .chain([0])
        .chain(split.bytes())
        .chain([0])
        .chain(index.to_le_bytes())
    {
        h ^= b as u64;
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}

fn parse_range(s: &str, frames: u32) -> Result<(u32, u32)> {
    let (a, b) = s
        .split_once("..")
        .with_context(|| format!("--frame-range '{s}': expected A..B"))?;
    let a: u32 = a
        .trim()
        .parse()
        .with_context(|| format!("--frame-range '{s}': bad start"))?;
    let b: u32 = b
        .trim()
        .parse()
        .with_context(|| format!("--frame-range '{s}': bad end"))?;
    if a >= b || b > frames {
        bail!("--frame-range {a}..{b} must be a non-empty range within 0..{frames}");
    }
    Ok((a, b))
}

pub(super) fn run(a: &DatasetArgs) -> Result<()> {
    if a.sequences == 0 || a.frames == 0 {
        bail!("--sequences and --frames must be at least 1");
    }
    let (first, end) = match &a.frame_range {
        Some(r) => parse_range(r, a.frames)?,
        None => (0, a.frames),
    };
    if a.first_sequence >= a.sequences {
        bail!(
            "--first-sequence {} must be below --sequences {}",
            a.first_sequence,
            a.sequences
        );
    }
    let slug = scene_slug(&a.scene);
    for s in a.first_sequence..a.sequences {
        let name = format!("{slug}_{}_{s:03}", a.split);
        let dir = a.out.join(&a.split).join(&name);
        let seed = sequence_seed(&slug, &a.split, s);
        println!(
            "sequence {}/{}: {} (frames {first}..{end}, seed {seed})",
            s + 1,
            a.sequences,
            dir.display()
        );
        let args = RenderArgs {
            scene: a.scene.clone(),
            mode: Mode::Quarter,
            spp: 1,
            frames: end - first,
            first_frame: first,
            width: Some(a.width),
            height: Some(a.height),
            max_depth: a.max_depth,
            seed,
            // The scene's own camera path when it has one (procedural scenes: static, orbits,
            // slow and fast fly-throughs, cuts), else a fly-through generated from the seed.
            path: None,
            fallback_path: Some("flythrough".parse().expect("known path")),
            reference_spp: Some(a.reference_spp),
            reference_noise_target: a.reference_noise_target,
            reference_spp_max: a.reference_spp_max,
            png: false,
            resume: true,
            backend: a.backend,
            // A 1-spp frame of the same camera: the four-times-the-samples input of
            // baselines (OIDN on 1 spp); cheap next to the reference.
            full_spp: true,
            background: a.background,
            scene_options: a.scene_options.clone(),
            // The keys of the training loader (training/ssr/data.py).
            sequence_json: Some(
                serde_json::json!({
                    // Scenes are known by their short name (the folder prefix), whatever
                    // path was given; `scene_source` keeps the path.
                    "scene": slug, "scene_source": a.scene,
                    "split": a.split, "sequence": s, "frames": a.frames,
                    "width": a.width, "height": a.height, "spp": a.reference_spp,
                })
                .as_object()
                .expect("an object")
                .clone(),
            ),
            out: dir,
        };
        render_command(&args)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slugs_seeds_and_ranges() {
        assert_eq!(scene_slug("builtin:cornell"), "cornell");
        assert_eq!(
            scene_slug("../shared/scenes/living-room/scene.json"),
            "living-room"
        );
        assert_eq!(scene_slug("a/b/FlightHelmet.gltf"), "FlightHelmet");
        assert_eq!(scene_slug("builtin:procedural:1000000"), "procedural_1000000");
        let seeds: std::collections::HashSet<u64> = ["train", "val", "test"]
            .iter()
            .flat_map(|sp| (0..50).map(move |i| sequence_seed("cornell", sp, i)))
            .collect();
        assert_eq!(
            seeds.len(),
            150,
            "every (split, sequence) has its own camera path"
        );
        assert_eq!(parse_range("2..5", 8).unwrap(), (2, 5));
        assert!(
            parse_range("5..2", 8).is_err()
                && parse_range("0..9", 8).is_err()
                && parse_range("x", 8).is_err()
        );
    }
}
