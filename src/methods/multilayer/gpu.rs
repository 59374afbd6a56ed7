//! `multilayer` on the GPU: the paper's method (Selgrad et al. sections 4 to 6.1) as GPU
//! passes, timed under the CPU's names.
//!
//! - `multilayer/collect`: the fragment lists of the pinhole view over the frame and its
//!   guard band, drawn by the GPU's own rasteriser in one pass into per-pixel linked lists,
//!   then the N nearest of each pixel kept in depth order ([`crate::raster::gpu::fragment_lists`]).
//! - `multilayer/filter`: the Y-map, one compute dispatch a step (`multilayer.wgsl`, `step`),
//!   merging as the CPU's [`super::filter::merge4`], with truncation.
//! - `multilayer/accumulate`: the paper's box levels, per pixel (`accumulate`), as the CPU's
//!   [`super::accumulate::accumulate_box`].
//!
//! What runs on the GPU is the paper's configuration: fragments sampled at pixel centres
//! (`--no-coverage`), the box bokeh (`--ml-bokeh box`), bright fragments filtered as every
//! other (`--highlight-rays off`), with `--ml-supersample` as on the CPU (the lists collected
//! at K x K times the resolution and merged down first). The CPU's defaults beyond the paper
//! (coverage masks, the aperture's shape, highlights ray by ray) are refused by name on the
//! GPU. The filtered levels hold at most [`LEVEL_CAP`] fragments a cell (the CPU 64) and a
//! pixel's accumulation at most [`MAX_ENTRIES`] weighted fragments, the farthest dropped.

use bytemuck::{Pod, Zeroable};

use super::filter::{y_map, Step};
use super::{Bokeh, Borders, MultilayerSettings, REACH_RADII, REACH_SLACK_PX};
use crate::gpu::{GpuContext, PassTimer};
use crate::image::{ColorImage, GrayImage};
use crate::lens::Camera;
use crate::methods::MethodOutput;
use crate::raster::{gpu::fragment_lists, PreparedScene, Reach};
use crate::scene::Scene;
use crate::timing::Timings;
use crate::{Error, Result};

/// The WGSL source of the passes.
pub const SHADER: &str = concat!(
    include_str!("multilayer.wgsl"),
    include_str!("../../gpu/half.wgsl")
);

/// The name the shader is compiled under.
pub const SHADER_NAME: &str = "multilayer.wgsl";

/// Fragments a cell of a filtered level holds on the GPU (the shader's `LEVEL_CAP`).
pub const LEVEL_CAP: usize = 16;

/// Weighted fragments a pixel's accumulation holds on the GPU (the shader's `MAX_ENTRIES`).
pub const MAX_ENTRIES: usize = 32;

/// Invocations of a workgroup along x.
const WORKGROUP_X: u32 = 64;

/// The shader's `LevelInfo`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct LevelInfo {
    dims: [u32; 4],
    place: [f32; 4],
    gates: [f32; 4],
}

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    levels: [u32; 4],
    consts: [f32; 4],
    lens: [f32; 4],
    region: [u32; 4],
}

/// Refuses on the GPU what `settings` ask that runs on the CPU only, naming the flag.
pub fn check(settings: &MultilayerSettings) -> Result<()> {
    let refuse = |what: &str, flag: &str| {
        Err(Error::invalid(
            "device",
            format!(
                "multilayer on the GPU runs the paper's configuration so far, without {what}: \
                 add {flag}, or use --device cpu"
            ),
        ))
    };
    if settings.input.coverage {
        return refuse("coverage masks", "--no-coverage");
    }
    if settings.bokeh != Bokeh::Box {
        return refuse(
            &format!("the bokeh of --ml-bokeh {}", settings.bokeh.name()),
            "--ml-bokeh box",
        );
    }
    if settings.highlights.is_some() {
        return refuse("highlights ray by ray", "--highlight-rays off");
    }
    Ok(())
}

