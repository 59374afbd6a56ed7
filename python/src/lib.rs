//! `defocus._defocus`: the native module of the Python package, a thin shell over the library,
//! as the command line is another:
//! - NumPy arrays in and out: colour `HxWx3` / `HxWx4` (float32 linear, premultiplied where
//!   there is alpha; or uint8 sRGB, decoded as the command line decodes a PNG), depth `HxW`, and
//!   a leading batch axis `N` on both for batches;
//! - the methods' options parsed as the command line's flags ([`PostArgs`]), so their names,
//!   units, defaults and checks are the command line's;
//! - batches run in parallel (rayon) with the GIL released;
//! - errors as `ValueError` (bad arguments) or `OSError` (files), with the command line's
//!   message.
//!
//! The Python-facing signatures, docstrings and defaults are in `pysrc/defocus/__init__.py`.

use std::borrow::Cow;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use clap::{CommandFactory, Parser};
use defocus::blur::{frame_lens, DepthKind, FocusChoice, Highlights, LensSpec};
use defocus::gpu::{Device, GpuContext};
use defocus::image::io::{self, DepthRead, Placement};
use defocus::image::{ColorImage, GrayImage};
use defocus::jobs::blur::BlurArgs;
use defocus::jobs::report::CompareArgs;
use defocus::jobs::sequence::Events;
use defocus::lens::SamplerKind;
use defocus::methods::fill::{self, FillSettings, Occlusion};
use defocus::methods::registry::{self, Frame, SceneOptions, DEFAULT_FRAME_SAMPLES, METHODS};
use defocus::options::{parse_aperture, PostArgs};
use defocus::scene::load;
use defocus::timing::Timings;
use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use rayon::prelude::*;

/// The methods' flags alone, parsed from the keyword arguments turned into flags.
#[derive(Parser)]
#[command(name = "defocus", no_binary_name = true)]
struct MethodFlags {
    #[command(flatten)]
    post: PostArgs,
}

/// A library error as the Python exception it is: files are `OSError`, the rest `ValueError`.
/// The message is escaped as the command line prints it ([`defocus::error::shown`]): names
/// read from files (a scene's, a material's, a channel's) may hold control characters.
fn py_err(e: defocus::Error) -> PyErr {
    let text = defocus::error::shown(&e.to_string());
    match e {
        defocus::Error::Io { .. } => PyOSError::new_err(text),
        _ => PyValueError::new_err(text),
    }
}

/// A flag parser's error as a `ValueError` of one line: clap's message without its usage
/// lines, with what it lists (the missing arguments, the values expected) kept.
fn flag_error(kind: &str, e: &clap::Error) -> PyErr {
    let text = e.to_string();
    let lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .take_while(|l| !l.starts_with("Usage:"))
        .filter(|l| !l.is_empty() && !l.starts_with("For more information"))
        .collect();
    PyValueError::new_err(format!(
        "invalid {kind} option: {}",
        lines.join(" ").trim_start_matches("error: ")
    ))
}

/// Parses the method options (flags built from keyword arguments by the Python layer).
fn method_flags(flags: Vec<String>) -> PyResult<PostArgs> {
    MethodFlags::try_parse_from(flags)
        .map(|f| f.post)
        .map_err(|e| flag_error("method", &e))
}

/// A colour array as NumPy holds it, borrowed for the call.
enum ColorArray<'py> {
    /// Linear light, premultiplied alpha.
    F32(PyReadonlyArrayDyn<'py, f32>),
    /// sRGB-encoded, straight alpha.
    U8(PyReadonlyArrayDyn<'py, u8>),
}

impl<'py> ColorArray<'py> {
    /// `array` (`name` in errors) as float32 or uint8.
    fn of(array: &Bound<'py, PyAny>, name: &str) -> PyResult<Self> {
        if let Ok(a) = array.extract::<PyReadonlyArrayDyn<'py, f32>>() {
            Ok(Self::F32(a))
        } else if let Ok(a) = array.extract::<PyReadonlyArrayDyn<'py, u8>>() {
            Ok(Self::U8(a))
        } else {
            Err(PyValueError::new_err(format!(
                "{name}: expected a NumPy array of float32 (linear light) or uint8 (sRGB)"
            )))
        }
    }
}

/// Pixels of a batch of colour images: NumPy's buffer itself when the array is C-contiguous,
/// else its samples gathered once in C order.
enum Samples<'a> {
    /// Linear light, premultiplied alpha.
    F32(Cow<'a, [f32]>),
    /// sRGB-encoded, straight alpha.
    U8(Cow<'a, [u8]>),
}

/// The images an array holds, from its shape alone: `n` images of `h` x `w` pixels with `c`
/// channels (1 for depth).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Layout {
    n: usize,
    h: usize,
    w: usize,
    c: usize,
    /// Whether the array has a batch axis.
    batched: bool,
}

