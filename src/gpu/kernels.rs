//! The kernel registry: every WGSL file embedded once, validated with naga, and its
//! compute pipelines cached per specialisation ([`Specialisation`]: WGSL `override`
//! constants, and template parameters that shape unrolled code, see [`super::template`]).
//!
//! Calling convention shared by every kernel: `@group(0) @binding(0)` is a uniform
//! block of parameters (when the kernel has one), followed by the resources at bindings
//! 1, 2, ... in the order the kernel's Rust wrapper passes them (mostly storage buffers).
//! On adapters where uniform blocks misbehave the parameters are bound as a read-only
//! storage buffer instead (see [`ParamsBinding`]); the kernels' WGSL is the same either
//! way. A dispatch says how many invocations it needs ([`Grid`]); the workgroup counts
//! follow from the kernel's own `@workgroup_size`. Each [`Dispatch`] knows the bytes it
//! reads and writes (from the kernel's binding access), for roofline models.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use crate::error::{Error, Result};

/// One embedded WGSL kernel: its entry file, composed with the library files it includes.
///
/// WGSL has no `#include`; a kernel that shares code (the path tracer's traversal, BSDF,
/// sampling) lists library files under `wgsl/**/lib/`, which are concatenated in order in
/// front of the entry file at compile time. Library files hold functions, structs and
/// constants only; they may refer to bindings that every including entry file declares
/// (one exception declares bindings itself: `trace/lib/scene`, the tracer's scene arrays).
#[derive(Debug, Clone, Copy)]
pub struct KernelSource {
    /// Name: the path under `wgsl/` without extension, e.g. `nn/conv3x3`.
    pub name: &'static str,
    /// WGSL text: the included libraries followed by the entry file.
    pub source: &'static str,
    /// Library files (names under `wgsl/`, no extension) composed in front of the entry file.
    pub includes: &'static [&'static str],
}

macro_rules! kernel {
    ($name:literal) => {
        KernelSource {
            name: $name,
            source: include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/wgsl/", $name, ".wgsl")),
            includes: &[],
        }
    };
    ($name:literal, [$($lib:literal),+ $(,)?]) => {
        KernelSource {
            name: $name,
            source: concat!(
                $(
                    "// ---- library wgsl/", $lib, ".wgsl ----\n",
                    include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/wgsl/", $lib, ".wgsl")),
                    "\n",
                )+
                "// ---- kernel wgsl/", $name, ".wgsl ----\n",
                include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/wgsl/", $name, ".wgsl")),
            ),
            includes: &[$($lib),+],
        }
    };
}

/// Libraries of the path tracer, in dependency order (each may use those before it).
macro_rules! trace_kernel {
    ($name:literal) => {
        kernel!(
            $name,
            [
                "trace/lib/common",
                "trace/lib/scene",
                "trace/lib/bvh",
                "trace/lib/material",
                "trace/lib/bsdf",
                "trace/lib/lights",
                "trace/lib/camera",
            ]
        )
    };
}

impl KernelSource {
    /// The WGSL compiled for this kernel when its parameters are bound as `params` and its
    /// template parameters (see [`super::template`]; defaults for those not given) take
    /// `template`'s values. WGSL wants `enable` directives before any declaration, so
    /// those of the entry file (an f16 variant's `enable f16;`) move in front of the
    /// libraries composed before it.
    pub fn wgsl(&self, params: ParamsBinding, template: &[(&str, u32)]) -> Result<String> {
        let expanded = super::template::expand(self.name, self.source, template)?;
        let is_enable = |l: &&str| l.trim_start().starts_with("enable ");
        let mut source = String::with_capacity(expanded.len());
        for l in expanded.lines().filter(is_enable) {
            source.push_str(l.trim());
            source.push('\n');
        }
        for l in expanded.lines().filter(|l| !is_enable(l)) {
            source.push_str(l);
            source.push('\n');
        }
        Ok(match params {
            ParamsBinding::Uniform => source,
            ParamsBinding::Storage => source.replace(PARAMS_UNIFORM, PARAMS_STORAGE),
        })
    }
}

/// The declaration every kernel's parameter block starts with.
const PARAMS_UNIFORM: &str = "@group(0) @binding(0) var<uniform>";
/// Its replacement when the parameters are bound as a storage buffer.
const PARAMS_STORAGE: &str = "@group(0) @binding(0) var<storage, read>";

/// How a kernel's parameter block (binding 0) is bound.
///
/// `Uniform` everywhere except Mesa's CPU Vulkan driver (lavapipe). Lavapipe "inlines"
/// uniform values that control loops into the shader and recompiles it with LLVM when
/// they change; the Mesa 22 shipped by Debian 12 does so at every dispatch, without
/// caching the variant or freeing it: each frame of the tracer and denoiser at 16x16
/// cost about 30 ms of compilation and leaked about 7 MiB (`tests/soak.rs`). Lavapipe
/// never inlines storage buffers, so there the parameters are bound as a read-only
/// storage buffer: one more storage binding, so a kernel keeps its uniform block on a
/// device whose limits have no room for it ([`KernelRegistry::params_binding`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ParamsBinding {
    /// `var<uniform>` (the WGSL as written).
    #[default]
    Uniform,
    /// `var<storage, read>`.
    Storage,
}

impl ParamsBinding {
    /// The binding for an adapter: `Storage` on lavapipe (Vulkan backend, `llvmpipe`
    /// device), `Uniform` elsewhere.
    pub fn for_adapter(info: &wgpu::AdapterInfo) -> Self {
        if info.backend == wgpu::Backend::Vulkan && info.name.to_ascii_lowercase().contains("llvmpipe") {
            Self::Storage
        } else {
            Self::Uniform
        }
    }
}

