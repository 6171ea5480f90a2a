//! Adam (Kingma & Ba 2015) with PyTorch's defaults (β = 0.9, 0.999, ε = 1e-8), over one `Mlp`.
//!
//! burn ships an Adam, but its state is keyed by parameter ids that are not stable across
//! processes and its ε default differs from PyTorch's. Ours is the same ten lines of arithmetic
//! with its moments stored per parameter in `Mlp::tensors()` order, so a resumed run continues
//! from exactly the state an uninterrupted one would have.

use burn::module::Param;
use burn::tensor::{Device, Gradients, Tensor};

use super::Mlp;

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

    /// The moments as flat host vectors, `m` then `v`, each in `Mlp::tensors()` order.
    pub fn state(&self) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        let flat = |net: &Mlp| net.tensors().into_iter().map(|(_, values)| values).collect();
        (flat(&self.m), flat(&self.v))
    }

    /// Restores moments saved by `state()`.
    pub fn set_state(&mut self, step: u64, m: &[Vec<f32>], v: &[Vec<f32>], device: &Device) {
        self.step = step;
        self.m.set_tensors(m, device);
        self.v.set_tensors(v, device);
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
