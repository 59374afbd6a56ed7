//! Writing files: the one way every output of every command is written.
//!
//! 1. An [`OutputSet`] is one transaction: each output is written to a staged file beside its
//!    target, and all are renamed over their targets only by [`OutputSet::commit`], after every
//!    write succeeded. Dropped without a commit (an error, a panic), it removes its staged files
//!    and no target is touched. [`write_file`] is a set of one.
//! 2. A staged file has a short, hidden, unpredictable name in the target's folder
//!    (`.defocus-<pid>-<64 random bits>.tmp`: it stays within the file-name limit whatever the
//!    target's name) and is created with create-new, so it is never opened through an existing
//!    file or link. A link at the target is replaced by the rename, never written through.
//! 3. A target that exists and is not a regular file (a folder, a device, a FIFO, a socket, or a
//!    link to one of those) is refused, naming it.
//! 4. Every error names the target, never the staged file.
//! 5. Each staged file is synced to the disk before the rename, unless [`set_durable`] turned
//!    that off.
//! 6. An interrupted process removes its staged files with [`interrupt`], which waits for a
//!    commit under way to finish its renames, so a set's targets are all replaced or none.
//! 7. Files that belong together in one folder (a report) are replaced under a [`FolderLock`],
//!    and what was written is recorded by [`Digest`], so that a later run removes only files
//!    that are still exactly what it wrote.
//! 8. A process killed outright (SIGKILL, a power loss) cannot remove its staged files. On Unix
//!    each staged file is locked (`flock`) by its writer until it is renamed or removed, and the
//!    first file this process stages in a folder first removes the staged files there whose
//!    process no longer runs and which no one holds locked ([`remove_stale_staged`]).

use std::ffi::OsString;
use std::fs::{File, OpenOptions};
use std::hash::{BuildHasher, Hasher};
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

use crate::error::shown;
use crate::{Error, Result};

/// Staged files of this process not yet committed or removed. Its lock is also held by every
/// commit while it renames and by the creation of a staged file, so [`interrupt`] never runs
/// between the two renames of a commit nor misses a file just created.
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The pending list, also after a panic elsewhere (the list itself is always consistent).
fn pending() -> MutexGuard<'static, Vec<PathBuf>> {
    PENDING.lock().unwrap_or_else(|e| e.into_inner())
}

/// For a Ctrl-C or SIGTERM handler: waits for a commit under way to finish, removes every staged
/// file of this process, and keeps the staging lock, so that no file is staged or committed
/// afterwards. The caller then ends the process.
pub fn interrupt() {
    let mut staged = pending();
    for path in staged.drain(..) {
        let _ = std::fs::remove_file(path);
    }
    // Held until the process ends: a write or commit of another thread now waits forever.
    std::mem::forget(staged);
}

/// Whether a staged file is synced to the disk before its rename ([`set_durable`]).
static DURABLE: AtomicBool = AtomicBool::new(true);

/// Sets whether every output is synced to the disk (`fsync`) before it replaces its target, for
/// the whole process; the default is `true`. With `false` an output is still staged and renamed
/// (a reader never sees a partial file), but a crash or power loss soon after may leave a target
/// empty or lose it: for scratch outputs and render farms whose frames are checked afterwards.
pub fn set_durable(durable: bool) {
    DURABLE.store(durable, Ordering::Relaxed);
}

/// See [`set_durable`].
pub fn is_durable() -> bool {
    DURABLE.load(Ordering::Relaxed)
}

/// A staged file being written: a plain file that, on Linux, asks the kernel to start writing
/// its bytes to the disk every `WRITEBACK_BYTES` (`sync_file_range`, without waiting), so that
/// the fsync before the rename finds most of a large file already on its way and waits for less.
#[derive(Debug)]
pub struct StagedFile {
    file: File,
    /// Position of the next write.
    pos: u64,
    /// Bytes before this offset have been handed to the kernel's writeback.
    started: u64,
}