/// Every WGSL kernel of the crate.
pub const KERNELS: &[KernelSource] = &[
    kernel!("nn/conv3x3", ["nn/lib/storage", "nn/lib/fetch"]),
    kernel!(
        "nn/conv3x3_blocked",
        [
            "nn/lib/storage",
            "nn/lib/conv_shape",
            "nn/lib/uniform_weights",
            "nn/lib/fetch"
        ]
    ),
    kernel!(
        "nn/conv3x3_winograd",
        [
            "nn/lib/storage",
            "nn/lib/conv_shape",
            "nn/lib/uniform_weights",
            "nn/lib/fetch"
        ]
    ),
    kernel!(
        "nn/conv3x3_coop",
        ["nn/lib/storage", "nn/lib/conv_shape", "nn/lib/fetch"]
    ),
    kernel!("nn/resample2x", ["nn/lib/storage", "nn/lib/fetch"]),
    kernel!("nn/to_texture", ["nn/lib/storage"]),
    kernel!("nn/tfa_blend", ["nn/lib/storage", "nn/lib/grid"]),
    kernel!("nn/warp", ["nn/lib/grid", "nn/lib/warp"]),
    kernel!(
        "nn/demodulate",
        ["nn/lib/storage", "nn/lib/grid", "nn/lib/modulation"]
    ),
    kernel!(
        "nn/remodulate",
        ["nn/lib/storage", "nn/lib/grid", "nn/lib/modulation"]
    ),
    kernel!("ssr/pack_inputs", ["ssr/lib/pack", "ssr/lib/sanitize"]),
    kernel!("ssr/pack_mt", ["ssr/lib/pack", "ssr/lib/sanitize"]),
    kernel!("ssr/store_output", ["ssr/lib/sanitize", "ssr/lib/output"]),
    kernel!(
        "ssr/tile_means",
        ["ssr/lib/sanitize", "ssr/lib/output", "ssr/lib/traced"]
    ),
    kernel!(
        "ssr/mean_history",
        [
            "ssr/lib/sanitize",
            "ssr/lib/output",
            "ssr/lib/traced",
            "nn/lib/warp"
        ]
    ),
    kernel!("ssr/mean_atrous"),
    kernel!("ssr/exposure_partial", ["ssr/lib/sanitize", "ssr/lib/exposure"]),
    kernel!("ssr/exposure_final", ["ssr/lib/exposure"]),
    kernel!(
        "ssr/warp_history",
        ["nn/lib/storage", "nn/lib/grid", "nn/lib/warp"]
    ),
    kernel!("ssr/fold_emission", ["nn/lib/grid"]),
    kernel!("view/display"),
    trace_kernel!("trace/query"),
    trace_kernel!("trace/gbuffer"),
    trace_kernel!("trace/pathtrace"),
    trace_kernel!("trace/background"),
    trace_kernel!("trace/emission_outline"),
];

/// Every library file under `wgsl/` that kernels include (not kernels themselves).
pub fn libraries() -> Vec<&'static str> {
    let mut libs: Vec<&'static str> = KERNELS.iter().flat_map(|k| k.includes.iter().copied()).collect();
    libs.sort_unstable();
    libs.dedup();
    libs
}

/// Looks a kernel up by name.
pub fn kernel_source(name: &str) -> Result<&'static KernelSource> {
    KERNELS
        .iter()
        .find(|k| k.name == name)
        .ok_or_else(|| Error::Kernel {
            kernel: name.to_string(),
            message: "no such kernel is embedded in the crate".into(),
        })
}

/// Parses and validates WGSL with naga (all capabilities the crate may request).
pub fn validate_wgsl(name: &str, source: &str) -> Result<naga::Module> {
    Ok(validate_wgsl_info(name, source)?.0)
}

/// [`validate_wgsl`], also returning naga's analysis of the module.
fn validate_wgsl_info(name: &str, source: &str) -> Result<(naga::Module, naga::valid::ModuleInfo)> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| Error::Kernel {
        kernel: name.to_string(),
        message: format!("WGSL parse error:\n{}", e.emit_to_string(source)),
    })?;
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    );
    let info = validator.validate(&module).map_err(|e| Error::Kernel {
        kernel: name.to_string(),
        message: format!("WGSL validation error:\n{}", e.emit_to_string(source)),
    })?;
    Ok((module, info))
}

/// The bindings of group 0 that entry point `main` uses (declared globals it never
/// reaches, such as scene arrays a shared library declares, are left out of its layout).
fn used_bindings(module: &naga::Module, info: &naga::valid::ModuleInfo) -> std::collections::HashSet<u32> {
    let Some(ep) = module.entry_points.iter().position(|e| e.name == "main") else {
        return Default::default();
    };
    let uses = info.get_entry_point(ep);
    module
        .global_variables
        .iter()
        .filter(|(h, _)| !uses[*h].is_empty())
        .filter_map(|(_, v)| v.binding.as_ref())
        .filter(|b| b.group == 0)
        .map(|b| b.binding)
        .collect()
}

/// What a kernel asks of the device, read from its WGSL with naga: its bindings by kind,
/// its workgroup shape and its workgroup memory. [`check_limits`] compares it with a
/// device's [`wgpu::Limits`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct KernelNeeds {
    /// Storage buffers bound (`var<storage>`).
    pub storage_buffers: u32,
    /// Uniform buffers bound.
    pub uniform_buffers: u32,
    /// Storage textures bound.
    pub storage_textures: u32,
    /// Sampled textures bound.
    pub sampled_textures: u32,
    /// Samplers bound.
    pub samplers: u32,
    /// Bind groups used (highest group index + 1).
    pub bind_groups: u32,
    /// Bindings per group (highest binding index + 1).
    pub bindings_per_group: u32,
    /// `@workgroup_size` of `main` (0 where an override sets it).
    pub workgroup_size: [u32; 3],
    /// Bytes of `var<workgroup>` memory.
    pub workgroup_memory: u32,
}

