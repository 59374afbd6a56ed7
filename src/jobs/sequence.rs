//! Image sequences for `blur` and `render`: frame patterns in the file flags, `--frames`,
//! keyframed focus and f-number, and resuming by keeping finished frames.
//!
//! Each frame is an ordinary single-image job, built from the flags with the frame's file names
//! and lens values, so it is checked and written exactly as a lone image is (atomically). `blur`
//! runs frames side by side, as many as the worker threads and the memory budget allow, so that
//! one frame's reading and writing overlap another's filtering; `render` runs one frame at a
//! time, since each frame's passes already use every core. A failed frame does not stop the
//! others: [`Finished`] counts it, and keeps the errors of the first [`ERRORS_KEPT`].

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{bail, Context, Result};

use super::blur::{method_of, BlurArgs, BlurJob};
use super::flags::{check_output, open_device, Focus, FrameDone, IMAGE_EXTENSIONS};
use super::render::{RenderArgs, RenderJob};
use crate::error::shown;
use crate::frames::{self, FramePattern, FrameSet, Interpolation, Keyed};
use crate::image::io;
use crate::timing::Timings;

/// What a sequence reports while it runs. The callbacks are called from the threads that run
/// the frames.
pub struct Events<'a> {
    /// Once, before any frame runs: the frames to run, and those kept because their outputs
    /// exist.
    pub start: &'a (dyn Fn(&[i64], &[i64]) + Sync),
    /// After each frame, in the order they finish.
    pub frame: &'a (dyn Fn(i64, &Result<FrameDone>) + Sync),
    /// The lines a frame's job would show (the command line prints them).
    pub note: &'a (dyn Fn(String) + Sync),
}

impl Events<'static> {
    /// Reports nothing.
    pub fn none() -> Self {
        Events {
            start: &|_, _| {},
            frame: &|_, _| {},
            note: &|_| {},
        }
    }
}

/// A sequence run to its end.
#[derive(Debug)]
pub struct Finished {
    /// `blur` or `render`.
    pub command: &'static str,
    /// Every frame asked for.
    pub frames: Vec<i64>,
    /// The frames kept because their outputs existed.
    pub kept: Vec<i64>,
    /// The frames written.
    pub written: Vec<i64>,
    /// The first frames that failed in the order of `frames`, at most [`ERRORS_KEPT`], each
    /// with its error (every error was also handed to [`Events::frame`] as it happened).
    pub failed: Vec<(i64, anyhow::Error)>,
    /// How many frames failed, those beyond `failed` included.
    pub failed_count: usize,
    /// Each pass summed over the written frames.
    pub timings: Timings,
    /// The last frame written (its method and size).
    pub last: Option<FrameDone>,
    /// Wall-clock seconds of the run.
    pub wall_s: f64,
}

impl Finished {
    /// Frames written per second of the run.
    pub fn frames_per_second(&self) -> f64 {
        self.written.len() as f64 / self.wall_s.max(1e-9)
    }
}

/// The most failed frames whose errors a sequence keeps (the first ones): a sequence may have
/// [`frames::MAX_FRAMES`] frames, and keeping every error of a run whose input is missing would
/// take gigabytes.
pub const ERRORS_KEPT: usize = 100;

/// Bytes a frame of `blur` may take at its peak, per pixel: the largest frame method's
/// estimate (`lowrank`, 100) and the decoder's (32).
const BLUR_FRAME_BYTES_PER_PIXEL: u64 = 132;

/// Whether `blur`'s flags ask for a sequence (a frame pattern in --color). Patterns elsewhere
/// without one there, and --frames or --overwrite without one, are refused.
pub fn is_blur_sequence(a: &BlurArgs) -> Result<bool> {
    if FramePattern::parse(&a.color)
        .context("invalid --color")?
        .is_some()
    {
        return Ok(true);
    }
    if a.frames.is_some() || a.overwrite {
        bail!(
            "--frames and --overwrite are for sequences: give --color a frame pattern such as \
             shot.####.exr"
        );
    }
    let others = [("--out", Some(&a.out)), ("--depth", a.depth.as_ref())];
    for (flag, path) in others
        .into_iter()
        .chain([("--coc-out", a.coc_out.as_ref())])
    {
        if let Some(p) = path {
            if FramePattern::parse(p)
                .with_context(|| format!("invalid {flag}"))?
                .is_some()
            {
                bail!(
                    "{flag} {} has a frame number but --color {} has none: give --color a frame \
                     pattern too",
                    shown(p),
                    shown(&a.color)
                );
            }
        }
    }
    Ok(false)
}

