//! Showing tensors on screen: tonemapping, channel views, split screen and a bitmap-font
//! text overlay, written by one compute kernel into an `rgba8unorm` texture that a viewer
//! blits to its surface (or saves as a screenshot).

use bytemuck::{Pod, Zeroable};

use crate::error::{Error, Result};
use crate::gpu::{Bound, Gpu, Grid, Specialisation};
use crate::nn::{HostTensor, Tensor};

/// How source values become display colours.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DisplayMode {
    /// Linear HDR radiance, filmic tonemap + gamma 2.2 (as [`crate::metrics::tonemap`]).
    Radiance,
    /// Signed values: `v * scale` in [-1, 1] shown as [0, 1] (normals, motion).
    Signed(f32),
    /// Values clamped to [0, 1] (albedo, depth, masks).
    Unit,
}

/// A source the display reads: a tensor (channels padded to 4), or a float texture of 4
/// channels such as the denoiser's output ([`crate::ssr::Denoiser::output`]).
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    /// A GPU tensor.
    Tensor(&'a Tensor),
    /// A 2D texture with a float sample type (e.g. `rgba32float`) and `TEXTURE_BINDING`.
    Texture(&'a wgpu::Texture),
}

impl<'a> From<&'a Tensor> for Source<'a> {
    fn from(t: &'a Tensor) -> Self {
        Source::Tensor(t)
    }
}

impl<'a> From<&'a wgpu::Texture> for Source<'a> {
    fn from(t: &'a wgpu::Texture) -> Self {
        Source::Texture(t)
    }
}

/// What a bound display dispatch reads, to know when to rebind.
#[derive(Debug, Clone, PartialEq)]
enum SourceKey {
    Buffer(wgpu::Buffer),
    Texture(wgpu::Texture),
}

impl Source<'_> {
    fn size(&self) -> (u32, u32) {
        match self {
            Source::Tensor(t) => (t.width, t.height),
            Source::Texture(t) => (t.width(), t.height()),
        }
    }

    /// Channels, padded to a multiple of 4 as the kernel reads them.
    fn padded_channels(&self) -> u32 {
        match self {
            Source::Tensor(t) => t.c4() * 4,
            Source::Texture(_) => 4,
        }
    }

    fn c4(&self) -> u32 {
        self.padded_channels() / 4
    }

    fn key(&self) -> SourceKey {
        match self {
            Source::Tensor(t) => SourceKey::Buffer(t.buffer.clone()),
            Source::Texture(t) => SourceKey::Texture((*t).clone()),
        }
    }

    fn is_texture(&self) -> bool {
        matches!(self, Source::Texture(_))
    }
}

/// What to show.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Colour mapping.
    pub mode: DisplayMode,
    /// First source channel shown.
    pub first: u32,
    /// Channels shown: 1 (grey), 2 (red-green) or 3 (rgb).
    pub channels: u32,
    /// Output column where the second source starts (split screen), if any.
    pub split_x: Option<u32>,
    /// Overlay text lines (ASCII; others show as `?`).
    pub text: Vec<String>,
    /// Glyph scale (8 px glyphs times this).
    pub text_scale: u32,
}

