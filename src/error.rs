//! Typed errors of the library. Every variant names what was wrong and, for files, the path.

use std::ffi::OsStr;
use std::path::PathBuf;

/// Result alias for the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in the library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written. The OS error is part of the message and not
    /// also a `source`, so an error chain prints it once.
    #[error("{}: {}", shown(.path), .cause)]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        cause: std::io::Error,
    },
    /// A file was read but its content is not what was expected (corrupt, truncated, wrong channels).
    #[error("{}: {}", shown(.path), .message)]
    Format {
        /// The file.
        path: PathBuf,
        /// What was wrong, naming the field and what was expected.
        message: String,
    },
    /// A parameter is out of its valid range.
    #[error("invalid {name}: {message}")]
    Invalid {
        /// The parameter (flag or field) name.
        name: &'static str,
        /// What was given and what was expected.
        message: String,
    },
    /// A method option (a flag of the command line, a keyword of the Python package) is out of
    /// range or contradicts another; the message names the flag and what was expected.
    #[error("{0}")]
    Option(String),
    /// Two inputs disagree (e.g. image and depth sizes).
    #[error("mismatch: {0}")]
    Mismatch(String),
    /// A scene, method or option name that is not known.
    #[error("unknown {kind} '{name}' (expected one of: {expected})")]
    Unknown {
        /// What kind of thing (scene, method, ...).
        kind: &'static str,
        /// The name given.
        name: String,
        /// The valid names.
        expected: String,
    },
    /// The GPU backend failed: no adapter for `--device gpu`, a frame over the adapter's
    /// limits, a shader that did not build, a GPU out of memory or a lost device. The message
    /// names the adapter.
    #[error("GPU: {0}")]
    Gpu(String),
}

impl Error {
    /// Shorthand for [`Error::Invalid`].
    pub fn invalid(name: &'static str, message: impl Into<String>) -> Self {
        Error::Invalid {
            name,
            message: message.into(),
        }
    }

    /// Shorthand for [`Error::Format`].
    pub fn format(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            message: message.into(),
        }
    }

    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            cause: source,
        }
    }
}

/// A file name, path or URI as it may be printed in a message, on a terminal or in a report:
/// control characters are escaped (`\n`, `\r`, `\t`, `\x1b`, `\u{85}`) and so are the Unicode
/// bidirectional overrides that reorder what a terminal shows (`\u{202e}`), so a name cannot
/// move the cursor, recolour the terminal or forge a line. Bytes that are not UTF-8 show as
/// U+FFFD. Every path formatted into a message goes through here.
pub fn shown<S: AsRef<OsStr> + ?Sized>(name: &S) -> String {
    let text = name.as_ref().to_string_lossy();
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if c.is_control() && (c as u32) < 0x100 => {
                out.push_str(&format!("\\x{:02x}", c as u32));
            }
            c if c.is_control() || is_bidi_control(c) => {
                out.push_str(&format!("\\u{{{:x}}}", c as u32));
            }
            c => out.push(c),
        }
    }
    out
}

/// The Unicode characters that override the display order of text (embeddings, overrides,
/// isolates and marks).
fn is_bidi_control(c: char) -> bool {
    matches!(c, '\u{061c}' | '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_characters_in_names_are_escaped() {
        assert_eq!(shown("plain name.png"), "plain name.png");
        assert_eq!(shown("a\nb"), "a\\nb");
        assert_eq!(shown("\x1b[31mred"), "\\x1b[31mred");
        assert_eq!(shown("x\u{7f}\u{85}\u{202e}y"), "x\\x7f\\x85\\u{202e}y");
        assert_eq!(shown(std::path::Path::new("dir/t\tab")), "dir/t\\tab");
        assert_eq!(shown("caf\u{e9}"), "caf\u{e9}");
    }

    #[test]
    fn errors_print_paths_escaped() {
        let e = Error::format("evil\nerror: forged", "bad");
        assert_eq!(e.to_string(), "evil\\nerror: forged: bad");
    }
}