impl Layout {
    /// The layout of a colour array (`HxWxC` or `NxHxWxC`, C = 3 or 4) or, without `color`, a
    /// depth array (`HxW` or `NxHxW`), `name` in errors. Each image's size is checked against
    /// the library's limits ([`defocus::image::check_size`]), before anything reads or copies
    /// the array: a broadcast array's shape can be far larger than its memory.
    fn of(shape: &[usize], color: bool, name: &str) -> PyResult<Layout> {
        let layout = match (shape, color) {
            (&[h, w, c], true) if c == 3 || c == 4 => (1, h, w, c, false),
            (&[n, h, w, c], true) if c == 3 || c == 4 => (n, h, w, c, true),
            (&[h, w], false) => (1, h, w, 1, false),
            (&[n, h, w], false) => (n, h, w, 1, true),
            _ => {
                return Err(PyValueError::new_err(if color {
                    format!(
                        "{name}: shape {shape:?}: expected HxWx3 or HxWx4 (or NxHxWxC for a batch)"
                    )
                } else {
                    format!("{name}: shape {shape:?}: expected HxW (or NxHxW for a batch)")
                }))
            }
        };
        let (n, h, w, c, batched) = layout;
        defocus::image::check_size(w, h).map_err(|e| {
            PyValueError::new_err(format!("{name}: shape {shape:?}: {}", shown_error(&e)))
        })?;
        Ok(Layout {
            n,
            h,
            w,
            c,
            batched,
        })
    }

    /// Samples of the whole array (saturating: a shape's product may exceed any memory).
    fn samples(&self) -> u64 {
        [self.n, self.h, self.w, self.c]
            .iter()
            .fold(1u64, |a, &b| a.saturating_mul(b as u64))
    }

    /// Pixels of one image.
    fn pixels(&self) -> u64 {
        self.h as u64 * self.w as u64
    }
}

/// A library error's message, escaped for the terminal.
fn shown_error(e: &defocus::Error) -> String {
    defocus::error::shown(&e.to_string())
}

/// Refuses work whose memory (`bytes`, for `what`) exceeds the budget
/// ([`defocus::budget`]), before anything is allocated.
fn check_memory(bytes: u64, what: &str) -> PyResult<()> {
    defocus::budget::check(bytes, what, "the batch or the image size").map_err(py_err)
}

/// Bytes of the copy of an array that is not C-contiguous (its samples gathered in C order),
/// 0 for one that is read in place.
fn gathered_bytes<T: numpy::Element>(a: &PyReadonlyArrayDyn<'_, T>, layout: &Layout) -> u64 {
    if a.is_c_contiguous() {
        0
    } else {
        layout
            .samples()
            .saturating_mul(std::mem::size_of::<T>() as u64)
    }
}

/// Checks an array's shape before the Python layer converts it (`defocus._as_color`,
/// `_as_depth`): its layout, each image's size against the library's limit, and its samples as
/// float32 against the memory budget. `color` tells a colour array from a depth array.
#[pyfunction]
fn check_array(name: &str, shape: Vec<usize>, color: bool) -> PyResult<()> {
    let layout = Layout::of(&shape, color, name)?;
    check_memory(
        layout.samples().saturating_mul(4),
        &format!("{name} as float32 (shape {shape:?})"),
    )
}

/// A batch of colour images: `n` images of `h` x `w` pixels with `c` channels (3 or 4).
struct ColorBatch<'a> {
    n: usize,
    h: usize,
    w: usize,
    c: usize,
    /// Whether the array had a batch axis.
    batched: bool,
    samples: Samples<'a>,
}

impl<'a> ColorBatch<'a> {
    /// The layout of `array` (`name` in errors: `HxWxC` or `NxHxWxC`, C = 3 or 4, each image
    /// within the size limit) and the bytes a copy of it takes when it must be gathered, from
    /// its shape alone.
    fn layout(array: &ColorArray<'_>, name: &str) -> PyResult<(Layout, u64)> {
        Ok(match array {
            ColorArray::F32(a) => {
                let l = Layout::of(a.shape(), true, name)?;
                (l, gathered_bytes(a, &l))
            }
            ColorArray::U8(a) => {
                let l = Layout::of(a.shape(), true, name)?;
                (l, gathered_bytes(a, &l))
            }
        })
    }

    /// Reads `array`, whose layout [`ColorBatch::layout`] gave (and whose memory the caller
    /// checked): NumPy's buffer, or its samples gathered once in C order.
    fn new(array: &'a ColorArray<'_>, layout: Layout) -> Self {
        let samples = match array {
            ColorArray::F32(a) => Samples::F32(samples_of(a)),
            ColorArray::U8(a) => Samples::U8(samples_of(a)),
        };
        Self {
            n: layout.n,
            h: layout.h,
            w: layout.w,
            c: layout.c,
            batched: layout.batched,
            samples,
        }
    }

    /// Bytes of a sample of the array and of the output made like it.
    fn sample_bytes(array: &ColorArray<'_>) -> u64 {
        match array {
            ColorArray::F32(_) => 4,
            ColorArray::U8(_) => 1,
        }
    }

