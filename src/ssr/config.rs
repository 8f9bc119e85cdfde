//! Network configuration, stored as JSON in the weights' metadata.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
pub use crate::frame::{AlbedoSource, EmissionSource, EscapedSource};
use crate::nn::ops::{Activation, PoolMode, UpsampleMode};

/// Channels of the accumulated feature set A (DESIGN §4).
pub const A_CHANNELS: u32 = 15;
/// Channels of the mask + transparent tensor MT.
pub const MT_CHANNELS: u32 = 4;
/// Channels of an RGB image.
pub const RGB: u32 = 3;

/// Config version this engine writes (and the weights file version of such configs).
pub const CONFIG_VERSION: u32 = 2;

/// Input normalisation (config `exposure`, version 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExposureMode {
    /// Absolute radiance in (version 1).
    None,
    /// Per-channel exposure normalisation: colour and shadow divided by the frame's
    /// exposure s (geometric mean of the demodulated traced samples, smoothed over frames),
    /// the output multiplied by it; the history re-exposed when s changes.
    Channel,
    /// The same with one exposure per buffer (config `"shared"`): the geometric mean over
    /// every channel of the colour (of the shadow) and the traced pixels, the same for its
    /// three channels, so the network is fed the samples' colour as it is (per channel, the
    /// geometric means of heavy-tailed samples can part from the colour of their means).
    Shared,
}

impl ExposureMode {
    /// Whether colour and shadow are normalised by an exposure (and the history re-exposed).
    pub fn normalises(self) -> bool {
        self != ExposureMode::None
    }
}

/// Which albedo remodulates the output (config `remodulation`, version 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RemodulationAlbedo {
    /// The accumulated albedo of A_acc (version 1).
    Accumulated,
    /// The current frame's albedo, the one that demodulated.
    Current,
}

/// Which warped history is invalid (config `history`, version 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HistoryTest {
    /// Only samples off screen (version 1).
    Screen,
    /// Also samples whose accumulated depth or normal disagrees with the current frame's.
    Geometry,
}

/// Whether the output is capped (config `ceiling`, version 2; absent: `none`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CeilingMode {
    /// The network's output as it is (version 1 and files written before the option).
    None,
    /// The log output o is clamped to ln(1 + [`CEILING_GAIN`] M_c / s_c), M_c the running max
    /// of the demodulated traced samples of colour channel c ([`CEILING_DECAY`]; per channel,
    /// so the pipeline stays equivariant to per-channel scaling), before remodulation and
    /// before it becomes the history: the output never exceeds the brightest recent sample,
    /// however the network extrapolates. Needs exposure `channel` (M lives in its state).
    Max,
}

/// Whether the output pass corrects the reconstruction's brightness (config
/// `mean_correction`, version 2; absent: `none`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeanCorrection {
    /// The reconstruction as the network gives it.
    None,
    /// Per tile of `side` x `side` pixels and per channel, the reconstruction is scaled by
    /// the traced samples' sum over its own sum at the same pixels, both over the last
    /// [`MEAN_RING`] frames, clamped to [[`MEAN_LO`], [`MEAN_HI`]] and interpolated between
    /// tile centres (`wgsl/ssr/tile_means.wgsl`; with a background buffer, only the part of
    /// each pixel the network reconstructs). The samples are an unbiased estimate of the
    /// radiance, so the tiles' brightness follows them; the history is not changed.
    /// `"tiles"`: 32-pixel tiles ([`MEAN_TILE`]); `"tiles16"`: 16-pixel tiles (smaller tiles
    /// follow the samples more locally, with fewer samples per factor).
    Tiles {
        /// Tile side in pixels (a multiple of 8, the statistic's workgroup side).
        side: u32,
    },
    /// `"atrous"`: per pixel instead of per tile, and along the motion. Each frame's samples
    /// and reconstruction at its traced pixels (0 elsewhere) are added to the last frame's
    /// sums warped to this frame times [`ATROUS_DECAY`] (`wgsl/ssr/mean_history.wgsl`); the
    /// two sums are filtered alike by [`ATROUS_LEVELS`] levels of an edge-aware a-trous
    /// filter (5 x 5 B-spline taps
    /// 1, 2, 4, 8, 16 pixels apart, each weighted by the agreement of its normal and depth
    /// with the pixel's: `max(n . n_q, 0)^8 exp(-|z - z_q| / max(z, z_q) / ATROUS_DEPTH_SIGMA)`,
    /// `wgsl/ssr/mean_atrous.wgsl`), and each pixel's factor is the ratio of the two,
    /// `clamp((S + ATROUS_EPS) / (R + ATROUS_EPS), MEAN_LO, MEAN_HI)`: the brightness
    /// follows the samples of the pixel's own surface over about 60 pixels, not across
    /// silhouettes and creases.
    Atrous,
}

