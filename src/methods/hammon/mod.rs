//! `hammon`: post-process depth of field by blending blur levels, with a blurred near CoC so
//! that out-of-focus foreground objects spread over what lies behind them.
//!
//! Earl Hammon Jr., "Practical Post-Process Depth of Field", GPU Gems 3, chapter 28 (2007):
//! section 28.4 (the near-CoC trick `D = 2 max(D0, DB) - D0`) and section 28.5 with
//! Listings 28-1 to 28-4 (the passes). Input: a pinhole colour image (linear, premultiplied
//! RGBA) and its view-axis depth in metres. The passes run on the CPU, rows in parallel, and
//! on the GPU ([`gpu`], WGSL compute shaders under the same pass names).
//!
//! # Passes, in order (each timed as `hammon/<pass>`, one file each)
//! The signed blur amount `s` of a pixel, in [-1, 1], is `-near` in front of the in-focus
//! range, `+far * far_to_near_ratio` behind it, 0 for sky (depth > `sky_depth_m`); 1 means
//! "the large blur". It comes from either the artist curve of fig. 28-6 or the thin-lens CoC
//! ([`crate::lens::ThinLens::coc_px`]), see [`CocMode`]. [`coc`] (section 28.5.3) holds its
//! function and the depth validation (finite or +inf, > 0). As in the chapter's shaders, the
//! two full-resolution passes compute it from depth row by row where they read it
//! ([`coc::Amounts::Depth`]); [`coc::coc`] makes a whole image of it, which both passes also
//! accept.
//! 1. [`downsample`] (Listing 28-1): reads colour and depth; writes a 1/4 x 1/4 image: the mean
//!    RGBA of each 4x4 block and the MAX near CoC of its 16 pixels ("shrunk").
//! 2. [`blur`] (section 28.5.5): reads the shrunk image; writes its Gaussian blur, colour and
//!    near CoC together ("large blur" colour, and the blurred CoC `DB`).
//! 3. [`near_coc`] (Listings 28-2, 28-3): reads shrunk and blurred; writes
//!    `D = 2 max(DB, D0) - D0` (clamped to [0, 1]) with the shrunk colour, then its 3x3
//!    [1 2 1]^2/16 blur: the "medium blur" colour with the final near CoC.
//! 4. [`composite`] (Listing 28-4): reads colour, depth, medium and large; writes the output.
//!    Small blur = the 17 pixels of fig. 28-5 (four bilinear taps and the centre); medium and
//!    large are sampled bilinearly; `t = max(near, far)`; colour = the piecewise-linear blend of
//!    unblurred / small / medium / large by `t` with the weights of `dofLerpScale/Bias`.
//!
//! # Blur levels and the physical CoC
//! The chapter blends four levels by `t` in [0, 1]. We give each level an *equivalent CoC
//! radius*: the radius of the uniform disc with the same per-axis variance (a disc of radius R
//! has variance R²/4, so R = 2σ). The variances add along each level's chain of filters:
//! - small: the 17-tap pattern has variance 24/17 = 1.41 px² per axis, R = 2.38 px
//!   ([`SMALL_BLUR_COC_PX`]; the chapter's "1.4 pixel Gaussian" matches this variance);
//! - medium: 4x4 box (1.25 px²) + 3x3 blur at 1/4 res (0.5 texel² = 8 px²) + bilinear upsample
//!   (2.75 px², mean over the four phases) = 12 px², σ = 3.46 px, R = 6.93 px
//!   ([`MEDIUM_BLUR_COC_PX`]; the chapter measured a "3.6 pixel Gaussian");
//! - large: 1.25 + 16 var(kernel) + 2.75 px², 30.1 px at 1280x720 with the defaults
//!   ([`HammonSettings::large_blur_coc_px`]; about 20 px at 480p, 45 px at 1080p).
//!
//! The test `blur_levels_match_their_stated_coc_radii` measures these second moments on the
//! passes' impulse responses.
//!
//! In [`CocMode::Physical`], `t = |C(z)| / R_large`, clamped to 1: the largest blur is the
//! large level. Unless [`HammonSettings::lerp`] is given, the blend distances are derived from
//! the level radii, `d0 = R_small / R_large`, `d1 = (R_medium - R_small) / R_large`,
//! `d2 = 1 - d0 - d1`, so a pixel whose |C| equals a level's radius gets exactly that level and
//! the blend in between is linear in |C|. The chapter leaves d0..d2 to the artist.
//!
//! # Where we differ from the chapter, and why
//! - The weapon (view-model) curve of section 28.5.4, selected by negative depth, is omitted:
//!   depth must be positive.
//! - The large Gaussian is a truncated Gaussian (radius ceil(3σ) quarter-res texels, clamp to
//!   edge), applied as one fused vertical-then-horizontal pass per output row instead of the
//!   chapter's bilinear-tap passes: on a CPU each tap costs the same, and the fused row pass
//!   keeps everything in cache. Its σ never drops below one quarter-res texel (below about
//!   190 image rows the scaled radius would otherwise be no larger than the medium level).
//! - Widths and heights need not be multiples of 4: the last 4x4 block is partial and averages
//!   the pixels it has; quarter texel j is sampled as if centred at full-res position 4j + 2.
//!   All image borders clamp to edge, as texture addressing does.
//! - Premultiplied RGBA is blurred in all four channels (the chapter treats alpha as 1); the
//!   chapter's "alpha-blend the centre sample with the frame buffer" is written out as a sum of
//!   weighted levels.
//! - The final blend finds the segment of `t` and lerps the two levels that have weight there,
//!   which is what `dofLerpScale/Bias` and the two `min`s compute (the test against
//!   [`composite::naive`], which keeps the listing's form, checks it). Measured on the
//!   benchmark frame: the listing's form with branches on the clamped weights was slowest
//!   (they mispredict where `t` varies); written branch-free it still ran about 270
//!   instructions per blurred pixel (callgrind: 76 M per frame); the segment form runs 58 M per
//!   frame in a quarter less CPU time. Pixels in focus (t <= 0) are copied, so a frame entirely
//!   in focus comes back bit for bit.
//!
//! # Cost
//! Criterion medians at 1280x720 on the 2-core development machine (`benches/hammon.rs`, a
//! procedural frame with sky, a receding far field, an in-focus band and a near disc; every row
//! pass compiled for AVX-512, AVX2 and NEON and chosen at run time): `downsample` 0.70 ms
//! (0.58 ms from a CoC image), `blur` 0.41 ms, `near_coc` 0.17 ms, `composite` 1.98 ms, total
//! 3.19 ms, against 1.31-1.38 ms for the memory floor (read colour + depth, write one colour
//! image: `memory_floor/1280x720`), a ratio of 2.3-2.4. The composite alone moves the floor's
//! traffic, and the downsample reads colour and depth once more, so this structure costs at
//! least 1.5 floors before any arithmetic. Both the composite and that floor then wrote into a
//! zero-filled frame; now both write straight into fresh memory (`Image::par_from_rows` for
//! the composite). On a second machine (AMD EPYC, 32 MB L3) that took the composite from
//! 2.21-2.83 to 1.74-2.21 ms, the total from 4.19-5.30 to 3.19-3.56 ms, and the floor from
//! 1.21-1.53 to 0.74-0.81 ms: 4.3-4.4 floors. With a separate CoC pass writing a
//! full-resolution image (as before), the total was 3.85 ms: computing the CoC a row at a time
//! inside both passes saves that image's write and two reads. Computed pixel by pixel inside
//! the old per-pixel loops it had been slower (4.3 -> 4.7 ms). The chapter measured 1 - 1.5 ms
//! at 1024x768 on a 2006 GPU.
//!
//! Every output row depends only on inputs, never on another thread's work, so the output is
//! bit-identical whatever the number of threads.

