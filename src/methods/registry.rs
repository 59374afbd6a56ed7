//! The list of methods, owned by the library: id, one-line description, paper, the input each
//! needs, its settings type with defaults, and one way to run it. The command line and the
//! comparison report iterate over [`METHODS`] and never match on method names; adding a method
//! is one module, one entry here (and in [`MethodSettings`]) and its flags.

use crate::image::{ColorImage, GrayImage};
use crate::lens::{Camera, SamplerKind, ThinLens};

/// Most samples a run takes (`--samples`): lens views, rays or pixel samples.
pub const MAX_SAMPLES: usize = 1 << 20;
use crate::gpu::{Device, GpuContext};
use crate::scene::Scene;
use crate::{Error, Result};

use super::gaussian::{self, GaussianSettings};
use super::hammon::{self, HammonSettings};
use super::lowrank::{self, LowRankSettings};
use super::multilayer::{self, MultilayerSettings};
use super::multiview::{self, MultiviewSettings};
use super::poisson::{self, PoissonSettings};
use super::reference::{self, ReferenceSettings};
use super::splat::{self, SplatSettings};
use super::MethodOutput;

/// What a method reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// Views of a 3D scene rasterized through points on the lens (`reference`, `pinhole`).
    SceneViews,
    /// One pinhole frame: linear colour + view-axis depth at pixel centres. From a scene (an
    /// anti-aliased frame is rendered first) or from files (`blur`).
    PinholeFrame,
    /// Per-pixel fragment lists of the pinhole view, every surface a pixel sees (a scene).
    FragmentLists,
    /// Depth layers of the scene spaced in CoC (a scene).
    DepthLayers,
}

impl InputKind {
    /// True when the input can only be made from a 3D scene (not from a colour + depth pair).
    pub fn needs_scene(self) -> bool {
        !matches!(self, InputKind::PinholeFrame)
    }

    /// True when a colour image with a depth pass can be made into the input: a frame, or
    /// fragment lists (the frame decomposed into layers, [`super::fill::fragment_lists`]).
    pub fn takes_frame(self) -> bool {
        matches!(self, InputKind::PinholeFrame | InputKind::FragmentLists)
    }

    /// A short phrase for messages and reports.
    pub fn describe(self) -> &'static str {
        match self {
            InputKind::SceneViews => "views of a 3D scene through the lens",
            InputKind::PinholeFrame => "a colour image with a depth pass",
            InputKind::FragmentLists => "per-pixel fragment lists rasterized from a 3D scene",
            InputKind::DepthLayers => "depth layers rasterized from a 3D scene",
        }
    }
}

/// One method of the registry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MethodInfo {
    /// The id used on the command line, in `--timings` labels and in reports.
    pub id: &'static str,
    /// One line on what it does.
    pub description: &'static str,
    /// The paper it implements ("" for `pinhole`).
    pub paper: &'static str,
    /// What it reads.
    pub input: InputKind,
    /// The lens effects ([`crate::lens::EFFECT_NAMES`]) it renders; it refuses the others.
    pub effects: &'static [&'static str],
    /// Whether it runs on the GPU too (`--device gpu`; its GPU passes beside its CPU ones).
    pub gpu: bool,
}

