//! The SSR network on the WGSL kernels, built from its declaration in [`super::graph`]:
//! layers uploaded once, every [`TensorId`] allocated once per resolution, each step's
//! dispatch built once per resolution and history parity and replayed every frame.

use std::collections::BTreeMap;

use bytemuck::{Pod, Zeroable};

use super::config::{CEILING_GAIN, CeilingMode, LayerSpec, SsrConfig};
use super::graph::{self, Extent, Op, StepSpec, TensorId};
use super::shared_textures::{self, StepTextures, TextureSource};
use super::weights::Weights;
use crate::error::{Error, Result};
use crate::gpu::{Dispatch, Gpu, Grid, Profiler, time_dispatch};
use crate::nn::autotune::{self, EngineOptions, LayerStorage, Pooling, Precision};
use crate::nn::conv::{self, ConvKernel, InputTexture, TextureIo};
use crate::nn::ops::{self, Conv3x3, Fetch, TfaBlend};
use crate::nn::{DType, HostTensor, Tensor};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct WarpHistoryParams {
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

/// The network at one padded resolution (a multiple of [`SsrConfig::pad_multiple`] in both
/// dimensions), built from
/// the declaration in [`super::graph`].
pub struct Network {
    /// Its configuration.
    pub config: SsrConfig,
    /// Padded width.
    pub width: u32,
    /// Padded height.
    pub height: u32,
    convs: BTreeMap<String, Conv3x3>,
    tensors: BTreeMap<TensorId, Tensor>,
    /// Accumulated features A_acc, ping-pong by frame parity.
    a_acc: [Tensor; 2],
    /// Log-space outputs o, ping-pong by frame parity.
    o: [Tensor; 2],
    ones: Tensor,
    /// The first frame's copy of A_t into W(A_acc) where the two are stored differently (f32
    /// and f16 with f16 activations), else `None` (a buffer copy).
    first_copy: Option<Dispatch>,
    /// The steps of a frame, in execution order.
    specs: Vec<StepSpec>,
    /// Each tensor's stored tensor and how steps read it ([`TensorId::stored`]).
    stored: Stored,
    /// Storage of the interior activations ([`TensorId::may_store_f16`]).
    activations: DType,
    /// The texture arrays of the tensors several convolutions read as textures, or one
    /// produces for them ([`shared_textures::plan`]).
    textures: BTreeMap<TensorId, conv::ActivationTexture>,
    /// Per step, the shared textures it fills, reads or stores to.
    step_textures: Vec<StepTextures>,
    /// `[parity][step]` -> its dispatch.
    dispatches: [Vec<Dispatch>; 2],
    parity: usize,
}

/// Names of the intermediate tensors [`Network::tensor`] exposes.
pub const INTERMEDIATES: &[&str] = &[
    "exposure",
    "a_cur",
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
    "enc4",
    "i4",
    "i3",
    "i2",
    "o",
    "output",
];

/// The storage of layer `name`'s tensors in the first step that runs it when the interior
/// activations are `dtype`: what the autotuner times. (The graph gives a layer the same
/// output storage in every step; `tfa.emb.0` reads A_t in one and W(A_acc) in the other,
/// which may differ, and runs the same kernel specialised to each.)
fn layer_storage(specs: &[StepSpec], name: &str, dtype: DType) -> LayerStorage {
    let s = specs
        .iter()
        .find(|s| matches!(s.op, Op::Conv(n) if n == name))
        .expect("every layer runs in a step");
    let of = |id: &TensorId| if id.may_store_f16() { dtype } else { DType::F32 };
    let (out, ins) = s.tensors.split_last().expect("a convolution has an output");
    LayerStorage {
        inputs: ins.iter().map(of).collect(),
        output: of(out),
    }
}

/// The interior activations' storage under `precision`: for [`Precision::Auto`], f16 when
/// the device has SHADER_F16 and the tuned times of a frame's layer runs (each layer at
/// its `size`) are lower with it (the layers tuned as `options.kernels` says: among its
/// kernels for `KernelChoice::Among`, else among all).
fn activation_storage(
    gpu: &Gpu,
    specs: &[StepSpec],
    layers: &[LayerSpec],
    convs: &BTreeMap<String, Conv3x3>,
    options: EngineOptions,
    size: impl Fn(&LayerSpec) -> (u32, u32),
) -> Result<DType> {
    let among = options.kernels.resolve()?.among();
    Ok(match options.precision.resolve()? {
        Precision::F16 => {
            gpu.require(wgpu::Features::SHADER_F16, "f16 activations")?;
            DType::F16
        }
        Precision::Auto if gpu.has(wgpu::Features::SHADER_F16) => {
            let mut total = [0.0f64; 2];
            for (i, dtype) in [DType::F32, DType::F16].into_iter().enumerate() {
                for l in layers {
                    let (lw, lh) = size(l);
                    let storage = layer_storage(specs, &l.name, dtype);
                    total[i] +=
                        autotune::tuned_ms(gpu, &convs[&l.name], lw, lh, &storage, among)? * l.runs as f64;
                }
            }
            log::info!(
                "activations: tuned layers {:.2} ms with f32, {:.2} ms with f16 storage",
                total[0],
                total[1]
            );
            if total[1] < total[0] {
                DType::F16
            } else {
                DType::F32
            }
        }
        _ => DType::F32,
    })
}

/// Where each tensor of the graph is stored and how it is read ([`TensorId::stored`]).
type Stored = BTreeMap<TensorId, (TensorId, Fetch)>;

/// The steps of a frame with or without pooling passes, where each tensor is stored, and
/// each convolution set to read its inputs accordingly (resampled on load for views; one
/// step per layer is enough: the graph gives a layer the same inputs in every step that
/// runs it, up to history).
fn graph_with(
    config: &SsrConfig,
    pool_pass: bool,
    convs: &mut BTreeMap<String, Conv3x3>,
) -> Result<(Vec<StepSpec>, Stored)> {
    let specs = graph::steps(config, pool_pass)?;
    let stored: Stored = TensorId::ALL
        .iter()
        .map(|&id| Ok((id, id.stored(config, pool_pass)?)))
        .collect::<Result<_>>()?;
    for s in &specs {
        if let Op::Conv(layer) = s.op {
            let (_, ins) = s.tensors.split_last().expect("a convolution has an output");
            let fetch: Vec<Fetch> = ins.iter().map(|id| stored[id].1).collect();
            convs
                .get_mut(layer)
                .expect("every layer is built")
                .set_fetch(&fetch)?;
        }
    }
    Ok((specs, stored))
}

/// Whether the pooled encoder levels get pooling passes, as `pooling` resolves; for
/// [`Pooling::Auto`], whether the tuned times of the layers that read them (each at its
/// `size`, `runs` times a frame) with direct reads, plus the pooling passes timed here, are
/// lower than their tuned times pooling on load; with fixed kernels (`options.kernels`,
/// nothing tuned), on load. `specs` and `convs` read on load.
fn pool_pass(
    gpu: &Gpu,
    specs: &[StepSpec],
    layers: &[LayerSpec],
    convs: &mut BTreeMap<String, Conv3x3>,
    options: EngineOptions,
    dtype: DType,
    size: impl Fn(&LayerSpec) -> (u32, u32),
) -> Result<bool> {
    match options.pooling.resolve()? {
        Pooling::OnLoad => return Ok(false),
        Pooling::Pass => return Ok(true),
        _ if !options.measures()? => return Ok(false),
        _ => {}
    }
    let among = options.kernels.resolve()?.among();
    let (mut on_load, mut passes) = (0.0f64, 0.0f64);
    for l in layers {
        let conv = convs.get_mut(&l.name).expect("every layer is built");
        let fetch = conv.fetch().to_vec();
        if !fetch.iter().any(|f| matches!(f, Fetch::Pool(_))) {
            continue;
        }
        let (lw, lh) = size(l);
        let storage = layer_storage(specs, &l.name, dtype);
        on_load += autotune::tuned_ms(gpu, conv, lw, lh, &storage, among)? * l.runs as f64;
        let direct: Vec<Fetch> = fetch
            .iter()
            .map(|&f| {
                if matches!(f, Fetch::Pool(_)) {
                    Fetch::Direct
                } else {
                    f
                }
            })
            .collect();
        conv.set_fetch(&direct)?;
        let tuned = autotune::tuned_ms(gpu, conv, lw, lh, &storage, among);
        conv.set_fetch(&fetch)?;
        passes += tuned? * l.runs as f64;
        for (i, f) in fetch.iter().enumerate() {
            if let Fetch::Pool(mode) = *f {
                let (dtype, c) = (storage.inputs[i], l.inputs[i]);
                let key = format!("{} pool2x2 {mode:?} {lw}x{lh}x{c} {dtype:?}", gpu.describe());
                let ms = autotune::timed_once(key, || {
                    let input = Tensor::new_typed(gpu, "pooling.in", 2 * lw, 2 * lh, c, dtype)?;
                    let out = Tensor::new_typed(gpu, "pooling.out", lw, lh, c, dtype)?;
                    let d = ops::pool2x2(gpu, mode, &input, &out)?;
                    Ok(time_dispatch(gpu, &d, 1, autotune::TUNE_ITERATIONS)?.0.median_ms)
                })?;
                passes += ms * l.runs as f64;
            }
        }
    }
    log::info!(
        "pooled levels: their layers take {on_load:.3} ms pooling on load, {passes:.3} ms with pooling passes"
    );
    Ok(passes < on_load)
}

impl Network {
    /// Uploads `weights` and allocates everything for a `width x height` padded image;
    /// the interior activations are stored as `options.precision` resolves and each
    /// convolution runs on the kernel `options.kernels` picks for its shape, resolution
    /// and storage.
    pub fn new(
        gpu: &Gpu,
        weights: &Weights,
        width: u32,
        height: u32,
        options: EngineOptions,
    ) -> Result<Self> {
        let config = weights.config.clone();
        config.validate()?;
        let m = config.pad_multiple();
        if width == 0 || height == 0 || !width.is_multiple_of(m) || !height.is_multiple_of(m) {
            return Err(Error::shape(
                "ssr network",
                format!(
                    "padded size {width}x{height} must be a non-zero multiple of {m} (a {}-level U-Net)",
                    config.levels()
                ),
            ));
        }
        let layers = config.layers();
        let mut convs = BTreeMap::new();
        for l in &layers {
            let (w, b) = weights.layer(&l.name)?;
            convs.insert(
                l.name.clone(),
                Conv3x3::new(gpu, &l.name, w, b, &l.inputs, l.cout, l.act)?,
            );
        }
        // The graph with the pooled levels read on load first: the precision and the
        // pooling are chosen from it, then the graph is built as chosen.
        let (specs, stored) = graph_with(&config, false, &mut convs)?;
        let size = |l: &LayerSpec| (width >> l.level, height >> l.level);
        let activations = activation_storage(gpu, &specs, &layers, &convs, options, size)?;
        let pool_pass = pool_pass(gpu, &specs, &layers, &mut convs, options, activations, size)?;
        let (specs, stored) = if pool_pass {
            graph_with(&config, true, &mut convs)?
        } else {
            (specs, stored)
        };
        for l in &layers {
            let (lw, lh) = size(l);
            let conv = convs.get_mut(&l.name).expect("inserted above");
            let storage = layer_storage(&specs, &l.name, activations);
            conv.set_kernel(
                gpu,
                autotune::choose(gpu, conv, lw, lh, &storage, options.kernels)?,
            )?;
        }
        let dims = |id: TensorId| {
            let (extent, c) = id.shape(&config);
            let (w, h) = match extent {
                Extent::Level(l) => (width >> l, height >> l),
                Extent::Single => (1, 1),
                Extent::ExposureGroups => (exposure_groups(width, height), 1),
            };
            let dtype = if id.may_store_f16() {
                activations
            } else {
                DType::F32
            };
            (w, h, c, dtype)
        };
        let alloc = |id: TensorId, label: &str| {
            let (w, h, c, dtype) = dims(id);
            Tensor::new_typed(gpu, label, w, h, c, dtype)
        };
        // Lifetimes within a frame (first and last step using each tensor): a transient
        // tensor takes the memory of an earlier one of the same shape that is dead by then.
        let mut life: BTreeMap<TensorId, (usize, usize)> = BTreeMap::new();
        for (i, s) in specs.iter().enumerate() {
            for id in &s.tensors {
                let id = stored[id].0;
                life.entry(id).and_modify(|l| l.1 = i).or_insert((i, i));
            }
        }
        let mut tensors: BTreeMap<TensorId, Tensor> = BTreeMap::new();
        // Shared memory: (the tensor that owns it, last step of its current occupant).
        let mut slots: Vec<(TensorId, usize)> = Vec::new();
        let mut order: Vec<TensorId> = TensorId::ALL.to_vec();
        order.sort_by_key(|id| life.get(id).map_or(0, |l| l.0));
        for id in order {
            if matches!(
                id,
                TensorId::AAcc | TensorId::AAccPrev | TensorId::O | TensorId::OPrev
            ) || stored[&id].0 != id
                || !id.in_config(&config)
            {
                continue;
            }
            let transient = life.get(&id).copied().filter(|_| id.is_transient());
            let shared = transient.and_then(|(first, last)| {
                let slot = slots
                    .iter_mut()
                    .find(|(owner, free_after)| *free_after < first && dims(*owner) == dims(id))?;
                slot.1 = last;
                Some(slot.0)
            });
            let t = match shared {
                Some(owner) => tensors[&owner].share(),
                None => {
                    if let Some((_, last)) = transient {
                        slots.push((id, last));
                    }
                    alloc(id, id.name())?
                }
            };
            tensors.insert(id, t);
        }
        let a_acc = [
            alloc(TensorId::AAcc, "a_acc.0")?,
            alloc(TensorId::AAcc, "a_acc.1")?,
        ];
        let o = [alloc(TensorId::O, "o.0")?, alloc(TensorId::O, "o.1")?];
        // Each tensor convolutions read as a texture is copied once a frame, or stored by
        // the convolution producing it (as the kernels were chosen).
        let (step_textures, shared) =
            shared_textures::plan(&specs, |id| stored[&id].0, |layer| convs[layer].kernel());
        let ones = Tensor::from_host(gpu, "ones", &HostTensor::from_fn(width, height, 1, |_, _, _| 1.0))?;
        // Without exposure normalisation (version-1 weights) the exposure is 1 for good.
        for id in [TensorId::Exposure, TensorId::ExposureRatio] {
            let c = tensors[&id].channels;
            tensors[&id].write(gpu, &HostTensor::from_vec(1, 1, c, vec![1.0; c as usize]))?;
        }
        let mut net = Self {
            config,
            width,
            height,
            convs,
            tensors,
            a_acc,
            o,
            first_copy: None,
            ones,
            specs,
            stored,
            activations,
            textures: BTreeMap::new(),
            step_textures,
            dispatches: [Vec::new(), Vec::new()],
            parity: 0,
        };
        let (a_t, warp_acc) = (&net.tensors[&TensorId::ACur], &net.tensors[&TensorId::WarpAcc]);
        if a_t.dtype != warp_acc.dtype {
            net.first_copy = Some(ops::convert(gpu, a_t, warp_acc)?);
        }
        // A texture per shared tensor, the same for both parities: each is written and read
        // within a frame.
        for id in shared {
            let texture = conv::activation_texture(gpu, id.name(), net.at(id, 0))?;
            net.textures.insert(id, texture);
        }
        for p in 0..2 {
            net.dispatches[p] = net
                .specs
                .iter()
                .enumerate()
                .map(|(i, s)| net.bind(gpu, s, &net.step_textures[i], p))
                .collect::<Result<_>>()?;
        }
        Ok(net)
    }

    /// Storage of the interior activations (f32, or f16 under [`Precision::F16`] or a
    /// [`Precision::Auto`] that measured it faster).
    pub fn activations(&self) -> DType {
        self.activations
    }

    /// Each convolution layer and the kernel it runs on.
    pub fn conv_kernels(&self) -> Vec<(&str, ConvKernel)> {
        self.convs.iter().map(|(n, c)| (n.as_str(), c.kernel())).collect()
    }

    /// Tensor `id` when the frame of parity `p` is recorded.
    fn at(&self, id: TensorId, p: usize) -> &Tensor {
        match self.stored[&id].0 {
            TensorId::AAcc => &self.a_acc[p],
            TensorId::AAccPrev => &self.a_acc[1 - p],
            TensorId::O => &self.o[p],
            TensorId::OPrev => &self.o[1 - p],
            id => &self.tensors[&id],
        }
    }

    /// The dispatch of step `s` for the frame of parity `p`, with its shared textures `tex`.
    fn bind(&self, gpu: &Gpu, s: &StepSpec, tex: &StepTextures, p: usize) -> Result<Dispatch> {
        let t: Vec<&Tensor> = s.tensors.iter().map(|&id| self.at(id, p)).collect();
        match s.op {
            Op::Conv(layer) => {
                let (out, inputs) = t.split_last().expect("a convolution has an output");
                let io = TextureIo {
                    inputs: tex
                        .inputs
                        .iter()
                        .map(|a| {
                            a.map(|a| match a {
                                TextureSource::Fill(id) => InputTexture::Fill(&self.textures[&id].view),
                                TextureSource::Filled(id) => InputTexture::Filled(&self.textures[&id].view),
                            })
                        })
                        .collect(),
                    output: tex.output.map(|id| &self.textures[&id].view),
                };
                let conv = &self.convs[layer];
                conv.bind_textured(gpu, conv.kernel(), inputs, out, &io)
            }
            Op::WarpHistory { rescale, geometry } => {
                // The kernel's fixed layout: A tensors of 4 vec4, o and motion of 1.
                let expect = [4, 1, 1, 4, 2, 4, 1, 1];
                if let Some(k) = (0..8).find(|&k| t[k].c4() != expect[k]) {
                    return Err(Error::shape(
                        "ssr/warp_history",
                        format!(
                            "tensor {k} has {} vec4s per pixel, expected {}",
                            t[k].c4(),
                            expect[k]
                        ),
                    ));
                }
                let params = WarpHistoryParams {
                    width: self.width,
                    height: self.height,
                    rescale: rescale as u32,
                    geometry: geometry as u32,
                };
                // Last frame's A_acc and o, and W(A_acc), as stored; the others f32.
                ops::f32_only(
                    "ssr/warp_history",
                    &[
                        ("motion", t[2]),
                        ("a_cur", t[3]),
                        ("exposure_ratio", t[4]),
                        ("warp_out", t[6]),
                        ("warp_valid", t[7]),
                    ],
                )?;
                let buffers: Vec<&wgpu::Buffer> = t.iter().map(|x| &x.buffer).collect();
                gpu.kernels.dispatch(
                    "ssr/warp_history",
                    &ops::storage_flags(&[t[0], t[1]], Some(t[5])),
                    bytemuck::bytes_of(&params),
                    &buffers,
                    Grid::pixels(self.width, self.height),
                )
            }
            Op::TfaBlend => ops::tfa_blend(
                gpu,
                TfaBlend {
                    r: t[0],
                    e_cur: t[1],
                    e_prev: t[2],
                    cur: t[3],
                    prev: t[4],
                    valid: t[5],
                    out: t[6],
                    weights: t[7],
                },
            ),
            Op::Pool(mode) => ops::pool2x2(gpu, mode, t[0], t[1]),
            Op::Remodulate => {
                let ceiling = match self.config.ceiling_mode()? {
                    CeilingMode::None => None,
                    CeilingMode::Max => Some(CEILING_GAIN),
                };
                ops::remodulate(gpu, t[0], t[1], 3, t[2], ceiling, t[3])
            }
        }
    }

    /// The packed input tensors the caller fills before [`Network::record`]:
    /// `(A_t, MT, motion)`.
    pub fn inputs(&self) -> (&Tensor, &Tensor, &Tensor) {
        let t = |id| &self.tensors[&id];
        (t(TensorId::ACur), t(TensorId::Mt), t(TensorId::Motion))
    }

    /// The exposure tensors the caller's exposure pass writes before [`Network::record`]
    /// (`ssr/exposure_partial`, `ssr/exposure_final`): `(partials, exposure, ratio)`.
    pub fn exposure(&self) -> (&Tensor, &Tensor, &Tensor) {
        let t = |id| &self.tensors[&id];
        (
            t(TensorId::ExposurePartials),
            t(TensorId::Exposure),
            t(TensorId::ExposureRatio),
        )
    }

    /// The remodulated output (padded size, 3 channels) of the last recorded frame.
    pub fn output(&self) -> &Tensor {
        &self.tensors[&TensorId::Output]
    }

    /// A tensor of the last recorded frame by name ([`INTERMEDIATES`], or any
    /// [`TensorId::name`] that is not transient: transient tensors share memory, so their
    /// contents after the frame are not theirs); `None` for other names and for the
    /// tensors of a fourth U-Net level this network does not have.
    pub fn tensor(&self, name: &str) -> Option<&Tensor> {
        let cur = 1 - self.parity; // parity was advanced after recording
        TensorId::ALL
            .iter()
            .find(|id| id.name() == name && !id.is_transient() && id.in_config(&self.config))
            .map(|&id| self.at(id, cur))
    }

    /// Bytes of GPU memory the network's tensors hold (shared memory counted once; the
    /// weights not included).
    pub fn memory_bytes(&self) -> u64 {
        let mut seen: Vec<&wgpu::Buffer> = Vec::new();
        let all = self
            .tensors
            .values()
            .chain(&self.a_acc)
            .chain(&self.o)
            .chain([&self.ones]);
        all.filter(|t| {
            let new = !seen.contains(&&t.buffer);
            seen.push(&t.buffer);
            new
        })
        .map(|t| t.bytes())
        .sum()
    }

    /// Records one frame. `first` means there is no history (first frame, camera cut,
    /// resize): the history is then the current frame itself (DESIGN §4) and W(o) is 0.
    /// Otherwise the history is warped, re-exposed and checked against this frame's
    /// geometry (`ssr/warp_history`, one pass; re-exposure and test in version-2 configs) before the TFA.
    pub fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        first: bool,
        mut profiler: Option<&mut Profiler>,
        granularity: Granularity,
    ) {
        let p = self.parity;
        if first {
            let (a_t, warp_acc) = (self.at(TensorId::ACur, p), self.at(TensorId::WarpAcc, p));
            match &self.first_copy {
                Some(convert) => convert.encode(encoder),
                None => encoder.copy_buffer_to_buffer(&a_t.buffer, 0, &warp_acc.buffer, 0, a_t.bytes()),
            }
            let valid = self.at(TensorId::WarpValid, p);
            encoder.copy_buffer_to_buffer(&self.ones.buffer, 0, &valid.buffer, 0, self.ones.bytes());
            encoder.clear_buffer(&self.at(TensorId::WarpOut, p).buffer, 0, None);
        }
        let ordered: Vec<(&StepSpec, &Dispatch)> = self
            .specs
            .iter()
            .zip(&self.dispatches[p])
            .filter(|(s, _)| !(first && s.history))
            .collect();
        let mut i = 0;
        while i < ordered.len() {
            let j = match granularity {
                Granularity::Layer => i + 1,
                Granularity::Stage => {
                    let mut j = i;
                    while j < ordered.len() && ordered[j].0.stage == ordered[i].0.stage {
                        j += 1;
                    }
                    j
                }
            };
            let label = match granularity {
                Granularity::Layer => ordered[i].0.label,
                Granularity::Stage => ordered[i].0.stage,
            };
            let mut pass = Profiler::pass(encoder, label, profiler.as_deref_mut());
            for (_, d) in &ordered[i..j] {
                d.record(&mut pass);
            }
            drop(pass);
            i = j;
        }
        self.parity = 1 - p;
    }

    /// Every step in execution order (history steps included) with its stage, FLOPs per
    /// frame at this resolution (0 for data movement) and compulsory memory traffic.
    pub fn step_costs(&self) -> Vec<StepCost> {
        let levels: BTreeMap<String, u32> = self
            .config
            .layers()
            .into_iter()
            .map(|l| (l.name, l.level))
            .collect();
        self.specs
            .iter()
            .zip(&self.dispatches[self.parity])
            .map(|(s, d)| {
                let flops = match s.op {
                    Op::Conv(layer) => {
                        let lv = levels[layer];
                        self.convs[layer].flops_per_pixel()
                            * (self.width as u64 >> lv)
                            * (self.height as u64 >> lv)
                    }
                    _ => 0,
                };
                StepCost {
                    stage: s.stage,
                    label: s.label.to_string(),
                    flops,
                    bytes_read: d.bytes_read,
                    bytes_written: d.bytes_written,
                    matrix: matches!(s.op, Op::Conv(_)),
                }
            })
            .collect()
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
    /// Whether its FLOPs are a matrix product a tensor-core kernel can run (the
    /// convolutions).
    pub matrix: bool,
}
