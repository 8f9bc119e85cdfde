//! Files: multi-channel EXR frames, PNG previews, frame folders.

pub mod exr;
pub mod frames;
pub mod png;

pub use self::exr::{FrameFile, read_frame, write_frame};
