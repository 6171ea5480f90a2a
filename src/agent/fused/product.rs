//! The CPU engine's matrix products, and how they round (`--arithmetic`, `Arithmetic`).
//!
//! **Why the rounding depends on the machine (native).** `gemm` picks its kernels the first time
//! it runs, by what the CPU has: AVX-512 (Cargo.toml turns on `x86-v4`), else AVX2+FMA, else
//! scalar. For most products every output is one chain of FMAs in k order whatever the kernel,
//! and the bits agree; two things break that. (1) A product with one output column (the
//! critic's last layer, Q = x·w) is a dot product: gemm sums k in 8 lanes (AVX2) or 16
//! (AVX-512) and then adds the lanes, so the sum is grouped differently. (2) When k exceeds the
//! depth gemm blocks by (`kc`, from the kernel's shape and the caches it reads from CPUID),
//! each block's sum is added to the output separately, at block boundaries that depend on the
//! machine. Measured (issue 66) on one AVX-512 machine with gemm's two kernels forced through its
//! own driver, on the products of one 256-row part of FetchPush at `--hidden 256`: only Q = x·w
//! differs (190 of 256 outputs, by up to 4e-6); at `--hidden 1024` nearly every product does.
//! Under `qemu-x86_64 -cpu EPYC-Milan` (Zen 3: AVX2+FMA, no AVX-512) the dispatched products
//! equal the forced AVX2 ones. A few ulps in Q move the TD targets, the ReLU kinks the rows fall
//! on, and from there the whole run: the same pipeline gave a Q whose mean differed by 5 %.
//!
//! **The portable product.** dst[i][j] = Σ_p a[i][p]·b[p][j], summed as one chain of fused
//! multiply-adds from 0 in increasing p: acc ← fma(a[i][p], b[p][j], acc). An FMA rounds once,
//! exactly as IEEE 754 says, so that chain has one result for given inputs on any machine, and
//! every path below computes that chain and nothing else:
//! - AVX-512 (`avx512`): 16 columns a vector, 6 rows × 32 columns a block (12 accumulators),
//!   each lane its own chain; columns past n masked off (never loaded from B, never stored);
//! - AVX2+FMA (`avx2`): the same with 8 columns a vector, 6 rows × 16 columns a block;
//! - scalar: the same chain with `f32::mul_add` (one rounding, as the instruction), for x86-64
//!   without AVX2/FMA or any other architecture: the same bits, slower.
//!
//! No blocking of k, no lanes added to each other, no tree: the order is the textbook one, so
//! the result depends on the inputs alone: a wider vector only computes more chains at once.
//! `arith_tests.rs` checks the three paths against each other to the bit, each forced on one
//! machine, and against an f64 product. The cost is in BENCHMARKS.md ("Portable arithmetic").
//!
//! `PGSER_ARITHMETIC_PATH=scalar|avx2|avx512` makes portable products take that path (where the
//! CPU has it): a switch for tests and for checking a machine, read once; it changes the speed,
//! never a bit.

use std::cell::RefCell;
use std::sync::OnceLock;

use crate::agent::Arithmetic;

/// How the engine's products are computed: `gemm` (native), or the portable chain on one of
/// its paths.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(in crate::agent) enum Product {
    Native,
    Portable(Path),
}

/// The kernels of the portable product: all give the same bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(in crate::agent) enum Path {
    Scalar,
    Avx2,
    Avx512,
}

impl Product {
    /// The product `arithmetic` asks for on this machine: the portable chain on the widest path
    /// the CPU has, or the one `PGSER_ARITHMETIC_PATH` names.
    pub(in crate::agent) fn of(arithmetic: Arithmetic) -> Product {
        match arithmetic {
            Arithmetic::Native => Product::Native,
            Arithmetic::Portable => Product::Portable(chosen()),
        }
    }
}

fn chosen() -> Path {
    static CHOSEN: OnceLock<Path> = OnceLock::new();
    *CHOSEN.get_or_init(|| {
        let asked = match std::env::var("PGSER_ARITHMETIC_PATH").as_deref() {
            Ok("scalar") => Some(Path::Scalar),
            Ok("avx2") => Some(Path::Avx2),
            Ok("avx512") => Some(Path::Avx512),
            _ => None,
        };
        asked.filter(|p| p.available()).unwrap_or_else(Path::widest)
    })
}