/// Every method, in the order reports list them.
pub const METHODS: &[MethodInfo] = &[
    MethodInfo {
        id: "pinhole",
        description: "no blur: the scene through the lens centre (supersampled with --samples)",
        paper: "",
        input: InputKind::SceneViews,
        effects: &[],
        gpu: true,
    },
    MethodInfo {
        id: "reference",
        description: "ground truth: the mean of many views through points on the lens",
        paper: "Haeberli & Akeley 1990, The accumulation buffer",
        input: InputKind::SceneViews,
        effects: &crate::lens::EFFECT_NAMES,
        gpu: true,
    },
    MethodInfo {
        id: "hammon",
        description: "post-process gather: blend of small / medium / large blurs with a blurred near CoC",
        paper: "Hammon 2007, GPU Gems 3 ch. 28",
        input: InputKind::PinholeFrame,
        effects: &[],
        gpu: true,
    },
    MethodInfo {
        id: "lowrank",
        description: "aperture kernel as a sum of separable filters (SVD), depth-edge mask with a 2D fallback",
        paper: "McGraw 2015, Fast bokeh effects using low-rank linear filters",
        input: InputKind::PinholeFrame,
        effects: super::lowrank::EFFECTS,
        gpu: true,
    },
    MethodInfo {
        id: "gaussian",
        description: "baseline: separable Gaussian gather sized by the CoC",
        paper: "after Zhou et al. 2007",
        input: InputKind::PinholeFrame,
        effects: &[],
        gpu: true,
    },
    MethodInfo {
        id: "poisson",
        description: "baseline: Poisson-disc gather in the aperture shape with depth rejection",
        paper: "after Scheuermann 2004",
        input: InputKind::PinholeFrame,
        effects: super::poisson::EFFECTS,
        gpu: true,
    },
    MethodInfo {
        id: "splat",
        description: "tiled scatter: every fragment splatted in the aperture's shape, blended in depth order per tile (--layers N: from fragment lists)",
        paper: "Fast depth of field rendering (poster; tiled DoF splatting)",
        input: InputKind::PinholeFrame,
        effects: super::splat::EFFECTS,
        gpu: false,
    },
    MethodInfo {
        id: "multilayer",
        description: "per-pixel fragment lists filtered into levels of growing blur, blended by CoC: sees behind near blur",
        paper: "Selgrad et al. 2015, Real-time depth of field using multi-layer filtering",
        input: InputKind::FragmentLists,
        effects: &[],
        gpu: true,
    },
    MethodInfo {
        id: "multiview",
        description: "lens rays traced through CoC-spaced depth layers rendered once: reference-like, cost independent of the scene",
        paper: "Lee, Eisemann, Seidel 2009, Depth-of-field rendering with multiview synthesis",
        input: InputKind::DepthLayers,
        effects: super::multiview::EFFECTS,
        gpu: false,
    },
];

/// Checks the lens effects' ranges, and refuses those that method `id` does not render
/// ([`MethodInfo::effects`]), naming them and the methods that render them all.
pub fn check_effects(id: &str, effects: &crate::lens::LensEffects) -> Result<()> {
    effects.validate()?;
    let info = find(id)?;
    let missing = effects.unsupported(info.effects);
    if missing.is_empty() {
        return Ok(());
    }
    let supported: Vec<&str> = METHODS
        .iter()
        .filter(|m| missing.iter().all(|e| m.effects.contains(e)))
        .map(|m| m.id)
        .collect();
    Err(crate::Error::Option(format!(
        "method {id} does not support the lens effect {} (--{}); {} support it",
        missing.join(", "),
        missing.join(", --"),
        supported.join(", ")
    )))
}

/// The registry entry of `id`, or an error listing the known ids.
pub fn find(id: &str) -> Result<&'static MethodInfo> {
    METHODS
        .iter()
        .find(|m| m.id == id)
        .ok_or_else(|| Error::Unknown {
            kind: "method",
            name: id.to_string(),
            expected: ids().join(", "),
        })
}

/// The ids of the methods that run on the GPU ([`MethodInfo::gpu`]), in registry order.
pub fn gpu_ids() -> Vec<&'static str> {
    METHODS.iter().filter(|m| m.gpu).map(|m| m.id).collect()
}

/// Every WGSL shader of the GPU methods: its name and source (for validation by naga).
pub const GPU_SHADERS: &[(&str, &str)] = &[
    (crate::raster::gpu::SHADER_NAME, crate::raster::gpu::SHADER),
    (hammon::gpu::SHADER_NAME, hammon::gpu::SHADER),
    (gaussian::gpu::SHADER_NAME, gaussian::gpu::SHADER),
    (poisson::gpu::SHADER_NAME, poisson::gpu::SHADER),
    (lowrank::gpu::SHADER_NAME, lowrank::gpu::SHADER),
    (multilayer::gpu::SHADER_NAME, multilayer::gpu::SHADER),
];

/// Builds every pipeline of every GPU method on `ctx` (compiled once, then cached there): a
/// shader that does not build is an error naming it.
pub fn prepare_gpu(ctx: &GpuContext) -> Result<()> {
    crate::raster::gpu::prepare(ctx)?;
    hammon::gpu::prepare(ctx)?;
    gaussian::gpu::prepare(ctx)?;
    poisson::gpu::prepare(ctx)?;
    multilayer::gpu::prepare(ctx)?;
    lowrank::gpu::prepare(ctx)
}

/// Whether a run with `settings` runs on the GPU: its method has GPU passes, and they cover
/// what `settings` ask (`multilayer` runs the paper's configuration there,
/// [`multilayer::gpu::check`]). `--device auto` runs the others on the CPU.
pub fn runs_on_gpu(settings: &MethodSettings) -> bool {
    settings.info().gpu
        && match settings {
            MethodSettings::Multilayer(s) => multilayer::gpu::check(s).is_ok(),
            _ => true,
        }
}