/// Renders `scene` through `camera` with multi-layer filtering on the GPU of `ctx`: the GPU
/// twin of [`super::render`] for the settings [`check`] accepts.
pub fn render(
    ctx: &GpuContext,
    scene: &Scene,
    camera: &Camera,
    settings: &MultilayerSettings,
) -> Result<MethodOutput> {
    settings.validate()?;
    check(settings)?;
    let frame = camera.thin_lens()?;
    let held = crate::methods::registry::scene_peak_bytes(scene)?;
    super::check_memory(&frame, settings, held)?;
    let mut timings = Timings::default();
    let prepared = timings.time(super::pass::PREPARE, || {
        PreparedScene::new(scene, &camera.camera_from_world)
    })?;
    let guard = settings.input.guard_band_px(&prepared, &frame);
    let lens = frame.with_guard_band(guard);
    super::check_memory(&lens, settings, held)?;
    // With supersampling the lists are collected at K x K times the resolution (the guard band
    // and the reach with them), as on the CPU.
    let k = settings.supersample;
    let fine = crate::lens::ThinLens {
        width_px: lens.width_px * k,
        height_px: lens.height_px * k,
        f_px: lens.f_px * k as f32,
        ..lens
    };
    let reach = (guard > 0).then_some(Reach {
        frame: (
            guard * k,
            guard * k,
            frame.width_px * k,
            frame.height_px * k,
        ),
        lens: fine,
        factor: REACH_RADII,
        slack_px: REACH_SLACK_PX * k as f32,
        square: false,
    });
    let lists = fragment_lists(
        ctx,
        &prepared,
        fine,
        settings.fragments,
        reach.as_ref(),
        super::pass::COLLECT,
        &mut timings,
    )?;
    let result = filter_and_accumulate(ctx, &lists, &lens, guard, &frame, settings, &mut timings);
    lists.recycle(ctx);
    let (image, depth, bytes) = result?;
    Ok(MethodOutput {
        image,
        depth: Some(depth),
        timings,
        memory_bytes: Some(bytes),
    })
}

/// The levels' layout: per level its table entry; and the cells of all levels.
fn layout(
    lists: &crate::raster::gpu::GpuLists,
    borders: &Borders,
    pre: usize,
    steps: &[Step],
) -> (Vec<LevelInfo>, u64) {
    // Gates of the levels accumulated, by their index from the base.
    let gates = super::accumulate::gates(borders, steps.len() + 1 - pre);
    let gate = |s: usize| -> [f32; 4] {
        let (i0, i1, o0, o1) = gates[s];
        [i0, i1, o0, o1]
    };
    let (mut w, mut h) = (lists.width, lists.height);
    let (mut stride, mut origin) = (1.0f32, 0.5f32);
    let mut cells = 0u64;
    let mut table = Vec::with_capacity(steps.len() + 1);
    let mut push = |w: usize, h: usize, cap: usize, stride: f32, origin: f32, s: usize| {
        table.push(LevelInfo {
            dims: [w as u32, h as u32, cap as u32, cells as u32],
            place: [stride, origin, 0.0, 0.0],
            gates: gate(s),
        });
        cells += (w * h) as u64;
    };
    push(w, h, lists.cap, stride, origin, 0);
    for (i, st) in steps.iter().enumerate() {
        if i + 1 == pre {
            // The supersampled lists merged down to the output resolution: from here on cells
            // are output pixels (as the CPU's `filter_with`).
            (stride, origin) = (1.0, 0.5);
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            push(nw, nh, LEVEL_CAP, stride, origin, 0);
            (w, h) = (nw, nh);
            continue;
        }
        match *st {
            Step::Mip => {
                w = w.div_ceil(2);
                h = h.div_ceil(2);
                origin += 0.5 * stride;
                stride *= 2.0;
            }
            Step::Stack { offset } => {
                if offset == 1 {
                    origin += 0.5 * stride;
                }
            }
        }
        push(w, h, LEVEL_CAP, stride, origin, (i + 1).saturating_sub(pre));
    }
    (table, cells)
}

/// Key under which a context remembers the slots a filtered cell the last frame's levels took
/// (in sixteenths), so that the next frame of a sequence or batch filters once.
const POOL_HINT: &str = "multilayer level pool";