impl Path {
    /// The widest path this CPU runs.
    pub(in crate::agent) fn widest() -> Path {
        [Path::Avx512, Path::Avx2].into_iter().find(|p| p.available()).unwrap_or(Path::Scalar)
    }

    /// Whether this CPU runs the path.
    pub(in crate::agent) fn available(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            match self {
                Path::Scalar => true,
                Path::Avx2 => is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"),
                Path::Avx512 => is_x86_feature_detected!("avx512f"),
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            self == Path::Scalar
        }
    }
}

thread_local! {
    /// B laid out dense when it comes strided (a transpose): reused, so a product allocates
    /// nothing once a thread has seen the largest B.
    static PACKED: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
}

/// Panics unless every element the strides of `a` (`m × k`) and `b` (`k × n`) reach lies inside
/// its slice and `dst` holds `m × n`: what makes the raw-pointer kernels of both products safe.
pub(in crate::agent) fn check_operands(
    m: usize,
    n: usize,
    k: usize,
    dst: &[f32],
    a: (&[f32], usize, usize),
    b: (&[f32], usize, usize),
) {
    // Checked arithmetic: a stride product that wrapped (release builds do not trap) would pass
    // a bound it does not meet, and the kernels would read outside the slice.
    let last = |rows: usize, cols: usize, (v, rs, cs): (&[f32], usize, usize)| {
        let end = || (rows - 1).checked_mul(rs)?.checked_add((cols - 1).checked_mul(cs)?);
        assert!(rows == 0 || cols == 0 || end().is_some_and(|e| e < v.len()), "product operand out of bounds");
    };
    last(m, k, a);
    last(k, n, b);
    assert!(m.checked_mul(n).is_some_and(|mn| dst.len() >= mn), "product output out of bounds");
}

/// `dst` (`m × n`, row-major, row stride n) = A·B in the portable order, A and B each given as
/// (values, row stride, column stride), on `path` (which the CPU must have). Same bits on
/// every path.
pub(in crate::agent) fn portable(
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    a: (&[f32], usize, usize),
    b: (&[f32], usize, usize),
    path: Path,
) {
    if m == 0 || n == 0 {
        return;
    }
    check_operands(m, n, k, dst, a, b);
    if b.2 == 1 {
        dense(m, n, k, dst, a, (b.0, b.1), path);
        return;
    }
    PACKED.with_borrow_mut(|packed| {
        packed.clear();
        packed.extend((0..k).flat_map(|p| (0..n).map(move |j| b.0[p * b.1 + j * b.2])));
        dense(m, n, k, dst, a, (packed, n), path);
    });
}

/// `portable` with B's rows dense (column stride 1, row stride `b.1`).
fn dense(m: usize, n: usize, k: usize, dst: &mut [f32], a: (&[f32], usize, usize), b: (&[f32], usize), path: Path) {
    assert!(path.available(), "the portable product's {path:?} path on a CPU without it");
    match path {
        Path::Scalar => scalar(m, n, k, dst, a, b),
        // SAFETY: the CPU has the path's instructions (asserted); `portable` checked that every
        // element the strides reach lies inside `a`, `b` and `dst`.
        #[cfg(target_arch = "x86_64")]
        Path::Avx2 => unsafe { avx2::product(m, n, k, dst, a, b) },
        #[cfg(target_arch = "x86_64")]
        Path::Avx512 => unsafe { avx512::product(m, n, k, dst, a, b) },
        #[cfg(not(target_arch = "x86_64"))]
        _ => unreachable!("only the scalar path is available off x86-64"),
    }
}

/// The chain, one output at a time.
fn scalar(
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    (a, ars, acs): (&[f32], usize, usize),
    (b, brs): (&[f32], usize),
) {
    for i in 0..m {
        for j in 0..n {
            let mut acc = 0.0f32;
            for p in 0..k {
                acc = a[i * ars + p * acs].mul_add(b[p * brs + j], acc);
            }
            dst[i * n + j] = acc;
        }
    }
}

