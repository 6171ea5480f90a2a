//! One network of the hand-written CPU update, on its own: where its parameters sit in a flat
//! buffer, its forward and backward passes as `gemm` products with the elementwise work folded
//! into one pass over each output, and Adam with the targets' Polyak step. The update in
//! `mod.rs` calls these for every (agent, part) and network; the derivation is in its doc comment.

use rayon::prelude::*;

use super::product::{self, Product};
use crate::agent::Member;
use crate::agent::engine::Net;

// Adam's constants as `adam.rs` has them (f64, each product rounded to f32 as burn does).
const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;
/// Most parts a batch is cut into.
pub(super) const MAX_PARTS: usize = 4;
/// Adam runs over each network in chunks of this many parameters, side by side.
const ADAM_CHUNK: usize = 16 * 1024;

/// Layer sizes of one network and where each layer's weight `[in, out]` and bias `[out]` sit in
/// its flat parameter buffer (in `Member` order: w0, b0, w1, b1, ...), and how its products
/// round (`product.rs`).
#[derive(Debug, Clone)]
pub(in crate::agent) struct Shape {
    pub(in crate::agent) sizes: Vec<usize>,
    offsets: Vec<usize>,
    pub(in crate::agent) len: usize,
    product: Product,
}

impl Shape {
    /// A network whose products are `gemm`'s (native arithmetic).
    pub(in crate::agent) fn new(sizes: &[usize]) -> Shape {
        Shape::with(sizes, Product::Native)
    }

    pub(in crate::agent) fn with(sizes: &[usize], product: Product) -> Shape {
        let mut offsets = Vec::new();
        let mut len = 0;
        for io in sizes.windows(2) {
            offsets.push(len);
            len += io[0] * io[1] + io[1];
        }
        Shape { sizes: sizes.to_vec(), offsets, len, product }
    }

    pub(in crate::agent) fn layers(&self) -> usize {
        self.sizes.len() - 1
    }

    pub(in crate::agent) fn weight(&self, l: usize) -> std::ops::Range<usize> {
        let o = self.offsets[l];
        o..o + self.sizes[l] * self.sizes[l + 1]
    }

    pub(in crate::agent) fn bias(&self, l: usize) -> std::ops::Range<usize> {
        let e = self.weight(l).end;
        e..e + self.sizes[l + 1]
    }

    pub(in crate::agent) fn widest(&self) -> usize {
        *self.sizes.iter().max().expect("a network has layers")
    }
}

/// A member's layers as one flat buffer, and back.
pub fn flatten(member: &Member) -> Vec<f32> {
    member.iter().flat_map(|(w, b)| w.iter().chain(b).copied()).collect()
}

pub(in crate::agent) fn unflatten(flat: &[f32], sizes: &[usize]) -> Member {
    let shape = Shape::new(sizes);
    (0..shape.layers()).map(|l| (flat[shape.weight(l)].to_vec(), flat[shape.bias(l)].to_vec())).collect()
}

/// The network's forward pass for `rows` rows of `x` (row stride `x_rs`, its first `sizes[0]`
/// columns the input): `outs[l]` gets layer l's output, ReLU'd below the top.
pub(super) fn forward(shape: &Shape, p: &[f32], x: &[f32], x_rs: usize, rows: usize, outs: &mut [Vec<f32>]) {
    let top = shape.layers() - 1;
    for l in 0..shape.layers() {
        let (din, dout) = (shape.sizes[l], shape.sizes[l + 1]);
        let (below, here) = outs.split_at_mut(l);
        let (input, in_rs) = if l == 0 { (x, x_rs) } else { (&below[l - 1][..], din) };
        let out = &mut here[0][..rows * dout];
        matmul(shape.product, rows, dout, din, out, (input, in_rs, 1), (&p[shape.weight(l)], dout, 1));
        let b = &p[shape.bias(l)];
        for row in out.chunks_exact_mut(dout) {
            if l == top {
                row.iter_mut().zip(b).for_each(|(y, b)| *y += b);
            } else {
                row.iter_mut().zip(b).for_each(|(y, b)| *y = (*y + b).max(0.0));
            }
        }
    }
}

