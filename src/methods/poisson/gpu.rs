//! `poisson` on the GPU: the passes of [`super`] (`coc`, `gather`, timed as `poisson/<pass>`)
//! as the entry points of one WGSL compute shader, `poisson.wgsl`, computing what the CPU
//! passes compute, in f32, with the CPU's taps ([`Taps::poisson_disc`], squeezed by the
//! anamorphic aspect). The CPU passes are its oracle (tested within 45 dB PSNR on every
//! built-in scene). The cat's eye keeps, per pixel, the taps that pass its view of the barrel,
//! as on the CPU; chromatic aberration is a run per channel through its own lens, as on the CPU.
//!
//! A depth that is not > 0 is recorded by the `coc` pass and reported with the CPU's message
//! once the run is done. Besides the method's passes, `gpu/upload` and `gpu/download` are
//! timed by the wall clock.

use bytemuck::{Pod, Zeroable};

use super::{PoissonSettings, Taps, EFFECTS};
use crate::gpu::{GpuContext, PassTimer, NO_FAILURE};
use crate::image::{ColorImage, GrayImage};
use crate::lens::ThinLens;
use crate::methods::{coc_map, MethodOutput};
use crate::timing::Timings;
use crate::Result;

/// The WGSL source of the passes: the shared functions, the gather, the entry points.
pub const SHADER: &str = concat!(
    include_str!("../../gpu/common.wgsl"),
    include_str!("gather.wgsl"),
    include_str!("poisson.wgsl")
);

/// The name the shader is compiled under.
pub const SHADER_NAME: &str = "poisson.wgsl";

/// The passes, in order: each is an entry point of [`SHADER`] named after the part after `/`.
pub const PASSES: [&str; 2] = ["poisson/coc", "poisson/gather"];

/// Invocations of a workgroup along x (the shader's `@workgroup_size`).
const WORKGROUP_X: u32 = 64;

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    width: u32,
    height: u32,
    tap_count: u32,
    cats_eye: u32,
    f_times_e: f32,
    focus_m: f32,
    max_coc_px: f32,
    barrel_radius: f32,
    centre: [f32; 2],
    shift_per_px: f32,
    pad: f32,
}

/// The taps as the shaders read them: `(x, y, weight, 0)` each.
pub(crate) fn tap_table(taps: &Taps) -> Vec<[f32; 4]> {
    taps.points
        .iter()
        .zip(&taps.weights)
        .map(|(p, &w)| [p.x, p.y, w, 0.0])
        .collect()
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
    settings: &PoissonSettings,
) -> Result<MethodOutput> {
    coc_map::check_frame(color, depth, lens)?;
    let effects = settings.effects;
    effects.check_supported("poisson", EFFECTS)?;
    if effects.is_chromatic() {
        let mono = PoissonSettings {
            effects: effects.without_colour(),
            ..settings.clone()
        };
        return crate::methods::per_channel_lens(&effects, lens, |channel| {
            render(ctx, color, depth, channel, &mono)
        });
    }
    coc_map::check_max_coc(settings.max_coc_px)?;
    let mut taps = Taps::poisson_disc(&settings.aperture, settings.taps, settings.seed, 0.0)?;
    for p in &mut taps.points {
        *p = effects.squeeze(*p);
    }
    let (w, h) = (color.width(), color.height());
    let pixels = (w * h) as u64;
    let what = format!("poisson at {w}x{h}");
    // Depth, CoC, colour, the output and its read-back copy.
    ctx.plan(&what, pixels * 16, pixels * (4 + 4 + 16 + 16 + 16))?;
    let groups = ctx.row_groups(&what, w, h, WORKGROUP_X)?;
    let pipelines = ctx.pipelines(SHADER_NAME, SHADER, &PASSES)?;

    let mut timings = Timings::default();
    let start = std::time::Instant::now();
    let centre = [lens.width_px as f32 * 0.5, lens.height_px as f32 * 0.5];
    let params = Params {
        width: w as u32,
        height: h as u32,
        tap_count: taps.points.len() as u32,
        cats_eye: u32::from(effects.has_cats_eye()),
        f_times_e: lens.f_px * lens.lens_radius_m,
        focus_m: lens.focus_m,
        max_coc_px: settings.max_coc_px,
        barrel_radius: effects.barrel_radius(lens),
        centre,
        shift_per_px: effects.barrel_shift_per_px(lens),
        pad: 0.0,
    };
    let params_buf = ctx.uniform("poisson params", bytemuck::bytes_of(&params));
    let depth_buf = ctx.upload("depth", bytemuck::cast_slice(depth.pixels()))?;
    let color_buf = ctx.upload("colour", bytemuck::cast_slice(color.pixels()))?;
    let taps_buf = ctx.upload("poisson taps", bytemuck::cast_slice(&tap_table(&taps)))?;
    let status_buf = ctx.upload("status", bytemuck::bytes_of(&NO_FAILURE))?;
    let coc_buf = ctx.storage("CoC", pixels * 4)?;
    let out_buf = ctx.storage("poisson output", pixels * 16)?;
    ctx.flush()?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);

    let bind_groups = [
        ctx.bind(
            &pipelines[0],
            &[
                (0, &params_buf),
                (1, &depth_buf),
                (2, &coc_buf),
                (3, &status_buf),
            ],
        ),
        ctx.bind(
            &pipelines[1],
            &[
                (0, &params_buf),
                (2, &coc_buf),
                (4, &color_buf),
                (5, &out_buf),
                (6, &taps_buf),
            ],
        ),
    ];
    let passes: Vec<_> = (0..PASSES.len())
        .map(|i| (PASSES[i], &pipelines[i], &bind_groups[i], groups))
        .collect();
    timings.extend(&PassTimer::run(ctx, &passes)?);

    let start = std::time::Instant::now();
    let image = ctx.read_frame(&status_buf, &out_buf, w, h)?;
    timings.add("gpu/download", start.elapsed().as_secs_f64() * 1e3);
    ctx.recycle([
        params_buf, depth_buf, color_buf, taps_buf, status_buf, coc_buf, out_buf,
    ]);
    let image = image.map_err(|failed| coc_map::gpu_bad_depth(depth, failed, &what))?;
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}
