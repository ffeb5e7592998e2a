//! What this CPU allows for the 4 x 32 network's matrix products, independent of pinc's
//! kernels: the yardstick for the `step` and `rollout_65` targets of `benches/runtime.rs`.
//!
//! `floor/products_5_layers`: the network's five matrix products (14 -> 32, three 32 -> 32,
//! 32 -> 16) chained as in a rollout, with `max(y, 0)` for an activation and no LayerNorm:
//! what a step costs here before its softplus and LayerNorm, in the fastest form found (a
//! measurement, not a proof that nothing faster exists).
//!
//! The products use the fastest layout found on this machine: weights in "XOR diagonals"
//! (lane `i` of block `(p, q, r)` holds `W[8p + i][8q + (i ^ r)]`), so that each output
//! pack is a sum of weight blocks times in-register permutations of the input packs, with
//! no horizontal sums. Needs AVX2 + FMA; on other CPUs the group is empty.
//!
//! Run with `cargo bench --bench floor`.
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, criterion_group, criterion_main};

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    /// A dense layer of `NI` input packs and `NO` output packs in XOR-diagonal order.
    pub struct Layer<const NI: usize, const NO: usize> {
        w: Vec<[[[f32; 8]; 8]; NI]>,
        b: [[f32; 8]; NO],
    }

    impl<const NI: usize, const NO: usize> Layer<NI, NO> {
        /// Deterministic weights of the size a trained layer has (|w| < 0.3).
        pub fn new(seed: u32) -> Self {
            let mut s = seed.wrapping_mul(2_654_435_761).max(1);
            let mut next = || {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s as f32 / u32::MAX as f32 - 0.5) * 0.6
            };
            let w = (0..NO)
                .map(|_| std::array::from_fn(|_| std::array::from_fn(|_| std::array::from_fn(|_| next()))))
                .collect();
            Self { w, b: std::array::from_fn(|_| std::array::from_fn(|_| next() * 0.1)) }
        }

        /// `max(W h + b, 0)` written out lane by lane, to check [`Self::apply`] against.
        pub fn reference(&self, h: &[[f32; 8]; NI]) -> [[f32; 8]; NO] {
            std::array::from_fn(|p| {
                std::array::from_fn(|i| {
                    let mut y = self.b[p][i];
                    for (q, hq) in h.iter().enumerate() {
                        for r in 0..8 {
                            y += self.w[p][q][r][i] * hq[i ^ r];
                        }
                    }
                    y.max(0.0)
                })
            })
        }

        /// `max(W h + b, 0)`.
        #[inline(always)]
        pub unsafe fn apply(&self, h: &[__m256; NI]) -> [__m256; NO] {
            unsafe {
                // Two accumulators per output pack: chains of 4 NI multiply-adds.
                // (Plain loops: `array::map` and `from_fn` were not always inlined into this
                // AVX2 function, and the out-of-line copies run without AVX.)
                let mut acc = [[_mm256_setzero_ps(); 2]; NO];
                for (acc, b) in acc.iter_mut().zip(&self.b) {
                    acc[0] = _mm256_loadu_ps(b.as_ptr());
                }
                for (q, &v) in h.iter().enumerate() {
                    let s = _mm256_permute2f128_ps::<1>(v, v);
                    let x = [
                        v,
                        _mm256_permute_ps::<0xB1>(v),
                        _mm256_permute_ps::<0x4E>(v),
                        _mm256_permute_ps::<0x1B>(v),
                        s,
                        _mm256_permute_ps::<0xB1>(s),
                        _mm256_permute_ps::<0x4E>(s),
                        _mm256_permute_ps::<0x1B>(s),
                    ];
                    for (acc, w) in acc.iter_mut().zip(&self.w) {
                        let w = &w[q];
                        for r in 0..8 {
                            acc[r % 2] = _mm256_fmadd_ps(_mm256_loadu_ps(w[r].as_ptr()), x[r], acc[r % 2]);
                        }
                    }
                }
                let mut out = [_mm256_setzero_ps(); NO];
                for (o, [a, b]) in out.iter_mut().zip(acc) {
                    *o = _mm256_max_ps(_mm256_add_ps(a, b), _mm256_setzero_ps());
                }
                out
            }
        }
    }

    /// The five products of a step of the 4 x 32 network.
    pub struct Products {
        input: Layer<2, 4>,
        hidden: [Layer<4, 4>; 3],
        output: Layer<4, 2>,
    }

    impl Products {
        pub fn new() -> Self {
            Self { input: Layer::new(1), hidden: [Layer::new(2), Layer::new(3), Layer::new(4)], output: Layer::new(5) }
        }

        /// [`Self::step`] lane by lane.
        pub fn reference(&self, z: &[f32; 16]) -> [f32; 16] {
            let mut h = self.input.reference(&[z[..8].try_into().unwrap(), z[8..].try_into().unwrap()]);
            for layer in &self.hidden {
                h = layer.reference(&h);
            }
            *self.output.reference(&h).as_flattened().as_array().unwrap()
        }

        /// One step's products from a 14-value input (two packs).
        #[target_feature(enable = "avx2,fma")]
        pub unsafe fn step(&self, z: &[f32; 16]) -> [f32; 16] {
            unsafe {
                let z = [_mm256_loadu_ps(z.as_ptr()), _mm256_loadu_ps(z[8..].as_ptr())];
                let mut h = self.input.apply(&z);
                for layer in &self.hidden {
                    h = layer.apply(&h);
                }
                let o = self.output.apply(&h);
                let mut out = [0.0; 16];
                _mm256_storeu_ps(out.as_mut_ptr(), o[0]);
                _mm256_storeu_ps(out[8..].as_mut_ptr(), o[1]);
                out
            }
        }
    }
}

fn floor(c: &mut Criterion) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        use std::hint::black_box;
        let products = avx2::Products::new();
        let mut z = [0.0_f32; 16];
        for (k, v) in z.iter_mut().take(14).enumerate() {
            *v = 0.1 * k as f32 - 0.5;
        }
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        let (fast, slow) = (unsafe { products.step(&z) }, products.reference(&z));
        let worst = fast.iter().zip(&slow).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-5 && slow.iter().any(|&v| v > 0.0), "products differ from the reference by {worst}");
        c.bench_function("floor/products_5_layers", |b| {
            b.iter(|| {
                // Each step starts from the last one's output, as in a rollout.
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                let out = unsafe { products.step(black_box(&z)) };
                z[..14].copy_from_slice(&out[..14]);
            })
        });
    }
}

criterion_group!(benches, floor);
criterion_main!(benches);
