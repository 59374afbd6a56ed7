//! Gather tap sets: best-candidate (Mitchell) approximations of a Poisson-disc set inside the
//! [`Aperture`], weighted by its density and the aberration profile. `poisson` gathers with them
//! and `lowrank` uses them in its 2D fallback.

use glam::Vec2;

use super::shapes::{aberration_profile, check_aberration};
use super::Aperture;
use crate::random::SplitMix64;
use crate::{Error, Result};

/// Random candidates drawn for each new tap of the best-candidate Poisson-disc set.
pub const CANDIDATES: usize = 24;

/// Largest number of taps.
pub const MAX_TAPS: usize = 1024;

/// A set of gather taps in the unit aperture (image axes) with their weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Taps {
    /// Tap positions in the unit aperture, x right, y down; the first is the centre when the
    /// aperture passes light there.
    pub points: Vec<Vec2>,
    /// Weight of each tap: aperture density times the aberration profile.
    pub weights: Vec<f32>,
}

impl Taps {
    /// `count` best-candidate Poisson-disc taps inside `aperture` (see the module
    /// documentation), weighted by the density and the spherical-aberration profile
    /// `aberration` (-1 to 1, see [`crate::methods::lowrank::KernelSpec::aberration`]).
    pub fn poisson_disc(
        aperture: &Aperture,
        count: usize,
        seed: u64,
        aberration: f32,
    ) -> Result<Self> {
        aperture.validate()?;
        check_aberration(aberration)?;
        if !(1..=MAX_TAPS).contains(&count) {
            return Err(Error::invalid(
                "taps",
                format!("{count}: expected 1 to {MAX_TAPS} taps"),
            ));
        }
        let mut rng = SplitMix64::new(seed ^ crate::lens::SAMPLER_SEED_SALT);
        let mut points: Vec<Vec2> = Vec::with_capacity(count);
        let density = aperture.density_fn();
        if density(Vec2::ZERO) > 0.0 {
            points.push(Vec2::ZERO);
        }
        // Shapes covering less than 1/64 of the square are refused rather than looped on.
        let max_draws = 64 * CANDIDATES;
        while points.len() < count {
            let mut best: Option<(f32, Vec2)> = None;
            for _ in 0..CANDIDATES {
                let mut candidate = None;
                for _ in 0..max_draws {
                    let v = Vec2::new(rng.next_f32() * 2.0 - 1.0, rng.next_f32() * 2.0 - 1.0);
                    if density(v) > 0.0 {
                        candidate = Some(v);
                        break;
                    }
                }
                let Some(v) = candidate else {
                    return Err(Error::invalid(
                        "aperture",
                        "too little of the unit square passes light to place gather taps",
                    ));
                };
                let d = points
                    .iter()
                    .map(|p| p.distance_squared(v))
                    .fold(f32::INFINITY, f32::min);
                if best.is_none_or(|(bd, _)| d > bd) {
                    best = Some((d, v));
                }
            }
            if let Some((_, v)) = best {
                points.push(v);
            }
        }
        let weights = points
            .iter()
            .map(|&v| density(v) * aberration_profile(aberration, v.length_squared()))
            .collect();
        Ok(Self { points, weights })
    }
}