impl KernelNeeds {
    /// Every limit of `limits` this kernel exceeds, as `(limit field, needed, allowed)`.
    pub fn exceeded(&self, limits: &wgpu::Limits) -> Vec<(&'static str, u64, u64)> {
        let [x, y, z] = self.workgroup_size;
        // (the limit's field name, what the kernel needs, what `limits` allows)
        macro_rules! limit {
            ($field:ident, $need:expr) => {
                (
                    stringify!($field),
                    u64::from($need),
                    u64::from(limits.$field),
                )
            };
        }
        let checks: [(&'static str, u64, u64); 12] = [
            limit!(max_storage_buffers_per_shader_stage, self.storage_buffers),
            limit!(max_uniform_buffers_per_shader_stage, self.uniform_buffers),
            limit!(max_storage_textures_per_shader_stage, self.storage_textures),
            limit!(max_sampled_textures_per_shader_stage, self.sampled_textures),
            limit!(max_samplers_per_shader_stage, self.samplers),
            limit!(max_bind_groups, self.bind_groups),
            limit!(max_bindings_per_bind_group, self.bindings_per_group),
            limit!(max_compute_workgroup_size_x, x),
            limit!(max_compute_workgroup_size_y, y),
            limit!(max_compute_workgroup_size_z, z),
            limit!(
                max_compute_invocations_per_workgroup,
                u64::from(x) * u64::from(y) * u64::from(z)
            ),
            limit!(max_compute_workgroup_storage_size, self.workgroup_memory),
        ];
        checks
            .into_iter()
            .filter(|&(_, need, have)| need > have)
            .collect()
    }
}

/// What kernel `name` asks of the device with its parameters bound as `params` (see
/// [`KernelNeeds`]).
pub fn kernel_needs(name: &str, params: ParamsBinding) -> Result<KernelNeeds> {
    let k = kernel_source(name)?;
    let (module, info) = validate_wgsl_info(k.name, &k.wgsl(params, &[])?)?;
    let used = used_bindings(&module, &info);
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).map_err(|e| Error::Kernel {
        kernel: k.name.to_string(),
        message: format!("type layout: {e}"),
    })?;
    let mut n = KernelNeeds::default();
    for (_, var) in module.global_variables.iter() {
        if var.space == naga::AddressSpace::WorkGroup {
            n.workgroup_memory += layouter[var.ty].size;
            continue;
        }
        let Some(b) = var
            .binding
            .as_ref()
            .filter(|b| b.group != 0 || used.contains(&b.binding))
        else {
            continue;
        };
        n.bind_groups = n.bind_groups.max(b.group + 1);
        n.bindings_per_group = n.bindings_per_group.max(b.binding + 1);
        match var.space {
            naga::AddressSpace::Storage { .. } => n.storage_buffers += 1,
            naga::AddressSpace::Uniform => n.uniform_buffers += 1,
            naga::AddressSpace::Handle => match &module.types[var.ty].inner {
                naga::TypeInner::Image {
                    class: naga::ImageClass::Storage { .. },
                    ..
                } => n.storage_textures += 1,
                naga::TypeInner::Image { .. } => n.sampled_textures += 1,
                naga::TypeInner::Sampler { .. } => n.samplers += 1,
                _ => {}
            },
            _ => {}
        }
    }
    if let Some(ep) = module.entry_points.iter().find(|e| e.name == "main") {
        n.workgroup_size = ep.workgroup_size;
    }
    Ok(n)
}

/// Checks that every kernel in `kernels`, as written (parameters in a uniform block), fits
/// `limits` (a device's); the error names `what` needs them, each kernel and each limit it
/// exceeds, with the numbers. [`KernelRegistry::check_limits`] checks the bindings a
/// device actually uses.
pub fn check_limits(what: &str, kernels: &[&str], limits: &wgpu::Limits) -> Result<()> {
    let bound: Vec<_> = kernels.iter().map(|&k| (k, ParamsBinding::Uniform)).collect();
    check_bound_limits(what, &bound, limits)
}

/// [`check_limits`] with each kernel's own parameter binding.
fn check_bound_limits(what: &str, kernels: &[(&str, ParamsBinding)], limits: &wgpu::Limits) -> Result<()> {
    let mut problems = Vec::new();
    for &(k, params) in kernels {
        for (limit, need, have) in kernel_needs(k, params)?.exceeded(limits) {
            problems.push(format!(
                "kernel '{k}' needs {limit} >= {need}, the device allows {have}"
            ));
        }
    }
    if problems.is_empty() {
        return Ok(());
    }
    Err(Error::Limits {
        what: what.to_string(),
        message: problems.join("; "),
    })
}

/// How many workgroups a dispatch runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grid {
    /// One invocation per element of this extent (pixels, rays, ...); the workgroup counts
    /// follow from the kernel's own `@workgroup_size`, read from its WGSL.
    Invocations([u32; 3]),
    /// These workgroup counts, for kernels whose workgroups stride over their data
    /// (reductions).
    Workgroups([u32; 3]),
}

impl Grid {
    /// One invocation per pixel of a `width x height` image.
    pub fn pixels(width: u32, height: u32) -> Self {
        Grid::Invocations([width, height, 1])
    }

    fn workgroups(self, size: [u32; 3]) -> [u32; 3] {
        match self {
            Grid::Invocations(n) => [0, 1, 2].map(|i| n[i].div_ceil(size[i].max(1))),
            Grid::Workgroups(g) => g,
        }
    }
}

