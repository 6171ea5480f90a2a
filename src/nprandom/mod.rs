//! `numpy.random` in Rust, bit for bit: `Generator(PCG64(SeedSequence(seed)))`, the generator
//! `np.random.default_rng(seed)` and gymnasium's `seeding.np_random(seed)` build.
//!
//! It is the bottom of pgser's randomness, below every stage that draws: the environments' resets,
//! collect's policies, swap, score, the samplers, the agents' initialisation and noise, and the
//! reports. It sits in a module of its own (it used to live in `env/`) because all of them share
//! it and none of them owns it.
//!
//! Why numpy's generator and not a Rust RNG: gymnasium's environments draw object and goal
//! positions from it, so `reset(Some(seed))` here gives the same episode as `env.reset(seed=seed)`
//! in Python, and a dataset or an evaluation made by one can be checked against the other; and
//! every other stream pgser draws can be recomputed from Python with numpy alone.
//!
//! What equals which numpy function, and the test that checks it:
//!
//! | here | numpy | checked by |
//! |---|---|---|
//! | [`seed_sequence_state`] | `SeedSequence(seed).generate_state(4, np.uint64)` | `tests::seed_sequence_matches_numpy` |
//! | [`seed_sequence_state_spawned`], [`NpRandom::spawned`] | `SeedSequence(seed, spawn_key=key)`, child `key` of `.spawn(n)` | `tests::spawned_streams_match_numpy` |
//! | [`NpRandom::next_u64`] | `Generator.bit_generator.random_raw()` | `tests::doubles_match_numpy` |
//! | [`NpRandom::random`] | `Generator.random()` | `tests::doubles_match_numpy`; 1,000 draws for 5 seeds in `tests/env_parity.rs` `numpy_generator_is_reproduced` |
//! | [`NpRandom::uniform`], [`NpRandom::uniform_n`] | `Generator.uniform(low, high[, size])` | `tests::uniform_is_affine_in_the_double`; `numpy_generator_is_reproduced` |
//! | [`ziggurat::Ziggurat::standard_normal`], [`ziggurat::Ziggurat::normal`] | `Generator.standard_normal()`, `Generator.normal(loc, scale)` | `numpy_generator_is_reproduced` (needs numpy's tables from `make deps`) |
//!
//! Two draws are pgser's own and equal no numpy function: [`NpRandom::below`] (Lemire's
//! multiply-shift, not numpy's `integers`) and [`NpRandom::standard_normal`] (Box–Muller from two
//! `random()` draws, recomputable from `rng.random(2)`); `tests::normals_have_unit_variance`
//! checks the latter's moments.
//!
//! Ported from numpy's `bit_generator.pyx` (SeedSequence), `pcg64.h` (PCG64 XSL-RR 128/64) and
//! `distributions.c` (`next_double`, `random_uniform`, `random_standard_normal`).

pub mod legacy;
pub mod ziggurat;

/// SeedSequence's hash constants (numpy `bit_generator.pyx`).
const INIT_A: u32 = 0x43b0_d7e5;
const MULT_A: u32 = 0x931e_8875;
const INIT_B: u32 = 0x8b51_f9dd;
const MULT_B: u32 = 0x58f3_8ded;
const MIX_MULT_L: u32 = 0xca01_f9dd;
const MIX_MULT_R: u32 = 0x4973_f715;
const XSHIFT: u32 = 16;
/// numpy's default pool size: four 32-bit words.
const POOL_SIZE: usize = 4;
/// PCG's default 128-bit LCG multiplier (`PCG_DEFAULT_MULTIPLIER_128`).
const PCG_MULT: u128 = 0x2360_ed05_1fc6_5da4_4385_df64_9fcc_f645;

/// `hashmix` mutates its constant as it goes, so every call depends on all earlier ones.
fn hashmix(value: u32, hash_const: &mut u32) -> u32 {
    let mut v = value ^ *hash_const;
    *hash_const = hash_const.wrapping_mul(MULT_A);
    v = v.wrapping_mul(*hash_const);
    v ^ (v >> XSHIFT)
}

fn mix(x: u32, y: u32) -> u32 {
    let r = MIX_MULT_L.wrapping_mul(x).wrapping_sub(MIX_MULT_R.wrapping_mul(y));
    r ^ (r >> XSHIFT)
}

/// A non-negative Python int as numpy coerces it: 32-bit words, least significant first, and a
/// single zero word for 0.
fn entropy_words(seed: u64) -> Vec<u32> {
    let (lo, hi) = (seed as u32, (seed >> 32) as u32);
    if hi == 0 { vec![lo] } else { vec![lo, hi] }
}

