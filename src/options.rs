//! The methods' options, as the flags of `defocus render` and `defocus blur` name them, turned
//! into validated [`MethodSettings`] in one place. The command line flattens [`PostArgs`] into
//! its commands; the Python package parses its keyword arguments with the same struct (as the
//! flags they name), so both have the same names, units, defaults and checks. Running the
//! settings is the registry's ([`crate::methods::registry`]).

use crate::lens::{Aperture, LensEffects, ThinLens};
use crate::methods::coc_map;
use crate::methods::gaussian::GaussianSettings;
use crate::methods::hammon::{CocMode, HammonSettings, LerpDistances};
use crate::methods::lowrank::LowRankSettings;
use crate::methods::multilayer::{Bokeh, BoxRead, FilterSteps, MultilayerSettings};
use crate::methods::multiview::{LayerCount, LayerOrigin, MipFilter, MultiviewSettings};
use crate::methods::poisson::{self, PoissonSettings};
use crate::methods::reference::ReferenceSettings;
use crate::methods::registry::MethodSettings;
use crate::methods::splat::SplatSettings;
use crate::raster::LayeredInput;
use anyhow::{bail, Context};
use clap::{Args, ValueEnum};

/// The result of the checks in this module: an error chain whose messages name the flag.
type Result<T> = anyhow::Result<T>;

/// Parses `--aperture`: `disc`, `poly:B[,rot=DEG][,curve=R]`, `star[:N[,INNER]]`, `heart`,
/// `ring[:INNER]`, or `image:PATH` (a greyscale image read as the aperture's density).
pub fn parse_aperture(spec: &str) -> crate::Result<Aperture> {
    use crate::lens::{ApertureImage, CustomShape};
    let invalid =
        |e: &dyn std::fmt::Display| crate::Error::Option(format!("invalid --aperture {spec}: {e}"));
    if let Some(path) = spec.strip_prefix("image:") {
        // A file that cannot be read stays an I/O error (naming the file).
        let img =
            crate::image::io::read_color(std::path::Path::new(path)).map_err(|e| match e {
                io @ crate::Error::Io { .. } => io,
                other => invalid(&other),
            })?;
        let grey = img.map(|p| crate::image::luminance([p[0], p[1], p[2]]));
        let grey = crate::image::GrayImage::from_vec(grey.width(), grey.height(), grey.into_vec())?;
        let density = ApertureImage::new(grey)
            .map_err(|e| crate::Error::Option(format!("aperture image {path}: {e}")))?;
        return Ok(Aperture::Image(std::sync::Arc::new(density)));
    }
    let name = spec.trim().split(':').next().unwrap_or("");
    if ["star", "heart", "ring"].contains(&name) {
        let shape = CustomShape::parse(spec).map_err(|e| invalid(&e))?;
        return shape.aperture();
    }
    Aperture::parse(spec).map_err(|e| invalid(&e))
}

/// Parses comma-separated finite numbers; `None` if any is not one.
pub fn parse_numbers(s: &str) -> Option<Vec<f32>> {
    s.split(',')
        .map(|p| p.trim().parse::<f32>().ok().filter(|x| x.is_finite()))
        .collect()
}

/// `--coc` of hammon.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum HammonCoc {
    /// The thin-lens CoC of the shared camera model.
    Physical,
    /// The chapter's artist curve (fig. 28-6), from --artist-near and --artist-far.
    Artist,
}

/// Largest CoC radius in pixels of the methods that clamp it (`--max-coc`), blurring one frame:
/// a compositing tool's bound on the blur's cost, as Nuke's ZDefocus and Blender's Defocus node
/// have one.
pub const DEFAULT_MAX_COC_PX: f32 = 64.0;

/// The default `--max-coc` of `splat --layers N` (N > 1, fragment lists of a scene) for a
/// `width` x `height` frame: the larger of [`DEFAULT_MAX_COC_PX`] and the guard band's bound, 1/8
/// of the longer side ([`crate::raster::GUARD_BAND_MAX_FRACTION`]), at most
/// [`coc_map::MAX_COC_LIMIT_PX`]. A scene's CoCs grow with the resolution: at 1280x720 `traps`'
/// near bars have a radius of 96 px, and 64 clamped them to a visibly sharper blur (22.2 dB
/// against `reference`, 28.2 unclamped). The methods that blur one frame keep 64: they cannot
/// show what a wider near blur reveals, and on `traps` at 1280x720 unclamped blur cost them
/// 0.2-0.7 dB.
pub fn layered_max_coc_px(width: usize, height: usize) -> f32 {
    let bound = crate::raster::GUARD_BAND_MAX_FRACTION * width.max(height) as f32;
    bound.clamp(DEFAULT_MAX_COC_PX, coc_map::MAX_COC_LIMIT_PX)
}