    /// Image `i` as the library's linear premultiplied RGBA. Float colour must be finite, as
    /// the command line requires of the images it reads: the error names the channel, the
    /// pixel and the value (`name` names the array).
    fn image(&self, i: usize, name: &str) -> defocus::Result<ColorImage> {
        let len = self.h * self.w * self.c;
        match &self.samples {
            Samples::F32(s) => {
                let s = &s[i * len..(i + 1) * len];
                let c = self.c;
                let mut pixels = recycled::colors().take(self.h * self.w);
                pixels.par_extend(
                    s.par_chunks_exact(c)
                        .map(|p| [p[0], p[1], p[2], if c == 4 { p[3] } else { 1.0 }]),
                );
                let image = ColorImage::from_vec(self.w, self.h, pixels)?;
                if let Some(why) = io::non_finite_color(&image) {
                    return Err(defocus::Error::Option(format!(
                        "{name}: {why} (numpy.nan_to_num replaces them)"
                    )));
                }
                Ok(image)
            }
            Samples::U8(s) => {
                io::color_from_srgb8(self.w, self.h, self.c, &s[i * len..(i + 1) * len])
            }
        }
    }
}

/// Output images back in the input's layout: same dtype, channels and batch axis. The array
/// is made once and filled in parallel, the GIL released.
fn to_numpy(py: Python<'_>, like: &ColorBatch, mut images: Vec<ColorImage>) -> PyResult<Py<PyAny>> {
    let mut shape = vec![like.h, like.w, like.c];
    if like.batched {
        shape.insert(0, images.len());
    }
    let c = like.c;
    let len = like.h * like.w * c;
    if matches!(like.samples, Samples::F32(_)) && c == 4 && images.len() == 1 {
        // One RGBA float image: its pixels become the array, without a copy.
        let data = images.remove(0).into_vec().into_flattened();
        return ArrayD::from_shape_vec(IxDyn(&shape), data)
            .map(|a| a.into_pyarray(py).into_any().unbind())
            .map_err(|e| PyValueError::new_err(e.to_string()));
    }
    let w = like.w;
    match like.samples {
        Samples::F32(_) => filled::<f32>(py, &shape, len, &images, |dst, img| {
            dst.par_chunks_mut(w * c)
                .zip(img.pixels().par_chunks(w))
                .for_each(|(row, src)| {
                    for (d, p) in row.chunks_exact_mut(c).zip(src) {
                        d.copy_from_slice(&p[..c]);
                    }
                })
        }),
        Samples::U8(_) => filled::<u8>(py, &shape, len, &images, |dst, img| {
            let rgba = io::png8_samples(img);
            for (d, p) in dst.chunks_exact_mut(c).zip(rgba.chunks_exact(4)) {
                d.copy_from_slice(&p[..c]);
            }
        }),
    }
}

/// A new array of `shape`, each image's `len` samples filled by `fill` in parallel, the GIL
/// released.
fn filled<T: numpy::Element + Send>(
    py: Python<'_>,
    shape: &[usize],
    len: usize,
    images: &[ColorImage],
    fill: impl Fn(&mut [T], &ColorImage) + Sync,
) -> PyResult<Py<PyAny>> {
    let array = PyArrayDyn::<T>::zeros(py, IxDyn(shape), false);
    {
        let mut view = array.readwrite();
        let out = view
            .as_slice_mut()
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        py.detach(|| {
            out.par_chunks_mut(len)
                .zip(images)
                .for_each(|(dst, img)| fill(dst, img))
        });
    }
    Ok(array.into_any().unbind())
}

/// Depth `HxW`, or `NxHxW` for a batch, as float32 values.
fn depth_array<'py>(array: &Bound<'py, PyAny>) -> PyResult<PyReadonlyArrayDyn<'py, f32>> {
    array
        .extract::<PyReadonlyArrayDyn<'py, f32>>()
        .map_err(|_| {
            PyValueError::new_err(
                "depth: expected a NumPy array of float32 (HxW, or NxHxW for a batch)",
            )
        })
}

/// An array's samples in C order: its own buffer when it is C-contiguous, else gathered
/// element by element.
fn samples_of<'a, T: numpy::Element + Copy>(a: &'a PyReadonlyArrayDyn<'_, T>) -> Cow<'a, [T]> {
    match a.as_slice() {
        Ok(s) => Cow::Borrowed(s),
        Err(_) => Cow::Owned(a.as_array().iter().copied().collect()),
    }
}

/// The buffers the input arrays are converted into, kept from one call for the next: fresh
/// memory costs a page fault per page on its first write, several times the copy itself (a
/// 1280x720 frame's conversion took 6 ms in new memory, 1.5 ms in reused), and a data set is
/// made by many calls of one size. At most a few buffers per kind, and 512 MiB in all, are
/// kept.
mod recycled {
    use std::sync::{Mutex, MutexGuard};

    use defocus::image::Rgba;

    /// Spare buffers of one element type.
    pub struct Pool<T> {
        spare: Vec<Vec<T>>,
    }

    /// How many spare buffers a pool keeps: one per worker thread and one more.
    fn most_kept() -> usize {
        rayon::current_num_threads() + 1
    }

    /// The bytes a pool keeps at most.
    const MOST_BYTES: usize = 256 << 20;

