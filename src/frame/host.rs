//! One frame of the per-frame data contract in host memory.

use crate::error::{Error, Result};
use crate::nn::HostTensor;

/// Which albedo a model's pipeline uses (its config `albedo`,
/// [`crate::ssr::SsrConfig::albedo_source`]; absent: `centre`): the one in
/// [`FrameInputs::albedo_depth`](super::FrameInputs) demodulates, feeds the network, tests
/// the history and remodulates, so it is the caller who provides it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlbedoSource {
    /// The G-buffer's first-hit base colour at the pixel centre (every model before the
    /// option).
    Centre,
    /// The first-hit base colour averaged over the pixel's footprint (the background
    /// pass's `albedo_footprint`, [`crate::frame::Background::albedo`]): the albedo the
    /// reference sees, so remodulation reaches the reference where a pixel mixes surfaces.
    Footprint,
}

/// Who reconstructs the emission of the surfaces the camera sees directly (a model's config
/// `emission`, [`crate::ssr::SsrConfig::emission_source`]; absent: `network`). It sets what
/// the caller feeds the denoiser as `color` and `background`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EmissionSource {
    /// The network, from the samples: `color` is the traced radiance, emission included
    /// (every model before the option).
    Network,
    /// The output pass: `color` leaves out the emission of the surfaces the camera rays meet
    /// first, and the denoiser's `emission` input holds that emission averaged over the
    /// pixel's footprint, which the output pass adds, so the emitters come without noise
    /// and the network reconstructs only reflected light ([`HostFrame::fold_directly_seen`]
    /// and [`HostFrame::pack_emission`] make such a frame from a full one).
    Background,
}

/// Who reconstructs the traced samples whose camera ray escaped to the environment (a
/// model's config `escaped`, [`crate::ssr::SsrConfig::escaped_source`]; absent: `network`).
/// Such a sample's radiance is the environment along its ray, which the background
/// ([`Background`]) already holds for the whole footprint: the output pass composites
/// `background + (1 - coverage) x reconstruction`, so the reconstruction is of the part of
/// the footprint that hits the scene. It sets what the caller feeds the denoiser as `color`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EscapedSource {
    /// The network, from the samples: escaped samples are fed as any other (every model
    /// before the option), so on a silhouette against the sky the reconstruction holds the
    /// sky in proportion to the coverage and the composite counts it a second time.
    Network,
    /// The background composite: `color` and `mask` leave out a traced pixel whose samples
    /// escaped (at least half of them, [`DirectEmission::escaped`]; colour and mask 0, as an
    /// untraced pixel), so the network sees only samples of the part of the footprint that
    /// hits the scene ([`HostFrame::fold_directly_seen`]); the mean correction compares
    /// those samples with the reconstruction (`ssr/lib/traced`).
    Background,
}

/// One frame of inputs in host memory, one [`HostTensor`] per buffer of DESIGN §3.
#[derive(Debug, Clone, PartialEq)]
pub struct HostFrame {
    /// Traced radiance (3).
    pub color: HostTensor,
    /// 1 where traced (1).
    pub mask: HostTensor,
    /// Albedo (3).
    pub albedo: HostTensor,
    /// Normal (3).
    pub normal: HostTensor,
    /// NEE shadow (3).
    pub shadow: HostTensor,
    /// Transparent tint (3).
    pub transparent: HostTensor,
    /// Normalised depth (1).
    pub depth: HostTensor,
    /// Metallic (1).
    pub metallic: HostTensor,
    /// Roughness (1).
    pub roughness: HostTensor,
    /// Motion in pixels (2).
    pub motion: HostTensor,
    /// The directly seen environment, optional (DESIGN §3, `background`).
    pub background: Option<Background>,
}

/// The optional `background` buffer of the contract: per pixel, the environment seen
/// directly through the pixel's footprint, averaged over the footprint (rays that hit
/// anything count 0), and the fraction of the footprint that escapes to the environment.
/// A pixel's radiance is the background plus `(1 - coverage)` times the radiance of the
/// rest of its footprint, and that is how the denoiser composites it: where the coverage
/// is 1 the output is the background, not a reconstruction from sparse samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Background {
    /// Environment radiance averaged over the footprint (3).
    pub radiance: HostTensor,
    /// Fraction of the footprint that escapes, in [0, 1] (1).
    pub coverage: HostTensor,
    /// First-hit base colour averaged over the same footprint rays (the G-buffer's albedo
    /// with sky 1, box-filtered over the pixel) (3): what the reference's albedo is, where
    /// the G-buffer's `albedo` is the value at the pixel centre. `None` in frame files
    /// written before it existed (`subpixel dataset --background N --resume` adds it).
    pub albedo: Option<HostTensor>,
    /// The directly seen emission, optional ([`DirectEmission`]): what a model whose
    /// config says `emission = "background"` takes out of the network's hands as the
    /// environment is. `None` in frame files written before it existed (`subpixel dataset
    /// --background N --resume` adds it) and from the GPU tracer.
    pub emission: Option<DirectEmission>,
}

