//! One multi-channel f32 EXR per frame, channels named `buffer.C` (DESIGN §3, §6):
//! `color.R color.G color.B mask.Y albedo.R.. normal.X normal.Y normal.Z shadow.R..
//! transparent.R.. depth.Y metallic.Y roughness.Y motion.X motion.Y`, plus optional
//! `reference.R..` (the N-spp reference), `reference_half.R..` (the mean of its first half of
//! samples, for its noise), `full.R..` (a 1-spp frame), `background.R.. coverage.Y` (the
//! directly seen environment over each pixel's footprint and the fraction that escapes) and
//! `pred.R..` (a denoised prediction).

use std::collections::HashMap;
use std::path::Path;

use exr::prelude::*;

use crate::error::{Error, Result};
use crate::frame::{Background, DirectEmission, HostFrame};
use crate::nn::HostTensor;

/// Channel suffixes of a buffer with `c` channels named `name`.
pub fn suffixes(name: &str, c: u32) -> &'static [&'static str] {
    match (name, c) {
        ("normal", 3) => &["X", "Y", "Z"],
        ("motion", 2) => &["X", "Y"],
        (_, 3) => &["R", "G", "B"],
        (_, 1) => &["Y"],
        (_, 2) => &["X", "Y"],
        _ => &["R", "G", "B", "A"],
    }
}

/// Everything one frame file may hold.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameFile {
    /// The renderer's buffers, when present.
    pub frame: Option<HostFrame>,
    /// The reference image (`reference.*`), when present.
    pub reference: Option<HostTensor>,
    /// A prediction (`pred.*`), when present.
    pub pred: Option<HostTensor>,
    /// The mean of the first half of the reference's samples (`reference_half.*`): with
    /// `reference` it measures the reference's own noise.
    pub reference_half: Option<HostTensor>,
    /// A 1-spp full-resolution colour of the same camera (`full.*`), for baselines.
    pub full: Option<HostTensor>,
}

/// Writes named HWC tensors of one size as f32 channels `name.SUFFIX`.
pub fn write_tensors(path: &Path, tensors: &[(&str, &HostTensor)]) -> Result<()> {
    let err = |m: String| Error::File {
        path: path.to_path_buf(),
        message: m,
    };
    let Some((_, first)) = tensors.first() else {
        return Err(err("nothing to write".into()));
    };
    let (w, h) = (first.width as usize, first.height as usize);
    let mut channels = Vec::new();
    for (name, t) in tensors {
        if (t.width as usize, t.height as usize) != (w, h) {
            return Err(err(format!(
                "tensor '{name}' is {}x{}, the image is {w}x{h}",
                t.width, t.height
            )));
        }
        for (c, suffix) in suffixes(name, t.channels)
            .iter()
            .enumerate()
            .take(t.channels as usize)
        {
            let samples: Vec<f32> = (0..w * h).map(|i| t.data[i * t.channels as usize + c]).collect();
            channels.push(AnyChannel::new(
                format!("{name}.{suffix}").as_str(),
                FlatSamples::F32(samples),
            ));
        }
    }
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    Image::from_layer(layer)
        .write()
        .to_file(path)
        .map_err(|e| err(format!("cannot write EXR: {e}")))
}

/// Most bytes the decoded channels of one EXR may take (f32 samples).
pub const MAX_DECODED_BYTES: u64 = 4 << 30;

/// Checks an EXR's headers before anything is decoded: a regular file whose every part
/// has a plausible size (the decoded f32 channels within [`MAX_DECODED_BYTES`]) and an
/// offset table that fits in the file. A corrupt or hostile header (a 50 KB file claiming
/// 100000 x 100000 pixels) is an error naming the file instead of a huge allocation.
pub fn check_header(path: &Path) -> Result<()> {
    read_header(path).map(|_| ())
}

/// The renderer's buffers of a frame file (DESIGN §3): name and channel count.
pub const FRAME_BUFFERS: [(&str, u32); 10] = [
    ("color", 3),
    ("mask", 1),
    ("albedo", 3),
    ("normal", 3),
    ("shadow", 3),
    ("transparent", 3),
    ("depth", 1),
    ("metallic", 1),
    ("roughness", 1),
    ("motion", 2),
];

/// What an EXR's first header says, read without decoding any pixel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExrHeader {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Channel names.
    pub channels: Vec<String>,
}

