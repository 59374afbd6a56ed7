//! The views of [`super::views`] drawn by the GPU's own rasteriser: the GPU twin of
//! [`super::accumulate_views_clipped`] and [`super::render_view`], for `pinhole` and
//! `reference` with `--device gpu`.
//!
//! The scene goes up once per frame: its camera-space triangles (from the [`PreparedScene`]
//! the CPU made, opaque and alpha-mask triangles first, blended ones after, each vertex with its
//! material and triangle index), its materials, and every mip level of every texture (the
//! CPU's own levels, in one storage buffer, so that the shader filters them as the CPU does).
//! Each view then runs the passes of `raster.wgsl` (its header says what each does): the
//! hardware rasterises with the view's sheared projection and sub-pixel offset, the depth test
//! keeps the nearest opaque surface, blended fragments in front of it go to per-pixel lists
//! that a compute pass sorts and composites as [`super::GBuffer`] does, and the result is added
//! to a float sum in sample order. A last pass divides by the views (or by the views that
//! reach each pixel through the lens barrel: the cat's eye).
//!
//! The lists hold 4 fragments a pixel at first; a frame whose pixels were handed more is drawn
//! again with as many as the most a pixel was handed, up to 16, and refused beyond (naming the
//! limit) rather than composited wrongly.
//!
//! Timed as the CPU twin's `setup` (the planes), `raster` (the other passes of each view) and
//! `resolve`, with `gpu/upload` and `gpu/download` by the wall clock.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::{PreparedScene, View, ViewPassLabels};
use crate::gpu::{GpuContext, PassTimer};
use crate::image::{ColorImage, GrayImage};
use crate::lens::{LensEffects, LensSample, ThinLens};
use crate::scene::{AlphaMode, FilterMode, Scene, TextureBinding, WrapMode};
use crate::timing::Timings;
use crate::{Error, Result};

/// The WGSL source of the passes.
pub const SHADER: &str = concat!(
    include_str!("raster.wgsl"),
    include_str!("../gpu/half.wgsl")
);

/// The name the shader is compiled under.
pub const SHADER_NAME: &str = "raster.wgsl";

/// Invocations of a compute workgroup along x (the shader's `@workgroup_size`).
const WORKGROUP_X: u32 = 64;

/// Fragments a pixel's list holds at first.
const FIRST_LIST: u32 = 4;

/// Fragments a pixel's list can hold at most (the shader's `MAX_LIST`).
pub const MAX_LIST: u32 = 16;

/// Views recorded into one command buffer before it is submitted (and progress reported).
const VIEWS_PER_SUBMIT: usize = 64;

/// The shader's `View` flags.
const STORE: u32 = 1;
const CLIP: u32 = 2;

/// The shader's `View`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ViewParams {
    a: [f32; 4],
    v: [f32; 4],
    planes: [f32; 4],
    lens: [f32; 4],
    info: [u32; 4],
    extra: [u32; 4],
    coc: [f32; 4],
    frame: [u32; 4],
}

/// Bytes of a [`ViewParams`], the stride of the views' table (a multiple of 16, so that each
/// copies into the uniform at an aligned offset).
const VIEW_BYTES: u64 = std::mem::size_of::<ViewParams>() as u64;

/// A vertex as the shader reads it: camera-space position, texture coordinates, material and
/// triangle index.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Vertex {
    p: [f32; 3],
    uv: [f32; 2],
    ids: [u32; 2],
}

/// The shader's `Slot`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuSlot {
    info: [u32; 4],
    affine: [f32; 4],
    offset_origin: [f32; 4],
    size: [f32; 4],
}

/// The shader's `Material`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuMaterial {
    base: [f32; 4],
    emission: [f32; 4],
    mode: [u32; 4],
    cutoff: [f32; 4],
    base_slot: GpuSlot,
    emissive_slot: GpuSlot,
}

/// The compiled pipelines, cached in the context.
struct Pipelines {
    setup: wgpu::ComputePipeline,
    opaque: wgpu::RenderPipeline,
    blended: wgpu::RenderPipeline,
    composite: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    collect: wgpu::RenderPipeline,
    keep: wgpu::ComputePipeline,
}

/// Formats of the targets: colour, view depth, hardware depth.
const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const DEPTH_M_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
const Z_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Builds the pipelines on `ctx` (compiled once, then cached in it).
pub fn prepare(ctx: &GpuContext) -> Result<()> {
    pipelines(ctx).map(|_| ())
}

fn pipelines(ctx: &GpuContext) -> Result<Arc<Pipelines>> {
    ctx.cached("raster.wgsl pipelines", || build_pipelines(ctx))
}

