//! Scalar CPU references of every `wgsl/nn` kernel, written for clarity, not speed.
//! The GPU kernels are tested against these.

use super::ops::{Activation, PoolMode, UpsampleMode};

/// An image in host memory, `height x width x channels`, row-major HWC, unpadded.
#[derive(Debug, Clone, PartialEq)]
pub struct HostTensor {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Channels.
    pub channels: u32,
    /// `height * width * channels` values.
    pub data: Vec<f32>,
}

impl HostTensor {
    /// A zero tensor.
    pub fn zeros(width: u32, height: u32, channels: u32) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; (width * height * channels) as usize],
        }
    }

    /// Wraps `data` (HWC); panics if the length does not match (a programming error).
    pub fn from_vec(width: u32, height: u32, channels: u32, data: Vec<f32>) -> Self {
        assert_eq!(
            data.len(),
            (width * height * channels) as usize,
            "HostTensor size"
        );
        Self {
            width,
            height,
            channels,
            data,
        }
    }

    /// Builds a tensor from a function of (x, y, c).
    pub fn from_fn(width: u32, height: u32, channels: u32, f: impl Fn(u32, u32, u32) -> f32) -> Self {
        let mut t = Self::zeros(width, height, channels);
        for y in 0..height {
            for x in 0..width {
                for c in 0..channels {
                    t.set(x, y, c, f(x, y, c));
                }
            }
        }
        t
    }

    fn idx(&self, x: u32, y: u32, c: u32) -> usize {
        ((y * self.width + x) * self.channels + c) as usize
    }

    /// Value at (x, y, c).
    pub fn at(&self, x: u32, y: u32, c: u32) -> f32 {
        self.data[self.idx(x, y, c)]
    }

    /// Sets (x, y, c).
    pub fn set(&mut self, x: u32, y: u32, c: u32, v: f32) {
        let i = self.idx(x, y, c);
        self.data[i] = v;
    }

    /// Zero-padded channels as stored on the GPU.
    pub fn to_padded(&self) -> Vec<f32> {
        let cp = super::tensor::padded(self.channels) as usize;
        let c = self.channels as usize;
        let mut out = vec![0.0; self.width as usize * self.height as usize * cp];
        for (i, px) in self.data.chunks(c).enumerate() {
            out[i * cp..i * cp + c].copy_from_slice(px);
        }
        out
    }

    /// Drops channel padding.
    pub fn from_padded(width: u32, height: u32, channels: u32, data: &[f32]) -> Self {
        let cp = super::tensor::padded(channels) as usize;
        let c = channels as usize;
        let n = width as usize * height as usize;
        let mut out = Vec::with_capacity(n * c);
        for i in 0..n {
            out.extend_from_slice(&data[i * cp..i * cp + c]);
        }
        Self::from_vec(width, height, channels, out)
    }

    /// Channels `range` of every pixel as a new tensor.
    pub fn slice_channels(&self, start: u32, count: u32) -> Self {
        Self::from_fn(self.width, self.height, count, |x, y, c| self.at(x, y, start + c))
    }

    /// Concatenation along channels.
    pub fn concat(parts: &[&HostTensor]) -> Self {
        let (w, h) = (parts[0].width, parts[0].height);
        let total: u32 = parts.iter().map(|p| p.channels).sum();
        let mut out = Self::zeros(w, h, total);
        for y in 0..h {
            for x in 0..w {
                let mut c0 = 0;
                for p in parts {
                    for c in 0..p.channels {
                        out.set(x, y, c0 + c, p.at(x, y, c));
                    }
                    c0 += p.channels;
                }
            }
        }
        out
    }

    /// Largest absolute value (NaN counts as infinite).
    pub fn max_abs(&self) -> f32 {
        self.data.iter().fold(
            0.0f32,
            |m, v| {
                if v.is_nan() { f32::INFINITY } else { m.max(v.abs()) }
            },
        )
    }
}

