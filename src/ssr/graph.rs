//! The SSR network declared once (DESIGN §4), typed: every tensor ([`TensorId`], with its
//! name, traits, resolution level and channels) and every step of a frame ([`StepSpec`]: its
//! operation and the tensors it takes, in the operation's argument order). The network
//! allocates, binds, counts FLOPs and traffic from this table alone; the layer list of
//! [`SsrConfig::layers`] (shared with the PyTorch mirror through the weight names) is
//! checked against it.

use super::config::{A_CHANNELS, HistoryTest, MT_CHANNELS, RGB, RemodulationAlbedo, SsrConfig};
use crate::error::Result;
use crate::nn::ops::{Fetch, PoolMode};

/// What a tensor is besides its shape ([`TensorId::traits`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trait {
    /// Only the steps of a frame use it (hidden layers, pooled, upsampled and downsampled
    /// copies): the network lets such tensors share memory when their lifetimes within
    /// the frame do not overlap, and does not expose them after it.
    Transient,
    /// It may be stored as f16 ([`crate::nn::autotune::Precision`]): an interior
    /// activation that only kernels with f16 variants produce and read, at arguments that
    /// take f16 ([`Op::takes_f16`]; checked by a test).
    F16,
}

/// Declares [`TensorId`]: each variant with its doc, its name and its traits, in
/// allocation order.
macro_rules! tensor_ids {
    ($($(#[$doc:meta])* $id:ident = $name:literal $(: $($t:ident)+)?,)*) => {
        /// Every tensor of the network. The names ([`TensorId::name`]) are those of the
        /// PyTorch mirror's golden intermediates where it has them.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum TensorId {
            $($(#[$doc])* $id,)*
        }

        impl TensorId {
            /// Every tensor, in allocation order.
            pub const ALL: &[TensorId] = &[$(TensorId::$id,)*];

            /// Its name (the PyTorch mirror's, where the mirror exports it as a golden
            /// intermediate; [`super::Network::tensor`] looks tensors up by it).
            pub fn name(self) -> &'static str {
                match self {
                    $(TensorId::$id => $name,)*
                }
            }

            /// Its traits.
            pub fn traits(self) -> &'static [Trait] {
                match self {
                    $(TensorId::$id => &[$($(Trait::$t,)+)?],)*
                }
            }
        }
    };
}

tensor_ids! {
    /// Exposure of the colour (rgb) and of the shadow (rgb), then the output ceiling's
    /// running max M (rgb) of the demodulated samples, 1x1.
    Exposure = "exposure",
    /// Its ratio to the last frame's, 1x1.
    ExposureRatio = "exposure_ratio",
    /// The exposure reduction's partial sums and max (4 vec4 per workgroup).
    ExposurePartials = "exposure_partials",
    /// A_t, the packed per-frame features (the mirror's `a_cur`).
    ACur = "a_cur",
    /// MT: mask and transparency.
    Mt = "mt",
    /// Motion vectors.
    Motion = "motion",
    /// Warped A_acc of the last frame.
    WarpAcc = "warp_acc": F16,
    /// Its validity.
    WarpValid = "warp_valid",
    /// TFA reference net, hidden layer.
    RefHidden = "ref_hidden": Transient F16,
    /// TFA reference features R.
    RefFeat = "ref_feat": F16,
    /// TFA embedding of the current features, hidden layer.
    EmbHiddenCur = "emb_hidden_cur": Transient F16,
    /// TFA embedding of the current features.
    EmbCur = "emb_cur": F16,
    /// TFA embedding of the warped history, hidden layer.
    EmbHiddenPrev = "emb_hidden_prev": Transient F16,
    /// TFA embedding of the warped history.
    EmbPrev = "emb_prev": F16,
    /// Per-pixel TFA weights (beta, alpha, s_cur, s_prev).
    TfaWeights = "tfa_weights",
    /// The accumulated features of this frame (ping-pong by frame parity).
    AAcc = "a_acc": F16,
    /// The accumulated features of the last frame.
    AAccPrev = "a_acc_prev": F16,
    /// Warped log-space output of the last frame, W(o).
    WarpOut = "warp_out",
    /// W(o) at half resolution.
    Wo2 = "wo2": Transient,
    /// W(o) at quarter resolution.
    Wo4 = "wo4": Transient,
    /// W(o) at eighth resolution (a fourth U-Net level only).
    Wo8 = "wo8": Transient,
    /// U-Net encoder level 1, hidden layer.
    Enc1Hidden = "enc1_hidden": Transient F16,
    /// U-Net encoder level 1.
    Enc1 = "enc1": F16,
    /// Its pooling (a view: [`TensorId::stored`]).
    Pool1 = "pool1": Transient F16,
    /// Encoder level 2, hidden layer.
    Enc2Hidden = "enc2_hidden": Transient F16,
    /// Encoder level 2.
    Enc2 = "enc2": F16,
    /// Its pooling (a view).
    Pool2 = "pool2": Transient F16,
    /// Encoder level 3, hidden layer.
    Enc3Hidden = "enc3_hidden": Transient F16,
    /// Encoder level 3.
    Enc3 = "enc3": F16,
    /// Its pooling (a view; a fourth U-Net level only).
    Pool3 = "pool3": Transient F16,
    /// Encoder level 4, hidden layer (a fourth U-Net level only, as are the tensors down
    /// to [`TensorId::Up4`]).
    Enc4Hidden = "enc4_hidden": Transient F16,
    /// Encoder level 4.
    Enc4 = "enc4": F16,
    /// Decoder level 4, hidden layer.
    Dec4Hidden = "dec4_hidden": Transient F16,
    /// Decoder level 4 output I4.
    I4 = "i4",
    /// I4 upsampled (a view).
    Up4 = "up4": Transient,
    /// Decoder level 3, hidden layer.
    Dec3Hidden = "dec3_hidden": Transient F16,
    /// Decoder level 3 output I3.
    I3 = "i3",
    /// I3 upsampled (a view).
    Up3 = "up3": Transient,
    /// Decoder level 2, hidden layer.
    Dec2Hidden = "dec2_hidden": Transient F16,
    /// Decoder level 2 output I2.
    I2 = "i2",
    /// I2 upsampled (a view).
    Up2 = "up2": Transient,
    /// Decoder level 1, hidden layer.
    Dec1Hidden = "dec1_hidden": Transient F16,
    /// The log-space output o of this frame (ping-pong by frame parity).
    O = "o",
    /// The log-space output of the last frame.
    OPrev = "o_prev",
    /// The remodulated output.
    Output = "output",
}

/// Where a tensor's size comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extent {
    /// The padded image at resolution level `l` (0 full, 1 half, 2 quarter, 3 eighth).
    Level(u32),
    /// One pixel.
    Single,
    /// One pixel per workgroup of the exposure reduction.
    ExposureGroups,
}

