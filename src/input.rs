//! Opening the files a command reads: only regular files, never waiting on one.
//!
//! A FIFO blocks its reader until some writer comes, a device (`/dev/zero`, `/dev/random`)
//! reads without end, and a folder holds no data. Every file read as an input (images, scene
//! files and the files they refer to) is opened by [`open_regular`]:
//! 1. The path's type is checked before it is opened, following links: anything but a regular
//!    file is refused.
//! 2. It is opened without blocking (`O_NONBLOCK` on Linux), so a file swapped for a FIFO
//!    between the check and the open is not waited on either, and the open file's type is
//!    checked again.

use std::fs::{File, Metadata, OpenOptions};
use std::path::Path;

/// Why [`open_regular`] did not open a file.
#[derive(Debug)]
pub enum OpenError {
    /// It exists but is not a regular file: what it is (`a folder`, `a FIFO`, ...).
    NotRegular(&'static str),
    /// It could not be inspected or opened (the OS error: missing, no permission, ...).
    Io(std::io::Error),
}

/// What a file that is not a regular one is, for messages: `a folder`, `a FIFO`, `a device`,
/// `a socket`.
pub fn kind_of(meta: &Metadata) -> &'static str {
    let t = meta.file_type();
    if t.is_dir() {
        return "a folder";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_block_device() || t.is_char_device() {
            return "a device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    "not a file of data"
}

/// Opens `path` for reading if it is a regular file (or a link to one); see the module
/// documentation. Never blocks on a FIFO or a device.
pub fn open_regular(path: &Path) -> Result<File, OpenError> {
    let meta = std::fs::metadata(path).map_err(OpenError::Io)?;
    if !meta.is_file() {
        return Err(OpenError::NotRegular(kind_of(&meta)));
    }
    let mut options = OpenOptions::new();
    options.read(true);
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // Reads of a regular file never wait, so the flag changes nothing once it is one.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(OpenError::Io)?;
    let meta = file.metadata().map_err(OpenError::Io)?;
    if !meta.is_file() {
        return Err(OpenError::NotRegular(kind_of(&meta)));
    }
    Ok(file)
}
