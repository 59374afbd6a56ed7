//! `hammon` on the GPU: the passes of [`super`] (`downsample`, `blur`, `near_coc`,
//! `composite`, timed as `hammon/<pass>`) as the entry points of one WGSL compute shader,
//! `hammon.wgsl`, computing what the CPU passes compute, in f32. The CPU passes are its oracle
//! (tested within 45 dB PSNR on every built-in scene).
//!
//! - The per-frame constants are the CPU's [`Constants`]: the depth-to-blur curve, the large
//!   Gaussian's weights and the blend's `dofLerpScale` / `dofLerpBias`.
//! - `blur` runs as two dispatches, down the columns then along the rows (the CPU fuses them
//!   per row pair); its time is their sum.
//! - `near_coc` and `composite` follow the listings' form, as [`super::near_coc::naive`] and
//!   [`super::composite::naive`] do; a pixel with `t <= 0` is copied, as on the CPU.
//! - A depth that is not > 0 is recorded by `downsample` and reported with the CPU's message
//!   once the run is done.
//!
//! Besides the method's passes, `gpu/upload` and `gpu/download` are timed by the wall clock.

use bytemuck::{Pod, Zeroable};

use super::{quarter_size, Constants, Curve, HammonSettings};
use crate::gpu::{GpuContext, PassTimer, NO_FAILURE};
use crate::image::{ColorImage, GrayImage};
use crate::lens::ThinLens;
use crate::methods::MethodOutput;
use crate::timing::Timings;
use crate::{Error, Result};

/// The WGSL source of the passes.
pub const SHADER: &str = include_str!("hammon.wgsl");

/// The name the shader is compiled under.
pub const SHADER_NAME: &str = "hammon.wgsl";

/// The pipelines, by entry point (`hammon/<entry>`), in the order they run.
const PIPELINES: [&str; 5] = [
    "hammon/downsample",
    "hammon/blur_vertical",
    "hammon/blur_horizontal",
    "hammon/near_coc",
    "hammon/composite",
];

/// The pass each pipeline is timed under (the CPU's pass names).
pub const PASSES: [&str; 5] = [
    "hammon/downsample",
    "hammon/blur",
    "hammon/blur",
    "hammon/near_coc",
    "hammon/composite",
];

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    width: u32,
    height: u32,
    qw: u32,
    qh: u32,
    mode: u32,
    radius: u32,
    sky_is_inf: u32,
    pad0: u32,
    f_times_e: f32,
    focus_m: f32,
    inv_large_blur_coc_px: f32,
    far_to_near_ratio: f32,
    near_scale: f32,
    near_bias: f32,
    far_scale: f32,
    far_bias: f32,
    sky_depth_m: f32,
    pad: [f32; 3],
    lerp_scale: [f32; 4],
    lerp_bias: [f32; 4],
}

impl Params {
    fn new(k: &Constants) -> Self {
        let (qw, qh) = quarter_size(k.width(), k.height());
        let (lerp_scale, lerp_bias) = k.lerp_distances().scale_bias();
        let mut p = Self {
            width: k.width() as u32,
            height: k.height() as u32,
            qw: qw as u32,
            qh: qh as u32,
            mode: 0,
            radius: (k.kernel().len() / 2) as u32,
            sky_is_inf: u32::from(k.sky_depth_m == f32::INFINITY),
            pad0: 0,
            f_times_e: 0.0,
            focus_m: 1.0,
            inv_large_blur_coc_px: 0.0,
            far_to_near_ratio: k.far_to_near_ratio,
            near_scale: 0.0,
            near_bias: 0.0,
            far_scale: 0.0,
            far_bias: 0.0,
            sky_depth_m: if k.sky_depth_m.is_finite() {
                k.sky_depth_m
            } else {
                0.0
            },
            pad: [0.0; 3],
            lerp_scale,
            lerp_bias,
        };
        match k.curve {
            Curve::Physical {
                lens,
                inv_large_blur_coc_px,
            } => {
                p.f_times_e = lens.f_px * lens.lens_radius_m;
                p.focus_m = lens.focus_m;
                p.inv_large_blur_coc_px = inv_large_blur_coc_px;
            }
            Curve::Artist {
                near_scale,
                near_bias,
                far_scale,
                far_bias,
            } => {
                p.mode = 1;
                (p.near_scale, p.near_bias, p.far_scale, p.far_bias) =
                    (near_scale, near_bias, far_scale, far_bias);
            }
        }
        p
    }
}

/// Builds every pipeline of the method on `ctx` (compiled once, then cached in it).
pub fn prepare(ctx: &GpuContext) -> Result<()> {
    ctx.pipelines(SHADER_NAME, SHADER, &PIPELINES).map(|_| ())
}

