//! One stack of networks on the device: its forward and backward passes as batched products
//! with the elementwise work in kernels, Adam, and the input rows, in the launches `mod.rs`
//! sequences into an update (the CPU engine's `fused/net.rs`, on the device).

use anyhow::{Context, Result};

use super::NetBufs;
use super::device::{Arg, Gemm, Gpu, Mat, Ptr, at};
use crate::agent::fused::{ADAM_BETAS, Shape};

/// A view of `items` networks of one shape for a product: member b's parameters at
/// `params + b·member_stride` (the critic 1 of each agent: the critics' buffer, stride K·len).
#[derive(Clone, Copy)]
pub(super) struct View {
    pub(super) params: Ptr,
    pub(super) member_stride: usize,
    pub(super) items: usize,
}

/// `pgser_inputs`: the normalized (s, g[, a]) rows of `agents` agents, `copies` times each
/// (the critics' copies), into `out.0` (and (s', g) into `out.1` when `src.2`, next_obs, is set).
/// `dims` = (obs, goal, action columns); `src` = (obs, goal, next_obs, action) pointers (0: none).
#[allow(clippy::too_many_arguments)]
pub(super) fn inputs(
    gpu: &mut dyn Gpu,
    agents: usize,
    copies: usize,
    n: usize,
    dims: (usize, usize, usize),
    src: (Ptr, Ptr, Ptr, Ptr),
    norm: (Ptr, Ptr, Ptr),
    out: (Ptr, Ptr),
) -> Result<()> {
    let (od, gd, act) = dims;
    gpu.launch(
        "pgser_inputs",
        agents * copies * n * (od + gd + act),
        &[
            Arg::I(agents as i32),
            Arg::I(copies as i32),
            Arg::I(n as i32),
            Arg::I(od as i32),
            Arg::I(gd as i32),
            Arg::I(act as i32),
            Arg::P(src.0),
            Arg::P(src.1),
            Arg::P(src.2),
            Arg::P(src.3),
            Arg::P(norm.0),
            Arg::P(norm.1),
            Arg::P(norm.2),
            Arg::P(out.0),
            Arg::P(out.1),
        ],
    )
}

/// Forward pass of `view.items` networks of `shape` on `n` rows each: `outs[l]` `[items, n, d]`
/// gets layer l's output, ReLU'd below the top. `x` is the first layer's input.
pub(super) fn forward(
    gpu: &mut dyn Gpu,
    shape: &Shape,
    view: View,
    x: Mat,
    outs: &[Ptr],
    n: usize,
    p: usize,
) -> Result<()> {
    let top = shape.layers() - 1;
    for l in 0..shape.layers() {
        let (din, dout) = (shape.sizes[l], shape.sizes[l + 1]);
        let a = if l == 0 { x } else { Mat { ptr: outs[l - 1], ld: din, trans: false, stride: n * din } };
        gpu.gemm(&Gemm {
            m: n,
            n: dout,
            k: din,
            a,
            b: Mat { ptr: at(view.params, shape.weight(l).start), ld: dout, trans: false, stride: view.member_stride },
            c: Mat { ptr: outs[l], ld: dout, trans: false, stride: n * dout },
            batch: view.items,
            parts: Some(p),
        })?;
        gpu.launch(
            "pgser_bias_act",
            view.items * n * dout,
            &[
                Arg::L((view.items * n) as i64),
                Arg::I(dout as i32),
                Arg::P(outs[l]),
                Arg::P(view.params),
                Arg::L(view.member_stride as i64),
                Arg::L(shape.bias(l).start as i64),
                Arg::I(n as i32),
                Arg::I((l < top) as i32),
            ],
        )?;
    }
    Ok(())
}