fn build_pipelines(ctx: &GpuContext) -> Result<Pipelines> {
    let device = ctx.device();
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(SHADER_NAME),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let vertex = wgpu::VertexState {
        module: &module,
        entry_point: Some("project"),
        compilation_options: Default::default(),
        buffers: &[Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2, 2 => Uint32x2],
        })],
    };
    let primitive = wgpu::PrimitiveState {
        topology: wgpu::PrimitiveTopology::TriangleList,
        front_face: wgpu::FrontFace::Ccw,
        // Single-sided materials are culled in the shader, per material.
        cull_mode: None,
        ..Default::default()
    };
    let render = |entry: &str, targets: &[Option<wgpu::ColorTargetState>], write_z: bool| {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(entry),
            layout: None,
            vertex: vertex.clone(),
            primitive,
            depth_stencil: Some(wgpu::DepthStencilState {
                format: Z_FORMAT,
                depth_write_enabled: Some(write_z),
                // Depth is reversed: nearer is greater.
                depth_compare: Some(if write_z {
                    wgpu::CompareFunction::Greater
                } else {
                    wgpu::CompareFunction::Always
                }),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                targets,
            }),
            multiview_mask: None,
            cache: None,
        })
    };
    let opaque = render(
        "opaque",
        &[Some(COLOR_FORMAT.into()), Some(DEPTH_M_FORMAT.into())],
        true,
    );
    let blended = render("blended", &[], false);
    let collect = render("collect", &[], false);
    let compute = |entry: &str| {
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
    };
    let setup = compute("setup");
    let composite = compute("composite");
    let resolve = compute("resolve");
    let keep = compute("keep");
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(Error::Gpu(format!(
            "the pipelines of {SHADER_NAME} did not build on {}: {e}",
            ctx.description().label()
        )));
    }
    Ok(Pipelines {
        setup,
        opaque,
        blended,
        composite,
        resolve,
        collect,
        keep,
    })
}

/// A prepared scene's triangles, materials and textures as the shader reads them.
struct SceneData {
    /// Bytes the run holds on the CPU beside these copies: the scene and its camera-space copy.
    held: u64,
    vertices: Vec<Vertex>,
    /// Vertices of the opaque and alpha-mask triangles (the first ones); the rest are blended.
    opaque_vertices: u32,
    materials: Vec<GpuMaterial>,
    textures: Vec<[u32; 4]>,
    levels: Vec<[u32; 4]>,
    texels: Vec<[f32; 4]>,
}

impl SceneData {
    /// Bytes of the vertices and texels [`SceneData::new`] makes of `prepared`, and whether
    /// it has blended triangles, before they are made.
    fn sizes(prepared: &PreparedScene) -> (u64, u64, bool) {
        let scene = prepared.scene();
        let texels: u64 = scene
            .textures
            .iter()
            .flat_map(|t| t.levels())
            .map(|l| (l.width() * l.height()) as u64)
            .sum();
        let blended = prepared.triangles.iter().any(|t| {
            scene
                .materials
                .get(t.material as usize)
                .is_some_and(|m| m.alpha_mode == AlphaMode::Blend)
        });
        (
            3 * prepared.triangles.len() as u64 * std::mem::size_of::<Vertex>() as u64,
            texels.max(1) * 16,
            blended,
        )
    }

    fn new(prepared: &PreparedScene) -> Result<Self> {
        let scene = prepared.scene();
        let blended = |m: u32| {
            scene
                .materials
                .get(m as usize)
                .is_some_and(|m| m.alpha_mode == AlphaMode::Blend)
        };
        // Opaque and alpha-mask triangles nearest first (by their nearest vertex), so that the
        // depth test rejects the hidden fragments of the ones behind before they are shaded
        // (a meadow of cut-out tufts was 17 times slower drawn in scene order on lavapipe);
        // blended ones after, in scene order (the composite sorts them per pixel).
        let nearest = |t: &super::PreparedTriangle| {
            t.v.iter()
                .map(|&v| -prepared.positions[v as usize].z)
                .fold(f32::INFINITY, f32::min)
        };
        let mut order: Vec<(bool, f32, usize)> = prepared
            .triangles
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let b = blended(t.material);
                (b, if b { 0.0 } else { nearest(t) }, i)
            })
            .collect();
        order.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)).then(a.2.cmp(&b.2)));
        let mut vertices = Vec::with_capacity(3 * prepared.triangles.len());
        {
            for &(_, _, i) in &order {
                let t = &prepared.triangles[i];
                for &v in &t.v {
                    let p = prepared.positions[v as usize];
                    let uv = prepared.uvs[v as usize];
                    vertices.push(Vertex {
                        p: p.to_array(),
                        uv: uv.to_array(),
                        ids: [t.material, i as u32],
                    });
                }
            }
        }
        let opaque_vertices = 3 * prepared
            .triangles
            .iter()
            .filter(|t| !blended(t.material))
            .count() as u32;
        let mut textures = Vec::with_capacity(scene.textures.len().max(1));
        let mut levels = Vec::new();
        let mut texels: Vec<[f32; 4]> = Vec::new();
        for t in &scene.textures {
            textures.push([levels.len() as u32, t.levels().len() as u32, 0, 0]);
            for level in t.levels() {
                let first = u32::try_from(texels.len()).map_err(|_| {
                    Error::Gpu(format!(
                        "scene '{}': its textures have more texels than the GPU rasteriser \
                         addresses (2^32)",
                        crate::error::shown(&scene.name)
                    ))
                })?;
                levels.push([first, level.width() as u32, level.height() as u32, 0]);
                texels.extend_from_slice(level.pixels());
            }
        }
        // Bindings may not be empty.
        if textures.is_empty() {
            textures.push([0, 1, 0, 0]);
            levels.push([0, 1, 1, 0]);
            texels.push([0.0; 4]);
        }
        let mut materials: Vec<GpuMaterial> =
            scene.materials.iter().map(|m| material(scene, m)).collect();
        if materials.is_empty() {
            materials.push(GpuMaterial::zeroed());
        }
        Ok(Self {
            held: held(prepared),
            vertices,
            opaque_vertices,
            materials,
            textures,
            levels,
            texels,
        })
    }

    /// The vertices, materials, textures, texture levels and texels in GPU buffers.
    fn upload(&self, ctx: &GpuContext) -> Result<[wgpu::Buffer; 5]> {
        let vertex_bytes = std::mem::size_of_val(self.vertices.as_slice()) as u64;
        let vertices = ctx.buffer(
            "raster vertices",
            vertex_bytes,
            wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        if vertex_bytes > 0 {
            ctx.queue()
                .write_buffer(&vertices, 0, bytemuck::cast_slice(&self.vertices));
        }
        Ok([
            vertices,
            ctx.upload("materials", bytemuck::cast_slice(&self.materials))?,
            ctx.upload("textures", bytemuck::cast_slice(&self.textures))?,
            ctx.upload("texture levels", bytemuck::cast_slice(&self.levels))?,
            ctx.upload("texels", bytemuck::cast_slice(&self.texels))?,
        ])
    }

    fn has_blended(&self) -> bool {
        (self.opaque_vertices as usize) < self.vertices.len()
    }
}

