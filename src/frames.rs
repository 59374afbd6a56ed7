//! Image sequences, for whole shots: frame-numbered file names (`shot.####.exr`), frame sets
//! (`1001-1100`, `1-100x2`, `1,5,10-20`), values keyframed over the frames (a rack focus), and
//! running frames side by side.
//!
//! The grammar is the one compositors know from Nuke and fileseq:
//! - **Padding.** In a file name, a run of `#` or of `@` stands for the frame number with one
//!   digit per character (Nuke's convention, and fileseq's with one-digit hashes): `####` is
//!   `0042`, `@` is `42`. `%04d` is four digits and `%d` no padding, as in printf. A frame
//!   number longer than its padding is written in full (`#` with frame 1001 is `1001`), and a
//!   negative frame has its sign before the padded digits (`-0007`).
//! - **Frame sets.** Comma-separated items, each a frame `N`, a range `A-B` (both ends in, `B`
//!   may be below `A` for a backward range) or a stepped range `A-BxS`. Frames may be negative:
//!   `-5--1`. A frame listed twice runs once, where it is first listed.
//! - **Keyframes.** `V` (one value for every frame) or `F:V,F:V,...`: the value at frame `F`,
//!   held before the first key and after the last, and interpolated between keys in a space
//!   chosen per quantity ([`Interpolation`]).
//! - **Frame numbers** lie from `-FRAME_LIMIT` to [`FRAME_LIMIT`] (nine digits), in frame sets,
//!   keys and the files a sequence finds on disk; a number beyond is refused, naming it and
//!   the range, so that no arithmetic on frames can overflow.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::error::{shown, Error, Result};

/// Most frames one frame set may hold (a day of film at 24 frames a second is 2 million; a
/// typo such as `1-1000000000` is refused instead of filling memory).
pub const MAX_FRAMES: usize = 10_000_000;

/// The largest frame number (and, negated, the smallest) of a frame set, a key or a file found
/// on disk: nine digits, far beyond any shot, so that differences of frames and their ratios are
/// exact.
pub const FRAME_LIMIT: i64 = 999_999_999;

/// The widest padding of a frame number, in digits (`%032d`, or 32 `#`).
pub const MAX_PADDING: usize = 32;

/// Refuses a frame number outside `-FRAME_LIMIT..=FRAME_LIMIT`; `what` says where it came from.
fn check_frame(frame: i64, what: &str) -> std::result::Result<i64, String> {
    if (-FRAME_LIMIT..=FRAME_LIMIT).contains(&frame) {
        Ok(frame)
    } else {
        Err(format!(
            "{what} {frame} is outside the frames accepted, -{FRAME_LIMIT} to {FRAME_LIMIT}"
        ))
    }
}

/// A file name with a frame number in it: `shot.####.exr`, `shot.%04d.exr`, `shot.@.exr`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePattern {
    /// The folder, as given (empty for the current one).
    folder: PathBuf,
    /// The file name before the frame number.
    prefix: String,
    /// The file name after the frame number.
    suffix: String,
    /// Least number of digits of the frame number.
    padding: usize,
    /// The pattern as given, for messages.
    text: String,
}