impl ExrHeader {
    /// Whether the file holds every channel of the renderer's buffers ([`FRAME_BUFFERS`]);
    /// an error naming the file and the first missing channel when it holds only some.
    pub fn has_frame(&self, path: &Path) -> Result<bool> {
        let names: Vec<String> = FRAME_BUFFERS
            .iter()
            .flat_map(|&(n, c)| {
                suffixes(n, c)
                    .iter()
                    .take(c as usize)
                    .map(move |s| format!("{n}.{s}"))
            })
            .collect();
        let missing: Vec<&String> = names.iter().filter(|n| !self.channels.contains(n)).collect();
        match missing.first() {
            None => Ok(true),
            Some(_) if missing.len() == names.len() => Ok(false),
            Some(first) => {
                let mut found = self.channels.clone();
                found.sort();
                Err(Error::File {
                    path: path.to_path_buf(),
                    message: format!("channel '{first}' is missing (found {})", found.join(" ")),
                })
            }
        }
    }
}

/// Reads and checks an EXR's headers (as [`check_header`]) and returns the first one's
/// size and channels, without decoding pixels.
pub fn read_header(path: &Path) -> Result<ExrHeader> {
    let err = |m: String| Error::File {
        path: path.to_path_buf(),
        message: m,
    };
    let len = super::regular_file_len(path).map_err(|e| err(format!("cannot read EXR: {e}")))?;
    let headers = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| err(format!("cannot read EXR: {e}")))?
        .headers;
    for h in headers.iter() {
        let (w, hh) = (h.layer_size.0 as u64, h.layer_size.1 as u64);
        let channels = h.channels.list.len() as u64;
        let bytes = w.saturating_mul(hh).saturating_mul(channels).saturating_mul(4);
        if bytes > MAX_DECODED_BYTES {
            return Err(err(format!(
                "cannot read EXR: its header claims {w}x{hh} pixels of {channels} channels \
                 ({:.1} GiB decoded), more than the {} GiB limit",
                bytes as f64 / (1u64 << 30) as f64,
                MAX_DECODED_BYTES >> 30
            )));
        }
        let table = (h.chunk_count as u64).saturating_mul(8);
        if table > len {
            return Err(err(format!(
                "cannot read EXR: its header claims {} chunks, whose offset table alone needs \
                 {table} bytes, but the file has {len} bytes (truncated or corrupt)",
                h.chunk_count
            )));
        }
    }
    let first = headers
        .first()
        .ok_or_else(|| err("cannot read EXR: no header".into()))?;
    Ok(ExrHeader {
        width: first.layer_size.0 as u32,
        height: first.layer_size.1 as u32,
        channels: first.channels.list.iter().map(|c| c.name.to_string()).collect(),
    })
}

/// Reads every channel of an EXR: `(width, height, name -> samples)`.
pub fn read_channels(path: &Path) -> Result<(u32, u32, HashMap<String, Vec<f32>>)> {
    let err = |m: String| Error::File {
        path: path.to_path_buf(),
        message: m,
    };
    check_header(path)?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| err(format!("cannot read EXR: {e}")))?;
    let layer = image.layer_data;
    let size = layer.size;
    let mut out = HashMap::new();
    for ch in layer.channel_data.list {
        out.insert(ch.name.to_string(), ch.sample_data.values_as_f32().collect());
    }
    Ok((size.0 as u32, size.1 as u32, out))
}

/// Gathers channels `name.SUFFIX` into a tensor; `None` when none of them exists, an error
/// naming the file and the channel when only some do.
pub fn gather(
    path: &Path,
    w: u32,
    h: u32,
    chans: &HashMap<String, Vec<f32>>,
    name: &str,
    c: u32,
) -> Result<Option<HostTensor>> {
    let names: Vec<String> = suffixes(name, c)
        .iter()
        .take(c as usize)
        .map(|s| format!("{name}.{s}"))
        .collect();
    if names.iter().all(|n| !chans.contains_key(n)) {
        return Ok(None);
    }
    let mut t = HostTensor::zeros(w, h, c);
    for (ci, n) in names.iter().enumerate() {
        let src = chans.get(n).ok_or_else(|| Error::File {
            path: path.to_path_buf(),
            message: format!("channel '{n}' is missing (found {})", sorted_names(chans)),
        })?;
        for (i, v) in src.iter().enumerate().take((w * h) as usize) {
            t.data[i * c as usize + ci] = *v;
        }
    }
    Ok(Some(t))
}