pub mod blur;
pub mod coc;
pub mod composite;
pub mod downsample;
pub mod gpu;
pub mod near_coc;

use crate::image::{ColorImage, GrayImage};
use crate::lens::ThinLens;
use crate::timing::Timings;
use crate::{Error, Result};

use super::MethodOutput;

/// Equivalent CoC radius in pixels of the small blur (the 17 texels of fig. 28-5): per-axis
/// variance 24/17 px², radius `2 sqrt(24/17)`.
pub const SMALL_BLUR_COC_PX: f32 = 2.376_354;

/// Equivalent CoC radius in pixels of the medium blur (4x4 box, 3x3 blur at 1/4 resolution,
/// bilinear upsample): per-axis variance 12 px², radius `2 sqrt(12)`.
pub const MEDIUM_BLUR_COC_PX: f32 = 6.928_203;

/// Smallest standard deviation of the large Gaussian, in quarter-resolution texels.
pub const MIN_LARGE_BLUR_SIGMA_QUARTER_PX: f32 = 1.0;

/// Largest accepted [`HammonSettings::large_blur_sigma_480p_px`], in pixels at 480p: twice the
/// image height, far beyond any useful blur, and a bound on the kernel's size.
pub const MAX_LARGE_BLUR_SIGMA_480P_PX: f32 = 1000.0;