/// 3x3 convolution over the channel concatenation of `inputs`, zero padding.
/// `weight` is OIHW `[cout][cin][3][3]` with cin the total logical input channels.
pub fn conv3x3(
    inputs: &[&HostTensor],
    weight: &[f32],
    bias: &[f32],
    cout: u32,
    act: Activation,
) -> HostTensor {
    let x = HostTensor::concat(inputs);
    let (w, h, cin) = (x.width as i32, x.height as i32, x.channels as usize);
    let mut out = HostTensor::zeros(x.width, x.height, cout);
    for oy in 0..h {
        for ox in 0..w {
            for co in 0..cout as usize {
                let mut acc = bias[co] as f64;
                for ky in 0..3i32 {
                    for kx in 0..3i32 {
                        let (ix, iy) = (ox + kx - 1, oy + ky - 1);
                        if ix < 0 || iy < 0 || ix >= w || iy >= h {
                            continue;
                        }
                        for ci in 0..cin {
                            let wv = weight[((co * cin + ci) * 3 + ky as usize) * 3 + kx as usize];
                            acc += wv as f64 * x.at(ix as u32, iy as u32, ci as u32) as f64;
                        }
                    }
                }
                out.set(ox as u32, oy as u32, co as u32, act.apply(acc as f32));
            }
        }
    }
    out
}

/// Output size of 2x2 pooling: `ceil(n / 2)`.
pub fn pooled(n: u32) -> u32 {
    n.div_ceil(2)
}

/// 2x2 pooling; windows are clipped to the input and averages taken over what is inside.
pub fn pool2x2(x: &HostTensor, mode: PoolMode) -> HostTensor {
    HostTensor::from_fn(pooled(x.width), pooled(x.height), x.channels, |ox, oy, c| {
        let mut vals = Vec::new();
        for y in 2 * oy..(2 * oy + 2).min(x.height) {
            for xx in 2 * ox..(2 * ox + 2).min(x.width) {
                vals.push(x.at(xx, y, c));
            }
        }
        match mode {
            PoolMode::Max => vals.iter().cloned().fold(f32::NEG_INFINITY, f32::max),
            PoolMode::Average => vals.iter().sum::<f32>() / vals.len() as f32,
        }
    })
}

/// 2x upsampling to `out_w x out_h` (PyTorch `align_corners=False` for bilinear).
pub fn upsample2x(x: &HostTensor, mode: UpsampleMode, out_w: u32, out_h: u32) -> HostTensor {
    HostTensor::from_fn(out_w, out_h, x.channels, |ox, oy, c| match mode {
        UpsampleMode::Nearest => x.at((ox / 2).min(x.width - 1), (oy / 2).min(x.height - 1), c),
        UpsampleMode::Bilinear => {
            let src = |o: u32, n: u32| {
                let f = ((o as f32 + 0.5) * 0.5 - 0.5).max(0.0);
                let i0 = (f.floor() as u32).min(n - 1);
                let i1 = (i0 + 1).min(n - 1);
                (i0, i1, f - i0 as f32)
            };
            let (x0, x1, tx) = src(ox, x.width);
            let (y0, y1, ty) = src(oy, x.height);
            let top = x.at(x0, y0, c) * (1.0 - tx) + x.at(x1, y0, c) * tx;
            let bot = x.at(x0, y1, c) * (1.0 - tx) + x.at(x1, y1, c) * tx;
            top * (1.0 - ty) + bot * ty
        }
    })
}