/// Refuses `--device gpu` for method `id` when it has no GPU passes, naming those that have.
pub fn check_gpu(id: &str) -> Result<()> {
    let info = find(id)?;
    if info.gpu {
        return Ok(());
    }
    Err(Error::Option(format!(
        "method {} does not run on the GPU yet (--device gpu); the methods that do: {}. Use \
         --device cpu or auto",
        info.id,
        gpu_ids().join(", ")
    )))
}

/// The GPU context a run of method `id` takes on `device` ([`crate::gpu::choose`]), or `None`
/// for the CPU: `cpu`; `auto` for a method without GPU passes or on a machine without a
/// hardware adapter. `gpu` refuses a method without GPU passes, and fails when there is no
/// adapter.
pub fn gpu_context(device: Device, id: &str) -> Result<Option<GpuContext>> {
    let info = find(id)?;
    match device {
        Device::Cpu => Ok(None),
        Device::Auto if !info.gpu => Ok(None),
        Device::Gpu if !info.gpu => check_gpu(id).map(|()| None),
        _ => GpuContext::open(device),
    }
}

/// Every method id, in registry order.
pub fn ids() -> Vec<&'static str> {
    METHODS.iter().map(|m| m.id).collect()
}

/// Settings of `pinhole`.
#[derive(Clone, Debug, PartialEq)]
pub struct PinholeSettings {
    /// Samples per pixel (box filter, the reference's sampler); 1 = pixel centres.
    pub samples: usize,
    /// Seed of the pixel sampler.
    pub seed: u64,
    /// Pixel sampler.
    pub sampler: crate::lens::SamplerKind,
}

impl Default for PinholeSettings {
    fn default() -> Self {
        Self {
            samples: 1,
            seed: 0,
            sampler: crate::lens::SamplerKind::Halton,
        }
    }
}

/// The settings of one method: which method runs, and how.
#[derive(Clone, Debug)]
pub enum MethodSettings {
    /// `pinhole`.
    Pinhole(PinholeSettings),
    /// `reference`.
    Reference(ReferenceSettings),
    /// `hammon`.
    Hammon(HammonSettings),
    /// `lowrank`.
    Lowrank(LowRankSettings),
    /// `gaussian`.
    Gaussian(GaussianSettings),
    /// `poisson`.
    Poisson(PoissonSettings),
    /// `splat`.
    Splat(SplatSettings),
    /// `multilayer`.
    Multilayer(MultilayerSettings),
    /// `multiview`.
    Multiview(MultiviewSettings),
}

impl MethodSettings {
    /// The defaults of method `id`.
    pub fn default_for(id: &str) -> Result<Self> {
        Ok(match find(id)?.id {
            "pinhole" => Self::Pinhole(PinholeSettings::default()),
            "reference" => Self::Reference(ReferenceSettings::default()),
            "hammon" => Self::Hammon(HammonSettings::default()),
            "lowrank" => Self::Lowrank(LowRankSettings::default()),
            "gaussian" => Self::Gaussian(GaussianSettings::default()),
            "poisson" => Self::Poisson(PoissonSettings::default()),
            "splat" => Self::Splat(SplatSettings::default()),
            "multilayer" => Self::Multilayer(MultilayerSettings::default()),
            "multiview" => Self::Multiview(MultiviewSettings::default()),
            other => {
                return Err(Error::invalid(
                    "method",
                    format!("'{other}' is in the registry but has no settings type"),
                ))
            }
        })
    }