/// Config `mean_correction = "tiles"`: tile side in pixels (`"tiles16"`: 16).
pub const MEAN_TILE: u32 = 32;
/// Config `mean_correction = "tiles"`: frames whose sums make a factor.
pub const MEAN_RING: u32 = 4;
/// Config `mean_correction = "tiles"`: added to both sums of a factor.
pub const MEAN_EPS: f32 = 1e-4;
/// Config `mean_correction = "tiles"`: smallest factor.
pub const MEAN_LO: f32 = 0.67;
/// Config `mean_correction = "tiles"`: largest factor.
pub const MEAN_HI: f32 = 1.5;
/// Config `mean_correction = "atrous"`: filter levels (taps `2^level` pixels apart).
pub const ATROUS_LEVELS: u32 = 5;
/// Config `mean_correction = "atrous"`: the normal weight `max(n . n_q, 0)` is raised to
/// `2^ATROUS_NORMAL_SQUARINGS` (8) by squaring.
pub const ATROUS_NORMAL_SQUARINGS: u32 = 3;
/// Config `mean_correction = "atrous"`: relative depth difference at which the depth weight
/// is `1/e`.
pub const ATROUS_DEPTH_SIGMA: f32 = 0.2;
/// Config `mean_correction = "atrous"`: added to both filtered means of a factor
/// ([`MEAN_EPS`] over the 256 pixels of a 16-pixel tile).
pub const ATROUS_EPS: f32 = MEAN_EPS / 256.0;
/// Config `mean_correction = "atrous"`: each frame's sums add the last frame's, warped along
/// the motion, times this (about three frames' worth of samples).
pub const ATROUS_DECAY: f32 = 0.7;

/// Config `ceiling = "max"`: the demodulated output is at most this times M.
pub const CEILING_GAIN: f32 = 1.0;
/// M_t = max(m_t, CEILING_DECAY M_{t-1}) per colour channel, m_t the frame's max over its
/// traced pixels of clean(color) / (clean(albedo) + 0.00316); M_0 = m_0.
pub const CEILING_DECAY: f32 = 0.9;

/// `enc`: one width per U-Net level, three or four (the fourth level at 1/8 resolution;
/// training/README, Tensor contract). Any other count is refused by name.
fn unet_levels<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Vec<u32>, D::Error> {
    let v = Vec::<u32>::deserialize(d)?;
    if !(MIN_LEVELS..=MAX_LEVELS).contains(&v.len()) {
        return Err(serde::de::Error::custom(format!(
            "`enc` holds {} widths {v:?}: this engine runs U-Nets of {MIN_LEVELS} or {MAX_LEVELS} levels (one width per level)",
            v.len()
        )));
    }
    Ok(v)
}

/// The fewest U-Net levels a config may have.
pub const MIN_LEVELS: usize = 3;
/// The most U-Net levels a config may have.
pub const MAX_LEVELS: usize = 4;