/// The network's backward pass from `g` = ∂loss/∂(top layer's output) (`rows × out`,
/// overwritten; `tmp` is scratch of the same size). Writes ∂W, ∂b into `grad` when given, and
/// the gradient of the input columns `from..sizes[0]` into `dx` (`rows × (sizes[0] − from)`).
#[allow(clippy::too_many_arguments)]
pub(super) fn backward(
    shape: &Shape,
    p: &[f32],
    x: &[f32],
    x_rs: usize,
    rows: usize,
    outs: &[Vec<f32>],
    g: &mut Vec<f32>,
    tmp: &mut Vec<f32>,
    mut grad: Option<&mut Vec<f32>>,
    dx: Option<(&mut Vec<f32>, usize)>,
) {
    let top = shape.layers() - 1;
    if let Some(grad) = grad.as_deref_mut() {
        let dout = shape.sizes[top + 1];
        let db = &mut grad[shape.bias(top)];
        db.fill(0.0);
        for row in g[..rows * dout].chunks_exact(dout) {
            db.iter_mut().zip(row).for_each(|(d, x)| *d += x);
        }
    }
    for l in (0..=top).rev() {
        let (din, dout) = (shape.sizes[l], shape.sizes[l + 1]);
        let (input, in_rs) = if l == 0 { (x, x_rs) } else { (&outs[l - 1][..], din) };
        if let Some(grad) = grad.as_deref_mut() {
            // ∂W = inputᵀ·G: the input read transposed through its strides.
            matmul(
                shape.product,
                din,
                dout,
                rows,
                &mut grad[shape.weight(l)],
                (input, 1, in_rs),
                (&g[..rows * dout], dout, 1),
            );
        }
        let w = &p[shape.weight(l)];
        if l > 0 {
            // G·Wᵀ, masked by the ReLU below, with that layer's ∂b in the same pass.
            matmul(shape.product, rows, din, dout, &mut tmp[..rows * din], (&g[..rows * dout], dout, 1), (w, 1, dout));
            let mut db = grad.as_deref_mut().map(|grad| &mut grad[shape.bias(l - 1)]);
            if let Some(db) = db.as_deref_mut() {
                db.fill(0.0);
            }
            for (t, below) in tmp[..rows * din].chunks_exact_mut(din).zip(outs[l - 1].chunks_exact(din)) {
                // A select, not a branch: the loop vectorizes.
                t.iter_mut().zip(below).for_each(|(ti, &bi)| *ti = if bi > 0.0 { *ti } else { 0.0 });
                if let Some(db) = db.as_deref_mut() {
                    db.iter_mut().zip(t.iter()).for_each(|(d, x)| *d += x);
                }
            }
            std::mem::swap(g, tmp);
        } else if let Some((dx, from)) = dx {
            // The input columns from..din only: rows from..din of W.
            let cols = din - from;
            matmul(
                shape.product,
                rows,
                cols,
                dout,
                &mut dx[..rows * cols],
                (&g[..rows * dout], dout, 1),
                (&w[from * dout..], 1, dout),
            );
            return;
        }
    }
}

/// `dst` (`m × n`, row-major) = A·B, A given as (values, row stride, column stride) of an `m × k`
/// matrix and B of a `k × n` one: transposes are strides, never copies. One thread: the caller
/// spreads whole products over the pool, which keeps every sum in one fixed order. `kind`
/// says whose: `gemm`'s, or the portable order's (`product.rs`).
fn matmul(
    kind: Product,
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    a: (&[f32], usize, usize),
    b: (&[f32], usize, usize),
) {
    if let Product::Portable(path) = kind {
        product::portable(m, n, k, dst, a, b, path);
        return;
    }
    product::check_operands(m, n, k, dst, a, b);
    // SAFETY: `check_operands` above keeps every element gemm reads inside `a` and `b` and every
    // one it writes inside `dst`; `dst` is a unique borrow, so it overlaps neither input.
    unsafe {
        gemm_raw(m, n, k, dst.as_mut_ptr(), n, (a.0.as_ptr(), a.1, a.2), (b.0.as_ptr(), b.1, b.2));
    }
}