/// The emission of the surfaces a frame's camera rays meet first (emitters seen directly,
/// not through a reflection): a pixel's radiance is that emission plus light the surfaces
/// reflect, and the first part is known without noise from the geometry alone.
#[derive(Debug, Clone, PartialEq)]
pub struct DirectEmission {
    /// First-hit emission averaged over the background's footprint rays, as its
    /// environment radiance, and over [`crate::render::EMISSION_OUTLINE_RAYS`] per axis on
    /// emitters' outlines ([`DirectEmission::outline`]) when the background traces fewer
    /// (3; channel `emission_footprint`).
    pub footprint: HostTensor,
    /// First-hit emission of each traced pixel's own samples (3; channel `emission`; 0
    /// where not traced): the part of `color` that is emission seen directly.
    pub samples: HostTensor,
    /// The fraction of each traced pixel's own samples whose camera ray escaped to the
    /// environment (1; channel `escaped`; 0 where not traced): such a sample's radiance is the
    /// environment seen directly, which the background already holds for the whole footprint
    /// (a model of config escaped "background" is not fed them, [`HostFrame::fold_directly_seen`]).
    /// `None` in frame files written before it existed (`subpixel dataset --background N
    /// --resume` adds it).
    pub escaped: Option<HostTensor>,
}

impl DirectEmission {
    /// Per pixel (row-major), whether it lies on an emitter's outline: its 3 x 3
    /// neighbourhood (within the frame) holds both pixels whose footprint sees an emitter
    /// (`footprint` above 0 in some channel) and pixels whose footprint sees none. There a
    /// few footprint rays measure an emitter's coverage coarsely, so the tracers trace these
    /// pixels' footprint again with more rays
    /// ([`crate::render::EMISSION_OUTLINE_RAYS`]).
    pub fn outline(&self) -> Vec<bool> {
        let (w, h) = (self.footprint.width as usize, self.footprint.height as usize);
        let lit: Vec<bool> = self
            .footprint
            .data
            .chunks_exact(3)
            .map(|c| c.iter().any(|&v| v > 0.0))
            .collect();
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (mut any_lit, mut any_dark) = (false, false);
                for ny in y.saturating_sub(1)..(y + 2).min(h) {
                    for nx in x.saturating_sub(1)..(x + 2).min(w) {
                        let l = lit[ny * w + nx];
                        any_lit |= l;
                        any_dark |= !l;
                    }
                }
                any_lit && any_dark
            })
            .collect()
    }
}