/// Whether `render`'s flags ask for a sequence (--frames).
pub fn is_render_sequence(a: &RenderArgs) -> Result<bool> {
    let out = FramePattern::parse(&a.out).context("invalid --out")?;
    match (&a.frames, out) {
        (Some(_), _) => Ok(true),
        (None, Some(_)) => bail!(
            "--out {} is a frame pattern: give the frames to render with --frames (e.g. 1-48)",
            shown(&a.out)
        ),
        (None, None) => Ok(false),
    }
}

/// A pattern flag's pattern, or an error saying the flag needs one.
fn pattern(path: &std::path::Path, flag: &str) -> Result<FramePattern> {
    FramePattern::parse(path)
        .with_context(|| format!("invalid {flag}"))?
        .with_context(|| {
            format!(
                "{flag} {}: a sequence needs a frame pattern here too, such as shot.####.exr",
                shown(&path)
            )
        })
}

/// Refuses keyframed values that no frame could use, before any frame runs.
fn check_positive(k: &Keyed, flag: &str, unit: &str) -> Result<()> {
    if let Some(v) = k.values().find(|v| v.is_nan() || *v <= 0.0) {
        bail!("invalid {flag}: a key is {v}; expected {unit} greater than 0");
    }
    Ok(())
}

/// `blur` over a sequence.
pub fn blur(a: &BlurArgs, events: &Events) -> Result<Finished> {
    let color = pattern(&a.color, "--color")?;
    let out = pattern(&a.out, "--out")?;
    check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
    let coc_out = a
        .coc_out
        .as_ref()
        .map(|p| pattern(p, "--coc-out"))
        .transpose()?;
    if let Some(c) = &a.coc_out {
        io::check_distinct_outputs(&[("--out", &a.out), ("--coc-out", c)])?;
    }
    // A depth pattern, or one depth file for every frame (a locked-off camera).
    let depth = match &a.depth {
        Some(p) => Some(match FramePattern::parse(p).context("invalid --depth")? {
            Some(pat) => Ok(pat),
            None => Err(p.clone()),
        }),
        None => None,
    };
    let frames = match &a.frames {
        Some(spec) => FrameSet::parse(spec)?.frames().to_vec(),
        None => {
            let found = color.frames_on_disk()?;
            if found.is_empty() {
                bail!(
                    "no file matches --color {} (give --frames to name the frames)",
                    shown(color.as_str())
                );
            }
            found
        }
    };
    let focus = if a.focus.trim() == "auto" {
        None
    } else {
        let k = Keyed::parse(&a.focus, "--focus")?;
        check_positive(&k, "--focus", "a distance in metres")?;
        Some(k)
    };
    check_positive(&a.fstop, "--fstop", "an f-number")?;
    // Every file of every frame, before any frame runs: no frame's output may be another
    // frame's input or output.
    let mut files = vec![Named::input("--color", Files::Frames(&color))];
    match &depth {
        Some(Ok(pattern)) => files.push(Named::input("--depth", Files::Frames(pattern))),
        Some(Err(fixed)) => files.push(Named::input("--depth", Files::Each(fixed.clone()))),
        None => {}
    }
    let lens_file = a.post.lens_file();
    files.extend(fixed_inputs(Some(a.aperture.as_str()), lens_file));
    files.push(Named::output("--out", &out));
    if let Some(c) = &coc_out {
        files.push(Named::output("--coc-out", c));
    }
    check_clashes(&frames, &files)?;
    let frame_args = |n: i64| {
        let mut f = a.clone();
        f.color = color.path(n);
        f.depth = depth.as_ref().map(|d| match d {
            Ok(p) => p.path(n),
            Err(fixed) => fixed.clone(),
        });
        f.out = out.path(n);
        f.coc_out = coc_out.as_ref().map(|p| p.path(n));
        if let Some(k) = &focus {
            f.focus = k.at(n, Interpolation::Inverse).to_string();
        }
        f.fstop = Keyed::constant(a.fstop.at(n, Interpolation::Logarithmic));
        f.frames = None;
        f.timings = None;
        f.in_sequence = true;
        f
    };
    let outputs = |n: i64| -> Vec<PathBuf> {
        std::iter::once(out.path(n))
            .chain(coc_out.as_ref().map(|p| p.path(n)))
            .collect()
    };
    // As many frames at once as there are worker threads, within the memory budget (sized
    // from the first frame's header).
    let first_size = frames
        .iter()
        .find_map(|&n| io::image_size(&color.path(n)).ok());
    let per_frame = first_size.map_or(0, |(w, h)| {
        crate::methods::registry::FIXED_PEAK_BYTES + (w * h) as u64 * BLUR_FRAME_BYTES_PER_PIXEL
    });
    let by_memory = crate::budget::budget_bytes()? / per_frame.max(1);
    let workers = rayon::current_num_threads().min(by_memory.max(1) as usize);
    // One GPU context for every frame: its pipelines and buffers are reused.
    let gpu = open_device(a.device, method_of(a)?)?;
    run(
        "blur",
        &frames,
        outputs,
        a.overwrite,
        workers,
        events,
        |n| {
            BlurJob::new_on(&frame_args(n), gpu.clone(), &mut |line| (events.note)(line))?.execute()
        },
    )
}

