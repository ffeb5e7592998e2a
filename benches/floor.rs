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
//! `floor/batch_1000x65`: the same network over 1000 trajectories of 65 steps, vectorised
//! across trajectories (16 per block, two registers), with the softplus (`ln(1 + e^y)` by
//! the same range reduction and polynomials as the runtime) and without LayerNorm or any
//! bookkeeping (no envelope, no finiteness checks, no f64 states): the yardstick for
//! `batch/batch_rollout_1000x65`. Each layer takes four output units at a time, so every
//! input value loaded feeds eight multiply-adds.
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

    /// Lanes per block of the batch floor: two registers of trajectories.
    pub const LANES: usize = 16;

    /// A dense layer for the batch: `w[j][i]` row-major, `b[j]`.
    pub struct BatchLayer {
        rows: usize,
        cols: usize,
        w: Vec<f32>,
        b: Vec<f32>,
    }

    impl BatchLayer {
        pub fn new(rows: usize, cols: usize, seed: u32) -> Self {
            let mut s = seed.wrapping_mul(2_654_435_761).max(1);
            let mut next = || {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s as f32 / u32::MAX as f32 - 0.5) * 0.6
            };
            let w = (0..rows * cols).map(|_| next()).collect();
            Self { rows, cols, w, b: (0..rows).map(|_| next() * 0.1).collect() }
        }

        /// `W h + b` (then softplus if `act`) for `LANES` lanes, component-major, plainly.
        pub fn reference(&self, h: &[[f32; LANES]], act: bool) -> Vec<[f32; LANES]> {
            (0..self.rows)
                .map(|j| {
                    std::array::from_fn(|l| {
                        let y = self.b[j] + (0..self.cols).map(|i| self.w[j * self.cols + i] * h[i][l]).sum::<f32>();
                        if act { (1.0 + y.exp()).ln() } else { y }
                    })
                })
                .collect()
        }

        /// `W h + b`, then softplus if `act`, for `LANES` lanes: four units at a time.
        #[inline(always)]
        pub unsafe fn apply(&self, h: &[[__m256; 2]], out: &mut [[__m256; 2]], act: bool) {
            unsafe {
                let mut j = 0;
                while self.rows - j >= 4 {
                    self.units::<4>(j, h, out, act);
                    j += 4;
                }
                while j < self.rows {
                    self.units::<1>(j, h, out, act);
                    j += 1;
                }
            }
        }

        /// Units `j .. j + U`.
        #[inline(always)]
        unsafe fn units<const U: usize>(&self, j: usize, h: &[[__m256; 2]], out: &mut [[__m256; 2]], act: bool) {
            unsafe {
                let w = &self.w[j * self.cols..(j + U) * self.cols];
                let h = &h[..self.cols];
                let mut acc = [[_mm256_setzero_ps(); 2]; U];
                for u in 0..U {
                    acc[u] = [_mm256_set1_ps(self.b[j + u]); 2];
                }
                for i in 0..self.cols {
                    for u in 0..U {
                        let wu = _mm256_broadcast_ss(w.get_unchecked(u * self.cols + i));
                        acc[u][0] = _mm256_fmadd_ps(wu, h.get_unchecked(i)[0], acc[u][0]);
                        acc[u][1] = _mm256_fmadd_ps(wu, h.get_unchecked(i)[1], acc[u][1]);
                    }
                }
                for u in 0..U {
                    out[j + u] = if act { [softplus(acc[u][0]), softplus(acc[u][1])] } else { acc[u] };
                }
            }
        }
    }

    /// `ln(1 + e^y)` as `max(y, 0) + ln(1 + e^-|y|)`: `exp` by range reduction and a
    /// degree-6 polynomial, `ln(1 + e)` on [0, 1] by a degree-8 polynomial, both by Estrin's
    /// scheme (the runtime's coefficients, so the arithmetic is the same).
    #[inline(always)]
    unsafe fn softplus(y: __m256) -> __m256 {
        unsafe {
            const EXP: [f32; 7] = [1.0, 1.0, 0.499_999_9, 0.166_664_2, 0.041_668_225, 0.008_374_816, 0.001_383_683_5];
            const LOG1P: [f32; 9] = [
                0.999_999_94,
                -0.499_994_93,
                0.333_190_98,
                -0.248_429_85,
                0.191_060_14,
                -0.136_632_58,
                0.078_226_045,
                -0.029_505_279,
                0.005_232_701,
            ];
            const MAGIC: f32 = 1.5 * (1u32 << 23) as f32;
            let ps = _mm256_set1_ps;
            let sign = ps(-0.0);
            let x = _mm256_max_ps(_mm256_or_ps(sign, y), ps(-87.0));
            let t = _mm256_fmadd_ps(x, ps(std::f32::consts::LOG2_E), ps(MAGIC));
            let k = _mm256_sub_ps(t, ps(MAGIC));
            let r = _mm256_fnmadd_ps(k, ps(std::f32::consts::LN_2), x);
            let (r2, c) = (_mm256_mul_ps(r, r), EXP);
            let lo = _mm256_fmadd_ps(_mm256_fmadd_ps(ps(c[3]), r, ps(c[2])), r2, _mm256_add_ps(r, ps(c[0])));
            let hi = _mm256_fmadd_ps(ps(c[6]), r2, _mm256_fmadd_ps(ps(c[5]), r, ps(c[4])));
            let poly = _mm256_fmadd_ps(hi, _mm256_mul_ps(r2, r2), lo);
            let bits = _mm256_sub_epi32(_mm256_castps_si256(t), _mm256_set1_epi32(MAGIC.to_bits() as i32 - 127));
            let e = _mm256_mul_ps(poly, _mm256_castsi256_ps(_mm256_slli_epi32::<23>(bits)));
            let (e2, c) = (_mm256_mul_ps(e, e), LOG1P);
            let e4 = _mm256_mul_ps(e2, e2);
            let r0 =
                _mm256_fmadd_ps(_mm256_fmadd_ps(ps(c[3]), e, ps(c[2])), e2, _mm256_fmadd_ps(ps(c[1]), e, ps(c[0])));
            let r1 =
                _mm256_fmadd_ps(_mm256_fmadd_ps(ps(c[7]), e, ps(c[6])), e2, _mm256_fmadd_ps(ps(c[5]), e, ps(c[4])));
            let r1 = _mm256_fmadd_ps(ps(c[8]), e4, r1);
            let log1p = _mm256_mul_ps(e, _mm256_fmadd_ps(r1, e4, r0));
            _mm256_add_ps(_mm256_max_ps(y, _mm256_setzero_ps()), log1p)
        }
    }

    /// The 4 x 32 network (14 inputs, 9 outputs) for the batch floor.
    pub struct BatchNetwork {
        layers: [BatchLayer; 5],
    }

    impl BatchNetwork {
        pub fn new() -> Self {
            let hidden = |seed| BatchLayer::new(32, 32, seed);
            Self {
                layers: [BatchLayer::new(32, 14, 11), hidden(12), hidden(13), hidden(14), BatchLayer::new(9, 32, 15)],
            }
        }

        /// One step of `LANES` trajectories, plainly: the raw output (9 components).
        pub fn reference(&self, z: &[[f32; LANES]; 14]) -> Vec<[f32; LANES]> {
            let mut h = z.to_vec();
            for (l, layer) in self.layers.iter().enumerate() {
                h = layer.reference(&h, l < 4);
            }
            h
        }

        /// `steps` steps of every block of `LANES` trajectories in `z` (component-major
        /// per block): each step's nine outputs are added to the first nine inputs, as a
        /// residual network's state would be.
        #[target_feature(enable = "avx2,fma")]
        pub unsafe fn rollout(&self, z: &mut [[[f32; LANES]; 14]], steps: usize) {
            unsafe {
                let zero = [_mm256_setzero_ps(); 2];
                let (mut a, mut b) = ([zero; 32], [zero; 32]);
                for block in z.iter_mut() {
                    let mut input = [zero; 14];
                    for (v, c) in input.iter_mut().zip(block.iter()) {
                        *v = [_mm256_loadu_ps(c.as_ptr()), _mm256_loadu_ps(c[8..].as_ptr())];
                    }
                    for _ in 0..steps {
                        self.layers[0].apply(&input, &mut a, true);
                        self.layers[1].apply(&a, &mut b, true);
                        self.layers[2].apply(&b, &mut a, true);
                        self.layers[3].apply(&a, &mut b, true);
                        self.layers[4].apply(&b, &mut a, false);
                        for k in 0..9 {
                            input[k] = [_mm256_add_ps(input[k][0], a[k][0]), _mm256_add_ps(input[k][1], a[k][1])];
                        }
                    }
                    for (v, c) in input.iter().zip(block.iter_mut()) {
                        _mm256_storeu_ps(c.as_mut_ptr(), v[0]);
                        _mm256_storeu_ps(c[8..].as_mut_ptr(), v[1]);
                    }
                }
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

fn batch_floor(c: &mut Criterion) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        use avx2::LANES;
        let net = avx2::BatchNetwork::new();
        let start: Vec<[[f32; LANES]; 14]> = (0..1000usize.div_ceil(LANES))
            .map(|b| {
                std::array::from_fn(|k| std::array::from_fn(|l| 0.05 * ((b * LANES + l + 3 * k) % 17) as f32 - 0.4))
            })
            .collect();
        // One step of the first block against the plain computation.
        let mut one = vec![start[0]];
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        unsafe { net.rollout(&mut one, 1) };
        let out = net.reference(&start[0]);
        let worst = (0..9)
            .flat_map(|k| (0..LANES).map(move |l| (k, l)))
            .map(|(k, l)| (one[0][k][l] - start[0][k][l] - out[k][l]).abs())
            .fold(0.0, f32::max);
        assert!(worst < 1e-4, "batch floor differs from the reference by {worst}");
        let mut z = start.clone();
        let mut group = c.benchmark_group("floor");
        group.sample_size(20);
        group.bench_function("batch_1000x65", |b| {
            b.iter(|| {
                z.copy_from_slice(&start);
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                unsafe { net.rollout(std::hint::black_box(&mut z), 65) }
            })
        });
        group.finish();
    }
}

criterion_group!(benches, floor, batch_floor);
criterion_main!(benches);