/// Options of the post-process methods (each applies to the methods its heading names).
#[derive(Debug, Args, Clone)]
#[command(next_help_heading = "Method options (each names the methods it applies to)")]
pub struct PostArgs {
    /// Largest CoC radius in pixels the lowrank, gaussian, poisson and splat methods blur
    /// (`None`: [`DEFAULT_MAX_COC_PX`], or for `splat`'s fragment lists [`layered_max_coc_px`]).
    #[arg(
        long,
        value_name = "PX",
        allow_negative_numbers = true,
        help = format!(
            "Largest CoC radius in pixels the lowrank, gaussian, poisson and splat methods blur; larger blurs are clamped to it (greater than 0, at most {}) [default: {DEFAULT_MAX_COC_PX}; for splat --layers N > 1, the larger of {DEFAULT_MAX_COC_PX} and 1/8 of the frame's longer side (160 at 1280x720), the guard band's bound, so that a scene's blur is the thin lens's]",
            coc_map::MAX_COC_LIMIT_PX
        )
    )]
    pub max_coc: Option<f32>,

    /// hammon, lowrank, gaussian, poisson, splat (one layer): what near blur uncovers. `none`:
    /// the frame blurred as one layer, as the papers; `fill`: split into a near layer (CoC at
    /// least 2 px in front of the focus) and a back layer filled where the near one hides it
    /// (pull-push, after Kraus and Strengert 2007), each blurred, the near one composited over
    /// the back. The methods that read a scene's hidden surfaces ignore it.
    #[arg(long, value_name = "none|fill", default_value = "none", value_parser = parse_occlusion)]
    pub occlusion: crate::methods::fill::Occlusion,

    /// hammon: depth to blur amount: `physical` (thin lens) or `artist` (fig. 28-6 curve).
    #[arg(long, value_enum, default_value_t = HammonCoc::Physical)]
    pub coc: HammonCoc,
    /// hammon, --coc artist: near blur is full up to START metres and falls to 0 at END.
    #[arg(long, value_name = "START,END", value_parser = parse_pair)]
    pub artist_near: Option<(f32, f32)>,
    /// hammon, --coc artist: far blur rises from 0 at START metres to full at END.
    #[arg(long, value_name = "START,END", value_parser = parse_pair)]
    pub artist_far: Option<(f32, f32)>,
    /// hammon: far blur radius over near blur radius (the chapter's dofEqFar.z, >= 0).
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "RATIO",
        allow_negative_numbers = true
    )]
    pub far_to_near_ratio: f32,
    /// hammon: depth in metres beyond which a pixel is sky and gets only near blur (`inf`:
    /// no sky).
    #[arg(
        long,
        default_value_t = 1e6,
        value_name = "M",
        allow_negative_numbers = true
    )]
    pub sky_depth: f32,
    /// hammon: standard deviation of the large blur in pixels of a 480-row image, scaled to
    /// the real height (the chapter's convention; 10 gives a largest CoC of about 30 px at
    /// 720 rows).
    #[arg(
        long,
        default_value_t = 10.0,
        value_name = "PX",
        allow_negative_numbers = true,
        conflicts_with = "large_blur_coc"
    )]
    pub large_blur_sigma: f32,
    /// hammon: set the large blur by its equivalent CoC radius in pixels instead, or `auto`
    /// for the lens's CoC at infinity (so the far field gets its physical blur).
    #[arg(long, value_name = "PX|auto")]
    pub large_blur_coc: Option<String>,
    /// hammon: the chapter's blend distances d0, d1, d2 (> 0, normalised to sum 1)
    /// [default: derived from the blur levels' radii, linear in CoC].
    #[arg(long, value_name = "D0,D1,D2", value_parser = parse_triple)]
    pub lerp: Option<(f32, f32, f32)>,

    /// lowrank: rank r of the separable approximation (the paper uses 3 for DoF).
    #[arg(long, default_value_t = 3, value_name = "R")]
    pub rank: usize,
    /// lowrank: spherical aberration, -1 (bright centre) to 1 (bright rim).
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "A",
        allow_negative_numbers = true
    )]
    pub aberration: f32,
    /// lowrank: side in pixels (odd) of the decomposed base kernel [default: 2 ceil(max |C|) + 1,
    /// 17 to 129].
    #[arg(long, value_name = "PX")]
    pub kernel_size: Option<usize>,
    /// lowrank: no depth-discontinuity mask and no 2D fallback (fig. 15 off).
    #[arg(long)]
    pub no_mask: bool,
    /// lowrank: a pixel is on a depth edge where its CoC differs from a neighbour's by more than
    /// this many pixels.
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "PX",
        allow_negative_numbers = true
    )]
    pub edge_threshold: f32,
    /// lowrank: a pixel gets the 2D fallback when more than this fraction of its kernel lies on
    /// depth edges (0 to 1).
    #[arg(
        long,
        default_value_t = 0.01,
        value_name = "FRACTION",
        allow_negative_numbers = true
    )]
    pub mask_threshold: f32,
    /// lowrank: taps of the 2D fallback gather on masked pixels.
    #[arg(long, default_value_t = 64, value_name = "N",
          help = format!("lowrank: taps of the 2D fallback gather on masked pixels (1 to {})", poisson::MAX_TAPS))]
    pub fallback_taps: usize,

    /// gaussian: standard deviation per pixel of CoC radius (0.5: the variance of the disc).
    #[arg(
        long,
        default_value_t = 0.5,
        value_name = "S",
        allow_negative_numbers = true
    )]
    pub sigma_per_coc: f32,

    /// poisson: taps per pixel, centre included.
    #[arg(long, default_value_t = 32, value_name = "N",
          help = format!("poisson: taps per pixel, centre included (1 to {})", poisson::MAX_TAPS))]
    pub taps: usize,

    /// splat: merge M x M fragments before distribution where the blur hides it (1, 2 or 4).
    #[arg(long, default_value_t = 1, value_name = "M", help_heading = "splat")]
    pub merge: usize,
    /// splat: fragments per pixel: 1 (default) splats the pinhole frame, N > 1 (up to 16,
    /// `render` only) the N nearest fragments of every pixel, so hidden surfaces show through
    /// near blur. multiview: the number of depth layers (1 to 64) [default: from
    /// --layer-spacing]; with --frames and a keyframed --fstop or --focus, a fixed count keeps
    /// the layers at the same depths from frame to frame (spaced layers move through the
    /// scene, which flickers).
    #[arg(long, value_name = "N", help_heading = "splat, multiview")]
    pub layers: Option<usize>,
    /// splat: fragments whose CoCs differ by at most this many pixels are one surface (summed
    /// before blending).
    #[arg(
        long,
        default_value_t = 2.0,
        value_name = "PX",
        allow_negative_numbers = true,
        help_heading = "splat"
    )]
    pub group: f32,

    /// multiview: spacing of the depth layers in pixels of CoC (the paper's delta).
    #[arg(
        long,
        default_value_t = 4.0,
        value_name = "PX",
        allow_negative_numbers = true,
        conflicts_with = "layers",
        help_heading = "multiview"
    )]
    pub layer_spacing: f32,
    /// multiview: where spaced layers' boundaries fall: `near` (from the nearest surface, the
    /// spacing as given: the paper's) or `focus` (from the nearest surface, the spacing changed
    /// by at most half so that the focal plane lies at the middle of a layer and no in-focus
    /// surface is split between two: up to 2 dB better at 640x360, up to 0.5 dB worse at
    /// 1280x720 on the built-in scenes).
    #[arg(
        long,
        default_value = "near",
        value_name = "near|focus",
        conflicts_with = "layers",
        help_heading = "multiview"
    )]
    pub layer_origin: String,
    /// multiview: no approximate cone tracing (plain rays).
    #[arg(long, help_heading = "multiview")]
    pub no_cone: bool,
    /// multiview: the paper's cone tracing, where only a ray whose centre hits a surface takes
    /// the coverage of its cone (thin objects then block too little light); by default a ray
    /// that passes a layer also takes the coverage its cone meets there.
    #[arg(long, help_heading = "multiview", conflicts_with = "no_cone")]
    pub paper_cone: bool,
    /// multiview: the paper's false-position refinement of where a ray crosses a layer's
    /// surface (three steps on a linear model of it; the hit can stay on the neighbouring
    /// pixel at an in-focus edge); by default the first point at or behind the surface as the
    /// layer stores it, walked pixel by pixel.
    #[arg(long, help_heading = "multiview")]
    pub paper_refine: bool,
    /// multiview: the cones' mipmap filter, `tent` (`[1 3 3 1]`: the same footprint wherever a
    /// read falls among the texels, so the blur does not shift with the guard band from frame
    /// to frame) or `box` (the paper's 2x2 means). Default tent, box with --paper-cone.
    #[arg(
        long,
        value_name = "box|tent",
        help_heading = "multiview",
        conflicts_with = "no_cone"
    )]
    pub cone_mipmap: Option<String>,
    /// multiview: the same lens samples for every pixel (no jitter).
    #[arg(long, help_heading = "multiview")]
    pub no_jitter: bool,
    /// multiview: no early layer culling (same image, slower).
    #[arg(long, help_heading = "multiview")]
    pub no_culling: bool,
    /// multiview: drop a surface hidden behind a nearer one of its layer, as the paper's layers
    /// do; by default one more than 2 px of CoC behind it is also written to the next layer,
    /// where a ray that passes behind the nearer surface finds it (not in the paper).
    #[arg(long, help_heading = "multiview")]
    pub no_see_behind: bool,

    /// multilayer, splat --layers N, multiview: sample the fragments and layers at pixel
    /// centres, as the papers, instead of with 16-sample coverage masks (anti-aliased edges,
    /// textures and cut-outs).
    #[arg(long, help_heading = "layered methods")]
    pub no_coverage: bool,
    /// multilayer, splat --layers N, multiview: rasterize the frame only, as the papers,
    /// instead of the frame grown by the largest CoC in view (at most 1/8 of its longer side),
    /// whose blur reaches into the frame.
    #[arg(long, help_heading = "layered methods")]
    pub no_guard_band: bool,
    /// multilayer, splat --layers N, multiview: how a minified texture is looked up with
    /// coverage masks: once a `quadrant` of the pixel, or at every covered `sample` (sharper
    /// minified textures, the pixel's mean as reference's views make it; the rasterization
    /// takes about twice as long). Default sample for multiview, quadrant for the others.
    #[arg(
        long,
        value_name = "quadrant|sample",
        help_heading = "layered methods",
        conflicts_with = "no_coverage"
    )]
    pub texture_lookups: Option<String>,
    /// multilayer, splat --layers N, multiview: fragments brighter than this linear luminance
    /// (over their coverage; 1 is white) are scattered on their own, each pixel of a light's
    /// bokeh taking it through its one lens ray with that ray's visibility past the nearer
    /// surfaces (the shadow of a near railing across the bokeh of a light behind it; for
    /// multiview, without the noise of a few rays meeting a small light), or `off`: blended or
    /// traced as every fragment, as the papers. Default 1.
    #[arg(long, value_name = "LUMINANCE|off", help_heading = "layered methods")]
    pub highlight_rays: Option<String>,

    /// multilayer: fragments kept per pixel, N.
    #[arg(
        long,
        default_value_t = 4,
        value_name = "N",
        help_heading = "multilayer",
        help = format!(
            "multilayer: fragments kept per pixel, N (1 to {}; the paper keeps 3 or 4)",
            crate::raster::MAX_FRAGMENTS_PER_PIXEL
        )
    )]
    pub fragments: usize,
    /// multilayer: depth threshold for merging fragments while filtering, relative to depth
    /// (0.05: within 5% of the nearer fragment's depth; 0 to 1).
    #[arg(
        long,
        default_value_t = 0.05,
        value_name = "REL",
        allow_negative_numbers = true,
        help_heading = "multilayer"
    )]
    pub epsilon: f32,
    /// multilayer: the Y-map, M mip-mapping steps then S stack steps (the paper's 1/3, 2/2,
    /// 4/0), or `auto`: one mip step, then stack steps until the largest CoC is covered.
    #[arg(
        long,
        default_value = "auto",
        value_name = "M/S|auto",
        help_heading = "multilayer"
    )]
    pub filter_steps: String,
    /// multilayer: keep every fragment in every level (no list truncation, section 6.2).
    #[arg(long, help_heading = "multilayer")]
    pub no_truncation: bool,
    /// multilayer: collect the fragment lists at K x K samples per pixel and merge them down
    /// (1, 2 or 4; anti-aliases the in-focus surfaces; not in the paper).
    #[arg(
        long,
        default_value_t = 1,
        value_name = "K",
        help_heading = "multilayer"
    )]
    pub ml_supersample: usize,
    /// multilayer: bokeh in the paper's `box` (each fragment from the box-filtered level that
    /// matches its CoC) or in the aperture's `shape` (--aperture; not in the paper) for CoC radii
    /// from 4.5 px; `full`: in the shape from 2.5 px (closer to `reference` where much of the
    /// frame has a blur of a few pixels, such as small frames; 10-30% more time).
    #[arg(
        long,
        default_value = Bokeh::default().name(),
        value_name = "box|shape|full",
        help_heading = "multilayer"
    )]
    pub ml_bokeh: String,
    /// multilayer: how a pixel reads the box-filtered levels coarser than a pixel (CoCs below
    /// the shape's threshold): `nearest`, the cell whose centre is nearest (the paper's; the
    /// blur comes in blocks of the level's cells), or `bilinear`, the four cells around the
    /// pixel's centre (not in the paper). `--ml-bokeh box` reads as the paper.
    #[arg(
        long,
        default_value = "bilinear",
        value_name = "nearest|bilinear",
        help_heading = "multilayer"
    )]
    pub ml_box_read: String,

    /// A lens preset: `vintage-swirl` (strong cat's eye), `anamorphic-2x` (tall oval bokeh),
    /// `apochromat` (nearly ideal), or a JSON file of your own with `description` and any of
    /// `anamorphic`, `cats_eye_mm` and `chromatic` (the flags below, in their units; see
    /// `presets/`). The flags below override it.
    #[arg(
        long,
        value_name = "PRESET|FILE.json",
        help_heading = "Lens effects (reference, multiview, poisson: all; splat, lowrank: anamorphic, chromatic)"
    )]
    pub lens: Option<String>,
    /// Anamorphic aperture: the bokeh's width over its height, its area kept (0.5: the tall
    /// ovals of a 2x anamorphic lens; 1: round). Exact in reference; multiview stretches its lens
    /// rays, poisson its taps, splat its footprints and lowrank its kernel; other methods refuse
    /// it.
    #[arg(
        long,
        value_name = "ASPECT",
        help_heading = "Lens effects (reference, multiview, poisson: all; splat, lowrank: anamorphic, chromatic)"
    )]
    pub anamorphic: Option<f32>,
    /// Cat's eye (optical vignetting): the lens barrel's front opening DIST millimetres in front
    /// of the aperture, of radius RADIUS millimetres [default: the lens radius at this
    /// f-number]. Towards the corners the bokeh is clipped into a lemon, its long side
    /// tangential; stopping down inside a larger opening fades it. Exact in reference (per
    /// view); multiview per ray and poisson per tap; other methods refuse it.
    #[arg(
        long,
        value_name = "DIST[,RADIUS]",
        value_parser = parse_cats_eye,
        help_heading = "Lens effects (reference, multiview, poisson: all; splat, lowrank: anamorphic, chromatic)"
    )]
    pub cats_eye: Option<(f32, Option<f32>)>,
    /// Chromatic aberration: red in focus DPT dioptres (1/m) nearer than green and blue as much
    /// farther (longitudinal: behind the focus the bokeh fringes red, in front of it blue), and
    /// red's aperture SCALE times green's, blue's 1/SCALE times (lateral) [default SCALE: 1].
    /// Exact in reference (a pass per channel); multiview, poisson, splat and lowrank run once
    /// per channel through its lens as well; other methods refuse it.
    #[arg(
        long,
        value_name = "DPT[,SCALE]",
        value_parser = parse_chromatic,
        allow_negative_numbers = true,
        help_heading = "Lens effects (reference, multiview, poisson: all; splat, lowrank: anamorphic, chromatic)"
    )]
    pub chromatic: Option<(f32, f32)>,
}