/// Values of a kernel's WGSL `override` constants.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Specialisation(pub Vec<(&'static str, f64)>);

impl Specialisation {
    /// No overrides.
    pub fn none() -> Self {
        Self(Vec::new())
    }
    fn key(&self) -> Vec<(&'static str, u64)> {
        let mut k: Vec<_> = self.0.iter().map(|(n, v)| (*n, v.to_bits())).collect();
        k.sort();
        k
    }
}

type PipelineKey = (&'static str, Vec<(&'static str, u64)>);
/// A kernel and the values of its template parameters.
type ModuleKey = (&'static str, Vec<(&'static str, u32)>);
/// What the registry reads from a kernel's naga module once: per binding index of group 0
/// whether the kernel may write it, and the workgroup size of `main`.
#[derive(Debug)]
struct KernelInfo {
    writable: HashMap<u32, bool>,
    workgroup: [u32; 3],
    used: std::collections::HashSet<u32>,
}
type Info = Arc<KernelInfo>;
/// A compiled module and its bindings' access.
type CompiledModule = (Arc<wgpu::ShaderModule>, Info);
/// A pipeline and its bindings' access.
type CompiledPipeline = (Arc<wgpu::ComputePipeline>, Info);

/// Per binding of group 0: whether the kernel may write it (`read_write` storage, storage
/// textures that are not read-only); read from its naga module.
fn writable_bindings(module: &naga::Module) -> HashMap<u32, bool> {
    let mut out = HashMap::new();
    for (_, var) in module.global_variables.iter() {
        let Some(b) = &var.binding else { continue };
        let writable = match var.space {
            naga::AddressSpace::Storage { access } => access.contains(naga::StorageAccess::STORE),
            naga::AddressSpace::Handle => matches!(
                &module.types[var.ty].inner,
                naga::TypeInner::Image {
                    class: naga::ImageClass::Storage { access, .. },
                    ..
                } if access.contains(naga::StorageAccess::STORE)
            ),
            _ => false,
        };
        if b.group == 0 {
            out.insert(b.binding, writable);
        }
    }
    out
}

/// Compiled shader modules and pipelines of one device.
pub struct KernelRegistry {
    device: wgpu::Device,
    preferred: ParamsBinding,
    bindings: Mutex<HashMap<&'static str, ParamsBinding>>,
    modules: Mutex<HashMap<ModuleKey, CompiledModule>>,
    pipelines: Mutex<HashMap<PipelineKey, CompiledPipeline>>,
}

impl KernelRegistry {
    /// An empty registry binding kernel parameters as `preferred` where the device's limits
    /// allow; modules compile on first use.
    pub fn new(device: &wgpu::Device, preferred: ParamsBinding) -> Self {
        Self {
            device: device.clone(),
            preferred,
            bindings: Mutex::new(HashMap::new()),
            modules: Mutex::new(HashMap::new()),
            pipelines: Mutex::new(HashMap::new()),
        }
    }

    /// How kernel `name`'s parameters are bound on this device: the preferred binding
    /// when the kernel fits the device's limits with it, `Uniform` otherwise.
    pub fn params_binding(&self, name: &str) -> Result<ParamsBinding> {
        let k = kernel_source(name)?;
        if self.preferred == ParamsBinding::Uniform {
            return Ok(ParamsBinding::Uniform);
        }
        if let Some(&b) = self.bindings.lock().unwrap().get(k.name) {
            return Ok(b);
        }
        let fits = kernel_needs(k.name, self.preferred)?
            .exceeded(&self.device.limits())
            .is_empty();
        let b = if fits {
            self.preferred
        } else {
            ParamsBinding::Uniform
        };
        self.bindings.lock().unwrap().insert(k.name, b);
        Ok(b)
    }

    /// Checks that every kernel in `kernels`, bound as [`KernelRegistry::params_binding`]
    /// says, fits this device (see [`check_limits`]).
    pub fn check_limits(&self, what: &str, kernels: &[&str]) -> Result<()> {
        let bound = kernels
            .iter()
            .map(|&k| Ok((k, self.params_binding(k)?)))
            .collect::<Result<Vec<_>>>()?;
        check_bound_limits(what, &bound, &self.device.limits())
    }

