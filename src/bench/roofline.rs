//! Roofline model of a frame on a named GPU (issue 14): each pass takes the longer of its
//! FLOPs at the GPU's FP32 peak (or, for the convolutions when the model puts them on tensor
//! cores, its dense f16 tensor peak with f32 sums) and its compulsory memory traffic at the
//! GPU's bandwidth, plus a fixed cost per pass. It judges kernel designs on paper where no such GPU is at
//! hand; where one is, `subpixel bench denoise` prints it beside the measured time.

use crate::error::{Error, Result};
use crate::ssr::StepCost;

/// A GPU as the model sees it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GpuModel {
    /// Name.
    pub name: String,
    /// FP32 peak (non-tensor), GFLOP/s.
    pub peak_gflops: f64,
    /// Dense f16 tensor-core peak with f32 accumulation, GFLOP/s.
    pub tensor_gflops: f64,
    /// Whether the convolutions' FLOPs run at [`GpuModel::tensor_gflops`] (the
    /// `nn/conv3x3_coop` kernel) rather than at the FP32 peak.
    pub tensor_cores: bool,
    /// Memory bandwidth, GB/s.
    pub bandwidth_gbs: f64,
    /// Fixed cost per pass (dispatch and barrier), microseconds.
    pub pass_us: f64,
}

/// Presets: vendor FP32 peaks, dense f16 tensor peaks with f32 accumulation (H100 SXM:
/// 989.4 TFLOP/s; the RTX 4070, a GeForce part, runs f32 accumulation at half its f16 rate:
/// 58.3) and memory bandwidths; 2 us per pass is an assumption (dispatches in one command
/// buffer with a barrier between them).
pub const PRESETS: &[(&str, &str, f64, f64, f64, f64)] = &[
    (
        "h100",
        "NVIDIA H100 SXM (model)",
        66_900.0,
        989_400.0,
        3_350.0,
        2.0,
    ),
    (
        "rtx4070",
        "NVIDIA RTX 4070 (model)",
        29_150.0,
        58_300.0,
        504.0,
        2.0,
    ),
];

impl GpuModel {
    /// The preset named `name` (`h100`, `rtx4070`).
    pub fn preset(name: &str) -> Result<Self> {
        PRESETS
            .iter()
            .find(|p| p.0 == name.to_ascii_lowercase())
            .map(|&(_, n, f, t, b, l)| GpuModel {
                name: n.to_string(),
                peak_gflops: f,
                tensor_gflops: t,
                tensor_cores: false,
                bandwidth_gbs: b,
                pass_us: l,
            })
            .ok_or_else(|| {
                let names: Vec<&str> = PRESETS.iter().map(|p| p.0).collect();
                Error::Invalid(format!("GPU model '{name}': expected one of {names:?}"))
            })
    }

    /// The model with the convolutions on tensor cores (or not).
    pub fn with_tensor_cores(mut self, on: bool) -> Self {
        self.tensor_cores = on;
        self
    }

    /// The peak pass `c`'s FLOPs run at, GFLOP/s.
    fn peak_for(&self, c: &StepCost) -> f64 {
        if self.tensor_cores && c.matrix {
            self.tensor_gflops
        } else {
            self.peak_gflops
        }
    }

    /// Modelled milliseconds of one pass.
    pub fn pass_ms(&self, c: &StepCost) -> f64 {
        let compute = c.flops as f64 / (self.peak_for(c) * 1e9);
        let memory = (c.bytes_read + c.bytes_written) as f64 / (self.bandwidth_gbs * 1e9);
        compute.max(memory) * 1e3 + self.pass_us * 1e-3
    }

    /// Whether the pass is bound by memory (else by compute).
    pub fn memory_bound(&self, c: &StepCost) -> bool {
        (c.bytes_read + c.bytes_written) as f64 / self.bandwidth_gbs > c.flops as f64 / self.peak_for(c)
    }
}

/// One pass in the model.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ModelledPass {
    /// Stage.
    pub stage: String,
    /// Label.
    pub name: String,
    /// FLOPs per frame.
    pub flops: u64,
    /// Bytes read per frame.
    pub bytes_read: u64,
    /// Bytes written per frame.
    pub bytes_written: u64,
    /// Modelled time, ms.
    pub modelled_ms: f64,
    /// `"memory"` or `"compute"`.
    pub bound: &'static str,
}

/// The model of every pass (its bytes as the engine moves them: f16 activations, when the
/// network runs with them, count half).
pub fn model(gpu: &GpuModel, costs: &[StepCost]) -> Vec<ModelledPass> {
    costs
        .iter()
        .map(|c| ModelledPass {
            stage: c.stage.to_string(),
            name: c.label.clone(),
            flops: c.flops,
            bytes_read: c.bytes_read,
            bytes_written: c.bytes_written,
            modelled_ms: gpu.pass_ms(c),
            bound: if gpu.memory_bound(c) { "memory" } else { "compute" },
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cost(flops: u64, bytes: u64) -> StepCost {
        StepCost {
            stage: "unet",
            label: "x".into(),
            flops,
            bytes_read: bytes,
            bytes_written: 0,
            matrix: true,
        }
    }

    /// Analytic cases: 1 TFLOP at 66.9 TFLOP/s is 14.95 ms; 3.35 GB at 3,350 GB/s is 1 ms;
    /// the longer wins; each pass adds its fixed cost.
    #[test]
    fn passes_take_the_longer_of_compute_and_memory() {
        let h = GpuModel::preset("H100").unwrap();
        let t = h.pass_ms(&cost(1_000_000_000_000, 0));
        assert!((t - (1000.0 / 66.9 + 0.002)).abs() < 1e-9, "{t}");
        let t = h.pass_ms(&cost(0, 3_350_000_000));
        assert!((t - 1.002).abs() < 1e-9, "{t}");
        assert!(h.memory_bound(&cost(1, 1_000)) && !h.memory_bound(&cost(1_000_000, 1)));
        let e = GpuModel::preset("a770").unwrap_err().to_string();
        assert!(e.contains("a770") && e.contains("h100"), "{e}");
    }

    /// With tensor cores, a convolution's 1 TFLOP takes 1 / 989.4 s on the H100 and a pass
    /// that is not a matrix product keeps the FP32 peak; 1 GB/s-bound passes do not change.
    #[test]
    fn tensor_cores_speed_up_matrix_passes_only() {
        let h = GpuModel::preset("h100").unwrap().with_tensor_cores(true);
        let t = h.pass_ms(&cost(1_000_000_000_000, 0));
        assert!((t - (1000.0 / 989.4 + 0.002)).abs() < 1e-9, "{t}");
        let blend = StepCost {
            matrix: false,
            ..cost(1_000_000_000_000, 0)
        };
        assert!((h.pass_ms(&blend) - (1000.0 / 66.9 + 0.002)).abs() < 1e-9);
        assert!((h.pass_ms(&cost(1, 3_350_000_000)) - 1.002).abs() < 1e-9);
        assert!(h.memory_bound(&cost(1_000_000, 3_350_000)));
    }
}