/// How many bytes a staged file writes between two requests for writeback.
const WRITEBACK_BYTES: u64 = 4 << 20;

impl StagedFile {
    fn new(file: File) -> Self {
        Self {
            file,
            pos: 0,
            started: 0,
        }
    }
}

impl Write for StagedFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.file.write(buf)?;
        self.pos += n as u64;
        if self.pos >= self.started + WRITEBACK_BYTES && is_durable() {
            #[cfg(target_os = "linux")]
            {
                use std::os::fd::AsRawFd;
                // SAFETY: the descriptor is this open file's; the call only starts the
                // writeback of a byte range of it and reads or writes no memory of ours.
                unsafe {
                    libc::sync_file_range(
                        self.file.as_raw_fd(),
                        self.started as libc::off64_t,
                        (self.pos - self.started) as libc::off64_t,
                        libc::SYNC_FILE_RANGE_WRITE,
                    );
                }
            }
            self.started = self.pos;
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl std::io::Seek for StagedFile {
    fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
        self.pos = self.file.seek(to)?;
        // Bytes rewritten behind the writeback mark are left to the fsync.
        self.started = self.started.max(self.pos);
        Ok(self.pos)
    }
}

/// The outputs of one command as one transaction (see the module documentation).
#[derive(Debug, Default)]
pub struct OutputSet {
    /// (staged file, target, the staged file's lock), in the order written. The lock is an
    /// open handle of the staged file that holds its `flock` until the entry is dropped.
    staged: Vec<(PathBuf, PathBuf, Option<File>)>,
}

impl OutputSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Writes the content of `target`: `fill` writes it to a new staged file, which is then
    /// flushed and synced. The target is replaced at [`OutputSet::commit`]. Errors name
    /// `target`; `fill` should name it too.
    pub fn write(
        &mut self,
        target: &Path,
        fill: impl FnOnce(&mut BufWriter<StagedFile>) -> Result<()>,
    ) -> Result<()> {
        check_target(target)?;
        let (temp, file) = create_staged(target)?;
        // Recorded at once, so that a failure below removes it (on drop).
        let lock = file.try_clone().ok();
        self.staged.push((temp, target.to_path_buf(), lock));
        let mut out = BufWriter::new(StagedFile::new(file));
        fill(&mut out)?;
        let staged = out
            .into_inner()
            .map_err(|e| Error::io(target, e.into_error()))?;
        if is_durable() {
            staged.file.sync_all().map_err(|e| Error::io(target, e))?;
        }
        Ok(())
    }

    /// Writes `bytes` as the content of `target` (see [`OutputSet::write`]).
    pub fn write_bytes(&mut self, target: &Path, bytes: &[u8]) -> Result<()> {
        self.write(target, |out| {
            out.write_all(bytes).map_err(|e| Error::io(target, e))
        })
    }

    /// The [`Digest`] of what has been staged for `target` (written, not yet committed).
    pub fn staged_digest(&self, target: &Path) -> Result<Digest> {
        let (temp, _, _) = self
            .staged
            .iter()
            .rev()
            .find(|(_, t, _)| t == target)
            .ok_or_else(|| {
                Error::invalid(
                    "output path",
                    format!("{} has not been written", shown(target)),
                )
            })?;
        let file = File::open(temp).map_err(|e| Error::io(target, e))?;
        Digest::of(file).map_err(|e| Error::io(target, e))
    }

    /// Renames every staged file over its target. Every target is checked again first (a folder
    /// or a device in the way fails before anything is renamed). The renames run under the
    /// staging lock, so an interrupt waits until they are done. A rename that still fails
    /// leaves the earlier targets replaced and the later staged files removed.
    pub fn commit(mut self) -> Result<()> {
        for (_, target, _) in &self.staged {
            check_target(target)?;
        }
        let mut pending = pending();
        let mut result = Ok(());
        for (temp, target, _lock) in self.staged.drain(..) {
            if result.is_ok() {
                result = std::fs::rename(&temp, &target).map_err(|e| Error::io(&target, e));
            }
            if result.is_err() {
                let _ = std::fs::remove_file(&temp);
            }
            pending.retain(|p| *p != temp);
        }
        result
    }
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if self.staged.is_empty() {
            return;
        }
        let mut pending = pending();
        for (temp, _, _lock) in self.staged.drain(..) {
            let _ = std::fs::remove_file(&temp);
            pending.retain(|p| *p != temp);
        }
    }
}

