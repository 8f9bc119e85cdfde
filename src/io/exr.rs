//! One multi-channel EXR per frame: every buffer of DESIGN.md section 3 as named f32
//! channels (`color.R`, `mask.Y`, `normal.X`, `motion.X`, ...), plus `reference.R/G/B` when
//! present (DESIGN.md section 6).

use std::path::Path;

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, ReadChannels, ReadLayers,
    SmallVec, WritableImage, read,
};

use crate::error::{Error, Result};
use crate::nn::HostTensor;
use crate::render::FrameHost;

fn err(path: &Path, message: impl Into<String>) -> Error {
    Error::File {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Writes `frame` to `path` (f32 channels, lossless ZIP compression).
pub fn write_frame(path: &Path, frame: &FrameHost) -> Result<()> {
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let mut list = Vec::new();
    for (name, chans, t) in frame.named() {
        if (t.width as usize, t.height as usize) != (w, h) || t.channels as usize != chans.len() {
            return Err(err(
                path,
                format!(
                    "buffer '{name}' is {}x{}x{}, expected {w}x{h}x{}",
                    t.width,
                    t.height,
                    t.channels,
                    chans.len()
                ),
            ));
        }
        for (c, suffix) in chans.iter().enumerate() {
            let samples: Vec<f32> = (0..w * h).map(|i| t.data[i * chans.len() + c]).collect();
            list.push(AnyChannel::new(
                format!("{name}.{suffix}").as_str(),
                FlatSamples::F32(samples),
            ));
        }
    }
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    Image::from_layer(layer)
        .write()
        .to_file(path)
        .map_err(|e| err(path, format!("cannot write EXR: {e}")))
}

/// Reads a frame written by [`write_frame`]. A missing channel is an error naming it.
pub fn read_frame(path: &Path) -> Result<FrameHost> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| err(path, format!("cannot read EXR: {e}")))?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.0 as u32, layer.size.1 as u32);
    let find = |name: &str| -> Option<Vec<f32>> {
        layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == name)
            .map(|c| c.sample_data.values_as_f32().collect())
    };
    let get = |name: &str, chans: &[&str]| -> Result<HostTensor> {
        let mut data = vec![0f32; (w * h) as usize * chans.len()];
        for (c, suffix) in chans.iter().enumerate() {
            let full = format!("{name}.{suffix}");
            let v = find(&full).ok_or_else(|| err(path, format!("missing channel '{full}'")))?;
            for (i, x) in v.into_iter().enumerate() {
                data[i * chans.len() + c] = x;
            }
        }
        Ok(HostTensor::from_vec(w, h, chans.len() as u32, data))
    };
    const RGB: &[&str] = &["R", "G", "B"];
    let reference = if find("reference.R").is_some() {
        Some(get("reference", RGB)?)
    } else {
        None
    };
    Ok(FrameHost {
        color: get("color", RGB)?,
        mask: get("mask", &["Y"])?,
        albedo: get("albedo", RGB)?,
        normal: get("normal", &["X", "Y", "Z"])?,
        shadow: get("shadow", RGB)?,
        transparent: get("transparent", RGB)?,
        depth: get("depth", &["Y"])?,
        metallic: get("metallic", &["Y"])?,
        roughness: get("roughness", &["Y"])?,
        motion: get("motion", &["X", "Y"])?,
        reference,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(w: u32, h: u32, with_ref: bool) -> FrameHost {
        let t = |c: u32, k: f32| {
            HostTensor::from_fn(w, h, c, |x, y, ch| {
                k + x as f32 * 0.5 - y as f32 * 1e-3 + ch as f32
            })
        };
        FrameHost {
            color: t(3, 0.1),
            mask: t(1, 1.0),
            albedo: t(3, 0.2),
            normal: t(3, -0.3),
            shadow: t(3, 4.0),
            transparent: t(3, 0.0),
            depth: t(1, 0.7),
            metallic: t(1, 0.8),
            roughness: t(1, 0.9),
            motion: t(2, -1_234.567_8),
            reference: with_ref.then(|| t(3, 9.0)),
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let dir = std::env::temp_dir().join(format!("subpixel-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for with_ref in [false, true] {
            let f = frame(7, 5, with_ref);
            let p = dir.join(format!("f{with_ref}.exr"));
            write_frame(&p, &f).unwrap();
            let g = read_frame(&p).unwrap();
            assert_eq!(f, g);
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn missing_channel_is_named() {
        let dir = std::env::temp_dir().join(format!("subpixel-exr-missing-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("partial.exr");
        let layer = Layer::new(
            (2, 2),
            LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
                "color.R",
                FlatSamples::F32(vec![0.0; 4]),
            )])),
        );
        Image::from_layer(layer).write().to_file(&p).unwrap();
        let e = read_frame(&p).unwrap_err().to_string();
        assert!(e.contains("partial.exr") && e.contains("color.G"), "{e}");
        let e = read_frame(&dir.join("nope.exr")).unwrap_err().to_string();
        assert!(e.contains("nope.exr"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
