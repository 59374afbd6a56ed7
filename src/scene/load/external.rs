//! The files a scene file refers to (glTF buffer and image URIs, OBJ `mtllib`, MTL maps), read
//! as an untrusted scene may ask (see DESIGN.md, "Untrusted input"):
//! 1. The path is resolved against the scene's folder, following links, and refused when it
//!    leaves that folder (`../`, an absolute path, a link pointing out), unless the user allows
//!    external files ([`LoadOptions::allow_external_files`]).
//! 2. Only regular files are read: a device (`/dev/zero`), a FIFO or a folder is refused before
//!    it is opened, and checked again once open, so nothing blocks or reads without end.
//! 3. At most a given number of bytes is read (a buffer's declared `byteLength`, an image's cap),
//!    and a file longer than its cap is refused from its size, before it is read.
//! 4. What is read is counted against the memory budget ([`crate::budget::Ledger`], with the
//!    meshes and textures the loaders make), before it is read.
//! 5. An error about a refused file names the scene file, the field and the path as written, and
//!    says why: never anything read from the file, nor its size.

use std::io::Read;
use std::path::{Component, Path, PathBuf};

use super::LoadOptions;
use crate::budget::{gib_text, Ledger};
use crate::error::shown;
use crate::input::OpenError;
use crate::{Error, Result};

/// Most bytes read from an image file a scene refers to: far more than the largest image
/// accepted ([`MAX_PIXELS`](crate::image::MAX_PIXELS)) needs compressed, far less than memory.
pub const MAX_IMAGE_FILE_BYTES: u64 = 512 << 20;

/// Most bytes of a scene file itself (a `.gltf`, `.glb` or `.obj`), and of an MTL library.
pub const MAX_SCENE_FILE_BYTES: u64 = 4 << 30;

/// How much of a referenced file is read.
#[derive(Clone, Copy, Debug)]
pub(super) enum Limit {
    /// The whole file, refused when longer than this many bytes (images, MTL libraries).
    Cap(u64),
    /// Only the first this many bytes (a buffer's `byteLength`: what follows is not the
    /// buffer's, and is not read).
    Prefix(u64),
}

/// The folder of one scene file, and whether files outside it may be read.
#[derive(Debug)]
pub(super) struct SceneFolder {
    /// The scene file, as given: what errors name.
    scene: PathBuf,
    /// The folder that relative paths are resolved against, as given.
    dir: PathBuf,
    /// That folder with every link followed.
    root: PathBuf,
    allow_external: bool,
    /// The files read so far through this folder, as resolved (links followed).
    read: std::sync::Mutex<Vec<PathBuf>>,
    /// What the load holds: the files read, the meshes and textures made from them.
    ledger: Ledger,
}

/// Why a referenced file is not read.
enum Refusal {
    /// It resolves outside the scene's folder.
    Leaves,
    /// It exists but is not a regular file.
    NotRegular,
    /// It could not be opened or read (the OS error).
    Unreadable(std::io::Error),
    /// It is longer than the cap (only said of files the scene may read).
    TooLarge(u64),
    /// Reading it would pass the memory budget (the budget and what the load held before it).
    OverBudget { budget: u64, held: u64 },
}

impl SceneFolder {
    /// The folder of `scene` (the scene file's path as given).
    pub(super) fn new(scene: &Path, options: &LoadOptions) -> Result<Self> {
        let dir = match scene.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let root = dir.canonicalize().map_err(|e| Error::io(scene, e))?;
        Ok(Self {
            scene: scene.to_path_buf(),
            dir,
            root,
            allow_external: options.allow_external_files,
            read: std::sync::Mutex::new(Vec::new()),
            ledger: Ledger::new()?,
        })
    }

    /// What the load holds, counted against the memory budget: the files read through this
    /// folder, and what the loaders reserve for the meshes and textures they make.
    pub(super) fn ledger(&self) -> &Ledger {
        &self.ledger
    }