/// Backward bilinear warp at `pos + motion`; returns (warped, validity).
pub fn warp(src: &HostTensor, motion: &HostTensor) -> (HostTensor, HostTensor) {
    let (w, h) = (src.width, src.height);
    let mut out = HostTensor::zeros(w, h, src.channels);
    let mut valid = HostTensor::zeros(w, h, 1);
    for y in 0..h {
        for x in 0..w {
            let (mx, my) = (motion.at(x, y, 0), motion.at(x, y, 1));
            let (px, py) = (x as f32 + 0.5 + mx, y as f32 + 0.5 + my);
            let ok =
                mx.is_finite() && my.is_finite() && px >= 0.0 && py >= 0.0 && px < w as f32 && py < h as f32;
            if !ok {
                continue;
            }
            valid.set(x, y, 0, 1.0);
            let (sx, sy) = (px - 0.5, py - 0.5);
            let (fx, fy) = (sx.floor(), sy.floor());
            let (tx, ty) = (sx - fx, sy - fy);
            let cl = |v: f32, n: u32| v.clamp(0.0, (n - 1) as f32) as u32;
            let (x0, x1, y0, y1) = (cl(fx, w), cl(fx + 1.0, w), cl(fy, h), cl(fy + 1.0, h));
            for c in 0..src.channels {
                let top = src.at(x0, y0, c) * (1.0 - tx) + src.at(x1, y0, c) * tx;
                let bot = src.at(x0, y1, c) * (1.0 - tx) + src.at(x1, y1, c) * tx;
                out.set(x, y, c, top * (1.0 - ty) + bot * ty);
            }
        }
    }
    (out, valid)
}

/// TFA blend: returns (blended, weights = (beta, alpha, s_cur, s_prev)).
pub fn tfa_blend(
    r: &HostTensor,
    e_cur: &HostTensor,
    e_prev: &HostTensor,
    cur: &HostTensor,
    prev: &HostTensor,
    valid: &HostTensor,
) -> (HostTensor, HostTensor) {
    let (w, h) = (cur.width, cur.height);
    let mut out = HostTensor::zeros(w, h, cur.channels);
    let mut weights = HostTensor::zeros(w, h, 4);
    for y in 0..h {
        for x in 0..w {
            let (mut sc, mut sp) = (0.0f64, 0.0f64);
            for k in 0..r.channels {
                sc += e_cur.at(x, y, k) as f64 * r.at(x, y, k) as f64;
                sp += e_prev.at(x, y, k) as f64 * r.at(x, y, k) as f64;
            }
            let (beta, alpha) = if valid.at(x, y, 0) > 0.5 {
                let m = sc.max(sp);
                let (a, b) = ((sp - m).exp(), (sc - m).exp());
                (b / (a + b), a / (a + b))
            } else {
                (1.0, 0.0)
            };
            for c in 0..cur.channels {
                let v = alpha * prev.at(x, y, c) as f64 + beta * cur.at(x, y, c) as f64;
                out.set(x, y, c, v as f32);
            }
            for (c, v) in [beta, alpha, sc, sp].into_iter().enumerate() {
                weights.set(x, y, c as u32, v as f32);
            }
        }
    }
    (out, weights)
}

/// The demodulation epsilon of DESIGN §3.
pub const ALBEDO_EPS: f32 = 0.00316;

fn clean(v: f32) -> f32 {
    if v.is_finite() && v >= 0.0 { v } else { 0.0 }
}

/// `ln(1 + color / (albedo + eps))` on the first 3 channels of `color` and channels
/// `albedo_channel..+3` of `albedo`.
pub fn demodulate(color: &HostTensor, albedo: &HostTensor, albedo_channel: u32) -> HostTensor {
    HostTensor::from_fn(color.width, color.height, 3, |x, y, c| {
        (1.0 + clean(color.at(x, y, c)) / (clean(albedo.at(x, y, albedo_channel + c)) + ALBEDO_EPS)).ln()
    })
}

/// `o` capped at `ln(1 + gain m_c / scale_c)` on its first 3 channels (the SSR output
/// ceiling; `m` the running max of the demodulated samples, `scale` the colour exposure).
pub fn ceiling(o: &HostTensor, gain: f32, m: [f32; 3], scale: [f32; 3]) -> HostTensor {
    HostTensor::from_fn(o.width, o.height, 3, |x, y, c| {
        let c = c as usize;
        o.at(x, y, c as u32).min((1.0 + gain * m[c] / scale[c]).ln())
    })
}