/// Passes `filter` and `accumulate` of `lists` (over the frame of `lens`, the frame `frame`
/// within it `guard` pixels from each side): the image, the pinhole depth and the GPU bytes
/// the levels took.
fn filter_and_accumulate(
    ctx: &GpuContext,
    lists: &crate::raster::gpu::GpuLists,
    lens: &crate::lens::ThinLens,
    guard: usize,
    frame: &crate::lens::ThinLens,
    settings: &MultilayerSettings,
    timings: &mut Timings,
) -> Result<Filtered> {
    let borders = Borders::new(*lens);
    // Supersampled lists are first merged down to the output resolution by `pre` mip steps
    // that keep every fragment; their CoCs are K times the output's.
    let k = settings.supersample;
    let pre = k.trailing_zeros() as usize;
    let (mip, stack) = super::steps_for(settings, lists.widest_px / k as f32);
    let mut steps = vec![Step::Mip; pre];
    steps.extend(y_map(mip, stack));
    let (table, cells) = layout(lists, &borders, pre, &steps);
    let base_slots = (lists.width * lists.height * lists.cap) as u64;
    let filtered_cells = cells - (lists.width * lists.height) as u64;
    // Slots a filtered cell the last frame's levels took, in sixteenths (at least two slots).
    let hint = ctx.cached(POOL_HINT, || Ok(std::sync::atomic::AtomicU64::new(32)))?;
    let per_cell = hint.load(std::sync::atomic::Ordering::Relaxed).max(32);
    // Within what one binding may hold (8 bytes a slot's colour); a frame that needs more is
    // refused by the plan, naming the limit.
    let limits = &ctx.description().limits;
    let most = (limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
        / 8)
    .saturating_sub(base_slots)
    .max(1);
    let mut pool = (filtered_cells * per_cell).div_ceil(16).min(most).max(1);
    loop {
        let (out, taken) = levels_with(
            ctx,
            lists,
            (&table, cells, &steps, pre),
            (base_slots, pool),
            (guard, frame),
            settings,
            lens,
            timings,
        )?;
        if let Some(out) = out {
            let per_cell = (16 * pool).div_ceil(filtered_cells.max(1));
            hint.store(per_cell, std::sync::atomic::Ordering::Relaxed);
            return Ok(out);
        }
        // An eighth more, so that the next frames of a sequence fit.
        let wanted = taken.saturating_sub(base_slots);
        pool = wanted + wanted / 8;
    }
}