/// Parses `--chromatic DPT[,SCALE]`.
pub fn parse_chromatic(s: &str) -> std::result::Result<(f32, f32), String> {
    match parse_numbers(s).as_deref() {
        Some([d]) => Ok((*d, 1.0)),
        Some([d, k]) => Ok((*d, *k)),
        _ => Err(format!(
            "'{s}': expected the focus shift in dioptres, and optionally the aperture scale: DPT[,SCALE]"
        )),
    }
}

/// Parses `--cats-eye DIST[,RADIUS]` (millimetres).
pub fn parse_cats_eye(s: &str) -> std::result::Result<(f32, Option<f32>), String> {
    match parse_numbers(s).as_deref() {
        Some([d]) => Ok((*d, None)),
        Some([d, r]) => Ok((*d, Some(*r))),
        _ => Err(format!(
            "'{s}': expected the barrel's distance in millimetres, and optionally its radius: DIST[,RADIUS]"
        )),
    }
}

impl PostArgs {
    /// `--highlight-rays`, or `default` where not given.
    fn highlight_rays(&self, default: Option<f32>) -> crate::Result<Option<f32>> {
        match &self.highlight_rays {
            None => Ok(default),
            Some(s) => crate::methods::highlights::parse_threshold(s),
        }
    }

    /// The layered methods' input from `--no-coverage`, `--no-guard-band` and
    /// `--texture-lookups`, over the method's default `default`.
    fn layered_input(&self, default: LayeredInput) -> Result<LayeredInput> {
        let sample_shading = match self.texture_lookups.as_deref() {
            None => default.sample_shading,
            Some("sample") => true,
            Some("quadrant") => false,
            Some(other) => {
                bail!("invalid --texture-lookups: {other:?}: expected one of quadrant, sample")
            }
        };
        Ok(LayeredInput {
            coverage: !self.no_coverage,
            guard_band: !self.no_guard_band,
            sample_shading: !self.no_coverage && sample_shading,
        })
    }