/// Image height, in rows, at which [`HammonSettings::large_blur_sigma_480p_px`] is given.
pub const REFERENCE_HEIGHT_PX: f32 = 480.0;

/// Per-axis variance in px² added by the 4x4 box downsample (`(4² - 1) / 12`).
const DOWNSAMPLE_VARIANCE_PX2: f64 = 1.25;
/// Per-axis variance in px² added by the 4x bilinear upsample, averaged over the four phases.
const UPSAMPLE_VARIANCE_PX2: f64 = 2.75;

/// How depth becomes a blur amount.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CocMode {
    /// The thin lens of `DESIGN.md`: `t = |C(z)| / R_large` clamped to 1, with `C` from
    /// [`ThinLens::coc_px`] and `R_large` = [`HammonSettings::large_blur_coc_px`]. Near when
    /// `C < 0` (in front of the focal plane), far when `C > 0`.
    Physical,
    /// The artist curve of fig. 28-6 (section 28.5.3): near blur 1 up to `near_start_m`, falling
    /// linearly to 0 at `near_end_m`; far blur 0 up to `far_start_m`, rising to 1 at `far_end_m`
    /// and staying there. Distances are view-axis depths in metres, with
    /// `near_start_m <= near_end_m <= far_start_m <= far_end_m`; equal start and end disable that
    /// side (no near or no far blur), as the chapter does for degenerate ranges.
    Artist {
        /// Depth in metres at and before which the near blur is full (1).
        near_start_m: f32,
        /// Depth in metres where the near blur reaches 0 (start of the in-focus range).
        near_end_m: f32,
        /// Depth in metres where the far blur starts to rise from 0 (end of the in-focus range).
        far_start_m: f32,
        /// Depth in metres at and beyond which the far blur is full (1).
        far_end_m: f32,
    },
}

/// The chapter's blend distances (comment of `InterpolateDof`, Listing 28-4): the fade from
/// unblurred to small blur happens over `d0` of the blur amount `t`, small to medium over `d1`,
/// medium to large over `d2`. Dimensionless, each > 0; they are divided by their sum, so
/// `d0 + d1 + d2 = 1` as the chapter requires.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LerpDistances {
    /// Width in `t` of the fade unblurred -> small.
    pub d0: f32,
    /// Width in `t` of the fade small -> medium.
    pub d1: f32,
    /// Width in `t` of the fade medium -> large.
    pub d2: f32,
}

impl LerpDistances {
    /// `dofLerpScale` and `dofLerpBias` of Listing 28-4: the weights of unblurred, small, medium
    /// and large before the `min` step are `saturate(t * scale + bias)`.
    pub fn scale_bias(&self) -> ([f32; 4], [f32; 4]) {
        let Self { d0, d1, d2 } = *self;
        (
            [-1.0 / d0, -1.0 / d1, -1.0 / d2, 1.0 / d2],
            [1.0, (1.0 - d2) / d1, 1.0 / d2, (d2 - 1.0) / d2],
        )
    }
}

/// Every parameter of the chapter (GPU Gems 3 ch. 28), with units and defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HammonSettings {
    /// Depth to blur amount: thin lens or artist curve. Default [`CocMode::Physical`] (the
    /// chapter uses the artist curve and gives no distances: they are per scene).
    pub coc: CocMode,
    /// `dofEqFar.z`: far blur radius over near blur radius (dimensionless, >= 0); the far blur
    /// amount is multiplied by it. Default 1, which keeps [`CocMode::Physical`] physical.
    pub far_to_near_ratio: f32,
    /// Depth in metres beyond which a pixel is sky and gets no far blur (only the near blur of
    /// foreground objects spreading over it). Default 1e6, the chapter's constant; +inf blurs
    /// the sky like any far surface.
    pub sky_depth_m: f32,
    /// Standard deviation of the large Gaussian in pixels of a 480-row image (the chapter
    /// specifies its radius "in pixels at a normalised 480p resolution"); it is scaled by
    /// `height / 480` and applied at 1/4 resolution. Default 10 px: 2.5 quarter-res texels,
    /// truncated at 3σ = 17 taps at 480p, the chapter's typical "17 taps" (section 28.6).
    pub large_blur_sigma_480p_px: f32,
    /// Blend distances d0, d1, d2. Default `None`: derived from the equivalent CoC radii of the
    /// levels so that the blend is linear in CoC radius (see the module documentation).
    pub lerp: Option<LerpDistances>,
}

