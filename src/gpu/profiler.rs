//! GPU timestamp profiler: one scope per compute pass, resolved and read back each frame,
//! summarised as median and p95 over frames. Falls back to CPU wall time when the adapter
//! has no timestamp queries.

use std::collections::BTreeMap;

use super::Gpu;
use crate::error::Result;

/// Median / p95 / mean over a set of samples, in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Stats {
    /// Median.
    pub median_ms: f64,
    /// 95th percentile.
    pub p95_ms: f64,
    /// Mean.
    pub mean_ms: f64,
    /// Number of samples.
    pub samples: usize,
}

impl Stats {
    /// Summarises `samples` (ms). Returns `None` for an empty slice.
    pub fn from_samples(samples: &[f64]) -> Option<Self> {
        if samples.is_empty() {
            return None;
        }
        let mut s = samples.to_vec();
        s.sort_by(|a, b| a.total_cmp(b));
        let n = s.len();
        let median = if n % 2 == 1 {
            s[n / 2]
        } else {
            0.5 * (s[n / 2 - 1] + s[n / 2])
        };
        let p95 = s[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1];
        Some(Self {
            median_ms: median,
            p95_ms: p95,
            mean_ms: s.iter().sum::<f64>() / n as f64,
            samples: n,
        })
    }
}

/// Timing of one named stage.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StageStats {
    /// Stage label.
    pub name: String,
    /// Its statistics.
    pub stats: Stats,
    /// `true` when measured with GPU timestamps, `false` for CPU wall time.
    pub gpu: bool,
}

/// Collects per-pass GPU timestamps over many frames.
pub struct Profiler {
    query_set: Option<wgpu::QuerySet>,
    resolve: Option<wgpu::Buffer>,
    capacity: u32,
    labels: Vec<String>,
    period_ns: f64,
    samples: BTreeMap<String, Vec<f64>>,
    order: Vec<String>,
    gpu_timed: bool,
}

impl Profiler {
    /// A profiler for up to `max_scopes` timed passes per frame.
    pub fn new(gpu: &Gpu, max_scopes: u32) -> Self {
        Self::build(gpu, max_scopes, gpu.has(wgpu::Features::TIMESTAMP_QUERY))
    }

    /// A profiler that records CPU wall time only (around submit and wait), as on an
    /// adapter without timestamps.
    pub fn wall(gpu: &Gpu) -> Self {
        Self::build(gpu, 1, false)
    }