    impl<T> Pool<T> {
        /// An empty buffer with room for `len` elements: a spare one if one is that large.
        pub fn take(&mut self, len: usize) -> Vec<T> {
            match self.spare.iter().position(|v| v.capacity() >= len) {
                Some(i) => {
                    let mut v = self.spare.swap_remove(i);
                    v.clear();
                    v
                }
                None => Vec::with_capacity(len),
            }
        }

        /// Keeps `v` for a later call, unless the pool is full.
        pub fn keep(&mut self, v: Vec<T>) {
            let bytes = |v: &Vec<T>| v.capacity() * std::mem::size_of::<T>();
            let held: usize = self.spare.iter().map(bytes).sum();
            if self.spare.len() < most_kept() && held + bytes(&v) <= MOST_BYTES {
                self.spare.push(v);
            }
        }
    }

    static COLORS: Mutex<Pool<Rgba>> = Mutex::new(Pool { spare: Vec::new() });
    static DEPTHS: Mutex<Pool<f32>> = Mutex::new(Pool { spare: Vec::new() });

    /// The pool of colour buffers.
    pub fn colors() -> MutexGuard<'static, Pool<Rgba>> {
        COLORS.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The pool of depth buffers.
    pub fn depths() -> MutexGuard<'static, Pool<f32>> {
        DEPTHS.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Everything of a `blur` call but the pixels.
struct BlurParams {
    /// The GPU the method runs on; `None`: the CPU.
    gpu: Option<Arc<GpuContext>>,
    method: String,
    kind: DepthKind,
    depth_scale: f32,
    zero_depth_is_far: bool,
    focus: FocusChoice,
    spec: LensSpec,
    aperture: String,
    seed: u64,
    post: PostArgs,
}

/// The GPU contexts opened so far, one per `device` value: a context is costly to open (the
/// driver, the device, the compiled pipelines), so the calls of a program share it, as the
/// frames of a command-line sequence do.
static CONTEXTS: Mutex<Vec<(Device, Arc<GpuContext>)>> = Mutex::new(Vec::new());

/// The GPU context a call of `method` takes for `device` (`"cpu"`, `"gpu"` or `"auto"`, as
/// `--device`), or `None` for the CPU; opened on first use, then shared.
fn gpu_for(device: &str, method: &str) -> PyResult<Option<Arc<GpuContext>>> {
    let d = match device {
        "cpu" => Device::Cpu,
        "gpu" => Device::Gpu,
        "auto" => Device::Auto,
        other => {
            return Err(PyValueError::new_err(format!(
                "invalid device '{other}': expected 'cpu', 'gpu' or 'auto'"
            )))
        }
    };
    let info = registry::find(method).map_err(py_err)?;
    match d {
        Device::Cpu => return Ok(None),
        Device::Auto if !info.gpu => return Ok(None),
        Device::Gpu if !info.gpu => {
            registry::check_gpu(method).map_err(py_err)?;
        }
        _ => {}
    }
    let mut contexts = CONTEXTS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, ctx)) = contexts.iter().find(|(k, _)| *k == d) {
        return Ok(Some(Arc::clone(ctx)));
    }
    let opened = GpuContext::open(d)
        .map_err(|e| PyValueError::new_err(format!("device: {e}")))?
        .map(Arc::new);
    if let Some(ctx) = &opened {
        contexts.push((d, Arc::clone(ctx)));
    }
    Ok(opened)
}

/// One frame of `blur`: the image and the method's per-pass timings.
fn blur_one(
    color: ColorImage,
    values: Vec<f32>,
    p: &BlurParams,
) -> defocus::Result<(ColorImage, Timings)> {
    let (w, h) = (color.width(), color.height());
    let source = Path::new("depth array");
    let depth = if p.kind == DepthKind::Coc {
        let radii: Vec<f32> = values.iter().map(|v| v * p.depth_scale).collect();
        if let Some(why) = io::bad_coc_radii(&radii, w) {
            return Err(defocus::Error::Option(format!(
                "depth (depth_kind coc), times depth_scale {}: {why}",
                p.depth_scale
            )));
        }
        GrayImage::from_vec(w, h, radii)?
    } else {
        let opts = DepthRead {
            scale: p.depth_scale,
            inverse: p.kind == DepthKind::Inverse,
            zero_is_far: p.zero_depth_is_far,
            ..DepthRead::default()
        };
        io::depth_from_values(source, "values", w, h, values, &opts)?
    };
    let fl = frame_lens(
        depth,
        p.kind,
        p.focus,
        &p.spec,
        &Placement::full(w, h),
        "color array",
    )?;
    let start = Instant::now();
    let aperture = parse_aperture(&p.aperture)?;
    let settings = p
        .post
        .settings(&p.method, &aperture, p.seed, h, Some(&fl.lens))?;
    let frame = Frame {
        color: &color,
        depth: &fl.depth,
        lens: &fl.lens,
    };
    let layered = registry::find(&p.method)?.input == registry::InputKind::FragmentLists
        || matches!(
            (&settings, p.post.occlusion),
            (registry::MethodSettings::Splat(_), Occlusion::Fill)
        );
    let mut out = match p.post.occlusion {
        _ if layered => fill::run_layered(&settings, &frame, p.post.occlusion)?,
        Occlusion::None => registry::run_frame_on(&settings, &frame, p.gpu.as_deref())?,
        Occlusion::Fill if p.gpu.is_some() => return Err(defocus::Error::Option(
            "occlusion='fill' runs on the CPU only so far: use device='cpu', or occlusion='none'"
                .to_string(),
        )),
        Occlusion::Fill => fill::run_frame(&settings, &frame, &FillSettings::default())?,
    };
    // The whole library call, its passes and the work between them, as the last row.
    out.timings
        .add(METHOD_WALL, start.elapsed().as_secs_f64() * 1e3);
    recycled::colors().keep(color.into_vec());
    recycled::depths().keep(fl.depth.into_vec());
    Ok((out.image, out.timings))
}

