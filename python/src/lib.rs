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

use std::path::Path;

use clap::{CommandFactory, Parser};
use defocus::blur::{frame_lens, DepthKind, FocusChoice, Highlights, LensSpec};
use defocus::image::io::{self, DepthRead, Placement};
use defocus::image::{ColorImage, GrayImage, Rgba};
use defocus::jobs::report::CompareArgs;
use defocus::lens::SamplerKind;
use defocus::methods::registry::{self, Frame, SceneOptions, DEFAULT_FRAME_SAMPLES, METHODS};
use defocus::options::{parse_aperture, PostArgs};
use defocus::scene::load;
use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyReadonlyArrayDyn, PyUntypedArrayMethods};
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
fn py_err(e: defocus::Error) -> PyErr {
    match e {
        defocus::Error::Io { .. } => PyOSError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// Parses the method options (flags built from keyword arguments by the Python layer).
fn method_flags(flags: Vec<String>) -> PyResult<PostArgs> {
    MethodFlags::try_parse_from(flags)
        .map(|f| f.post)
        .map_err(|e| {
            let text = e.to_string();
            let first = text.lines().next().unwrap_or_default();
            PyValueError::new_err(format!(
                "invalid method option: {}",
                first.trim_start_matches("error: ")
            ))
        })
}

/// Pixels of a batch of colour images as they came from NumPy.
enum Samples {
    /// Linear light, premultiplied alpha.
    F32(Vec<f32>),
    /// sRGB-encoded, straight alpha.
    U8(Vec<u8>),
}

/// A batch of colour images: `n` images of `h` x `w` pixels with `c` channels (3 or 4).
struct ColorBatch {
    n: usize,
    h: usize,
    w: usize,
    c: usize,
    /// Whether the array had a batch axis.
    batched: bool,
    samples: Samples,
}

impl ColorBatch {
    /// Reads `array` (`name` in errors): float32 or uint8, `HxWxC` or `NxHxWxC`, C = 3 or 4.
    /// A C-contiguous array is read straight from its buffer.
    fn from_numpy(array: &Bound<'_, PyAny>, name: &str) -> PyResult<Self> {
        let shape_of = |shape: &[usize]| -> PyResult<(usize, usize, usize, usize, bool)> {
            match *shape {
                [h, w, c] if c == 3 || c == 4 => Ok((1, h, w, c, false)),
                [n, h, w, c] if c == 3 || c == 4 => Ok((n, h, w, c, true)),
                _ => Err(PyValueError::new_err(format!(
                    "{name}: shape {shape:?}: expected HxWx3 or HxWx4 (or NxHxWxC for a batch)"
                ))),
            }
        };
        let (shape, samples) = if let Ok(a) = array.extract::<PyReadonlyArrayDyn<'_, f32>>() {
            (a.shape().to_vec(), Samples::F32(samples_of(&a)))
        } else if let Ok(a) = array.extract::<PyReadonlyArrayDyn<'_, u8>>() {
            (a.shape().to_vec(), Samples::U8(samples_of(&a)))
        } else {
            return Err(PyValueError::new_err(format!(
                "{name}: expected a NumPy array of float32 (linear light) or uint8 (sRGB)"
            )));
        };
        let (n, h, w, c, batched) = shape_of(&shape)?;
        Ok(Self {
            n,
            h,
            w,
            c,
            batched,
            samples,
        })
    }

    /// Image `i` as the library's linear premultiplied RGBA.
    fn image(&self, i: usize) -> defocus::Result<ColorImage> {
        let len = self.h * self.w * self.c;
        match &self.samples {
            Samples::F32(s) => {
                let s = &s[i * len..(i + 1) * len];
                let pixels: Vec<Rgba> = s
                    .chunks_exact(self.c)
                    .map(|p| [p[0], p[1], p[2], if self.c == 4 { p[3] } else { 1.0 }])
                    .collect();
                ColorImage::from_vec(self.w, self.h, pixels)
            }
            Samples::U8(s) => {
                io::color_from_srgb8(self.w, self.h, self.c, &s[i * len..(i + 1) * len])
            }
        }
    }
}

/// Output images back in the input's layout: same dtype, channels and batch axis.
fn to_numpy(py: Python<'_>, like: &ColorBatch, images: &[ColorImage]) -> PyResult<Py<PyAny>> {
    let mut shape = vec![like.h, like.w, like.c];
    if like.batched {
        shape.insert(0, images.len());
    }
    let c = like.c;
    let shape = IxDyn(&shape);
    let array = match like.samples {
        Samples::F32(_) => {
            let data: Vec<f32> = images
                .iter()
                .flat_map(|img| img.pixels().iter().flat_map(move |p| p[..c].to_vec()))
                .collect();
            let a = ArrayD::from_shape_vec(shape, data)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            a.into_pyarray(py).into_any().unbind()
        }
        Samples::U8(_) => {
            let data: Vec<u8> = images
                .iter()
                .flat_map(|img| {
                    io::png8_samples(img)
                        .chunks_exact(4)
                        .flat_map(|p| p[..c].to_vec())
                        .collect::<Vec<u8>>()
                })
                .collect();
            let a = ArrayD::from_shape_vec(shape, data)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            a.into_pyarray(py).into_any().unbind()
        }
    };
    Ok(array)
}