/// Backward pass of `view.items` networks from G = ∂loss/∂(top layer's output) in `g.0`
/// (`[items, n, out]`; `g.1` is scratch of the same size; both are overwritten). With `grad`,
/// writes each (network, part)'s ∂W and ∂b into `grad` (`[items, p, len]`); with `dx = (ptr,
/// from)`, the gradient of the input columns `from..` into `ptr` (`[items, n, in − from]`).
#[allow(clippy::too_many_arguments)]
pub(super) fn backward(
    gpu: &mut dyn Gpu,
    shape: &Shape,
    view: View,
    x: Mat,
    outs: &[Ptr],
    g: (Ptr, Ptr),
    grad: Option<Ptr>,
    dx: Option<(Ptr, usize)>,
    n: usize,
    p: usize,
) -> Result<()> {
    let (mut g, mut tmp) = g;
    let top = shape.layers() - 1;
    let items = view.items;
    let len = shape.len;
    if let Some(grad) = grad {
        let dout = shape.sizes[top + 1];
        gpu.launch(
            "pgser_bias_grad",
            items * p * dout,
            &[
                Arg::L(items as i64),
                Arg::I(n as i32),
                Arg::I(p as i32),
                Arg::I(dout as i32),
                Arg::P(g),
                Arg::P(grad),
                Arg::L(len as i64),
                Arg::L(shape.bias(top).start as i64),
            ],
        )?;
    }
    for l in (0..=top).rev() {
        let (din, dout) = (shape.sizes[l], shape.sizes[l + 1]);
        let input = if l == 0 { x } else { Mat { ptr: outs[l - 1], ld: din, trans: false, stride: n * din } };
        let w = at(view.params, shape.weight(l).start);
        if let Some(grad) = grad {
            // ∂W = inputᵀ·G, part by part (each part's its own, added by Adam in part order).
            for q in 0..p {
                let (start, end) = (n * q / p, n * (q + 1) / p);
                gpu.gemm(&Gemm {
                    m: din,
                    n: dout,
                    k: end - start,
                    a: Mat { ptr: at(input.ptr, start * input.ld), ld: input.ld, trans: true, stride: input.stride },
                    b: Mat { ptr: at(g, start * dout), ld: dout, trans: false, stride: n * dout },
                    c: Mat { ptr: at(grad, q * len + shape.weight(l).start), ld: dout, trans: false, stride: p * len },
                    batch: items,
                    parts: None,
                })?;
            }
        }
        let g_rows = Mat { ptr: g, ld: dout, trans: false, stride: n * dout };
        if l > 0 {
            // G·Wᵀ, masked by the ReLU below, with that layer's ∂b in the same pass.
            gpu.gemm(&Gemm {
                m: n,
                n: din,
                k: dout,
                a: g_rows,
                b: Mat { ptr: w, ld: dout, trans: true, stride: view.member_stride },
                c: Mat { ptr: tmp, ld: din, trans: false, stride: n * din },
                batch: items,
                parts: Some(p),
            })?;
            gpu.launch(
                "pgser_relu_mask",
                items * p * din,
                &[
                    Arg::L(items as i64),
                    Arg::I(n as i32),
                    Arg::I(p as i32),
                    Arg::I(din as i32),
                    Arg::P(tmp),
                    Arg::P(outs[l - 1]),
                    Arg::P(grad.unwrap_or(0)),
                    Arg::L(len as i64),
                    Arg::L(shape.bias(l - 1).start as i64),
                ],
            )?;
            std::mem::swap(&mut g, &mut tmp);
        } else if let Some((dx, from)) = dx {
            // The input columns from..din only: rows from..din of W.
            let cols = din - from;
            gpu.gemm(&Gemm {
                m: n,
                n: cols,
                k: dout,
                a: g_rows,
                b: Mat { ptr: at(w, from * dout), ld: dout, trans: true, stride: view.member_stride },
                c: Mat { ptr: dx, ld: cols, trans: false, stride: n * cols },
                batch: items,
                parts: Some(p),
            })?;
        }
    }
    Ok(())
}

/// Adam and, when this update's constants say so, Polyak, on `members` networks of `len`.
pub(super) fn adam(
    gpu: &mut dyn Gpu,
    net: &NetBufs,
    members: usize,
    len: usize,
    p: usize,
    grad: Ptr,
    consts: Ptr,
) -> Result<()> {
    gpu.launch(
        "pgser_adam",
        members * len,
        &[
            Arg::L(members as i64),
            Arg::L(len as i64),
            Arg::I(p as i32),
            Arg::P(net.p),
            Arg::P(net.m),
            Arg::P(net.v),
            Arg::P(net.target),
            Arg::P(grad),
            Arg::P(consts),
            Arg::F(ADAM_BETAS.0),
            Arg::F(ADAM_BETAS.1),
            Arg::F(ADAM_BETAS.2),
            Arg::F(ADAM_BETAS.3),
            Arg::F(ADAM_BETAS.4),
        ],
    )
    .context("Adam")
}
