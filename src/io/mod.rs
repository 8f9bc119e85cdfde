//! Files: multi-channel EXR frames, PNG previews, frame folders.

pub mod exr;
pub mod frames;
pub mod png;

pub use self::exr::{FrameFile, read_frame, write_frame};

use std::io::Read;
use std::path::Path;

/// Most bytes read from any one input file (weights, glTF files and their buffers and
/// images, environment maps, scene files).
pub const MAX_INPUT_BYTES: u64 = 4 << 30;

/// The size of `path` when it is a regular file (symlinks followed). Anything else (a FIFO,
/// which would block the reader, a device such as `/dev/zero`, which never ends, a folder)
/// is an error, checked before the file is opened.
pub fn regular_file_len(path: &Path) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        let kind = if meta.is_dir() {
            "a folder"
        } else {
            "a FIFO, socket or device"
        };
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("not a regular file ({kind})"),
        ));
    }
    Ok(meta.len())
}

/// Reads the regular file `path` ([`regular_file_len`]), at most `cap` bytes of it (the
/// size the caller's format declares, when it knows one) and never more than the file's
/// size or [`MAX_INPUT_BYTES`].
pub fn read_regular(path: &Path, cap: u64) -> std::io::Result<Vec<u8>> {
    let len = regular_file_len(path)?;
    let want = len.min(cap);
    if want > MAX_INPUT_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "{want} bytes to read, more than the {} GiB limit",
                MAX_INPUT_BYTES >> 30
            ),
        ));
    }
    let file = std::fs::File::open(path)?;
    if !file.metadata()?.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file",
        ));
    }
    let mut buf = Vec::with_capacity(want as usize);
    file.take(want).read_to_end(&mut buf)?;
    Ok(buf)
}

/// A temporary folder for the unit test `name` (created; named after the process, so
/// concurrent test runs do not meet).
#[cfg(test)]
pub(crate) fn test_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("subpixel-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 12 item 9: FIFOs, devices and folders are refused without blocking or reading
    /// forever; reads stop at the cap.
    #[test]
    fn only_regular_files_are_read_up_to_their_cap() {
        let dir = test_dir("io");
        let f = dir.join("f.bin");
        std::fs::write(&f, b"0123456789").unwrap();
        assert_eq!(read_regular(&f, u64::MAX).unwrap(), b"0123456789");
        assert_eq!(read_regular(&f, 4).unwrap(), b"0123");
        assert_eq!(regular_file_len(&f).unwrap(), 10);
        let e = read_regular(&dir, u64::MAX).unwrap_err().to_string();
        assert!(e.contains("not a regular file (a folder)"), "{e}");
        #[cfg(unix)]
        {
            let e = read_regular(Path::new("/dev/zero"), u64::MAX)
                .unwrap_err()
                .to_string();
            assert!(e.contains("not a regular file"), "{e}");
            let e = crate::ssr::Weights::load("/dev/zero").unwrap_err().to_string();
            assert!(e.contains("/dev/zero") && e.contains("not a regular file"), "{e}");
            let fifo = dir.join("fifo");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.map(|s| s.success()).unwrap_or(false) {
                let e = read_regular(&fifo, u64::MAX).unwrap_err().to_string();
                assert!(e.contains("not a regular file"), "{e}");
                let e = crate::ssr::Weights::load(&fifo).unwrap_err().to_string();
                assert!(e.contains("not a regular file"), "{e}");
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
