//! Adam (Kingma & Ba 2015) with PyTorch's defaults (β = 0.9, 0.999, ε = 1e-8), over one `Mlp`.
//!
//! burn ships an Adam, but its state is keyed by parameter ids that are not stable across
//! processes and its ε default differs from PyTorch's. Ours is the same ten lines of arithmetic
//! with its moments stored per parameter in `Mlp::tensors()` order, so a resumed run continues
//! from exactly the state an uninterrupted one would have.

use burn::module::Param;
use burn::tensor::{Device, Gradients, Tensor, TensorData};

use super::{Mlp, host};

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

pub struct Adam {
    pub lr: f64,
    /// Steps taken (for the bias corrections).
    pub step: u64,
    /// First and second moments: for layer i, `[2i]` is the weight's and `[2i+1]` the bias's.
    m: Vec<Moment>,
    v: Vec<Moment>,
}

/// A moment tensor of either rank (weights are 2-D, biases 1-D).
#[derive(Clone)]
enum Moment {
    W(Tensor<2>),
    B(Tensor<1>),
}

impl Adam {
    pub fn new(lr: f64, net: &Mlp) -> Adam {
        let zeros: Vec<Moment> = net
            .layers
            .iter()
            .flat_map(|l| [Moment::W(l.weight.val().zeros_like()), Moment::B(l.bias.val().zeros_like())])
            .collect();
        Adam { lr, step: 0, m: zeros.clone(), v: zeros }
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
        for (i, (layer, leaf)) in net.layers.iter_mut().zip(&tracked.layers).enumerate() {
            let gw = leaf.weight.val().grad(grads).expect("every weight is used by the loss");
            let gb = leaf.bias.val().grad(grads).expect("every bias is used by the loss");
            let (Moment::W(mw), Moment::W(vw)) = (&self.m[2 * i], &self.v[2 * i]) else { unreachable!() };
            let (mw, vw, w) = update(layer.weight.val(), gw, mw.clone(), vw.clone(), step_size, bc2_sqrt);
            let (Moment::B(mb), Moment::B(vb)) = (&self.m[2 * i + 1], &self.v[2 * i + 1]) else { unreachable!() };
            let (mb, vb, b) = update(layer.bias.val(), gb, mb.clone(), vb.clone(), step_size, bc2_sqrt);
            layer.weight = Param::from_tensor(w);
            layer.bias = Param::from_tensor(b);
            self.m[2 * i] = Moment::W(mw);
            self.v[2 * i] = Moment::W(vw);
            self.m[2 * i + 1] = Moment::B(mb);
            self.v[2 * i + 1] = Moment::B(vb);
        }
    }

    /// The moments as flat host vectors, `m` then `v`, each in `Mlp::tensors()` order.
    pub fn state(&self) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        let flat = |ms: &[Moment]| ms.iter().map(moment_host).collect();
        (flat(&self.m), flat(&self.v))
    }

    /// Restores moments saved by `state()`.
    pub fn set_state(&mut self, step: u64, m: &[Vec<f32>], v: &[Vec<f32>], device: &Device) {
        self.step = step;
        let load = |old: &Moment, values: &Vec<f32>| match old {
            Moment::W(t) => Moment::W(Tensor::from_data(TensorData::new(values.clone(), t.dims()), device)),
            Moment::B(t) => Moment::B(Tensor::from_data(TensorData::new(values.clone(), t.dims()), device)),
        };
        self.m = self.m.iter().zip(m).map(|(o, x)| load(o, x)).collect();
        self.v = self.v.iter().zip(v).map(|(o, x)| load(o, x)).collect();
    }
}

fn moment_host(m: &Moment) -> Vec<f32> {
    match m {
        Moment::W(t) => host(t.clone()).1,
        Moment::B(t) => host(t.clone()).1,
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