/// `max(exp(o) - 1, 0) * (albedo + eps) * scale` on the first 3 channels of `o` and channels
/// `albedo_channel..+3` of `albedo`.
pub fn remodulate(o: &HostTensor, albedo: &HostTensor, albedo_channel: u32, scale: [f32; 3]) -> HostTensor {
    HostTensor::from_fn(o.width, o.height, 3, |x, y, c| {
        (o.at(x, y, c).exp() - 1.0).max(0.0)
            * (albedo.at(x, y, albedo_channel + c).max(0.0) + ALBEDO_EPS)
            * scale[c as usize]
    })
}

/// One frame's sums of the SSR mean correction (`wgsl/ssr/tile_means.wgsl`): per tile of
/// `tile x tile` pixels, over the pixels whose `mask` (channel 0) is above 1/2, the sum of
/// `sample` (the traced sample minus the background) and of `part` (the reconstruction's
/// share, `(1 - coverage) x output`), each `W x H x 3`. Returns `tiles_x x tiles_y x 6`:
/// the samples' sums, then the reconstruction's (accumulated in f64).
pub fn mean_tile_sums(part: &HostTensor, sample: &HostTensor, mask: &HostTensor, tile: u32) -> HostTensor {
    let (tx, ty) = (part.width.div_ceil(tile), part.height.div_ceil(tile));
    let mut sums = vec![0f64; (tx * ty * 6) as usize];
    for y in 0..part.height {
        for x in 0..part.width {
            if mask.at(x, y, 0) <= 0.5 {
                continue;
            }
            let t = ((y / tile) * tx + x / tile) as usize * 6;
            for c in 0..3 {
                sums[t + c as usize] += sample.at(x, y, c) as f64;
                sums[t + 3 + c as usize] += part.at(x, y, c) as f64;
            }
        }
    }
    HostTensor::from_fn(tx, ty, 6, |x, y, c| sums[((y * tx + x) * 6 + c) as usize] as f32)
}

/// The mean correction's factors from the sums of [`mean_tile_sums`] over some frames: per
/// tile and channel `clamp((sum s + eps) / (sum r + eps), lo, hi)`, `tiles_x x tiles_y x 3`.
pub fn mean_tile_factors(frames: &[HostTensor], eps: f32, lo: f32, hi: f32) -> HostTensor {
    let (tx, ty) = (frames[0].width, frames[0].height);
    HostTensor::from_fn(tx, ty, 3, |x, y, c| {
        let s: f64 = frames.iter().map(|f| f.at(x, y, c) as f64).sum();
        let r: f64 = frames.iter().map(|f| f.at(x, y, c + 3) as f64).sum();
        (((s + eps as f64) / (r + eps as f64)) as f32).clamp(lo, hi)
    })
}

/// One frame's own per-pixel values of the `"atrous"` mean correction
/// (`wgsl/ssr/mean_history.wgsl`): at the pixels whose `mask` is above 1/2, `sample` (the
/// traced sample minus the background) and `part` (`(1 - coverage) x output`), 0 elsewhere;
/// `W x H x 6`, samples first.
pub fn mean_pixel_sums(part: &HostTensor, sample: &HostTensor, mask: &HostTensor) -> HostTensor {
    HostTensor::from_fn(part.width, part.height, 6, |x, y, c| {
        if mask.at(x, y, 0) <= 0.5 {
            0.0
        } else if c < 3 {
            sample.at(x, y, c)
        } else {
            part.at(x, y, c - 3)
        }
    })
}

