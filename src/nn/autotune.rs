//! Choosing each convolution's kernel on the adapter it runs on (issue 14).
//!
//! The fastest [`ConvKernel`] for a layer depends on the driver and on the layer's size: on
//! a CPU Vulkan driver many accumulators per invocation win; on an H100 at 1080p, 2-8
//! pixels by 1-4 output blocks did, and at 128x128 the kernels that launch the most
//! invocations did. So the engine measures: for each layer shape it compiles every
//! candidate kernel (on every core at once), times each on scratch tensors with GPU
//! timestamps at [`tuning_size`] (at least the layer's own size on a GPU, at most
//! 128x128 on a CPU driver), times the fastest few again interleaved ([`CONFIRM_CANDIDATES`];
//! on a GPU after [`SPIN_UP_MS`] of continuous work) and keeps the fastest of those. Results are cached in memory for
//! the process and on disk per adapter, driver, kernel sources and shape, in
//! `autotune.json` under the cache folder ([`cache_dir`]); a corrupt cache file is
//! ignored (with a warning) and rewritten.
//!
//! For reproducibility the choice can be fixed: [`KernelChoice::Fixed`] through the API,
//! or the environment variable `SUBPIXEL_CONV_KERNEL` (`auto`, `generic` or a tiling such
//! as `px8-cob4`; a layer the tiling cannot run falls back to `generic`). A first tuning
//! compiles every candidate for every layer shape, which on a CPU driver takes minutes;
//! [`KernelChoice::Among`] (or a comma-separated list in `SUBPIXEL_CONV_KERNEL`, e.g.
//! `px16-cob2-tex,px8-cob4`) tunes among a few kernels only.
//!
//! The storage of the network's interior activations is chosen alike ([`Precision`],
//! `SUBPIXEL_PRECISION`): f32 by default (the trained model to float tolerance), f16
//! (half the bytes, f32 arithmetic; needs `SHADER_F16`), or `auto`: f16 when the adapter
//! has it and the tuned layers are faster with it in total.

use std::collections::BTreeMap;
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::sync::{Mutex, OnceLock};

use super::conv::{COOP_TOLERANCE, Conv3x3, ConvKernel};
use super::ops::Fetch;
use super::tensor::tensor_bytes;
use super::{DType, HostTensor, Tensor};
use crate::error::{Error, Result};
use crate::gpu::{AdapterKind, Dispatch, Gpu, time_dispatch};

/// The environment variable that fixes the convolution kernel.
pub const ENV_KERNEL: &str = "SUBPIXEL_CONV_KERNEL";
/// The environment variable that chooses the activations' storage ([`Precision`]).
pub const ENV_PRECISION: &str = "SUBPIXEL_PRECISION";
/// The environment variable that chooses how the pooled levels are read ([`Pooling`]).
pub const ENV_POOLING: &str = "SUBPIXEL_POOLING";
/// The environment variable that sets the pixels per invocation of the mean correction's
/// a-trous filter ([`AtrousPixels`]).
pub const ENV_ATROUS_PIXELS: &str = "SUBPIXEL_ATROUS_PIXELS";
/// The most pixels per invocation `ssr/mean_atrous` takes (each adds 3 vec4 accumulators
/// and 5 tap columns).
pub const ATROUS_PIXELS_MAX: u32 = 8;
/// The environment variable that moves the cache folder.
pub const ENV_CACHE_DIR: &str = "SUBPIXEL_CACHE_DIR";
/// On a CPU driver, layers are tuned on at most this many pixels per side (a 1080p layer
/// would make tuning slow there, and its ranking already holds at this size: a CPU driver's
/// few cores are full with a few thousand invocations).
pub const TUNE_MAX_SIDE_CPU: u32 = 128;
/// On a GPU, layers are tuned on at most this many pixels per side. Below it a layer is
/// tuned on at least its own size, so the GPU is at least as full as when the layer runs: a
/// small size leaves a large GPU mostly idle and ranks kernels by how many invocations they
/// launch, not by their arithmetic. Measured on an H100 (Vulkan, driver 580.159.04), a
/// 32->32 conv3x3 tuned at 128x128 picked px4-cob1, which at 1920x1080 takes 15.1 ms
/// against px2-cob4's 1.7 ms.
pub const TUNE_MAX_SIDE_GPU: u32 = 2048;
/// Timed runs per candidate (after one warm-up run); the median is compared.
pub const TUNE_ITERATIONS: u32 = 3;
/// On a GPU, continuous work (wall time, ms) before a layer shape's candidates are timed.
/// The candidates' compiles leave the GPU idle, and a GPU that clocks down when idle times
/// the first candidates slow: in two tunings of the same layer shapes in one call on an
/// H100 (2026-11-27, `tools/gpu_runs/2026-11-27-h100`), the first timed whole shapes
/// 1.4-3.7x slower than the second, and single candidates up to 5.6x.
pub const SPIN_UP_MS: f64 = 100.0;
/// The fastest candidates of the first pass, timed again interleaved (one round of each in
/// turn, [`CONFIRM_ROUNDS`] times) so that a change of clock or load during tuning slows
/// them alike; the fastest of them by the median of their rounds is chosen. Six rather
/// than three since the fortieth session: on a CPU driver tuned beside other work (both
/// cores busy), the first pass's noise pushed the best tilings out of the first three, and
/// the network as tuned came out about 1.6 ms slower than after a quiet tuning (Mesa 26,
/// 128x128: 23.5 against 21.9 ms); with six candidates and three rounds, 22.5 (README
/// Performance, fortieth session).
pub const CONFIRM_CANDIDATES: usize = 6;
/// Rounds of the interleaved re-timing ([`TUNE_ITERATIONS`] runs each).
pub const CONFIRM_ROUNDS: usize = 3;
/// The size at which the autotuner checks the cooperative-matrix kernel's output against
/// the CPU reference before timing it: two pixel tiles of 16 and a partial one, a few rows.
pub const COOP_CHECK_SIZE: (u32, u32) = (37, 5);

