//! The SSR network on the WGSL kernels: layers uploaded once, activations allocated once
//! per resolution, dispatches built once per resolution and history parity, replayed
//! every frame.

use std::collections::BTreeMap;

use bytemuck::{Pod, Zeroable};

use super::config::{A_CHANNELS, ExposureMode, HistoryTest, MT_CHANNELS, RGB, RemodulationAlbedo, SsrConfig};
use super::weights::Weights;
use crate::error::{Error, Result};
use crate::gpu::{Dispatch, Gpu, Profiler, Specialisation};
use crate::nn::autotune::{self, KernelChoice};
use crate::nn::conv::ConvKernel;
use crate::nn::ops::{self, Conv3x3, PoolMode, TfaBlend};
use crate::nn::{HostTensor, Tensor};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct HistoryParams {
    width: u32,
    height: u32,
    rescale: u32,
    geometry: u32,
}

/// Workgroups of the exposure reduction's first pass (each strides over the pixels).
pub(super) fn exposure_groups(width: u32, height: u32) -> u32 {
    (width as u64 * height as u64).div_ceil(256).clamp(1, 256) as u32
}

/// How finely to time the network with a [`Profiler`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Granularity {
    /// One timestamp scope per stage (`tfa`, `unet`).
    Stage,
    /// One scope per layer (each conv, pool, warp, ... in its own pass).
    Layer,
}

/// One recorded step: its stage, its label and the dispatch.
#[derive(Debug)]
struct Step {
    stage: &'static str,
    label: String,
    dispatch: Dispatch,
}

/// The network at one padded resolution (a multiple of 4 in both dimensions).
pub struct Network {
    /// Its configuration.
    pub config: SsrConfig,
    /// Padded width.
    pub width: u32,
    /// Padded height.
    pub height: u32,
    convs: BTreeMap<String, Conv3x3>,
    tensors: BTreeMap<&'static str, Tensor>,
    /// Accumulated features A_acc, ping-pong by frame parity.
    a_acc: [Tensor; 2],
    /// Log-space outputs o, ping-pong by frame parity.
    o: [Tensor; 2],
    ones: Tensor,
    /// `[parity]` -> warps of the history (skipped on the first frame).
    warps: [Vec<Step>; 2],
    /// `[parity]` -> the rest of the network.
    steps: [Vec<Step>; 2],
    parity: usize,
}

/// Names of the intermediate tensors [`Network::tensor`] exposes.
pub const INTERMEDIATES: &[&str] = &[
    "exposure",
    "a_t",
    "mt",
    "motion",
    "warp_acc",
    "warp_valid",
    "ref_feat",
    "emb_cur",
    "emb_prev",
    "tfa_weights",
    "a_acc",
    "warp_out",
    "enc1",
    "enc2",
    "enc3",
    "i3",
    "i2",
    "o",
    "output",
];