/// What a run holds on the CPU while it draws `prepared`: the scene and its camera-space copy.
fn held(prepared: &PreparedScene) -> u64 {
    prepared.scene().bytes() + PreparedScene::bytes_for(prepared.scene())
}

fn material(scene: &Scene, m: &crate::scene::Material) -> GpuMaterial {
    let (mode, cutoff) = match m.alpha_mode {
        AlphaMode::Opaque => (0, 0.0),
        AlphaMode::Mask { cutoff } => (1, cutoff),
        AlphaMode::Blend => (2, 0.0),
    };
    let e = m.emissive.map(|e| e * m.emissive_strength);
    GpuMaterial {
        base: m.base_color,
        emission: [e[0], e[1], e[2], 0.0],
        mode: [mode, u32::from(m.double_sided), 0, 0],
        cutoff: [cutoff, 0.0, 0.0, 0.0],
        base_slot: slot(scene, m.base_color_texture.as_ref()),
        emissive_slot: slot(scene, m.emissive_texture.as_ref()),
    }
}

fn slot(scene: &Scene, b: Option<&TextureBinding>) -> GpuSlot {
    let Some(b) = b else {
        return GpuSlot::zeroed();
    };
    let Some(t) = scene.textures.get(b.texture) else {
        return GpuSlot::zeroed();
    };
    let filter = |f: FilterMode| u32::from(f == FilterMode::Linear);
    let mip = match b.sampler.mip_filter {
        None => 0,
        Some(FilterMode::Nearest) => 1,
        Some(FilterMode::Linear) => 2,
    };
    let wrap = |w: WrapMode| match w {
        WrapMode::Repeat => 0,
        WrapMode::ClampToEdge => 1,
        WrapMode::MirroredRepeat => 2,
    };
    let s = &b.sampler;
    let tr = &b.uv_transform;
    let (sin, cos) = tr.rotation_rad.sin_cos();
    let origin = tr.apply(glam::Vec2::ZERO);
    let (w, h) = t.size();
    GpuSlot {
        info: [
            b.texture as u32 + 1,
            filter(s.mag_filter) + 4 * filter(s.min_filter) + 16 * mip,
            wrap(s.wrap_u) + 4 * wrap(s.wrap_v),
            u32::from(!tr.is_identity()),
        ],
        affine: [tr.scale.x, tr.scale.y, sin, cos],
        offset_origin: [tr.offset.x, tr.offset.y, origin.x, origin.y],
        size: [w as f32, h as f32, 0.0, 0.0],
    }
}

/// The shader's `View` of `view`, with `flags`, lists of `capacity` fragments and the setup
/// pass's `triangles` in rows of `row` invocations.
fn view_params(
    view: &View,
    views: usize,
    (flags, capacity): (u32, u32),
    (triangles, row): (u32, u32),
    clip: Option<&LensEffects>,
) -> ViewParams {
    let l = &view.lens;
    let (cx, cy) = l.centre_px();
    let vx = l.lens_radius_m * view.lens_point.x;
    let vy = -l.lens_radius_m * view.lens_point.y;
    let f = l.f_px;
    let (shift, radius) = clip.map_or((0.0, 1.0), |e| {
        (e.barrel_shift_per_px(l), e.barrel_radius(l))
    });
    let clip_flag = if clip.is_some() { CLIP } else { 0 };
    ViewParams {
        a: [
            cx - view.pixel_offset.x + f * vx / l.focus_m,
            cy - view.pixel_offset.y - f * vy / l.focus_m,
            f,
            view.lod_bias,
        ],
        v: [vx, vy, 2.0 / l.width_px as f32, 2.0 / l.height_px as f32],
        planes: [
            l.near_m,
            l.far_m,
            1.0 / (1.0 - l.near_m / l.far_m),
            1.0 / views.max(1) as f32,
        ],
        lens: [view.lens_point.x, view.lens_point.y, shift, radius],
        info: [
            l.width_px as u32,
            l.height_px as u32,
            capacity,
            flags | clip_flag,
        ],
        extra: [triangles, row, 0, 0],
        coc: [0.0; 4],
        frame: [0; 4],
    }
}

