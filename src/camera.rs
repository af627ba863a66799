//! The camera models of the core ([`infraloc_core::camera`]) and the reading of camera files.

pub use infraloc_core::camera::*;

use crate::error::{Error, Result};
use import::{parse_camera_named, parse_intrinsics_sigma, IntrinsicsSigma, CAMERA_SELECTOR};
use std::path::{Path, PathBuf};

/// Read and parse an intrinsics file. For a Kalibr camchain, `path#camN` selects camera `camN`
/// (default: the first camera in the file); the suffix is only split off when `path` itself does
/// not name an existing file.
pub fn load_camera(path: &Path) -> Result<Camera> {
    let (file, selector) = split_selector(path);
    let text = std::fs::read_to_string(&file).map_err(|e| Error::io(&file, e))?;
    Ok(parse_camera_named(&text, &file, selector.as_deref())?)
}

/// Read a camera file's stated intrinsics uncertainty ([`parse_intrinsics_sigma`]); `path` as
/// for [`load_camera`].
pub(crate) fn load_intrinsics_sigma(path: &Path) -> Result<Option<IntrinsicsSigma>> {
    let (file, _) = split_selector(path);
    let text = std::fs::read_to_string(&file).map_err(|e| Error::io(&file, e))?;
    Ok(parse_intrinsics_sigma(&text, &file)?)
}

/// Split `file#cam1` into the file and the selector, unless the whole path is an existing file.
fn split_selector(path: &Path) -> (PathBuf, Option<String>) {
    if path.is_file() {
        return (path.to_path_buf(), None);
    }
    let s = path.to_string_lossy();
    match s.rsplit_once(CAMERA_SELECTOR) {
        Some((f, sel)) if !sel.is_empty() && !sel.contains('/') => {
            (PathBuf::from(f), Some(sel.to_string()))
        }
        _ => (path.to_path_buf(), None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selector_split_only_when_not_a_file() {
        let (f, s) = split_selector(Path::new("/nonexistent/chain.yaml#cam1"));
        assert_eq!(
            (f, s.as_deref()),
            (PathBuf::from("/nonexistent/chain.yaml"), Some("cam1"))
        );
        let (f, s) = split_selector(Path::new("/nonexistent/chain.yaml"));
        assert_eq!((f, s), (PathBuf::from("/nonexistent/chain.yaml"), None));
    }
}