impl FramePattern {
    /// The pattern in `path`'s file name, `Ok(None)` when the name has no frame token. Two
    /// tokens in one name, or a token in the folder part, are errors naming the path.
    pub fn parse(path: &Path) -> Result<Option<FramePattern>> {
        let text = path.to_string_lossy().into_owned();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            return Ok(None);
        };
        let tokens = tokens(name);
        let folder = path.parent().map(Path::to_path_buf).unwrap_or_default();
        if tokens.is_empty() {
            if tokens_in_folder(&folder) {
                return Err(Error::invalid(
                    "frame pattern",
                    format!(
                        "{}: the frame number (#, @ or %0Nd) must be in the file name, not in a folder",
                        shown(&text)
                    ),
                ));
            }
            return Ok(None);
        }
        if tokens.len() > 1 {
            return Err(Error::invalid(
                "frame pattern",
                format!(
                    "{}: expected one frame number (a run of # or @, or %0Nd) in the file name, found {}",
                    shown(&text),
                    tokens.len()
                ),
            ));
        }
        let (start, end, padding) = tokens[0];
        let padding = padding.filter(|p| *p <= MAX_PADDING).ok_or_else(|| {
            Error::invalid(
                "frame pattern",
                format!(
                    "{}: the frame number '{}' asks for more than {MAX_PADDING} digits; expected \
                     a run of up to {MAX_PADDING} # or @, or %0Nd with N up to {MAX_PADDING}",
                    shown(&text),
                    shown(&name[start..end])
                ),
            )
        })?;
        Ok(Some(FramePattern {
            folder,
            prefix: name[..start].to_string(),
            suffix: name[end..].to_string(),
            padding,
            text,
        }))
    }

    /// The file of frame `frame`.
    pub fn path(&self, frame: i64) -> PathBuf {
        self.folder.join(self.file_name(frame))
    }

    /// The file name (without the folder) of frame `frame`.
    pub fn file_name(&self, frame: i64) -> String {
        let digits = format!("{:0width$}", frame.unsigned_abs(), width = self.padding);
        let sign = if frame < 0 { "-" } else { "" };
        format!("{}{sign}{digits}{}", self.prefix, self.suffix)
    }

    /// The folder of the frames, as given (empty for the current one).
    pub fn folder(&self) -> &Path {
        &self.folder
    }

    /// The frame whose file name under this pattern is exactly `name` ([`Self::file_name`] of
    /// it), if any: `o11.exr` is frame 11 of `o#.exr` and frame 1 of `o1#.exr`.
    pub fn frame_named(&self, name: &str) -> Option<i64> {
        self.frame_of(name)
            .filter(|&frame| self.file_name(frame) == name)
    }

    /// The pattern as the user gave it.
    pub fn as_str(&self) -> &str {
        &self.text
    }

    /// The frame a file name holds under this pattern, if it matches: the prefix, then an
    /// optional `-` and at least `padding` digits (more only without a leading zero), then the
    /// suffix.
    pub fn frame_of(&self, name: &str) -> Option<i64> {
        let middle = name
            .strip_prefix(&self.prefix)?
            .strip_suffix(&self.suffix)?;
        let digits = middle.strip_prefix('-').unwrap_or(middle);
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        if digits.len() < self.padding || (digits.len() > self.padding && digits.starts_with('0')) {
            return None;
        }
        let value: i64 = digits.parse().ok()?;
        Some(if middle.starts_with('-') {
            -value
        } else {
            value
        })
    }

    /// The frames whose files exist in the pattern's folder, in increasing order.
    pub fn frames_on_disk(&self) -> Result<Vec<i64>> {
        let folder = if self.folder.as_os_str().is_empty() {
            Path::new(".")
        } else {
            &self.folder
        };
        let entries = std::fs::read_dir(folder).map_err(|e| Error::io(folder, e))?;
        let mut frames = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(folder, e))?;
            let name = entry.file_name();
            if let Some(f) = name.to_str().and_then(|n| self.frame_of(n)) {
                check_frame(f, "frame").map_err(|why| {
                    Error::invalid(
                        "frame pattern",
                        format!(
                            "{}: {why}: give the frames to run (--frames)",
                            shown(&folder.join(&name))
                        ),
                    )
                })?;
                frames.push(f);
            }
        }
        frames.sort_unstable();
        frames.dedup();
        Ok(frames)
    }
}

/// The frame tokens of a file name: (start byte, end byte, padding digits), the padding `None`
/// when `%Nd`'s N is too large to be read.
fn tokens(name: &str) -> Vec<(usize, usize, Option<usize>)> {
    let bytes = name.as_bytes();
    let mut found = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            c @ (b'#' | b'@') => {
                let start = i;
                while i < bytes.len() && bytes[i] == c {
                    i += 1;
                }
                found.push((start, i, Some(i - start)));
            }
            b'%' => {
                // %d or %0Nd (or %Nd, padded with spaces in printf: taken as N digits).
                let start = i;
                let mut j = i + 1;
                while j < bytes.len() && bytes[j].is_ascii_digit() {
                    j += 1;
                }
                if j < bytes.len() && bytes[j] == b'd' {
                    // No digits, or %0d: no padding (one digit at least).
                    let digits = &name[start + 1..j];
                    let width = if digits.is_empty() {
                        Some(1)
                    } else {
                        digits.parse::<usize>().ok().map(|w| w.max(1))
                    };
                    found.push((start, j + 1, width));
                    i = j + 1;
                } else {
                    i += 1;
                }
            }
            _ => i += 1,
        }
    }
    found
}

