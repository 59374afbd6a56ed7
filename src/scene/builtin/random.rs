//! Seeded randomness for the built-in scenes: a SplitMix64 generator and lattice hashes, so
//! every scene is the same on every run and every machine.

/// The SplitMix64 output function (Steele, Lea and Flood, "Fast splittable pseudorandom number
/// generators", OOPSLA 2014): a bijective mix of 64 bits.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Golden-ratio increment of SplitMix64.
const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// A SplitMix64 generator: a Weyl sequence passed through [`mix64`].
#[derive(Clone, Debug)]
pub(crate) struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator started at `seed`.
    pub(crate) fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// The next 64 random bits.
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GAMMA);
        mix64(self.state)
    }

    /// Uniform in [0, 1), with 24 bits of precision.
    pub(crate) fn next_f32(&mut self) -> f32 {
        unit_f32(self.next_u64())
    }

    /// Uniform in [lo, hi).
    pub(crate) fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }

    /// Uniform integer in [0, n), `n > 0`.
    pub(crate) fn below(&mut self, n: usize) -> usize {
        // The bias of a modulo is below 2^-40 for the small n used here.
        (self.next_u64() % n as u64) as usize
    }
}

/// The top 24 bits of `bits` as a float in [0, 1).
#[inline]
fn unit_f32(bits: u64) -> f32 {
    (bits >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

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
    fn same_seed_gives_same_sequence_and_values_stay_in_range() {
        let mut a = SplitMix64::new(7);
        let mut b = SplitMix64::new(7);
        for _ in 0..1000 {
            let x = a.next_f32();
            assert_eq!(x, b.next_f32());
            assert!((0.0..1.0).contains(&x));
        }
        assert!(a.below(5) < 5);
    }

    #[test]
    fn lattice_hash_is_spread_over_the_unit_interval() {
        let n = 64;
        let mean: f32 = (0..n * n).map(|i| hash2(i % n, i / n, 3)).sum::<f32>() / (n * n) as f32;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
        assert_ne!(hash2(1, 2, 3), hash2(2, 1, 3));
        assert_ne!(hash2(1, 2, 3), hash2(1, 2, 4));
    }
}
