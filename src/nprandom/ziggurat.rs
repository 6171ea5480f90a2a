//! numpy's `Generator.standard_normal` / `normal`: the 256-layer ziggurat of
//! `random_standard_normal`, with numpy's own tables.
//!
//! The hand tasks' resets add `np_random.normal(size=3, scale=0.005)` to the object position,
//! and an episode only replays Python's if those draws are numpy's to the bit (the object then
//! falls into the hand; contact dynamics amplify any difference). Recomputing the tables from
//! their defining recurrence gives values a few ulps off numpy's (they were computed once with
//! another libm), so `make deps` takes them out of the numpy wheel's `libnpyrandom.a`
//! (`scripts/numpy_ziggurat.py`) into `.deps/numpy_ziggurat.bin`, and this module reads them.
//! Box–Muller ([`NpRandom::standard_normal`]) stays what pgser's own noise uses.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{Context, Result, anyhow, ensure};

use super::NpRandom;

/// The tail cut-off r of the outermost layer, and 1/r (numpy's `ziggurat_nor_r`/`_inv_r`).
const NOR_R: f64 = 3.654_152_885_361_009;
const NOR_INV_R: f64 = 0.273_661_237_329_758_3;
const LAYERS: usize = 256;

/// numpy's three tables: acceptance bounds `ki`, layer widths `wi` (× 2⁻⁵²), densities `fi`.
pub struct Ziggurat {
    ki: [u64; LAYERS],
    wi: [f64; LAYERS],
    fi: [f64; LAYERS],
}

/// Where the tables are: `$PGSER_ZIGGURAT` if set, else an installed wheel's
/// `pgser/data/numpy_ziggurat.bin`, else where `make deps` writes them (baked in by build.rs):
/// [`crate::install`].
pub fn tables_path() -> PathBuf {
    crate::install::data_path("PGSER_ZIGGURAT", "data/numpy_ziggurat.bin", env!("PGSER_ZIGGURAT"))
}

/// The tables, read once per process.
pub fn tables() -> Result<&'static Ziggurat> {
    static TABLES: OnceLock<Result<Ziggurat, String>> = OnceLock::new();
    TABLES
        .get_or_init(|| Ziggurat::load(&tables_path()).map_err(|e| format!("{e:#}")))
        .as_ref()
        .map_err(|e| anyhow!("{e}"))
}

impl Ziggurat {
    pub fn load(path: &Path) -> Result<Ziggurat> {
        let bytes = std::fs::read(path).with_context(|| {
            format!(
                "{}: numpy's ziggurat tables are missing (the hand tasks draw numpy's normals): run `make deps`, \
                 or point PGSER_ZIGGURAT at a file scripts/numpy_ziggurat.py wrote",
                path.display()
            )
        })?;
        Self::from_bytes(&bytes).with_context(|| path.display().to_string())
    }

    /// 256 u64 `ki`, then 256 f64 `wi`, then 256 f64 `fi`, little endian.
    pub fn from_bytes(b: &[u8]) -> Result<Ziggurat> {
        ensure!(b.len() == 3 * LAYERS * 8, "{} bytes, expected {} (ki, wi, fi × 256 × 8)", b.len(), 3 * LAYERS * 8);
        let word = |t: usize, i: usize| u64::from_le_bytes(b[(t * LAYERS + i) * 8..][..8].try_into().unwrap());
        let z = Ziggurat {
            ki: std::array::from_fn(|i| word(0, i)),
            wi: std::array::from_fn(|i| f64::from_bits(word(1, i))),
            fi: std::array::from_fn(|i| f64::from_bits(word(2, i))),
        };
        // The shape every 256-layer normal ziggurat has: the top layer always rejects, widths
        // grow towards the tail, densities fall from 1.
        ensure!(
            z.ki[1] == 0 && z.fi[0] == 1.0 && z.wi.windows(2).skip(1).all(|w| w[0] < w[1]),
            "these are not numpy's ziggurat tables"
        );
        Ok(z)
    }

    /// `random_standard_normal`: one raw word gives the layer (8 bits), the sign (1) and a
    /// 52-bit magnitude; 99 % of draws return at the first comparison.
    pub fn standard_normal(&self, rng: &mut NpRandom) -> f64 {
        loop {
            let r = rng.next_u64();
            let idx = (r & 0xff) as usize;
            let r = r >> 8;
            let rabs = (r >> 1) & 0x000f_ffff_ffff_ffff;
            let mut x = rabs as f64 * self.wi[idx];
            if r & 1 == 1 {
                x = -x;
            }
            if rabs < self.ki[idx] {
                return x;
            }
            if idx == 0 {
                // The tail beyond r, by Marsaglia's exponential method; 1 − U avoids log(0).
                loop {
                    let xx = -NOR_INV_R * (-rng.random()).ln_1p();
                    let yy = -(-rng.random()).ln_1p();
                    if yy + yy > xx * xx {
                        return if (rabs >> 8) & 1 == 1 { -(NOR_R + xx) } else { NOR_R + xx };
                    }
                }
            }
            if (self.fi[idx - 1] - self.fi[idx]) * rng.random() + self.fi[idx] < (-0.5 * x * x).exp() {
                return x;
            }
        }
    }

    /// `Generator.normal(loc, scale)`: `loc + scale · z`, in numpy's order.
    pub fn normal(&self, rng: &mut NpRandom, loc: f64, scale: f64) -> f64 {
        loc + scale * self.standard_normal(rng)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn malformed_tables_are_refused() {
        assert!(Ziggurat::from_bytes(&[0u8; 100]).err().unwrap().to_string().contains("6144"));
        let e = Ziggurat::from_bytes(&[0u8; 6144]).err().unwrap().to_string();
        assert!(e.contains("not numpy's"), "{e}");
        let e = Ziggurat::load(Path::new("/nonexistent/z.bin")).err().unwrap().to_string();
        assert!(e.contains("/nonexistent/z.bin") && e.contains("make deps"), "{e}");
    }

    /// Moments of 200k draws: numpy's stream itself is compared in tests/env_parity.rs.
    #[test]
    fn draws_are_standard_normal() {
        let z = tables().expect("make deps writes the ziggurat tables");
        let mut rng = NpRandom::new(11);
        let x: Vec<f64> = (0..200_000).map(|_| z.standard_normal(&mut rng)).collect();
        let n = x.len() as f64;
        let mean = x.iter().sum::<f64>() / n;
        let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
        let tail = x.iter().filter(|v| v.abs() > NOR_R).count() as f64 / n;
        assert!(mean.abs() < 0.01 && (var - 1.0).abs() < 0.01, "mean {mean}, var {var}");
        // P(|z| > 3.654) = 2.58e-4: about 52 of 200k; the tail path must be taken.
        assert!((20.0..100.0).contains(&(tail * n)), "{} draws beyond r", tail * n);
    }
}