    fn module(&self, k: &'static KernelSource, template: &[(&'static str, u32)]) -> Result<CompiledModule> {
        let key = (k.name, template.to_vec());
        if let Some(m) = self.modules.lock().unwrap().get(&key) {
            return Ok(m.clone());
        }
        let source = k.wgsl(self.params_binding(k.name)?, template)?;
        let (naga_module, naga_info) = validate_wgsl_info(k.name, &source)?;
        let workgroup = naga_module
            .entry_points
            .iter()
            .find(|e| e.name == "main")
            .map(|e| e.workgroup_size)
            .unwrap_or([1, 1, 1]);
        let info = Arc::new(KernelInfo {
            writable: writable_bindings(&naga_module),
            workgroup,
            used: used_bindings(&naga_module, &naga_info),
        });
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(&format!("subpixel.{}", k.name)),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Kernel {
                kernel: k.name.to_string(),
                message: format!("shader module creation failed: {e}"),
            });
        }
        let compiled = (Arc::new(module), info);
        self.modules.lock().unwrap().insert(key, compiled.clone());
        Ok(compiled)
    }

    /// The compute pipeline of kernel `name` (entry point `main`) under `spec`, cached.
    pub fn pipeline(&self, name: &str, spec: &Specialisation) -> Result<Arc<wgpu::ComputePipeline>> {
        Ok(self.compiled(name, spec)?.0)
    }

    /// The pipeline and, per binding, whether the kernel writes it.
    fn compiled(&self, name: &str, spec: &Specialisation) -> Result<CompiledPipeline> {
        let k = kernel_source(name)?;
        let key = (k.name, spec.key());
        if let Some(p) = self.pipelines.lock().unwrap().get(&key) {
            return Ok(p.clone());
        }
        // Template parameters shape the source; the other names are `override` constants.
        let declared = super::template::params(k.source);
        let mut template = Vec::new();
        let mut constants = Vec::new();
        for &(n, v) in &spec.0 {
            if declared.iter().any(|(d, _)| *d == n) {
                if v < 0.0 || v.fract() != 0.0 || v > u32::MAX as f64 {
                    return Err(Error::Kernel {
                        kernel: k.name.to_string(),
                        message: format!("template parameter {n} = {v} is not a non-negative integer"),
                    });
                }
                template.push((n, v as u32));
            } else {
                constants.push((n, v));
            }
        }
        template.sort_unstable();
        let (module, info) = self.module(k, &template)?;
        let started = std::time::Instant::now();
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(&format!("subpixel.{}", k.name)),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    zero_initialize_workgroup_memory: false,
                },
                cache: None,
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Kernel {
                kernel: k.name.to_string(),
                message: format!("pipeline creation failed (specialisation {:?}): {e}", spec.0),
            });
        }
        log::debug!(
            "pipeline {} {template:?} created in {:.2?}",
            k.name,
            started.elapsed()
        );
        let compiled = (Arc::new(pipeline), info);
        self.pipelines.lock().unwrap().insert(key, compiled.clone());
        Ok(compiled)
    }

    /// Builds a ready-to-record dispatch: pipeline, bind group (uniform `params` at binding 0
    /// when non-empty, then `buffers` at bindings 1..), and the workgroup counts of `grid`.
    pub fn dispatch(
        &self,
        name: &str,
        spec: &Specialisation,
        params: &[u8],
        buffers: &[&wgpu::Buffer],
        grid: Grid,
    ) -> Result<Dispatch> {
        let max_binding = self.device.limits().max_storage_buffer_binding_size;
        for (i, b) in buffers.iter().enumerate() {
            if b.size() > max_binding {
                return Err(Error::Kernel {
                    kernel: name.to_string(),
                    message: format!(
                        "binding {} is {} bytes, more than the adapter's storage binding limit of {max_binding}",
                        i + 1,
                        b.size()
                    ),
                });
            }
        }
        let resources: Vec<wgpu::BindingResource<'_>> =
            buffers.iter().map(|b| b.as_entire_binding()).collect();
        let (mut d, info) = self.bind(name, spec, params, &resources, grid)?;
        // Compulsory traffic: each distinct buffer once, by whether the kernel writes it.
        let mut seen: Vec<&wgpu::Buffer> = Vec::new();
        d.bytes_read = params.len() as u64;
        for (i, b) in buffers.iter().enumerate() {
            if seen.contains(b) || !info.used.contains(&(i as u32 + 1)) {
                continue;
            }
            seen.push(b);
            if info.writable.get(&(i as u32 + 1)).copied().unwrap_or(false) {
                d.bytes_written += b.size();
            } else {
                d.bytes_read += b.size();
            }
        }
        Ok(d)
    }

    /// Like [`KernelRegistry::dispatch`] with arbitrary resources (textures, samplers) at
    /// bindings 1...
    pub fn dispatch_with(
        &self,
        name: &str,
        spec: &Specialisation,
        params: &[u8],
        resources: &[wgpu::BindingResource<'_>],
        grid: Grid,
    ) -> Result<Dispatch> {
        Ok(self.bind(name, spec, params, resources, grid)?.0)
    }

    /// The dispatch of [`KernelRegistry::dispatch_with`] and what the registry knows of
    /// its kernel.
    fn bind(
        &self,
        name: &str,
        spec: &Specialisation,
        params: &[u8],
        resources: &[wgpu::BindingResource<'_>],
        grid: Grid,
    ) -> Result<(Dispatch, Info)> {
        let (pipeline, info) = self.compiled(name, spec)?;
        let groups = grid.workgroups(info.workgroup);
        let limit = self.device.limits().max_compute_workgroups_per_dimension;
        if groups.contains(&0) {
            return Err(Error::Kernel {
                kernel: name.to_string(),
                message: format!("zero-sized dispatch {groups:?}"),
            });
        }
        if groups.iter().any(|&g| g > limit) {
            return Err(Error::Kernel {
                kernel: name.to_string(),
                message: format!(
                    "dispatch {groups:?} exceeds the adapter's {limit} workgroups per dimension"
                ),
            });
        }
        let uniform = (!params.is_empty()).then(|| {
            use wgpu::util::DeviceExt;
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!("subpixel.{name}.params")),
                contents: params,
                usage: match self.preferred {
                    ParamsBinding::Uniform => wgpu::BufferUsages::UNIFORM,
                    ParamsBinding::Storage => wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::STORAGE,
                } | wgpu::BufferUsages::COPY_DST,
            })
        });
        let mut entries = Vec::new();
        if let Some(u) = &uniform {
            entries.push(wgpu::BindGroupEntry {
                binding: 0,
                resource: u.as_entire_binding(),
            });
        }
        // Resources the kernel declares but never reaches are not in its layout.
        for (i, r) in resources.iter().enumerate() {
            if info.used.contains(&(i as u32 + 1)) {
                entries.push(wgpu::BindGroupEntry {
                    binding: i as u32 + 1,
                    resource: r.clone(),
                });
            }
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(&format!("subpixel.{name}")),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Kernel {
                kernel: name.to_string(),
                message: format!("bind group does not match the kernel: {e}"),
            });
        }
        let d = Dispatch {
            kernel: kernel_source(name)?.name,
            pipeline,
            bind_group,
            groups,
            uniform,
            bytes_read: 0,
            bytes_written: 0,
            then: Vec::new(),
        };
        Ok((d, info))
    }
}