/// Whether a folder path holds a frame token (which we refuse: frames are files).
fn tokens_in_folder(folder: &Path) -> bool {
    folder.components().any(|c| {
        c.as_os_str()
            .to_str()
            .is_some_and(|s| !tokens(s).is_empty())
    })
}

/// An ordered set of frame numbers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameSet {
    frames: Vec<i64>,
}

impl FrameSet {
    /// Parses `1001-1100`, `1-100x2`, `1,5,10-20`, `-5--1` (see the module doc).
    pub fn parse(spec: &str) -> Result<FrameSet> {
        let bad = |why: String| {
            Error::invalid(
                "--frames",
                format!("'{spec}': {why}; expected frames such as 1001-1100, 1-100x2 or 1,5,10-20"),
            )
        };
        let mut frames = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for item in spec.split(',').map(str::trim) {
            if item.is_empty() {
                return Err(bad("an empty item".into()));
            }
            let (range, step) = match item.split_once('x') {
                Some((r, s)) => {
                    let step: i64 =
                        s.trim().parse().ok().filter(|&s| s > 0).ok_or_else(|| {
                            bad(format!("step '{s}' is not a whole number above 0"))
                        })?;
                    (r.trim(), Some(step))
                }
                None => (item, None),
            };
            let (first, last) = split_range(range)
                .ok_or_else(|| bad(format!("'{item}' is not a frame or a range A-B")))?;
            let first = check_frame(first, "frame").map_err(&bad)?;
            let last = check_frame(last, "frame").map_err(&bad)?;
            if step.is_some() && first == last && !range.contains('-') {
                return Err(bad(format!("'{item}': a step needs a range A-BxS")));
            }
            let step = step.unwrap_or(1);
            // Both ends lie within FRAME_LIMIT: their distance and the count fit easily.
            let count = first.abs_diff(last) / step.unsigned_abs() + 1;
            if frames.len() as u64 + count > MAX_FRAMES as u64 {
                return Err(bad(format!("more than {MAX_FRAMES} frames")));
            }
            let step = if last >= first { step } else { -step };
            let mut f = first;
            for _ in 0..count {
                if seen.insert(f) {
                    frames.push(f);
                }
                let Some(next) = f.checked_add(step) else {
                    break;
                };
                f = next;
            }
        }
        Ok(FrameSet { frames })
    }

    /// A set of the given frames, in that order (duplicates dropped).
    pub fn from_frames(list: impl IntoIterator<Item = i64>) -> FrameSet {
        let mut seen = std::collections::HashSet::new();
        FrameSet {
            frames: list.into_iter().filter(|f| seen.insert(*f)).collect(),
        }
    }

    /// The frames in order.
    pub fn frames(&self) -> &[i64] {
        &self.frames
    }
}

/// `N` or `A-B` with optional signs on both: (A, B).
fn split_range(s: &str) -> Option<(i64, i64)> {
    let number = |t: &str| t.trim().parse::<i64>().ok();
    if let Some(n) = number(s) {
        return Some((n, n));
    }
    // The separating '-' is the first one after the first character (which may be a sign).
    let at = s.char_indices().skip(1).find(|&(_, c)| c == '-')?.0;
    Some((number(&s[..at])?, number(&s[at + 1..])?))
}

/// How a keyframed value moves between two keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// Linearly in the value itself.
    Linear,
    /// Linearly in 1 / value: a focus distance, the way a focus puller's ring moves the image
    /// plane (the lens-to-sensor distance is linear in 1 / focus distance).
    Inverse,
    /// Linearly in log(value): an f-number, the way an aperture ring turns in stops.
    Logarithmic,
}

/// A value that may change over the frames: one constant, or keys (frame, value).
#[derive(Clone, Debug, PartialEq)]
pub struct Keyed {
    /// Keys in increasing frame order; one key with frame `None` is a constant.
    keys: Vec<(Option<i64>, f32)>,
}

impl Keyed {
    /// One value for every frame.
    pub fn constant(value: f32) -> Keyed {
        Keyed {
            keys: vec![(None, value)],
        }
    }