/// The vector paths' driver, written once: `product` walks the output in blocks of up to 6 rows ×
/// two vectors of columns and `block` runs one block's chains, using the module's `LANES`, `V`
/// (a vector), `M` (a lane mask) and its `zero`, `load`, `load_masked`, `store_masked`, `splat`,
/// `fma` and `mask`. `$feature` is the instruction set `product` is compiled for; `block` and
/// the helpers are inlined into it.
#[cfg(target_arch = "x86_64")]
macro_rules! vector_path {
    ($feature:literal) => {
        /// Rows of A a block keeps in registers (with two vectors of columns: 12 accumulators).
        const MR: usize = 6;

        /// `scalar`'s result, 6 rows × 2·LANES columns at a time, each lane its own chain.
        ///
        /// # Safety
        /// The CPU has `$feature`, and every element the strides reach lies in its slice
        /// (`portable` asserts it).
        #[target_feature(enable = $feature)]
        pub(super) unsafe fn product(
            m: usize,
            n: usize,
            k: usize,
            dst: &mut [f32],
            (a, ars, acs): (&[f32], usize, usize),
            (b, brs): (&[f32], usize),
        ) {
            let (a, b, d) = (a.as_ptr(), b.as_ptr(), dst.as_mut_ptr());
            let mut j = 0;
            while j < n {
                let w = (n - j).min(2 * LANES);
                let mut i = 0;
                while i < m {
                    let r = (m - i).min(MR);
                    // SAFETY: rows i..i + r and columns j..j + w lie inside the operands; the
                    // caller's contract covers the CPU.
                    unsafe {
                        let (ap, bp, dp) = (a.add(i * ars), b.add(j), d.add(i * n + j));
                        match r {
                            6 => block::<6>(k, ap, ars, acs, bp, brs, dp, n, w),
                            5 => block::<5>(k, ap, ars, acs, bp, brs, dp, n, w),
                            4 => block::<4>(k, ap, ars, acs, bp, brs, dp, n, w),
                            3 => block::<3>(k, ap, ars, acs, bp, brs, dp, n, w),
                            2 => block::<2>(k, ap, ars, acs, bp, brs, dp, n, w),
                            _ => block::<1>(k, ap, ars, acs, bp, brs, dp, n, w),
                        }
                    }
                    i += r;
                }
                j += w;
            }
        }

        /// R rows × w ≤ 2·LANES columns: two vectors of columns, the lanes past w masked (never
        /// loaded from B, never stored).
        #[inline(always)]
        #[allow(clippy::too_many_arguments)]
        unsafe fn block<const R: usize>(
            k: usize,
            a: *const f32,
            ars: usize,
            acs: usize,
            b: *const f32,
            brs: usize,
            d: *mut f32,
            drs: usize,
            w: usize,
        ) {
            // SAFETY: the caller's contract; masked lanes are neither read nor written.
            unsafe {
                let (m0, m1) = (mask(w.min(LANES)), mask(w.saturating_sub(LANES)));
                let mut lo: [V; R] = [zero(); R];
                let mut hi: [V; R] = [zero(); R];
                if w == 2 * LANES {
                    for p in 0..k {
                        let (b0, b1) = (load(b.add(p * brs)), load(b.add(p * brs + LANES)));
                        for r in 0..R {
                            let x = splat(*a.add(r * ars + p * acs));
                            lo[r] = fma(x, b0, lo[r]);
                            hi[r] = fma(x, b1, hi[r]);
                        }
                    }
                } else if w > LANES {
                    for p in 0..k {
                        let (b0, b1) = (load(b.add(p * brs)), load_masked(b.add(p * brs + LANES), m1));
                        for r in 0..R {
                            let x = splat(*a.add(r * ars + p * acs));
                            lo[r] = fma(x, b0, lo[r]);
                            hi[r] = fma(x, b1, hi[r]);
                        }
                    }
                } else {
                    for p in 0..k {
                        let b0 = load_masked(b.add(p * brs), m0);
                        for r in 0..R {
                            let x = splat(*a.add(r * ars + p * acs));
                            lo[r] = fma(x, b0, lo[r]);
                        }
                    }
                }
                for r in 0..R {
                    store_masked(d.add(r * drs), m0, lo[r]);
                    if w > LANES {
                        store_masked(d.add(r * drs + LANES), m1, hi[r]);
                    }
                }
            }
        }
    };
}

