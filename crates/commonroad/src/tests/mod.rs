//! Unit tests: the real scenarios in the repository's `data/commonroad` (counts checked against
//! plain text counts of the XML, values spot-checked against the text), and one hostile document per
//! check, built by editing a small valid document.

mod hostile;
mod real_files;

use std::path::{Path, PathBuf};

/// This crate's directory as `cargo test` gives it when the tests run. The path compiled in is
/// only the fallback: this crate's test binary is not rebuilt when the same sources are built
/// from another checkout with the same target directory (CI's clone), and would read there.
fn crate_dir() -> PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")), PathBuf::from)
}

/// The repository's `data/commonroad` directory.
fn data_dir() -> PathBuf {
    crate_dir().join("../../data/commonroad")
}

/// The repository's `tests/data/commonroad/test_reading_all.xml` (commonroad-io's every-shape test).
fn reading_all() -> PathBuf {
    crate_dir().join("../../tests/data/commonroad/test_reading_all.xml")
}

/// The real scenario files, sorted.
fn real_files() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(data_dir())
        .expect("data/commonroad is readable")
        .map(|entry| entry.expect("directory entry").path())
        .filter(|path| path.extension().is_some_and(|e| e == "xml"))
        .collect();
    files.sort();
    files
}

/// A real scenario by file name.
fn real(name: &str) -> PathBuf {
    data_dir().join(name)
}

/// The file's text.
fn text_of(path: &Path) -> String {
    std::fs::read_to_string(path).expect("scenario text")
}

/// Occurrences of `pattern` in `text`.
fn count(text: &str, pattern: &str) -> usize {
    text.matches(pattern).count()
}

/// The number between `<tag>` and `</tag>` at the first `<tag>` after the first `anchor` (a plain
/// text search, independent of the reader).
fn number_after(text: &str, anchor: &str, tag: &str) -> f64 {
    let start = text.find(anchor).expect("anchor in text");
    let open = format!("<{tag}>");
    let from = start + text[start..].find(&open).expect("tag after anchor") + open.len();
    let to = from + text[from..].find('<').expect("closing tag");
    text[from..to].trim().parse().expect("a number")
}