/// The mean of the views of `samples` drawn on the GPU of `ctx`: the GPU twin of
/// [`super::accumulate_views_clipped`] (the same views, lens points, sub-pixel offsets and
/// texture level-of-detail bias; the cat's eye of `clip` as there).
#[allow(clippy::too_many_arguments)]
pub fn accumulate_views(
    ctx: &GpuContext,
    prepared: &PreparedScene,
    lens: ThinLens,
    samples: &[LensSample],
    clip: Option<&LensEffects>,
    labels: &ViewPassLabels,
    timings: &mut Timings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ColorImage> {
    let clip = clip.filter(|e| e.has_cats_eye());
    let views: Vec<View> = samples
        .iter()
        .map(|s| super::sample_view(lens, s, samples.len()))
        .collect();
    let (color, _) = draw(
        ctx, prepared, &views, false, clip, labels, timings, progress,
    )?;
    Ok(color)
}

/// One view drawn on the GPU of `ctx` into a G-buffer (colour and the depth pass of
/// [`super::GBuffer::depth`]): the GPU twin of [`super::render_view`].
pub fn render_view(
    ctx: &GpuContext,
    prepared: &PreparedScene,
    view: &View,
    labels: &ViewPassLabels,
    timings: &mut Timings,
) -> Result<(ColorImage, GrayImage)> {
    let (color, depth) = draw(
        ctx,
        prepared,
        std::slice::from_ref(view),
        true,
        None,
        labels,
        timings,
        &mut |_, _| {},
    )?;
    let depth = depth.ok_or_else(|| Error::Gpu("the G-buffer pass returned no depth".into()))?;
    Ok((color, depth))
}

/// Draws `views` (one, stored as a G-buffer, with `store`; else their mean), growing the
/// lists when a pixel was handed more fragments than they held.
#[allow(clippy::too_many_arguments)]
fn draw(
    ctx: &GpuContext,
    prepared: &PreparedScene,
    views: &[View],
    store: bool,
    clip: Option<&LensEffects>,
    labels: &ViewPassLabels,
    timings: &mut Timings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(ColorImage, Option<GrayImage>)> {
    let Some(first) = views.first() else {
        return Err(Error::invalid("samples", "no views to draw"));
    };
    let lens = first.lens;
    let start = std::time::Instant::now();
    // Checked before the scene's copies are made, with the lists' first capacity.
    let (vertex_bytes, texel_bytes, blended) = SceneData::sizes(prepared);
    plan(
        ctx,
        &lens,
        blended,
        FIRST_LIST,
        vertex_bytes,
        texel_bytes,
        held(prepared),
    )?;
    let data = SceneData::new(prepared)?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);
    let mut capacity = if data.has_blended() { FIRST_LIST } else { 1 };
    loop {
        let (color, depth, handed) = draw_with(
            ctx, &data, &lens, views, store, clip, capacity, labels, timings, progress,
        )?;
        if handed <= capacity {
            return Ok((color, depth));
        }
        if handed > MAX_LIST {
            return Err(Error::Gpu(format!(
                "scene '{}': {handed} transparent surfaces lie in front of one pixel; the GPU \
                 rasteriser composites at most {MAX_LIST} a pixel (--device cpu has no limit)",
                crate::error::shown(&prepared.scene().name)
            )));
        }
        capacity = handed;
    }
}

/// One try of [`draw`] with lists of `capacity` fragments: the image, the depth (with
/// `store`), and the most fragments a pixel was handed.
#[allow(clippy::too_many_arguments)]
fn draw_with(
    ctx: &GpuContext,
    data: &SceneData,
    lens: &ThinLens,
    views: &[View],
    store: bool,
    clip: Option<&LensEffects>,
    capacity: u32,
    labels: &ViewPassLabels,
    timings: &mut Timings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(ColorImage, Option<GrayImage>, u32)> {
    let (w, h) = (lens.width_px, lens.height_px);
    let pixels = (w * h) as u64;
    let what = format!("the GPU rasteriser at {w}x{h}");
    let texel_bytes = std::mem::size_of_val(data.texels.as_slice()) as u64;
    let vertex_bytes = std::mem::size_of_val(data.vertices.as_slice()) as u64;
    let list_entries = plan(
        ctx,
        lens,
        data.has_blended(),
        capacity,
        vertex_bytes,
        texel_bytes,
        data.held,
    )?;
    check_target(ctx, &what, w, h)?;
    let limits = &ctx.description().limits;
    if vertex_bytes > limits.max_buffer_size {
        return Err(Error::Gpu(format!(
            "{what} needs a vertex buffer of {vertex_bytes} bytes; {} allows {} (max buffer \
             size)",
            ctx.description().label(),
            limits.max_buffer_size
        )));
    }
    let groups = ctx.row_groups(&what, w, h, WORKGROUP_X)?;
    let p = pipelines(ctx)?;

    let start = std::time::Instant::now();
    let device = ctx.device();
    let [vertices, materials, textures, levels, texels] = data.upload(ctx)?;
    let flags = if store { STORE } else { 0 };
    let triangles = (data.vertices.len() / 3) as u32;
    let setup_groups = setup_groups(ctx, &what, triangles)?;
    let row = setup_groups[0] * WORKGROUP_X;
    let table: Vec<ViewParams> = views
        .iter()
        .map(|v| view_params(v, views.len(), (flags, capacity), (triangles, row), clip))
        .collect();
    let table_buf = ctx.upload("views", bytemuck::cast_slice(&table))?;
    let view_buf = ctx.buffer(
        "view",
        VIEW_BYTES,
        wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
    );
    let counts = ctx.storage("list counts", pixels * 4)?;
    let keys = ctx.storage("list keys", list_entries * 8)?;
    let colors = ctx.storage("list colours", list_entries * 16)?;
    let sum = ctx.storage("view sum", pixels * 16)?;
    let reached = ctx.storage("views reached", pixels * 4)?;
    let out_color = ctx.storage("raster colour", pixels * 16)?;
    let out_depth = ctx.storage("raster depth", pixels * 4)?;
    let status = ctx.storage("raster status", 4)?;
    let planes = ctx.storage("triangle planes", u64::from(triangles.max(1)) * 48)?;
    let target = |label: &'static str, format: wgpu::TextureFormat| {
        ctx.texture(
            label,
            (w as u32, h as u32),
            format,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        )
    };
    let targets = [
        target("raster colour target", COLOR_FORMAT),
        target("raster depth target", DEPTH_M_FORMAT),
        target("raster z", Z_FORMAT),
    ];
    let [color_target, depth_target, z_target] = targets
        .each_ref()
        .map(|t| t.create_view(&Default::default()));
    let mut encoder = device.create_command_encoder(&Default::default());
    for b in [&counts, &sum, &reached, &status] {
        encoder.clear_buffer(b, 0, None);
    }
    ctx.queue().submit([encoder.finish()]);
    ctx.flush()?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);

    let bind = |layout: wgpu::BindGroupLayout, entries: &[(u32, wgpu::BindingResource)]| {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(binding, resource)| wgpu::BindGroupEntry {
                binding: *binding,
                resource: resource.clone(),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &layout,
            entries: &entries,
        })
    };
    fn whole(b: &wgpu::Buffer) -> wgpu::BindingResource<'_> {
        b.as_entire_binding()
    }
    let shading = [
        (0, whole(&view_buf)),
        (1, whole(&materials)),
        (2, whole(&textures)),
        (3, whole(&levels)),
        (4, whole(&texels)),
    ];
    let mut shading_planes = shading.to_vec();
    shading_planes.push((16, whole(&planes)));
    let opaque_group = bind(p.opaque.get_bind_group_layout(0), &shading_planes);
    let setup_group = bind(
        p.setup.get_bind_group_layout(0),
        &[
            (0, whole(&view_buf)),
            (15, whole(&vertices)),
            (16, whole(&planes)),
        ],
    );
    let mut blended_entries = shading_planes.clone();
    blended_entries.extend([
        (5, whole(&counts)),
        (6, whole(&keys)),
        (7, whole(&colors)),
        (9, wgpu::BindingResource::TextureView(&depth_target)),
    ]);
    let blended_group = data
        .has_blended()
        .then(|| bind(p.blended.get_bind_group_layout(0), &blended_entries));
    let composite_group = bind(
        p.composite.get_bind_group_layout(0),
        &[
            (0, whole(&view_buf)),
            (5, whole(&counts)),
            (6, whole(&keys)),
            (7, whole(&colors)),
            (8, wgpu::BindingResource::TextureView(&color_target)),
            (9, wgpu::BindingResource::TextureView(&depth_target)),
            (10, whole(&sum)),
            (11, whole(&reached)),
            (12, whole(&out_color)),
            (13, whole(&out_depth)),
            (14, whole(&status)),
        ],
    );
    let resolve_group = bind(
        p.resolve.get_bind_group_layout(0),
        &[
            (0, whole(&view_buf)),
            (10, whole(&sum)),
            (11, whole(&reached)),
            (12, whole(&out_color)),
        ],
    );

    let opaque_end = data.opaque_vertices;
    let all_end = data.vertices.len() as u32;
    let mut done = 0;
    for (chunk_index, chunk) in views.chunks(VIEWS_PER_SUBMIT).enumerate() {
        let mut timer = PassTimer::new(ctx, 4 * chunk.len() as u32 + 1);
        for k in 0..chunk.len() {
            let at = (chunk_index * VIEWS_PER_SUBMIT + k) as u64 * VIEW_BYTES;
            timer.record(labels.setup, |encoder, stamps| {
                encoder.copy_buffer_to_buffer(&table_buf, at, &view_buf, 0, VIEW_BYTES);
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("raster/setup"),
                    timestamp_writes: stamps.map(|s| s.compute()),
                });
                pass.set_pipeline(&p.setup);
                pass.set_bind_group(0, &setup_group, &[]);
                pass.dispatch_workgroups(setup_groups[0], setup_groups[1], 1);
            })?;
            timer.record(labels.raster, |encoder, stamps| {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("raster/opaque"),
                    color_attachments: &[
                        Some(clear_attachment(&color_target)),
                        Some(clear_attachment(&depth_target)),
                    ],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &z_target,
                        depth_ops: Some(wgpu::Operations {
                            load: wgpu::LoadOp::Clear(0.0),
                            store: wgpu::StoreOp::Store,
                        }),
                        stencil_ops: None,
                    }),
                    timestamp_writes: stamps.map(|s| s.render()),
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&p.opaque);
                pass.set_bind_group(0, &opaque_group, &[]);
                pass.set_vertex_buffer(0, vertices.slice(..));
                if opaque_end > 0 {
                    pass.draw(0..opaque_end, 0..1);
                }
            })?;
            if let Some(group) = &blended_group {
                timer.record(labels.raster, |encoder, stamps| {
                    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                        label: Some("raster/blended"),
                        color_attachments: &[],
                        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                            view: &z_target,
                            depth_ops: None,
                            stencil_ops: None,
                        }),
                        timestamp_writes: stamps.map(|s| s.render()),
                        occlusion_query_set: None,
                        multiview_mask: None,
                    });
                    pass.set_pipeline(&p.blended);
                    pass.set_bind_group(0, group, &[]);
                    pass.set_vertex_buffer(0, vertices.slice(..));
                    pass.draw(opaque_end..all_end, 0..1);
                })?;
            }
            timer.dispatch(labels.raster, &p.composite, &composite_group, groups)?;
        }
        let last = done + chunk.len() == views.len();
        if last && !store {
            timer.dispatch(labels.resolve, &p.resolve, &resolve_group, groups)?;
        }
        timings.extend(&timer.finish()?);
        done += chunk.len();
        progress(done, views.len());
    }

    let start = std::time::Instant::now();
    let mut wanted = vec![(&status, 4), (&out_color, pixels * 16)];
    if store {
        wanted.push((&out_depth, pixels * 4));
    }
    let read = ctx.read(&wanted)?;
    timings.add("gpu/download", start.elapsed().as_secs_f64() * 1e3);
    let handed = u32::from_le_bytes(read[0][..4].try_into().unwrap_or([0; 4]));
    let color = ColorImage::from_vec(w, h, bytemuck::pod_collect_to_vec(&read[1]))?;
    let depth = match read.get(2) {
        Some(d) => Some(GrayImage::from_vec(w, h, bytemuck::pod_collect_to_vec(d))?),
        None => None,
    };
    ctx.recycle([
        vertices, materials, textures, levels, texels, table_buf, view_buf, counts, keys, colors,
        sum, reached, out_color, out_depth, status, planes,
    ]);
    ctx.recycle_textures(targets);
    Ok((color, depth, handed))
}