impl TensorId {
    /// Whether it has trait [`Trait::Transient`].
    pub fn is_transient(self) -> bool {
        self.traits().contains(&Trait::Transient)
    }

    /// Whether it has trait [`Trait::F16`].
    pub fn may_store_f16(self) -> bool {
        self.traits().contains(&Trait::F16)
    }

    /// The stored tensor it is read from and how: itself as stored, or, for a view (the
    /// U-Net's upsampled decoder outputs, and its pooled encoder levels unless `pool_pass`),
    /// its source resampled on load by the convolution that reads it (`nn/lib/fetch`), so
    /// that it takes no pass and no memory of its own. With `pool_pass` the pooled levels
    /// are tensors of their own that pooling steps write ([`steps`]).
    pub fn stored(self, config: &SsrConfig, pool_pass: bool) -> Result<(TensorId, Fetch)> {
        use TensorId::*;
        Ok(match self {
            Pool1 if !pool_pass => (Enc1, Fetch::Pool(config.pool_mode()?)),
            Pool2 if !pool_pass => (Enc2, Fetch::Pool(config.pool_mode()?)),
            Pool3 if !pool_pass => (Enc3, Fetch::Pool(config.pool_mode()?)),
            Up4 => (I4, Fetch::Upsample(config.upsample_mode()?)),
            Up3 => (I3, Fetch::Upsample(config.upsample_mode()?)),
            Up2 => (I2, Fetch::Upsample(config.upsample_mode()?)),
            _ => (self, Fetch::Direct),
        })
    }