    /// Parses `V` or `F:V,F:V,...` (frames in increasing order, each once; values finite).
    /// `what` names the flag in errors.
    pub fn parse(spec: &str, what: &'static str) -> Result<Keyed> {
        let bad = |why: String| {
            Error::invalid(
                what,
                format!("'{spec}': {why}; expected a number, or keyframes FRAME:VALUE,... such as 1001:2.0,1100:5.0"),
            )
        };
        let number = |t: &str| {
            t.trim()
                .parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("'{}' is not a finite number", t.trim())))
        };
        if !spec.contains(':') {
            return Ok(Keyed::constant(number(spec)?));
        }
        let mut keys: Vec<(Option<i64>, f32)> = Vec::new();
        for item in spec.split(',') {
            let (f, v) = item
                .split_once(':')
                .ok_or_else(|| bad(format!("'{}' is not FRAME:VALUE", item.trim())))?;
            let f: i64 = f
                .trim()
                .parse()
                .map_err(|_| bad(format!("frame '{}' is not a whole number", f.trim())))?;
            let f = check_frame(f, "key frame").map_err(&bad)?;
            if let Some((Some(prev), _)) = keys.last() {
                if f <= *prev {
                    return Err(bad(format!(
                        "frame {f} comes after frame {prev}: expected keys in increasing frame order"
                    )));
                }
            }
            keys.push((Some(f), number(v)?));
        }
        Ok(Keyed { keys })
    }

    /// The value, when it is one constant (no keyframes).
    pub fn constant_value(&self) -> Option<f32> {
        match self.keys.as_slice() {
            [(None, v)] => Some(*v),
            _ => None,
        }
    }

    /// Whether the value changes over the frames (more than one key, or one key at a frame).
    pub fn is_keyed(&self) -> bool {
        self.keys.len() > 1 || self.keys[0].0.is_some()
    }

    /// Every value of the keys (to check them all before any frame runs).
    pub fn values(&self) -> impl Iterator<Item = f32> + '_ {
        self.keys.iter().map(|k| k.1)
    }

    /// The value at `frame`: held before the first key and after the last, interpolated
    /// between keys by `how` (the value's space must hold both keys: positive for
    /// [`Interpolation::Inverse`] and [`Interpolation::Logarithmic`], else linear is used).
    pub fn at(&self, frame: i64, how: Interpolation) -> f32 {
        let after = self
            .keys
            .iter()
            .position(|k| k.0.is_some_and(|f| f > frame));
        let (i0, i1) = match after {
            None => return self.keys[self.keys.len() - 1].1,
            Some(0) => return self.keys[0].1,
            Some(i) => (i - 1, i),
        };
        let ((f0, v0), (f1, v1)) = (self.keys[i0], self.keys[i1]);
        let (f0, f1) = (f0.unwrap_or(frame), f1.unwrap_or(frame));
        // In i128: frames from anywhere (a file's number) cannot overflow the differences.
        let span = |a: i64, b: i64| (i128::from(b) - i128::from(a)) as f64;
        let t = span(f0, frame) / span(f0, f1);
        let (v0, v1) = (f64::from(v0), f64::from(v1));
        let positive = v0 > 0.0 && v1 > 0.0;
        let v = match how {
            Interpolation::Inverse if positive => 1.0 / (1.0 / v0 + t * (1.0 / v1 - 1.0 / v0)),
            Interpolation::Logarithmic if positive => (v0.ln() + t * (v1.ln() - v0.ln())).exp(),
            _ => v0 + t * (v1 - v0),
        };
        v as f32
    }
}

/// How one frame of a sequence ended.
#[derive(Debug)]
pub enum FrameStatus {
    /// Rendered and written.
    Written,
    /// Its outputs existed already and were kept.
    Skipped,
}