/// Checks a frame's memory before anything is allocated for it, and returns the entries of
/// its lists: on the GPU the targets (colour, view depth, hardware depth), the lists' counts
/// and entries (`capacity` a pixel where the scene has blended surfaces), the sum, the counts
/// of views that reach a pixel, the outputs and their read-back copies, the scene's vertices
/// (and their planes, 48 bytes a triangle) and texels; on the CPU beside them `held` (the
/// scene, its camera-space copy) and the staging copies of the vertices and texels.
fn plan(
    ctx: &GpuContext,
    lens: &ThinLens,
    blended: bool,
    capacity: u32,
    vertex_bytes: u64,
    texel_bytes: u64,
    held: u64,
) -> Result<u64> {
    let (w, h) = (lens.width_px, lens.height_px);
    let pixels = (w * h) as u64;
    let list_entries = if blended {
        pixels * u64::from(capacity)
    } else {
        1
    };
    let per_pixel = 16 + 4 + 4 + 4 + 16 + 4 + 2 * (16 + 4);
    let gpu = pixels * per_pixel + list_entries * 24 + texel_bytes + vertex_bytes * 3;
    let cpu = held + vertex_bytes + texel_bytes;
    ctx.plan(
        &format!("the GPU rasteriser at {w}x{h}"),
        texel_bytes.max(list_entries * 16).max(pixels * 16),
        gpu + cpu,
    )?;
    Ok(list_entries)
}