    /// The method's id.
    pub fn id(&self) -> &'static str {
        match self {
            Self::Pinhole(_) => "pinhole",
            Self::Reference(_) => "reference",
            Self::Hammon(_) => "hammon",
            Self::Lowrank(_) => "lowrank",
            Self::Gaussian(_) => "gaussian",
            Self::Poisson(_) => "poisson",
            Self::Splat(_) => "splat",
            Self::Multilayer(_) => "multilayer",
            Self::Multiview(_) => "multiview",
        }
    }

    /// The settings of a run on a scene: `samples` (lens views of `reference`, samples per
    /// pixel of `pinhole`, lens rays per pixel of `multiview`; each method's default when
    /// `None`), the lens and pixel `sampler`, its `seed` and the `aperture` of `reference`.
    /// Other methods are returned as they are (their samples are those of the frame they
    /// blur, [`SceneOptions::frame_samples`]). `samples` must be 1 to 2^20.
    pub fn with_run(
        self,
        samples: Option<usize>,
        sampler: SamplerKind,
        seed: u64,
        aperture: &crate::lens::Aperture,
    ) -> Result<Self> {
        if let Some(n) = samples {
            if n == 0 || n > MAX_SAMPLES {
                return Err(Error::Option(format!(
                    "invalid --samples {n}: expected 1 to {MAX_SAMPLES}"
                )));
            }
        }
        Ok(match self {
            Self::Reference(r) => Self::Reference(ReferenceSettings {
                samples: samples.unwrap_or(r.samples),
                sampler,
                seed,
                aperture: aperture.clone(),
                ..r
            }),
            Self::Pinhole(p) => Self::Pinhole(PinholeSettings {
                samples: samples.unwrap_or(p.samples),
                sampler,
                seed,
            }),
            Self::Multiview(m) => {
                let m = MultiviewSettings {
                    samples: samples.unwrap_or(m.samples),
                    sampler,
                    ..m
                };
                m.validate()
                    .map_err(|e| Error::Option(format!("invalid multiview option: {e}")))?;
                Self::Multiview(m)
            }
            other => other,
        })
    }

    /// The method's registry entry.
    pub fn info(&self) -> &'static MethodInfo {
        let id = self.id();
        METHODS
            .iter()
            .find(|m| m.id == id)
            .expect("every MethodSettings variant has a registry entry (tested)")
    }
}

/// A pinhole frame: what the post-process methods read.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// Linear premultiplied RGBA.
    pub color: &'a ColorImage,
    /// View-axis depth in metres at pixel centres (+inf where nothing was hit).
    pub depth: &'a GrayImage,
    /// The thin lens the frame is blurred for.
    pub lens: &'a ThinLens,
}

/// Memory a run takes besides its images: the program, its threads and their stacks, the
/// scene (measured: 55-60 MiB for a 1280x720 `reference` run of `railing`, most of it fixed).
pub const FIXED_PEAK_BYTES: u64 = 64 << 20;

/// Estimated peak bytes a pixel of a run of `settings` takes, for the methods whose memory is
/// proportional to the frame: its input frame (colour and depth), scratch and output. Measured
/// as the largest resident size of `render --scene railing` at 1280x720 and 2560x1440 (the
/// difference over the difference in pixels), rounded up by a quarter: `reference` and
/// `pinhole` 32-40, `hammon`, `gaussian` and `poisson` 56, `lowrank` 81 bytes a pixel. The
/// layered methods and `splat`'s tile lists grow with their options and the CoCs: they check
/// their own estimates before allocating (`multilayer::peak_bytes`, `multiview::peak_bytes`,
/// `splat`'s lists), and count here only the frame they start from.
pub fn peak_bytes_per_pixel(settings: &MethodSettings) -> u64 {
    match settings {
        MethodSettings::Reference(_) | MethodSettings::Pinhole(_) => 50,
        MethodSettings::Lowrank(_) => 100,
        _ => 70,
    }
}

/// Estimated peak bytes of a run of `settings` on a `width` x `height` frame (see
/// [`peak_bytes_per_pixel`]).
pub fn peak_bytes(settings: &MethodSettings, width: usize, height: usize) -> u64 {
    FIXED_PEAK_BYTES + (width as u64 * height as u64) * peak_bytes_per_pixel(settings)
}

/// Refuses a run whose estimated peak ([`peak_bytes`]) exceeds the memory budget, before
/// anything is allocated.
pub fn check_budget(settings: &MethodSettings, width: usize, height: usize) -> Result<()> {
    crate::budget::check(
        peak_bytes(settings, width, height),
        &format!("{} at {width}x{height}", settings.id()),
        "the resolution",
    )
}

/// Bytes a run on `scene` holds for the scene besides its frame: the scene itself
/// ([`Scene::bytes`]: meshes and decoded textures), its camera-space copy
/// ([`crate::raster::PreparedScene::bytes_for`]) and the set-up and binned triangles of the views rendered at
/// once ([`crate::raster::views::view_bytes`] times [`crate::raster::views::views_per_chunk`]).
pub fn scene_peak_bytes(scene: &Scene) -> Result<u64> {
    use crate::raster::views::{view_bytes, views_per_chunk};
    let triangles = scene.triangle_count();
    let views = views_per_chunk(triangles, crate::budget::budget_bytes()?) as u64;
    Ok(scene.bytes()
        + crate::raster::PreparedScene::bytes_for(scene)
        + views * view_bytes(triangles))
}