impl Default for HammonSettings {
    fn default() -> Self {
        Self {
            coc: CocMode::Physical,
            far_to_near_ratio: 1.0,
            sky_depth_m: 1e6,
            large_blur_sigma_480p_px: 10.0,
            lerp: None,
        }
    }
}

impl HammonSettings {
    /// Standard deviation of the large Gaussian in quarter-resolution texels for an image
    /// `height_px` rows high (at least [`MIN_LARGE_BLUR_SIGMA_QUARTER_PX`]).
    pub fn large_blur_sigma_quarter_px(&self, height_px: usize) -> f32 {
        let sigma_full = self.large_blur_sigma_480p_px * height_px as f32 / REFERENCE_HEIGHT_PX;
        (0.25 * sigma_full).max(MIN_LARGE_BLUR_SIGMA_QUARTER_PX)
    }

    /// Equivalent CoC radius in pixels of the large blur level for an image `height_px` rows
    /// high: the |C| that maps to full blur in [`CocMode::Physical`], and the largest blur the
    /// method can show.
    pub fn large_blur_coc_px(&self, height_px: usize) -> f32 {
        let kernel = blur::gaussian_kernel(self.large_blur_sigma_quarter_px(height_px));
        large_level_coc_px(&kernel)
    }

    /// Sets [`Self::large_blur_sigma_480p_px`] so that [`Self::large_blur_coc_px`] is `coc_px`
    /// for an image `height_px` rows high (e.g. the lens's CoC at infinity, to give the far
    /// field its physical blur). Values below the smallest large blur (about 8.9 px) give the
    /// smallest; values above the largest (sigma [`MAX_LARGE_BLUR_SIGMA_480P_PX`]) are an error.
    pub fn set_large_blur_coc_px(&mut self, coc_px: f32, height_px: usize) -> Result<()> {
        if !(coc_px.is_finite() && coc_px > 0.0) {
            return Err(Error::invalid(
                "large blur CoC",
                format!("{coc_px} px: expected a finite radius greater than 0"),
            ));
        }
        crate::image::check_size(1, height_px)?;
        // Bisection on sigma: the equivalent radius grows monotonically with it.
        let radius_at = |sigma_480p: f32| {
            let s = Self {
                large_blur_sigma_480p_px: sigma_480p,
                ..*self
            };
            s.large_blur_coc_px(height_px)
        };
        let (mut lo, mut hi) = (0.0f32, MAX_LARGE_BLUR_SIGMA_480P_PX);
        let largest = radius_at(hi);
        if largest < coc_px {
            return Err(Error::invalid(
                "large blur CoC",
                format!(
                    "{coc_px} px: the largest blur at {height_px} rows is {largest} px \
                     (large blur sigma {MAX_LARGE_BLUR_SIGMA_480P_PX} px at 480p)"
                ),
            ));
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if radius_at(mid) < coc_px {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        self.large_blur_sigma_480p_px = hi;
        Ok(())
    }

    /// Checks every field: finite, in range, artist distances in order.
    pub fn validate(&self) -> Result<()> {
        let check = |name: &'static str, v: f32, ok: bool, expected: &str| -> Result<()> {
            if ok {
                Ok(())
            } else {
                Err(Error::invalid(name, format!("{v}: expected {expected}")))
            }
        };
        let r = self.far_to_near_ratio;
        check(
            "far-to-near blur ratio",
            r,
            r.is_finite() && r >= 0.0,
            "a finite ratio >= 0",
        )?;
        let s = self.sky_depth_m;
        check(
            "sky depth",
            s,
            s > 0.0,
            "a distance in metres greater than 0 (inf: no sky)",
        )?;
        let g = self.large_blur_sigma_480p_px;
        check(
            "large blur sigma",
            g,
            (0.0..=MAX_LARGE_BLUR_SIGMA_480P_PX).contains(&g),
            "a standard deviation in pixels at 480p, from 0 to 1000",
        )?;
        if let Some(d) = self.lerp {
            for (name, v) in [
                ("blend distance d0", d.d0),
                ("blend distance d1", d.d1),
                ("blend distance d2", d.d2),
            ] {
                check(name, v, v.is_finite() && v > 0.0, "a finite value > 0")?;
            }
        }
        if let CocMode::Artist {
            near_start_m,
            near_end_m,
            far_start_m,
            far_end_m,
        } = self.coc
        {
            let ds = [near_start_m, near_end_m, far_start_m, far_end_m];
            if !ds.iter().all(|d| d.is_finite() && *d >= 0.0)
                || !ds.windows(2).all(|p| p[0] <= p[1])
            {
                return Err(Error::invalid(
                    "artist CoC distances",
                    format!(
                        "near start {near_start_m} m, near end {near_end_m} m, far start \
                         {far_start_m} m, far end {far_end_m} m: expected finite distances \
                         >= 0 with near start <= near end <= far start <= far end"
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Equivalent CoC radius in pixels of the large level whose quarter-res Gaussian is `kernel`.
fn large_level_coc_px(kernel: &[f32]) -> f32 {
    let r = (kernel.len() / 2) as f64;
    let var_quarter: f64 = kernel
        .iter()
        .enumerate()
        .map(|(i, &w)| w as f64 * (i as f64 - r).powi(2))
        .sum();
    let var_px = DOWNSAMPLE_VARIANCE_PX2 + 16.0 * var_quarter + UPSAMPLE_VARIANCE_PX2;
    (2.0 * var_px.sqrt()) as f32
}

/// Depth-to-blur constants of one frame.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Curve {
    /// `t = C(z) / R_large` from the lens.
    Physical {
        lens: ThinLens,
        inv_large_blur_coc_px: f32,
    },
    /// `near = saturate(near_scale z + near_bias)`, `far = saturate(far_scale z + far_bias)`
    /// (`dofEqWorld` and `dofEqFar.xy`); scale and bias 0 disable a side.
    Artist {
        near_scale: f32,
        near_bias: f32,
        far_scale: f32,
        far_bias: f32,
    },
}

/// The per-frame constants derived once from [`HammonSettings`] and the lens (the chapter's
/// shader constants): depth-to-blur curve, Gaussian kernel, blend scale and bias.
#[derive(Clone, Debug)]
pub struct Constants {
    width: usize,
    height: usize,
    pub(crate) curve: Curve,
    pub(crate) far_to_near_ratio: f32,
    pub(crate) sky_depth_m: f32,
    kernel: Vec<f32>,
    lerp: LerpDistances,
    large_blur_coc_px: f32,
}

impl Constants {
    /// Validates `settings` and derives the constants for a `width` x `height` frame. In
    /// [`CocMode::Physical`] the lens must have the same size as the frame.
    pub fn new(
        settings: &HammonSettings,
        lens: &ThinLens,
        width: usize,
        height: usize,
    ) -> Result<Self> {
        crate::image::check_size(width, height)?;
        settings.validate()?;
        let kernel = blur::gaussian_kernel(settings.large_blur_sigma_quarter_px(height));
        let large_blur_coc_px = large_level_coc_px(&kernel);
        let curve = match settings.coc {
            CocMode::Physical => {
                if lens.width_px != width || lens.height_px != height {
                    return Err(Error::Mismatch(format!(
                        "the lens is set up for {}x{} pixels but the image is {width}x{height}",
                        lens.width_px, lens.height_px
                    )));
                }
                Curve::Physical {
                    lens: *lens,
                    inv_large_blur_coc_px: 1.0 / large_blur_coc_px,
                }
            }
            CocMode::Artist {
                near_start_m,
                near_end_m,
                far_start_m,
                far_end_m,
            } => {
                // Near: 1 at near_start, 0 at near_end. Far: 0 at far_start, 1 at far_end.
                // A degenerate range (start == end) gives scale and bias 0: no blur on that side.
                let (near_scale, near_bias) = if near_end_m > near_start_m {
                    let scale = -1.0 / (near_end_m - near_start_m);
                    (scale, -near_end_m * scale)
                } else {
                    (0.0, 0.0)
                };
                let (far_scale, far_bias) = if far_end_m > far_start_m {
                    let scale = 1.0 / (far_end_m - far_start_m);
                    (scale, -far_start_m * scale)
                } else {
                    (0.0, 0.0)
                };
                Curve::Artist {
                    near_scale,
                    near_bias,
                    far_scale,
                    far_bias,
                }
            }
        };
        let lerp = match settings.lerp {
            Some(d) => {
                let sum = d.d0 + d.d1 + d.d2;
                LerpDistances {
                    d0: d.d0 / sum,
                    d1: d.d1 / sum,
                    d2: d.d2 / sum,
                }
            }
            None => {
                let r = large_blur_coc_px;
                let d0 = SMALL_BLUR_COC_PX / r;
                let d1 = (MEDIUM_BLUR_COC_PX - SMALL_BLUR_COC_PX) / r;
                LerpDistances {
                    d0,
                    d1,
                    d2: 1.0 - d0 - d1,
                }
            }
        };
        let (lerp_scale, lerp_bias) = lerp.scale_bias();
        if !lerp_scale.iter().chain(&lerp_bias).all(|v| v.is_finite()) {
            return Err(Error::invalid(
                "blend distances",
                format!("{lerp:?}: too small to divide by"),
            ));
        }
        Ok(Self {
            width,
            height,
            curve,
            far_to_near_ratio: settings.far_to_near_ratio,
            sky_depth_m: settings.sky_depth_m,
            kernel,
            lerp,
            large_blur_coc_px,
        })
    }

    /// Frame width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Frame height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The large Gaussian's weights over quarter-res texels `-r..=r`, summing to 1.
    pub fn kernel(&self) -> &[f32] {
        &self.kernel
    }

    /// The blend distances in use, normalised to `d0 + d1 + d2 = 1`.
    pub fn lerp_distances(&self) -> LerpDistances {
        self.lerp
    }

    /// Equivalent CoC radius in pixels of the large blur level (see
    /// [`HammonSettings::large_blur_coc_px`]).
    pub fn large_blur_coc_px(&self) -> f32 {
        self.large_blur_coc_px
    }
}

/// A quarter-resolution image (1/4 per axis, rounded up): premultiplied RGBA and the near CoC
/// (blur amount in [0, 1]), as the chapter's RGBA render targets hold colour and CoC.
#[derive(Clone, Debug, PartialEq)]
pub struct QuarterImage {
    /// Linear premultiplied RGBA.
    pub color: ColorImage,
    /// Near blur amount in [0, 1] (the chapter's alpha channel).
    pub coc: GrayImage,
}

impl QuarterImage {
    /// Width in quarter-res texels.
    pub fn width(&self) -> usize {
        self.color.width()
    }

    /// Height in quarter-res texels.
    pub fn height(&self) -> usize {
        self.color.height()
    }

    /// Fails unless colour and CoC have the same, non-zero size.
    pub fn check(&self) -> Result<()> {
        if !self.color.same_size(&self.coc) {
            return Err(Error::Mismatch(format!(
                "quarter-res colour is {}x{} but its CoC is {}x{}",
                self.color.width(),
                self.color.height(),
                self.coc.width(),
                self.coc.height()
            )));
        }
        crate::image::check_size(self.width(), self.height())
    }
}

/// Size of the quarter-resolution images for a `width` x `height` frame: each side divided by
/// 4, rounded up.
pub fn quarter_size(width: usize, height: usize) -> (usize, usize) {
    (width.div_ceil(4), height.div_ceil(4))
}

/// Renders depth of field from a pinhole `color` image (linear, premultiplied RGBA) and its
/// view-axis `depth` in metres (> 0; +inf for sky), passes timed as `hammon/<pass>`.
///
/// Fails with [`Error::Mismatch`] if the sizes differ (or, in [`CocMode::Physical`], if the
/// lens is set up for another size), and [`Error::Invalid`] for a depth that is NaN, zero or
/// negative, naming the pixel, or for invalid settings.
pub fn render(
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
    let constants = Constants::new(settings, lens, color.width(), color.height())?;
    let mut timings = Timings::default();
    // The signed blur amounts are computed from depth where downsample and composite read
    // them, as the chapter's shaders do: no full-resolution image of them is written.
    let amounts = coc::Amounts::Depth(depth, &constants);
    let shrunk = timings.time("hammon/downsample", || {
        downsample::downsample(color, amounts)
    })?;
    let blurred = timings.time("hammon/blur", || blur::blur(&shrunk, constants.kernel()))?;
    let medium = timings.time("hammon/near_coc", || near_coc::near_coc(&shrunk, &blurred))?;
    let image = timings.time("hammon/composite", || {
        composite::composite(color, amounts, &medium, &blurred, &constants)
    })?;
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}

/// `x` clamped to [0, 1]; NaN gives 0 (`saturate` in HLSL).
#[inline(always)]
pub(crate) fn saturate(x: f32) -> f32 {
    // Not `clamp`, which keeps NaN.
    if x > 0.0 {
        x.min(1.0)
    } else {
        0.0
    }
}