/// The workgroups of the setup pass over `triangles` triangles: rows of at most 32768
/// workgroups.
fn setup_groups(ctx: &GpuContext, what: &str, triangles: u32) -> Result<[u32; 2]> {
    const ROW: u32 = 32768;
    let groups = triangles.div_ceil(WORKGROUP_X).max(1);
    let out = [groups.min(ROW), groups.div_ceil(ROW)];
    let max = ctx
        .description()
        .limits
        .max_compute_workgroups_per_dimension;
    if out[0] > max || out[1] > max {
        return Err(Error::Gpu(format!(
            "{what}: {triangles} triangles need {} x {} workgroups; {} allows {max} a \
             dimension (max compute workgroups per dimension)",
            out[0],
            out[1],
            ctx.description().label()
        )));
    }
    Ok(out)
}

/// Refuses a `w` x `h` render target, naming `what` needs it, where the adapter allows fewer
/// pixels a side.
fn check_target(ctx: &GpuContext, what: &str, w: usize, h: usize) -> Result<()> {
    let most = ctx.description().limits.max_texture_dimension_2d;
    if w as u64 > u64::from(most) || h as u64 > u64::from(most) {
        return Err(Error::Gpu(format!(
            "{what} needs a {w}x{h} target; {} allows {most} a side (max texture dimension 2d)",
            ctx.description().label()
        )));
    }
    Ok(())
}

/// A colour attachment cleared to zero and stored.
fn clear_attachment(view: &wgpu::TextureView) -> wgpu::RenderPassColorAttachment<'_> {
    wgpu::RenderPassColorAttachment {
        view,
        depth_slice: None,
        resolve_target: None,
        ops: wgpu::Operations {
            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
            store: wgpu::StoreOp::Store,
        },
    }
}

/// The N nearest fragments of every pixel of a pinhole view, left on the GPU: the GPU twin of
/// [`super::render_fragment_lists_with`] sampled at pixel centres (no coverage masks), for the
/// layered methods' `--device gpu`. Pixel `i` holds `count[i]` fragments in slots
/// `i * cap ..`, nearest first: depth (f32) and premultiplied colour (four halves).
pub struct GpuLists {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Slots a pixel (N).
    pub cap: usize,
    /// Fragments held per pixel (u32).
    pub count: wgpu::Buffer,
    /// Depths, `cap` slots a pixel (f32).
    pub depth: wgpu::Buffer,
    /// Colours, `cap` slots a pixel (two words of halves).
    pub color: wgpu::Buffer,
    /// The largest CoC diameter of the fragments held, in pixels.
    pub widest_px: f32,
}

