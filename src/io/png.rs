//! 8-bit PNG previews of HDR images (the tonemap of DESIGN §7).

use std::path::Path;

use crate::error::{Error, Result};
use crate::metrics::tonemap_u8;
use crate::nn::HostTensor;

/// Writes `images` side by side (same height) as one tonemapped 8-bit PNG.
pub fn write_png_row(path: &Path, images: &[&HostTensor]) -> Result<()> {
    let err = |m: String| Error::File {
        path: path.to_path_buf(),
        message: m,
    };
    let Some(first) = images.first() else {
        return Err(err("no image to write".into()));
    };
    let h = first.height;
    if images.iter().any(|i| i.height != h || i.channels < 3) {
        return Err(err(
            "side-by-side images need the same height and 3 channels".into()
        ));
    }
    let w: u32 = images.iter().map(|i| i.width).sum();
    let mut img = image::RgbImage::new(w, h);
    let mut x0 = 0;
    for im in images {
        for y in 0..h {
            for x in 0..im.width {
                let px = [0, 1, 2].map(|c| tonemap_u8(im.at(x, y, c)));
                img.put_pixel(x0 + x, y, image::Rgb(px));
            }
        }
        x0 += im.width;
    }
    img.save(path).map_err(|e| err(format!("cannot write PNG: {e}")))
}