/// The `"atrous"` mean correction's sums of a frame (`wgsl/ssr/mean_history.wgsl`): its own
/// [`mean_pixel_sums`] plus, unless it is the first after a reset (`prev` none), the last
/// frame's sums warped to it ([`warp`] by `motion`, invalid history 0) times `decay`.
pub fn mean_history_sums(
    own: &HostTensor,
    prev: Option<&HostTensor>,
    motion: &HostTensor,
    decay: f32,
) -> HostTensor {
    let Some(prev) = prev else {
        return own.clone();
    };
    let (warped, _) = warp(prev, motion);
    HostTensor::from_fn(own.width, own.height, own.channels, |x, y, c| {
        own.at(x, y, c) + decay * warped.at(x, y, c)
    })
}

/// The `"atrous"` mean correction's factors (`wgsl/ssr/mean_atrous.wgsl`), `W x H x 3`: the
/// frame's sums ([`mean_history_sums`], `W x H x 6`) filtered by `levels` levels of the edge-aware
/// a-trous filter (level `l`: 5 x 5 taps `2^l` pixels apart, B-spline weights
/// `(1, 4, 6, 4, 1) / 16` per axis times `max(n . n_q, 0)^(2^squarings)` times
/// `exp(-|z - z_q| / max(z, z_q, 1e-4) / depth_sigma)` against the centre's `normal`
/// (`W x H x 3`) and `depth` (`W x H x 1`), taps outside the frame left out, normalised by
/// the weights' sum, at least 1e-12), then per channel `clamp((S + eps) / (R + eps), lo,
/// hi)`. In f64.
#[allow(clippy::too_many_arguments)]
pub fn mean_atrous_factors(
    sums: &HostTensor,
    normal: &HostTensor,
    depth: &HostTensor,
    levels: u32,
    squarings: u32,
    depth_sigma: f32,
    eps: f32,
    lo: f32,
    hi: f32,
) -> HostTensor {
    let (w, h) = (normal.width as i64, normal.height as i64);
    let at = |x: i64, y: i64| (y * w + x) as usize;
    let mut vals: Vec<[f64; 6]> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            std::array::from_fn(|c| sums.at(x, y, c as u32) as f64)
        })
        .collect();
    let taps = [1.0 / 16.0, 0.25, 0.375, 0.25, 1.0 / 16.0];
    let n = |x: i64, y: i64| -> [f64; 3] {
        std::array::from_fn(|c| normal.at(x as u32, y as u32, c as u32) as f64)
    };
    let z = |x: i64, y: i64| depth.at(x as u32, y as u32, 0) as f64;
    for level in 0..levels {
        let step = 1i64 << level;
        let mut next = vec![[0f64; 6]; vals.len()];
        for y in 0..h {
            for x in 0..w {
                let (np, zp) = (n(x, y), z(x, y));
                let (mut acc, mut wsum) = ([0f64; 6], 0f64);
                for (j, ty) in taps.iter().enumerate() {
                    for (i, tx) in taps.iter().enumerate() {
                        let (qx, qy) = (x + (i as i64 - 2) * step, y + (j as i64 - 2) * step);
                        if qx < 0 || qy < 0 || qx >= w || qy >= h {
                            continue;
                        }
                        let nq = n(qx, qy);
                        let mut c = (np[0] * nq[0] + np[1] * nq[1] + np[2] * nq[2]).max(0.0);
                        for _ in 0..squarings {
                            c *= c;
                        }
                        let zq = z(qx, qy);
                        let rel = (zp - zq).abs() / zp.max(zq).max(1e-4);
                        let wt = ty * tx * c * (-rel / depth_sigma as f64).exp();
                        for (a, v) in acc.iter_mut().zip(vals[at(qx, qy)]) {
                            *a += wt * v;
                        }
                        wsum += wt;
                    }
                }
                let norm = 1.0 / wsum.max(1e-12);
                next[at(x, y)] = acc.map(|a| a * norm);
            }
        }
        vals = next;
    }
    HostTensor::from_fn(normal.width, normal.height, 3, |x, y, c| {
        let v = vals[at(x as i64, y as i64)];
        let (s, r) = (v[c as usize], v[c as usize + 3]);
        (((s + eps as f64) / (r + eps as f64)) as f32).clamp(lo, hi)
    })
}