/// How convolution layers pick their kernel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KernelChoice {
    /// `SUBPIXEL_CONV_KERNEL` if set, else [`KernelChoice::Autotune`].
    #[default]
    FromEnv,
    /// Time the candidates on this adapter and keep the fastest (cached).
    Autotune,
    /// This kernel wherever it can run the layer, [`ConvKernel::Generic`] elsewhere.
    Fixed(ConvKernel),
    /// Time these kernels (those a layer can run, and always the generic kernel) and keep
    /// the fastest, cached apart from full tunings.
    Among(KernelSet),
}

/// A set of convolution kernels from [`ConvKernel::catalogue`] ([`KernelChoice::Among`]);
/// written and parsed as the kernels' names separated by commas.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct KernelSet(u64);

impl KernelSet {
    /// The set of `kernels`; an error names a kernel the autotuner does not know.
    pub fn of(kernels: &[ConvKernel]) -> Result<Self> {
        let all = ConvKernel::catalogue();
        let mut bits = 0u64;
        for k in kernels {
            let i = all.iter().position(|c| c == k).ok_or_else(|| {
                Error::Invalid(format!(
                    "conv kernel '{k}' is not one the autotuner tries (ConvKernel::catalogue)"
                ))
            })?;
            bits |= 1 << i;
        }
        Ok(KernelSet(bits))
    }

    /// Whether the set holds `kernel`.
    pub fn contains(&self, kernel: ConvKernel) -> bool {
        ConvKernel::catalogue()
            .iter()
            .position(|&c| c == kernel)
            .is_some_and(|i| self.0 & (1 << i) != 0)
    }

    /// The kernels of the set, in the catalogue's order.
    pub fn kernels(&self) -> Vec<ConvKernel> {
        ConvKernel::catalogue()
            .into_iter()
            .enumerate()
            .filter(|&(i, _)| self.0 & (1 << i) != 0)
            .map(|(_, k)| k)
            .collect()
    }
}

impl std::fmt::Display for KernelSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<String> = self.kernels().iter().map(|k| k.to_string()).collect();
        write!(f, "{}", names.join(","))
    }
}

impl std::str::FromStr for KernelSet {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        let kernels: Vec<ConvKernel> = s.split(',').map(|k| k.trim().parse()).collect::<Result<_>>()?;
        KernelSet::of(&kernels)
    }
}

impl KernelChoice {
    /// Resolves [`KernelChoice::FromEnv`] (an unparsable value is an error naming the
    /// variable); the other choices come back as they are.
    pub fn resolve(self) -> Result<Self> {
        if self != KernelChoice::FromEnv {
            return Ok(self);
        }
        match std::env::var(ENV_KERNEL) {
            Err(_) => Ok(KernelChoice::Autotune),
            Ok(v) if v.trim().is_empty() || v.trim() == "auto" => Ok(KernelChoice::Autotune),
            Ok(v) if v.contains(',') => v
                .parse()
                .map(KernelChoice::Among)
                .map_err(|e| Error::Invalid(format!("{ENV_KERNEL}: {e}"))),
            Ok(v) => v.trim().parse().map(KernelChoice::Fixed).map_err(|e| {
                Error::Invalid(format!(
                    "{ENV_KERNEL}: {e} (or 'auto', or kernels separated by commas)"
                ))
            }),
        }
    }

    /// The kernels a tuning under this (resolved) choice times: `None` for all of them.
    pub fn among(self) -> Option<KernelSet> {
        match self {
            KernelChoice::Among(set) => Some(set),
            _ => None,
        }
    }
}

/// Storage of the network's interior activations (the tensors only convolutions and
/// pooling touch; inputs, history and outputs stay f32).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Precision {
    /// `SUBPIXEL_PRECISION` (`f32`, `f16` or `auto`) if set, else [`Precision::F32`].
    #[default]
    FromEnv,
    /// f32: the trained model to float tolerance.
    F32,
    /// f16 storage with f32 arithmetic (needs `SHADER_F16`; an error without it).
    F16,
    /// f16 when the adapter has `SHADER_F16` and the autotuner's times of the network's
    /// layers are lower with it in total, else f32.
    Auto,
}

impl std::str::FromStr for Precision {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim() {
            "f32" => Ok(Precision::F32),
            "f16" => Ok(Precision::F16),
            "auto" => Ok(Precision::Auto),
            other => Err(Error::Invalid(format!(
                "precision '{other}': expected f32, f16 or auto"
            ))),
        }
    }
}

impl Precision {
    /// Resolves [`Precision::FromEnv`] (an unparsable value is an error naming the
    /// variable); the other choices come back as they are.
    pub fn resolve(self) -> Result<Self> {
        if self != Precision::FromEnv {
            return Ok(self);
        }
        from_env(ENV_PRECISION, Precision::F32)
    }
}

/// How the convolutions that read the U-Net's pooled encoder levels get them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pooling {
    /// `SUBPIXEL_POOLING` if set (`load`, `pass` or `auto`), else [`Pooling::Auto`].
    #[default]
    FromEnv,
    /// Pooled on load by the convolution (no pass and no memory of their own).
    OnLoad,
    /// Written by a pooling pass each and read directly: on an H100 the convolutions that
    /// pool on load ran 1.7-4x slower per FLOP than their peers (2026-11-27).
    Pass,
    /// Whichever is faster by the tuned times: the reading convolutions' tunings for both
    /// reads, plus the pooling passes timed on this adapter; with fixed kernels
    /// ([`KernelChoice::Fixed`], nothing tuned), [`Pooling::OnLoad`].
    Auto,
}

impl std::str::FromStr for Pooling {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim() {
            "load" => Ok(Pooling::OnLoad),
            "pass" => Ok(Pooling::Pass),
            "auto" => Ok(Pooling::Auto),
            other => Err(Error::Invalid(format!(
                "pooling '{other}': expected load, pass or auto"
            ))),
        }
    }
}

