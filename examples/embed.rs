//! Minimal embedding of the SSR denoiser in your own wgpu program: your device, your
//! buffers, one `denoise` call per frame recorded into your command encoder.
//!
//! ```sh
//! cargo run --release --example embed [-- WEIGHTS.safetensors]
//! ```
//!
//! It fills the six input buffers of the data contract with a synthetic 1/4-spp frame of a
//! lit gradient (and, for a model that draws the directly seen emission itself, as the
//! shipped one does, the background and emission buffers: no sky and no light in view),
//! denoises 4 frames and prints the mean of the output.

use subpixel::ssr::{Denoiser, FrameInputs, Weights};

fn main() -> anyhow::Result<()> {
    // 1. Your renderer's device (here: the default adapter).
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))?;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("my renderer"),
        required_limits: adapter.limits(),
        ..Default::default()
    }))?;

    // 2. Weights: trained ones if given/shipped, else the random test weights (not a denoiser).
    let path = std::env::args().nth(1).unwrap_or_else(|| {
        let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/weights/ssr.safetensors");
        if std::path::Path::new(shipped).exists() {
            shipped.to_string()
        } else {
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/data/golden_weights.safetensors"
            )
            .to_string()
        }
    });
    let weights = Weights::load(&path)?;
    if weights.is_random_init() {
        println!("note: {path} holds random test weights; the output shows the plumbing, not denoising");
    }

    // 3. Your frame buffers: W*H vec4<f32> each, with STORAGE usage.
    let (w, h) = (64u32, 48u32);
    let buf = |label: &str| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (w * h * 16) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    };
    // The six of `FrameInputs::NAMES`; a model of config emission "background" (the shipped
    // one) also takes the background (environment seen directly, coverage) and the directly
    // seen emission, and wants the colour without the emission of what the camera sees
    // directly: here there is none, so those two stay zero.
    let bufs: Vec<wgpu::Buffer> = weights.config.input_names()?.iter().map(|n| buf(n)).collect();
    let mut denoiser = Denoiser::new(&device, &queue, &weights, w, h)?;

    for t in 0..4u32 {
        // Your renderer would write these on the GPU; here they are uploaded.
        let (dx, dy) = [(0, 0), (1, 1), (1, 0), (0, 1)][t as usize % 4];
        let mut data: [Vec<[f32; 4]>; 6] = Default::default();
        for y in 0..h {
            for x in 0..w {
                let traced = x % 2 == dx && y % 2 == dy;
                let radiance = x as f32 / w as f32 * 2.0;
                let m = traced as u32 as f32;
                data[0].push([radiance * m * 0.8, radiance * m * 0.6, radiance * m * 0.4, m]);
                // albedo + depth (a model of config albedo "footprint", the shipped one, wants
                // the albedo averaged over each pixel's footprint: uniform here)
                data[1].push([0.8, 0.6, 0.4, 0.5]);
                data[2].push([0.0, 0.0, 1.0, 0.0]);
                data[3].push([m, m, m, 0.7]);
                data[4].push([0.0; 4]);
                data[5].push([0.0; 4]);
            }
        }
        for (b, d) in bufs.iter().zip(&data) {
            queue.write_buffer(b, 0, bytemuck::cast_slice(d));
        }
        let mut encoder = device.create_command_encoder(&Default::default());
        let inputs = FrameInputs::from_slice(&bufs)?;
        // 4. One call per frame; the output texture is rgba32float linear radiance.
        let _output: &wgpu::Texture = denoiser.denoise(&mut encoder, &inputs)?;
        queue.submit([encoder.finish()]);
    }
    let out = denoiser.read_output()?;
    let mean: f32 = out.data.iter().sum::<f32>() / out.data.len() as f32;
    println!(
        "denoised {} frames of {w}x{h}; mean output radiance {mean:.4}",
        denoiser.frames()
    );
    println!(
        "non-finite input values sanitised: {}",
        denoiser.sanitized_count()?
    );
    Ok(())
}
