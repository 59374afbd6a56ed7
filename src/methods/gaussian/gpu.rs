//! `gaussian` on the GPU: the passes of [`super`] (`coc`, `horizontal`, `vertical`, timed as
//! `gaussian/<pass>`) as the entry points of one WGSL compute shader, `gaussian.wgsl`, which
//! computes what the CPU passes compute, in f32, summing in the same order. The CPU passes are
//! its oracle (tested within 45 dB PSNR on every built-in scene).
//!
//! The tap table is the CPU's [`GaussTable`], tabulated up to `max_coc_px` instead of the
//! frame's largest radius (the same taps: a level's taps do not depend on how many levels
//! there are, and no radius of the frame reaches past its own largest level), so the GPU needs
//! no read-back between passes. A depth that is not > 0 is recorded by the `coc` pass and
//! reported with the CPU's message once the run is done.
//!
//! Besides the method's passes, `gpu/upload` (colour, depth and table to the GPU) and
//! `gpu/download` (the image back) are timed by the wall clock.

use bytemuck::{Pod, Zeroable};

use super::{GaussTable, GaussianSettings};
use crate::gpu::{GpuContext, PassTimer, NO_FAILURE};
use crate::image::{ColorImage, GrayImage};
use crate::lens::ThinLens;
use crate::methods::coc_map;
use crate::methods::MethodOutput;
use crate::timing::Timings;
use crate::Result;

/// The WGSL source of the passes.
pub const SHADER: &str = concat!(
    include_str!("../../gpu/common.wgsl"),
    include_str!("gaussian.wgsl")
);

/// The name the shader is compiled under.
pub const SHADER_NAME: &str = "gaussian.wgsl";

/// The passes, in order: each is an entry point of [`SHADER`] named after the part after `/`.
pub const PASSES: [&str; 3] = ["gaussian/coc", "gaussian/horizontal", "gaussian/vertical"];

/// Invocations of a workgroup along x (the shader's `@workgroup_size`).
const WORKGROUP_X: u32 = 64;

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    width: u32,
    height: u32,
    stride: u32,
    levels: u32,
    f_times_e: f32,
    focus_m: f32,
    max_coc_px: f32,
    pad: f32,
}

/// Builds every pipeline of the method on `ctx` (compiled once, then cached in it).
pub fn prepare(ctx: &GpuContext) -> Result<()> {
    ctx.pipelines(SHADER_NAME, SHADER, &PASSES).map(|_| ())
}

/// Renders depth of field from a pinhole colour image and its view-axis depth in metres, on
/// the GPU of `ctx`: the GPU twin of [`super::render`].
pub fn render(
    ctx: &GpuContext,
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &GaussianSettings,
) -> Result<MethodOutput> {
    settings.validate()?;
    coc_map::check_frame(color, depth, lens)?;
    let (w, h) = (color.width(), color.height());
    let pixels = (w * h) as u64;
    let what = format!("gaussian at {w}x{h}");
    // Depth, CoC, colour, rows, the output and its read-back copy.
    ctx.plan(&what, pixels * 16, pixels * (4 + 4 + 16 + 16 + 16 + 16))?;
    let groups = ctx.row_groups(&what, w, h, WORKGROUP_X)?;
    let pipelines = ctx.pipelines(SHADER_NAME, SHADER, &PASSES)?;

    let mut timings = Timings::default();
    let table = GaussTable::new(settings, settings.max_coc_px);
    let start = std::time::Instant::now();
    let params = Params {
        width: w as u32,
        height: h as u32,
        stride: table.stride as u32,
        levels: table.levels as u32,
        f_times_e: lens.f_px * lens.lens_radius_m,
        focus_m: lens.focus_m,
        max_coc_px: settings.max_coc_px,
        pad: 0.0,
    };
    let half: Vec<u32> = table.half.iter().map(|&n| n as u32).collect();
    let params_buf = ctx.uniform("gaussian params", bytemuck::bytes_of(&params));
    let depth_buf = ctx.upload("depth", bytemuck::cast_slice(depth.pixels()))?;
    let color_buf = ctx.upload("colour", bytemuck::cast_slice(color.pixels()))?;
    let half_buf = ctx.upload("gaussian half widths", bytemuck::cast_slice(&half))?;
    let weights_buf = ctx.upload("gaussian weights", bytemuck::cast_slice(&table.weights))?;
    let status_buf = ctx.upload("status", bytemuck::bytes_of(&NO_FAILURE))?;
    let coc_buf = ctx.storage("CoC", pixels * 4)?;
    let rows_buf = ctx.storage("rows", pixels * 16)?;
    let out_buf = ctx.storage("gaussian output", pixels * 16)?;
    ctx.flush()?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);

    let bind = |pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]| {
        ctx.bind(pipeline, entries)
    };
    let groups_of = [
        bind(
            &pipelines[0],
            &[
                (0, &params_buf),
                (1, &depth_buf),
                (2, &coc_buf),
                (3, &status_buf),
            ],
        ),
        bind(
            &pipelines[1],
            &[
                (0, &params_buf),
                (2, &coc_buf),
                (4, &color_buf),
                (5, &rows_buf),
                (7, &half_buf),
                (8, &weights_buf),
            ],
        ),
        bind(
            &pipelines[2],
            &[
                (0, &params_buf),
                (2, &coc_buf),
                (4, &color_buf),
                (5, &rows_buf),
                (6, &out_buf),
                (7, &half_buf),
                (8, &weights_buf),
            ],
        ),
    ];
    let passes: Vec<_> = (0..PASSES.len())
        .map(|i| (PASSES[i], &pipelines[i], &groups_of[i], groups))
        .collect();
    timings.extend(&PassTimer::run(ctx, &passes)?);

    let start = std::time::Instant::now();
    let image = ctx.read_frame(&status_buf, &out_buf, w, h)?;
    timings.add("gpu/download", start.elapsed().as_secs_f64() * 1e3);
    ctx.recycle([
        params_buf,
        depth_buf,
        color_buf,
        half_buf,
        weights_buf,
        status_buf,
        coc_buf,
        rows_buf,
        out_buf,
    ]);
    let image = image.map_err(|failed| coc_map::gpu_bad_depth(depth, failed, &what))?;
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}