impl Pooling {
    /// Resolves [`Pooling::FromEnv`] (an unparsable value is an error naming the variable);
    /// the other choices come back as they are.
    pub fn resolve(self) -> Result<Self> {
        if self != Pooling::FromEnv {
            return Ok(self);
        }
        from_env(ENV_POOLING, Pooling::Auto)
    }
}

/// The environment variable `var` parsed as `T`; `default` when it is unset or empty, an
/// error naming the variable when it does not parse.
fn from_env<T: std::str::FromStr<Err = Error>>(var: &str, default: T) -> Result<T> {
    match std::env::var(var) {
        Ok(v) if !v.trim().is_empty() => v.parse().map_err(|e| Error::Invalid(format!("{var}: {e}"))),
        _ => Ok(default),
    }
}

/// How the engine runs the network on an adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EngineOptions {
    /// Convolution kernels.
    pub kernels: KernelChoice,
    /// Storage of the interior activations.
    pub precision: Precision,
    /// How the pooled encoder levels are read.
    pub pooling: Pooling,
    /// Pixels of a row per invocation of the mean correction's a-trous filter.
    pub atrous_pixels: AtrousPixels,
}

impl EngineOptions {
    /// Whether the engine measures its choices on the adapter: the convolutions' kernels
    /// are autotuned, and so are the choices made by timing (`Pooling::Auto`,
    /// `AtrousPixels::Auto`); with fixed kernels ([`KernelChoice::Fixed`]) nothing is timed
    /// and those take their defaults, for reproducible runs.
    pub fn measures(&self) -> Result<bool> {
        Ok(!matches!(self.kernels.resolve()?, KernelChoice::Fixed(_)))
    }
}

/// How many pixels of a row each invocation of the mean correction's edge-aware a-trous
/// filter (`ssr/mean_atrous`, config `mean_correction = "atrous"`) takes, their taps'
/// shared columns fetched once for all; any number gives the same factors. Measured (the
/// five levels' medians summed): on the 2-core CPU driver at 128x128, 7.6 ms with 2 and
/// 6.3 ms with 4 (1 took about twice as long as 4); on an H200 at 1080p, 1.06 ms with 2,
/// 1.20 with 4, 1.56 with 1 and 1.63 with 8 (README Performance).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AtrousPixels {
    /// `SUBPIXEL_ATROUS_PIXELS` if set (`auto` or 1 to [`ATROUS_PIXELS_MAX`]), else
    /// [`AtrousPixels::Auto`].
    #[default]
    FromEnv,
    /// This many, 1 to [`ATROUS_PIXELS_MAX`].
    Fixed(u32),
    /// The faster of [`AtrousPixels::CANDIDATES`], timed on this adapter at the frame's
    /// size (once per process); with fixed convolution kernels ([`KernelChoice::Fixed`],
    /// nothing timed), [`AtrousPixels::DEFAULT`].
    Auto,
}

impl AtrousPixels {
    /// The number when nothing is timed.
    pub const DEFAULT: u32 = 4;
    /// What [`AtrousPixels::Auto`] times.
    pub const CANDIDATES: [u32; 2] = [2, 4];

    /// Resolves [`AtrousPixels::FromEnv`] (an unparsable value is an error naming the
    /// variable); the other choices come back as they are, a fixed number checked to be
    /// within range.
    pub fn resolve(self) -> Result<Self> {
        match self {
            AtrousPixels::FromEnv => from_env(ENV_ATROUS_PIXELS, AtrousPixels::Auto),
            AtrousPixels::Fixed(px) if !Self::in_range(px) => Err(Error::Invalid(format!(
                "a-trous filter: {px} pixels per invocation; expected 1 to {ATROUS_PIXELS_MAX}"
            ))),
            other => Ok(other),
        }
    }

    /// Whether `ssr/mean_atrous` takes `px` pixels per invocation.
    fn in_range(px: u32) -> bool {
        (1..=ATROUS_PIXELS_MAX).contains(&px)
    }
}

impl std::str::FromStr for AtrousPixels {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim() {
            "auto" => Ok(AtrousPixels::Auto),
            t => match t.parse::<u32>() {
                Ok(px) if Self::in_range(px) => Ok(AtrousPixels::Fixed(px)),
                _ => Err(Error::Invalid(format!(
                    "a-trous pixels '{t}': expected 1 to {ATROUS_PIXELS_MAX} or auto"
                ))),
            },
        }
    }
}

/// The storage of one layer's tensors: its inputs' (in concatenation order) and its
/// output's.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LayerStorage {
    /// Each input's element type.
    pub inputs: Vec<DType>,
    /// The output's.
    pub output: DType,
}

impl LayerStorage {
    /// Every tensor f32.
    pub fn f32(conv: &Conv3x3) -> Self {
        Self {
            inputs: vec![DType::F32; conv.input_channels.len()],
            output: DType::F32,
        }
    }

    /// `f32` when all are, else e.g. `in f16,f32 out f16` (part of cache keys).
    fn describe(&self) -> String {
        if self.output == DType::F32 && self.inputs.iter().all(|&d| d == DType::F32) {
            return "f32".into();
        }
        let ins: Vec<&str> = self.inputs.iter().map(|d| d.name()).collect();
        format!("in {} out {}", ins.join(","), self.output.name())
    }
}

/// One candidate's measurement.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Candidate {
    /// The kernel.
    pub kernel: ConvKernel,
    /// Median time in ms over [`TUNE_ITERATIONS`] runs (for the [`CONFIRM_CANDIDATES`]
    /// fastest, the median of their interleaved re-timing's rounds), `None` when it failed.
    pub median_ms: Option<f64>,
    /// Why it could not run (compile or validation failure), when it failed.
    pub error: Option<String>,
}

/// The outcome of tuning one layer shape.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Tuning {
    /// The chosen kernel.
    pub choice: ConvKernel,
    /// Every candidate, in the order tried.
    pub candidates: Vec<Candidate>,
    /// Whether the times were GPU timestamps (else wall time).
    pub gpu_timestamps: bool,
}

