//! Lat-long environment maps (`.hdr`, `.exr`, or anything the `image` crate reads).

use std::path::Path;

use glam::Mat3;

use super::file_err;
use crate::error::Result;
use crate::render::scene::Environment;

/// Loads a lat-long environment map (`.hdr`, `.exr`, or anything the `image` crate reads).
pub fn load_environment(path: &Path, scale: f32, to_world: Mat3) -> Result<Environment> {
    let bytes = crate::io::read_regular(path, u64::MAX)
        .map_err(|e| file_err(path, format!("cannot open environment map: {e}")))?;
    let img = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| file_err(path, format!("cannot read environment map: {e}")))?
        .decode()
        .map_err(|e| file_err(path, format!("cannot decode environment map: {e}")))?
        .to_rgb32f();
    let (width, height) = img.dimensions();
    if width == 0 || height == 0 {
        return Err(file_err(path, "empty environment map"));
    }
    let pixels: Vec<[f32; 3]> = img
        .pixels()
        .map(|p| p.0.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 }))
        .collect();
    Ok(Environment {
        scale,
        to_world,
        ..Environment::from_pixels(path, width, height, pixels)
    })
}
