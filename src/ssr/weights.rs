//! Loading SSR weights from safetensors (PyTorch names, OIHW conv layout) with every name
//! and shape checked.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use super::config::SsrConfig;
use crate::error::{Error, Result};

/// Value of the `format` metadata key.
pub const WEIGHTS_FORMAT: &str = "subpixel-ssr";
/// Weights file version this engine writes; it reads 1 and 2. A file's version is its
/// config's: version 1 predates exposure normalisation, remodulation with the current albedo
/// and the geometric history test, and runs without them ([`SsrConfig::legacy`]).
pub const WEIGHTS_VERSION: u32 = super::config::CONFIG_VERSION;

/// Network weights and their provenance.
#[derive(Debug, Clone)]
pub struct Weights {
    /// Where they came from (a file path, or `<memory>`).
    pub path: PathBuf,
    /// Network configuration.
    pub config: SsrConfig,
    /// Tensors by PyTorch name, row-major f32.
    pub tensors: HashMap<String, Vec<f32>>,
    /// The file's `__metadata__` (format, version, config, provenance, metrics, ...).
    pub metadata: BTreeMap<String, String>,
}

impl Weights {
    /// Loads and checks a weights file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = crate::io::read_regular(path, u64::MAX).map_err(|e| Error::Weights {
            path: path.to_path_buf(),
            message: format!("cannot read: {e}"),
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses and checks weights from bytes; `path` only names them in errors.
    pub fn from_bytes(bytes: &[u8], path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let err = |message: String| Error::Weights {
            path: path.clone(),
            message,
        };
        let (_, header) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| {
            err(format!(
                "not a valid safetensors file (truncated or corrupt?): {e}"
            ))
        })?;
        let metadata: BTreeMap<String, String> = header
            .metadata()
            .clone()
            .unwrap_or_default()
            .into_iter()
            .collect();
        match metadata.get("format") {
            Some(f) if f == WEIGHTS_FORMAT => {}
            Some(f) => {
                return Err(err(format!(
                    "metadata format is '{f}', expected '{WEIGHTS_FORMAT}'"
                )));
            }
            None => {
                return Err(err(format!(
                    "no 'format' in the metadata (expected '{WEIGHTS_FORMAT}')"
                )));
            }
        }
        let version = match metadata.get("version").map(|v| v.parse::<u32>()) {
            Some(Ok(v @ (1 | WEIGHTS_VERSION))) => v,
            Some(Ok(v)) => {
                return Err(err(format!(
                    "version {v}, this engine reads versions 1 and {WEIGHTS_VERSION}"
                )));
            }
            _ => return Err(err("metadata 'version' is missing or not an integer".into())),
        };
        let config: SsrConfig = serde_json::from_str(
            metadata
                .get("config")
                .ok_or_else(|| err("no 'config' in the metadata".into()))?,
        )
        .map_err(|e| err(format!("metadata 'config' is not a valid SSR config: {e}")))?;
        config.validate().map_err(|e| err(e.to_string()))?;
        if config.version != version {
            return Err(err(format!(
                "metadata 'version' is {version} but its config is version {}",
                config.version
            )));
        }
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| {
            err(format!(
                "not a valid safetensors file (truncated or corrupt?): {e}"
            ))
        })?;

        let mut tensors = HashMap::new();
        let mut expected = Vec::new();
        for l in config.layers() {
            let cin: u32 = l.inputs.iter().sum();
            expected.push((
                format!("{}.weight", l.name),
                vec![l.cout as usize, cin as usize, 3, 3],
            ));
            expected.push((format!("{}.bias", l.name), vec![l.cout as usize]));
        }
        for (name, shape) in &expected {
            let view = st
                .tensor(name)
                .map_err(|_| err(format!("tensor '{name}' is missing (expected shape {shape:?})")))?;
            if view.shape() != shape.as_slice() {
                return Err(err(format!(
                    "tensor '{name}' has shape {:?}, expected {shape:?}",
                    view.shape()
                )));
            }
            if view.dtype() != safetensors::Dtype::F32 {
                return Err(err(format!(
                    "tensor '{name}' is {:?}, expected F32",
                    view.dtype()
                )));
            }
            let data: Vec<f32> = view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            if let Some(i) = data.iter().position(|v| !v.is_finite()) {
                return Err(err(format!(
                    "tensor '{name}' holds a non-finite value at index {i}"
                )));
            }
            tensors.insert(name.clone(), data);
        }
        let mut unexpected: Vec<&str> = st
            .names()
            .into_iter()
            .filter(|n| !expected.iter().any(|(e, _)| e == n))
            .collect();
        unexpected.sort();
        if !unexpected.is_empty() {
            return Err(err(format!(
                "unexpected tensors {unexpected:?} (config {:?} has no such layers)",
                config
            )));
        }
        Ok(Self {
            path,
            config,
            tensors,
            metadata,
        })
    }

    /// Deterministic pseudo-random weights (He-scaled) for `config`: for benchmarks and
    /// tests of the plumbing only, never a denoiser ([`Weights::is_random_init`] is true).
    pub fn random(config: &SsrConfig, seed: u64) -> Result<Self> {
        config.validate()?;
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut tensors = HashMap::new();
        for l in config.layers() {
            let cin: u32 = l.inputs.iter().sum();
            let scale = (6.0 / (9.0 * cin as f64)).sqrt();
            let n = (l.cout * cin * 9) as usize;
            tensors.insert(
                format!("{}.weight", l.name),
                (0..n).map(|_| (next() * scale) as f32).collect(),
            );
            tensors.insert(
                format!("{}.bias", l.name),
                (0..l.cout).map(|_| (next() * 0.05) as f32).collect(),
            );
        }
        let metadata = BTreeMap::from([
            ("format".to_string(), WEIGHTS_FORMAT.to_string()),
            ("version".to_string(), config.version.to_string()),
            (
                "config".to_string(),
                serde_json::to_string(config).expect("config serialises"),
            ),
            (
                "provenance".to_string(),
                "\"random-init: for tests only, not a denoiser\"".to_string(),
            ),
        ]);
        Ok(Self {
            path: PathBuf::from("<random>"),
            config: config.clone(),
            tensors,
            metadata,
        })
    }

    /// Weight and bias of layer `name`.
    pub fn layer(&self, name: &str) -> Result<(&[f32], &[f32])> {
        let get = |k: String| {
            self.tensors
                .get(&k)
                .map(|v| v.as_slice())
                .ok_or_else(|| Error::Weights {
                    path: self.path.clone(),
                    message: format!("tensor '{k}' is missing"),
                })
        };
        Ok((get(format!("{name}.weight"))?, get(format!("{name}.bias"))?))
    }

    /// The `provenance` metadata (JSON text), if any.
    pub fn provenance(&self) -> Option<&str> {
        self.metadata.get("provenance").map(|s| s.as_str())
    }

    /// Whether these are random-initialised test weights rather than a trained denoiser.
    pub fn is_random_init(&self) -> bool {
        self.provenance().is_some_and(|p| p.contains("random-init"))
    }
}