/// Refuses a run of `settings` on `scene` through `camera` whose estimated peak, the frame's
/// ([`peak_bytes`]) and the scene's ([`scene_peak_bytes`]), exceeds the memory budget, before
/// anything is allocated for it.
pub fn check_scene_budget(settings: &MethodSettings, scene: &Scene, camera: &Camera) -> Result<()> {
    let (w, h) = (camera.width_px, camera.height_px);
    crate::budget::check(
        peak_bytes(settings, w, h) + scene_peak_bytes(scene)?,
        &format!(
            "{} at {w}x{h} on scene '{}' ({} triangles, {} textures)",
            settings.id(),
            crate::error::shown(&scene.name),
            scene.triangle_count(),
            scene.textures.len()
        ),
        "the resolution or the scene's size",
    )
}

/// Runs a method that reads a pinhole frame. A method that needs a scene is refused with a
/// message that says what it needs.
pub fn run_frame(settings: &MethodSettings, frame: &Frame) -> Result<MethodOutput> {
    run_frame_on(settings, frame, None)
}

/// [`run_frame`] on the GPU of `gpu` (`None`: the CPU). A method without GPU passes is
/// refused on a GPU ([`check_gpu`]); one that reads a scene is refused as on the CPU.
pub fn run_frame_on(
    settings: &MethodSettings,
    frame: &Frame,
    gpu: Option<&GpuContext>,
) -> Result<MethodOutput> {
    let (c, d, l) = (frame.color, frame.depth, frame.lens);
    check_budget(settings, c.width(), c.height())?;
    // A method that reads a scene falls through to the CPU's refusal below, on any device.
    if let Some(ctx) = gpu.filter(|_| settings.info().input == InputKind::PinholeFrame) {
        check_gpu(settings.id())?;
        let out = match settings {
            MethodSettings::Hammon(s) => hammon::gpu::render(ctx, c, d, l, s),
            MethodSettings::Gaussian(s) => gaussian::gpu::render(ctx, c, d, l, s),
            MethodSettings::Poisson(s) => poisson::gpu::render(ctx, c, d, l, s),
            MethodSettings::Lowrank(s) => lowrank::gpu::render(ctx, c, d, l, s),
            other => Err(Error::invalid(
                "method",
                format!(
                    "'{}' is marked as a GPU method in the registry but has no GPU passes",
                    other.id()
                ),
            )),
        };
        ctx.check()?;
        return out;
    }
    match settings {
        MethodSettings::Hammon(s) => hammon::render(c, d, l, s),
        MethodSettings::Lowrank(s) => lowrank::render(c, d, l, s),
        MethodSettings::Gaussian(s) => gaussian::render(c, d, l, s),
        MethodSettings::Poisson(s) => poisson::render(c, d, l, s),
        MethodSettings::Splat(s) if s.layers == 1 => splat::render(c, d, l, s),
        MethodSettings::Splat(s) => Err(Error::invalid(
            "layers",
            format!(
                "{}: splatting several layers needs the fragment lists of a 3D scene (defocus render --method splat --layers {}); a colour image with a depth pass has one layer",
                s.layers, s.layers
            ),
        )),
        other => {
            let info = other.info();
            Err(Error::invalid(
                "method",
                format!(
                    "'{}' needs {}, not a colour image with a depth pass: render it from a scene (defocus render --method {})",
                    info.id,
                    info.input.describe(),
                    info.id
                ),
            ))
        }
    }
}

/// How the input of a method is made from a scene (what is not the method's own setting).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneOptions {
    /// Samples per pixel of the pinhole frame that post-process methods blur (box filter, as
    /// `pinhole --samples N`); the depth stays at pixel centres, as a renderer's Z pass.
    pub frame_samples: usize,
    /// Seed of the frame's pixel sampler.
    pub seed: u64,
    /// Also return the pinhole depth at pixel centres.
    pub with_depth: bool,
    /// What the post-process methods do where near blur uncovers what the frame hides
    /// ([`super::fill`]).
    pub occlusion: super::fill::Occlusion,
}

/// Samples per pixel of the anti-aliased pinhole frame the post-process methods blur when they
/// run on a scene. Measured on `railing` and `grass` at 640x360 (README, "Anti-aliased input"):
/// the frame is then within 0.5 dB of a 256-sample frame.
pub const DEFAULT_FRAME_SAMPLES: usize = 16;