/// A kernel invocation with its resources bound, recorded into a compute pass as often as
/// needed (the denoiser builds its dispatches once per resolution and replays them).
#[derive(Debug)]
pub struct Dispatch {
    /// Kernel name.
    pub kernel: &'static str,
    pipeline: Arc<wgpu::ComputePipeline>,
    bind_group: wgpu::BindGroup,
    /// Workgroup counts.
    pub groups: [u32; 3],
    uniform: Option<wgpu::Buffer>,
    /// Bytes of the buffers (and parameters) it only reads, each distinct buffer counted
    /// once: its compulsory memory traffic, for roofline models. 0 for dispatches bound
    /// with [`KernelRegistry::dispatch_with`] (textures).
    pub bytes_read: u64,
    /// Bytes of the buffers it may write, each counted once.
    pub bytes_written: u64,
    /// More dispatches recorded right after this one: the parts of one operation that
    /// does not fit a single dispatch (a convolution whose weights span several buffers).
    then: Vec<Dispatch>,
}

impl Dispatch {
    /// This dispatch followed by `rest` as one operation (recorded together, traffic
    /// summed).
    pub fn chain(mut self, rest: impl IntoIterator<Item = Dispatch>) -> Self {
        for d in rest {
            self.bytes_read += d.bytes_read;
            self.bytes_written += d.bytes_written;
            self.then.push(d);
        }
        self
    }

    /// How many dispatches it records (1, or more for a chained operation).
    pub fn parts(&self) -> usize {
        1 + self.then.iter().map(Dispatch::parts).sum::<usize>()
    }

    /// Rewrites the uniform parameters in place (same size as when bound), so a dispatch
    /// whose parameters change every frame is built once. Like `Queue::write_buffer`, it
    /// takes effect at the next submission: record the dispatch once per submission.
    pub fn write_params(&self, queue: &wgpu::Queue, params: &[u8]) {
        if let Some(u) = &self.uniform {
            queue.write_buffer(u, 0, params);
        }
        for d in &self.then {
            d.write_params(queue, params);
        }
    }

    /// Records the dispatch into `pass`.
    pub fn record(&self, pass: &mut wgpu::ComputePass<'_>) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.dispatch_workgroups(self.groups[0], self.groups[1], self.groups[2]);
        for d in &self.then {
            d.record(pass);
        }
    }

    /// Records the dispatch in its own compute pass on `encoder`, labelled by the kernel.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder) {
        self.record(&mut super::Profiler::pass(encoder, self.kernel, None));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every embedded WGSL file parses and validates with naga; no GPU needed.
    #[test]
    fn every_kernel_validates_with_naga() {
        for k in KERNELS {
            let source = k
                .wgsl(ParamsBinding::Uniform, &[])
                .unwrap_or_else(|e| panic!("{e}"));
            let module = validate_wgsl(k.name, &source).unwrap_or_else(|e| panic!("{e}"));
            assert!(
                module.entry_points.iter().any(|e| e.name == "main"),
                "kernel {} has no `main` entry point",
                k.name
            );
        }
        // Flags of the SSR kernels whose default is off, each on.
        for (name, flag) in [("ssr/fold_emission", "ESCAPED"), ("ssr/exposure_final", "SHARED")] {
            let k = kernel_source(name).unwrap();
            let source = k.wgsl(ParamsBinding::Uniform, &[(flag, 1)]).unwrap();
            validate_wgsl(name, &source).unwrap_or_else(|e| panic!("{name} {flag}: {e}"));
        }
    }

    /// SPIR-V of a validated module with its override constants at their defaults (what the
    /// Vulkan backend compiles), through naga's SPIR-V writer.
    fn spirv(module: &naga::Module, info: &naga::valid::ModuleInfo) -> std::result::Result<Vec<u32>, String> {
        let constants = naga::back::PipelineConstants::default();
        let (module, info) =
            naga::back::pipeline_constants::process_overrides(module, info, None, &constants)
                .map_err(|e| e.to_string())?;
        let options = naga::back::spv::Options {
            lang_version: (1, 5),
            ..Default::default()
        };
        naga::back::spv::write_vec(&module, &info, &options, None).map_err(|e| e.to_string())
    }