    /// The lens effects of `--lens`, then `--anamorphic`, `--cats-eye` and `--chromatic`
    /// over it, checked.
    pub fn lens_effects(&self) -> crate::Result<LensEffects> {
        let mut effects = match &self.lens {
            Some(spec) => LensEffects::preset(spec)?.0,
            None => LensEffects::default(),
        };
        if let Some(a) = self.anamorphic {
            effects.aspect = a;
        }
        if let Some((distance_mm, radius_mm)) = self.cats_eye {
            effects.barrel_distance_m = distance_mm / 1000.0;
            effects.barrel_radius_m = radius_mm.map(|r| r / 1000.0);
        }
        if let Some((dpt, scale)) = self.chromatic {
            effects.chroma_dpt = dpt;
            effects.chroma_scale = scale;
        }
        effects.validate()?;
        Ok(effects)
    }

    /// The file `--lens` names, when it names a preset file rather than a built-in preset.
    pub fn lens_file(&self) -> Option<std::path::PathBuf> {
        self.lens
            .as_deref()
            .filter(|spec| !crate::lens::PRESETS.iter().any(|(n, _)| n == spec))
            .map(std::path::PathBuf::from)
    }

    /// True when `--large-blur-coc auto` is given (resolved against the run's lens).
    pub fn large_blur_coc_is_auto(&self) -> bool {
        self.large_blur_coc.as_deref().map(str::trim) == Some("auto")
    }