impl Default for SceneOptions {
    fn default() -> Self {
        Self {
            frame_samples: DEFAULT_FRAME_SAMPLES,
            seed: 0,
            with_depth: false,
            occlusion: super::fill::Occlusion::None,
        }
    }
}

/// Runs any method on a scene: scene methods render it directly; post-process methods blur an
/// anti-aliased pinhole frame rendered first (its passes are timed as `pinhole/...`).
/// `progress(done, total)` reports views rendered.
pub fn run_scene(
    settings: &MethodSettings,
    scene: &Scene,
    camera: &Camera,
    options: &SceneOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<MethodOutput> {
    run_scene_on(settings, scene, camera, options, None, progress)
}

/// [`run_scene`] on the GPU of `gpu` (`None`: the CPU). A method without GPU passes is
/// refused on a GPU ([`check_gpu`]); the pinhole frame that a post-process method blurs is
/// rendered on the same GPU.
pub fn run_scene_on(
    settings: &MethodSettings,
    scene: &Scene,
    camera: &Camera,
    options: &SceneOptions,
    gpu: Option<&GpuContext>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<MethodOutput> {
    check_scene_budget(settings, scene, camera)?;
    // `auto` runs on the CPU what the GPU passes do not cover.
    let gpu = gpu.filter(|ctx| !ctx.chosen_by_auto() || runs_on_gpu(settings));
    if gpu.is_some() {
        check_gpu(settings.id())?;
    }
    match settings {
        MethodSettings::Reference(s) => {
            let s = ReferenceSettings {
                use_lens: true,
                with_depth: options.with_depth,
                ..s.clone()
            };
            reference::render_on(scene, camera, &s, gpu, progress)
        }
        MethodSettings::Pinhole(p) => {
            let s = ReferenceSettings {
                samples: p.samples,
                sampler: p.sampler,
                seed: p.seed,
                use_lens: false,
                with_depth: options.with_depth,
                ..ReferenceSettings::default()
            };
            reference::render_on(scene, camera, &s, gpu, progress)
        }
        MethodSettings::Splat(s) if s.layers > 1 => {
            let (out, _) = splat::render_scene(scene, camera, s)?;
            progress(1, 1);
            Ok(out)
        }
        MethodSettings::Multiview(s) => {
            let out = multiview::render(scene, camera, s)?;
            progress(1, 1);
            Ok(out)
        }
        MethodSettings::Multilayer(s) => {
            let out = match gpu {
                Some(ctx) => multilayer::gpu::render(ctx, scene, camera, s)?,
                None => multilayer::render(scene, camera, s)?,
            };
            progress(1, 1);
            Ok(out)
        }
        post => {
            let frame_settings = ReferenceSettings {
                samples: options.frame_samples,
                seed: options.seed,
                use_lens: false,
                with_depth: true,
                ..ReferenceSettings::default()
            };
            let pin = reference::render_on(scene, camera, &frame_settings, gpu, progress)?;
            let depth = pin.depth.ok_or_else(|| {
                Error::invalid("pinhole frame", "the pinhole pass returned no depth")
            })?;
            let lens = camera.thin_lens()?;
            let frame = Frame {
                color: &pin.image,
                depth: &depth,
                lens: &lens,
            };
            let out =
                match options.occlusion {
                    super::fill::Occlusion::None => run_frame_on(post, &frame, gpu)?,
                    super::fill::Occlusion::Fill if gpu.is_some() => return Err(Error::invalid(
                        "occlusion",
                        "fill runs on the CPU only so far: use --device cpu, or --occlusion none",
                    )),
                    super::fill::Occlusion::Fill => {
                        super::fill::run_frame(post, &frame, &super::fill::FillSettings::default())?
                    }
                };
            let mut timings = pin.timings;
            timings.extend(&out.timings);
            Ok(MethodOutput {
                image: out.image,
                depth: Some(depth),
                timings,
                memory_bytes: out.memory_bytes,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_registry_entry_has_default_settings_with_its_own_id() {
        for m in METHODS {
            let s = MethodSettings::default_for(m.id).unwrap();
            assert_eq!(s.id(), m.id);
            assert_eq!(s.info(), m);
        }
    }

    #[test]
    fn unknown_id_lists_the_known_ones() {
        let e = find("bokeh").unwrap_err().to_string();
        assert!(e.contains("bokeh") && e.contains("lowrank"), "{e}");
    }
}