    /// Whether `config`'s network has it: the tensors of a fourth U-Net level only with
    /// four widths in `enc`.
    pub fn in_config(self, config: &SsrConfig) -> bool {
        use TensorId::*;
        config.levels() >= 4 || !matches!(self, Wo8 | Pool3 | Enc4Hidden | Enc4 | Dec4Hidden | I4 | Up4)
    }

    /// Its extent and channel count under `config` (0 channels for a tensor the config's
    /// network does not have: [`TensorId::in_config`]).
    pub fn shape(self, config: &SsrConfig) -> (Extent, u32) {
        use Extent::*;
        use TensorId::*;
        let (c1, c2, c3) = (config.enc[0], config.enc[1], config.enc[2]);
        let c4 = config.enc.get(3).copied().unwrap_or(0);
        let (h, k) = (config.tfa_hidden, config.k);
        match self {
            Exposure => (Single, 3 * RGB),
            ExposureRatio => (Single, 2 * RGB),
            ExposurePartials => (ExposureGroups, 16),
            ACur | WarpAcc | AAcc | AAccPrev => (Level(0), A_CHANNELS),
            Mt => (Level(0), MT_CHANNELS),
            Motion => (Level(0), 2),
            WarpValid => (Level(0), 1),
            RefHidden | EmbHiddenCur | EmbHiddenPrev => (Level(0), h),
            RefFeat | EmbCur | EmbPrev => (Level(0), k),
            TfaWeights => (Level(0), 4),
            WarpOut | Up2 | O | OPrev | Output => (Level(0), RGB),
            Wo2 | Up3 | I2 => (Level(1), RGB),
            Wo4 | I3 | Up4 => (Level(2), RGB),
            Wo8 | I4 => (Level(3), RGB),
            Enc1Hidden | Enc1 | Dec1Hidden => (Level(0), c1),
            Pool1 => (Level(1), c1),
            Enc2Hidden | Enc2 | Dec2Hidden => (Level(1), c2),
            Pool2 => (Level(2), c2),
            Enc3Hidden | Enc3 | Dec3Hidden => (Level(2), c3),
            Pool3 => (Level(3), c3),
            Enc4Hidden | Enc4 | Dec4Hidden => (Level(3), c4),
        }
    }
}

/// What a step computes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Op {
    /// The 3x3 convolution layer of that name (`inputs..., output`).
    Conv(&'static str),
    /// The history warped by the motion, re-exposed and checked against this frame's
    /// geometry, in one pass (`a_acc_prev, o_prev, motion, a_cur, exposure_ratio,
    /// warp_acc, warp_out, warp_valid`).
    WarpHistory {
        /// Rescale by the exposure ratio.
        rescale: bool,
        /// Reject history whose geometry disagrees.
        geometry: bool,
    },
    /// TFA scores, softmax and blend (`r, e_cur, e_prev, cur, prev, valid, out, weights`).
    TfaBlend,
    /// 2x2 pooling (`in, out`).
    Pool(PoolMode),
    /// Remodulation by the albedo at channel 3 of the second tensor and the colour
    /// exposure (`o, albedo, exposure, output`).
    Remodulate,
}

impl Op {
    /// Whether argument `arg` (its index in [`StepSpec::tensors`]) may be stored as f16:
    /// every tensor of a convolution or a pooling; the last frame's A_acc and o and W(A_acc)
    /// of the history warp; R, the embeddings, the current and warped features and the
    /// output of the TFA blend; o and the albedo of the remodulation. (The network keeps o
    /// in f32: the exponential of the remodulation would magnify its rounding in the
    /// output.)
    pub fn takes_f16(&self, arg: usize) -> bool {
        match self {
            Op::Conv(_) | Op::Pool(_) => true,
            Op::WarpHistory { .. } => matches!(arg, 0 | 1 | 5),
            Op::TfaBlend => matches!(arg, 0..=4 | 6),
            Op::Remodulate => matches!(arg, 0 | 1),
        }
    }
}

/// One step of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StepSpec {
    /// Its stage (`tfa`, `unet`): the production pass it is recorded in.
    pub stage: &'static str,
    /// Its label (timings, errors).
    pub label: &'static str,
    /// The operation.
    pub op: Op,
    /// The tensors it takes, in the operation's argument order.
    pub tensors: Vec<TensorId>,
    /// Whether it runs only when there is history (not on the first frame after a reset).
    pub history: bool,
}

