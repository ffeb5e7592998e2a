//! The seeded random streams of a dataset's sets and the collocation times drawn from them:
//! shared by generation and import (an imported set's times come from the stream its name
//! keys, as a generated set's do).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Each set draws from its own ChaCha stream keyed by its name, so adding or resizing one
/// set never changes another.
pub(super) fn set_rng(seed: u64, name: &str) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(u64::from(crc32fast::hash(name.as_bytes())));
    rng
}

/// Collocation times for `intervals` recorded intervals of the set `name`, `m` per interval,
/// from the set's own stream of `seed` (as generation draws them, but without trajectories).
#[cfg(feature = "tools")]
pub(super) fn collocation_times(seed: u64, name: &str, intervals: usize, m: usize, dt: f64) -> Vec<f64> {
    let mut rng = set_rng(seed, name);
    let mut out = Vec::with_capacity(intervals * m);
    for _ in 0..intervals {
        latin_hypercube(&mut rng, m, dt, &mut out);
    }
    out
}

/// Appends `m` collocation times in `[0, dt]`: one at `dt` when `m == 1`, otherwise a
/// Latin-hypercube sample (one uniform point in each of `m` equal strata, shuffled).
pub(super) fn latin_hypercube(rng: &mut impl Rng, m: usize, dt: f64, out: &mut Vec<f64>) {
    if m == 1 {
        out.push(dt);
        return;
    }
    let start = out.len();
    out.extend((0..m).map(|j| dt * (j as f64 + rng.random::<f64>()) / m as f64));
    // Fisher–Yates, so strata are not in time order.
    for i in (1..m).rev() {
        let j = rng.random_range(0..=i);
        out.swap(start + i, start + j);
    }
}
