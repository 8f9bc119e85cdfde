//! Choosing each convolution's kernel on the adapter it runs on (issue 14).
//!
//! The fastest [`ConvKernel`] for a layer depends on the driver and on the layer's size: on
//! a CPU Vulkan driver many accumulators per invocation win; on an H100 at 1080p, 2-8
//! pixels by 1-4 output blocks did, and at 128x128 the kernels that launch the most
//! invocations did. So the engine measures: for each layer shape it compiles every
//! candidate kernel (on every core at once), times each on scratch tensors with GPU
//! timestamps at [`tuning_size`] (at least the layer's own size on a GPU, at most
//! 128x128 on a CPU driver) and keeps the fastest. Results are cached in memory for
//! the process and on disk per adapter, driver, kernel sources and shape, in
//! `autotune.json` under the cache folder ([`cache_dir`]); a corrupt cache file is
//! ignored (with a warning) and rewritten.
//!
//! For reproducibility the choice can be fixed: [`KernelChoice::Fixed`] through the API,
//! or the environment variable `SUBPIXEL_CONV_KERNEL` (`auto`, `generic` or a tiling such
//! as `px8-cob4`; a layer the tiling cannot run falls back to `generic`).
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
            Ok(v) => v
                .trim()
                .parse()
                .map(KernelChoice::Fixed)
                .map_err(|e| Error::Invalid(format!("{ENV_KERNEL}: {e} (or 'auto')"))),
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
        match std::env::var(ENV_PRECISION) {
            Err(_) => Ok(Precision::F32),
            Ok(v) if v.trim().is_empty() => Ok(Precision::F32),
            Ok(v) => v
                .parse()
                .map_err(|e| Error::Invalid(format!("{ENV_PRECISION}: {e}"))),
        }
    }
}

/// How the engine runs the network on an adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EngineOptions {
    /// Convolution kernels.
    pub kernels: KernelChoice,
    /// Storage of the interior activations.
    pub precision: Precision,
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
    /// Median time in ms over [`TUNE_ITERATIONS`] runs, `None` when it failed.
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
pub fn key(gpu: &Gpu, conv: &Conv3x3, w: u32, h: u32, storage: &LayerStorage) -> String {
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
        "{} | {:?} | {} {} | {} | conv3x3 {:?}->{} {:?} at {w}x{h}{storage}{fetch}{coop}",
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

/// Times every candidate of `conv` at `w x h` on scratch tensors stored as `storage` says
/// (deterministic pseudo-random inputs). A candidate that fails to build or run is recorded
/// with its error and skipped (logged), never fatal; the generic kernel always runs.
pub fn measure(
    gpu: &Gpu,
    conv: &Conv3x3,
    w: u32,
    h: u32,
    storage: &LayerStorage,
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
    let mut candidates = Vec::new();
    let mut gpu_timestamps = true;
    for (kernel, dispatch) in bound {
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
        let timed = checked
            .and(dispatch)
            .and_then(|d| time_dispatch(gpu, &d, warmup, iterations));
        match timed {
            Ok((stats, timestamps)) => {
                gpu_timestamps &= timestamps;
                candidates.push(Candidate {
                    kernel,
                    median_ms: Some(stats.median_ms),
                    error: None,
                });
            }
            Err(e) => {
                log::warn!("conv3x3 '{}': kernel {kernel} skipped: {e}", conv.name);
                candidates.push(Candidate {
                    kernel,
                    median_ms: None,
                    error: Some(e.to_string()),
                });
            }
        }
    }
    let choice = candidates
        .iter()
        .filter_map(|c| c.median_ms.map(|t| (t, c.kernel)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, k)| k)
        .ok_or_else(|| Error::Kernel {
            kernel: "nn/conv3x3".into(),
            message: format!("no candidate kernel could run layer '{}'", conv.name),
        })?;
    Ok(Tuning {
        choice,
        candidates,
        gpu_timestamps,
    })
}

/// The tuning of `conv` for a `w x h` layer with `storage`: from the process's memory,
/// else the disk cache, else measured now (at [`tuning_size`]) and cached. Returns it and
/// whether it came from a cache.
pub fn tune(gpu: &Gpu, conv: &Conv3x3, w: u32, h: u32, storage: &LayerStorage) -> Result<(Tuning, bool)> {
    let (tw, th) = tuning_size(gpu, conv, w, h, storage);
    let key = key(gpu, conv, tw, th, storage);
    if let Some(t) = memory().lock().unwrap().get(&key) {
        // A cached choice this build cannot run (an edited cache) is re-measured.
        if conv.unsupported(gpu, t.choice).is_none() {
            return Ok((t.clone(), true));
        }
    }
    let started = std::time::Instant::now();
    let t = measure(gpu, conv, tw, th, storage, 1, TUNE_ITERATIONS)?;
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
    memory().lock().unwrap().insert(key.clone(), t.clone());
    store(&key, &t);
    Ok((t, false))
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
        _ => Ok(tune(gpu, conv, w, h, storage)?.0.choice),
    }
}

/// The tuned time of `conv`'s fastest kernel for a `w x h` layer with `storage`, in ms,
/// scaled from the tuning size to the layer's pixels (what [`Precision::Auto`] compares).
pub fn tuned_ms(gpu: &Gpu, conv: &Conv3x3, w: u32, h: u32, storage: &LayerStorage) -> Result<f64> {
    let (t, _) = tune(gpu, conv, w, h, storage)?;
    let best = t
        .candidates
        .iter()
        .filter_map(|c| c.median_ms)
        .fold(f64::INFINITY, f64::min);
    let (tw, th) = tuning_size(gpu, conv, w, h, storage);
    Ok(best * (w as f64 * h as f64) / (tw as f64 * th as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

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
                choice: ConvKernel::Blocked { px: 8, cob: 4 },
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