impl Default for View {
    fn default() -> Self {
        Self {
            mode: DisplayMode::Radiance,
            first: 0,
            channels: 3,
            split_x: None,
            text: Vec::new(),
            text_scale: 2,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    out_w: u32,
    out_h: u32,
    src_w: u32,
    src_h: u32,
    mode: u32,
    first: u32,
    channels: u32,
    c4_a: u32,
    c4_b: u32,
    split_x: u32,
    text_cols: u32,
    text_rows: u32,
    text_scale: u32,
    scale_b: f32,
    _pad: [u32; 2],
}

/// Size of the kernel's uniform `Params`, for the naga layout test.
pub const PARAM_SIZES: &[(&str, usize)] = &[("view/display", std::mem::size_of::<Params>())];

/// The 8x8 font packed as the kernel reads it: per glyph, rows 0-3 then 4-7, 8 bits a row
/// with bit 0 the leftmost pixel.
fn font_words() -> Vec<u32> {
    font8x8::legacy::BASIC_LEGACY
        .iter()
        .flat_map(|g| {
            [
                u32::from_le_bytes([g[0], g[1], g[2], g[3]]),
                u32::from_le_bytes([g[4], g[5], g[6], g[7]]),
            ]
        })
        .collect()
}

/// Largest overlay: columns per line and lines (longer text is cut off).
pub const TEXT_MAX: (u32, u32) = (96, 32);

fn text_grid(lines: &[String]) -> (u32, u32, Vec<u32>) {
    let lines = &lines[..lines.len().min(TEXT_MAX.1 as usize)];
    let cols = (lines.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32).min(TEXT_MAX.0);
    let rows = lines.len() as u32;
    let mut grid = vec![b' ' as u32; (cols * rows).max(1) as usize];
    for (r, l) in lines.iter().enumerate() {
        for (c, ch) in l.chars().take(cols as usize).enumerate() {
            grid[r * cols as usize + c] = if ch.is_ascii() { ch as u32 } else { b'?' as u32 };
        }
    }
    (cols, rows, grid)
}

/// The display target and its resources. Drawing allocates nothing: the overlay text and
/// the parameters are written into buffers made once, and the kernel's bind group is kept
/// while the sources stay the same.
pub struct Display {
    gpu: Gpu,
    font: wgpu::Buffer,
    text: wgpu::Buffer,
    target: wgpu::Texture,
    width: u32,
    height: u32,
    /// The last dispatch and the sources it binds.
    cached: std::sync::Mutex<Bound<(SourceKey, SourceKey), crate::gpu::Dispatch>>,
}

impl Display {
    /// A `width x height` display target.
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::shape(
                "display",
                format!("size {width}x{height} must be non-zero"),
            ));
        }
        use wgpu::util::DeviceExt;
        let font = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("subpixel.view.font"),
            contents: bytemuck::cast_slice(&font_words()),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let text = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("subpixel.view.text"),
            size: (TEXT_MAX.0 * TEXT_MAX.1 * 4) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let target = gpu.storage_texture(
            "subpixel.view.target",
            width,
            height,
            wgpu::TextureFormat::Rgba8Unorm,
        );
        Ok(Self {
            gpu: gpu.clone(),
            font,
            text,
            target,
            width,
            height,
            cached: std::sync::Mutex::new(Bound::new()),
        })
    }

    /// The `rgba8unorm` texture the display is drawn into.
    pub fn texture(&self) -> &wgpu::Texture {
        &self.target
    }

    /// Records drawing `a` (and `b` right of `view.split_x`) with the overlay (at most
    /// [`TEXT_MAX`] columns and lines). The text and parameters are written with queue
    /// writes, which take effect at the next submission: submit between two draws.
    pub fn draw<'s>(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        a: impl Into<Source<'s>>,
        b: Option<Source<'s>>,
        view: &View,
    ) -> Result<()> {
        let a = a.into();
        let b = b.unwrap_or(a);
        if a.size() != b.size() {
            return Err(Error::shape("display", "split-screen sources differ in size"));
        }
        let need = view.first + view.channels.clamp(1, 3);
        let have = a.padded_channels().min(b.padded_channels());
        if need > have || !(1..=3).contains(&view.channels) {
            return Err(Error::shape(
                "display",
                format!(
                    "view of channels {}..{need} of a source of {have} channels",
                    view.first
                ),
            ));
        }
        let (cols, rows, grid) = text_grid(&view.text);
        self.gpu
            .queue
            .write_buffer(&self.text, 0, bytemuck::cast_slice(&grid));
        let (mode, scale_b) = match view.mode {
            DisplayMode::Radiance => (0, 1.0),
            DisplayMode::Signed(s) => (1, s),
            DisplayMode::Unit => (2, 1.0),
        };
        let params = Params {
            out_w: self.width,
            out_h: self.height,
            src_w: a.size().0,
            src_h: a.size().1,
            mode,
            first: view.first,
            channels: view.channels,
            c4_a: a.c4(),
            c4_b: b.c4(),
            split_x: view.split_x.unwrap_or(u32::MAX),
            text_cols: cols,
            text_rows: rows,
            text_scale: view.text_scale.max(1),
            scale_b,
            _pad: [0; 2],
        };
        let mut cached = self.cached.lock().unwrap_or_else(|e| e.into_inner());
        let d = cached.get_or_build((a.key(), b.key()), || {
            let tv = self.target.create_view(&Default::default());
            let views = [a, b].map(|s| match s {
                Source::Texture(t) => Some(t.create_view(&Default::default())),
                Source::Tensor(_) => None,
            });
            fn bind<'r>(s: Source<'r>, v: &'r Option<wgpu::TextureView>) -> wgpu::BindingResource<'r> {
                match (s, v) {
                    (_, Some(v)) => wgpu::BindingResource::TextureView(v),
                    (Source::Tensor(t), None) => t.buffer.as_entire_binding(),
                    (Source::Texture(_), None) => unreachable!("a view for every texture"),
                }
            }
            let flags = Specialisation(vec![
                ("TEXTURE_A", a.is_texture() as u32 as f64),
                ("TEXTURE_B", b.is_texture() as u32 as f64),
            ]);
            self.gpu.kernels.dispatch_with(
                "view/display",
                &flags,
                bytemuck::bytes_of(&params),
                &[
                    bind(a, &views[0]),
                    bind(b, &views[1]),
                    self.text.as_entire_binding(),
                    self.font.as_entire_binding(),
                    wgpu::BindingResource::TextureView(&tv),
                ],
                Grid::pixels(self.width, self.height),
            )
        })?;
        d.write_params(&self.gpu.queue, bytemuck::bytes_of(&params));
        d.encode(encoder);
        Ok(())
    }

    /// Reads the display back as an RGBA image (for screenshots).
    pub fn read_rgba(&self) -> Result<image::RgbaImage> {
        let bytes = self.gpu.read_texture(&self.target)?;
        let img = image::RgbaImage::from_raw(self.width, self.height, bytes)
            .ok_or_else(|| crate::error::Error::Readback("display readback has the wrong size".into()))?;
        Ok(img)
    }
}