/// The row of `blur(..., timings=True)` that is not a pass: the library call's wall time.
const METHOD_WALL: &str = "method";

/// Parses a focus argument: a distance in metres or `"auto"`.
fn focus_choice(
    focus: Option<&Bound<'_, PyAny>>,
    pixel: Option<(usize, usize)>,
) -> PyResult<FocusChoice> {
    if let Some((x, y)) = pixel {
        if focus.is_some_and(|f| !f.is_none()) {
            return Err(PyValueError::new_err("give focus or focus_pixel, not both"));
        }
        return Ok(FocusChoice::Pixel(x, y));
    }
    match focus {
        None => Ok(FocusChoice::Auto),
        Some(f) if f.is_none() => Ok(FocusChoice::Auto),
        Some(f) => {
            if let Ok(s) = f.extract::<String>() {
                if s.trim() == "auto" {
                    return Ok(FocusChoice::Auto);
                }
                return Err(PyValueError::new_err(format!(
                    "invalid focus '{s}': expected a distance in metres or 'auto'"
                )));
            }
            let m: f32 = f.extract().map_err(|_| {
                PyValueError::new_err("invalid focus: expected a distance in metres or 'auto'")
            })?;
            Ok(FocusChoice::Metres(m))
        }
    }
}

/// Depth of field for colour images with their depth (see `defocus.blur`).
#[pyfunction]
#[pyo3(signature = (color, depth, method, depth_kind, depth_scale, zero_depth_is_far, focus, focus_pixel, fstop, focal_length, sensor_width, aperture, seed, flags, highlights=None, timings=false, device="auto"))]
#[expect(
    clippy::too_many_arguments,
    reason = "the keyword arguments of defocus.blur"
)]
fn blur(
    py: Python<'_>,
    color: &Bound<'_, PyAny>,
    depth: &Bound<'_, PyAny>,
    method: String,
    depth_kind: String,
    depth_scale: f32,
    zero_depth_is_far: bool,
    focus: Option<&Bound<'_, PyAny>>,
    focus_pixel: Option<(usize, usize)>,
    fstop: f32,
    focal_length: f32,
    sensor_width: f32,
    aperture: String,
    seed: u64,
    flags: Vec<String>,
    highlights: Option<String>,
    timings: bool,
    device: &str,
) -> PyResult<Py<PyAny>> {
    let color = ColorArray::of(color, "color")?;
    // Shapes first: nothing is read, copied or converted before they and the memory they need
    // are checked.
    let (layout, color_copy) = ColorBatch::layout(&color, "color")?;
    let highlights = highlights
        .as_deref()
        .map(Highlights::parse)
        .transpose()
        .map_err(py_err)?;
    let depth = depth_array(depth)?;
    let dshape = depth.shape().to_vec();
    let want: Vec<usize> = if layout.batched {
        vec![layout.n, layout.h, layout.w]
    } else {
        vec![layout.h, layout.w]
    };
    if dshape != want {
        return Err(PyValueError::new_err(format!(
            "size mismatch: color is {}x{}{} but depth has shape {dshape:?}: expected {want:?}",
            layout.w,
            layout.h,
            if layout.batched {
                format!(" (batch of {})", layout.n)
            } else {
                String::new()
            }
        )));
    }
    let depth_layout = Layout::of(&dshape, false, "depth")?;
    let depth_copy = gathered_bytes(&depth, &depth_layout);
    let kind = match depth_kind.as_str() {
        "depth" | "view" => DepthKind::View,
        "radial" => DepthKind::Radial,
        "inverse" | "disparity" => DepthKind::Inverse,
        "coc" => DepthKind::Coc,
        other => {
            return Err(PyValueError::new_err(format!(
                "invalid depth_kind '{other}': expected depth, radial, inverse, disparity or coc"
            )))
        }
    };
    let info = registry::find(&method).map_err(py_err)?;
    if !info.input.takes_frame() {
        return Err(PyValueError::new_err(format!(
            "method {method} needs {}, not a colour image with depth: use defocus.render(scene, method='{method}')",
            info.input.describe()
        )));
    }
    // The whole call: the copies of arrays that are not C-contiguous, the output array, and
    // the images in flight (one per worker thread), each its colour and depth as the library
    // holds them (16 + 4 bytes a pixel) and the method's frame.
    let settings = registry::MethodSettings::default_for(&method).map_err(py_err)?;
    let in_flight = layout.n.min(rayon::current_num_threads()) as u64;
    let image_bytes = layout
        .pixels()
        .saturating_mul(20 + registry::peak_bytes_per_pixel(&settings));
    let needed = registry::FIXED_PEAK_BYTES
        .saturating_add(color_copy)
        .saturating_add(depth_copy)
        .saturating_add(
            layout
                .samples()
                .saturating_mul(ColorBatch::sample_bytes(&color)),
        )
        .saturating_add(in_flight.saturating_mul(image_bytes));
    check_memory(
        needed,
        &format!("blur of {} {}x{} image(s)", layout.n, layout.w, layout.h),
    )?;
    let batch = ColorBatch::new(&color, layout);
    let dvalues = samples_of(&depth);
    let params = BlurParams {
        gpu: gpu_for(device, &method)?,
        method,
        kind,
        depth_scale,
        zero_depth_is_far,
        focus: focus_choice(focus, focus_pixel)?,
        spec: LensSpec {
            fstop,
            focal_length_mm: focal_length,
            sensor_width_mm: sensor_width,
        },
        aperture,
        seed,
        post: method_flags(flags)?,
    };
    let per_image = batch.h * batch.w;
    let results: defocus::Result<Vec<(ColorImage, Timings)>> = py.detach(|| {
        (0..batch.n)
            .into_par_iter()
            .map(|i| {
                let one = || {
                    let mut values = recycled::depths().take(per_image);
                    values.extend_from_slice(&dvalues[i * per_image..(i + 1) * per_image]);
                    let mut image = batch.image(i, "color")?;
                    if let Some(h) = &highlights {
                        h.apply(&mut image);
                    }
                    blur_one(image, values, &params)
                };
                one().map_err(|e| match e {
                    e if batch.batched => {
                        defocus::Error::Option(format!("image {i} of the batch: {e}"))
                    }
                    e => e,
                })
            })
            .collect()
    });
    let (images, passes): (Vec<ColorImage>, Vec<Timings>) =
        results.map_err(py_err)?.into_iter().unzip();
    let array = to_numpy(py, &batch, images)?;
    if !timings {
        return Ok(array);
    }
    // Summed over a batch's images, in the order the passes ran.
    let mut total = Timings::default();
    for t in &passes {
        total.extend(t);
    }
    let list = PyList::empty(py);
    let mut method_ms = 0.0;
    for p in &total.passes {
        if p.name == METHOD_WALL {
            method_ms = p.ms;
        } else {
            list.append((p.name.as_str(), p.ms))?;
        }
    }
    let d = PyDict::new(py);
    d.set_item("passes", list)?;
    d.set_item("method_ms", method_ms)?;
    Ok((array, d).into_pyobject(py)?.into_any().unbind())
}

