//! Welch's t-test, the one significance test of pgser's tables (Table 2, a grid's results, a
//! study), and how a tested difference is printed: the two-sided p with ▲ or ▼ for a significant
//! difference's direction.

use statrs::distribution::{ContinuousCDF, StudentsT};

/// Significance level of the two-sided test, whose significant differences the markdown marks
/// with their direction.
pub const ALPHA: f64 = 0.05;
/// Marks of a significant difference: the variant's mean above / below the reference's.
pub const BETTER: &str = "▲";
pub const WORSE: &str = "▼";

/// A significant difference's mark: its direction and the letter of what it is against
/// (`▲b`: significantly above the baseline); None where p is not below [`ALPHA`].
pub(super) fn mark(p: Option<f64>, above: bool, letter: &str) -> Option<String> {
    p.filter(|p| *p < ALPHA).map(|_| format!("{}{letter}", if above { BETTER } else { WORSE }))
}

/// Welch's t-test (unequal variances) of `a` against `b`: (t, degrees of freedom, two-sided
/// p). None with fewer than 2 samples on either side or when both variances are 0 (t undefined).
pub fn welch_t_test(a: &[f64], b: &[f64]) -> Option<(f64, f64, f64)> {
    if a.len() < 2 || b.len() < 2 {
        return None;
    }
    let ((ma, sa), (mb, sb)) = (mean_std(a), mean_std(b));
    welch_from_summary((ma, sa, a.len()), (mb, sb, b.len()))
}

/// [`welch_t_test`] from each side's (mean, sample std, n) alone, which is all Welch's test
/// needs: Table 2 across tasks tests the cells of pipelines' results.csv files this way.
pub fn welch_from_summary(a: (f64, f64, usize), b: (f64, f64, usize)) -> Option<(f64, f64, f64)> {
    let ((ma, sa, na), (mb, sb, nb)) = (a, b);
    if na < 2 || nb < 2 {
        return None;
    }
    let (va, vb) = (sa * sa / na as f64, sb * sb / nb as f64);
    let se2 = va + vb;
    if se2 <= 0.0 || !se2.is_finite() {
        return None;
    }
    let t = (ma - mb) / se2.sqrt();
    // Welch–Satterthwaite.
    let df = se2 * se2 / (va * va / (na - 1) as f64 + vb * vb / (nb - 1) as f64);
    let dist = StudentsT::new(0.0, 1.0, df).ok()?;
    // 2·sf(|t|) rather than 2·(1 − cdf): keeps precision for tiny p.
    let p = (2.0 * dist.sf(t.abs())).min(1.0);
    Some((t, df, p))
}

/// Welch's one-sided p of `a` against `b` for H1: mean(a) > mean(b), i.e. sf(t) on the
/// Welch–Satterthwaite degrees of freedom: small when `a` is clearly higher, near 1 when it is
/// clearly lower. None where [`welch_t_test`] is.
pub fn welch_greater(a: &[f64], b: &[f64]) -> Option<f64> {
    let (t, df, _) = welch_t_test(a, b)?;
    Some(StudentsT::new(0.0, 1.0, df).ok()?.sf(t))
}

/// Mean and sample std (n − 1; NaN for one value).
pub(super) fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = if v.len() < 2 { f64::NAN } else { (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt() };
    // Equal scores give a mean one ulp off and a "std" of 1e-15, which would make Welch's t
    // astronomically large (p ≈ 1e-27 between two constant groups): round-off is zero spread.
    let s = if s < 1e-12 * m.abs().max(1.0) { 0.0 } else { s };
    (m, s)
}

/// The two-sided p with the direction of a significant difference, given whether the tested
/// mean (mem's, an arm's) is the higher one.
pub(super) fn fmt_p_above(two_sided: Option<f64>, above: Option<bool>) -> String {
    match (two_sided, above) {
        (Some(p), Some(above)) => {
            let mark = match (p < ALPHA, above) {
                (false, _) => "",
                (true, true) => BETTER,
                (true, false) => WORSE,
            };
            let p = if p < 1e-3 { format!("{p:.1e}") } else { format!("{p:.3}") };
            if mark.is_empty() { p } else { format!("{p} {mark}") }
        }
        _ => "—".to_string(),
    }
}