    /// Every expansion of a template kernel the crate can ask for validates with naga and
    /// translates to SPIR-V: each conv tiling the autotuner may pick (register-blocked, and
    /// cooperative-matrix ones with 16x16 and 8x8 matrices and subgroups of 32 and 8, whose
    /// SPIR-V declares the cooperative-matrix capability: what a machine without tensor
    /// cores can check of them), for 1 to 4 inputs, in both parameter bindings, with f32 and
    /// f16 storage; the f16 variants of the other kernels. `SUBPIXEL_DUMP_SPIRV=DIR` writes
    /// the cooperative ones' SPIR-V there (for `spirv-val`).
    #[test]
    fn every_template_expansion_validates_and_translates_to_spirv() {
        use crate::nn::conv::ConvKernel;
        let mut n = 0;
        for kernel in ConvKernel::blocked_tilings()
            .into_iter()
            .chain(ConvKernel::winograd_tilings())
            .chain(ConvKernel::texture_tilings())
            .chain(ConvKernel::coop_tilings())
        {
            for inputs in 1..=4 {
                for params in [ParamsBinding::Uniform, ParamsBinding::Storage] {
                    // f32 storage, and f16 for the first input and the output.
                    for f16 in [0, 1] {
                        let mut template = vec![("N_IN", inputs), ("F16_IN0", f16), ("F16_OUT", f16)];
                        let name = match kernel {
                            ConvKernel::Blocked { .. } | ConvKernel::Winograd { .. } => {
                                let l = kernel.uniform_layout().expect("uniform weights");
                                // The texture output on half the cases.
                                let tex_out = inputs % 2;
                                template.extend([
                                    l.tiling,
                                    ("COB", l.cob),
                                    ("TEX_IN", l.tex as u32),
                                    ("TEX_OUT", tex_out),
                                ]);
                                l.kernel
                            }
                            ConvKernel::Coop { mt, nt, rt } => {
                                template.extend([
                                    ("MT", mt),
                                    ("NT", nt),
                                    ("RT", rt),
                                    ("SG", if f16 == 0 { 32 } else { 8 }),
                                    ("T", if (inputs + f16) % 2 == 0 { 16 } else { 8 }),
                                ]);
                                "nn/conv3x3_coop"
                            }
                            ConvKernel::Generic => unreachable!(),
                        };
                        let k = kernel_source(name).unwrap();
                        let case = format!("{kernel} x{inputs} f16 {f16} {params:?}");
                        let src = k.wgsl(params, &template).unwrap();
                        let (module, info) =
                            validate_wgsl_info(k.name, &src).unwrap_or_else(|e| panic!("{case}: {e}"));
                        let words = spirv(&module, &info).unwrap_or_else(|e| panic!("{case}: {e}"));
                        if let ConvKernel::Coop { .. } = kernel {
                            if let Ok(dir) = std::env::var("SUBPIXEL_DUMP_SPIRV") {
                                let path = format!("{dir}/{kernel}-x{inputs}-f16{f16}-{params:?}.spv");
                                std::fs::write(path, bytemuck::cast_slice::<u32, u8>(&words)).unwrap();
                            }
                            // OpCapability (17, one operand) CooperativeMatrixKHR (6022).
                            assert!(
                                words.windows(2).any(|w| w == [(2 << 16) | 17, 6022]),
                                "{case}: no CooperativeMatrixKHR capability"
                            );
                        }
                        n += 1;
                    }
                }
            }
        }
        assert!(n >= 200 + 160, "{n} expansions");
        // The f16 storage variants of the other kernels that have them, every flag alone.
        for (name, flags) in [
            (
                "nn/conv3x3",
                &["F16_IN0", "F16_IN1", "F16_IN2", "F16_IN3", "F16_OUT"][..],
            ),
            ("nn/resample2x", &["F16_IN0", "F16_OUT"][..]),
            ("nn/to_texture", &["F16_IN0"][..]),
            (
                "nn/tfa_blend",
                &["F16_IN0", "F16_IN1", "F16_IN2", "F16_IN3", "F16_IN4", "F16_OUT"][..],
            ),
            ("ssr/warp_history", &["F16_IN0", "F16_IN1", "F16_OUT"][..]),
            ("nn/remodulate", &["F16_IN0", "F16_IN1"][..]),
            ("nn/demodulate", &["F16_IN0", "F16_IN1"][..]),
        ] {
            let k = kernel_source(name).unwrap();
            for flag in flags {
                let src = k.wgsl(ParamsBinding::Storage, &[(flag, 1)]).unwrap();
                assert!(src.starts_with("enable f16;"), "{name} {flag}");
                validate_wgsl(name, &src).unwrap_or_else(|e| panic!("{name} {flag}: {e}"));
            }
        }
    }