/// Runs `job` on every frame, up to `workers` frames at a time (each job may itself use the
/// rayon pool), and hands each frame's result to `done` as it finishes, with the frame's index
/// in `frames`, in the order they finish. A failed frame does not stop the others. Nothing is
/// kept here: `done` decides what to keep of a result, so a long sequence holds no more than
/// that.
pub fn run_frames<T, E, J, D>(frames: &[i64], workers: usize, job: J, done: D)
where
    J: Fn(i64) -> Result<T, E> + Sync,
    D: Fn(usize, i64, Result<T, E>) + Sync,
{
    let next = AtomicUsize::new(0);
    let workers = workers.clamp(1, frames.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&frame) = frames.get(i) else {
                    break;
                };
                done(i, frame, job(frame));
            });
        }
    });
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use super::*;

    #[test]
    fn hashes_and_ats_give_one_digit_each() {
        let p = FramePattern::parse(Path::new("out/shot.####.exr"))
            .unwrap()
            .unwrap();
        assert_eq!(p.path(42), Path::new("out/shot.0042.exr"));
        assert_eq!(p.path(12345), Path::new("out/shot.12345.exr"));
        assert_eq!(p.path(-7), Path::new("out/shot.-0007.exr"));
        let p = FramePattern::parse(Path::new("a_@@.png")).unwrap().unwrap();
        assert_eq!(p.path(3), Path::new("a_03.png"));
        let p = FramePattern::parse(Path::new("f%04d.exr"))
            .unwrap()
            .unwrap();
        assert_eq!(p.path(1001), Path::new("f1001.exr"));
        assert_eq!(p.path(5), Path::new("f0005.exr"));
        let p = FramePattern::parse(Path::new("f%d.exr")).unwrap().unwrap();
        assert_eq!(p.path(5), Path::new("f5.exr"));
        assert!(FramePattern::parse(Path::new("plain.exr"))
            .unwrap()
            .is_none());
        assert!(FramePattern::parse(Path::new("100%.exr"))
            .unwrap()
            .is_none());
    }

    #[test]
    fn two_frame_numbers_or_one_in_a_folder_are_refused() {
        let e = FramePattern::parse(Path::new("a.##.b.##.exr")).unwrap_err();
        assert!(e.to_string().contains("found 2"), "{e}");
        let e = FramePattern::parse(Path::new("shot_####/beauty.exr")).unwrap_err();
        assert!(e.to_string().contains("not in a folder"), "{e}");
    }

    #[test]
    fn file_names_match_their_pattern_only() {
        let p = FramePattern::parse(Path::new("shot.####.exr"))
            .unwrap()
            .unwrap();
        assert_eq!(p.frame_of("shot.0042.exr"), Some(42));
        assert_eq!(p.frame_of("shot.12345.exr"), Some(12345));
        assert_eq!(p.frame_of("shot.-0003.exr"), Some(-3));
        assert_eq!(p.frame_of("shot.042.exr"), None);
        assert_eq!(p.frame_of("shot.00042.exr"), None);
        assert_eq!(p.frame_of("shot.0042.png"), None);
        assert_eq!(p.frame_of("shot.00a2.exr"), None);
        for f in [-12, 0, 7, 1001, 123456] {
            let name = p.path(f);
            assert_eq!(p.frame_of(name.to_str().unwrap()), Some(f));
        }
    }

    #[test]
    fn frame_sets_follow_the_compositors_grammar() {
        let f = |s: &str| FrameSet::parse(s).unwrap().frames().to_vec();
        assert_eq!(f("1001-1004"), [1001, 1002, 1003, 1004]);
        assert_eq!(f("1-10x3"), [1, 4, 7, 10]);
        assert_eq!(f("1-9x4"), [1, 5, 9]);
        assert_eq!(f("1,5,10-12"), [1, 5, 10, 11, 12]);
        assert_eq!(f("5-3"), [5, 4, 3]);
        assert_eq!(f("-2-1"), [-2, -1, 0, 1]);
        assert_eq!(f("-5--3"), [-5, -4, -3]);
        assert_eq!(f("3,1-4"), [3, 1, 2, 4]);
        assert_eq!(f(" 7 "), [7]);
        for bad in [
            "",
            "1,,2",
            "a-b",
            "1-10x0",
            "1-10x-2",
            "1-",
            "1-2-3",
            "0-100000000",
            "4x2",
        ] {
            let e = FrameSet::parse(bad).unwrap_err().to_string();
            assert!(e.contains("--frames"), "{bad}: {e}");
        }
    }

    #[test]
    fn frames_beyond_nine_digits_are_refused_with_the_range() {
        let f = |s: &str| FrameSet::parse(s).unwrap().frames().to_vec();
        assert_eq!(f("-999999999--999999998"), [-999_999_999, -999_999_998]);
        assert_eq!(f("999999998-999999999x5"), [999_999_998]);
        for bad in [
            "-9223372036854775808-9223372036854775807",
            "9223372036854775807",
            "1000000000",
            "0-1000000000x1000000",
        ] {
            let e = FrameSet::parse(bad).unwrap_err().to_string();
            assert!(e.contains("-999999999 to 999999999"), "{bad}: {e}");
        }
        let e = Keyed::parse("-9223372036854775808:2,9223372036854775807:3", "--focus")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--focus") && e.contains("-999999999 to 999999999"),
            "{e}"
        );
        // Keys at the ends of the range, and frames from anywhere, interpolate without overflow.
        let k = Keyed::parse("-999999999:2,999999999:3", "--focus").unwrap();
        assert_eq!(k.at(-999_999_999, Interpolation::Linear), 2.0);
        assert!((k.at(0, Interpolation::Linear) - 2.5).abs() < 1e-6);
        assert_eq!(k.at(i64::MAX, Interpolation::Linear), 3.0);
        assert_eq!(k.at(i64::MIN, Interpolation::Linear), 2.0);
    }

    #[test]
    fn absurd_paddings_are_refused() {
        for name in ["f%99999999999999999999d.exr", "f%33d.exr"] {
            let e = FramePattern::parse(Path::new(name))
                .unwrap_err()
                .to_string();
            assert!(e.contains("more than 32 digits"), "{name}: {e}");
        }
        let long = format!("f{}.exr", "#".repeat(33));
        assert!(FramePattern::parse(Path::new(&long)).is_err());
        let p = FramePattern::parse(Path::new("f%032d.exr"))
            .unwrap()
            .unwrap();
        assert_eq!(p.file_name(7).len(), "f.exr".len() + 32);
        let p = FramePattern::parse(Path::new("f%0d.exr")).unwrap().unwrap();
        assert_eq!(p.file_name(7), "f7.exr");
    }

    #[test]
    fn keyed_focus_moves_linearly_in_inverse_distance() {
        let k = Keyed::parse("1001:2.0,1101:5.0", "--focus").unwrap();
        assert!(k.is_keyed());
        assert_eq!(k.at(900, Interpolation::Inverse), 2.0);
        assert_eq!(k.at(1200, Interpolation::Inverse), 5.0);
        // Halfway in frames is halfway in 1/distance: 1/d = (1/2 + 1/5) / 2.
        let mid = k.at(1051, Interpolation::Inverse);
        assert!((mid - 1.0 / 0.35).abs() < 1e-5, "{mid}");
        assert!((k.at(1051, Interpolation::Linear) - 3.5).abs() < 1e-6);
        // Stops: halfway between f/2 and f/8 is f/4.
        let n = Keyed::parse("0:2,10:8", "--fstop").unwrap();
        assert!((n.at(5, Interpolation::Logarithmic) - 4.0).abs() < 1e-5);
        let c = Keyed::parse("2.8", "--fstop").unwrap();
        assert!(!c.is_keyed());
        assert_eq!(c.at(-40, Interpolation::Logarithmic), 2.8);
        for bad in ["", "x", "1:2,1:3", "5:2,3:1", "1:nan", "1:2,inf", "a:2"] {
            assert!(Keyed::parse(bad, "--focus").is_err(), "{bad}");
        }
    }

    #[test]
    fn every_frame_runs_once_and_failures_do_not_stop_the_others() {
        let frames: Vec<i64> = (1..=40).collect();
        let results = Mutex::new(Vec::new());
        run_frames(
            &frames,
            3,
            |f| if f % 7 == 0 { Err(f) } else { Ok(f * 2) },
            |i, f, r| {
                assert_eq!(frames[i], f);
                results.lock().unwrap().push((f, r));
            },
        );
        let mut results = results.into_inner().unwrap();
        results.sort_by_key(|r| r.0);
        assert_eq!(results.len(), 40);
        for (k, (f, r)) in results.into_iter().enumerate() {
            assert_eq!(f, k as i64 + 1);
            match r {
                Ok(v) => assert_eq!(v, f * 2),
                Err(e) => assert!(e == f && f % 7 == 0),
            }
        }
    }
}
