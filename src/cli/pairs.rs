//! Pairs files: the image/point-file pairs of one pooled `refine` (`refine --pairs FILE`), as
//! `kitti import --drive … --pairs-out FILE` writes them for a drive's frames (docs/kitti.md).
//!
//! One pair a line: the image, a tab, the point file (or the two separated by spaces when
//! neither contains one). Blank lines and lines starting with `#` are skipped; a relative path
//! is relative to the pairs file's directory.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The first line of a written pairs file.
const HEADER: &str =
    "# infraloc pairs: IMAGE<TAB>POINTS, one pair a line (paths relative to this file's directory)";

/// The pairs file's text for `pairs`, one line each (paths written as given).
pub(crate) fn format(pairs: &[(PathBuf, PathBuf)]) -> String {
    let mut s = format!("{HEADER}\n");
    for (image, points) in pairs {
        s.push_str(&format!("{}\t{}\n", image.display(), points.display()));
    }
    s
}

/// Parse a pairs file's text; `origin` names it in errors and anchors relative paths.
pub fn parse(text: &str, origin: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
    let base = origin.parent().unwrap_or(Path::new(""));
    let at = |p: &str| {
        let p = Path::new(p);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            base.join(p)
        }
    };
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim_start_matches('\u{feff}').trim_end_matches('\r');
        if line.trim().is_empty() || line.trim_start().starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = if line.contains('\t') {
            line.split('\t').map(str::trim).collect()
        } else {
            line.split_whitespace().collect()
        };
        match fields.as_slice() {
            [image, points] if !image.is_empty() && !points.is_empty() => {
                out.push((at(image), at(points)))
            }
            _ => {
                return Err(Error::input(
                    origin,
                    format!(
                        "line {}: expected IMAGE<TAB>POINTS, found {} field(s)",
                        i + 1,
                        fields.iter().filter(|f| !f.is_empty()).count()
                    ),
                ))
            }
        }
    }
    if out.is_empty() {
        return Err(Error::input(
            origin,
            "no pairs (every line blank or a comment)",
        ));
    }
    Ok(out)
}

/// Read a pairs file.
pub(crate) fn read(path: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse(&text, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_pairs_read_back_and_relative_paths_follow_the_file() {
        let pairs = vec![
            (
                PathBuf::from("/d/image 00/1.png"),
                PathBuf::from("/d/v/1.bin"),
            ),
            (
                PathBuf::from("/d/image_00/2.png"),
                PathBuf::from("/d/v/2.bin"),
            ),
        ];
        let text = format(&pairs);
        assert_eq!(parse(&text, Path::new("/x/p.txt")).unwrap(), pairs);
        let rel = parse("a.png  b.bin\r\n\n# c\n", Path::new("/x/y/p.txt")).unwrap();
        assert_eq!(
            rel,
            vec![(PathBuf::from("/x/y/a.png"), PathBuf::from("/x/y/b.bin"))]
        );
    }

    #[test]
    fn malformed_lines_and_empty_files_name_the_file() {
        let e = parse("a.png\tb.bin\nc.png\n", Path::new("p.txt"))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "p.txt: line 2: expected IMAGE<TAB>POINTS, found 1 field(s)"
        );
        let e = parse("a.png\tb.bin\tc\n", Path::new("p.txt"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1") && e.contains("3 field(s)"), "{e}");
        let e = parse("# only\n\n", Path::new("p.txt"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("p.txt: no pairs"), "{e}");
    }
}