/// The folder for the crate's caches: `SUBPIXEL_CACHE_DIR`, else `$XDG_CACHE_HOME/subpixel`,
/// else `$HOME/.cache/subpixel`; `None` when none is set.
pub fn cache_dir() -> Option<PathBuf> {
    let env = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
    env(ENV_CACHE_DIR)
        .or_else(|| env("XDG_CACHE_HOME").map(|d| d.join("subpixel")))
        .or_else(|| env("HOME").map(|d| d.join(".cache").join("subpixel")))
}

fn cache_file() -> Option<PathBuf> {
    cache_dir().map(|d| d.join("autotune.json"))
}

/// The on-disk cache: key -> tuning.
type Cache = BTreeMap<String, Tuning>;

/// The process's tunings, loaded from disk on first use.
fn memory() -> &'static Mutex<Cache> {
    static MEMORY: OnceLock<Mutex<Cache>> = OnceLock::new();
    MEMORY.get_or_init(|| Mutex::new(cache_file().map(|f| load(&f)).unwrap_or_default()))
}

/// Reads the cache file; a missing file is empty, an unreadable or corrupt one is ignored
/// with a warning (it is rewritten at the next tuning).
pub fn load(path: &std::path::Path) -> Cache {
    match std::fs::read_to_string(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Cache::new(),
        Err(e) => {
            log::warn!("autotune cache {}: {e}; ignored", path.display());
            Cache::new()
        }
        Ok(text) => serde_json::from_str(&text).unwrap_or_else(|e| {
            log::warn!(
                "autotune cache {} is corrupt ({e}); ignored and rebuilt",
                path.display()
            );
            Cache::new()
        }),
    }
}

/// Adds `key` to the cache file (merging with what other processes wrote since), written
/// to a temporary file and renamed so readers never see half a file. Failures only warn:
/// the cache is an optimisation.
fn store(key: &str, tuning: &Tuning) {
    let Some(path) = cache_file() else { return };
    let mut cache = load(&path);
    // Choices made for other versions of the kernels can never be used again.
    let current = kernels_hash();
    cache.retain(|k, _| k.contains(&current));
    cache.insert(key.to_string(), tuning.clone());
    let write = || -> std::io::Result<()> {
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d)?;
        }
        let tmp = path.with_extension(format!("json.{}.tmp", std::process::id()));
        std::fs::write(&tmp, serde_json::to_string_pretty(&cache).unwrap_or_default())?;
        std::fs::rename(&tmp, &path)
    };
    if let Err(e) = write() {
        log::warn!("autotune cache {}: {e}; not saved", path.display());
    }
}

/// `kernels HASH`: a hash of the convolution kernels' sources, part of every cache key.
fn kernels_hash() -> String {
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    for name in ["nn/conv3x3", "nn/conv3x3_blocked", "nn/conv3x3_winograd"] {
        if let Ok(k) = crate::gpu::kernel_source(name) {
            k.source.hash(&mut hasher);
        }
    }
    format!("kernels {:016x}", hasher.finish())
}

/// The cache key of `conv` tuned at `w x h` with `storage` on `gpu`: adapter, driver, the
/// kernels' sources (a change of either kernel invalidates old choices), the layer's shape
/// and its tensors' storage (all-f32 keys are those of earlier versions).
pub fn key(
    gpu: &Gpu,
    conv: &Conv3x3,
    w: u32,
    h: u32,
    storage: &LayerStorage,
    among: Option<KernelSet>,
) -> String {
    // A tuning among a few kernels is kept apart from the full one.
    let among = among.map(|set| format!(" among {set}")).unwrap_or_default();
    let storage = match storage.describe().as_str() {
        "f32" => String::new(),
        s => format!(" {s}"),
    };
    // Inputs resampled on load (all-direct keys are those of earlier versions).
    let fetch = if conv.fetch().iter().all(|&f| f == Fetch::Direct) {
        String::new()
    } else {
        let names: Vec<&str> = conv.fetch().iter().map(|f| f.name()).collect();
        format!(" read {}", names.join(","))
    };
    // With cooperative matrices the candidates differ (keys without them are those of
    // earlier versions).
    let coop = gpu.coop_tile.map(|t| format!(" coop{t}")).unwrap_or_default();
    format!(
        "{} | {:?} | {} {} | {} | conv3x3 {:?}->{} {:?} at {w}x{h}{storage}{fetch}{coop}{among}",
        gpu.info.name,
        gpu.info.backend,
        gpu.info.driver,
        gpu.info.driver_info,
        kernels_hash(),
        conv.input_channels,
        conv.cout,
        conv.act,
    )
}

/// Layers are tuned on at least this many pixels per side.
pub const TUNE_MIN_SIDE: u32 = 32;

/// The size a layer of `w x h` is tuned at on an adapter of `kind`: each side rounded up to
/// a power of two within [`TUNE_MIN_SIDE`] and [`TUNE_MAX_SIDE_CPU`] on a CPU driver,
/// [`TUNE_MAX_SIDE_GPU`] on a GPU, so that nearby sizes (a window being resized) share one
/// measurement.
pub fn tune_size(kind: AdapterKind, w: u32, h: u32) -> (u32, u32) {
    let max = match kind {
        AdapterKind::Cpu => TUNE_MAX_SIDE_CPU,
        _ => TUNE_MAX_SIDE_GPU,
    };
    let side = |n: u32| n.next_power_of_two().clamp(TUNE_MIN_SIDE, max);
    (side(w), side(h))
}

