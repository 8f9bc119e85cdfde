//! File formats: multi-channel EXR frames.

pub mod exr;