/// `render` over a sequence.
pub fn render(a: RenderArgs, events: &Events) -> Result<Finished> {
    let spec = a.frames.as_deref().context("--frames")?;
    let frames = FrameSet::parse(spec)?.frames().to_vec();
    let out = pattern(&a.out, "--out")?;
    check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
    let depth_out = a
        .depth_out
        .as_ref()
        .map(|p| pattern(p, "--depth-out"))
        .transpose()?;
    if let Some(d) = &a.depth_out {
        check_output(d, "--depth-out", &["exr"])?;
        io::check_distinct_outputs(&[("--out", &a.out), ("--depth-out", d)])?;
    }
    if let Some(Focus::Keys(k)) = &a.focus {
        check_positive(k, "--focus", "a distance in metres")?;
    }
    if let Some(k) = &a.fstop {
        check_positive(k, "--fstop", "an f-number")?;
    }
    // Every file of every frame, before any frame runs: the scene file and the files it reads
    // (it is loaded once here for their list), and each frame's outputs.
    let mut files = Vec::new();
    if !crate::scene::builtin::NAMES.contains(&a.scene.as_str()) {
        let options = crate::scene::load::LoadOptions {
            allow_external_files: a.allow_external_files,
        };
        let scene = crate::scene::load::scene_by_name_or_path(
            &a.scene,
            a.view.camera.as_deref(),
            &options,
        )?;
        files.extend(
            scene
                .files_read
                .into_iter()
                .map(|p| Named::input("--scene", Files::Each(p))),
        );
    }
    files.extend(fixed_inputs(a.aperture.as_deref(), a.post.lens_file()));
    files.push(Named::output("--out", &out));
    if let Some(d) = &depth_out {
        files.push(Named::output("--depth-out", d));
    }
    check_clashes(&frames, &files)?;
    let frame_args = |n: i64| {
        let mut f = a.clone();
        f.out = out.path(n);
        f.depth_out = depth_out.as_ref().map(|p| p.path(n));
        if let Some(Focus::Keys(k)) = &a.focus {
            f.focus = Some(Focus::Metres(k.at(n, Interpolation::Inverse)));
        }
        f.fstop = a
            .fstop
            .as_ref()
            .map(|k| Keyed::constant(k.at(n, Interpolation::Logarithmic)));
        f.frames = None;
        f.timings = None;
        f.in_sequence = true;
        f
    };
    let outputs = |n: i64| -> Vec<PathBuf> {
        std::iter::once(out.path(n))
            .chain(depth_out.as_ref().map(|p| p.path(n)))
            .collect()
    };
    // One GPU context for every frame: its pipelines and buffers are reused.
    let gpu = open_device(a.device, &a.method)?;
    run("render", &frames, outputs, a.overwrite, 1, events, |n| {
        let mut note = |line| (events.note)(line);
        RenderJob::new_on(frame_args(n), gpu.clone(), &mut note)?.execute(&mut |_, _| {}, &mut note)
    })
}