/// The size `conv`, a layer of `w x h` with `storage`, is tuned at on `gpu`: [`tune_size`],
/// or the layer's own size where a scratch tensor at that size would exceed the device's
/// buffer limits (the layer's own tensors fit them, or the network could not hold them).
pub fn tuning_size(gpu: &Gpu, conv: &Conv3x3, w: u32, h: u32, storage: &LayerStorage) -> (u32, u32) {
    let (tw, th) = tune_size(gpu.kind(), w, h);
    let limits = gpu.device.limits();
    let max = limits.max_buffer_size.min(limits.max_storage_buffer_binding_size);
    let inputs_fit = conv.input_channels.iter().enumerate().all(|(i, &c)| {
        let dtype = storage.inputs.get(i).copied().unwrap_or(DType::F32);
        let (sw, sh) = conv.fetch()[i].stored_size(tw, th);
        tensor_bytes(sw, sh, c, dtype) <= max
    });
    if inputs_fit && tensor_bytes(tw, th, conv.cout, storage.output) <= max {
        (tw, th)
    } else {
        (w, h)
    }
}

/// Times the candidates of `conv` at `w x h` on scratch tensors stored as `storage` says
/// (deterministic pseudo-random inputs): those in `among`, all of them for `None`; the
/// generic kernel always. A candidate that fails to build or run is recorded with its
/// error and skipped (logged), never fatal.
#[allow(clippy::too_many_arguments)]
pub fn measure(
    gpu: &Gpu,
    conv: &Conv3x3,
    w: u32,
    h: u32,
    storage: &LayerStorage,
    among: Option<KernelSet>,
    warmup: u32,
    iterations: u32,
) -> Result<Tuning> {
    let inputs: Vec<Tensor> = conv
        .input_channels
        .iter()
        .enumerate()
        .map(|(i, &c)| {
            let (sw, sh) = conv.fetch()[i].stored_size(w, h);
            let host = HostTensor::from_fn(sw, sh, c, |x, y, ch| {
                let v = (x * 7 + y * 13 + ch * 5 + i as u32 * 3) % 17;
                v as f32 / 8.0 - 1.0
            });
            let dtype = storage.inputs.get(i).copied().unwrap_or(DType::F32);
            Tensor::from_host_typed(gpu, "autotune.in", &host, dtype)
        })
        .collect::<Result<_>>()?;
    let out = Tensor::new_typed(gpu, "autotune.out", w, h, conv.cout, storage.output)?;
    let refs: Vec<&Tensor> = inputs.iter().collect();
    // Each candidate is a pipeline of its own: they are compiled on every core at once (the
    // driver's compile is most of a tuning's time), then timed one after another.
    let bound: Vec<(ConvKernel, Result<Dispatch>)> = {
        use rayon::prelude::*;
        conv.candidates(gpu)
            .into_iter()
            .filter(|&k| k == ConvKernel::Generic || among.is_none_or(|set| set.contains(k)))
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|kernel| (kernel, conv.bind_with(gpu, kernel, &refs, &out)))
            .collect()
    };
    // The cooperative-matrix kernel runs on experimental driver paths: its output is
    // checked against the CPU reference (at a small size with partial tiles, one set of
    // inputs for every tiling) before it is timed.
    let coop: Vec<ConvKernel> = bound
        .iter()
        .map(|b| b.0)
        .filter(|k| matches!(k, ConvKernel::Coop { .. }))
        .collect();
    let mut coop_errors: std::collections::HashMap<ConvKernel, Result<f32>> = if coop.is_empty() {
        Default::default()
    } else {
        let (w, h) = COOP_CHECK_SIZE;
        match conv.output_errors(gpu, &coop, w, h, &storage.inputs) {
            Ok(errors) => coop.iter().copied().zip(errors).collect(),
            Err(e) => coop
                .iter()
                .map(|&k| {
                    let message = format!("its output check could not run: {e}");
                    (
                        k,
                        Err(Error::Kernel {
                            kernel: "nn/conv3x3_coop".into(),
                            message,
                        }),
                    )
                })
                .collect(),
        }
    };
    // Checked and bound candidates; the others fail with their reason.
    let checked: Vec<(ConvKernel, Result<Dispatch>)> = bound
        .into_iter()
        .map(|(kernel, dispatch)| {
            let checked = match coop_errors.remove(&kernel) {
                Some(error) => error.and_then(|e| {
                    if e <= COOP_TOLERANCE {
                        Ok(())
                    } else {
                        Err(Error::Kernel {
                            kernel: "nn/conv3x3_coop".into(),
                            message: format!(
                                "{kernel} disagrees with the CPU reference by {e:.2e} of the output's range (tolerance {COOP_TOLERANCE:.0e})"
                            ),
                        })
                    }
                }),
                None => Ok(()),
            };
            (kernel, checked.and(dispatch))
        })
        .collect();
    if gpu.kind() != AdapterKind::Cpu
        && let Some(d) = checked.iter().find_map(|(_, d)| d.as_ref().ok())
    {
        spin_up(gpu, d)?;
    }
    let mut candidates = Vec::new();
    let mut dispatches = Vec::new();
    let mut gpu_timestamps = true;
    for (kernel, dispatch) in checked {
        let timed = dispatch.and_then(|d| {
            let t = time_dispatch(gpu, &d, warmup, iterations)?;
            Ok((t, d))
        });
        match timed {
            Ok(((stats, timestamps), d)) => {
                gpu_timestamps &= timestamps;
                candidates.push(Candidate {
                    kernel,
                    median_ms: Some(stats.median_ms),
                    error: None,
                });
                dispatches.push(Some(d));
            }
            Err(e) => {
                log::warn!("conv3x3 '{}': kernel {kernel} skipped: {e}", conv.name);
                candidates.push(Candidate {
                    kernel,
                    median_ms: None,
                    error: Some(e.to_string()),
                });
                dispatches.push(None);
            }
        }
    }
    let first: Vec<Option<f64>> = candidates.iter().map(|c| c.median_ms).collect();
    let (medians, chosen) = confirm(&first, |i| {
        let d = dispatches[i]
            .as_ref()
            .expect("only candidates that ran are re-timed");
        Ok(time_dispatch(gpu, d, 0, iterations)?.0.median_ms)
    })
    .ok_or_else(|| Error::Kernel {
        kernel: "nn/conv3x3".into(),
        message: format!("no candidate kernel could run layer '{}'", conv.name),
    })?;
    for (c, m) in candidates.iter_mut().zip(medians) {
        c.median_ms = m;
    }
    Ok(Tuning {
        choice: candidates[chosen].kernel,
        candidates,
        gpu_timestamps,
    })
}