    /// The `--max-coc` given, or [`DEFAULT_MAX_COC_PX`].
    pub fn max_coc_px(&self) -> f32 {
        self.max_coc.unwrap_or(DEFAULT_MAX_COC_PX)
    }

    /// The settings of the method `method` (a registry id) for a frame `height_px` rows high, seen through `lens` (needed
    /// by `--large-blur-coc auto`), with the aperture and seed of the run. Every range is
    /// checked here, before any image is read or rendered.
    pub fn settings(
        &self,
        method: &str,
        aperture: &Aperture,
        seed: u64,
        height_px: usize,
        lens: Option<&ThinLens>,
    ) -> crate::Result<MethodSettings> {
        self.checked_settings(method, aperture, seed, height_px, lens)
            .map_err(|e| crate::Error::Option(format!("{e:#}")))
    }

    /// [`PostArgs::settings`], its error as a chain.
    fn checked_settings(
        &self,
        method: &str,
        aperture: &Aperture,
        seed: u64,
        height_px: usize,
        lens: Option<&ThinLens>,
    ) -> Result<MethodSettings> {
        let settings = self.settings_of(method, aperture, seed, height_px, lens)?;
        crate::methods::registry::check_effects(method, &self.lens_effects()?)?;
        // The flags of the other methods are range-checked too: a bad value is a mistake
        // whichever method runs (`--max-coc nan` with `hammon` is refused, not ignored).
        for other in crate::methods::registry::ids() {
            if other == method {
                continue;
            }
            // `--large-blur-coc auto` is resolved against the lens of a `hammon` run only.
            if other == "hammon" && lens.is_none() && self.large_blur_coc_is_auto() {
                continue;
            }
            self.settings_of(other, aperture, seed, height_px, lens)
                .with_context(|| {
                    format!("a flag of method {other} (not the one run, {method}) is out of range")
                })?;
        }
        Ok(settings)
    }