/// Widths and options of the SSR network. A key this engine does not know (an option of a
/// later trainer) is an error, never silently ignored: the engine would run another pipeline
/// than the one the weights were trained with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SsrConfig {
    /// Hidden width of the TFA reference and embedding nets.
    pub tfa_hidden: u32,
    /// TFA feature width K.
    pub k: u32,
    /// Encoder widths at 1/1, 1/2, 1/4 (and, with a fourth, 1/8) resolution.
    #[serde(deserialize_with = "unet_levels")]
    pub enc: Vec<u32>,
    /// Feature pooling: `"max"` or `"avg"`.
    pub feature_pool: String,
    /// Upsampling of the coarse RGB images: `"bilinear"` or `"nearest"`.
    pub upsample: String,
    /// U-Net input channels (must be 37).
    pub input_channels: u32,
    /// Config version: 1 (the options below are absent and mean exposure `none`,
    /// remodulation `accumulated`, history `screen`) or 2 (they are required).
    #[serde(default)]
    pub version: u32,
    /// Version 2: `"none"`, `"channel"` or `"shared"` ([`ExposureMode`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<String>,
    /// Version 2: `"accumulated"` or `"current"` ([`RemodulationAlbedo`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remodulation: Option<String>,
    /// Version 2: `"screen"` or `"geometry"` ([`HistoryTest`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub history: Option<String>,
    /// Version 2, optional (absent: `"none"`): `"none"` or `"max"` ([`CeilingMode`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ceiling: Option<String>,
    /// Version 2, optional (absent: `"none"`): `"none"`, `"tiles"` or `"tiles16"`
    /// ([`MeanCorrection`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_correction: Option<String>,
    /// Version 2, optional (absent: `"centre"`): `"centre"` or `"footprint"`
    /// ([`AlbedoSource`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo: Option<String>,
    /// Version 2, optional (absent: `"network"`): `"network"` or `"background"`
    /// ([`EmissionSource`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub emission: Option<String>,
    /// Version 2, optional (absent: `"network"`): `"network"` or `"background"`
    /// ([`EscapedSource`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub escaped: Option<String>,
}

impl Default for SsrConfig {
    fn default() -> Self {
        Self {
            tfa_hidden: 8,
            k: 8,
            enc: vec![16, 32, 28],
            feature_pool: "max".into(),
            upsample: "bilinear".into(),
            input_channels: 2 * A_CHANNELS + MT_CHANNELS + RGB,
            version: CONFIG_VERSION,
            exposure: Some("channel".into()),
            remodulation: Some("current".into()),
            history: Some("geometry".into()),
            ceiling: Some("max".into()),
            mean_correction: Some("none".into()),
            albedo: Some("centre".into()),
            emission: Some("network".into()),
            escaped: Some("network".into()),
        }
    }
}

/// One 3x3 conv layer of the network.
#[derive(Debug, Clone, PartialEq)]
pub struct LayerSpec {
    /// PyTorch name prefix, e.g. `unet.enc1.0`.
    pub name: String,
    /// Input channels per concatenated input tensor.
    pub inputs: Vec<u32>,
    /// Output channels.
    pub cout: u32,
    /// Activation after the conv.
    pub act: Activation,
    /// Resolution level: 0 full, 1 half, 2 quarter, 3 eighth.
    pub level: u32,
    /// How many times it runs per frame (the embedding net runs twice).
    pub runs: u32,
}

/// The value named `value` of option `key` among `choices`; an absent option (a version-1
/// config, or a later option a file predates) takes the first. Any other name is an error
/// naming the key, the value and the choices.
fn choose<T: Copy>(key: &str, value: Option<&str>, choices: &[(&str, T)]) -> Result<T> {
    let v = value.unwrap_or(choices[0].0);
    if let Some(&(_, t)) = choices.iter().find(|(name, _)| *name == v) {
        return Ok(t);
    }
    let names: Vec<String> = choices.iter().map(|(name, _)| format!("\"{name}\"")).collect();
    let (last, rest) = names.split_last().expect("options have choices");
    let expected = if rest.is_empty() {
        last.clone()
    } else {
        format!("{} or {last}", rest.join(", "))
    };
    Err(Error::Invalid(format!(
        "SSR config: {key} '{v}', expected {expected}"
    )))
}