/// `SeedSequence(seed).generate_state(4, np.uint64)`: the 256 bits PCG64 is seeded from.
pub fn seed_sequence_state(seed: u64) -> [u64; 4] {
    seed_sequence_state_spawned(seed, &[])
}

/// `SeedSequence(seed, spawn_key=key).generate_state(4, np.uint64)`. numpy pads the seed's
/// words to the pool size before appending the spawn key's, so a spawned stream's entropy is
/// never that of a plain seed.
pub fn seed_sequence_state_spawned(seed: u64, spawn_key: &[u64]) -> [u64; 4] {
    let mut entropy = entropy_words(seed);
    if !spawn_key.is_empty() {
        entropy.resize(entropy.len().max(POOL_SIZE), 0);
        entropy.extend(spawn_key.iter().flat_map(|&k| entropy_words(k)));
    }
    // mix_entropy: hash the entropy into the pool, then mix every word into every other.
    let mut pool = [0u32; POOL_SIZE];
    let mut hc = INIT_A;
    for (i, p) in pool.iter_mut().enumerate() {
        *p = hashmix(entropy.get(i).copied().unwrap_or(0), &mut hc);
    }
    for src in 0..POOL_SIZE {
        for dst in 0..POOL_SIZE {
            if src != dst {
                pool[dst] = mix(pool[dst], hashmix(pool[src], &mut hc));
            }
        }
    }
    // Entropy longer than the pool (a spawn key) is folded into every pool word.
    for &word in entropy.iter().skip(POOL_SIZE) {
        for p in pool.iter_mut() {
            *p = mix(*p, hashmix(word, &mut hc));
        }
    }
    // generate_state: 8 u32 words cycling over the pool, paired little-endian into u64s.
    let mut hc = INIT_B;
    let mut words = [0u32; 2 * POOL_SIZE];
    for (i, w) in words.iter_mut().enumerate() {
        let mut v = pool[i % POOL_SIZE] ^ hc;
        hc = hc.wrapping_mul(MULT_B);
        v = v.wrapping_mul(hc);
        *w = v ^ (v >> XSHIFT);
    }
    std::array::from_fn(|i| words[2 * i] as u64 | (words[2 * i + 1] as u64) << 32)
}

/// numpy's `Generator(PCG64(SeedSequence(seed)))`, for the draws the Fetch tasks make.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NpRandom {
    state: u128,
    inc: u128,
}

impl NpRandom {
    /// The generator gymnasium's `env.reset(seed=seed)` creates.
    pub fn new(seed: u64) -> NpRandom {
        Self::from_state(seed_sequence_state(seed))
    }

    /// `default_rng(SeedSequence(seed, spawn_key=key))`, i.e. child `key` of
    /// `SeedSequence(seed).spawn(...)`: numpy's way to give parallel workers independent streams.
    pub fn spawned(seed: u64, spawn_key: &[u64]) -> NpRandom {
        Self::from_state(seed_sequence_state_spawned(seed, spawn_key))
    }

    fn from_state(s: [u64; 4]) -> NpRandom {
        let initstate = (s[0] as u128) << 64 | s[1] as u128;
        let initseq = (s[2] as u128) << 64 | s[3] as u128;
        // pcg_setseq_128_srandom_r
        let mut rng = NpRandom { state: 0, inc: initseq << 1 | 1 };
        rng.advance();
        rng.state = rng.state.wrapping_add(initstate);
        rng.advance();
        rng
    }

    /// The generator's full state, (state, increment) as four words, for checkpoints.
    pub fn words(&self) -> [u64; 4] {
        [(self.state >> 64) as u64, self.state as u64, (self.inc >> 64) as u64, self.inc as u64]
    }

    /// A generator continuing exactly where the one `words()` was taken from stopped.
    pub fn from_words(w: [u64; 4]) -> NpRandom {
        NpRandom { state: (w[0] as u128) << 64 | w[1] as u128, inc: (w[2] as u128) << 64 | w[3] as u128 }
    }

    /// An integer uniform in [0, n): the high word of a 64×64-bit product (Lemire), whose bias
    /// (< n/2⁶⁴) is far below anything a batch of samples can detect.
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    fn advance(&mut self) {
        self.state = self.state.wrapping_mul(PCG_MULT).wrapping_add(self.inc);
    }