    fn build(gpu: &Gpu, max_scopes: u32, timed: bool) -> Self {
        let capacity = 2 * max_scopes.max(1);
        let (query_set, resolve) = if timed {
            let qs = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("subpixel.profiler"),
                ty: wgpu::QueryType::Timestamp,
                count: capacity,
            });
            let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("subpixel.profiler.resolve"),
                size: capacity as u64 * 8,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            (Some(qs), Some(buf))
        } else {
            (None, None)
        };
        Self {
            query_set,
            resolve,
            capacity,
            labels: Vec::new(),
            period_ns: gpu.queue.get_timestamp_period() as f64,
            samples: BTreeMap::new(),
            order: Vec::new(),
            gpu_timed: timed,
        }
    }

    /// Whether GPU timestamps are available.
    pub fn gpu_timed(&self) -> bool {
        self.gpu_timed
    }

    /// Timestamp writes for a compute pass labelled `label`, or `None` when timestamps
    /// are unavailable or the frame's scopes are used up.
    pub fn scope(&mut self, label: &str) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let qs = self.query_set.as_ref()?;
        let i = self.labels.len() as u32;
        if 2 * i + 2 > self.capacity {
            return None;
        }
        self.labels.push(label.to_string());
        Some(wgpu::ComputePassTimestampWrites {
            query_set: qs,
            beginning_of_pass_write_index: Some(2 * i),
            end_of_pass_write_index: Some(2 * i + 1),
        })
    }

    /// Begins a compute pass labelled `label` on `encoder`, timed as a scope of `profiler`
    /// when one is given (and has room): the one way every caller opens a pass.
    pub fn pass<'e>(
        encoder: &'e mut wgpu::CommandEncoder,
        label: &str,
        profiler: Option<&mut Profiler>,
    ) -> wgpu::ComputePass<'e> {
        encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes: profiler.and_then(|p| p.scope(label)),
        })
    }

    /// Ends a timed frame: resolves its timestamps into `encoder`, submits it, waits for
    /// the GPU and collects them. Where the adapter has no timestamps and `wall_label` is
    /// given, the wall time is recorded under that label instead. Returns the wall time
    /// from submit to done, in ms.
    pub fn submit(
        &mut self,
        gpu: &Gpu,
        mut encoder: wgpu::CommandEncoder,
        wall_label: Option<&str>,
    ) -> Result<f64> {
        self.resolve(&mut encoder);
        let t0 = std::time::Instant::now();
        gpu.queue.submit([encoder.finish()]);
        gpu.wait()?;
        let wall = t0.elapsed().as_secs_f64() * 1e3;
        self.collect(gpu)?;
        if let Some(label) = wall_label.filter(|_| !self.gpu_timed) {
            self.record(label, wall);
        }
        Ok(wall)
    }

    /// Resolves this frame's timestamps into the readback buffer; call before `finish()`.
    pub fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        if let (Some(qs), Some(buf)) = (&self.query_set, &self.resolve)
            && !self.labels.is_empty()
        {
            encoder.resolve_query_set(qs, 0..2 * self.labels.len() as u32, buf, 0);
        }
    }

    /// After the frame was submitted: reads the timestamps back and records one sample per
    /// scope (a label used twice in a frame is summed).
    pub fn collect(&mut self, gpu: &Gpu) -> Result<()> {
        let labels = std::mem::take(&mut self.labels);
        let Some(buf) = &self.resolve else {
            return Ok(());
        };
        if labels.is_empty() {
            return Ok(());
        }
        let bytes = gpu.read_buffer(buf, 0, labels.len() as u64 * 16)?;
        let ticks: &[u64] = bytemuck::cast_slice(&bytes);
        let mut frame: BTreeMap<&str, f64> = BTreeMap::new();
        for (i, l) in labels.iter().enumerate() {
            let dt = ticks[2 * i + 1].wrapping_sub(ticks[2 * i]) as f64 * self.period_ns * 1e-6;
            *frame.entry(l).or_default() += dt;
        }
        for (l, ms) in frame {
            self.record(l, ms);
        }
        Ok(())
    }

    /// Records a sample measured elsewhere (e.g. CPU wall time), in milliseconds.
    pub fn record(&mut self, label: &str, ms: f64) {
        if !self.samples.contains_key(label) {
            self.order.push(label.to_string());
        }
        self.samples.entry(label.to_string()).or_default().push(ms);
    }

    /// Discards all samples (e.g. after warm-up).
    pub fn clear(&mut self) {
        self.samples.clear();
        self.order.clear();
    }

    /// Statistics per label, in first-seen order.
    pub fn stats(&self) -> Vec<StageStats> {
        self.order
            .iter()
            .filter_map(|l| {
                Stats::from_samples(&self.samples[l]).map(|stats| StageStats {
                    name: l.clone(),
                    stats,
                    gpu: self.gpu_timed,
                })
            })
            .collect()
    }

    /// Statistics of one label.
    pub fn stat(&self, label: &str) -> Option<Stats> {
        self.samples.get(label).and_then(|s| Stats::from_samples(s))
    }
}

/// Times `dispatch` alone, each run in its own submission: `warmup` untimed runs, then
/// `iterations` timed ones (GPU timestamps where the adapter has them, else wall time
/// around submit and wait; on a CPU driver always wall time, which is exact there: with
/// texture-reading kernels bound beside them, lavapipe's timestamps around storage-buffer
/// kernels read tens of microseconds for passes that take milliseconds). Returns the
/// statistics and whether they are GPU-timed.
pub fn time_dispatch(
    gpu: &Gpu,
    dispatch: &super::Dispatch,
    warmup: u32,
    iterations: u32,
) -> Result<(Stats, bool)> {
    let label = dispatch.kernel;
    let mut prof = if gpu.kind() == super::AdapterKind::Cpu {
        Profiler::wall(gpu)
    } else {
        Profiler::new(gpu, 1)
    };
    for i in 0..warmup + iterations.max(1) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        dispatch.record(&mut Profiler::pass(&mut enc, label, Some(&mut prof)));
        prof.submit(gpu, enc, Some(label))?;
        if i + 1 == warmup {
            prof.clear();
        }
    }
    let stats = prof.stat(label).expect("timed iterations ran");
    Ok((stats, prof.gpu_timed()))
}

#[cfg(test)]
mod tests {
    use super::Stats;

    #[test]
    fn median_and_p95() {
        let s: Vec<f64> = (1..=100).map(|i| i as f64).collect();
        let st = Stats::from_samples(&s).unwrap();
        assert_eq!(st.median_ms, 50.5);
        assert_eq!(st.p95_ms, 95.0);
        assert_eq!(Stats::from_samples(&[3.0, 1.0, 2.0]).unwrap().median_ms, 2.0);
        assert!(Stats::from_samples(&[]).is_none());
    }
}
