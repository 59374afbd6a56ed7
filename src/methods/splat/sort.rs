//! Pass `sort`: each tile's list in depth order, by a least-significant-digit radix sort on a
//! 32-bit key (tiles in parallel). The key is the signed CoC made order-preserving as an
//! unsigned integer: the CoC grows monotonically with depth (`C(z) = f E (1/z_f - 1/z)`), so
//! sorting by it is sorting by depth, as the poster's compact fragment carries only its CoC.
//! The sort is stable, so fragments of equal depth keep their order of entry.

/// An order-preserving map of an `f32` onto `u32` (negative values flipped, positive ones with
/// the sign bit set): `a < b` as floats iff `key(a) < key(b)` as integers (NaN excluded).
#[inline]
pub fn key(v: f32) -> u32 {
    let b = v.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Sorts `entries` (key, payload) by key, stably, with 8-bit digits, in place; `scratch` is
/// reused (it grows to the length of `entries`).
pub fn radix_sort(entries: &mut [(u32, u32)], scratch: &mut Vec<(u32, u32)>) {
    let n = entries.len();
    if n < 2 {
        return;
    }
    if n <= 32 {
        // Insertion sort: stable, and cheaper than four passes on short lists.
        for i in 1..n {
            let mut j = i;
            while j > 0 && entries[j - 1].0 > entries[j].0 {
                entries.swap(j - 1, j);
                j -= 1;
            }
        }
        return;
    }
    scratch.clear();
    scratch.resize(n, (0, 0));
    let (mut src, mut dst) = (entries, &mut scratch[..]);
    let mut swapped = false;
    for pass in 0..4 {
        let shift = pass * 8;
        let mut count = [0usize; 256];
        for e in src.iter() {
            count[((e.0 >> shift) & 0xff) as usize] += 1;
        }
        if count.contains(&n) {
            continue; // every key has the same digit here
        }
        let mut pos = [0usize; 256];
        let mut sum = 0;
        for (p, c) in pos.iter_mut().zip(count) {
            *p = sum;
            sum += c;
        }
        for e in src.iter() {
            let d = ((e.0 >> shift) & 0xff) as usize;
            dst[pos[d]] = *e;
            pos[d] += 1;
        }
        std::mem::swap(&mut src, &mut dst);
        swapped = !swapped;
    }
    if swapped {
        // The sorted data is in the scratch buffer.
        dst.copy_from_slice(src);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_orders_floats_as_integers() {
        let v = [-1e9f32, -3.5, -0.0, 0.0, 1e-20, 2.0, 7.25, 1e30];
        for w in v.windows(2) {
            assert!(key(w[0]) <= key(w[1]), "{} {}", w[0], w[1]);
        }
    }

    #[test]
    fn radix_sort_agrees_with_a_stable_sort() {
        let mut rng = crate::random::SplitMix64::new(5);
        for n in [0usize, 1, 2, 31, 33, 500, 4097] {
            let mut v: Vec<(u32, u32)> = (0..n)
                .map(|i| (key(rng.range(-50.0, 50.0).round()), i as u32))
                .collect();
            let mut want = v.clone();
            want.sort_by_key(|e| e.0);
            let mut scratch = Vec::new();
            radix_sort(&mut v, &mut scratch);
            assert_eq!(v, want, "n = {n}");
        }
    }
}