    /// Every `.wgsl` file under `wgsl/` is registered, so none escapes validation.
    #[test]
    fn every_wgsl_file_is_registered() {
        fn walk(dir: &std::path::Path, root: &std::path::Path, out: &mut Vec<String>) {
            for e in std::fs::read_dir(dir).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    walk(&p, root, out);
                } else if p.extension().is_some_and(|x| x == "wgsl") {
                    let rel = p.strip_prefix(root).unwrap().with_extension("");
                    out.push(rel.to_string_lossy().replace('\\', "/"));
                }
            }
        }
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("wgsl");
        let mut files = Vec::new();
        walk(&root, &root, &mut files);
        let libs = libraries();
        for f in files {
            let is_lib = f.split('/').any(|part| part == "lib");
            if is_lib {
                // A library must be composed into at least one kernel, which validates it.
                assert!(
                    libs.contains(&f.as_str()),
                    "library wgsl/{f}.wgsl is included by no kernel in KERNELS"
                );
                assert!(
                    kernel_source(&f).is_err(),
                    "library wgsl/{f}.wgsl is registered as a kernel"
                );
            } else {
                assert!(kernel_source(&f).is_ok(), "wgsl/{f}.wgsl is not in KERNELS");
            }
        }
    }

    /// Composed kernels contain their libraries verbatim, in order, before the entry file.
    #[test]
    fn composed_kernels_embed_their_libraries() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("wgsl");
        for k in KERNELS.iter().filter(|k| !k.includes.is_empty()) {
            let mut at = 0;
            for lib in k.includes {
                let text = std::fs::read_to_string(root.join(format!("{lib}.wgsl"))).unwrap();
                let pos = k.source[at..]
                    .find(&text)
                    .unwrap_or_else(|| panic!("{}: library {lib} missing or out of order", k.name));
                at += pos + text.len();
            }
            let entry = std::fs::read_to_string(root.join(format!("{}.wgsl", k.name))).unwrap();
            assert!(
                k.source.ends_with(&entry),
                "{}: entry file must come last",
                k.name
            );
            // Libraries declare no bindings: those belong to the entry file; except the
            // tracer's scene, declared once for all tracer kernels, and the inputs, weights
            // and output of the convolutions with uniform weights (after the entry file's
            // parameter block).
            for lib in k.includes {
                let text = std::fs::read_to_string(root.join(format!("{lib}.wgsl"))).unwrap();
                assert!(
                    !text.contains("@binding") || ["trace/lib/scene", "nn/lib/uniform_weights"].contains(lib),
                    "library {lib} declares a binding"
                );
                assert!(
                    !text.contains("@compute"),
                    "library {lib} declares an entry point"
                );
            }
        }
    }

    /// Issue 12 item 10: the denoiser's kernels fit WebGPU's default limits (the portable
    /// embedding API), and a tighter device is refused naming the kernel and the limit.
    #[test]
    fn denoiser_kernels_fit_the_default_limits() {
        let ssr = crate::ssr::KERNELS_USED;
        check_limits("the denoiser", ssr, &wgpu::Limits::default()).unwrap();
        // Independent expectations: counted by hand from the WGSL.
        let pack = kernel_needs("ssr/pack_inputs", ParamsBinding::Uniform).unwrap();
        assert_eq!((pack.storage_buffers, pack.uniform_buffers), (7, 1));
        let blend = kernel_needs("nn/tfa_blend", ParamsBinding::Uniform).unwrap();
        assert_eq!((blend.storage_buffers, blend.workgroup_size), (8, [8, 8, 1]));
        let store = kernel_needs("ssr/store_output", ParamsBinding::Uniform).unwrap();
        assert_eq!((store.storage_buffers, store.storage_textures), (1, 1));
        assert_eq!(
            kernel_needs("ssr/exposure_partial", ParamsBinding::Uniform)
                .unwrap()
                .workgroup_memory,
            4 * 256 * 16
        );
        let tight = wgpu::Limits {
            max_storage_buffers_per_shader_stage: 7,
            max_compute_workgroup_storage_size: 8192,
            ..wgpu::Limits::default()
        };
        let e = check_limits("the denoiser", ssr, &tight).unwrap_err().to_string();
        assert!(
            e.contains("the denoiser")
                && e.contains("kernel 'nn/tfa_blend' needs max_storage_buffers_per_shader_stage >= 8, the device allows 7")
                && e.contains("kernel 'ssr/exposure_partial' needs max_compute_workgroup_storage_size >= 16384"),
            "{e}"
        );
        assert!(!e.contains("nn/conv3x3"), "conv3x3 binds 7: {e}");
    }

    /// Every kernel fits the limits the crate's own device asks for where it runs them: the
    /// adapter's, at least the downlevel defaults for the image kernels.
    #[test]
    fn every_kernel_has_known_needs() {
        for k in KERNELS {
            let n = kernel_needs(k.name, ParamsBinding::Uniform).unwrap();
            assert!(n.bind_groups == 1, "{}: every kernel uses group 0 only", k.name);
            assert!(n.workgroup_size.iter().all(|&s| s > 0), "{}", k.name);
        }
    }

    /// Every kernel's parameter block can be bound as a storage buffer (the lavapipe
    /// route): the rewritten WGSL validates and trades exactly one uniform block for one
    /// storage buffer; kernels without parameters are unchanged.
    #[test]
    fn every_kernel_binds_its_parameters_either_way() {
        for k in KERNELS {
            let u = kernel_needs(k.name, ParamsBinding::Uniform).unwrap();
            let s = kernel_needs(k.name, ParamsBinding::Storage).unwrap();
            let params = k.source.contains(PARAMS_UNIFORM) as u32;
            assert_eq!(s.uniform_buffers, u.uniform_buffers - params, "{}", k.name);
            assert_eq!(s.storage_buffers, u.storage_buffers + params, "{}", k.name);
            // Only the blocked and Winograd convolutions have a second uniform block (their
            // weights).
            let extra = matches!(k.name, "nn/conv3x3_blocked" | "nn/conv3x3_winograd") as u32;
            assert_eq!(u.uniform_buffers, params + extra, "{}", k.name);
        }
    }

    #[test]
    fn unknown_kernel_is_a_named_error() {
        let e = kernel_source("nn/nope").unwrap_err().to_string();
        assert!(e.contains("nn/nope"), "{e}");
    }

    #[test]
    fn broken_wgsl_error_names_the_kernel() {
        let e = validate_wgsl("nn/broken", "fn main( {").unwrap_err().to_string();
        assert!(e.contains("nn/broken") && e.contains("parse"), "{e}");
    }

    /// The uniform `Params` struct of every kernel has the same size in WGSL (naga's
    /// layout) as in Rust.
    #[test]
    fn param_struct_sizes_match_naga() {
        for (name, rust_size) in crate::nn::ops::PARAM_SIZES
            .iter()
            .chain(crate::nn::conv::PARAM_SIZES)
            .chain(crate::ssr::PARAM_SIZES)
            .chain(crate::view::PARAM_SIZES)
            .chain(crate::render::PARAM_SIZES)
        {
            let k = kernel_source(name).unwrap();
            let module = validate_wgsl(k.name, &k.wgsl(ParamsBinding::Uniform, &[]).unwrap()).unwrap();
            let mut layouter = naga::proc::Layouter::default();
            layouter.update(module.to_ctx()).unwrap();
            let (_, var) = module
                .global_variables
                .iter()
                .find(|(_, v)| {
                    v.space == naga::AddressSpace::Uniform
                        && v.binding.as_ref().is_some_and(|b| b.binding == 0)
                })
                .unwrap_or_else(|| panic!("{name} has no uniform block"));
            let size = layouter[var.ty].size as usize;
            assert_eq!(
                size, *rust_size,
                "kernel {name}: WGSL Params is {size} bytes, Rust {rust_size}"
            );
        }
    }
}
