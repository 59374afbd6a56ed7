use glam::Vec2;

use super::Aperture;
use crate::random::SplitMix64;

/// Xored into the user's seed so the sampler's stream differs from other users of that seed.
pub(crate) const SAMPLER_SEED_SALT: u64 = 0x5DEE_CE66_D1CE_4E5B;
use crate::{Error, Result};

/// How lens and pixel sample points are chosen. All are deterministic for a given seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum SamplerKind {
    /// Halton sequence (bases 2, 3 for the lens; 5, 7 for the pixel; 11 for rejection),
    /// with a Cranley-Patterson rotation chosen by the seed. Low discrepancy; the default.
    #[default]
    Halton,
    /// Jittered grid over the lens (ceil(sqrt N) squared strata, N of them used in a seeded
    /// shuffled order), uniform random pixel positions.
    Stratified,
    /// Independent uniform random numbers (for comparisons; noisiest).
    Random,
}

impl SamplerKind {
    /// Parses `halton`, `stratified` or `random`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "halton" => Ok(Self::Halton),
            "stratified" => Ok(Self::Stratified),
            "random" => Ok(Self::Random),
            other => Err(Error::Unknown {
                kind: "sampler",
                name: other.to_string(),
                expected: "halton, stratified, random".into(),
            }),
        }
    }
}

/// One sample of the reference renderer: a point on the lens and a position inside the pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensSample {
    /// Point in the unit aperture, image axes (x right, y down).
    pub lens: Vec2,
    /// Offset of the sample from the pixel centre, in pixels, in [-0.5, 0.5)^2 (box filter).
    pub pixel_offset: Vec2,
}

/// A deterministic set of lens samples.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleSet {
    /// The samples, in the order they are accumulated.
    pub samples: Vec<LensSample>,
}

/// Radical inverse of `i` in base `b`, in [0, 1).
pub(crate) fn radical_inverse(mut i: u64, b: u64) -> f64 {
    let inv = 1.0 / b as f64;
    let mut f = inv;
    let mut r = 0.0;
    while i > 0 {
        r += (i % b) as f64 * f;
        i /= b;
        f *= inv;
    }
    r
}

fn rotate(x: f64, offset: f32) -> f32 {
    let v = (x as f32 + offset).fract();
    // Guard against rounding up to 1.0.
    v.min(1.0 - f32::EPSILON)
}

/// Upper bound on candidates drawn for rejection sampling (shapes covering at least 1/64 of
/// their bounding area always fill the set well before this).
const MAX_CANDIDATES_PER_SAMPLE: usize = 4096;

impl SampleSet {
    /// `count` samples covering `aperture` evenly. With `count == 1` the single sample sits at
    /// the lens centre and the pixel centre, so the result is the plain pinhole image.
    pub fn generate(
        aperture: &Aperture,
        kind: SamplerKind,
        count: usize,
        seed: u64,
    ) -> Result<Self> {
        if count == 0 {
            return Err(Error::invalid("samples", "0: expected at least 1 sample"));
        }
        aperture.validate()?;
        if count == 1 {
            return Ok(Self {
                samples: vec![LensSample {
                    lens: Vec2::ZERO,
                    pixel_offset: Vec2::ZERO,
                }],
            });
        }
        let mut rng = SplitMix64::new(seed ^ SAMPLER_SEED_SALT);
        let rot: [f32; 5] = std::array::from_fn(|_| rng.next_f32());
        // Candidate stream: index -> (lens u, pixel u, acceptance u).
        let grid = (count as f64).sqrt().ceil() as usize;
        let mut order: Vec<usize> = (0..grid * grid).collect();
        if kind == SamplerKind::Stratified {
            for i in (1..order.len()).rev() {
                let j = (rng.next_u64() % (i as u64 + 1)) as usize;
                order.swap(i, j);
            }
        }
        let candidate = |i: usize, rng: &mut SplitMix64| -> (Vec2, Vec2, f32) {
            match kind {
                SamplerKind::Halton => {
                    let i = i as u64 + 1;
                    (
                        Vec2::new(
                            rotate(radical_inverse(i, 2), rot[0]),
                            rotate(radical_inverse(i, 3), rot[1]),
                        ),
                        Vec2::new(
                            rotate(radical_inverse(i, 5), rot[2]),
                            rotate(radical_inverse(i, 7), rot[3]),
                        ),
                        rotate(radical_inverse(i, 11), rot[4]),
                    )
                }
                SamplerKind::Stratified => {
                    let cell = order[i % order.len()];
                    let (cx, cy) = (cell % grid, cell / grid);
                    (
                        Vec2::new(
                            ((cx as f32 + rng.next_f32()) / grid as f32).min(1.0 - f32::EPSILON),
                            ((cy as f32 + rng.next_f32()) / grid as f32).min(1.0 - f32::EPSILON),
                        ),
                        Vec2::new(rng.next_f32(), rng.next_f32()),
                        rng.next_f32(),
                    )
                }
                SamplerKind::Random => (
                    Vec2::new(rng.next_f32(), rng.next_f32()),
                    Vec2::new(rng.next_f32(), rng.next_f32()),
                    rng.next_f32(),
                ),
            }
        };
        let mut samples = Vec::with_capacity(count);
        let mut i = 0usize;
        while samples.len() < count {
            if i >= count * MAX_CANDIDATES_PER_SAMPLE {
                return Err(Error::invalid(
                    "aperture",
                    "the shape is too small or too dark to be sampled (under 1/4096 of its bounds)",
                ));
            }
            let (u_lens, u_pixel, u_accept) = candidate(i, &mut rng);
            i += 1;
            let lens = match aperture.warp(u_lens) {
                Some(v) => v,
                None => {
                    let v = if aperture.inside_unit_disc() {
                        super::aperture::concentric_disc(u_lens)
                    } else {
                        u_lens * 2.0 - Vec2::ONE
                    };
                    if u_accept >= aperture.density(v) {
                        continue;
                    }
                    v
                }
            };
            samples.push(LensSample {
                lens,
                pixel_offset: u_pixel - Vec2::splat(0.5),
            });
        }
        Ok(Self { samples })
    }
}
