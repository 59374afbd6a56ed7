//! Seeded randomness for the built-in scenes: the crate's SplitMix64 and lattice hashes, so
//! every scene is the same on every run and every machine.

pub(crate) use crate::random::SplitMix64;
use crate::random::{mix64, unit_f32, GAMMA};

/// A hash of an integer lattice point and a seed, uniform in [0, 1).
#[inline]
pub(crate) fn hash2(x: i32, y: i32, seed: u64) -> f32 {
    let key = (x as u32 as u64) | ((y as u32 as u64) << 32);
    unit_f32(mix64(
        mix64(key ^ seed.wrapping_mul(GAMMA)).wrapping_add(seed),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_hash_is_spread_over_the_unit_interval() {
        let n = 64;
        let mean: f32 = (0..n * n).map(|i| hash2(i % n, i / n, 3)).sum::<f32>() / (n * n) as f32;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
        assert_ne!(hash2(1, 2, 3), hash2(2, 1, 3));
        assert_ne!(hash2(1, 2, 3), hash2(1, 2, 4));
    }
}