/// The files one flag of a sequence names.
enum Files<'a> {
    /// A frame pattern: one file per frame.
    Frames(&'a FramePattern),
    /// One file for every frame (the depth pass of a locked-off camera, an aperture image, a
    /// scene file and the files it reads).
    Each(PathBuf),
}

/// The files of one flag, and whether the sequence writes them.
struct Named<'a> {
    flag: &'static str,
    files: Files<'a>,
    output: bool,
}

impl<'a> Named<'a> {
    fn input(flag: &'static str, files: Files<'a>) -> Self {
        Named {
            flag,
            files,
            output: false,
        }
    }

    fn output(flag: &'static str, pattern: &'a FramePattern) -> Self {
        Named {
            flag,
            files: Files::Frames(pattern),
            output: true,
        }
    }

    /// What the flag names, for messages: its pattern or its file.
    fn text(&self) -> String {
        match &self.files {
            Files::Frames(p) => shown(p.as_str()),
            Files::Each(p) => shown(p),
        }
    }
}

/// The inputs every frame reads besides its images: an `--aperture image:PATH` and a `--lens`
/// preset file.
fn fixed_inputs(aperture: Option<&str>, lens_file: Option<PathBuf>) -> Vec<Named<'static>> {
    let image = aperture
        .and_then(|s| s.strip_prefix("image:"))
        .map(|p| Named::input("--aperture image:", Files::Each(PathBuf::from(p))));
    let lens = lens_file.map(|p| Named::input("--lens", Files::Each(p)));
    image.into_iter().chain(lens).collect()
}

/// `path` with its links, `.` and `..` resolved as far as it exists: two spellings of one
/// place give one path (`./c.0001.exr`, `c.0001.exr`, a link to the folder).
fn resolved(path: &Path) -> PathBuf {
    let path = if path.as_os_str().is_empty() {
        Path::new(".")
    } else {
        path
    };
    if let Ok(p) = path.canonicalize() {
        return p;
    }
    match (path.parent(), path.file_name()) {
        (Some(parent), Some(name)) => resolved(parent).join(name),
        _ => std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()),
    }
}

/// Refuses a sequence in which a frame's output is a file that another frame reads or writes,
/// or the same frame reads: every output file of every frame is checked against every file of
/// every flag, by place (the folders resolved, so `./c.####.exr` and `c.%04d.exr` name
/// `c.####.exr`'s files) and, for files that exist, as the same file (device and inode: a hard
/// link, a link to a file). An output that would replace a file of an input pattern is refused
/// whether or not that frame is among `frames`; one that another output also writes, when both
/// frames are.
fn check_clashes(frames: &[i64], files: &[Named]) -> Result<()> {
    let mut sorted = frames.to_vec();
    sorted.sort_unstable();
    let asked = |m: i64| sorted.binary_search(&m).is_ok();
    // Where each flag's files lie: a pattern's folder, or the one file.
    let places: Vec<PathBuf> = files
        .iter()
        .map(|f| match &f.files {
            Files::Frames(p) => resolved(p.folder()),
            Files::Each(p) => resolved(p),
        })
        .collect();
    let refuse = |out: &Named, n: i64, path: &Path, other: &Named, m: Option<i64>| {
        let whose = match m {
            Some(m) => format!("frame {m} of {} {}", other.flag, other.text()),
            None => format!("{} {}", other.flag, other.text()),
        };
        let (verb, what) = if other.output {
            ("writes", "outputs never overwrite each other")
        } else {
            ("reads", "outputs never overwrite inputs")
        };
        anyhow::anyhow!(
            "{} {}: frame {n} would write {}, which {whose} {verb}: {what}; choose another {} \
             pattern",
            out.flag,
            out.text(),
            shown(path),
            out.flag
        )
    };
    // By place.
    for (i, out) in files.iter().enumerate().filter(|(_, f)| f.output) {
        let Files::Frames(pattern) = &out.files else {
            continue;
        };
        for &n in frames {
            let name = pattern.file_name(n);
            for (j, other) in files.iter().enumerate() {
                let clash = match &other.files {
                    Files::Frames(q) if places[j] == places[i] => q
                        .frame_named(&name)
                        .filter(|&m| (j, m) != (i, n) && (!other.output || asked(m)))
                        .map(Some),
                    Files::Each(_) => (places[j] == places[i].join(&name)).then_some(None),
                    Files::Frames(_) => None,
                };
                if let Some(m) = clash {
                    return Err(refuse(out, n, &pattern.path(n), other, m));
                }
            }
        }
    }
    // As files: the inputs that exist, by device and inode, against the outputs that exist.
    #[cfg(unix)]
    {
        use std::collections::HashMap;
        use std::os::unix::fs::MetadataExt;
        let id = |p: &Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
        let mut inputs: HashMap<(u64, u64), (usize, Option<i64>)> = HashMap::new();
        for (j, input) in files.iter().enumerate().filter(|(_, f)| !f.output) {
            match &input.files {
                Files::Frames(q) => {
                    for &m in frames {
                        if let Some(key) = id(&q.path(m)) {
                            inputs.entry(key).or_insert((j, Some(m)));
                        }
                    }
                }
                Files::Each(p) => {
                    if let Some(key) = id(p) {
                        inputs.entry(key).or_insert((j, None));
                    }
                }
            }
        }
        for out in files.iter().filter(|f| f.output) {
            let Files::Frames(pattern) = &out.files else {
                continue;
            };
            for &n in frames {
                let path = pattern.path(n);
                if let Some(&(j, m)) = id(&path).and_then(|key| inputs.get(&key)) {
                    return Err(refuse(out, n, &path, &files[j], m));
                }
            }
        }
    }
    Ok(())
}