/// Writes one file as a transaction of its own: staged, synced, then renamed over `target`
/// (see [`OutputSet`]).
pub fn write_file(
    target: &Path,
    fill: impl FnOnce(&mut BufWriter<StagedFile>) -> Result<()>,
) -> Result<()> {
    let mut set = OutputSet::new();
    set.write(target, fill)?;
    set.commit()
}

/// Refuses a target that exists and is not a regular file, or a link to one; a link to a
/// regular file, or to nothing, is fine (the rename replaces the link itself).
pub fn check_target(target: &Path) -> Result<()> {
    if target.file_name().is_none() {
        return Err(Error::invalid(
            "output path",
            format!("{}: expected a path ending in a file name", shown(target)),
        ));
    }
    let Ok(meta) = std::fs::symlink_metadata(target) else {
        return Ok(());
    };
    let meta = if meta.file_type().is_symlink() {
        match std::fs::metadata(target) {
            Ok(m) => m,
            Err(_) => return Ok(()),
        }
    } else {
        meta
    };
    if meta.is_file() {
        return Ok(());
    }
    let kind = if meta.is_dir() {
        "a folder"
    } else {
        "not a regular file (a device, a FIFO or a socket)"
    };
    Err(Error::invalid(
        "output path",
        format!(
            "{} is {kind}: expected a new or a regular file",
            shown(target)
        ),
    ))
}

/// The size and SHA-256 of a file's content: how a command records the files it wrote, so that
/// a later run recognises them (a file replaced or changed since, by anyone, differs) before it
/// removes one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Digest {
    /// Length in bytes.
    pub bytes: u64,
    /// SHA-256 of the content, 64 lower-case hexadecimal digits.
    pub sha256: String,
}

impl Digest {
    /// The digest of everything `reader` yields.
    pub fn of(mut reader: impl Read) -> std::io::Result<Digest> {
        use sha2::Digest as _;
        let mut hasher = sha2::Sha256::new();
        let mut buf = vec![0u8; 1 << 16];
        let mut bytes = 0u64;
        loop {
            let n = match reader.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            hasher.update(&buf[..n]);
            bytes += n as u64;
        }
        let sha256 = hasher
            .finalize()
            .iter()
            .fold(String::with_capacity(64), |mut s, b| {
                use std::fmt::Write as _;
                let _ = write!(s, "{b:02x}");
                s
            });
        Ok(Digest { bytes, sha256 })
    }

    /// Whether `path` is a regular file (not a link: a link is never followed to a file
    /// elsewhere) whose content has this digest.
    pub fn matches_file(&self, path: &Path) -> bool {
        let is_plain_file = std::fs::symlink_metadata(path)
            .is_ok_and(|m| m.file_type().is_file() && m.len() == self.bytes);
        is_plain_file
            && crate::input::open_regular(path)
                .ok()
                .and_then(|f| Digest::of(f).ok())
                .is_some_and(|d| d == *self)
    }
}

/// An exclusive lock on a folder, held while a command replaces files in it that belong
/// together (a report: its images, its `results.json`, and the removal of the images of the
/// report it replaces), so that two commands writing into one folder at once take their turns
/// there. Released when dropped.
///
/// On Linux it is `flock` on the folder itself: nothing is left in the folder, and the lock
/// goes with the process however that ends. Elsewhere it is a file [`FolderLock::FILE_NAME`]
/// in the folder, created new and removed on drop (one left by a process that crashed must
/// be removed by hand).
#[derive(Debug)]
pub struct FolderLock {
    #[cfg(target_os = "linux")]
    _folder: File,
    #[cfg(not(target_os = "linux"))]
    file: PathBuf,
}