/// Renders a scene (see `defocus.render`): colour `HxWx4` float32 (linear, premultiplied) and,
/// with `with_depth`, view-axis depth `HxW` in metres (inf where nothing was hit).
#[pyfunction]
#[pyo3(signature = (scene, method, width, height, samples, seed, sampler, focus, focus_pixel, fstop, focal_length, sensor_width, aperture, camera, allow_external_files, with_depth, flags, device="auto"))]
#[expect(
    clippy::too_many_arguments,
    reason = "the keyword arguments of defocus.render"
)]
fn render(
    py: Python<'_>,
    scene: String,
    method: String,
    width: Option<usize>,
    height: Option<usize>,
    samples: Option<usize>,
    seed: u64,
    sampler: String,
    focus: Option<&Bound<'_, PyAny>>,
    focus_pixel: Option<(usize, usize)>,
    fstop: Option<f32>,
    focal_length: Option<f32>,
    sensor_width: Option<f32>,
    aperture: Option<String>,
    camera: Option<String>,
    allow_external_files: bool,
    with_depth: bool,
    flags: Vec<String>,
    device: &str,
) -> PyResult<(Py<PyAny>, Option<Py<PyAny>>)> {
    registry::find(&method).map_err(py_err)?;
    let gpu = gpu_for(device, &method)?;
    let focus = match (focus, focus_pixel) {
        (f, p) if f.is_none_or(|f| f.is_none()) && p.is_none() => None,
        (f, p) => Some(focus_choice(f, p)?),
    };
    let post = method_flags(flags)?;
    let sampler = SamplerKind::parse(&sampler).map_err(py_err)?;
    let options = load::LoadOptions {
        allow_external_files,
    };
    let result = py.detach(|| -> defocus::Result<_> {
        let file = load::scene_by_name_or_path(&scene, camera.as_deref(), &options)?;
        let scene = file.scene;
        let defaults = scene.defaults.clone().ok_or_else(|| {
            defocus::Error::Option(format!("scene '{}' has no camera", scene.name))
        })?;
        let mut cam = defaults.camera;
        if let Some(w) = width {
            cam.width_px = w;
        }
        if let Some(h) = height {
            cam.height_px = h;
        }
        if let Some(n) = fstop {
            cam.fstop = n;
        }
        if let Some(f) = focal_length {
            cam.focal_length_mm = f;
        }
        if let Some(s) = sensor_width {
            cam.sensor_width_mm = s;
        }
        match focus {
            Some(FocusChoice::Metres(m)) => cam.focus_m = m,
            Some(FocusChoice::Auto) | Some(FocusChoice::Pixel(..)) => {
                let (x, y) = match focus {
                    Some(FocusChoice::Pixel(x, y)) => (x, y),
                    _ => (cam.width_px / 2, cam.height_px / 2),
                };
                let pick =
                    defocus::autofocus::focus_at_pixel(&scene, &cam, x, y)?.ok_or_else(|| {
                        defocus::Error::Option(format!(
                            "focus: no surface near pixel ({x}, {y}) to focus on"
                        ))
                    })?;
                cam.focus_m = pick.depth_m;
            }
            None => {}
        }
        let lens = cam.thin_lens()?;
        let aperture = match &aperture {
            Some(spec) => parse_aperture(spec)?,
            None => defaults.aperture,
        };
        let settings = post
            .settings(&method, &aperture, seed, cam.height_px, Some(&lens))?
            .with_run(samples, sampler, seed, &aperture)?;
        let options = SceneOptions {
            frame_samples: samples.unwrap_or(DEFAULT_FRAME_SAMPLES),
            seed,
            with_depth,
            occlusion: post.occlusion,
        };
        if gpu.is_some() && post.occlusion == Occlusion::Fill {
            return Err(defocus::Error::Option(
                "occlusion='fill' runs on the CPU only so far: use device='cpu', or occlusion='none'"
                    .to_string(),
            ));
        }
        registry::run_scene_on(&settings, &scene, &cam, &options, gpu.as_deref(), &mut |_, _| {})
    });
    let out = result.map_err(py_err)?;
    let (w, h) = (out.image.width(), out.image.height());
    let data: Vec<f32> = out.image.pixels().iter().flat_map(|p| *p).collect();
    let color = ArrayD::from_shape_vec(IxDyn(&[h, w, 4]), data)
        .map_err(|e| PyValueError::new_err(e.to_string()))?
        .into_pyarray(py)
        .into_any()
        .unbind();
    let depth = match out.depth {
        Some(d) => Some(
            ArrayD::from_shape_vec(IxDyn(&[h, w]), d.into_vec())
                .map_err(|e| PyValueError::new_err(e.to_string()))?
                .into_pyarray(py)
                .into_any()
                .unbind(),
        ),
        None => None,
    };
    Ok((color, depth))
}

