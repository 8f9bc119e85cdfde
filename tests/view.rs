//! The display kernel against its CPU reference: every mode, split screen and text overlay.

mod common;

use subpixel::nn::Tensor;
use subpixel::view::{Display, DisplayMode, View, reference_pixel};

#[test]
fn display_matches_reference() {
    let g = common::gpu();
    let a = common::random(1, 13, 9, 15, -1.0, 4.0);
    let b = common::random(2, 13, 9, 15, -1.0, 4.0);
    let (ta, tb) = (
        Tensor::from_host(&g, "a", &a).unwrap(),
        Tensor::from_host(&g, "b", &b).unwrap(),
    );
    let (w, h) = (37, 21);
    let disp = Display::new(&g, w, h).unwrap();
    let views = [
        View::default(),
        View {
            mode: DisplayMode::Signed(0.5),
            first: 6,
            channels: 3,
            ..Default::default()
        },
        View {
            mode: DisplayMode::Unit,
            first: 12,
            channels: 1,
            split_x: Some(20),
            ..Default::default()
        },
        View {
            mode: DisplayMode::Signed(1.0),
            first: 13,
            channels: 2,
            ..Default::default()
        },
        View {
            text: vec!["FPS 60.0".into(), "tfa 1.2ms".into()],
            text_scale: 1,
            split_x: Some(5),
            ..Default::default()
        },
    ];
    // Every view of (a, b), then sources swapped: parameters are rewritten in place while
    // the sources stay, the bind group is rebuilt when they change.
    let cases = views
        .iter()
        .map(|v| (v, false))
        .chain([(&views[2], true), (&views[4], false)]);
    for (i, (v, swap)) in cases.enumerate() {
        let (ta, tb, a, b) = if swap {
            (&tb, &ta, &b, &a)
        } else {
            (&ta, &tb, &a, &b)
        };
        let mut enc = g.device.create_command_encoder(&Default::default());
        disp.draw(&mut enc, ta, Some(tb.into()), v).unwrap();
        g.queue.submit([enc.finish()]);
        let img = disp.read_rgba().unwrap();
        for y in 0..h {
            for x in 0..w {
                let want = reference_pixel(a, b, v, w, h, x, y);
                let got = img.get_pixel(x, y).0;
                for c in 0..3 {
                    // One 8-bit step: pow/exp differ in the last ulp between GPU and CPU.
                    assert!(
                        (got[c] as i32 - want[c] as i32).abs() <= 1,
                        "view {i} at ({x},{y}) ch {c}: gpu {got:?} cpu {want:?}"
                    );
                }
                assert_eq!(got[3], 255);
            }
        }
    }
    // Asking for channels the tensor does not have is an error, not garbage.
    let mut enc = g.device.create_command_encoder(&Default::default());
    let bad = View {
        first: 15,
        channels: 3,
        ..Default::default()
    };
    assert!(
        disp.draw(&mut enc, &ta, None, &bad)
            .unwrap_err()
            .to_string()
            .contains("channels 15..18")
    );
}

/// A texture source (the denoiser's output is one) against the same reference: the texture
/// on its own, and right of a tensor in split screen; its 4 channels bound the view.
#[test]
fn display_reads_textures() {
    let g = common::gpu();
    let (w, h) = (11, 7);
    let a = common::random(3, w, h, 4, -1.0, 4.0);
    let b = common::random(4, w, h, 4, 0.0, 8.0);
    let ta = Tensor::from_host(&g, "a", &a).unwrap();
    let tex = g.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("b"),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    g.queue.write_texture(
        tex.as_image_copy(),
        bytemuck::cast_slice(&b.data),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(w * 16),
            rows_per_image: None,
        },
        tex.size(),
    );
    let disp = Display::new(&g, 23, 15).unwrap();
    let views = [
        View::default(),
        View {
            mode: DisplayMode::Unit,
            first: 3,
            channels: 1,
            split_x: Some(9),
            ..Default::default()
        },
    ];
    for (i, v) in views.iter().enumerate() {
        let mut enc = g.device.create_command_encoder(&Default::default());
        if v.split_x.is_some() {
            disp.draw(&mut enc, &ta, Some((&tex).into()), v).unwrap();
        } else {
            disp.draw(&mut enc, &tex, None, v).unwrap();
        }
        g.queue.submit([enc.finish()]);
        let img = disp.read_rgba().unwrap();
        let left = if v.split_x.is_some() { &a } else { &b };
        for y in 0..15 {
            for x in 0..23 {
                let want = reference_pixel(left, &b, v, 23, 15, x, y);
                let got = img.get_pixel(x, y).0;
                for c in 0..3 {
                    assert!(
                        (got[c] as i32 - want[c] as i32).abs() <= 1,
                        "view {i} at ({x},{y}) ch {c}: gpu {got:?} cpu {want:?}"
                    );
                }
            }
        }
    }
    let mut enc = g.device.create_command_encoder(&Default::default());
    let beyond = View {
        first: 2,
        channels: 3,
        ..Default::default()
    };
    let e = disp.draw(&mut enc, &tex, None, &beyond).unwrap_err().to_string();
    assert!(e.contains("channels 2..5"), "{e}");
}
