//! The SSR reconstruction network (DESIGN §4): weights, the network on the WGSL kernels,
//! its history, and the embeddable [`Denoiser`].

mod config;
mod denoiser;
mod fold;
pub mod graph;
mod network;
mod shared_textures;
mod weights;

pub use crate::frame::HostFrame;
pub use config::{
    ATROUS_DECAY, ATROUS_DEPTH_SIGMA, ATROUS_EPS, ATROUS_LEVELS, ATROUS_NORMAL_SQUARINGS, AlbedoSource,
    CEILING_DECAY, CEILING_GAIN, CONFIG_VERSION, CeilingMode, EmissionSource, EscapedSource, ExposureMode,
    HistoryTest, LayerSpec, MEAN_EPS, MEAN_HI, MEAN_LO, MEAN_RING, MEAN_TILE, MeanCorrection,
    RemodulationAlbedo, SsrConfig,
};
pub use denoiser::{Denoiser, FrameInputs, Granularity, KERNELS_USED, PARAM_SIZES};
pub use fold::{EmissionFold, FoldParams};
pub use network::{INTERMEDIATES, Network, StepCost};
pub use weights::{WEIGHTS_FORMAT, WEIGHTS_VERSION, Weights};