/// The report's flags alone, parsed from the keyword arguments turned into flags.
#[derive(Parser)]
#[command(name = "defocus compare", no_binary_name = true)]
struct ReportFlags {
    #[command(flatten)]
    args: CompareArgs,
}

/// An error of a job as the Python exception it is: a file that could not be read or written
/// is `OSError`, the rest `ValueError`; the message is the command line's.
fn job_err(e: anyhow::Error) -> PyErr {
    let text: Vec<String> = e.chain().map(|c| c.to_string()).collect();
    let text = defocus::error::shown(&text.join(": "));
    let is_io = e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>().is_some()
            || matches!(
                c.downcast_ref::<defocus::Error>(),
                Some(defocus::Error::Io { .. })
            )
    });
    if is_io {
        PyOSError::new_err(text)
    } else {
        PyValueError::new_err(text)
    }
}

/// Writes the comparison report (see `defocus.report`), the GIL released: the path of its
/// `index.html`, the text of its `results.json` and the labels of the runs that failed.
#[pyfunction]
fn report(py: Python<'_>, flags: Vec<String>) -> PyResult<(String, String, Vec<String>)> {
    let args = ReportFlags::try_parse_from(flags)
        .map(|f| f.args)
        .map_err(|e| flag_error("report", &e))?;
    let written = py
        .detach(|| defocus::jobs::report::write(&args, &mut |_| {}, &mut |_| {}))
        .map_err(job_err)?;
    Ok((
        written.index_html.to_string_lossy().into_owned(),
        written.results.to_string(),
        written.failed,
    ))
}

/// `blur`'s flags alone, parsed from the keyword arguments turned into flags.
#[derive(Parser)]
#[command(name = "defocus blur", no_binary_name = true)]
struct BlurFlags {
    #[command(flatten)]
    args: BlurArgs,
}

/// Blurs a sequence of frame files (see `defocus.blur_sequence`): the frames written and kept,
/// the first failed frames (each with its error), how many failed in all, and the frames per
/// second.
#[pyfunction]
#[expect(
    clippy::type_complexity,
    reason = "the tuple defocus.blur_sequence unpacks"
)]
fn blur_sequence(
    py: Python<'_>,
    flags: Vec<String>,
) -> PyResult<(Vec<i64>, Vec<i64>, Vec<(i64, String)>, usize, f64)> {
    let args = BlurFlags::try_parse_from(flags)
        .map(|f| f.args)
        .map_err(|e| flag_error("blur", &e))?;
    let done = py
        .detach(|| {
            if !defocus::jobs::sequence::is_blur_sequence(&args)? {
                anyhow::bail!(
                    "color {}: expected a frame pattern such as shot.####.exr or shot.%04d.exr",
                    defocus::error::shown(&args.color)
                );
            }
            defocus::jobs::sequence::blur(&args, &Events::none())
        })
        .map_err(job_err)?;
    let failed = done
        .failed
        .iter()
        .map(|(n, e)| {
            let text: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            (*n, defocus::error::shown(&text.join(": ")))
        })
        .collect();
    let fps = done.frames_per_second();
    Ok((done.written, done.kept, failed, done.failed_count, fps))
}

