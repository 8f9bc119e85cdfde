//! Which tensors the network keeps as texture arrays for the convolutions that read their
//! inputs as textures (issue 14, [`ConvKernel::reads_textures`]), and which step writes
//! each: a tensor several such convolutions read is copied to its texture once per frame,
//! by the first of them, and not at all when a convolution with uniform weights produces
//! it, which then stores its output to the texture too (template flag `TEX_OUT`). Without
//! this plan each reading convolution copies each of its inputs itself.

use std::collections::{BTreeMap, BTreeSet};

use super::graph::{Op, StepSpec, TensorId};
use crate::nn::conv::ConvKernel;

/// Where one input of a convolution step finds its texture ([`StepTextures::inputs`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TextureSource {
    /// The texture of this (stored) tensor, which the step fills first (copies it there).
    Fill(TensorId),
    /// The texture of this tensor, written by an earlier step of the frame.
    Filled(TensorId),
}

/// The shared textures one step of a frame uses.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StepTextures {
    /// Per input of a convolution reading textures, in argument order; `None`: a copy of
    /// the step's own (and an empty list for every other step).
    pub inputs: Vec<Option<TextureSource>>,
    /// The tensor whose texture a convolution producing it also stores its output to.
    pub output: Option<TensorId>,
}

/// The plan for one frame: per step (in `specs` order) its shared textures, and the set of
/// tensors that have one. `stored` maps each argument to the tensor that holds it (a view
/// reads its stored tensor: the texture is of the stored one, read with the view's fetch);
/// `kernel` gives each convolution layer's kernel.
///
/// A tensor gets a shared texture when convolutions reading textures read it and every
/// step involved (those readers and a convolution producing it) runs on the same frames
/// (`history` alike: a step skipped on the first frame after a reset must not be the one
/// that fills a texture others read). Its producer stores to the texture when it is a
/// convolution with uniform weights that runs before the first reader; otherwise the
/// first reader fills it and the later ones find it filled.
pub fn plan(
    specs: &[StepSpec],
    stored: impl Fn(TensorId) -> TensorId,
    kernel: impl Fn(&str) -> ConvKernel,
) -> (Vec<StepTextures>, BTreeSet<TensorId>) {
    // Readers (step, argument) of each stored tensor, among the convolutions reading textures.
    let mut readers: BTreeMap<TensorId, Vec<(usize, usize)>> = BTreeMap::new();
    // The convolution (step, layer) producing each stored tensor, where one does.
    let mut producer: BTreeMap<TensorId, (usize, &str)> = BTreeMap::new();
    let mut steps = vec![StepTextures::default(); specs.len()];
    for (i, s) in specs.iter().enumerate() {
        let Op::Conv(layer) = s.op else { continue };
        let (out, ins) = s.tensors.split_last().expect("a convolution has an output");
        producer.insert(stored(*out), (i, layer));
        if kernel(layer).reads_textures() {
            steps[i].inputs = vec![None; ins.len()];
            for (a, &id) in ins.iter().enumerate() {
                readers.entry(stored(id)).or_default().push((i, a));
            }
        }
    }
    let mut shared = BTreeSet::new();
    for (id, rs) in readers {
        let (first, _) = rs[0];
        // A producer after a reader (a reader of last frame's value): left alone.
        let producer = producer.get(&id).copied();
        if producer.is_some_and(|(p, _)| p >= first) {
            continue;
        }
        // The producer stores the texture when it has uniform weights (the other kernels
        // have no texture output).
        let writer = producer
            .filter(|&(_, layer)| kernel(layer).uniform_layout().is_some())
            .map(|(p, _)| p);
        let history = specs[first].history;
        if rs
            .iter()
            .map(|&(i, _)| i)
            .chain(writer)
            .any(|i| specs[i].history != history)
        {
            continue;
        }
        for (n, &(i, a)) in rs.iter().enumerate() {
            steps[i].inputs[a] = Some(if n == 0 && writer.is_none() {
                TextureSource::Fill(id)
            } else {
                TextureSource::Filled(id)
            });
        }
        if let Some(p) = writer {
            steps[p].output = Some(id);
        }
        shared.insert(id);
    }
    (steps, shared)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ssr::config::SsrConfig;
    use crate::ssr::graph;

    fn conv(label: &'static str, tensors: &[TensorId], history: bool) -> StepSpec {
        StepSpec {
            stage: "unet",
            label,
            op: Op::Conv(label),
            tensors: tensors.to_vec(),
            history,
        }
    }

    const TEX: ConvKernel = ConvKernel::Blocked {
        px: 4,
        cob: 2,
        tex: true,
    };
    const BUF: ConvKernel = ConvKernel::Blocked {
        px: 4,
        cob: 2,
        tex: false,
    };

    /// A hand-made chain: a tensor no convolution produces read by two texture readers is
    /// filled by the first; one a convolution produces is stored by it; a reader reading
    /// buffers gets nothing; steps of different history never share.
    #[test]
    fn fills_once_and_fuses_into_producers() {
        use TensorId::*;
        let specs = vec![
            conv("a", &[ACur, RefHidden], false),
            conv("b", &[ACur, RefHidden, RefFeat], false),
            conv("c", &[RefFeat, EmbCur], false),
            conv("d", &[WarpAcc, EmbHiddenPrev], true),
            conv("e", &[WarpAcc, EmbPrev], false),
        ];
        let kernel = |l: &str| if l == "a" { BUF } else { TEX };
        let (steps, shared) = plan(&specs, |id| id, kernel);
        // a reads buffers: it writes RefHidden's texture for b (a uniform kernel).
        assert_eq!(
            steps[0],
            StepTextures {
                inputs: vec![],
                output: Some(RefHidden)
            }
        );
        assert_eq!(
            steps[1],
            StepTextures {
                inputs: vec![
                    Some(TextureSource::Fill(ACur)),
                    Some(TextureSource::Filled(RefHidden))
                ],
                output: Some(RefFeat),
            }
        );
        assert_eq!(steps[2].inputs, vec![Some(TextureSource::Filled(RefFeat))]);
        // WarpAcc is read by a history step and by one that always runs: each copies its own.
        assert_eq!(steps[3].inputs, vec![None]);
        assert_eq!(steps[4].inputs, vec![None]);
        assert_eq!(shared, BTreeSet::from([ACur, RefHidden, RefFeat]));
        // With a generic producer (no texture output) the first reader fills instead.
        let kernel = |l: &str| if l == "a" { ConvKernel::Generic } else { TEX };
        let (steps, _) = plan(&specs, |id| id, kernel);
        assert_eq!(steps[0].output, None);
        assert_eq!(steps[1].inputs[1], Some(TextureSource::Fill(RefHidden)));
    }

    /// Over the shipped configuration's graph with every layer reading textures: every
    /// tensor a texture reader reads is either stored by its producer before it or filled
    /// by exactly one step, which runs before every other reader, and every step of a
    /// shared tensor has the same history flag.
    #[test]
    fn the_default_graph_fills_every_shared_texture_exactly_once_before_use() {
        let config = SsrConfig::default();
        for pool_pass in [false, true] {
            let specs = graph::steps(&config, pool_pass).unwrap();
            let stored = |id: TensorId| id.stored(&config, pool_pass).unwrap().0;
            let (steps, shared) = plan(&specs, stored, |_| TEX);
            assert!(!shared.is_empty());
            let mut fused = 0;
            for &id in &shared {
                let writes: Vec<usize> = (0..specs.len())
                    .filter(|&i| {
                        steps[i].output == Some(id)
                            || steps[i].inputs.contains(&Some(TextureSource::Fill(id)))
                    })
                    .collect();
                assert_eq!(writes.len(), 1, "{id:?} written by steps {writes:?}");
                let reads: Vec<usize> = (0..specs.len())
                    .filter(|&i| steps[i].inputs.contains(&Some(TextureSource::Filled(id))))
                    .collect();
                assert!(
                    reads.iter().all(|&r| r > writes[0]),
                    "{id:?}: read before written"
                );
                let history = specs[writes[0]].history;
                assert!(reads.iter().all(|&r| specs[r].history == history), "{id:?}");
                fused += steps[writes[0]].output.is_some() as usize;
            }
            // The U-Net's hidden layers and encoder outputs come from convolutions.
            assert!(fused >= 5, "{fused} textures stored by their producers");
            // Every argument of every texture reader is planned (none copied on its own).
            let own = steps
                .iter()
                .flat_map(|s| &s.inputs)
                .filter(|a| a.is_none())
                .count();
            assert_eq!(own, 0, "{own} inputs copied on their own");
        }
    }
}