/// One try of [`filter_and_accumulate`] with a pool of `pool` slots for the filtered levels
/// beside level 0's `base_slots`: the image, the depth and the bytes of the levels (`None`
/// where the pool was too small), and the slots the frame took.
#[allow(clippy::too_many_arguments)]
fn levels_with(
    ctx: &GpuContext,
    lists: &crate::raster::gpu::GpuLists,
    (table, cells, steps, pre): (&[LevelInfo], u64, &[Step], usize),
    (base_slots, pool): (u64, u64),
    (guard, frame): (usize, &crate::lens::ThinLens),
    settings: &MultilayerSettings,
    lens: &crate::lens::ThinLens,
    timings: &mut Timings,
) -> Result<(Option<Filtered>, u64)> {
    let (w, h) = (frame.width_px, frame.height_px);
    let pixels = (w * h) as u64;
    let what = format!(
        "multilayer's levels at {}x{}",
        lens.width_px, lens.height_px
    );
    let slots = base_slots + pool;
    if slots > u64::from(u32::MAX) {
        return Err(Error::Gpu(format!(
            "{what}: {slots} slots; the levels address at most 2^32 (lower the resolution)"
        )));
    }
    let level_bytes = cells * 8 + slots * 12;
    ctx.plan(&what, (slots * 8).max(cells * 8), level_bytes + pixels * 40)?;
    let start = std::time::Instant::now();
    let table_buf = ctx.upload("level table", bytemuck::cast_slice(table))?;
    let spans = ctx.storage("level spans", cells * 8)?;
    let depth = ctx.storage("level depths", slots * 4)?;
    let color = ctx.storage("level colours", slots * 8)?;
    let out_color = ctx.storage("multilayer colour", pixels * 16)?;
    let out_depth = ctx.storage("multilayer depth", pixels * 4)?;
    let status = ctx.upload(
        "multilayer status",
        bytemuck::cast_slice(&[base_slots as u32, slots as u32]),
    )?;
    let mut encoder = ctx.device().create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(&lists.depth, 0, &depth, 0, base_slots * 4);
    encoder.copy_buffer_to_buffer(&lists.color, 0, &color, 0, base_slots * 8);
    ctx.queue().submit([encoder.finish()]);
    let lens_consts = |levels: [u32; 4], s: f32, truncate: bool| Params {
        levels,
        consts: [
            settings.epsilon,
            f32::from(u8::from(truncate)),
            s,
            lens.f_px * lens.lens_radius_m,
        ],
        lens: [lens.focus_m, table.len() as f32, 0.0, 0.0],
        region: [guard as u32, guard as u32, w as u32, h as u32],
    };
    let [spans_pipeline, step_pipeline, accumulate_pipeline]: [wgpu::ComputePipeline; 3] = ctx
        .pipelines(SHADER_NAME, SHADER, &ENTRIES)?
        .try_into()
        .map_err(|_| Error::Gpu("multilayer's pipelines".into()))?;
    let mut uniforms = Vec::new();
    let mut passes = Vec::new();
    let g = ctx.row_groups(&what, lists.width, lists.height, WORKGROUP_X)?;
    passes.push((
        &spans_pipeline,
        ctx.bind(
            &spans_pipeline,
            &[(1, &table_buf), (2, &spans), (7, &lists.count)],
        ),
        g,
    ));
    for (i, st) in steps.iter().enumerate() {
        let (kind, d) = match *st {
            Step::Mip => (0, 1),
            Step::Stack { offset } => (1, offset as u32),
        };
        // The merges down from the supersampled lists keep every fragment.
        let params = lens_consts(
            [i as u32, i as u32 + 1, kind, d],
            (i + 1).saturating_sub(pre) as f32,
            settings.truncation && i >= pre,
        );
        let u = ctx.uniform("multilayer step", bytemuck::bytes_of(&params));
        let dims = table[i + 1].dims;
        let g = ctx.row_groups(&what, dims[0] as usize, dims[1] as usize, WORKGROUP_X)?;
        passes.push((
            &step_pipeline,
            ctx.bind(
                &step_pipeline,
                &[
                    (0, &u),
                    (1, &table_buf),
                    (2, &spans),
                    (3, &depth),
                    (4, &color),
                    (8, &status),
                ],
            ),
            g,
        ));
        uniforms.push(u);
    }
    let params = lens_consts([pre as u32, 0, 0, 0], 0.0, false);
    let u = ctx.uniform("multilayer accumulate", bytemuck::bytes_of(&params));
    let accumulate_group = ctx.bind(
        &accumulate_pipeline,
        &[
            (0, &u),
            (1, &table_buf),
            (2, &spans),
            (3, &depth),
            (4, &color),
            (5, &out_color),
            (6, &out_depth),
        ],
    );
    uniforms.push(u);
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);
    let mut timer = PassTimer::new(ctx, passes.len() as u32 + 1);
    for (pipeline, group, g) in &passes {
        timer.dispatch(super::pass::FILTER, pipeline, group, *g)?;
    }
    let g = ctx.row_groups(&what, w, h, WORKGROUP_X)?;
    timer.dispatch(
        super::pass::ACCUMULATE,
        &accumulate_pipeline,
        &accumulate_group,
        g,
    )?;
    let filter_timings = timer.finish()?;
    let start = std::time::Instant::now();
    let read = ctx.read(&[
        (&status, 4),
        (&out_color, pixels * 16),
        (&out_depth, pixels * 4),
    ])?;
    let taken = u64::from(u32::from_le_bytes(
        read[0][..4].try_into().unwrap_or([0; 4]),
    ));
    ctx.recycle(uniforms);
    ctx.recycle([table_buf, spans, depth, color, out_color, out_depth, status]);
    if taken > slots {
        return Ok((None, taken));
    }
    timings.extend(&filter_timings);
    timings.add("gpu/download", start.elapsed().as_secs_f64() * 1e3);
    let image = ColorImage::from_vec(w, h, bytemuck::pod_collect_to_vec(&read[1]))?;
    let depth_image = GrayImage::from_vec(w, h, bytemuck::pod_collect_to_vec(&read[2]))?;
    let bytes = (cells * 8 + taken * 12) as usize;
    Ok((Some((image, depth_image, bytes)), taken))
}

/// What the filter and accumulation give: the image, the pinhole depth, the bytes of the
/// levels.
type Filtered = (ColorImage, GrayImage, usize);

/// The entry points of `multilayer.wgsl`, in the order they run.
const ENTRIES: [&str; 3] = [
    "multilayer/spans",
    "multilayer/step",
    "multilayer/accumulate",
];

/// Builds the pipelines on `ctx` (compiled once, then cached in it).
pub fn prepare(ctx: &GpuContext) -> Result<()> {
    ctx.pipelines(SHADER_NAME, SHADER, &ENTRIES).map(|_| ())
}
