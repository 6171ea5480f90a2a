//! numpy's legacy global generator, `np.random.seed(s)` then `np.random.uniform` / `randint`:
//! MT19937 (`RandomState`), bit for bit.
//!
//! OGBench's maze environments draw their start and goal noise, and their random task, from this
//! global generator, not from the environment's seeded one (`env.reset(seed=s)` leaves it alone),
//! so reproducing one of its episodes means seeding this as `np.random.seed(s)` does. An integer
//! seed goes through MT19937's `init_genrand` (numpy's `_legacy_seeding` for a scalar); a double is
//! `random_sample`'s 53 bits from two 32-bit outputs; `randint(n)` masks a 32-bit output to the
//! next power of two and rejects values ≥ n. `normal` is numpy's legacy polar Box–Muller, which
//! makes values in pairs and keeps the second for the next call (`np.random.seed` drops it).

const N: usize = 624;
const M: usize = 397;

pub struct RandomState {
    mt: [u32; N],
    index: usize,
    /// The second value of the last Box–Muller pair, not yet returned.
    gauss: Option<f64>,
}

impl RandomState {
    /// `np.random.seed(seed)` for a seed in [0, 2³²).
    pub fn new(seed: u32) -> RandomState {
        let mut mt = [0u32; N];
        mt[0] = seed;
        for i in 1..N {
            mt[i] = 1_812_433_253u32.wrapping_mul(mt[i - 1] ^ (mt[i - 1] >> 30)).wrapping_add(i as u32);
        }
        RandomState { mt, index: N, gauss: None }
    }

    fn generate(&mut self) {
        for i in 0..N {
            let y = (self.mt[i] & 0x8000_0000) | (self.mt[(i + 1) % N] & 0x7fff_ffff);
            let mut v = self.mt[(i + M) % N] ^ (y >> 1);
            if y & 1 != 0 {
                v ^= 0x9908_b0df;
            }
            self.mt[i] = v;
        }
        self.index = 0;
    }

    /// One 32-bit output.
    pub fn next_u32(&mut self) -> u32 {
        if self.index >= N {
            self.generate();
        }
        let mut y = self.mt[self.index];
        self.index += 1;
        y ^= y >> 11;
        y ^= (y << 7) & 0x9d2c_5680;
        y ^= (y << 15) & 0xefc6_0000;
        y ^ (y >> 18)
    }

    /// `np.random.random_sample()`: [0, 1) with 53 random bits.
    pub fn random_sample(&mut self) -> f64 {
        let a = (self.next_u32() >> 5) as f64;
        let b = (self.next_u32() >> 6) as f64;
        (a * 67_108_864.0 + b) / 9_007_199_254_740_992.0
    }

    /// `np.random.uniform(low, high)`: `low + (high − low)·random_sample()`.
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * self.random_sample()
    }

    /// `np.random.standard_normal()` (numpy's `legacy_gauss`): draw points of the square until
    /// one falls inside the unit circle (and not at its centre), return `f·x2` and keep `f·x1`.
    pub fn standard_normal(&mut self) -> f64 {
        if let Some(g) = self.gauss.take() {
            return g;
        }
        loop {
            let x1 = 2.0 * self.random_sample() - 1.0;
            let x2 = 2.0 * self.random_sample() - 1.0;
            let r2 = x1 * x1 + x2 * x2;
            if r2 < 1.0 && r2 != 0.0 {
                let f = (-2.0 * r2.ln() / r2).sqrt();
                self.gauss = Some(f * x1);
                return f * x2;
            }
        }
    }

    /// `np.random.normal(loc, scale)`: `loc + scale·standard_normal()`; with `size=k`, k calls.
    pub fn normal(&mut self, loc: f64, scale: f64) -> f64 {
        loc + scale * self.standard_normal()
    }

    /// `np.random.randint(n)` for n ≥ 1: [0, n).
    pub fn randint(&mut self, n: u32) -> u32 {
        assert!(n >= 1, "randint(0)");
        let max = n - 1;
        if max == 0 {
            return 0; // numpy draws nothing for a range of one
        }
        let mask = u32::MAX >> max.leading_zeros();
        loop {
            let v = self.next_u32() & mask;
            if v <= max {
                return v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values printed by numpy 2.4.6: `np.random.seed(s)`, then the calls below.
    #[test]
    fn equals_numpys_global_generator() {
        let mut r = RandomState::new(0);
        let u: Vec<f64> = (0..4).map(|_| r.uniform(-1.0, 1.0)).collect();
        assert_eq!(u, [0.0976270078546495, 0.43037873274483895, 0.20552675214328775, 0.08976636599379373]);
        let mut r = RandomState::new(1);
        let u: Vec<f64> = (0..4).map(|_| r.uniform(-1.0, 1.0)).collect();
        assert_eq!(u, [-0.165955990594852, 0.4406489868843162, -0.9997712503653102, -0.39533485473632046]);
        let mut r = RandomState::new(0);
        assert_eq!(r.random_sample(), 0.5488135039273248);
        // randint(5) ×8, randint(1, 6) ×4 (= 1 + randint(5)), randint(3), randint(1) after seed(5).
        let mut r = RandomState::new(5);
        let a: Vec<u32> = (0..8).map(|_| r.randint(5)).collect();
        let b: Vec<u32> = (0..4).map(|_| 1 + r.randint(5)).collect();
        assert_eq!((a, b, r.randint(3), r.randint(1)), (vec![3, 0, 1, 0, 4, 3, 0, 0], vec![5, 2, 1, 4], 0, 0));
    }

    /// numpy 2.4.6: `np.random.seed(7)`; `normal(0, .5, 2)` twice, `normal(1, 2)`, `randint(10)`,
    /// `normal(0, .5, 3)` (its third value starts a pair and leaves one kept).
    #[test]
    fn normal_draws_pairs_as_numpy_does() {
        let mut r = RandomState::new(7);
        let mut v: Vec<f64> = (0..4).map(|_| r.normal(0.0, 0.5)).collect();
        v.push(r.normal(1.0, 2.0));
        assert_eq!(r.randint(10), 8);
        v.extend((0..3).map(|_| r.normal(0.0, 0.5)));
        let want = [
            0.845262851900178,
            -0.2329686852704164,
            0.0164100818392922,
            0.20375814149825391,
            -0.5778460572514772,
            0.001032786452974065,
            1.0128857620685174,
            -0.0006640252380790819,
        ];
        assert_eq!(v, want);
    }
}