impl SsrConfig {
    /// Checks the options; errors name the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Invalid(format!("SSR config: {m}")));
        if !(MIN_LEVELS..=MAX_LEVELS).contains(&self.enc.len()) {
            return bad(format!(
                "enc {:?}: {} widths, expected {MIN_LEVELS} or {MAX_LEVELS} (one per U-Net level)",
                self.enc,
                self.enc.len()
            ));
        }
        if self.tfa_hidden == 0 || self.k == 0 || self.enc.contains(&0) {
            return bad(format!(
                "widths must be > 0 (tfa_hidden {}, k {}, enc {:?})",
                self.tfa_hidden, self.k, self.enc
            ));
        }
        if self.input_channels != 2 * A_CHANNELS + MT_CHANNELS + RGB {
            return bad(format!(
                "input_channels is {}, the engine feeds 37",
                self.input_channels
            ));
        }
        match self.version {
            1 => {
                for (key, v) in self.options().into_iter().chain(self.late_options()) {
                    if v.is_some() {
                        return bad(format!(
                            "version 1 has no '{key}' option (it came with version 2)"
                        ));
                    }
                }
            }
            2 => {
                for (key, v) in self.options() {
                    if v.is_none() {
                        return bad(format!("version 2 needs the '{key}' option"));
                    }
                }
            }
            v => {
                return bad(format!(
                    "version {v}: this engine reads versions 1 and {CONFIG_VERSION}"
                ));
            }
        }
        self.pool_mode()?;
        self.upsample_mode()?;
        self.exposure_mode()?;
        self.remodulation_albedo()?;
        self.history_test()?;
        self.mean_correction()?;
        self.albedo_source()?;
        self.emission_source()?;
        self.escaped_source()?;
        if self.ceiling_mode()? == CeilingMode::Max && !self.exposure_mode()?.normalises() {
            return bad(
                "ceiling \"max\" needs exposure \"channel\" or \"shared\" (the running max lives in the exposure state)"
                    .into(),
            );
        }
        Ok(())
    }

    fn options(&self) -> [(&'static str, &Option<String>); 3] {
        [
            ("exposure", &self.exposure),
            ("remodulation", &self.remodulation),
            ("history", &self.history),
        ]
    }

    /// The version-2 options that came after the first version-2 weights (optional: absent,
    /// each reads as its first choice).
    fn late_options(&self) -> [(&'static str, &Option<String>); 5] {
        [
            ("albedo", &self.albedo),
            ("emission", &self.emission),
            ("escaped", &self.escaped),
            ("mean_correction", &self.mean_correction),
            ("ceiling", &self.ceiling),
        ]
    }

    /// One line naming the network and the late options its file sets, e.g. `version 2,
    /// enc [16, 32, 28], albedo footprint, mean correction tiles16, ceiling max` (what
    /// `subpixel run` prints beside the weights' path).
    pub fn describe(&self) -> String {
        let mut s = format!("version {}, enc {:?}", self.version, self.enc);
        for (key, value) in self.late_options() {
            if let Some(v) = value {
                s += &format!(", {} {v}", key.replace('_', " "));
            }
        }
        s
    }

    /// The version-1 config of these widths (the pipeline of version-1 weights).
    pub fn legacy(&self) -> Self {
        Self {
            version: 1,
            exposure: None,
            remodulation: None,
            history: None,
            ceiling: None,
            mean_correction: None,
            albedo: None,
            emission: None,
            escaped: None,
            ..self.clone()
        }
    }

    /// The albedo the pipeline uses (version 1 and files without the option: the centre's).
    pub fn albedo_source(&self) -> Result<AlbedoSource> {
        let choices = [
            ("centre", AlbedoSource::Centre),
            ("footprint", AlbedoSource::Footprint),
        ];
        choose("albedo", self.albedo.as_deref(), &choices)
    }

    /// Who reconstructs the directly seen emission (version 1 and files without the option:
    /// the network).
    pub fn emission_source(&self) -> Result<EmissionSource> {
        let choices = [
            ("network", EmissionSource::Network),
            ("background", EmissionSource::Background),
        ];
        choose("emission", self.emission.as_deref(), &choices)
    }

    /// Who reconstructs the traced samples whose camera ray escaped to the environment
    /// (version 1 and files without the option: the network).
    pub fn escaped_source(&self) -> Result<EscapedSource> {
        let choices = [
            ("network", EscapedSource::Network),
            ("background", EscapedSource::Background),
        ];
        choose("escaped", self.escaped.as_deref(), &choices)
    }

    /// The input buffers every frame of this model needs, in [`FrameInputs::from_slice`]'s
    /// order (a prefix of [`FrameInputs::ALL_NAMES`]): the six of [`FrameInputs::NAMES`], and
    /// `background` and `emission` for a model of config emission "background" (which draws
    /// the directly seen emission itself; zero buffers where no sky and no emitter are in
    /// view), `background` for one of config escaped "background" (whose samples leave out
    /// the environment the background holds). The background stays optional for the
    /// others: with it, the output is composited over the directly seen environment.
    ///
    /// [`FrameInputs::from_slice`]: crate::frame::FrameInputs::from_slice
    /// [`FrameInputs::ALL_NAMES`]: crate::frame::FrameInputs::ALL_NAMES
    /// [`FrameInputs::NAMES`]: crate::frame::FrameInputs::NAMES
    pub fn input_names(&self) -> Result<&'static [&'static str]> {
        use crate::frame::FrameInputs;
        let six = FrameInputs::NAMES.len();
        Ok(match (self.emission_source()?, self.escaped_source()?) {
            (EmissionSource::Background, _) => &FrameInputs::ALL_NAMES,
            (EmissionSource::Network, EscapedSource::Background) => &FrameInputs::ALL_NAMES[..six + 1],
            (EmissionSource::Network, EscapedSource::Network) => &FrameInputs::ALL_NAMES[..six],
        })
    }

    /// The output ceiling (version 1 and files without the option: none).
    pub fn ceiling_mode(&self) -> Result<CeilingMode> {
        let choices = [("none", CeilingMode::None), ("max", CeilingMode::Max)];
        choose("ceiling", self.ceiling.as_deref(), &choices)
    }

    /// The output pass's mean correction (version 1 and files without the option: none).
    pub fn mean_correction(&self) -> Result<MeanCorrection> {
        let choices = [
            ("none", MeanCorrection::None),
            ("tiles", MeanCorrection::Tiles { side: MEAN_TILE }),
            ("tiles16", MeanCorrection::Tiles { side: 16 }),
            ("atrous", MeanCorrection::Atrous),
        ];
        choose("mean_correction", self.mean_correction.as_deref(), &choices)
    }

    /// Input normalisation (version 1: none).
    pub fn exposure_mode(&self) -> Result<ExposureMode> {
        let choices = [
            ("none", ExposureMode::None),
            ("channel", ExposureMode::Channel),
            ("shared", ExposureMode::Shared),
        ];
        choose("exposure", self.exposure.as_deref(), &choices)
    }

    /// The albedo of the remodulation (version 1: accumulated).
    pub fn remodulation_albedo(&self) -> Result<RemodulationAlbedo> {
        let choices = [
            ("accumulated", RemodulationAlbedo::Accumulated),
            ("current", RemodulationAlbedo::Current),
        ];
        choose("remodulation", self.remodulation.as_deref(), &choices)
    }

    /// The history test (version 1: screen).
    pub fn history_test(&self) -> Result<HistoryTest> {
        let choices = [
            ("screen", HistoryTest::Screen),
            ("geometry", HistoryTest::Geometry),
        ];
        choose("history", self.history.as_deref(), &choices)
    }

    /// Feature pooling mode.
    pub fn pool_mode(&self) -> Result<PoolMode> {
        let choices = [
            ("max", PoolMode::Max),
            ("avg", PoolMode::Average),
            ("average", PoolMode::Average),
        ];
        choose("feature_pool", Some(&self.feature_pool), &choices)
    }

    /// Upsampling mode.
    pub fn upsample_mode(&self) -> Result<UpsampleMode> {
        let choices = [
            ("bilinear", UpsampleMode::Bilinear),
            ("nearest", UpsampleMode::Nearest),
        ];
        choose("upsample", Some(&self.upsample), &choices)
    }

    /// U-Net levels (3 or 4: the widths of `enc`).
    pub fn levels(&self) -> u32 {
        self.enc.len() as u32
    }

    /// What the padded frame's sides are a multiple of: each U-Net level below the first
    /// halves them (4 with three levels, 8 with four).
    pub fn pad_multiple(&self) -> u32 {
        1 << (self.levels() - 1)
    }

    /// Every conv layer in execution order.
    pub fn layers(&self) -> Vec<LayerSpec> {
        let (h, k) = (self.tfa_hidden, self.k);
        let (c1, c2, c3) = (self.enc[0], self.enc[1], self.enc[2]);
        let relu = Activation::Relu;
        let none = Activation::None;
        let l = |name: &str, inputs: &[u32], cout, act, level, runs| LayerSpec {
            name: name.to_string(),
            inputs: inputs.to_vec(),
            cout,
            act,
            level,
            runs,
        };
        let mut layers = vec![
            l("tfa.ref.0", &[A_CHANNELS, MT_CHANNELS], h, relu, 0, 1),
            l("tfa.ref.2", &[h], k, none, 0, 1),
            l("tfa.emb.0", &[A_CHANNELS], h, relu, 0, 2),
            l("tfa.emb.2", &[h], k, none, 0, 2),
            l(
                "unet.enc1.0",
                &[A_CHANNELS, MT_CHANNELS, A_CHANNELS, RGB],
                c1,
                relu,
                0,
                1,
            ),
            l("unet.enc1.2", &[c1], c1, relu, 0, 1),
            l("unet.enc2.0", &[c1, RGB], c2, relu, 1, 1),
            l("unet.enc2.2", &[c2], c2, relu, 1, 1),
            l("unet.enc3.0", &[c2, RGB], c3, relu, 2, 1),
            l("unet.enc3.2", &[c3], c3, relu, 2, 1),
        ];
        // dec3 reads enc3 and W(o) at 1/4, with a fourth level I4 upsampled between them.
        let dec3_inputs = match self.enc.get(3) {
            Some(&c4) => {
                layers.extend([
                    l("unet.enc4.0", &[c3, RGB], c4, relu, 3, 1),
                    l("unet.enc4.2", &[c4], c4, relu, 3, 1),
                    l("unet.dec4.0", &[c4, RGB], c4, relu, 3, 1),
                    l("unet.dec4.2", &[c4], RGB, none, 3, 1),
                ]);
                vec![c3, RGB, RGB]
            }
            None => vec![c3, RGB],
        };
        layers.extend([
            l("unet.dec3.0", &dec3_inputs, c3, relu, 2, 1),
            l("unet.dec3.2", &[c3], RGB, none, 2, 1),
            l("unet.dec2.0", &[c2, RGB, RGB], c2, relu, 1, 1),
            l("unet.dec2.2", &[c2], RGB, none, 1, 1),
            l("unet.dec1.0", &[c1, RGB, RGB], c1, relu, 0, 1),
            l("unet.dec1.2", &[c1], RGB, none, 0, 1),
        ]);
        layers
    }

    /// FLOPs per full-resolution pixel of one layer (18 Cin Cout per output pixel, /4 per
    /// level down, times its runs per frame).
    pub fn layer_flops_per_pixel(l: &LayerSpec) -> f64 {
        let cin: u32 = l.inputs.iter().sum();
        18.0 * cin as f64 * l.cout as f64 * l.runs as f64 / 4f64.powi(l.level as i32)
    }

    /// FLOPs per full-resolution pixel of the whole network.
    pub fn flops_per_pixel(&self) -> f64 {
        self.layers().iter().map(Self::layer_flops_per_pixel).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_model_is_within_the_flop_budget() {
        let f = SsrConfig::default().flops_per_pixel();
        assert!(f <= 50_000.0, "{f} FLOP/px");
        assert!(f > 40_000.0, "{f} FLOP/px");
        // the fourth level [16, 32, 28, 24]: what `python -m ssr.flops` measures on the
        // PyTorch model (training/README, Generalisation 22)
        let deep = SsrConfig {
            enc: vec![16, 32, 28, 24],
            ..SsrConfig::default()
        };
        assert_eq!(deep.flops_per_pixel().round(), 49_948.0);
    }

    #[test]
    fn bad_options_are_named() {
        type Edit = fn(&mut SsrConfig);
        let cases: [(Edit, &str); 5] = [
            (|c| c.feature_pool = "median".into(), "feature_pool 'median'"),
            (|c| c.input_channels = 36, "input_channels is 36"),
            (|c| c.exposure = Some("global".into()), "exposure 'global'"),
            (|c| c.history = None, "version 2 needs the 'history' option"),
            (|c| c.version = 3, "version 3"),
        ];
        for (edit, want) in cases {
            let mut c = SsrConfig::default();
            edit(&mut c);
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
    }

    #[test]
    fn version_1_configs_mean_the_v1_pipeline() {
        let v1: SsrConfig = serde_json::from_str(
            r#"{"enc":[16,32,28],"feature_pool":"max","input_channels":37,"k":8,"tfa_hidden":8,"upsample":"bilinear","version":1}"#,
        )
        .unwrap();
        v1.validate().unwrap();
        assert_eq!(v1, SsrConfig::default().legacy());
        assert_eq!(v1.exposure_mode().unwrap(), ExposureMode::None);
        assert_eq!(v1.remodulation_albedo().unwrap(), RemodulationAlbedo::Accumulated);
        assert_eq!(v1.history_test().unwrap(), HistoryTest::Screen);
        // written back without the version-2 keys
        assert!(!serde_json::to_string(&v1).unwrap().contains("exposure"));
        let bad = SsrConfig {
            exposure: Some("channel".into()),
            ..v1
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("version 1 has no 'exposure' option"), "{e}");
        let d = SsrConfig::default();
        assert_eq!(d.version, 2);
        assert_eq!(d.exposure_mode().unwrap(), ExposureMode::Channel);
        let shared = SsrConfig {
            exposure: Some("shared".into()),
            ..d.clone()
        };
        shared.validate().unwrap();
        assert_eq!(shared.exposure_mode().unwrap(), ExposureMode::Shared);
        let unnormalised = SsrConfig {
            exposure: Some("none".into()),
            ..d.clone()
        };
        let e = unnormalised.validate().unwrap_err().to_string();
        assert!(e.contains("ceiling \"max\" needs exposure"), "{e}");
        assert_eq!(d.remodulation_albedo().unwrap(), RemodulationAlbedo::Current);
        assert_eq!(d.history_test().unwrap(), HistoryTest::Geometry);
        assert_eq!(d.ceiling_mode().unwrap(), CeilingMode::Max);
        // the engine's JSON is the trainer's (ssr/model.py SSRConfig.to_json, keys sorted)
        let back: SsrConfig = serde_json::from_str(
            r#"{"albedo":"centre","ceiling":"max","emission":"network","enc":[16,32,28],"escaped":"network","exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"mean_correction":"none","remodulation":"current","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap();
        assert_eq!(back, d);
        assert_eq!(d.albedo_source().unwrap(), AlbedoSource::Centre);
        // a version-2 file written before the ceiling: none
        let before: SsrConfig = serde_json::from_str(
            r#"{"enc":[16,32,28],"exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"remodulation":"current","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap();
        before.validate().unwrap();
        assert_eq!(before.ceiling_mode().unwrap(), CeilingMode::None);
        assert_eq!(before.mean_correction().unwrap(), MeanCorrection::None);
        assert_eq!(before.albedo_source().unwrap(), AlbedoSource::Centre);
        // the footprint albedo (`ssr.train --model-config '{"albedo": "footprint"}'`)
        let fp = SsrConfig {
            albedo: Some("footprint".into()),
            ..d.clone()
        };
        fp.validate().unwrap();
        assert_eq!(fp.albedo_source().unwrap(), AlbedoSource::Footprint);
        let e = SsrConfig {
            albedo: Some("middle".into()),
            ..d.clone()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("albedo 'middle', expected \"centre\" or \"footprint\""),
            "{e}"
        );
        let e = SsrConfig {
            albedo: Some("footprint".into()),
            ..d.legacy()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("version 1 has no 'albedo' option"), "{e}");
        // the directly seen emission from the background (`--model-config '{"emission": "background"}'`)
        assert_eq!(before.emission_source().unwrap(), EmissionSource::Network);
        let em: SsrConfig = serde_json::from_str(
            r#"{"emission":"background","enc":[16,32,28],"exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"remodulation":"current","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap();
        em.validate().unwrap();
        assert_eq!(em.emission_source().unwrap(), EmissionSource::Background);
        assert!(em.describe().contains("emission background"), "{}", em.describe());
        let e = SsrConfig {
            emission: Some("both".into()),
            ..d.clone()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("emission 'both', expected \"network\" or \"background\""),
            "{e}"
        );
        let e = SsrConfig {
            emission: Some("background".into()),
            ..d.legacy()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("version 1 has no 'emission' option"), "{e}");
        // the samples that escaped to the environment left to the background
        // (`--model-config '{"escaped": "background"}'`; absent in earlier files: the network)
        assert_eq!(before.escaped_source().unwrap(), EscapedSource::Network);
        let esc = SsrConfig {
            escaped: Some("background".into()),
            ..d.clone()
        };
        esc.validate().unwrap();
        assert_eq!(esc.escaped_source().unwrap(), EscapedSource::Background);
        assert!(
            esc.describe().contains("escaped background"),
            "{}",
            esc.describe()
        );
        assert_eq!(
            esc.input_names().unwrap(),
            &crate::frame::FrameInputs::ALL_NAMES[..7]
        );
        assert_eq!(d.input_names().unwrap(), &crate::frame::FrameInputs::NAMES[..]);
        let both = SsrConfig {
            emission: Some("background".into()),
            ..esc.clone()
        };
        assert_eq!(
            both.input_names().unwrap(),
            &crate::frame::FrameInputs::ALL_NAMES[..]
        );
        let e = SsrConfig {
            escaped: Some("sky".into()),
            ..d.clone()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("escaped 'sky', expected \"network\" or \"background\""),
            "{e}"
        );
        // the mean correction, written by `ssr.export --option mean_correction=tiles`
        let tiles: SsrConfig = serde_json::from_str(
            r#"{"ceiling":"max","enc":[16,32,28],"exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"mean_correction":"tiles","remodulation":"current","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap();
        tiles.validate().unwrap();
        assert_eq!(
            tiles.mean_correction().unwrap(),
            MeanCorrection::Tiles { side: MEAN_TILE }
        );
        let tiles16 = SsrConfig {
            mean_correction: Some("tiles16".into()),
            albedo: Some("footprint".into()),
            ..d.clone()
        };
        tiles16.validate().unwrap();
        assert_eq!(
            tiles16.describe(),
            "version 2, enc [16, 32, 28], albedo footprint, emission network, escaped network, mean correction tiles16, ceiling max"
        );
        assert_eq!(d.legacy().describe(), "version 1, enc [16, 32, 28]");
        assert_eq!(
            tiles16.mean_correction().unwrap(),
            MeanCorrection::Tiles { side: 16 }
        );
        let e = SsrConfig {
            mean_correction: Some("blocks".into()),
            ..d.clone()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("mean_correction 'blocks', expected \"none\", \"tiles\", \"tiles16\" or \"atrous\""),
            "{e}"
        );
        let e = SsrConfig {
            mean_correction: Some("tiles".into()),
            ..d.legacy()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("version 1 has no 'mean_correction' option"), "{e}");
        // an option this engine does not know (a later trainer's) is an error naming it
        let e = serde_json::from_str::<SsrConfig>(
            r#"{"enc":[16,32,28],"exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"remodulation":"current","sky":"background","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("unknown field `sky`"), "{e}");
        // a fourth U-Net level (the trainer's `enc` of four widths) is read; five are refused by name
        let deep: SsrConfig = serde_json::from_str(
            r#"{"enc":[16,32,28,24],"exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"remodulation":"current","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap();
        deep.validate().unwrap();
        assert_eq!((deep.levels(), deep.pad_multiple()), (4, 8));
        assert_eq!((d.levels(), d.pad_multiple()), (3, 4));
        let e = serde_json::from_str::<SsrConfig>(
            r#"{"enc":[16,32,28,24,20],"exposure":"channel","feature_pool":"max","history":"geometry","input_channels":37,"k":8,"remodulation":"current","tfa_hidden":8,"upsample":"bilinear","version":2}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("`enc` holds 5 widths [16, 32, 28, 24, 20]") && e.contains("3 or 4 levels"),
            "{e}"
        );
        let e = SsrConfig {
            enc: vec![16, 32],
            ..d.clone()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("enc [16, 32]: 2 widths, expected 3 or 4"), "{e}");
        let bad = SsrConfig {
            exposure: Some("none".into()),
            ..d.clone()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("ceiling \"max\" needs exposure \"channel\""), "{e}");
        let bad = SsrConfig {
            ceiling: Some("max".into()),
            ..d.legacy()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("version 1 has no 'ceiling' option"), "{e}");
    }
}