fn step(stage: &'static str, label: &'static str, op: Op, tensors: &[TensorId]) -> StepSpec {
    StepSpec {
        stage,
        label,
        op,
        tensors: tensors.to_vec(),
        history: false,
    }
}

/// The steps of one frame under `config`, in execution order; with `pool_pass`, a pooling
/// step writes each pooled encoder level after the layer that produces it (else the
/// convolutions that read them pool on load: [`TensorId::stored`]).
pub fn steps(config: &SsrConfig, pool_pass: bool) -> Result<Vec<StepSpec>> {
    use Op::*;
    use TensorId::*;
    let rescale = config.exposure_mode()?.normalises();
    let geometry = config.history_test()? == HistoryTest::Geometry;
    let mut warp = step(
        "tfa",
        "warp history",
        WarpHistory { rescale, geometry },
        &[
            AAccPrev,
            OPrev,
            Motion,
            ACur,
            ExposureRatio,
            WarpAcc,
            WarpOut,
            WarpValid,
        ],
    );
    warp.history = true;
    let albedo = match config.remodulation_albedo()? {
        RemodulationAlbedo::Current => ACur,
        RemodulationAlbedo::Accumulated => AAcc,
    };
    let mut all = vec![warp];
    all.extend([
        step("tfa", "tfa.ref.0", Conv("tfa.ref.0"), &[ACur, Mt, RefHidden]),
        step("tfa", "tfa.ref.2", Conv("tfa.ref.2"), &[RefHidden, RefFeat]),
        step("tfa", "tfa.emb.0 (cur)", Conv("tfa.emb.0"), &[ACur, EmbHiddenCur]),
        step(
            "tfa",
            "tfa.emb.2 (cur)",
            Conv("tfa.emb.2"),
            &[EmbHiddenCur, EmbCur],
        ),
        step(
            "tfa",
            "tfa.emb.0 (prev)",
            Conv("tfa.emb.0"),
            &[WarpAcc, EmbHiddenPrev],
        ),
        step(
            "tfa",
            "tfa.emb.2 (prev)",
            Conv("tfa.emb.2"),
            &[EmbHiddenPrev, EmbPrev],
        ),
        step(
            "tfa",
            "tfa blend",
            TfaBlend,
            &[
                RefFeat, EmbCur, EmbPrev, ACur, WarpAcc, WarpValid, AAcc, TfaWeights,
            ],
        ),
        step("unet", "pool W(o)/2", Pool(PoolMode::Average), &[WarpOut, Wo2]),
        step("unet", "pool W(o)/4", Pool(PoolMode::Average), &[Wo2, Wo4]),
        step(
            "unet",
            "unet.enc1.0",
            Conv("unet.enc1.0"),
            &[ACur, Mt, AAcc, WarpOut, Enc1Hidden],
        ),
        step("unet", "unet.enc1.2", Conv("unet.enc1.2"), &[Enc1Hidden, Enc1]),
        step("unet", "pool enc1", Pool(config.pool_mode()?), &[Enc1, Pool1]),
        step(
            "unet",
            "unet.enc2.0",
            Conv("unet.enc2.0"),
            &[Pool1, Wo2, Enc2Hidden],
        ),
        step("unet", "unet.enc2.2", Conv("unet.enc2.2"), &[Enc2Hidden, Enc2]),
        step("unet", "pool enc2", Pool(config.pool_mode()?), &[Enc2, Pool2]),
        step(
            "unet",
            "unet.enc3.0",
            Conv("unet.enc3.0"),
            &[Pool2, Wo4, Enc3Hidden],
        ),
        step("unet", "unet.enc3.2", Conv("unet.enc3.2"), &[Enc3Hidden, Enc3]),
    ]);
    // A fourth level below the third, built alike; dec3 then reads I4 upsampled between
    // enc3 and W(o) at 1/4.
    let dec3_inputs: &[TensorId] = if config.levels() == 4 {
        all.extend([
            step("unet", "pool W(o)/8", Pool(PoolMode::Average), &[Wo4, Wo8]),
            step("unet", "pool enc3", Pool(config.pool_mode()?), &[Enc3, Pool3]),
            step(
                "unet",
                "unet.enc4.0",
                Conv("unet.enc4.0"),
                &[Pool3, Wo8, Enc4Hidden],
            ),
            step("unet", "unet.enc4.2", Conv("unet.enc4.2"), &[Enc4Hidden, Enc4]),
            step(
                "unet",
                "unet.dec4.0",
                Conv("unet.dec4.0"),
                &[Enc4, Wo8, Dec4Hidden],
            ),
            step("unet", "unet.dec4.2", Conv("unet.dec4.2"), &[Dec4Hidden, I4]),
        ]);
        &[Enc3, Up4, Wo4, Dec3Hidden]
    } else {
        &[Enc3, Wo4, Dec3Hidden]
    };
    all.extend([
        step("unet", "unet.dec3.0", Conv("unet.dec3.0"), dec3_inputs),
        step("unet", "unet.dec3.2", Conv("unet.dec3.2"), &[Dec3Hidden, I3]),
        step(
            "unet",
            "unet.dec2.0",
            Conv("unet.dec2.0"),
            &[Enc2, Up3, Wo2, Dec2Hidden],
        ),
        step("unet", "unet.dec2.2", Conv("unet.dec2.2"), &[Dec2Hidden, I2]),
        step(
            "unet",
            "unet.dec1.0",
            Conv("unet.dec1.0"),
            &[Enc1, Up2, WarpOut, Dec1Hidden],
        ),
        step("unet", "unet.dec1.2", Conv("unet.dec1.2"), &[Dec1Hidden, O]),
        step("unet", "remodulate", Remodulate, &[O, albedo, Exposure, Output]),
    ]);
    if !pool_pass {
        all.retain(|s| !matches!(s.tensors[..], [_, Pool1 | Pool2 | Pool3]));
    }
    // Production order: each stage's history steps, then its other steps.
    let mut ordered = Vec::with_capacity(all.len());
    for stage in ["tfa", "unet"] {
        ordered.extend(all.iter().filter(|s| s.stage == stage && s.history).cloned());
        ordered.extend(all.iter().filter(|s| s.stage == stage && !s.history).cloned());
    }
    Ok(ordered)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The graph and the layer list agree: every layer of `SsrConfig::layers` (whose names
    /// are the PyTorch mirror's weight names) runs as often as it says, with the channel
    /// split of the tensors the graph gives it, at its level.
    #[test]
    fn graph_matches_the_layer_list() {
        for config in configs() {
            for pool_pass in [false, true] {
                graph_matches_the_layer_list_with(&config, pool_pass);
            }
        }
    }

    /// The default 3-level network and one with a fourth U-Net level.
    fn configs() -> [SsrConfig; 2] {
        let deep = SsrConfig {
            enc: vec![16, 32, 28, 24],
            ..SsrConfig::default()
        };
        [SsrConfig::default(), deep]
    }

    fn graph_matches_the_layer_list_with(config: &SsrConfig, pool_pass: bool) {
        let config = config.clone();
        let steps = steps(&config, pool_pass).unwrap();
        for l in config.layers() {
            let uses: Vec<&StepSpec> = steps
                .iter()
                .filter(|s| matches!(s.op, Op::Conv(n) if n == l.name))
                .collect();
            assert_eq!(uses.len() as u32, l.runs, "{}", l.name);
            for s in uses {
                let (ins, out) = s.tensors.split_at(s.tensors.len() - 1);
                let split: Vec<u32> = ins.iter().map(|t| t.shape(&config).1).collect();
                assert_eq!(split, l.inputs, "{}", s.label);
                assert_eq!(
                    out[0].shape(&config),
                    (Extent::Level(l.level), l.cout),
                    "{}",
                    s.label
                );
                for t in ins {
                    assert_eq!(t.shape(&config).0, Extent::Level(l.level), "{}: {t:?}", s.label);
                }
            }
        }
        let convs = steps.iter().filter(|s| matches!(s.op, Op::Conv(_))).count() as u32;
        assert_eq!(convs, config.layers().iter().map(|l| l.runs).sum::<u32>());
        // every tensor a step takes is the config's, with channels, read after it is written
        // (but for the history, written by the last frame, and the frame's own inputs)
        let mut written = vec![TensorId::AAccPrev, TensorId::OPrev, TensorId::ACur, TensorId::Mt];
        written.extend([TensorId::Motion, TensorId::Exposure, TensorId::ExposureRatio]);
        for s in &steps {
            let outputs = match s.op {
                Op::WarpHistory { .. } => 3,
                Op::TfaBlend => 2,
                _ => 1,
            };
            let (ins, outs) = s.tensors.split_at(s.tensors.len() - outputs);
            for t in &s.tensors {
                assert!(
                    t.in_config(&config) && t.shape(&config).1 > 0,
                    "{}: {t:?}",
                    s.label
                );
            }
            for t in ins {
                let (stored, _) = t.stored(&config, pool_pass).unwrap();
                assert!(
                    written.contains(&stored),
                    "{}: {t:?} read before it is written",
                    s.label
                );
            }
            written.extend(outs);
        }
    }

    /// Tensors that may be f16 meet kernels only at arguments with f16 variants, and each
    /// layer writes the same storage in every step that runs it. (Its inputs may differ:
    /// `tfa.emb.0` reads A_t, f32, and W(A_acc), f16 with f16 activations; the kernel is
    /// specialised to each when bound, the autotuner times the first step's.)
    #[test]
    fn f16_tensors_meet_only_kernels_with_f16_variants() {
        for config in configs() {
            let steps = steps(&config, true).unwrap();
            let mut seen = std::collections::HashMap::new();
            for s in &steps {
                let f16: Vec<bool> = s.tensors.iter().map(|t| t.may_store_f16()).collect();
                for (arg, (t, f)) in s.tensors.iter().zip(&f16).enumerate() {
                    assert!(
                        !f || s.op.takes_f16(arg),
                        "{}: {t:?} at {arg} of {:?}",
                        s.label,
                        s.op
                    );
                }
                if let Op::Conv(layer) = s.op {
                    let out = *f16.last().unwrap();
                    let before = seen.insert(layer, out);
                    assert!(before.is_none_or(|b| b == out), "{layer}");
                }
            }
        }
        assert_eq!(TensorId::ALL.iter().filter(|t| t.may_store_f16()).count(), 24);
    }

    /// With pooling passes, each pooled level is written once, after the last write of its
    /// source and before its first read, and nothing reads it as a view; without them,
    /// no step writes it and the convolutions read it pooled on load.
    #[test]
    fn pooled_levels_are_written_before_they_are_read() {
        use TensorId::*;
        let [_, config] = configs();
        for pool_pass in [false, true] {
            let steps = steps(&config, pool_pass).unwrap();
            for (pooled, source) in [(Pool1, Enc1), (Pool2, Enc2), (Pool3, Enc3)] {
                let (stored, fetch) = pooled.stored(&config, pool_pass).unwrap();
                let writes: Vec<usize> = (0..steps.len())
                    .filter(|&i| steps[i].tensors.last() == Some(&pooled))
                    .collect();
                let first_read = (0..steps.len())
                    .find(|&i| steps[i].tensors[..steps[i].tensors.len() - 1].contains(&pooled))
                    .unwrap();
                let source_written = (0..steps.len())
                    .filter(|&i| steps[i].tensors.last() == Some(&source))
                    .max()
                    .unwrap();
                if pool_pass {
                    assert_eq!((stored, fetch), (pooled, Fetch::Direct));
                    assert_eq!(writes.len(), 1, "{pooled:?}");
                    assert!(source_written < writes[0] && writes[0] < first_read, "{pooled:?}");
                    assert_eq!(steps[writes[0]].tensors, [source, pooled]);
                } else {
                    assert_eq!(stored, source);
                    assert!(matches!(fetch, Fetch::Pool(_)));
                    assert!(writes.is_empty(), "{pooled:?}");
                    assert!(source_written < first_read);
                }
            }
        }
    }

    #[test]
    fn names_are_unique() {
        let mut names: Vec<&str> = TensorId::ALL.iter().map(|t| t.name()).collect();
        names.sort_unstable();
        let n = names.len();
        names.dedup();
        assert_eq!(names.len(), n);
    }
}