fn sorted_names(chans: &HashMap<String, Vec<f32>>) -> String {
    let mut v: Vec<&str> = chans.keys().map(|s| s.as_str()).collect();
    v.sort();
    v.join(" ")
}

/// Writes a frame file.
pub fn write_frame(path: &Path, f: &FrameFile) -> Result<()> {
    let mut tensors: Vec<(&str, &HostTensor)> = Vec::new();
    if let Some(frame) = &f.frame {
        frame.size()?;
        tensors.extend(frame.fields().iter().map(|(n, t, _)| (*n, *t)));
        if let Some(b) = &frame.background {
            tensors.push(("background", &b.radiance));
            tensors.push(("coverage", &b.coverage));
            if let Some(a) = &b.albedo {
                tensors.push(("albedo_footprint", a));
            }
            if let Some(e) = &b.emission {
                tensors.push(("emission_footprint", &e.footprint));
                tensors.push(("emission", &e.samples));
                if let Some(a) = &e.escaped {
                    tensors.push(("escaped", a));
                }
            }
        }
    }
    if let Some(r) = &f.reference {
        tensors.push(("reference", r));
    }
    if let Some(p) = &f.pred {
        tensors.push(("pred", p));
    }
    if let Some(r) = &f.reference_half {
        tensors.push(("reference_half", r));
    }
    if let Some(t) = &f.full {
        tensors.push(("full", t));
    }
    write_tensors(path, &tensors)
}