/// MSE (linear), PSNR (dB, sRGB) and SSIM of `a` against `b` (see `defocus.compare`).
#[pyfunction]
fn compare<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let (a, b) = (ColorArray::of(a, "a")?, ColorArray::of(b, "b")?);
    let (la, copy_a) = ColorBatch::layout(&a, "a")?;
    let (lb, copy_b) = ColorBatch::layout(&b, "b")?;
    if la.batched || lb.batched {
        return Err(PyValueError::new_err(
            "compare takes two images, not batches",
        ));
    }
    // The copies of arrays that are not C-contiguous and the two images as the library holds
    // them (16 bytes a pixel); the comparison checks its own memory.
    check_memory(
        copy_a
            .saturating_add(copy_b)
            .saturating_add((la.pixels() + lb.pixels()).saturating_mul(16)),
        &format!(
            "comparing a {}x{} and a {}x{} image",
            la.w, la.h, lb.w, lb.h
        ),
    )?;
    let (a, b) = (ColorBatch::new(&a, la), ColorBatch::new(&b, lb));
    let (ia, ib) = (
        a.image(0, "a").map_err(py_err)?,
        b.image(0, "b").map_err(py_err)?,
    );
    if !ia.same_size(&ib) {
        return Err(PyValueError::new_err(format!(
            "size mismatch: a is {}x{} but b is {}x{}",
            ia.width(),
            ia.height(),
            ib.width(),
            ib.height()
        )));
    }
    let m = py
        .detach(|| defocus::metrics::compare(&ia, &ib))
        .map_err(py_err)?;
    let d = PyDict::new(py);
    d.set_item("mse", m.mse_linear)?;
    d.set_item("psnr", m.psnr_db)?;
    d.set_item("ssim", m.ssim)?;
    Ok(d)
}

/// The registry: every method with its description, paper, input and options (the command
/// line's method flags, with the methods each applies to, its help and default).
#[pyfunction]
fn methods(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
    let command = MethodFlags::command();
    let ids: Vec<&str> = METHODS.iter().map(|m| m.id).collect();
    let mut options = Vec::new();
    for arg in command.get_arguments() {
        let Some(long) = arg.get_long() else { continue };
        if long == "help" {
            continue;
        }
        let help = arg.get_help().map(|h| h.to_string()).unwrap_or_default();
        // A flag's help starts with the methods it applies to ("hammon: ...", "multilayer,
        // splat --layers N, multiview: ..."); a flag whose first sentence names none applies
        // to the methods it names anywhere.
        let heading = arg.get_help_heading().unwrap_or_default();
        let head = format!("{heading}, {}", help.split(':').next().unwrap_or(""));
        let named = |text: &str| -> Vec<String> {
            ids.iter()
                .filter(|id| {
                    text.split(|c: char| !c.is_alphanumeric())
                        .any(|w| w == **id)
                })
                .map(|id| id.to_string())
                .collect()
        };
        let mut applies = named(&head);
        if applies.is_empty() {
            applies = named(help.split(". ").next().unwrap_or(""));
        }
        let default: Vec<String> = arg
            .get_default_values()
            .iter()
            .map(|v| v.to_string_lossy().into_owned())
            .collect();
        let takes_value = arg.get_action().takes_values();
        options.push((
            long.replace('-', "_"),
            long.to_string(),
            help,
            default,
            applies,
            takes_value,
        ));
    }
    let list = PyList::empty(py);
    for m in METHODS {
        let d = PyDict::new(py);
        d.set_item("id", m.id)?;
        d.set_item("description", m.description)?;
        d.set_item("paper", m.paper)?;
        d.set_item("input", m.input.describe())?;
        d.set_item("needs_scene", !m.input.takes_frame())?;
        d.set_item("effects", m.effects.to_vec())?;
        let opts = PyList::empty(py);
        for (name, flag, help, default, applies, takes_value) in &options {
            if !applies.iter().any(|a| a == m.id) {
                continue;
            }
            let o = PyDict::new(py);
            o.set_item("name", name)?;
            o.set_item("flag", format!("--{flag}"))?;
            o.set_item("help", help)?;
            o.set_item("default", default.first())?;
            o.set_item("switch", !takes_value)?;
            opts.append(o)?;
        }
        d.set_item("options", opts)?;
        list.append(d)?;
    }
    Ok(list)
}

/// The names of the built-in scenes.
#[pyfunction]
fn scenes() -> Vec<&'static str> {
    defocus::scene::builtin::NAMES.to_vec()
}

/// The native module.
#[pymodule]
fn _defocus(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(blur, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(report, m)?)?;
    m.add_function(wrap_pyfunction!(blur_sequence, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(scenes, m)?)?;
    m.add_function(wrap_pyfunction!(check_array, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