    /// [`PostArgs::settings`] of one method, without checking the flags of the others.
    fn settings_of(
        &self,
        method: &str,
        aperture: &Aperture,
        seed: u64,
        height_px: usize,
        lens: Option<&ThinLens>,
    ) -> Result<MethodSettings> {
        let s = match method {
            "hammon" => {
                let mut h = HammonSettings {
                    far_to_near_ratio: self.far_to_near_ratio,
                    sky_depth_m: self.sky_depth,
                    large_blur_sigma_480p_px: self.large_blur_sigma,
                    ..HammonSettings::default()
                };
                h.coc = match self.coc {
                    HammonCoc::Physical => {
                        if self.artist_near.is_some() || self.artist_far.is_some() {
                            bail!("--artist-near / --artist-far need --coc artist");
                        }
                        CocMode::Physical
                    }
                    HammonCoc::Artist => {
                        let (Some(near), Some(far)) = (self.artist_near, self.artist_far) else {
                            bail!("--coc artist needs --artist-near START,END and --artist-far START,END (metres)");
                        };
                        CocMode::Artist {
                            near_start_m: near.0,
                            near_end_m: near.1,
                            far_start_m: far.0,
                            far_end_m: far.1,
                        }
                    }
                };
                h.lerp = self.lerp.map(|(d0, d1, d2)| LerpDistances { d0, d1, d2 });
                h.validate().context("invalid hammon option")?;
                if let Some(spec) = &self.large_blur_coc {
                    let px = if spec.trim() == "auto" {
                        lens.map(|l| l.coc_at_infinity_px()).context(
                            "--large-blur-coc auto needs a lens (give --focal-length, --fstop, --focus)",
                        )?
                    } else {
                        spec.trim().parse::<f32>().map_err(|_| {
                            anyhow::anyhow!(
                                "invalid --large-blur-coc '{spec}': expected a radius in pixels or auto"
                            )
                        })?
                    };
                    h.set_large_blur_coc_px(px, height_px)
                        .context("invalid --large-blur-coc")?;
                }
                MethodSettings::Hammon(h)
            }
            "lowrank" => {
                let l = LowRankSettings {
                    aperture: aperture.clone(),
                    rank: self.rank,
                    aberration: self.aberration,
                    kernel_size_px: self.kernel_size,
                    use_mask: !self.no_mask,
                    edge_threshold_px: self.edge_threshold,
                    mask_threshold: self.mask_threshold,
                    fallback_taps: self.fallback_taps,
                    seed,
                    max_coc_px: self.max_coc_px(),
                    effects: self.lens_effects()?,
                    ..LowRankSettings::default()
                };
                if let Some(k) = self.kernel_size {
                    if self.rank > k {
                        bail!(
                            "--rank {} (the default is 3) needs a kernel of at least {} px, but --kernel-size is {k}: raise --kernel-size or lower --rank",
                            self.rank,
                            self.rank
                        );
                    }
                }
                l.validate().context("invalid lowrank option")?;
                // The kernel's own checks (odd size, in range), before any frame is read.
                l.kernel_spec(0.0)
                    .validate()
                    .context("invalid --kernel-size")?;
                check_taps("--fallback-taps", self.fallback_taps)?;
                MethodSettings::Lowrank(l)
            }
            "gaussian" => {
                let g = GaussianSettings {
                    sigma_per_coc: self.sigma_per_coc,
                    max_coc_px: self.max_coc_px(),
                    ..GaussianSettings::default()
                };
                g.validate().context("invalid gaussian option")?;
                MethodSettings::Gaussian(g)
            }
            "poisson" => {
                coc_map::check_max_coc(self.max_coc_px()).context("invalid --max-coc")?;
                check_taps("--taps", self.taps)?;
                MethodSettings::Poisson(PoissonSettings {
                    aperture: aperture.clone(),
                    taps: self.taps,
                    seed,
                    max_coc_px: self.max_coc_px(),
                    effects: self.lens_effects()?,
                })
            }
            "splat" => {
                let layers = self.layers.unwrap_or(1);
                // From fragment lists (a scene) the blur is the lens's, up to the guard band's
                // bound; from one frame, a compositing tool's bound.
                let max_coc_px = match (self.max_coc, lens) {
                    (None, Some(lens)) if layers > 1 => {
                        layered_max_coc_px(lens.width_px, lens.height_px)
                    }
                    _ => self.max_coc_px(),
                };
                let sp = SplatSettings {
                    aperture: aperture.clone(),
                    merge: self.merge,
                    layers,
                    group_px: self.group,
                    max_coc_px,
                    input: self.layered_input(SplatSettings::default().input)?,
                    effects: self.lens_effects()?,
                    highlights: self.highlight_rays(SplatSettings::default().highlights)?,
                };
                sp.validate().context("invalid splat option")?;
                MethodSettings::Splat(sp)
            }
            "multiview" => {
                let mv = MultiviewSettings {
                    aperture: aperture.clone(),
                    seed,
                    layers: match self.layers {
                        Some(n) => LayerCount::Count(n),
                        None => LayerCount::Spacing {
                            spacing_px: self.layer_spacing,
                        },
                    },
                    layer_origin: LayerOrigin::parse(&self.layer_origin)
                        .context("invalid --layer-origin")?,
                    cone: !self.no_cone,
                    graze: !self.paper_cone,
                    paper_refine: self.paper_refine,
                    highlights: self.highlight_rays(MultiviewSettings::default().highlights)?,
                    mip_filter: match &self.cone_mipmap {
                        Some(name) => MipFilter::parse(name).context("invalid --cone-mipmap")?,
                        None if self.paper_cone => MipFilter::Box,
                        None => MipFilter::default(),
                    },
                    jitter: !self.no_jitter,
                    culling: !self.no_culling,
                    see_behind: !self.no_see_behind,
                    input: self.layered_input(MultiviewSettings::default().input)?,
                    effects: self.lens_effects()?,
                    ..MultiviewSettings::default()
                };
                mv.validate().context("invalid multiview option")?;
                MethodSettings::Multiview(mv)
            }
            "multilayer" => {
                let m = MultilayerSettings {
                    fragments: self.fragments,
                    epsilon: self.epsilon,
                    filter_steps: FilterSteps::parse(&self.filter_steps)
                        .context("invalid --filter-steps")?,
                    truncation: !self.no_truncation,
                    supersample: self.ml_supersample,
                    input: self.layered_input(MultilayerSettings::default().input)?,
                    bokeh: Bokeh::parse(&self.ml_bokeh).context("invalid --ml-bokeh")?,
                    aperture: aperture.clone(),
                    highlights: self.highlight_rays(MultilayerSettings::default().highlights)?,
                    box_read: BoxRead::parse(&self.ml_box_read).context("invalid --ml-box-read")?,
                };
                m.validate().context("invalid multilayer option")?;
                MethodSettings::Multilayer(m)
            }
            "reference" => MethodSettings::Reference(ReferenceSettings {
                effects: self.lens_effects()?,
                ..ReferenceSettings::default()
            }),
            other => MethodSettings::default_for(other)?,
        };
        Ok(s)
    }
}

fn check_taps(flag: &str, n: usize) -> Result<()> {
    if !(1..=poisson::MAX_TAPS).contains(&n) {
        bail!("invalid {flag} {n}: expected 1 to {}", poisson::MAX_TAPS);
    }
    Ok(())
}

/// Parses `A,B` (two finite numbers).
pub fn parse_pair(s: &str) -> std::result::Result<(f32, f32), String> {
    match parse_numbers(s).as_deref() {
        Some([a, b]) => Ok((*a, *b)),
        _ => Err(format!("'{s}': expected two numbers A,B")),
    }
}

/// Parses `A,B,C` (three finite numbers).
pub fn parse_triple(s: &str) -> std::result::Result<(f32, f32, f32), String> {
    match parse_numbers(s).as_deref() {
        Some([a, b, c]) => Ok((*a, *b, *c)),
        _ => Err(format!("'{s}': expected three numbers A,B,C")),
    }
}

/// `--occlusion`: `none` or `fill`.
fn parse_occlusion(s: &str) -> std::result::Result<crate::methods::fill::Occlusion, String> {
    crate::methods::fill::Occlusion::parse(s).map_err(|e| e.to_string())
}