/// Keeps the GPU busy with `d` for [`SPIN_UP_MS`] of wall time (a few dispatches per
/// submission, so that it does not idle between them).
fn spin_up(gpu: &Gpu, d: &Dispatch) -> Result<()> {
    let started = std::time::Instant::now();
    while started.elapsed().as_secs_f64() * 1e3 < SPIN_UP_MS {
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        for _ in 0..4 {
            d.encode(&mut encoder);
        }
        gpu.queue.submit([encoder.finish()]);
        gpu.wait()?;
    }
    Ok(())
}

/// The interleaved re-timing of the [`CONFIRM_CANDIDATES`] fastest of `first` (first-pass
/// medians, `None` for candidates that failed): [`CONFIRM_ROUNDS`] rounds, each calling
/// `round(i)` (one round's median of candidate `i`) for every one of them in turn. Returns
/// the medians to record (the re-timed candidates' replaced by the median of their rounds)
/// and the index chosen: the fastest re-timed candidate. A candidate whose re-timing fails
/// keeps its first time and is not chosen (logged), unless all fail: then the first pass
/// decides. `None` when no candidate ran.
fn confirm(
    first: &[Option<f64>],
    mut round: impl FnMut(usize) -> Result<f64>,
) -> Option<(Vec<Option<f64>>, usize)> {
    let mut ranked: Vec<(f64, usize)> = first
        .iter()
        .enumerate()
        .filter_map(|(i, t)| t.map(|t| (t, i)))
        .collect();
    ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
    let fastest_first = ranked.first()?.1;
    ranked.truncate(CONFIRM_CANDIDATES);
    let mut rounds: Vec<Option<Vec<f64>>> = vec![Some(Vec::new()); ranked.len()];
    for _ in 0..CONFIRM_ROUNDS {
        for (slot, &(_, i)) in rounds.iter_mut().zip(&ranked) {
            if let Some(times) = slot {
                match round(i) {
                    Ok(t) => times.push(t),
                    Err(e) => {
                        log::warn!("autotune: re-timing candidate {i} failed ({e}); it is not chosen");
                        *slot = None;
                    }
                }
            }
        }
    }
    let mut medians = first.to_vec();
    let mut chosen: Option<(f64, usize)> = None;
    for (times, &(_, i)) in rounds.iter().zip(&ranked) {
        let Some(stats) = times.as_deref().and_then(crate::gpu::Stats::from_samples) else {
            continue;
        };
        medians[i] = Some(stats.median_ms);
        if chosen.is_none_or(|(best, _)| stats.median_ms < best) {
            chosen = Some((stats.median_ms, i));
        }
    }
    Some((medians, chosen.map_or(fastest_first, |(_, i)| i)))
}

/// The tuning of `conv` for a `w x h` layer with `storage` among the kernels of `among`
/// (all of them for `None`; a tuning among a set is cached apart): from the process's
/// memory, else the disk cache, else measured now (at [`tuning_size`]) and cached. Returns
/// it and whether it came from a cache.
pub fn tune(
    gpu: &Gpu,
    conv: &Conv3x3,
    w: u32,
    h: u32,
    storage: &LayerStorage,
    among: Option<KernelSet>,
) -> Result<(Tuning, bool)> {
    let (tw, th) = tuning_size(gpu, conv, w, h, storage);
    let key = key(gpu, conv, tw, th, storage, among);
    if let Some(t) = memory().lock().unwrap().get(&key) {
        // A cached choice this build cannot run (an edited cache) is re-measured.
        if conv.unsupported(gpu, t.choice).is_none() {
            return Ok((t.clone(), true));
        }
    }
    announce_first_tuning(gpu);
    let started = std::time::Instant::now();
    let t = measure(gpu, conv, tw, th, storage, among, 1, TUNE_ITERATIONS)?;
    log::info!(
        "autotuned conv3x3 {:?}->{} ({}) at {tw}x{th}: {} of {} kernels in {:.1} s (once per adapter; cached in {})",
        conv.input_channels,
        conv.cout,
        storage.describe(),
        t.choice,
        t.candidates.len(),
        started.elapsed().as_secs_f64(),
        cache_file()
            .map(|f| f.display().to_string())
            .unwrap_or_else(|| "memory only".into())
    );
    // Another thread may have tuned the same shape meanwhile: the first result stays, so
    // every network of the process runs a shape on one kernel (and sums in one order).
    let (t, first) = {
        let mut memory = memory().lock().unwrap();
        let first = !memory.contains_key(&key);
        (memory.entry(key.clone()).or_insert(t).clone(), first)
    };
    if first {
        store(&key, &t);
    }
    Ok((t, false))
}

/// `measure()` (milliseconds) once per process and `key`, the later calls answering from
/// memory: for timings that steer a choice outside the tuning cache (e.g. whether the
/// pooled levels get passes of their own), so that every network built in a process
/// makes the same choice.
pub fn timed_once(key: String, measure: impl FnOnce() -> Result<f64>) -> Result<f64> {
    static TIMES: OnceLock<Mutex<BTreeMap<String, f64>>> = OnceLock::new();
    let times = TIMES.get_or_init(Default::default);
    if let Some(&ms) = times.lock().unwrap().get(&key) {
        return Ok(ms);
    }
    let ms = measure()?;
    Ok(*times.lock().unwrap().entry(key).or_insert(ms))
}