/// Scalar CPU reference of the display kernel: the 8-bit colour of output pixel (x, y).
pub fn reference_pixel(
    a: &HostTensor,
    b: &HostTensor,
    view: &View,
    out_w: u32,
    out_h: u32,
    x: u32,
    y: u32,
) -> [u8; 3] {
    let sx = (x * a.width / out_w).min(a.width - 1);
    let sy = (y * a.height / out_h).min(a.height - 1);
    let split = view.split_x.unwrap_or(u32::MAX);
    let src = if x >= split { b } else { a };
    let get = |c: u32| if c < src.channels { src.at(sx, sy, c) } else { 0.0 };
    let mut v = [0.0f32; 3];
    for (i, vi) in v.iter_mut().enumerate().take(view.channels.min(3) as usize) {
        *vi = get(view.first + i as u32);
    }
    if view.channels == 1 {
        v = [v[0]; 3];
    }
    let mut rgb = v.map(|c| match view.mode {
        DisplayMode::Radiance => crate::metrics::tonemap(c),
        DisplayMode::Signed(s) => (c * s * 0.5 + 0.5).clamp(0.0, 1.0),
        DisplayMode::Unit => c.clamp(0.0, 1.0),
    });
    if split < out_w && x == split {
        rgb = [1.0; 3];
    }
    let (cols, rows, grid) = text_grid(&view.text);
    let cell = 8 * view.text_scale.max(1);
    let (col, row) = (x / cell, y / cell);
    if col < cols && row < rows {
        let code = (grid[(row * cols + col) as usize] & 127) as usize;
        let (gx, gy) = (
            (x % cell) / view.text_scale.max(1),
            (y % cell) / view.text_scale.max(1),
        );
        let on = (font8x8::legacy::BASIC_LEGACY[code][gy as usize] >> gx) & 1 == 1;
        rgb = if on {
            [1.0, 1.0, 0.6]
        } else {
            rgb.map(|c| c * 0.35)
        };
    }
    rgb.map(|c| (c * 255.0).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlay_text_is_cut_to_the_buffer() {
        let long: Vec<String> = (0..40).map(|i| format!("{i:>3} {}", "x".repeat(200))).collect();
        let (cols, rows, grid) = text_grid(&long);
        assert_eq!((cols, rows), TEXT_MAX);
        assert_eq!(grid.len(), (TEXT_MAX.0 * TEXT_MAX.1) as usize);
        assert_eq!(grid[..3], [b' ' as u32, b' ' as u32, b'0' as u32]);
        let (cols, rows, grid) = text_grid(&["ab".into(), "é".into()]);
        assert_eq!((cols, rows), (2, 2));
        assert_eq!(grid, [b'a' as u32, b'b' as u32, b'?' as u32, b' ' as u32]);
    }
}