impl FolderLock {
    /// The lock file of systems without `flock` on folders.
    pub const FILE_NAME: &'static str = ".defocus-lock";

    /// Takes the lock on the folder `dir`. When another process (or another lock in this
    /// one) holds it, calls `waiting` once, then waits for it.
    pub fn acquire(dir: &Path, waiting: impl FnOnce()) -> Result<FolderLock> {
        #[cfg(target_os = "linux")]
        {
            use std::os::fd::AsRawFd;
            let folder = File::open(dir).map_err(|e| Error::io(dir, e))?;
            let lock = |mode: libc::c_int| loop {
                // SAFETY: the descriptor is the open folder's; flock reads no memory of ours.
                if unsafe { libc::flock(folder.as_raw_fd(), mode) } == 0 {
                    return Ok(());
                }
                let e = std::io::Error::last_os_error();
                if e.kind() != std::io::ErrorKind::Interrupted {
                    return Err(e);
                }
            };
            match lock(libc::LOCK_EX | libc::LOCK_NB) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    waiting();
                    lock(libc::LOCK_EX).map_err(|e| Error::io(dir, e))?;
                }
                Err(e) => return Err(Error::io(dir, e)),
            }
            Ok(FolderLock { _folder: folder })
        }
        #[cfg(not(target_os = "linux"))]
        {
            let file = dir.join(Self::FILE_NAME);
            let mut waiting = Some(waiting);
            loop {
                match OpenOptions::new().write(true).create_new(true).open(&file) {
                    Ok(_) => return Ok(FolderLock { file }),
                    Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                        if let Some(w) = waiting.take() {
                            w();
                        }
                        std::thread::sleep(std::time::Duration::from_millis(100));
                    }
                    Err(e) => return Err(Error::io(&file, e)),
                }
            }
        }
    }
}

#[cfg(not(target_os = "linux"))]
impl Drop for FolderLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.file);
    }
}

/// Distinguishes staged files of one process.
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// 64 bits no other process can predict: std's randomly keyed hasher over the clock, the process
/// id and a counter.
fn random_u64() -> u64 {
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    h.write_u128(now);
    h.write_u32(std::process::id());
    h.write_u64(COUNTER.fetch_add(1, Ordering::Relaxed));
    h.finish()
}

/// The process id in a staged file's name (`.defocus-<pid>-<16 hex digits>.tmp`), if `name` is
/// one.
fn staged_pid(name: &str) -> Option<u32> {
    let (pid, random) = name
        .strip_prefix(".defocus-")?
        .strip_suffix(".tmp")?
        .split_once('-')?;
    let is_digits = |s: &str, base: u32| !s.is_empty() && s.chars().all(|c| c.is_digit(base));
    (is_digits(pid, 10) && random.len() == 16 && is_digits(random, 16))
        .then(|| pid.parse().ok())
        .flatten()
}

/// Takes the `flock` of an open staged file without waiting: `true` when it is now held by
/// `file` (no other writer holds it). Elsewhere than on Unix, staged files are not locked.
fn lock_staged(file: &File) -> bool {
    #[cfg(unix)]
    {
        use std::os::fd::AsRawFd;
        // SAFETY: the descriptor is this open file's; flock reads no memory of ours.
        unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) == 0 }
    }
    #[cfg(not(unix))]
    {
        let _ = file;
        false
    }
}

/// Whether the process `pid` runs on this machine (or may: only "no such process" says no).
#[cfg(unix)]
fn process_runs(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return true;
    };
    // SAFETY: signal 0 checks that the process exists and sends nothing.
    let found = unsafe { libc::kill(pid, 0) } == 0;
    found || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Folders whose stale staged files this process has removed: each is looked at once.
