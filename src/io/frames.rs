//! Frame folders: `frame_NNNN.exr`, numbered from 0 without gaps.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// File name of frame `i`.
pub fn frame_name(i: usize) -> String {
    format!("frame_{i:04}.exr")
}

/// The frames of `dir` in order; a gap in the numbering is an error naming the missing file.
pub fn list_frames(dir: &Path) -> Result<Vec<PathBuf>> {
    let err = |m: String| Error::File {
        path: dir.to_path_buf(),
        message: m,
    };
    let rd = std::fs::read_dir(dir).map_err(|e| err(format!("cannot list the folder: {e}")))?;
    let mut idx = Vec::new();
    for e in rd {
        let name = e
            .map_err(|e| err(e.to_string()))?
            .file_name()
            .to_string_lossy()
            .to_string();
        if let Some(n) = name.strip_prefix("frame_").and_then(|s| s.strip_suffix(".exr"))
            && let Ok(i) = n.parse::<usize>()
        {
            idx.push(i);
        }
    }
    idx.sort();
    if idx.is_empty() {
        return Err(err("no frame_NNNN.exr files".into()));
    }
    for (want, &got) in idx.iter().enumerate() {
        if want != got {
            return Err(err(format!(
                "{} is missing (frames go up to {})",
                frame_name(want),
                idx.last().unwrap()
            )));
        }
    }
    Ok(idx.iter().map(|&i| dir.join(frame_name(i))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_are_named() {
        let dir = crate::io::test_dir("frames");
        for i in [0, 1, 3] {
            std::fs::write(dir.join(frame_name(i)), b"").unwrap();
        }
        let e = list_frames(&dir).unwrap_err().to_string();
        assert!(e.contains("frame_0002.exr is missing"), "{e}");
        std::fs::write(dir.join(frame_name(2)), b"").unwrap();
        assert_eq!(list_frames(&dir).unwrap().len(), 4);
        std::fs::remove_dir_all(&dir).ok();
        assert!(list_frames(&dir).unwrap_err().to_string().contains("cannot list"));
    }
}