impl GpuLists {
    /// The lists copied back to the CPU, as the CPU's [`super::FragmentLists`] holds them.
    pub fn download(&self, ctx: &GpuContext) -> Result<super::FragmentLists> {
        let pixels = (self.width * self.height) as u64;
        let slots = pixels * self.cap as u64;
        let read = ctx.read(&[
            (&self.count, pixels * 4),
            (&self.depth, slots * 4),
            (&self.color, slots * 8),
        ])?;
        let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&read[0]);
        let depths: Vec<f32> = bytemuck::pod_collect_to_vec(&read[1]);
        let colors: Vec<[u16; 4]> = bytemuck::pod_collect_to_vec(&read[2]);
        let mut offsets = Vec::with_capacity(counts.len() + 1);
        offsets.push(0u32);
        let (mut depth, mut color) = (Vec::new(), Vec::new());
        for (i, &n) in counts.iter().enumerate() {
            let n = (n as usize).min(self.cap);
            for k in i * self.cap..i * self.cap + n {
                depth.push(depths[k]);
                color.push(colors[k].map(half::f16::from_bits));
            }
            offsets.push(depth.len() as u32);
        }
        Ok(super::FragmentLists::from_parts(
            self.width,
            self.height,
            offsets,
            depth,
            color,
        ))
    }

    /// Gives the buffers back to `ctx`'s pool.
    pub fn recycle(self, ctx: &GpuContext) {
        ctx.recycle([self.count, self.depth, self.color]);
    }
}

/// Key under which a context remembers the list nodes a pixel the last lists needed, so that
/// the next frame of a sequence or batch is drawn once.
const POOL_HINT: &str = "raster fragment pool";

/// The fragment lists of the pinhole view of `lens` on the GPU of `ctx` ([`GpuLists`]): every
/// fragment linked into its pixel's list in one rasterisation pass (per-pixel linked lists
/// with an atomic counter, Yang et al. 2010, as Selgrad et al. section 4), then the `cap`
/// nearest of each pixel kept, in depth order (equal depths in the order the triangles are
/// drawn). With `reach`, the guard band's fragments that cannot reach the frame are dropped
/// as on the CPU. Timed as `pass`. The pool of list nodes holds as many a pixel as the last
/// frame needed (4 at first); a frame that needs more is drawn again with as many.
pub fn fragment_lists(
    ctx: &GpuContext,
    prepared: &PreparedScene,
    lens: ThinLens,
    cap: usize,
    reach: Option<&super::Reach>,
    pass: &'static str,
    timings: &mut Timings,
) -> Result<GpuLists> {
    let cap = cap.clamp(1, MAX_LIST as usize);
    let (w, h) = (lens.width_px, lens.height_px);
    let pixels = (w * h) as u64;
    let what = format!("the GPU fragment lists at {w}x{h}");
    let start = std::time::Instant::now();
    let (vertex_bytes, texel_bytes, _) = SceneData::sizes(prepared);
    // Nodes a pixel the last lists needed (at least 4).
    let hint = ctx.cached(POOL_HINT, || Ok(std::sync::atomic::AtomicU64::new(4)))?;
    // Within what one binding may hold (8 bytes a node); a frame that needs more is refused
    // by the plan below, naming the limit.
    let limits = &ctx.description().limits;
    let most = (limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
        / 8)
    .max(1);
    let per_pixel = hint.load(std::sync::atomic::Ordering::Relaxed).max(4);
    let mut pool = (pixels * per_pixel).min(most).max(1);
    plan_lists(
        ctx,
        &what,
        (pixels, cap as u64, pool),
        vertex_bytes,
        texel_bytes,
        held(prepared),
    )?;
    let data = SceneData::new(prepared)?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);
    loop {
        let (lists, wanted) = lists_with(ctx, &data, &lens, cap, reach, pool, pass, timings)?;
        if wanted <= pool {
            let per_pixel = pool.div_ceil(pixels.max(1));
            hint.store(per_pixel, std::sync::atomic::Ordering::Relaxed);
            return Ok(lists);
        }
        lists.recycle(ctx);
        if wanted > u64::from(u32::MAX) {
            return Err(Error::Gpu(format!(
                "{what}: the scene gives {wanted} fragments; the lists address at most 2^32"
            )));
        }
        // An eighth more, so that the next frames of a sequence fit.
        pool = (wanted + wanted / 8).min(u64::from(u32::MAX));
        plan_lists(
            ctx,
            &what,
            (pixels, cap as u64, pool),
            vertex_bytes,
            texel_bytes,
            data.held,
        )?;
    }
}

/// Checks the memory of fragment lists of `pixels` pixels keeping `cap` of a pool of `pool`
/// nodes before anything is allocated: on the GPU the heads, nodes and links, the kept slots,
/// the scene's vertices (and planes) and texels; on the CPU the scene, its camera-space copy and
/// the staging copies.
fn plan_lists(
    ctx: &GpuContext,
    what: &str,
    (pixels, cap, pool): (u64, u64, u64),
    vertex_bytes: u64,
    texel_bytes: u64,
    held: u64,
) -> Result<()> {
    let gpu = pixels * (4 + 4 + 12 * cap) + pool * 20 + texel_bytes + vertex_bytes * 3;
    ctx.plan(
        what,
        (pool * 8).max(pixels * cap * 8).max(texel_bytes),
        gpu + held + vertex_bytes + texel_bytes,
    )
}