impl Network {
    /// Uploads `weights` and allocates everything for a `width x height` padded image;
    /// each convolution runs on the kernel `choice` picks for its shape and resolution.
    pub fn new(gpu: &Gpu, weights: &Weights, width: u32, height: u32, choice: KernelChoice) -> Result<Self> {
        if width == 0 || height == 0 || !width.is_multiple_of(4) || !height.is_multiple_of(4) {
            return Err(Error::shape(
                "ssr network",
                format!("padded size {width}x{height} must be a non-zero multiple of 4"),
            ));
        }
        let config = weights.config.clone();
        config.validate()?;
        let mut convs = BTreeMap::new();
        for l in config.layers() {
            let (w, b) = weights.layer(&l.name)?;
            let mut conv = Conv3x3::new(gpu, &l.name, w, b, &l.inputs, l.cout, l.act)?;
            let (lw, lh) = (width >> l.level, height >> l.level);
            let kernel = autotune::choose(gpu, &conv, lw, lh, choice)?;
            conv.set_kernel(gpu, kernel)?;
            convs.insert(l.name.clone(), conv);
        }
        let [c1, c2, c3] = config.enc;
        let (h, k) = (config.tfa_hidden, config.k);
        let (w1, h1, w2, h2, w4, h4) = (width, height, width / 2, height / 2, width / 4, height / 4);
        let mut tensors = BTreeMap::new();
        let mut add = |name: &'static str, w, hh, c| -> Result<()> {
            tensors.insert(name, Tensor::new(gpu, name, w, hh, c)?);
            Ok(())
        };
        // Exposure of the colour (rgb) and of the shadow (rgb), and its ratio to the last
        // frame's; the reduction's partial sums (4 vec4 per workgroup).
        add("exposure", 1, 1, 2 * RGB)?;
        add("exposure_ratio", 1, 1, 2 * RGB)?;
        add("exposure_partials", exposure_groups(w1, h1), 1, 16)?;
        add("a_t", w1, h1, A_CHANNELS)?;
        add("mt", w1, h1, MT_CHANNELS)?;
        add("motion", w1, h1, 2)?;
        add("warp_acc", w1, h1, A_CHANNELS)?;
        add("warp_valid", w1, h1, 1)?;
        add("ref_hidden", w1, h1, h)?;
        add("ref_feat", w1, h1, k)?;
        add("emb_hidden_cur", w1, h1, h)?;
        add("emb_cur", w1, h1, k)?;
        add("emb_hidden_prev", w1, h1, h)?;
        add("emb_prev", w1, h1, k)?;
        add("tfa_weights", w1, h1, 4)?;
        add("warp_out", w1, h1, RGB)?;
        add("warp_out_valid", w1, h1, 1)?;
        add("wo2", w2, h2, RGB)?;
        add("wo4", w4, h4, RGB)?;
        add("enc1_hidden", w1, h1, c1)?;
        add("enc1", w1, h1, c1)?;
        add("pool1", w2, h2, c1)?;
        add("enc2_hidden", w2, h2, c2)?;
        add("enc2", w2, h2, c2)?;
        add("pool2", w4, h4, c2)?;
        add("enc3_hidden", w4, h4, c3)?;
        add("enc3", w4, h4, c3)?;
        add("dec3_hidden", w4, h4, c3)?;
        add("i3", w4, h4, RGB)?;
        add("up3", w2, h2, RGB)?;
        add("dec2_hidden", w2, h2, c2)?;
        add("i2", w2, h2, RGB)?;
        add("up2", w1, h1, RGB)?;
        add("dec1_hidden", w1, h1, c1)?;
        add("output", w1, h1, RGB)?;
        let a_acc = [
            Tensor::new(gpu, "a_acc.0", w1, h1, A_CHANNELS)?,
            Tensor::new(gpu, "a_acc.1", w1, h1, A_CHANNELS)?,
        ];
        let o = [
            Tensor::new(gpu, "o.0", w1, h1, RGB)?,
            Tensor::new(gpu, "o.1", w1, h1, RGB)?,
        ];
        let ones = Tensor::from_host(gpu, "ones", &HostTensor::from_fn(w1, h1, 1, |_, _, _| 1.0))?;
        // Without exposure normalisation (version-1 weights) the exposure is 1 for good.
        let unit = HostTensor::from_vec(1, 1, 2 * RGB, vec![1.0; 2 * RGB as usize]);
        tensors["exposure"].write(gpu, &unit)?;
        tensors["exposure_ratio"].write(gpu, &unit)?;
        let mut net = Self {
            config,
            width,
            height,
            convs,
            tensors,
            a_acc,
            o,
            ones,
            warps: [Vec::new(), Vec::new()],
            steps: [Vec::new(), Vec::new()],
            parity: 0,
        };
        for p in 0..2 {
            let (w, s) = net.build(gpu, p)?;
            net.warps[p] = w;
            net.steps[p] = s;
        }
        Ok(net)
    }

    /// Each convolution layer and the kernel it runs on.
    pub fn conv_kernels(&self) -> Vec<(&str, ConvKernel)> {
        self.convs.iter().map(|(n, c)| (n.as_str(), c.kernel())).collect()
    }

    fn t(&self, name: &str) -> &Tensor {
        &self.tensors[name]
    }

    fn build(&self, gpu: &Gpu, p: usize) -> Result<(Vec<Step>, Vec<Step>)> {
        let q = 1 - p;
        let t = |n: &str| self.t(n);
        let conv = |name: &str, inputs: &[&Tensor], out: &Tensor| self.convs[name].bind(gpu, inputs, out);
        let step = |stage, label: &str, dispatch| Step {
            stage,
            label: label.to_string(),
            dispatch,
        };
        let pool = self.config.pool_mode()?;
        let up = self.config.upsample_mode()?;
        let mut warps = vec![
            step(
                "tfa",
                "warp A_acc",
                ops::warp(gpu, &self.a_acc[q], t("motion"), t("warp_acc"), t("warp_valid"))?,
            ),
            step(
                "tfa",
                "warp o",
                ops::warp(gpu, &self.o[q], t("motion"), t("warp_out"), t("warp_out_valid"))?,
            ),
        ];
        let rescale = self.config.exposure_mode()? == ExposureMode::Channel;
        let geometry = self.config.history_test()? == HistoryTest::Geometry;
        if rescale || geometry {
            // Re-expose the history and reject what disagrees with this frame's geometry.
            let params = HistoryParams {
                width: self.width,
                height: self.height,
                rescale: rescale as u32,
                geometry: geometry as u32,
            };
            let d = gpu.kernels.dispatch(
                "ssr/history",
                &Specialisation::none(),
                bytemuck::bytes_of(&params),
                &[
                    &t("a_t").buffer,
                    &t("warp_acc").buffer,
                    &t("warp_out").buffer,
                    &t("warp_valid").buffer,
                    &t("exposure_ratio").buffer,
                ],
                [self.width.div_ceil(8), self.height.div_ceil(8), 1],
            )?;
            warps.push(step("tfa", "history", d));
        }
        let (a_t, mt) = (t("a_t"), t("mt"));
        let (albedo, albedo_channel) = match self.config.remodulation_albedo()? {
            RemodulationAlbedo::Current => (a_t, 3),
            RemodulationAlbedo::Accumulated => (&self.a_acc[p], 3),
        };
        let steps = vec![
            step(
                "tfa",
                "tfa.ref.0",
                conv("tfa.ref.0", &[a_t, mt], t("ref_hidden"))?,
            ),
            step(
                "tfa",
                "tfa.ref.2",
                conv("tfa.ref.2", &[t("ref_hidden")], t("ref_feat"))?,
            ),
            step(
                "tfa",
                "tfa.emb.0 (cur)",
                conv("tfa.emb.0", &[a_t], t("emb_hidden_cur"))?,
            ),
            step(
                "tfa",
                "tfa.emb.2 (cur)",
                conv("tfa.emb.2", &[t("emb_hidden_cur")], t("emb_cur"))?,
            ),
            step(
                "tfa",
                "tfa.emb.0 (prev)",
                conv("tfa.emb.0", &[t("warp_acc")], t("emb_hidden_prev"))?,
            ),
            step(
                "tfa",
                "tfa.emb.2 (prev)",
                conv("tfa.emb.2", &[t("emb_hidden_prev")], t("emb_prev"))?,
            ),
            step(
                "tfa",
                "tfa blend",
                ops::tfa_blend(
                    gpu,
                    TfaBlend {
                        r: t("ref_feat"),
                        e_cur: t("emb_cur"),
                        e_prev: t("emb_prev"),
                        cur: a_t,
                        prev: t("warp_acc"),
                        valid: t("warp_valid"),
                        out: &self.a_acc[p],
                        weights: t("tfa_weights"),
                    },
                )?,
            ),
            step(
                "unet",
                "pool W(o)/2",
                ops::pool2x2(gpu, PoolMode::Average, t("warp_out"), t("wo2"))?,
            ),
            step(
                "unet",
                "pool W(o)/4",
                ops::pool2x2(gpu, PoolMode::Average, t("wo2"), t("wo4"))?,
            ),
            step(
                "unet",
                "unet.enc1.0",
                conv(
                    "unet.enc1.0",
                    &[a_t, mt, &self.a_acc[p], t("warp_out")],
                    t("enc1_hidden"),
                )?,
            ),
            step(
                "unet",
                "unet.enc1.2",
                conv("unet.enc1.2", &[t("enc1_hidden")], t("enc1"))?,
            ),
            step(
                "unet",
                "pool enc1",
                ops::pool2x2(gpu, pool, t("enc1"), t("pool1"))?,
            ),
            step(
                "unet",
                "unet.enc2.0",
                conv("unet.enc2.0", &[t("pool1"), t("wo2")], t("enc2_hidden"))?,
            ),
            step(
                "unet",
                "unet.enc2.2",
                conv("unet.enc2.2", &[t("enc2_hidden")], t("enc2"))?,
            ),
            step(
                "unet",
                "pool enc2",
                ops::pool2x2(gpu, pool, t("enc2"), t("pool2"))?,
            ),
            step(
                "unet",
                "unet.enc3.0",
                conv("unet.enc3.0", &[t("pool2"), t("wo4")], t("enc3_hidden"))?,
            ),
            step(
                "unet",
                "unet.enc3.2",
                conv("unet.enc3.2", &[t("enc3_hidden")], t("enc3"))?,
            ),
            step(
                "unet",
                "unet.dec3.0",
                conv("unet.dec3.0", &[t("enc3"), t("wo4")], t("dec3_hidden"))?,
            ),
            step(
                "unet",
                "unet.dec3.2",
                conv("unet.dec3.2", &[t("dec3_hidden")], t("i3"))?,
            ),
            step(
                "unet",
                "upsample I3",
                ops::upsample2x(gpu, up, t("i3"), t("up3"))?,
            ),
            step(
                "unet",
                "unet.dec2.0",
                conv("unet.dec2.0", &[t("enc2"), t("up3"), t("wo2")], t("dec2_hidden"))?,
            ),
            step(
                "unet",
                "unet.dec2.2",
                conv("unet.dec2.2", &[t("dec2_hidden")], t("i2"))?,
            ),
            step(
                "unet",
                "upsample I2",
                ops::upsample2x(gpu, up, t("i2"), t("up2"))?,
            ),
            step(
                "unet",
                "unet.dec1.0",
                conv(
                    "unet.dec1.0",
                    &[t("enc1"), t("up2"), t("warp_out")],
                    t("dec1_hidden"),
                )?,
            ),
            step(
                "unet",
                "unet.dec1.2",
                conv("unet.dec1.2", &[t("dec1_hidden")], &self.o[p])?,
            ),
            step(
                "unet",
                "remodulate",
                ops::remodulate(
                    gpu,
                    &self.o[p],
                    albedo,
                    albedo_channel,
                    t("exposure"),
                    t("output"),
                )?,
            ),
        ];
        Ok((warps, steps))
    }

    /// The packed input tensors the caller fills before [`Network::record`]:
    /// `(A_t, MT, motion)`.
    pub fn inputs(&self) -> (&Tensor, &Tensor, &Tensor) {
        (self.t("a_t"), self.t("mt"), self.t("motion"))
    }

    /// The exposure tensors the caller's exposure pass writes before [`Network::record`]
    /// (`ssr/exposure_partial`, `ssr/exposure_final`): `(partials, exposure, ratio)`.
    pub fn exposure(&self) -> (&Tensor, &Tensor, &Tensor) {
        (
            self.t("exposure_partials"),
            self.t("exposure"),
            self.t("exposure_ratio"),
        )
    }

    /// The remodulated output (padded size, 3 channels) of the last recorded frame.
    pub fn output(&self) -> &Tensor {
        self.t("output")
    }

    /// An intermediate tensor of the last recorded frame by name (see [`INTERMEDIATES`]).
    pub fn tensor(&self, name: &str) -> Option<&Tensor> {
        let cur = 1 - self.parity; // parity was advanced after recording
        match name {
            "a_acc" => Some(&self.a_acc[cur]),
            "o" => Some(&self.o[cur]),
            n => self.tensors.get(n),
        }
    }

    /// Records one frame. `first` means there is no history (first frame, camera cut,
    /// resize): the history is then the current frame itself (DESIGN §4) and W(o) is 0.
    /// Otherwise the history is warped, re-exposed and checked against this frame's
    /// geometry (`ssr/history`, version-2 configs) before the TFA.
    pub fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        first: bool,
        mut profiler: Option<&mut Profiler>,
        granularity: Granularity,
    ) {
        let p = self.parity;
        if first {
            let (a_t, warp_acc) = (self.t("a_t"), self.t("warp_acc"));
            encoder.copy_buffer_to_buffer(&a_t.buffer, 0, &warp_acc.buffer, 0, a_t.bytes());
            encoder.copy_buffer_to_buffer(
                &self.ones.buffer,
                0,
                &self.t("warp_valid").buffer,
                0,
                self.ones.bytes(),
            );
            encoder.clear_buffer(&self.t("warp_out").buffer, 0, None);
        }
        let warps = if first { &[][..] } else { &self.warps[p][..] };
        // Warps first (each belongs to its stage), then the rest in order.
        let mut ordered: Vec<&Step> = Vec::new();
        let steps = &self.steps[p];
        ordered.extend(warps.iter().filter(|s| s.stage == "tfa"));
        ordered.extend(steps.iter().filter(|s| s.stage == "tfa"));
        ordered.extend(warps.iter().filter(|s| s.stage == "unet"));
        ordered.extend(steps.iter().filter(|s| s.stage == "unet"));
        let mut i = 0;
        while i < ordered.len() {
            let j = match granularity {
                Granularity::Layer => i + 1,
                Granularity::Stage => {
                    let mut j = i;
                    while j < ordered.len() && ordered[j].stage == ordered[i].stage {
                        j += 1;
                    }
                    j
                }
            };
            let label = match granularity {
                Granularity::Layer => ordered[i].label.as_str(),
                Granularity::Stage => ordered[i].stage,
            };
            let mut pass = Profiler::pass(encoder, label, profiler.as_deref_mut());
            for s in &ordered[i..j] {
                s.dispatch.record(&mut pass);
            }
            drop(pass);
            i = j;
        }
        self.parity = 1 - p;
    }

    /// Every step in execution order (history warps included) with its stage, FLOPs per
    /// frame at this resolution (0 for data movement) and compulsory memory traffic.
    pub fn step_costs(&self) -> Vec<StepCost> {
        let levels: BTreeMap<String, u32> = self
            .config
            .layers()
            .into_iter()
            .map(|l| (l.name, l.level))
            .collect();
        let p = self.parity;
        let mut out = Vec::new();
        for stage in ["tfa", "unet"] {
            for s in self.warps[p]
                .iter()
                .chain(&self.steps[p])
                .filter(|s| s.stage == stage)
            {
                let name = s.label.split(' ').next().unwrap_or_default();
                let flops = match (self.convs.get(name), levels.get(name)) {
                    (Some(c), Some(&lv)) => {
                        c.flops_per_pixel() * (self.width as u64 >> lv) * (self.height as u64 >> lv)
                    }
                    _ => 0,
                };
                out.push(StepCost {
                    stage,
                    label: s.label.clone(),
                    flops,
                    bytes_read: s.dispatch.bytes_read,
                    bytes_written: s.dispatch.bytes_written,
                });
            }
        }
        out
    }
}

/// What one step of the network costs per frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepCost {
    /// Its stage (`tfa`, `unet`).
    pub stage: &'static str,
    /// Its label (layer name or operation).
    pub label: String,
    /// Floating-point operations (multiply and add counted separately; 0 for data movement).
    pub flops: u64,
    /// Bytes it reads, each tensor once (compulsory traffic).
    pub bytes_read: u64,
    /// Bytes it writes.
    pub bytes_written: u64,
}
