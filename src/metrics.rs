//! Image quality metrics (DESIGN §7): PSNR and SSIM on tonemapped 8-bit images
//! (Uncharted 2 filmic, exposure 2, white point 11.2, then gamma 2.2), RMSE and relative
//! MSE on HDR, the temporal error, and the brightness error (image means on HDR).

use crate::nn::HostTensor;
use crate::nn::reference::warp;

const EXPOSURE: f32 = 2.0;
const WHITE: f32 = 11.2;

fn hable(x: f32) -> f32 {
    const A: f32 = 0.15;
    const B: f32 = 0.50;
    const C: f32 = 0.10;
    const D: f32 = 0.20;
    const E: f32 = 0.02;
    const F: f32 = 0.30;
    ((x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F)) - E / F
}

/// Uncharted 2 filmic tonemap + gamma 2.2 of one linear HDR value, in [0, 1].
/// Non-finite and negative values map to 0.
pub fn tonemap(v: f32) -> f32 {
    let v = if v.is_finite() { v.max(0.0) } else { 0.0 };
    let t = (hable(EXPOSURE * v) / hable(WHITE)).clamp(0.0, 1.0);
    t.powf(1.0 / 2.2)
}

/// [`tonemap`] quantised to 8 bits.
pub fn tonemap_u8(v: f32) -> u8 {
    (tonemap(v) * 255.0).round() as u8
}

fn tonemapped(t: &HostTensor) -> Vec<f64> {
    t.data.iter().map(|&v| tonemap_u8(v) as f64).collect()
}

fn same_shape(a: &HostTensor, b: &HostTensor) {
    assert_eq!(
        (a.width, a.height, a.channels),
        (b.width, b.height, b.channels),
        "metric on different shapes"
    );
}