static SWEPT: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Removes the staged files in `dir` that a process killed outright left: named
/// `.defocus-<pid>-<16 hex digits>.tmp`, a regular file (never a link), of another process that
/// no longer runs on this machine, and not locked (a writer on another machine that shares the
/// folder holds its staged file's lock while it lives). Once per folder per process; what
/// cannot be read or removed is left.
#[cfg(unix)]
pub fn remove_stale_staged(dir: &Path) {
    {
        let mut swept = SWEPT.lock().unwrap_or_else(|e| e.into_inner());
        if swept.iter().any(|d| d == dir) {
            return;
        }
        swept.push(dir.to_path_buf());
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let own = std::process::id();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(staged_pid) else {
            continue;
        };
        if pid == own || process_runs(pid) {
            continue;
        }
        let path = entry.path();
        if !std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_file()) {
            continue;
        }
        let mut options = OpenOptions::new();
        options.read(true);
        {
            use std::os::unix::fs::OpenOptionsExt;
            options.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
        }
        let Ok(file) = options.open(&path) else {
            continue;
        };
        // Removed while its lock is held here: no writer can be using it.
        if file.metadata().is_ok_and(|m| m.is_file()) && lock_staged(&file) {
            let _ = std::fs::remove_file(&path);
        }
    }
}

/// Creates a new, empty staged file in `target`'s folder, registered as pending and locked
/// ([`lock_staged`]); stale staged files of processes that are gone are removed from the folder
/// first ([`remove_stale_staged`]).
fn create_staged(target: &Path) -> Result<(PathBuf, File)> {
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    #[cfg(unix)]
    remove_stale_staged(dir);
    let mut attempts = 0;
    loop {
        let name = OsString::from(format!(
            ".defocus-{}-{:016x}.tmp",
            std::process::id(),
            random_u64()
        ));
        let temp = dir.join(name);
        // Created and registered under the lock: an interrupt sees every file that exists.
        let mut pending = pending();
        match OpenOptions::new().write(true).create_new(true).open(&temp) {
            Ok(file) => {
                pending.push(temp.clone());
                lock_staged(&file);
                return Ok((temp, file));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempts < 8 => {
                attempts += 1;
            }
            Err(e) => return Err(Error::io(target, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn staged_names_are_short_and_differ() {
        let dir = std::env::temp_dir().join(format!("defocus-output-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let target = dir.join("x".repeat(250));
        let (a, _) = create_staged(&target).unwrap();
        let (b, _) = create_staged(&target).unwrap();
        assert_ne!(a, b);
        for p in [&a, &b] {
            let name = p.file_name().unwrap().len();
            assert!(name < 48, "{}", p.display());
            std::fs::remove_file(p).unwrap();
        }
        pending().retain(|p| *p != a && *p != b);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn staged_names_give_their_process() {
        assert_eq!(staged_pid(".defocus-4242-0123456789abcdef.tmp"), Some(4242));
        for name in [
            ".defocus-4242-0123456789abcde.tmp",
            ".defocus-x-0123456789abcdef.tmp",
            ".defocus-4242-0123456789abcdeg.tmp",
            "defocus-4242-0123456789abcdef.tmp",
            ".defocus-4242-0123456789abcdef.exr",
            ".defocus-lock",
        ] {
            assert_eq!(staged_pid(name), None, "{name}");
        }
    }

    #[cfg(unix)]
    #[test]
    fn a_locked_staged_file_of_a_process_gone_from_this_machine_is_kept() {
        let dir = std::env::temp_dir().join(format!("defocus-stale-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        // A process id that ran and is gone.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let gone = child.id();
        child.wait().unwrap();
        let locked = dir.join(format!(".defocus-{gone}-00000000000000aa.tmp"));
        let stale = dir.join(format!(".defocus-{gone}-00000000000000bb.tmp"));
        std::fs::write(&stale, b"left").unwrap();
        std::fs::write(&locked, b"being written elsewhere").unwrap();
        // The writer on another machine holds its lock (another open file description).
        let writer = File::open(&locked).unwrap();
        assert!(lock_staged(&writer));
        remove_stale_staged(&dir);
        assert!(!stale.exists());
        assert!(locked.exists());
        drop(writer);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