/// AVX2+FMA: 8 lanes, masks as vectors of all-ones lanes.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    // SAFETY of every helper here: `vector_path!` calls them only inside `product`, compiled for
    // AVX2+FMA, which only runs on a CPU that has them, with pointers inside the operands.
    const LANES: usize = 8;
    type V = __m256;
    type M = __m256i;

    #[inline(always)]
    unsafe fn zero() -> V {
        unsafe { _mm256_setzero_ps() }
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> V {
        unsafe { _mm256_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn load_masked(p: *const f32, m: M) -> V {
        unsafe { _mm256_maskload_ps(p, m) }
    }
    #[inline(always)]
    unsafe fn store_masked(p: *mut f32, m: M, v: V) {
        unsafe { _mm256_maskstore_ps(p, m, v) }
    }
    #[inline(always)]
    unsafe fn splat(x: f32) -> V {
        unsafe { _mm256_set1_ps(x) }
    }
    #[inline(always)]
    unsafe fn fma(a: V, b: V, c: V) -> V {
        unsafe { _mm256_fmadd_ps(a, b, c) }
    }
    /// Lanes `0..len` on (len ≤ 8).
    #[inline(always)]
    unsafe fn mask(len: usize) -> M {
        const ON: [i32; 16] = [-1, -1, -1, -1, -1, -1, -1, -1, 0, 0, 0, 0, 0, 0, 0, 0];
        // SAFETY: 8 − len ≥ 0 and 8 − len + 8 ≤ 16.
        unsafe { _mm256_loadu_si256(ON.as_ptr().add(8 - len) as *const __m256i) }
    }

    vector_path!("avx2,fma");
}

/// AVX-512F: 16 lanes, masks as bit masks.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    // SAFETY of every helper here: `vector_path!` calls them only inside `product`, compiled for
    // AVX-512F, which only runs on a CPU that has it, with pointers inside the operands.
    const LANES: usize = 16;
    type V = __m512;
    type M = __mmask16;

    #[inline(always)]
    unsafe fn zero() -> V {
        unsafe { _mm512_setzero_ps() }
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> V {
        unsafe { _mm512_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn load_masked(p: *const f32, m: M) -> V {
        unsafe { _mm512_maskz_loadu_ps(m, p) }
    }
    #[inline(always)]
    unsafe fn store_masked(p: *mut f32, m: M, v: V) {
        unsafe { _mm512_mask_storeu_ps(p, m, v) }
    }
    #[inline(always)]
    unsafe fn splat(x: f32) -> V {
        unsafe { _mm512_set1_ps(x) }
    }
    #[inline(always)]
    unsafe fn fma(a: V, b: V, c: V) -> V {
        unsafe { _mm512_fmadd_ps(a, b, c) }
    }
    /// Lanes `0..len` on (len ≤ 16).
    #[inline(always)]
    unsafe fn mask(len: usize) -> M {
        ((1u32 << len) - 1) as M
    }

    vector_path!("avx512f");
}

#[cfg(test)]
mod bounds {
    use super::check_operands;

    /// Strides whose reach wraps past usize::MAX (to 0 here, 2 · 2^63) are out of bounds; in a
    /// release build an unchecked product wrapped, passed the check, and the kernels read far
    /// outside A.
    #[test]
    #[should_panic(expected = "product operand out of bounds")]
    fn a_stride_that_wraps_is_out_of_bounds() {
        let (a, b, dst) = (vec![0.0f32; 4], vec![0.0f32; 4], vec![0.0f32; 6]);
        check_operands(3, 2, 2, &dst, (&a, 1 << 63, 1), (&b, 2, 1));
    }

    #[test]
    fn operands_that_fit_pass() {
        let (a, b, dst) = (vec![0.0f32; 6], vec![0.0f32; 4], vec![0.0f32; 6]);
        check_operands(3, 2, 2, &dst, (&a, 2, 1), (&b, 2, 1));
    }
}
