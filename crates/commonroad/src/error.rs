//! The reader's error type: one line per error, naming the file and the offending element.

/// Why a CommonRoad file could not be read. `Display` is always one line starting with the file name;
/// [`ReadError::Invalid`] then names the element path, e.g.
/// `scenario.xml: lanelet 12 / leftBound / point 3 / x: expected a finite number with |value| <= 1e7, found "1e300"`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    /// The file could not be opened, inspected or read (or is not UTF-8 text).
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file.
        file: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The path names a directory, device, FIFO or socket rather than a regular file.
    #[error("{file}: expected a regular file, found {found}")]
    NotRegularFile {
        /// The file.
        file: String,
        /// What was found instead (e.g. `a directory`).
        found: String,
    },
    /// The file is larger than [`crate::MAX_FILE_BYTES`].
    #[error("{file}: expected at most {max} bytes, found {size} bytes")]
    TooLarge {
        /// The file.
        file: String,
        /// Its size in bytes.
        size: u64,
        /// The limit in bytes.
        max: u64,
    },
    /// The text is not well-formed XML (roxmltree's message with line:column), nests elements deeper
    /// than [`crate::MAX_DEPTH`] or has more than [`crate::MAX_XML_NODES`] nodes.
    #[error("{file}: malformed XML: {message}")]
    Xml {
        /// The file.
        file: String,
        /// What is wrong, with its position.
        message: String,
    },
    /// The XML is well formed but is not a valid CommonRoad scenario (or breaks a limit).
    #[error("{file}: {path}: {message}")]
    Invalid {
        /// The file.
        file: String,
        /// The element path, e.g. `lanelet 12 / leftBound / point 3` (ids for elements with an `id`,
        /// 1-based ordinals for repeated elements).
        path: String,
        /// What was expected and what was found.
        message: String,
    },
}

impl ReadError {
    /// The element path of an [`ReadError::Invalid`] error.
    pub fn path(&self) -> Option<&str> {
        match self {
            ReadError::Invalid { path, .. } => Some(path),
            _ => None,
        }
    }
}

/// Quotes text taken from the input for an error message: at most 40 characters, control
/// characters escaped, so that the message stays one short line.
pub(crate) fn quote(text: &str) -> String {
    let text = text.trim();
    let mut short: String = text.chars().take(40).collect();
    if short.len() < text.len() {
        short.push('…');
    }
    format!("\"{}\"", short.escape_debug())
}