impl HostFrame {
    /// `(name, tensor, expected channels)` of every buffer.
    pub fn fields(&self) -> [(&'static str, &HostTensor, u32); 10] {
        [
            ("color", &self.color, 3),
            ("mask", &self.mask, 1),
            ("albedo", &self.albedo, 3),
            ("normal", &self.normal, 3),
            ("shadow", &self.shadow, 3),
            ("transparent", &self.transparent, 3),
            ("depth", &self.depth, 1),
            ("metallic", &self.metallic, 1),
            ("roughness", &self.roughness, 1),
            ("motion", &self.motion, 2),
        ]
    }

    /// Every buffer, mutable, in the order of [`HostFrame::fields`].
    pub fn tensors_mut(&mut self) -> [&mut HostTensor; 10] {
        [
            &mut self.color,
            &mut self.mask,
            &mut self.albedo,
            &mut self.normal,
            &mut self.shadow,
            &mut self.transparent,
            &mut self.depth,
            &mut self.metallic,
            &mut self.roughness,
            &mut self.motion,
        ]
    }

    /// Width and height, after checking every buffer (the background's included) has
    /// them and the right channels.
    pub fn size(&self) -> Result<(u32, u32)> {
        let (w, h) = (self.color.width, self.color.height);
        let background = self.background.iter().flat_map(|b| {
            [("background", &b.radiance, 3), ("coverage", &b.coverage, 1)]
                .into_iter()
                .chain(b.albedo.iter().map(|a| ("albedo_footprint", a, 3)))
                .chain(b.emission.iter().flat_map(|e| {
                    [
                        ("emission_footprint", &e.footprint, 3),
                        ("emission", &e.samples, 3),
                    ]
                    .into_iter()
                    .chain(e.escaped.iter().map(|t| ("escaped", t, 1)))
                }))
        });
        for (name, t, c) in self.fields().into_iter().chain(background) {
            if (t.width, t.height, t.channels) != (w, h, c) {
                return Err(Error::shape(
                    "frame",
                    format!(
                        "buffer '{name}' is {}x{}x{}, expected {w}x{h}x{c}",
                        t.width, t.height, t.channels
                    ),
                ));
            }
        }
        Ok((w, h))
    }

    /// The six packed `vec4` buffers of [`FrameInputs`](super::FrameInputs), in its field
    /// order, with the albedo a model of `albedo` uses in `albedo_depth`
    /// ([`AlbedoSource`]): the G-buffer's, or the background's footprint albedo (an error
    /// naming it when the frame has none).
    pub fn pack(&self, albedo: AlbedoSource) -> Result<[Vec<[f32; 4]>; 6]> {
        let (w, h) = self.size()?;
        let albedo = match albedo {
            AlbedoSource::Centre => &self.albedo,
            AlbedoSource::Footprint => self.background.as_ref().and_then(|b| b.albedo.as_ref()).ok_or_else(|| {
                Error::shape(
                    "frame",
                    "the model uses the footprint albedo (config albedo \"footprint\") and the frame has none \
                     (buffer 'albedo_footprint', written with the background: `subpixel dataset --background N`)",
                )
            })?,
        };
        let n = (w * h) as usize;
        let mut out: [Vec<[f32; 4]>; 6] = Default::default();
        for v in out.iter_mut() {
            v.resize(n, [0.0; 4]);
        }
        let put = |dst: &mut Vec<[f32; 4]>, t: &HostTensor, at: usize| {
            let c = t.channels as usize;
            for (px, src) in dst.iter_mut().zip(t.data.chunks_exact(c)) {
                px[at..at + c].copy_from_slice(src);
            }
        };
        put(&mut out[0], &self.color, 0);
        put(&mut out[0], &self.mask, 3);
        put(&mut out[1], albedo, 0);
        put(&mut out[1], &self.depth, 3);
        put(&mut out[2], &self.normal, 0);
        put(&mut out[2], &self.metallic, 3);
        put(&mut out[3], &self.shadow, 0);
        put(&mut out[3], &self.roughness, 3);
        put(&mut out[4], &self.transparent, 0);
        put(&mut out[5], &self.motion, 0);
        Ok(out)
    }

    /// The frame as a model of config `emission` and `escaped` is fed it: itself for
    /// [`EmissionSource::Network`] and [`EscapedSource::Network`]; for
    /// [`EmissionSource::Background`], `color` without the traced samples' first-hit
    /// emission (at least 0), whose footprint average ([`DirectEmission::footprint`],
    /// [`HostFrame::pack_emission`]) the output pass adds instead; for
    /// [`EscapedSource::Background`], the traced pixels at least half of whose samples
    /// escaped to the environment ([`DirectEmission::escaped`]) left out (colour and mask
    /// 0), the background holding what they saw (WGSL `ssr/fold_emission`). An error naming
    /// the buffers when the frame lacks what the fold needs.
    pub fn fold_directly_seen(&self, emission: EmissionSource, escaped: EscapedSource) -> Result<HostFrame> {
        self.size()?;
        if (emission, escaped) == (EmissionSource::Network, EscapedSource::Network) {
            return Ok(self.clone());
        }
        let Some(e) = self.direct_emission() else {
            let what = if emission == EmissionSource::Background {
                "takes the directly seen emission from the output pass (config emission \"background\")"
            } else {
                "leaves the samples that escaped to the environment to the background (config escaped \"background\")"
            };
            return Err(Error::shape(
                "frame",
                format!(
                    "the model {what} and the frame has no directly seen emission (buffers 'emission' and \
                     'emission_footprint', written with the background: `subpixel dataset --background N`)"
                ),
            ));
        };
        let mut out = self.clone();
        if emission == EmissionSource::Background {
            for (c, s) in out.color.data.iter_mut().zip(&e.samples.data) {
                *c = (*c - s).max(0.0);
            }
        }
        if escaped == EscapedSource::Background {
            let Some(esc) = &e.escaped else {
                return Err(Error::shape(
                    "frame",
                    "the model leaves the samples that escaped to the environment to the background (config escaped \
                     \"background\") and the frame does not say which escaped (buffer 'escaped', added by \
                     `subpixel dataset --background N --resume`)",
                ));
            };
            for ((c, m), a) in out
                .color
                .data
                .chunks_exact_mut(3)
                .zip(&mut out.mask.data)
                .zip(&esc.data)
            {
                if *a >= 0.5 {
                    c.fill(0.0);
                    *m = 0.0;
                }
            }
        }
        Ok(out)
    }

    /// The frame's directly seen emission, when its background has one.
    pub fn direct_emission(&self) -> Option<&DirectEmission> {
        self.background.as_ref()?.emission.as_ref()
    }

    /// [`HostFrame::direct_emission`], mutable.
    pub fn direct_emission_mut(&mut self) -> Option<&mut DirectEmission> {
        self.background.as_mut()?.emission.as_mut()
    }

    /// The footprint's directly seen emission packed as
    /// [`FrameInputs::emission`](super::FrameInputs) wants it (rgb, 0), when the frame has one.
    pub fn pack_emission(&self) -> Option<Vec<[f32; 4]>> {
        let e = self.direct_emission()?;
        Some(
            e.footprint
                .data
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2], 0.0])
                .collect(),
        )
    }

    /// The background packed as [`FrameInputs::background`](super::FrameInputs) wants it
    /// (radiance rgb, coverage), when the frame has one.
    pub fn pack_background(&self) -> Result<Option<Vec<[f32; 4]>>> {
        self.size()?;
        Ok(self.background.as_ref().map(|b| {
            b.radiance
                .data
                .chunks_exact(3)
                .zip(&b.coverage.data)
                .map(|(r, c)| [r[0], r[1], r[2], *c])
                .collect()
        }))
    }
}