    /// The files read through this folder so far (resolved, each once), in the order first
    /// read.
    pub(super) fn files_read(&self) -> Vec<PathBuf> {
        self.read.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Reads `path` (already resolved) and records it among [`Self::files_read`].
    fn read_recorded(&self, path: &Path, limit: Limit) -> std::result::Result<Vec<u8>, Refusal> {
        let bytes = read_regular(path, limit, &self.ledger)?;
        let mut read = self.read.lock().unwrap_or_else(|e| e.into_inner());
        if !read.iter().any(|p| p == path) {
            read.push(path.to_path_buf());
        }
        Ok(bytes)
    }

    /// Reads the file `reference` (a path as the scene wrote it, after URI decoding) names,
    /// as much as `limit` says. `field` says where the scene names it (`buffers[0].uri`,
    /// `mtllib`, `material 'wood': map_Kd`); errors name the scene file, the field and the
    /// reference.
    pub(super) fn read(&self, field: &str, reference: &Path, limit: Limit) -> Result<Vec<u8>> {
        self.resolve(reference)
            .and_then(|path| self.read_recorded(&path, limit))
            .map_err(|why| self.refused(field, reference, why))
    }

    /// Like [`Self::read`], for a path already resolved by [`Self::resolve_checked`].
    pub(super) fn read_resolved(
        &self,
        field: &str,
        reference: &Path,
        path: &Path,
        limit: Limit,
    ) -> Result<Vec<u8>> {
        self.read_recorded(path, limit)
            .map_err(|why| self.refused(field, reference, why))
    }

    /// The file `reference` names, with links followed, or the error [`Self::read`] would give.
    pub(super) fn resolve_checked(&self, field: &str, reference: &Path) -> Result<PathBuf> {
        self.resolve(reference)
            .map_err(|why| self.refused(field, reference, why))
    }

    /// The scene file, as given.
    pub(super) fn scene(&self) -> &Path {
        &self.scene
    }

    /// An error about the scene file.
    pub(super) fn error(&self, message: String) -> Error {
        Error::format(&self.scene, message)
    }

    fn refused(&self, field: &str, reference: &Path, why: Refusal) -> Error {
        let reference = shown(reference);
        let message = match why {
            Refusal::Leaves => format!(
                "{field} '{reference}' leaves the scene's folder: a scene may only read files \
                 in its own folder (--allow-external-files reads others)"
            ),
            Refusal::NotRegular => {
                format!("{field} '{reference}' is not a regular file: expected a file of data")
            }
            Refusal::Unreadable(e) => format!("{field} '{reference}': could not read it: {e}"),
            Refusal::TooLarge(cap) => format!(
                "{field} '{reference}' is larger than {} MiB: expected a smaller file",
                cap >> 20
            ),
            Refusal::OverBudget { budget, held } => format!(
                "{field} '{reference}': reading it{} would pass the memory budget of {}: \
                 expected a smaller file (or raise --memory-budget)",
                match held {
                    0 => String::new(),
                    held => format!(" beside the {} the scene holds", gib_text(held)),
                },
                gib_text(budget)
            ),
        };
        self.error(message)
    }

    /// `reference` resolved against the folder with links followed, if the scene may read it.
    fn resolve(&self, given: &Path) -> std::result::Result<PathBuf, Refusal> {
        if !self.allow_external
            && given
                .components()
                .any(|c| matches!(c, Component::RootDir | Component::Prefix(_)))
        {
            return Err(Refusal::Leaves);
        }
        let joined = self.dir.join(given);
        match joined.canonicalize() {
            Ok(path) if self.allow_external || path.starts_with(&self.root) => Ok(path),
            Ok(_) => Err(Refusal::Leaves),
            Err(e) => {
                // Whether a file outside exists is not the scene's business either: judge by
                // the nearest folder on the way that does exist.
                let outside = !self.allow_external
                    && joined
                        .ancestors()
                        .skip(1)
                        .find_map(|a| a.canonicalize().ok())
                        .is_some_and(|a| !a.starts_with(&self.root));
                Err(if outside {
                    Refusal::Leaves
                } else {
                    Refusal::Unreadable(e)
                })
            }
        }
    }
}

/// Reads `path`, which must be a regular file, as far as `limit` says (opened by
/// [`crate::input::open_regular`]: a FIFO or a device is refused without blocking). Its size
/// decides before anything is read: a file longer than a cap is refused, and the bytes to read
/// are reserved in `ledger` (refused when they would pass the budget), then read into a buffer
/// of that size.
fn read_regular(
    path: &Path,
    limit: Limit,
    ledger: &Ledger,
) -> std::result::Result<Vec<u8>, Refusal> {
    let file = crate::input::open_regular(path).map_err(|e| match e {
        OpenError::NotRegular(_) => Refusal::NotRegular,
        OpenError::Io(e) => Refusal::Unreadable(e),
    })?;
    let len = file.metadata().map_err(Refusal::Unreadable)?.len();
    let (take, cap, expected) = match limit {
        Limit::Cap(cap) if len > cap => return Err(Refusal::TooLarge(cap)),
        // One byte more than the cap: a file that grows while it is read is caught too.
        Limit::Cap(cap) => (cap.saturating_add(1), Some(cap), len),
        Limit::Prefix(n) => (n, None, len.min(n)),
    };
    if !ledger.try_reserve(expected) {
        return Err(Refusal::OverBudget {
            budget: ledger.budget(),
            held: ledger.held(),
        });
    }
    let mut bytes = Vec::with_capacity(usize::try_from(expected).unwrap_or(usize::MAX));
    file.take(take)
        .read_to_end(&mut bytes)
        .map_err(Refusal::Unreadable)?;
    match cap {
        Some(cap) if bytes.len() as u64 > cap => Err(Refusal::TooLarge(cap)),
        _ => Ok(bytes),
    }
}

/// Reads the scene file itself: a regular file of at most [`MAX_SCENE_FILE_BYTES`] (a link to
/// a device or a FIFO given as the scene is refused, not read without end), refused from its
/// size when it is longer or when reading it would pass the memory budget (counted in
/// `folder`'s ledger).
pub(super) fn read_scene(path: &Path, folder: &SceneFolder) -> Result<Vec<u8>> {
    read_regular(path, Limit::Cap(MAX_SCENE_FILE_BYTES), &folder.ledger).map_err(|why| match why {
        Refusal::Unreadable(e) => Error::io(path, e),
        Refusal::NotRegular | Refusal::Leaves => {
            Error::format(path, "not a regular file: expected a scene file")
        }
        Refusal::TooLarge(cap) => Error::format(
            path,
            format!(
                "larger than {} GiB: expected a smaller scene file",
                cap >> 30
            ),
        ),
        Refusal::OverBudget { budget, .. } => Error::format(
            path,
            format!(
                "reading the scene file would pass the memory budget of {}: expected a \
                 smaller scene file (or raise --memory-budget)",
                gib_text(budget)
            ),
        ),
    })
}
