//! Adam (Kingma & Ba 2015) with PyTorch's defaults (β = 0.9, 0.999, ε = 1e-8), over one `Mlp`.
//!
//! burn ships an Adam, but its state is keyed by parameter ids that are not stable across
//! processes and its ε default differs from PyTorch's. Ours is the same ten lines of arithmetic
//! with its moments held as networks of the parameters' own (stacked) shapes, so a resumed run
//! continues from exactly the state an uninterrupted one would have. Adam is elementwise, so one
//! optimizer over a stack of agents is each agent's own Adam.

use burn::module::Param;
use burn::tensor::{Device, Gradients, Tensor};

use super::{Member, Mlp};

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

pub struct Adam {
    pub lr: f64,
    /// Steps taken (for the bias corrections).
    pub step: u64,
    /// First and second moments: each has exactly the network's shapes, so each is held as an
    /// `Mlp` and saved and restored with the network's own `tensors` / `set_tensors`.
    m: Mlp,
    v: Mlp,
}

impl Adam {
    pub fn new(lr: f64, net: &Mlp) -> Adam {
        Adam { lr, step: 0, m: net.zeros_like(), v: net.zeros_like() }
    }

    /// One step on `net` from the gradients of `tracked` (the autodiff copy the loss was built
    /// from). The new parameters are plain tensors.
    pub fn step(&mut self, net: &mut Mlp, tracked: &Mlp, grads: &Gradients) {
        self.step += 1;
        let t = self.step as i32;
        let bc1 = 1.0 - BETA1.powi(t);
        let bc2 = 1.0 - BETA2.powi(t);
        // p ← p − lr/bc1 · m / (√v/√bc2 + ε), PyTorch's formulation.
        let step_size = self.lr / bc1;
        let bc2_sqrt = bc2.sqrt();
        let layers = net.layers.iter_mut().zip(&tracked.layers).zip(self.m.layers.iter_mut().zip(&mut self.v.layers));
        for ((layer, leaf), (m, v)) in layers {
            let gw = leaf.weight.val().grad(grads).expect("every weight is used by the loss");
            let gb = leaf.bias.val().grad(grads).expect("every bias is used by the loss");
            let (mw, vw, w) = update(layer.weight.val(), gw, m.weight.val(), v.weight.val(), step_size, bc2_sqrt);
            let (mb, vb, b) = update(layer.bias.val(), gb, m.bias.val(), v.bias.val(), step_size, bc2_sqrt);
            layer.weight = Param::from_tensor(w);
            layer.bias = Param::from_tensor(b);
            m.weight = Param::from_tensor(mw);
            v.weight = Param::from_tensor(vw);
            m.bias = Param::from_tensor(mb);
            v.bias = Param::from_tensor(vb);
        }
    }

    /// The moments of member `i` of the stack, `m` then `v`, each as `Mlp::member` gives them.
    pub fn member(&self, i: usize) -> (Member, Member) {
        (self.m.member(i), self.v.member(i))
    }

    /// An Adam over a stack whose members' moments are given (all at the same `step`).
    pub fn from_members(lr: f64, step: u64, m: &[Member], v: &[Member], device: &Device) -> Adam {
        Adam { lr, step, m: Mlp::from_members(m, device), v: Mlp::from_members(v, device) }
    }

    /// The optimizers of several stacks as one over their concatenation (same lr and step).
    pub fn concat(parts: &[&Adam]) -> Adam {
        let (m, v): (Vec<&Mlp>, Vec<&Mlp>) = parts.iter().map(|a| (&a.m, &a.v)).unzip();
        Adam { lr: parts[0].lr, step: parts[0].step, m: Mlp::concat(&m), v: Mlp::concat(&v) }
    }
}

fn update<const D: usize>(
    p: Tensor<D>,
    g: Tensor<D>,
    m: Tensor<D>,
    v: Tensor<D>,
    step_size: f64,
    bc2_sqrt: f64,
) -> (Tensor<D>, Tensor<D>, Tensor<D>) {
    let m = m.mul_scalar(BETA1) + g.clone().mul_scalar(1.0 - BETA1);
    let v = v.mul_scalar(BETA2) + g.square().mul_scalar(1.0 - BETA2);
    let denom = v.clone().sqrt().div_scalar(bc2_sqrt).add_scalar(EPS);
    let p = p - m.clone().div(denom).mul_scalar(step_size);
    (m, v, p)
}