/// Whether frame `n` is finished: each of its outputs exists and is a whole image
/// ([`io::check_whole`]: its header reads and the file is as long as the header says). An
/// output that exists but is not whole (empty, truncated by a full disk or a copy that
/// stopped) is noted, and its frame runs again.
fn finished(n: i64, outputs: &[PathBuf], events: &Events) -> bool {
    outputs.iter().all(|p| {
        if std::fs::symlink_metadata(p).is_err() {
            return false;
        }
        match io::check_whole(p) {
            Ok(()) => true,
            Err(e) => {
                (events.note)(format!("note: frame {n}: {e}; the frame runs again"));
                false
            }
        }
    })
}

/// Runs `job` on every frame whose outputs are not all there yet and whole (or every frame with
/// `overwrite`), `workers` at a time, reporting to `events`.
fn run(
    command: &'static str,
    frames: &[i64],
    outputs: impl Fn(i64) -> Vec<PathBuf>,
    overwrite: bool,
    workers: usize,
    events: &Events,
    job: impl Fn(i64) -> Result<FrameDone> + Sync,
) -> Result<Finished> {
    let (todo, kept): (Vec<i64>, Vec<i64>) = frames
        .iter()
        .partition(|&&n| overwrite || !finished(n, &outputs(n), events));
    (events.start)(&todo, &kept);
    let start = Instant::now();
    // What is kept of each frame as it finishes: the indices of the written ones, the last one
    // written, the first failures and their count, the timings summed.
    let tally = Mutex::new(Tally::default());
    frames::run_frames(&todo, workers, &job, |i, n, r| {
        (events.frame)(n, &r);
        let mut t = tally.lock().unwrap_or_else(|p| p.into_inner());
        match r {
            Ok(frame) => {
                t.timings.extend(&frame.timings);
                t.written.push(i);
                if t.last.as_ref().is_none_or(|(j, _)| *j <= i) {
                    t.last = Some((i, frame));
                }
            }
            Err(e) => {
                t.failed_count += 1;
                let at = t.failed.partition_point(|(j, _)| *j < i);
                if at < ERRORS_KEPT {
                    t.failed.insert(at, (i, e));
                    t.failed.truncate(ERRORS_KEPT);
                }
            }
        }
    });
    let mut t = tally.into_inner().unwrap_or_else(|p| p.into_inner());
    t.written.sort_unstable();
    Ok(Finished {
        command,
        frames: frames.to_vec(),
        kept,
        written: t.written.into_iter().map(|i| todo[i]).collect(),
        failed: t.failed.into_iter().map(|(i, e)| (todo[i], e)).collect(),
        failed_count: t.failed_count,
        timings: t.timings,
        last: t.last.map(|(_, frame)| frame),
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// What a sequence keeps of its frames' results while they run; frames by their index in the
/// frames to run.
#[derive(Default)]
struct Tally {
    written: Vec<usize>,
    last: Option<(usize, FrameDone)>,
    failed: Vec<(usize, anyhow::Error)>,
    failed_count: usize,
    timings: Timings,
}
