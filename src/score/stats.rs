//! Summary statistics of the `q` column for the footer: min, mean, max and a histogram.
//!
//! The histogram's bins are fixed by the checkpoint's γ, not by the data: rewards are in
//! {−1, 0}, so a well-trained critic's Q lies in [−1/(1−γ), 0] (the trainer clips its TD
//! target there), and fixed edges make histograms of different files, checkpoints and seeds
//! comparable bin by bin. Values outside (an under-trained critic overshoots) are counted in
//! `below` / `above` instead of stretching the range. Chunks are summarised separately and
//! merged in chunk order, so the footer does not depend on the thread count either.

use serde::{Deserialize, Serialize};

/// Histogram bins over [−1/(1−γ), 0]: one per unit of return for γ = 0.98 (50 steps to go).
pub const BINS: usize = 50;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Histogram {
    /// BINS + 1 increasing edges; bin i is [edges[i], edges[i+1]), the last one closed.
    pub edges: Vec<f64>,
    pub counts: Vec<u64>,
    /// Values below edges[0] / above edges[BINS].
    pub below: u64,
    pub above: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QStats {
    pub min: f64,
    pub mean: f64,
    pub max: f64,
    pub histogram: Histogram,
}

/// Running statistics of q values; `add` a chunk's, `merge` chunks in order.
#[derive(Debug, Clone, PartialEq)]
pub struct QAccumulator {
    lo: f64,
    hi: f64,
    count: u64,
    sum: f64,
    min: f64,
    max: f64,
    counts: Vec<u64>,
    below: u64,
    above: u64,
}

impl QAccumulator {
    /// Bins over [−1/(1−γ), 0], the lower edge rounded to float32 (q's type): for γ = 0.98
    /// it is then −50 exactly, not −49.99999999999996, so a q of −50 falls in the first bin.
    pub fn new(gamma: f64) -> Self {
        let lo = (-1.0 / (1.0 - gamma)) as f32 as f64;
        QAccumulator {
            lo,
            hi: 0.0,
            count: 0,
            sum: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            counts: vec![0; BINS],
            below: 0,
            above: 0,
        }
    }

    pub fn add(&mut self, q: &[f32]) {
        let width = (self.hi - self.lo) / BINS as f64;
        for &v in q {
            let v = v as f64;
            self.count += 1;
            self.sum += v;
            self.min = self.min.min(v);
            self.max = self.max.max(v);
            if v < self.lo {
                self.below += 1;
            } else if v > self.hi {
                self.above += 1;
            } else {
                self.counts[(((v - self.lo) / width) as usize).min(BINS - 1)] += 1;
            }
        }
    }

    pub fn merge(&mut self, o: &QAccumulator) {
        self.count += o.count;
        self.sum += o.sum;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.counts.iter_mut().zip(&o.counts).for_each(|(a, b)| *a += b);
        self.below += o.below;
        self.above += o.above;
    }

    pub fn finish(&self) -> QStats {
        let width = (self.hi - self.lo) / BINS as f64;
        let mut edges: Vec<f64> = (0..BINS).map(|i| self.lo + i as f64 * width).collect();
        edges.push(self.hi);
        QStats {
            min: self.min,
            mean: if self.count == 0 { 0.0 } else { self.sum / self.count as f64 },
            max: self.max,
            histogram: Histogram { edges, counts: self.counts.clone(), below: self.below, above: self.above },
        }
    }
}

/// The statistics of several parts' rows together, from each part's statistics and row count (a
/// scored folder's shards, scored by different processes): min and max of theirs, the mean
/// weighted by rows, the histograms summed. Parts are taken in order, so the result does not
/// depend on which shard finished first.
pub fn merged<'a>(parts: impl Iterator<Item = (&'a QStats, u64)>) -> QStats {
    let mut out: Option<QStats> = None;
    let (mut sum, mut count) = (0.0, 0u64);
    for (q, rows) in parts {
        sum += q.mean * rows as f64;
        count += rows;
        match out.as_mut() {
            None => out = Some(q.clone()),
            Some(m) => {
                m.min = m.min.min(q.min);
                m.max = m.max.max(q.max);
                m.histogram.counts.iter_mut().zip(&q.histogram.counts).for_each(|(a, b)| *a += b);
                m.histogram.below += q.histogram.below;
                m.histogram.above += q.histogram.above;
            }
        }
    }
    let mut m = out.expect("at least one part");
    m.mean = if count == 0 { 0.0 } else { sum / count as f64 };
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_cover_the_return_range_and_count_the_rest_outside() {
        let mut a = QAccumulator::new(0.98);
        a.add(&[-50.0, -49.5, -0.5, 0.0, -60.0, 0.25, -25.0]);
        let s = a.finish();
        assert_eq!(s.histogram.edges.len(), BINS + 1);
        assert_eq!((s.histogram.edges[0], s.histogram.edges[BINS]), (-50.0, 0.0));
        let c = &s.histogram.counts;
        assert_eq!((c[0], c[BINS - 1], c[25]), (2, 2, 1));
        assert_eq!((s.histogram.below, s.histogram.above), (1, 1));
        assert_eq!(c.iter().sum::<u64>() + 2, 7);
        assert_eq!((s.min, s.max), (-60.0, 0.25));
    }

    #[test]
    fn merged_chunks_equal_one_pass() {
        let q: Vec<f32> = (0..1000).map(|i| -((i as f32 * 0.37).sin().abs() * 55.0)).collect();
        let mut whole = QAccumulator::new(0.98);
        whole.add(&q);
        let mut merged = QAccumulator::new(0.98);
        for c in q.chunks(97) {
            let mut part = QAccumulator::new(0.98);
            part.add(c);
            merged.merge(&part);
        }
        let (a, b) = (whole.finish(), merged.finish());
        assert_eq!(a.histogram, b.histogram);
        assert_eq!((a.min, a.max), (b.min, b.max));
        assert!((a.mean - b.mean).abs() < 1e-9);
    }

    #[test]
    fn merged_parts_equal_one_pass() {
        let q: Vec<f32> = (0..1000).map(|i| -((i as f32 * 0.61).cos().abs() * 52.0)).collect();
        let mut whole = QAccumulator::new(0.98);
        whole.add(&q);
        let parts: Vec<(QStats, u64)> = q
            .chunks(301)
            .map(|c| {
                let mut a = QAccumulator::new(0.98);
                a.add(c);
                (a.finish(), c.len() as u64)
            })
            .collect();
        let (a, b) = (whole.finish(), merged(parts.iter().map(|(q, n)| (q, *n))));
        assert_eq!(a.histogram, b.histogram);
        assert_eq!((a.min, a.max), (b.min, b.max));
        assert!((a.mean - b.mean).abs() < 1e-9);
    }
}