/// Says once per process, before the first layer shape is measured, what is happening and
/// how long it may take: on a CPU driver every candidate compiles at its first dispatch, and
/// a first tuning of the SSR network with Mesa's shader cache empty took about 20 minutes on a
/// 2-core machine before the texture-reading tilings joined the candidates, which add about
/// 2.5 (README Performance).
fn announce_first_tuning(gpu: &Gpu) {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let cost = if gpu.kind() == AdapterKind::Cpu {
            "on a CPU driver each candidate kernel compiles first: about 20-25 minutes for the SSR network on a 2-core machine the first time, about a minute once the driver's shader cache holds the kernels"
        } else {
            "seconds per layer shape"
        };
        log::info!(
            "autotuning the convolutions on {} (once per adapter, driver and layer shape; {cost}; \
             {ENV_KERNEL}=px16-cob1, a tiling every layer can run, skips it)",
            gpu.describe()
        );
        // A CPU driver's kernels share the cores with whatever else runs: other work slows
        // the candidates unevenly, and a tuning beside it chose a network about 3 % slower
        // than a quiet one even after the interleaved re-timing (README Performance,
        // fortieth session).
        let load = std::fs::read_to_string("/proc/loadavg").ok().and_then(|s| load_average(&s));
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        if gpu.kind() == AdapterKind::Cpu
            && let Some(load) = load.filter(|&l| busy(l, cores))
        {
            log::warn!(
                "autotune: this machine is busy (load average {load:.2} on {cores} cores): other work \
                 skews the timings of a CPU driver's kernels, so the tuning may choose slower ones; \
                 to tune again when it is quiet, remove {}",
                cache_file().map_or_else(|| "the autotune cache".to_string(), |p| p.display().to_string())
            );
        }
    });
}

/// The one-minute load average of a `/proc/loadavg` line.
fn load_average(line: &str) -> Option<f64> {
    line.split_whitespace()
        .next()?
        .parse()
        .ok()
        .filter(|l: &f64| l.is_finite())
}

/// Whether a load average means other work holds at least half the cores.
fn busy(load: f64, cores: usize) -> bool {
    load >= 0.5 * cores as f64
}

/// The kernel `conv` runs on for a `w x h` layer with `storage` under `choice`.
pub fn choose(
    gpu: &Gpu,
    conv: &Conv3x3,
    w: u32,
    h: u32,
    storage: &LayerStorage,
    choice: KernelChoice,
) -> Result<ConvKernel> {
    match choice.resolve()? {
        KernelChoice::Fixed(k) if conv.unsupported(gpu, k).is_none() => Ok(k),
        KernelChoice::Fixed(_) => Ok(ConvKernel::Generic),
        choice => Ok(tune(gpu, conv, w, h, storage, choice.among())?.0.choice),
    }
}