/// The CPU engine's one `gemm` call: `dst` (`m × n`, row stride `dst_rs`) = A·B, each operand
/// (pointer, row stride, column stride), on the calling thread. The CUDA engine's host shim
/// multiplies through it too, so that it rounds as the CPU engine rounds by construction.
///
/// # Safety
/// Every element the strides reach must lie inside its operand's allocation, and `dst` must
/// overlap neither input.
pub(in crate::agent) unsafe fn gemm_raw(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    dst_rs: usize,
    a: (*const f32, usize, usize),
    b: (*const f32, usize, usize),
) {
    // SAFETY: the caller's contract.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            dst_rs as isize,
            false,
            a.0,
            a.2 as isize,
            a.1 as isize,
            b.0,
            b.2 as isize,
            b.1 as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// Adam's constants as burn rounds them to f32: β₁, 1 − β₁, β₂, 1 − β₂, ε.
pub(in crate::agent) const ADAM_BETAS: (f32, f32, f32, f32, f32) =
    (BETA1 as f32, (1.0 - BETA1) as f32, BETA2 as f32, (1.0 - BETA2) as f32, EPS as f32);

/// One Adam step's constants (and, with `tau`, the Polyak weights; else 1 and 0), each rounded
/// to f32 as burn rounds a scalar. The CUDA engine's Adam kernel takes the same.
pub(in crate::agent) struct AdamStep {
    pub step_size: f32,
    pub bc2_sqrt: f32,
    pub keep: f32,
    pub take: f32,
}

pub(in crate::agent) fn adam_step(lr: f64, step: u64, tau: Option<f64>) -> AdamStep {
    let t = step as i32;
    let (keep, take) = tau.map_or((1.0, 0.0), |tau| ((1.0 - tau) as f32, tau as f32));
    AdamStep {
        step_size: (lr / (1.0 - BETA1.powi(t))) as f32,
        bc2_sqrt: (1.0 - BETA2.powi(t)).sqrt() as f32,
        keep,
        take,
    }
}

/// Adam (PyTorch's formulation, as `adam.rs`) on `net` from the sum of the parts' gradients in
/// part order, and with `tau`, the target's Polyak step from the new parameters in the same pass.
/// Every constant is rounded to f32 as burn rounds a scalar, so both engines compute alike.
pub(super) fn adam<'a>(
    net: &mut Net,
    grad: impl Fn(usize) -> &'a [f32] + Sync,
    parts: usize,
    lr: f64,
    step: u64,
    tau: Option<f64>,
) {
    let AdamStep { step_size, bc2_sqrt, keep, take } = adam_step(lr, step, tau);
    let (b1, nb1, b2, nb2, eps) = ADAM_BETAS;
    debug_assert!(parts <= MAX_PARTS);
    let Net { p, m, v, target } = net;
    p.par_chunks_mut(ADAM_CHUNK)
        .zip(m.par_chunks_mut(ADAM_CHUNK))
        .zip(v.par_chunks_mut(ADAM_CHUNK))
        .zip(target.par_chunks_mut(ADAM_CHUNK))
        .enumerate()
        .for_each(|(ci, (((p, m), v), target))| {
            let base = ci * ADAM_CHUNK;
            // In blocks, each loop a plain zip over slices, so that every one of them vectorizes.
            let mut g = [0.0f32; 256];
            for start in (0..p.len()).step_by(g.len()) {
                let len = g.len().min(p.len() - start);
                let (g, at) = (&mut g[..len], base + start..base + start + len);
                g.copy_from_slice(&grad(0)[at.clone()]);
                for q in 1..parts {
                    g.iter_mut().zip(&grad(q)[at.clone()]).for_each(|(g, x)| *g += x);
                }
                let (p, m, v) = (&mut p[start..start + len], &mut m[start..start + len], &mut v[start..start + len]);
                for (((p, m), v), g) in p.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(g.iter()) {
                    *m = *m * b1 + g * nb1;
                    *v = *v * b2 + g * g * nb2;
                    *p -= *m / (v.sqrt() / bc2_sqrt + eps) * step_size;
                }
                if tau.is_some() {
                    let t = &mut target[start..start + len];
                    t.iter_mut().zip(p.iter()).for_each(|(t, p)| *t = *t * keep + p * take);
                }
            }
        });
}