/// Renders depth of field from a pinhole colour image and its view-axis depth in metres, on
/// the GPU of `ctx`: the GPU twin of [`super::render`].
pub fn render(
    ctx: &GpuContext,
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &HammonSettings,
) -> Result<MethodOutput> {
    if !color.same_size(depth) {
        return Err(Error::Mismatch(format!(
            "colour image is {}x{} but depth is {}x{}",
            color.width(),
            color.height(),
            depth.width(),
            depth.height()
        )));
    }
    let (w, h) = (color.width(), color.height());
    let k = Constants::new(settings, lens, w, h)?;
    let (qw, qh) = quarter_size(w, h);
    let (pixels, texels) = ((w * h) as u64, (qw * qh) as u64);
    let what = format!("hammon at {w}x{h}");
    // Colour, depth, the output and its read-back copy at full size; four quarter-size
    // colour and CoC pairs.
    ctx.plan(
        &what,
        pixels * 16,
        pixels * (16 + 4 + 16 + 16) + texels * 4 * 20,
    )?;
    let full_groups = ctx.row_groups(&what, w, h, 64)?;
    let quarter_groups = [(qw as u32).div_ceil(64), qh as u32, 1];
    let block_groups = [(qw as u32).div_ceil(8), (qh as u32).div_ceil(8), 1];
    let pipelines = ctx.pipelines(SHADER_NAME, SHADER, &PIPELINES)?;

    let mut timings = Timings::default();
    let start = std::time::Instant::now();
    let params = ctx.uniform("hammon params", bytemuck::bytes_of(&Params::new(&k)));
    let depth_buf = ctx.upload("depth", bytemuck::cast_slice(depth.pixels()))?;
    let color_buf = ctx.upload("colour", bytemuck::cast_slice(color.pixels()))?;
    let kernel_buf = ctx.upload("hammon kernel", bytemuck::cast_slice(k.kernel()))?;
    let status_buf = ctx.upload("status", bytemuck::bytes_of(&NO_FAILURE))?;
    let quarter = |label| ctx.storage(label, texels * 16);
    let quarter_coc = |label| ctx.storage(label, texels * 4);
    let (shrunk_color, shrunk_coc) = (quarter("shrunk")?, quarter_coc("shrunk CoC")?);
    let (tmp_color, tmp_coc) = (quarter("blur columns")?, quarter_coc("blur columns CoC")?);
    let (large_color, large_coc) = (quarter("large")?, quarter_coc("large CoC")?);
    let (medium_color, medium_coc) = (quarter("medium")?, quarter_coc("medium CoC")?);
    let out_buf = ctx.storage("hammon output", pixels * 16)?;
    ctx.flush()?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);

    let bind = |pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]| {
        ctx.bind(pipeline, entries)
    };
    let groups = [
        bind(
            &pipelines[0],
            &[
                (0, &params),
                (1, &depth_buf),
                (2, &color_buf),
                (3, &status_buf),
                (4, &shrunk_color),
                (5, &shrunk_coc),
            ],
        ),
        bind(
            &pipelines[1],
            &[
                (0, &params),
                (4, &shrunk_color),
                (5, &shrunk_coc),
                (6, &tmp_color),
                (7, &tmp_coc),
                (13, &kernel_buf),
            ],
        ),
        bind(
            &pipelines[2],
            &[
                (0, &params),
                (6, &tmp_color),
                (7, &tmp_coc),
                (8, &large_color),
                (9, &large_coc),
                (13, &kernel_buf),
            ],
        ),
        bind(
            &pipelines[3],
            &[
                (0, &params),
                (4, &shrunk_color),
                (5, &shrunk_coc),
                (9, &large_coc),
                (10, &medium_color),
                (11, &medium_coc),
            ],
        ),
        bind(
            &pipelines[4],
            &[
                (0, &params),
                (1, &depth_buf),
                (2, &color_buf),
                (8, &large_color),
                (10, &medium_color),
                (11, &medium_coc),
                (12, &out_buf),
            ],
        ),
    ];
    let workgroups = [
        block_groups,
        quarter_groups,
        quarter_groups,
        quarter_groups,
        full_groups,
    ];
    let passes: Vec<_> = (0..PIPELINES.len())
        .map(|i| (PASSES[i], &pipelines[i], &groups[i], workgroups[i]))
        .collect();
    timings.extend(&PassTimer::run(ctx, &passes)?);

    let start = std::time::Instant::now();
    let image = ctx.read_frame(&status_buf, &out_buf, w, h)?;
    timings.add("gpu/download", start.elapsed().as_secs_f64() * 1e3);
    ctx.recycle([
        params,
        depth_buf,
        color_buf,
        kernel_buf,
        status_buf,
        shrunk_color,
        shrunk_coc,
        tmp_color,
        tmp_coc,
        large_color,
        large_coc,
        medium_color,
        medium_coc,
        out_buf,
    ]);
    let image = image.map_err(|_| super::coc::invalid_depth(depth))?;
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}