    /// One raw 64-bit output (`bit_generator.random_raw()`): advance, then XSL-RR of the new state.
    pub fn next_u64(&mut self) -> u64 {
        self.advance();
        let s = self.state;
        ((s >> 64) as u64 ^ s as u64).rotate_right((s >> 122) as u32)
    }

    /// `Generator.random()`: the top 53 bits as a double in [0, 1).
    pub fn random(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    /// `Generator.uniform(low, high)`: numpy computes `low + (high - low) * random()`, in this
    /// order; a different but algebraically equal formula would change the last bits.
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        let range = high - low;
        low + range * self.random()
    }

    /// `Generator.uniform(low, high, size=N)`: N draws in order.
    pub fn uniform_n<const N: usize>(&mut self, low: f64, high: f64) -> [f64; N] {
        std::array::from_fn(|_| self.uniform(low, high))
    }

    /// A standard normal by Box–Muller from two `random()` draws: `sqrt(-2 ln(1 − u1)) ·
    /// cos(2π u2)`. Not numpy's ziggurat ([`ziggurat`] is, for the hand resets that need it), but a
    /// fixed, documented function of the numpy stream, so Python can recompute it from `rng.random(2)`.
    pub fn standard_normal(&mut self) -> f64 {
        let (u1, u2) = (self.random(), self.random());
        (-2.0 * (1.0 - u1).ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Values printed by numpy 2.4 (`SeedSequence(s).generate_state(4, np.uint64)`,
    // `default_rng(s).random(3)`); tests/env_parity.rs compares 1000 draws for more seeds.
    #[test]
    fn seed_sequence_matches_numpy() {
        assert_eq!(
            seed_sequence_state(0),
            [0xdb2cd7e7b0f478be, 0xabf4641a2c71ba49, 0x20c6ed6d9d7b8d41, 0x2c4099de223c39d4]
        );
        assert_eq!(
            seed_sequence_state((1 << 32) + 5),
            [0xf9c15bd6e249d9ac, 0xb2021b4036320ed7, 0x9388b47fe6dcf739, 0x5eeba8d9ad6439e1]
        );
    }

    #[test]
    fn doubles_match_numpy() {
        let mut r = NpRandom::new(0);
        let got = [r.random(), r.random(), r.random()];
        assert_eq!(got, [0.6369616873214543, 0.2697867137638703, 0.04097352393619469]);
        let mut r = NpRandom::new((1 << 32) + 5);
        let got = [r.random(), r.random(), r.random()];
        assert_eq!(got, [0.7742041803738812, 0.47072268318809307, 0.6958803443421149]);
        assert_eq!(NpRandom::new(0).next_u64(), 0xa30febcfd9c2825f);
    }

    // `SeedSequence(s, spawn_key=(k,))`, printed by numpy 2.4.
    #[test]
    fn spawned_streams_match_numpy() {
        assert_eq!(
            seed_sequence_state_spawned(5, &[3]),
            [0xb79a6962ae8b0426, 0x257968387a6d6859, 0x8956311e2651165c, 0xcdefe6cef7f54a51]
        );
        assert_eq!(
            seed_sequence_state_spawned((1 << 32) + 5, &[7]),
            [0xd00c1e250913d159, 0x11ec8ce4cce92b3f, 0xd31152587460545a, 0x1f3d6f650104d3e2]
        );
        let mut r = NpRandom::spawned(123, &[1 << 40]);
        assert_eq!([r.random(), r.random()], [0.1807057134257054, 0.8260375535779318]);
        let mut r = NpRandom::spawned(0, &[0]);
        assert_eq!([r.random(), r.random()], [0.9429375528828794, 0.3163371523854981]);
        assert_ne!(NpRandom::spawned(0, &[0]), NpRandom::new(0));
    }

    #[test]
    fn normals_have_unit_variance() {
        let mut r = NpRandom::new(3);
        let x: Vec<f64> = (0..20_000).map(|_| r.standard_normal()).collect();
        let mean = x.iter().sum::<f64>() / x.len() as f64;
        let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / x.len() as f64;
        assert!(mean.abs() < 0.03 && (var - 1.0).abs() < 0.03, "mean {mean}, var {var}");
    }

    #[test]
    fn uniform_is_affine_in_the_double() {
        let (mut a, mut b) = (NpRandom::new(7), NpRandom::new(7));
        let u: [f64; 3] = a.uniform_n(-0.15, 0.15);
        for x in u {
            assert_eq!(x, -0.15 + 0.3 * b.random());
            assert!((-0.15..0.15).contains(&x));
        }
    }
}
