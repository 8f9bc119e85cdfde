//! 8-bit PNG previews of HDR images (the tonemap of DESIGN §7).

use std::path::Path;

use crate::error::{Error, Result};
use crate::metrics::tonemap_u8;
use crate::nn::HostTensor;

/// Writes `images` side by side (same height) as one tonemapped 8-bit PNG.
pub fn write_png_row(path: &Path, images: &[&HostTensor]) -> Result<()> {
    write_png_row_scaled(path, images, 1)
}

/// The smallest integer factor that makes an image `height` pixels tall at least
/// `min_height` (1 for images already that tall).
pub fn scale_for_height(height: u32, min_height: u32) -> u32 {
    if height == 0 {
        return 1;
    }
    min_height.div_ceil(height).max(1)
}

/// As [`write_png_row`], each pixel drawn as a `scale` x `scale` block (nearest-neighbour
/// upscaling, so small renders stay judgeable without inventing detail).
pub fn write_png_row_scaled(path: &Path, images: &[&HostTensor], scale: u32) -> Result<()> {
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
    if scale > 1 {
        img = image::imageops::resize(&img, w * scale, h * scale, image::imageops::FilterType::Nearest);
    }
    img.save(path).map_err(|e| err(format!("cannot write PNG: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_rows_repeat_each_pixel_as_a_block() {
        assert_eq!(scale_for_height(128, 256), 2);
        assert_eq!(scale_for_height(100, 256), 3);
        assert_eq!(scale_for_height(300, 256), 1);
        assert_eq!(scale_for_height(0, 256), 1);
        let mut t = HostTensor::zeros(3, 2, 3);
        for y in 0..2 {
            for x in 0..3 {
                for c in 0..3 {
                    t.set(x, y, c, (x + 3 * y) as f32 * 0.3 + c as f32 * 0.1);
                }
            }
        }
        let dir = crate::io::test_dir("png");
        let (p1, p3) = (dir.join("one.png"), dir.join("three.png"));
        write_png_row(&p1, &[&t, &t]).unwrap();
        write_png_row_scaled(&p3, &[&t, &t], 3).unwrap();
        let a = image::open(&p1).unwrap().to_rgb8();
        let b = image::open(&p3).unwrap().to_rgb8();
        assert_eq!((a.width(), a.height()), (6, 2));
        assert_eq!((b.width(), b.height()), (18, 6));
        for y in 0..6 {
            for x in 0..18 {
                assert_eq!(b.get_pixel(x, y), a.get_pixel(x / 3, y / 3), "({x}, {y})");
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