/// Depth `HxW`, or `NxHxW` for a batch, as float32 values.
fn depth_batch(array: &Bound<'_, PyAny>) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let a = array
        .extract::<PyReadonlyArrayDyn<'_, f32>>()
        .map_err(|_| {
            PyValueError::new_err(
                "depth: expected a NumPy array of float32 (HxW, or NxHxW for a batch)",
            )
        })?;
    Ok((a.shape().to_vec(), samples_of(&a)))
}

/// An array's samples in C order: straight from its buffer when it is C-contiguous, else
/// gathered element by element.
fn samples_of<T: numpy::Element + Copy>(a: &PyReadonlyArrayDyn<'_, T>) -> Vec<T> {
    match a.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => a.as_array().iter().copied().collect(),
    }
}

/// Everything of a `blur` call but the pixels.
struct BlurParams {
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

/// One frame of `blur`.
fn blur_one(color: ColorImage, values: Vec<f32>, p: &BlurParams) -> defocus::Result<ColorImage> {
    let (w, h) = (color.width(), color.height());
    let source = Path::new("depth array");
    let depth = if p.kind == DepthKind::Coc {
        if let Some(i) = values.iter().position(|v| !(v * p.depth_scale).is_finite()) {
            return Err(defocus::Error::Option(format!(
                "depth (depth_kind coc): the CoC radius at (x {}, y {}) times depth_scale is not finite: expected finite radii in pixels",
                i % w,
                i / w
            )));
        }
        GrayImage::from_vec(w, h, values.iter().map(|v| v * p.depth_scale).collect())?
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
    let aperture = parse_aperture(&p.aperture)?;
    let settings = p
        .post
        .settings(&p.method, &aperture, p.seed, h, Some(&fl.lens))?;
    let out = registry::run_frame(
        &settings,
        &Frame {
            color: &color,
            depth: &fl.depth,
            lens: &fl.lens,
        },
    )?;
    Ok(out.image)
}

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
#[pyo3(signature = (color, depth, method, depth_kind, depth_scale, zero_depth_is_far, focus, focus_pixel, fstop, focal_length, sensor_width, aperture, seed, flags, highlights=None))]
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
) -> PyResult<Py<PyAny>> {
    let batch = ColorBatch::from_numpy(color, "color")?;
    let highlights = highlights
        .as_deref()
        .map(Highlights::parse)
        .transpose()
        .map_err(py_err)?;
    let (dshape, dvalues) = depth_batch(depth)?;
    let want: Vec<usize> = if batch.batched {
        vec![batch.n, batch.h, batch.w]
    } else {
        vec![batch.h, batch.w]
    };
    if dshape != want {
        return Err(PyValueError::new_err(format!(
            "size mismatch: color is {}x{}{} but depth has shape {dshape:?}: expected {want:?}",
            batch.w,
            batch.h,
            if batch.batched {
                format!(" (batch of {})", batch.n)
            } else {
                String::new()
            }
        )));
    }
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
    if info.input.needs_scene() {
        return Err(PyValueError::new_err(format!(
            "method {method} needs {}, not a colour image with depth: use defocus.render(scene, method='{method}')",
            info.input.describe()
        )));
    }
    let params = BlurParams {
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
    let results: defocus::Result<Vec<ColorImage>> = py.detach(|| {
        (0..batch.n)
            .into_par_iter()
            .map(|i| {
                let values = dvalues[i * per_image..(i + 1) * per_image].to_vec();
                let mut image = batch.image(i)?;
                if let Some(h) = &highlights {
                    h.apply(&mut image);
                }
                blur_one(image, values, &params).map_err(|e| match e {
                    e if batch.batched => {
                        defocus::Error::Option(format!("image {i} of the batch: {e}"))
                    }
                    e => e,
                })
            })
            .collect()
    });
    let images = results.map_err(py_err)?;
    to_numpy(py, &batch, &images)
}

/// Renders a scene (see `defocus.render`): colour `HxWx4` float32 (linear, premultiplied) and,
/// with `with_depth`, view-axis depth `HxW` in metres (inf where nothing was hit).
#[pyfunction]
#[pyo3(signature = (scene, method, width, height, samples, seed, sampler, focus, focus_pixel, fstop, focal_length, sensor_width, aperture, camera, allow_external_files, with_depth, flags))]
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
) -> PyResult<(Py<PyAny>, Option<Py<PyAny>>)> {
    registry::find(&method).map_err(py_err)?;
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
        };
        registry::run_scene(&settings, &scene, &cam, &options, &mut |_, _| {})
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
        .map_err(|e| {
            let text = e.to_string();
            let first = text.lines().next().unwrap_or_default();
            PyValueError::new_err(format!(
                "invalid report option: {}",
                first.trim_start_matches("error: ")
            ))
        })?;
    let written = py
        .detach(|| defocus::jobs::report::write(&args, &mut |_| {}, &mut |_| {}))
        .map_err(job_err)?;
    Ok((
        written.index_html.to_string_lossy().into_owned(),
        written.results.to_string(),
        written.failed,
    ))
}

/// MSE (linear), PSNR (dB, sRGB) and SSIM of `a` against `b` (see `defocus.compare`).
#[pyfunction]
fn compare<'py>(
    py: Python<'py>,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let (a, b) = (
        ColorBatch::from_numpy(a, "a")?,
        ColorBatch::from_numpy(b, "b")?,
    );
    if a.batched || b.batched {
        return Err(PyValueError::new_err(
            "compare takes two images, not batches",
        ));
    }
    let (ia, ib) = (a.image(0).map_err(py_err)?, b.image(0).map_err(py_err)?);
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
        d.set_item("needs_scene", m.input.needs_scene())?;
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
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(scenes, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