/// Reads a frame file. The renderer's buffers are all-or-nothing: a file with some of
/// them is an error naming the first missing channel; so are the optional background's
/// two (`background`, `coverage`), which belong to the renderer's buffers, and its
/// optional footprint albedo (`albedo_footprint`), which belongs to the background.
pub fn read_frame(path: &Path) -> Result<FrameFile> {
    let (w, h, chans) = read_channels(path)?;
    let get = |name: &str, c: u32| gather(path, w, h, &chans, name, c);
    let reference = get("reference", 3)?;
    let pred = get("pred", 3)?;
    let reference_half = get("reference_half", 3)?;
    let full = get("full", 3)?;
    let albedo = get("albedo_footprint", 3)?;
    let escaped = get("escaped", 1)?;
    let emission = match (get("emission_footprint", 3)?, get("emission", 3)?) {
        (Some(footprint), Some(samples)) => Some(DirectEmission {
            footprint,
            samples,
            escaped,
        }),
        (None, None) if escaped.is_some() => {
            return Err(Error::File {
                path: path.to_path_buf(),
                message: "channel 'escaped.Y' without the directly seen emission it belongs to (emission.RGB, emission_footprint.RGB)".into(),
            });
        }
        (None, None) => None,
        (f, _) => {
            let (has, missing) = if f.is_none() {
                ("emission.RGB", "emission_footprint.R")
            } else {
                ("emission_footprint.RGB", "emission.R")
            };
            return Err(Error::File {
                path: path.to_path_buf(),
                message: format!(
                    "channels '{has}' without '{missing}': the directly seen emission needs both emission_footprint.RGB and emission.RGB"
                ),
            });
        }
    };
    let background = match (get("background", 3)?, get("coverage", 1)?) {
        (Some(radiance), Some(coverage)) => Some(Background {
            radiance,
            coverage,
            albedo,
            emission,
        }),
        (None, None) if albedo.is_some() || emission.is_some() => {
            let what = if albedo.is_some() {
                "albedo_footprint.RGB"
            } else {
                "emission.RGB and emission_footprint.RGB"
            };
            return Err(Error::File {
                path: path.to_path_buf(),
                message: format!(
                    "channels '{what}' without the background they belong to (background.RGB, coverage.Y)"
                ),
            });
        }
        (None, None) => None,
        (r, _) => {
            let missing = if r.is_none() { "background.R" } else { "coverage.Y" };
            return Err(Error::File {
                path: path.to_path_buf(),
                message: format!(
                    "channel '{missing}' is missing: the background needs both background.RGB and coverage.Y (found {})",
                    sorted_names(&chans)
                ),
            });
        }
    };
    let names = [
        "color",
        "mask",
        "albedo",
        "normal",
        "shadow",
        "transparent",
        "depth",
        "metallic",
        "roughness",
        "motion",
    ];
    let channels = [3, 1, 3, 3, 3, 3, 1, 1, 1, 2];
    let mut parts = Vec::new();
    for (n, c) in names.iter().zip(channels) {
        parts.push(get(n, c)?);
    }
    let frame = if parts.iter().all(|p| p.is_none()) {
        if background.is_some() {
            return Err(Error::File {
                path: path.to_path_buf(),
                message: "background channels without the renderer's buffers (color, mask, ...)".into(),
            });
        }
        None
    } else {
        if let Some(i) = parts.iter().position(|p| p.is_none()) {
            let first = format!("{}.{}", names[i], suffixes(names[i], channels[i])[0]);
            return Err(Error::File {
                path: path.to_path_buf(),
                message: format!("channel '{first}' is missing (found {})", sorted_names(&chans)),
            });
        }
        let mut it = parts.into_iter().map(|p| p.expect("checked above"));
        let mut next = || it.next().expect("ten buffers");
        Some(HostFrame {
            color: next(),
            mask: next(),
            albedo: next(),
            normal: next(),
            shadow: next(),
            transparent: next(),
            depth: next(),
            metallic: next(),
            roughness: next(),
            motion: next(),
            background,
        })
    };
    Ok(FrameFile {
        frame,
        reference,
        pred,
        reference_half,
        full,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(w: u32, h: u32) -> HostFrame {
        let t =
            |c, k: f32| HostTensor::from_fn(w, h, c, |x, y, ch| k * (x as f32 + 10.0 * y as f32) + ch as f32);
        HostFrame {
            color: t(3, 1.5),
            mask: t(1, 0.0),
            albedo: t(3, 0.01),
            normal: t(3, -0.02),
            shadow: t(3, 3.0),
            transparent: t(3, 0.0),
            depth: t(1, 0.001),
            metallic: t(1, 0.5),
            roughness: t(1, 0.25),
            motion: t(2, -0.123_456_7),
            background: None,
        }
    }

    /// A fresh temporary folder for test `test`, and the path of `file` in it.
    fn temp_file(test: &str, file: &str) -> (std::path::PathBuf, std::path::PathBuf) {
        let dir = crate::io::test_dir(&format!("exr-{test}"));
        let path = dir.join(file);
        (dir, path)
    }

    /// The message of the error reading the frame at `path` gives.
    fn read_err(path: &Path) -> String {
        read_frame(path).unwrap_err().to_string()
    }

    #[test]
    fn frame_round_trip_is_exact() {
        let (dir, path) = temp_file("round-trip", "frame_0000.exr");
        let f = FrameFile {
            frame: Some(HostFrame {
                background: Some(Background {
                    radiance: HostTensor::from_fn(7, 5, 3, |x, y, c| (x * c + y) as f32 * 0.5),
                    coverage: HostTensor::from_fn(7, 5, 1, |x, _, _| x as f32 / 6.0),
                    albedo: Some(HostTensor::from_fn(7, 5, 3, |x, y, c| (x + y + c) as f32 * 0.1)),
                    emission: Some(DirectEmission {
                        footprint: HostTensor::from_fn(7, 5, 3, |x, y, c| (x * y + c) as f32 * 2.5),
                        samples: HostTensor::from_fn(7, 5, 3, |x, y, c| ((x + y) % 2 * (c + 1)) as f32 * 4.0),
                        escaped: Some(HostTensor::from_fn(7, 5, 1, |x, y, _| {
                            ((x + 2 * y) % 3) as f32 * 0.5
                        })),
                    }),
                }),
                ..frame(7, 5)
            }),
            reference: Some(HostTensor::from_fn(7, 5, 3, |x, _, c| x as f32 * 1e3 + c as f32)),
            reference_half: Some(HostTensor::from_fn(7, 5, 3, |x, y, c| {
                x as f32 - y as f32 * 0.5 + c as f32
            })),
            full: Some(HostTensor::from_fn(7, 5, 3, |x, y, c| (x + y * c) as f32 * 0.25)),
            pred: None,
        };
        write_frame(&path, &f).unwrap();
        assert_eq!(read_frame(&path).unwrap(), f);
        // A background without the footprint albedo (files from before it existed).
        let mut old = f.clone();
        old.frame.as_mut().unwrap().background.as_mut().unwrap().albedo = None;
        write_frame(&path, &old).unwrap();
        assert_eq!(read_frame(&path).unwrap(), old);
        // Only a prediction.
        let p = FrameFile {
            pred: Some(HostTensor::from_fn(7, 5, 3, |x, y, c| (x * y + c) as f32)),
            ..Default::default()
        };
        write_frame(&path, &p).unwrap();
        assert_eq!(read_frame(&path).unwrap(), p);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A small file whose header claims 100000 x 100000 pixels is refused before decoding.
    #[test]
    fn header_bombs_are_refused() {
        let (dir, path) = temp_file("bomb", "frame_0000.exr");
        write_frame(
            &path,
            &FrameFile {
                frame: Some(frame(16, 16)),
                ..Default::default()
            },
        )
        .unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        // dataWindow (box2i: xmin, ymin, xmax, ymax) -> 0, 0, 99999, 99999.
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        for (k, v) in [0i32, 0, 99_999, 99_999].iter().enumerate() {
            bytes[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
        std::fs::write(&path, &bytes).unwrap();
        assert!(bytes.len() < 100_000);
        let e = read_err(&path);
        assert!(e.contains("frame_0000.exr") && e.contains("100000x100000"), "{e}");
        // A FIFO (or any non-regular file) is refused without blocking.
        #[cfg(unix)]
        {
            let fifo = dir.join("fifo.exr");
            let ok = std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .map(|s| s.success());
            if ok.unwrap_or(false) {
                let e = read_err(&fifo);
                assert!(e.contains("not a regular file"), "{e}");
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn missing_channels_are_named() {
        let (dir, path) = temp_file("missing", "frame_0001.exr");
        let f = frame(4, 4);
        let fields = f.fields();
        let partial: Vec<(&str, &HostTensor)> = fields
            .iter()
            .filter(|(n, _, _)| *n != "motion")
            .map(|(n, t, _)| (*n, *t))
            .collect();
        write_tensors(&path, &partial).unwrap();
        let e = read_err(&path);
        assert!(
            e.contains("frame_0001.exr") && e.contains("'motion.X' is missing"),
            "{e}"
        );
        // The footprint albedo without its background.
        let albedo = HostTensor::zeros(4, 4, 3);
        let mut all: Vec<(&str, &HostTensor)> = fields.iter().map(|(n, t, _)| (*n, *t)).collect();
        all.push(("albedo_footprint", &albedo));
        write_tensors(&path, &all).unwrap();
        let e = read_err(&path);
        assert!(
            e.contains("frame_0001.exr") && e.contains("'albedo_footprint.RGB' without the background"),
            "{e}"
        );
        // Half of the directly seen emission, then all of it without the background.
        let (coverage, zeros) = (HostTensor::zeros(4, 4, 1), HostTensor::zeros(4, 4, 3));
        let mut with_bg: Vec<(&str, &HostTensor)> = fields.iter().map(|(n, t, _)| (*n, *t)).collect();
        with_bg.extend([
            ("background", &zeros),
            ("coverage", &coverage),
            ("emission", &zeros),
        ]);
        write_tensors(&path, &with_bg).unwrap();
        let e = read_err(&path);
        assert!(
            e.contains("frame_0001.exr") && e.contains("'emission.RGB' without 'emission_footprint.R'"),
            "{e}"
        );
        // The samples' escapes without the emission they belong to.
        let mut escaped = with_bg[..with_bg.len() - 1].to_vec();
        escaped.push(("escaped", &coverage));
        write_tensors(&path, &escaped).unwrap();
        let e = read_err(&path);
        assert!(
            e.contains("frame_0001.exr") && e.contains("'escaped.Y' without the directly seen emission"),
            "{e}"
        );
        let mut no_bg: Vec<(&str, &HostTensor)> = fields.iter().map(|(n, t, _)| (*n, *t)).collect();
        no_bg.extend([("emission", &zeros), ("emission_footprint", &zeros)]);
        write_tensors(&path, &no_bg).unwrap();
        let e = read_err(&path);
        assert!(
            e.contains("'emission.RGB and emission_footprint.RGB' without the background"),
            "{e}"
        );
        let e = read_err(&dir.join("nope.exr"));
        assert!(e.contains("nope.exr") && e.contains("cannot read EXR"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