/// PSNR (dB) of the tonemapped 8-bit images; `f64::INFINITY` when identical.
pub fn psnr(pred: &HostTensor, reference: &HostTensor) -> f64 {
    same_shape(pred, reference);
    let (p, r) = (tonemapped(pred), tonemapped(reference));
    let mse = p.iter().zip(&r).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / p.len() as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// SSIM (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03, L 255) of
/// the tonemapped 8-bit images, per channel over the valid window positions, averaged.
/// Images smaller than the window use a window of their size.
pub fn ssim(pred: &HostTensor, reference: &HostTensor) -> f64 {
    same_shape(pred, reference);
    let (p, r) = (tonemapped(pred), tonemapped(reference));
    let (w, h, c) = (pred.width as usize, pred.height as usize, pred.channels as usize);
    let win = 11.min(w).min(h);
    let sigma = 1.5;
    let half = (win as f64 - 1.0) / 2.0;
    let g: Vec<f64> = (0..win)
        .map(|i| (-((i as f64 - half).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let gs: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / gs).collect();
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let mut total = 0.0;
    let mut n = 0usize;
    for ch in 0..c {
        let at = |img: &Vec<f64>, x: usize, y: usize| img[(y * w + x) * c + ch];
        for y0 in 0..=h - win {
            for x0 in 0..=w - win {
                let (mut mp, mut mr, mut pp, mut rr, mut pr) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for (dy, gy) in g.iter().enumerate() {
                    for (dx, gx) in g.iter().enumerate() {
                        let wgt = gy * gx;
                        let (a, b) = (at(&p, x0 + dx, y0 + dy), at(&r, x0 + dx, y0 + dy));
                        mp += wgt * a;
                        mr += wgt * b;
                        pp += wgt * a * a;
                        rr += wgt * b * b;
                        pr += wgt * a * b;
                    }
                }
                let (vp, vr, cov) = (pp - mp * mp, rr - mr * mr, pr - mp * mr);
                total +=
                    ((2.0 * mp * mr + c1) * (2.0 * cov + c2)) / ((mp * mp + mr * mr + c1) * (vp + vr + c2));
                n += 1;
            }
        }
    }
    total / n as f64
}

/// Noise of a reference of `spp` samples: the [`psnr`] between the means of its two halves
/// of samples (`0 .. spp / 2` in `first_half`, the rest recovered from the full mean
/// `reference`). The full reference's own error to the converged image is about 6 dB lower
/// in MSE terms (half the variance of each half, and the halves' difference has twice it).
pub fn reference_halves_psnr(reference: &HostTensor, first_half: &HostTensor, spp: u32) -> f64 {
    let half = (spp / 2) as f32;
    let rest = spp as f32 - half;
    if half == 0.0 || rest <= 0.0 {
        return f64::NAN;
    }
    let mut second = reference.clone();
    for (o, a) in second.data.iter_mut().zip(&first_half.data) {
        *o = (spp as f32 * *o - half * a) / rest;
    }
    psnr(first_half, &second)
}

/// The mean of `f(p, r)` over the values `p` of `pred` and `r` of `reference` (same shape).
fn mean_of(pred: &HostTensor, reference: &HostTensor, f: impl Fn(f32, f32) -> f64) -> f64 {
    same_shape(pred, reference);
    let s: f64 = pred
        .data
        .iter()
        .zip(&reference.data)
        .map(|(&a, &b)| f(a, b))
        .sum();
    s / pred.data.len() as f64
}

/// Root mean squared error on HDR values.
pub fn rmse(pred: &HostTensor, reference: &HostTensor) -> f64 {
    mean_of(pred, reference, |a, b| ((a - b) as f64).powi(2)).sqrt()
}

/// Relative MSE on HDR values: mean of `(p - r)^2 / (r^2 + 0.01)`.
pub fn relmse(pred: &HostTensor, reference: &HostTensor) -> f64 {
    mean_of(pred, reference, |a, b| {
        ((a - b) as f64).powi(2) / ((b as f64).powi(2) + 0.01)
    })
}

/// Brightness error on HDR values: the largest over the RGB channels of `|ln(P_c / R_c)|`,
/// `P_c` and `R_c` the channel's sums over the image. 0 when the means agree; `ln 2` for an
/// image twice as bright, or half as bright, as the reference in its worst channel. A
/// channel that is black in the reference counts only if the prediction is not (then the
/// error is infinite).
pub fn brightness_error(pred: &HostTensor, reference: &HostTensor) -> f64 {
    same_shape(pred, reference);
    let c = pred.channels as usize;
    let (mut p, mut r) = ([0f64; 3], [0f64; 3]);
    for (a, b) in pred.data.chunks_exact(c).zip(reference.data.chunks_exact(c)) {
        for k in 0..c.min(3) {
            p[k] += a[k] as f64;
            r[k] += b[k] as f64;
        }
    }
    (0..c.min(3))
        .map(|k| match (p[k] > 0.0, r[k] > 0.0) {
            (_, true) => (p[k].max(f64::MIN_POSITIVE) / r[k]).ln().abs(),
            (false, false) => 0.0,
            (true, false) => f64::INFINITY,
        })
        .fold(0.0, f64::max)
}

/// Temporal error of frame t: the L1 difference, over pixels whose history is valid, between
/// the prediction's warped frame difference `p_t - W(p_{t-1})` and the reference's, on
/// tonemapped values in [0, 1]. `motion` is frame t's motion (2 channels).
pub fn temporal_error(
    pred: &HostTensor,
    pred_prev: &HostTensor,
    reference: &HostTensor,
    reference_prev: &HostTensor,
    motion: &HostTensor,
) -> f64 {
    same_shape(pred, reference);
    let tm = |t: &HostTensor| {
        HostTensor::from_vec(
            t.width,
            t.height,
            t.channels,
            t.data.iter().map(|&v| tonemap(v)).collect(),
        )
    };
    let (p, pp, r, rp) = (tm(pred), tm(pred_prev), tm(reference), tm(reference_prev));
    let (wp, valid) = warp(&pp, motion);
    let (wr, _) = warp(&rp, motion);
    let (mut s, mut n) = (0.0f64, 0usize);
    for y in 0..p.height {
        for x in 0..p.width {
            if valid.at(x, y, 0) == 0.0 {
                continue;
            }
            for c in 0..p.channels {
                let dp = p.at(x, y, c) - wp.at(x, y, c);
                let dr = r.at(x, y, c) - wr.at(x, y, c);
                s += (dp - dr).abs() as f64;
                n += 1;
            }
        }
    }
    if n == 0 { 0.0 } else { s / n as f64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tonemap_anchors() {
        assert!(tonemap(0.0) < 1e-3 && tonemap_u8(0.0) == 0);
        assert!((tonemap(1e9) - 1.0).abs() < 1e-3);
        assert_eq!(tonemap(f32::NAN), tonemap(0.0));
        // Hand-computed: hable(2)/hable(11.2) = 0.49292 -> ^(1/2.2) = 0.72502.
        let want = (hable(2.0) / hable(11.2)).powf(1.0 / 2.2);
        assert!(
            (tonemap(1.0) - want).abs() < 1e-6 && (want - 0.72502).abs() < 1e-4,
            "{want}"
        );
    }

    #[test]
    fn psnr_and_ssim_known_values() {
        let a = HostTensor::from_fn(16, 16, 3, |x, y, c| ((x + y + c) % 5) as f32 * 0.3);
        assert_eq!(psnr(&a, &a), f64::INFINITY);
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-12);
        // All-zero vs a constant that tonemaps to 128: MSE = 128^2 -> PSNR = 20 log10(255/128).
        let target = (0..10_000)
            .map(|i| i as f32 * 1e-4)
            .find(|&v| tonemap_u8(v) == 128)
            .unwrap();
        let z = HostTensor::zeros(16, 16, 3);
        let k = HostTensor::from_fn(16, 16, 3, |_, _, _| target);
        assert!((psnr(&z, &k) - 20.0 * (255.0f64 / 128.0).log10()).abs() < 1e-9);
        // SSIM of two different constants: luminance term only.
        let c1 = (0.01f64 * 255.0).powi(2);
        let want = c1 / (128.0f64 * 128.0 + c1);
        assert!((ssim(&z, &k) - want).abs() < 1e-9);
    }

    #[test]
    fn hdr_errors() {
        let a = HostTensor::from_vec(2, 1, 1, vec![1.0, 3.0]);
        let b = HostTensor::from_vec(2, 1, 1, vec![2.0, 3.0]);
        assert!((rmse(&a, &b) - (0.5f64).sqrt()).abs() < 1e-12);
        assert!((relmse(&a, &b) - 0.5 / 4.01).abs() < 1e-9);
    }

    #[test]
    fn brightness_error_is_the_worst_channels_log_ratio() {
        let r = HostTensor::from_vec(2, 1, 3, vec![1.0, 2.0, 0.0, 3.0, 2.0, 0.0]);
        // same means, other distribution: 0
        let moved = HostTensor::from_vec(2, 1, 3, vec![4.0, 0.0, 0.0, 0.0, 4.0, 0.0]);
        assert_eq!(brightness_error(&moved, &r), 0.0);
        // red 2x, green 0.75x: ln 2 (black blue in both counts 0)
        let p = HostTensor::from_vec(2, 1, 3, vec![2.0, 1.0, 0.0, 6.0, 2.0, 0.0]);
        assert!((brightness_error(&p, &r) - 2f64.ln()).abs() < 1e-12);
        let half = HostTensor::from_vec(2, 1, 3, vec![0.5, 1.0, 0.0, 1.5, 1.0, 0.0]);
        assert!((brightness_error(&half, &r) - 2f64.ln()).abs() < 1e-12);
        let lit = HostTensor::from_vec(2, 1, 3, vec![1.0, 2.0, 0.1, 3.0, 2.0, 0.0]);
        assert_eq!(brightness_error(&lit, &r), f64::INFINITY);
    }

    #[test]
    fn temporal_error_is_zero_for_matching_motion() {
        let f = |s: u32| HostTensor::from_fn(9, 7, 3, move |x, y, c| ((x + s) * 3 + y + c) as f32 * 0.1);
        let motion = HostTensor::from_fn(9, 7, 2, |_, _, c| if c == 0 { -1.0 } else { 0.0 });
        // The prediction equals the reference: zero temporal error whatever the motion.
        assert_eq!(temporal_error(&f(1), &f(0), &f(1), &f(0), &motion), 0.0);
        // A flickering prediction has a positive error.
        let flicker = HostTensor::from_fn(9, 7, 3, |x, y, c| f(1).at(x, y, c) + 0.5);
        assert!(temporal_error(&flicker, &f(0), &f(1), &f(0), &motion) > 0.01);
    }
}