/// The factor of pixel (x, y), channel c: the tiles' `factors` interpolated bilinearly
/// between tile centres (`tile x tile` tiles; beyond the outer centres the edge is held).
pub fn mean_factor_at(factors: &HostTensor, tile: u32, x: u32, y: u32, c: u32) -> f32 {
    let lerp = |p: u32, n: u32| {
        let t = (p as f32 + 0.5) / tile as f32 - 0.5;
        let i0 = t.floor().clamp(0.0, (n - 1) as f32);
        (i0 as u32, (i0 as u32 + 1).min(n - 1), (t - i0).clamp(0.0, 1.0))
    };
    let (x0, x1, fx) = lerp(x, factors.width);
    let (y0, y1, fy) = lerp(y, factors.height);
    let row = |yy| factors.at(x0, yy, c) * (1.0 - fx) + factors.at(x1, yy, c) * fx;
    row(y0) * (1.0 - fy) + row(y1) * fy
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `"atrous"` correction's filter averages within a surface: where two surfaces meet
    /// at a right angle (orthogonal normals, weight 0 between them), scaling one surface's
    /// samples changes none of the other's factors, however near the seam; and on a frame
    /// of one plane whose samples are everywhere 1.25 times the reconstruction, every factor
    /// is 1.25.
    #[test]
    fn atrous_factors_stay_on_their_surface() {
        let (w, h) = (40, 24);
        let left = |x: u32| x < 17;
        let normal = HostTensor::from_fn(w, h, 3, |x, _, c| {
            let n = if left(x) { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] };
            n[c as usize]
        });
        let depth = HostTensor::from_fn(w, h, 1, |x, y, _| 0.3 + 0.001 * (x + y) as f32);
        let mask = HostTensor::from_fn(w, h, 1, |x, y, _| ((x + 3 * y) % 4 == 0) as u32 as f32);
        let part = HostTensor::from_fn(w, h, 3, |x, y, c| 0.5 + 0.01 * ((x * 7 + y * 3 + c) % 11) as f32);
        let sample = |right_gain: f32| {
            HostTensor::from_fn(w, h, 3, |x, y, c| {
                let s = part.at(x, y, c) * (1.0 + 0.3 * (((x * 5 + y * 11 + c) % 7) as f32 / 6.0 - 0.5));
                if left(x) { s } else { s * right_gain }
            })
        };
        let factors = |gain: f32| {
            let sums = mean_pixel_sums(&part, &sample(gain), &mask);
            mean_atrous_factors(&sums, &normal, &depth, 5, 3, 0.2, 1e-6, 0.67, 1.5)
        };
        let (a, b) = (factors(1.0), factors(1.2));
        let mut right_changed = 0;
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    if left(x) {
                        assert_eq!(a.at(x, y, c), b.at(x, y, c), "left pixel ({x}, {y}) channel {c}");
                    } else if (b.at(x, y, c) / a.at(x, y, c) - 1.2).abs() < 1e-4 {
                        right_changed += 1;
                    }
                }
            }
        }
        assert_eq!(
            right_changed,
            ((w - 17) * h * 3) as usize,
            "the right surface follows its samples"
        );
        let flat = HostTensor::from_fn(w, h, 3, |_, _, c| [0.0, 0.0, 1.0][c as usize]);
        let brighter = HostTensor::from_fn(w, h, 3, |x, y, c| 1.25 * part.at(x, y, c));
        let f = mean_atrous_factors(
            &mean_pixel_sums(&part, &brighter, &mask),
            &flat,
            &depth,
            5,
            3,
            0.2,
            1e-6,
            0.67,
            1.5,
        );
        assert!(
            f.data.iter().all(|v| (v - 1.25).abs() < 1e-5),
            "factors {:?}",
            &f.data[..6]
        );
    }
}