/// The tuned time of `conv`'s fastest kernel for a `w x h` layer with `storage`, in ms,
/// scaled from the tuning size to the layer's pixels (what [`Precision::Auto`] compares).
pub fn tuned_ms(
    gpu: &Gpu,
    conv: &Conv3x3,
    w: u32,
    h: u32,
    storage: &LayerStorage,
    among: Option<KernelSet>,
) -> Result<f64> {
    let (t, _) = tune(gpu, conv, w, h, storage, among)?;
    let best = t
        .candidates
        .iter()
        .find(|c| c.kernel == t.choice)
        .and_then(|c| c.median_ms)
        .unwrap_or(f64::INFINITY);
    let (tw, th) = tuning_size(gpu, conv, w, h, storage);
    Ok(best * (w as f64 * h as f64) / (tw as f64 * th as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn failed() -> Error {
        Error::Kernel {
            kernel: "test".into(),
            message: "re-timing failed".into(),
        }
    }

    #[test]
    fn a_clock_that_drifts_during_the_first_pass_does_not_decide_the_choice() {
        // True times; the first pass ran while the clock came up (3x, 2x, then steady), so
        // it ranks candidate 2 first and the truly fastest, 1, only sixth. The re-timing
        // runs the CONFIRM_CANDIDATES fastest of the first pass in turn, each round at its
        // own clock (1.5x, then 1x) for all of them alike.
        let truth = [1.0, 0.9, 1.1, 2.0, 1.5, 1.3, 1.2, 1.4, 3.0];
        let clocks = [3.0, 2.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
        let first: Vec<Option<f64>> = clocks.iter().zip(truth).map(|(f, t)| Some(f * t)).collect();
        let mut ranked: Vec<usize> = (0..truth.len()).collect();
        ranked.sort_by(|&a, &b| first[a].unwrap().total_cmp(&first[b].unwrap()));
        assert_eq!(ranked[..6], [2, 6, 5, 7, 4, 1], "the first pass ranks 1 sixth");
        ranked.truncate(CONFIRM_CANDIDATES);
        let mut calls = Vec::new();
        let (medians, chosen) = confirm(&first, |i| {
            calls.push(i);
            let clock = if calls.len() <= CONFIRM_CANDIDATES {
                1.5
            } else {
                1.0
            };
            Ok(clock * truth[i])
        })
        .unwrap();
        assert_eq!(chosen, 1, "the truly fastest of those re-timed");
        // Interleaved: every re-timed candidate once per round, the first pass's fastest first.
        assert_eq!(calls, ranked.repeat(CONFIRM_ROUNDS));
        // The median of its rounds (1.5x once, then 1x).
        assert!((medians[1].unwrap() - 0.9).abs() < 1e-12);
        for i in (0..truth.len()).filter(|i| !ranked.contains(i)) {
            assert_eq!(medians[i], first[i], "candidates not re-timed keep their time");
        }
    }

    #[test]
    fn a_busy_machine_is_told_from_its_load_average() {
        assert_eq!(load_average("2.05 1.98 1.51 3/180 24601\n"), Some(2.05));
        assert_eq!(load_average(""), None);
        assert_eq!(load_average("busy 1 2"), None);
        assert!(busy(2.05, 2) && busy(1.0, 2));
        assert!(!busy(0.4, 2) && !busy(3.9, 16));
    }

    #[test]
    fn failed_candidates_and_failed_re_timings_are_never_chosen() {
        let first = [None, Some(1.0), Some(1.2)];
        let (medians, chosen) = confirm(&first, |i| if i == 1 { Err(failed()) } else { Ok(1.3) }).unwrap();
        assert_eq!(chosen, 2);
        assert_eq!(medians, vec![None, Some(1.0), Some(1.3)]);
        // If every re-timing fails, the first pass decides.
        let (_, chosen) = confirm(&first, |_| Err(failed())).unwrap();
        assert_eq!(chosen, 1);
        assert!(confirm(&[None, None], |_| Ok(1.0)).is_none());
    }

    #[test]
    fn corrupt_or_missing_cache_files_are_empty() {
        let dir = std::env::temp_dir().join(format!("subpixel-autotune-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("autotune.json");
        assert!(load(&f).is_empty());
        std::fs::write(&f, "{ not json").unwrap();
        assert!(load(&f).is_empty());
        let mut c = Cache::new();
        c.insert(
            "k".into(),
            Tuning {
                choice: ConvKernel::Blocked {
                    px: 8,
                    cob: 4,
                    tex: false,
                },
                candidates: vec![Candidate {
                    kernel: ConvKernel::Generic,
                    median_ms: Some(1.5),
                    error: None,
                }],
                gpu_timestamps: true,
            },
        );
        std::fs::write(&f, serde_json::to_string(&c).unwrap()).unwrap();
        assert_eq!(load(&f), c);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn nearby_sizes_share_a_tuning_size() {
        let cpu = AdapterKind::Cpu;
        assert_eq!(tune_size(cpu, 1920, 1080), (128, 128));
        assert_eq!(tune_size(cpu, 16, 20), (32, 32));
        assert_eq!(tune_size(cpu, 33, 64), (64, 64));
        assert_eq!(tune_size(cpu, 100, 8), (128, 32));
        for gpu in [AdapterKind::Discrete, AdapterKind::Integrated, AdapterKind::Other] {
            assert_eq!(tune_size(gpu, 1920, 1080), (2048, 2048));
            assert_eq!(tune_size(gpu, 1366, 768), (2048, 1024));
            assert_eq!(tune_size(gpu, 960, 540), (1024, 1024));
            assert_eq!(tune_size(gpu, 3840, 2160), (2048, 2048));
            assert_eq!(tune_size(gpu, 16, 20), (32, 32));
        }
    }

    #[test]
    fn kernel_sets_parse_print_and_name_unknown_kernels() {
        let set: KernelSet = " px16-cob1 , generic,wino-tx2-cob2-tex".parse().unwrap();
        // Printed in the catalogue's order, whatever order they were given in.
        assert_eq!(set.to_string(), "generic,px16-cob1,wino-tx2-cob2-tex");
        assert!(set.contains(ConvKernel::Generic));
        assert!(!set.contains("px4-cob1".parse().unwrap()));
        assert_eq!(set.to_string().parse::<KernelSet>().unwrap(), set);
        assert_eq!(
            KernelSet::of(&ConvKernel::catalogue()).unwrap().kernels(),
            ConvKernel::catalogue()
        );
        assert!(
            ConvKernel::catalogue().len() <= 64,
            "a KernelSet holds 64 kernels"
        );
        let e = "px4-cob1,px3-cob1".parse::<KernelSet>().unwrap_err().to_string();
        assert!(e.contains("px3-cob1"), "{e}");
        let e = "px4-cob1,fast".parse::<KernelSet>().unwrap_err().to_string();
        assert!(e.contains("fast"), "{e}");
        let among = KernelChoice::Among(set);
        assert_eq!(among.resolve().unwrap(), among);
        assert_eq!(among.among(), Some(set));
        assert_eq!(KernelChoice::Autotune.among(), None);
        let options = EngineOptions {
            kernels: among,
            ..Default::default()
        };
        assert!(options.measures().unwrap(), "a tuning among a set measures");
    }

    #[test]
    fn poolings_parse_and_bad_ones_are_named() {
        assert_eq!("load".parse::<Pooling>().unwrap(), Pooling::OnLoad);
        assert_eq!(" pass ".parse::<Pooling>().unwrap(), Pooling::Pass);
        assert_eq!("auto".parse::<Pooling>().unwrap(), Pooling::Auto);
        let e = "fused".parse::<Pooling>().unwrap_err().to_string();
        assert!(e.contains("fused") && e.contains("load, pass or auto"), "{e}");
        assert_eq!(Pooling::Pass.resolve().unwrap(), Pooling::Pass);
    }

    #[test]
    fn atrous_pixels_parse_and_bad_ones_are_named() {
        assert_eq!(" 3".parse::<AtrousPixels>().unwrap(), AtrousPixels::Fixed(3));
        assert_eq!("auto".parse::<AtrousPixels>().unwrap(), AtrousPixels::Auto);
        for bad in ["0", "9", "four", ""] {
            let e = bad.parse::<AtrousPixels>().unwrap_err().to_string();
            assert!(
                e.contains(&format!("'{bad}'")) && e.contains("1 to 8 or auto"),
                "{e}"
            );
        }
        let e = AtrousPixels::Fixed(9).resolve().unwrap_err().to_string();
        assert!(e.contains("9 pixels per invocation"), "{e}");
        assert_eq!(AtrousPixels::Auto.resolve().unwrap(), AtrousPixels::Auto);
    }

    #[test]
    fn precisions_parse_and_bad_ones_are_named() {
        assert_eq!("f16".parse::<Precision>().unwrap(), Precision::F16);
        assert_eq!(" auto".parse::<Precision>().unwrap(), Precision::Auto);
        let e = "half".parse::<Precision>().unwrap_err().to_string();
        assert!(e.contains("half") && e.contains("f32, f16 or auto"), "{e}");
        assert_eq!(Precision::F16.resolve().unwrap(), Precision::F16);
    }

    #[test]
    fn fixed_choices_resolve_to_themselves() {
        let k = KernelChoice::Fixed(ConvKernel::Generic);
        assert_eq!(k.resolve().unwrap(), k);
        assert_eq!(KernelChoice::Autotune.resolve().unwrap(), KernelChoice::Autotune);
    }
}