/// One try of [`fragment_lists`] with a pool of `pool` nodes: the lists, and the nodes the
/// frame asked for.
#[allow(clippy::too_many_arguments)]
fn lists_with(
    ctx: &GpuContext,
    data: &SceneData,
    lens: &ThinLens,
    cap: usize,
    reach: Option<&super::Reach>,
    pool: u64,
    pass: &'static str,
    timings: &mut Timings,
) -> Result<(GpuLists, u64)> {
    let (w, h) = (lens.width_px, lens.height_px);
    let pixels = (w * h) as u64;
    let what = format!("the GPU fragment lists at {w}x{h}");
    check_target(ctx, &what, w, h)?;
    let groups = ctx.row_groups(&what, w, h, WORKGROUP_X)?;
    let p = pipelines(ctx)?;
    let start = std::time::Instant::now();
    let [vertices, materials, textures, levels, texels] = data.upload(ctx)?;
    let triangles = (data.vertices.len() / 3) as u32;
    let setup_groups = setup_groups(ctx, &what, triangles)?;
    let row = setup_groups[0] * WORKGROUP_X;
    let view = View::pinhole(*lens);
    let mut params = view_params(&view, 1, (0, pool as u32), (triangles, row), None);
    params.extra[2] = cap as u32;
    params.coc = [lens.f_px * lens.lens_radius_m, lens.focus_m, 0.0, 0.0];
    if let Some(r) = reach {
        let (x0, y0, fw, fh) = r.frame;
        params.coc[2] = r.factor;
        params.coc[3] = r.slack_px;
        params.frame = [x0 as u32, y0 as u32, (x0 + fw) as u32, (y0 + fh) as u32];
    }
    let view_buf = ctx.uniform("view", bytemuck::bytes_of(&params));
    let planes = ctx.storage("triangle planes", u64::from(triangles.max(1)) * 48)?;
    let heads = ctx.storage("list heads", pixels * 4)?;
    let nodes = ctx.storage("list nodes", pool * 8)?;
    let node_color = ctx.storage("list node colours", pool * 8)?;
    let next = ctx.storage("list links", pool * 4)?;
    let status = ctx.storage("raster status", 16)?;
    let count = ctx.storage("kept counts", pixels * 4)?;
    let depth = ctx.storage("kept depths", pixels * cap as u64 * 4)?;
    let color = ctx.storage("kept colours", pixels * cap as u64 * 8)?;
    let z_target = ctx.texture(
        "raster z",
        (w as u32, h as u32),
        Z_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let z_view = z_target.create_view(&Default::default());
    let mut encoder = ctx.device().create_command_encoder(&Default::default());
    for b in [&heads, &status] {
        encoder.clear_buffer(b, 0, None);
    }
    ctx.queue().submit([encoder.finish()]);
    ctx.flush()?;
    timings.add("gpu/upload", start.elapsed().as_secs_f64() * 1e3);

    let bind = |layout: wgpu::BindGroupLayout, entries: &[(u32, &wgpu::Buffer)]| {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(binding, b)| wgpu::BindGroupEntry {
                binding: *binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        ctx.device().create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &layout,
            entries: &entries,
        })
    };
    let setup_group = bind(
        p.setup.get_bind_group_layout(0),
        &[(0, &view_buf), (15, &vertices), (16, &planes)],
    );
    let collect_group = bind(
        p.collect.get_bind_group_layout(0),
        &[
            (0, &view_buf),
            (1, &materials),
            (2, &textures),
            (3, &levels),
            (4, &texels),
            (14, &status),
            (16, &planes),
            (17, &heads),
            (18, &nodes),
            (19, &next),
            (23, &node_color),
        ],
    );
    let keep_group = bind(
        p.keep.get_bind_group_layout(0),
        &[
            (0, &view_buf),
            (14, &status),
            (17, &heads),
            (18, &nodes),
            (19, &next),
            (23, &node_color),
            (20, &count),
            (21, &depth),
            (22, &color),
        ],
    );
    let mut timer = PassTimer::new(ctx, 3);
    timer.dispatch(
        pass,
        &p.setup,
        &setup_group,
        [setup_groups[0], setup_groups[1], 1],
    )?;
    timer.record(pass, |encoder, stamps| {
        let mut rp = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("raster/collect"),
            color_attachments: &[],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &z_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(0.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: stamps.map(|s| s.render()),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        rp.set_pipeline(&p.collect);
        rp.set_bind_group(0, &collect_group, &[]);
        rp.set_vertex_buffer(0, vertices.slice(..));
        if triangles > 0 {
            rp.draw(0..3 * triangles, 0..1);
        }
    })?;
    timer.dispatch(pass, &p.keep, &keep_group, groups)?;
    timings.extend(&timer.finish()?);
    let read = ctx.read(&[(&status, 16)])?;
    let word =
        |k: usize| u32::from_le_bytes(read[0][4 * k..4 * k + 4].try_into().unwrap_or([0; 4]));
    let wanted = u64::from(word(1));
    let widest_px = f32::from_bits(word(2));
    ctx.recycle([
        vertices, materials, textures, levels, texels, view_buf, planes, heads, nodes, node_color,
        next, status,
    ]);
    ctx.recycle_textures([z_target]);
    Ok((
        GpuLists {
            width: w,
            height: h,
            cap,
            count,
            depth,
            color,
            widest_px,
        },
        wanted,
    ))
}
