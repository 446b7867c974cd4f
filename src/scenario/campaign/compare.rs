//! Paired comparisons of two methods in a cell: the Wilcoxon signed-rank test over the seeds on
//! the log ratio of post-fault MSE (docs/method.md, "Comparisons with confidence").
//!
//! Both methods of a cell run on the same seeds (the same sensor noise, model error and fault
//! draw), so their runs pair by seed. For each pair d = log10(MSE_A) - log10(MSE_B): negative
//! when A's belief error is smaller. A run whose MSE is not finite (diverged) counts as the worst
//! possible: its difference is +inf (A) or -inf (B); two such runs, or equal MSEs, tie at 0. The
//! signed-rank test ranks |d| (midranks for ties, zero differences dropped as in Wilcoxon's
//! original test) and asks whether positive and negative ranks balance; its p-value is exact
//! (the distribution of the rank sum enumerated, ties included) up to [`EXACT_MAX_PAIRS`] pairs
//! and from the normal approximation with the tie and continuity corrections beyond. The test
//! is on ranks, so a diverged run enters as the largest difference without its size mattering.

use std::collections::BTreeMap;

use super::{Campaign, CampaignRun};
use crate::scenario::method::MethodId;

/// The significance level of the comparisons a campaign writes (two-sided).
pub const ALPHA: f64 = 0.05;
/// Most non-zero pairs for which the p-value is enumerated exactly (the enumeration costs
/// pairs^3 / 2 operations: 4e6 at 200).
pub const EXACT_MAX_PAIRS: usize = 200;

/// The Wilcoxon signed-rank test of paired differences (two-sided).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignedRank {
    /// Pairs with a non-zero difference (the test's n).
    pub pairs: usize,
    /// Pairs whose difference is zero (dropped).
    pub zeros: usize,
    /// Sum of the ranks of the positive differences.
    pub w_plus: f64,
    /// Sum of the ranks of the negative differences.
    pub w_minus: f64,
    /// Two-sided p-value (1 when no pair differs).
    pub p_value: f64,
    /// Whether `p_value` is exact (else the normal approximation).
    pub exact: bool,
}

/// The Wilcoxon signed-rank test of the differences `d` (NaN counts as a zero difference;
/// infinities rank above every finite difference and tie with each other).
pub fn signed_rank(d: &[f64]) -> SignedRank {
    let nonzero: Vec<f64> = d
        .iter()
        .copied()
        .filter(|x| *x != 0.0 && !x.is_nan())
        .collect();
    let zeros = d.len() - nonzero.len();
    let n = nonzero.len();
    if n == 0 {
        return SignedRank {
            pairs: 0,
            zeros,
            w_plus: 0.0,
            w_minus: 0.0,
            p_value: 1.0,
            exact: true,
        };
    }
    // Midranks of |d|, doubled so that they are integers (a tie group at ranks i+1..=j has
    // midrank (i + 1 + j) / 2).
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| nonzero[a].abs().total_cmp(&nonzero[b].abs()));
    let mut doubled = vec![0u64; n];
    let mut tie_correction = 0.0;
    let mut i = 0;
    while i < n {
        let mut j = i + 1;
        while j < n && nonzero[order[j]].abs() == nonzero[order[i]].abs() {
            j += 1;
        }
        for &k in &order[i..j] {
            doubled[k] = (i + 1 + j) as u64;
        }
        let t = (j - i) as f64;
        tie_correction += t * t * t - t;
        i = j;
    }
    let w_plus2: u64 = (0..n)
        .filter(|&k| nonzero[k] > 0.0)
        .map(|k| doubled[k])
        .sum();
    let total2: u64 = doubled.iter().sum();
    let (w_plus, w_minus) = (w_plus2 as f64 / 2.0, (total2 - w_plus2) as f64 / 2.0);
    let (p_value, exact) = if n <= EXACT_MAX_PAIRS {
        // Under the null hypothesis each rank's sign is + or - with probability 1/2: the
        // distribution of the doubled positive rank sum, by dynamic programming over the ranks.
        let mut dist = vec![0.0f64; total2 as usize + 1];
        dist[0] = 1.0;
        let mut reach = 0usize;
        for &r in &doubled {
            let r = r as usize;
            for s in (0..=reach).rev() {
                let p = dist[s] * 0.5;
                dist[s] = p;
                dist[s + r] += p;
            }
            reach += r;
        }
        let w = w_plus2 as usize;
        let lower: f64 = dist[..=w].iter().sum();
        let upper: f64 = dist[w..].iter().sum();
        ((2.0 * lower.min(upper)).min(1.0), true)
    } else {
        let nf = n as f64;
        let mean = nf * (nf + 1.0) / 4.0;
        let var = nf * (nf + 1.0) * (2.0 * nf + 1.0) / 24.0 - tie_correction / 48.0;
        let z = ((w_plus - mean).abs() - 0.5).max(0.0) / var.sqrt();
        ((2.0 * normal_upper_tail(z)).min(1.0), false)
    };
    SignedRank {
        pairs: n,
        zeros,
        w_plus,
        w_minus,
        p_value,
        exact,
    }
}

/// P(Z > z) for a standard normal Z: erfc(z / sqrt 2) / 2, with erfc from Numerical Recipes'
/// Chebyshev fit (relative error below 1.2e-7 everywhere).
fn normal_upper_tail(z: f64) -> f64 {
    let x = z / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * x.abs());
    let poly = -x * x - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let erfc = t * poly.exp();
    0.5 * if x >= 0.0 { erfc } else { 2.0 - erfc }
}

/// Which of two methods a comparison favours.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Better {
    A,
    B,
    /// No difference at the level asked.
    Neither,
}

impl Better {
    pub fn name(self) -> &'static str {
        match self {
            Self::A => "a",
            Self::B => "b",
            Self::Neither => "neither",
        }
    }
}

/// Methods `a` and `b` compared in one cell over the seeds both ran.
#[derive(Clone, Debug, PartialEq)]
pub struct PairComparison {
    pub cell: usize,
    pub a: MethodId,
    pub b: MethodId,
    /// Seeds both methods ran in the cell.
    pub seeds: usize,
    /// Median over the seeds of log10(MSE_a / MSE_b) (negative: a's error is smaller; +-inf when
    /// more than half the pairs have the same side diverged; NaN when the middle two are -inf and
    /// +inf).
    pub median_log10_ratio: f64,
    pub test: SignedRank,
    pub better: Better,
}

impl PairComparison {
    /// The method the comparison favours, or `neither`.
    pub fn better_name(&self) -> &str {
        match self.better {
            Better::A => self.a.name(),
            Better::B => self.b.name(),
            Better::Neither => "neither",
        }
    }

    /// The comparison as campaign.json and `aift compare --json` write it (the cell named by
    /// the caller).
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "a": self.a.name(),
            "b": self.b.name(),
            "seeds": self.seeds,
            "nonzero_pairs": self.test.pairs,
            "median_log10_ratio": self.median_log10_ratio,
            "w_plus": self.test.w_plus,
            "w_minus": self.test.w_minus,
            "p_value": self.test.p_value,
            "exact": self.test.exact,
            "better": self.better_name(),
        })
    }
}

/// d = log10(MSE_a) - log10(MSE_b), a non-finite MSE counting as the worst (module docs).
pub fn log10_ratio(mse_a: f64, mse_b: f64) -> f64 {
    match (mse_a.is_finite(), mse_b.is_finite()) {
        (false, false) => 0.0,
        (false, true) => f64::INFINITY,
        (true, false) => f64::NEG_INFINITY,
        (true, true) if mse_a == mse_b => 0.0,
        (true, true) => mse_a.log10() - mse_b.log10(),
    }
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        let (lo, hi) = (values[n / 2 - 1], values[n / 2]);
        if lo == hi { lo } else { 0.5 * (lo + hi) }
    }
}

/// The comparisons of `a` with `b` in every cell where both ran, at level `alpha` (two-sided).
pub fn compare_pair(
    campaign: &Campaign,
    runs: &[CampaignRun],
    a: &MethodId,
    b: &MethodId,
    alpha: f64,
) -> Vec<PairComparison> {
    // By (cell, whether b's).
    let mut by: BTreeMap<(usize, bool), BTreeMap<u64, f64>> = BTreeMap::new();
    for r in runs.iter().filter(|r| r.method == *a || r.method == *b) {
        by.entry((r.cell, r.method == *b))
            .or_default()
            .insert(r.seed, r.mse_post);
    }
    let mut out = Vec::new();
    for cell in 0..campaign.cells.len() {
        let (Some(ra), Some(rb)) = (by.get(&(cell, false)), by.get(&(cell, true))) else {
            continue;
        };
        let mut d: Vec<f64> = ra
            .iter()
            .filter_map(|(seed, &ma)| rb.get(seed).map(|&mb| log10_ratio(ma, mb)))
            .collect();
        if d.is_empty() {
            continue;
        }
        let test = signed_rank(&d);
        let better = if test.pairs > 0 && test.p_value < alpha {
            if test.w_plus < test.w_minus {
                Better::A
            } else {
                Better::B
            }
        } else {
            Better::Neither
        };
        out.push(PairComparison {
            cell,
            a: a.clone(),
            b: b.clone(),
            seeds: d.len(),
            median_log10_ratio: median(&mut d),
            test,
            better,
        });
    }
    out
}

/// Every pair of the campaign's methods (in its order, a before b) compared in every cell.
pub fn compare_all(campaign: &Campaign, runs: &[CampaignRun], alpha: f64) -> Vec<PairComparison> {
    let m = &campaign.methods;
    let mut out = Vec::new();
    for i in 0..m.len() {
        for j in i + 1..m.len() {
            out.extend(compare_pair(campaign, runs, &m[i], &m[j], alpha));
        }
    }
    out
}

/// The smallest two-sided p-value the exact test can give with `n` pairs (2 / 2^n): below
/// `alpha` only from 6 pairs at 5 %.
pub fn smallest_p_value(n: usize) -> f64 {
    (2.0f64 * 0.5f64.powi(n.min(1100) as i32)).min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_positive_differences_give_the_exact_tail() {
        // Six positive differences: W+ = 21, the largest of 2^6 equally likely sign patterns.
        let t = signed_rank(&[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]);
        assert_eq!((t.pairs, t.w_plus, t.w_minus), (6, 21.0, 0.0));
        assert!((t.p_value - 2.0 / 64.0).abs() < 1e-15);
        assert!(t.exact);
        assert!((smallest_p_value(6) - t.p_value).abs() < 1e-15);
    }

    #[test]
    fn ties_and_zeros_by_hand() {
        // d = 1, 1, -2, 3 and a zero: the zero is dropped; midranks 1.5, 1.5, 3, 4; W+ = 7,
        // W- = 3. Doubled ranks {3, 3, 6, 8}: of the 16 subset sums, 5 are >= 14 (14, 14, 17,
        // 17, 20) and 13 are <= 14, so p = 2 x 5/16.
        let t = signed_rank(&[1.0, 1.0, -2.0, 3.0, 0.0]);
        assert_eq!((t.pairs, t.zeros, t.w_plus, t.w_minus), (4, 1, 7.0, 3.0));
        assert!((t.p_value - 10.0 / 16.0).abs() < 1e-15, "{}", t.p_value);
    }

    #[test]
    fn the_exact_p_value_matches_enumerating_every_sign_pattern() {
        // Independent reference: enumerate the 2^n sign patterns of the observed midranks.
        let cases: [&[f64]; 4] = [
            &[0.3, -0.1, 0.3, 0.7, -0.7, 1.2, 0.05, -0.3],
            &[1.0, 2.0, 3.0, -4.0, 5.0, 6.0, 7.0, 8.0, -9.0, 10.0, 11.0],
            &[-0.2, -0.2, -0.2, 0.2, -1.0, -3.0, 0.5],
            &[2.0, -1.0],
        ];
        for d in cases {
            let n = d.len();
            let mut mags: Vec<f64> = d.iter().map(|x| x.abs()).collect();
            let rank = |x: f64, mags: &mut Vec<f64>| {
                mags.sort_by(f64::total_cmp);
                let below = mags.iter().filter(|&&m| m < x).count() as f64;
                let equal = mags.iter().filter(|&&m| m == x).count() as f64;
                below + (equal + 1.0) / 2.0
            };
            let ranks: Vec<f64> = d.iter().map(|x| rank(x.abs(), &mut mags)).collect();
            let observed: f64 = (0..n).filter(|&i| d[i] > 0.0).map(|i| ranks[i]).sum();
            let (mut lower, mut upper) = (0u64, 0u64);
            for pattern in 0u32..(1 << n) {
                let w: f64 = (0..n)
                    .filter(|i| pattern >> i & 1 == 1)
                    .map(|i| ranks[i])
                    .sum();
                lower += u64::from(w <= observed + 1e-9);
                upper += u64::from(w >= observed - 1e-9);
            }
            let p = (2.0 * lower.min(upper) as f64 / f64::from(1u32 << n)).min(1.0);
            let t = signed_rank(d);
            assert_eq!(t.w_plus, observed);
            assert!((t.p_value - p).abs() < 1e-12, "{d:?}: {} {p}", t.p_value);
        }
    }

    #[test]
    fn infinities_rank_highest_and_tie() {
        let t = signed_rank(&[f64::INFINITY, f64::INFINITY, -0.5, 0.1]);
        // |d|: 0.1 -> 1, 0.5 -> 2, inf, inf -> 3.5 each.
        assert_eq!((t.w_plus, t.w_minus), (8.0, 2.0));
    }

    #[test]
    fn normal_approximation_agrees_with_the_exact_count() {
        // 30 pairs with a shift: the exact enumeration and the normal approximation (with
        // continuity correction) of the same statistic agree within 0.005.
        let d: Vec<f64> = (0..30).map(|i| ((i as f64) * 0.37).sin() + 0.3).collect();
        let exact = signed_rank(&d);
        let nf = 30.0f64;
        let mean = nf * (nf + 1.0) / 4.0;
        let var = nf * (nf + 1.0) * (2.0 * nf + 1.0) / 24.0;
        let z = ((exact.w_plus - mean).abs() - 0.5) / var.sqrt();
        let approx = 2.0 * normal_upper_tail(z);
        assert!(exact.exact);
        assert!(
            (exact.p_value - approx).abs() < 5e-3,
            "{} {approx}",
            exact.p_value
        );
        // Beyond the exact range the approximation is used: 253 non-zero pairs with many ties
        // (values rounded to 0.1). Reference: SciPy 1.x `wilcoxon(d, zero_method="wilcox",
        // correction=True, method="approx")` on the same numbers (computed with numpy's sin and
        // cos, 2026-12-04): statistic min(W+, W-) = 13901.5, p = 0.06304774332731036.
        let long: Vec<f64> = (0..260)
            .map(|i| {
                let x = ((i as f64) * 0.37).sin() + 0.08 + 0.3 * ((i as f64) * 1.3).cos();
                (x * 10.0).round() / 10.0
            })
            .collect();
        let t = signed_rank(&long);
        assert!(!t.exact);
        assert_eq!(t.pairs, 253);
        assert_eq!(t.w_plus.min(t.w_minus), 13901.5);
        assert!(
            (t.p_value - 0.063_047_743_327_310_36).abs() < 1e-6,
            "{}",
            t.p_value
        );
    }

    #[test]
    fn normal_tail_at_known_points() {
        for (z, p) in [(0.0, 0.5), (1.959_963_985, 0.025), (3.090_232_306, 0.001)] {
            assert!((normal_upper_tail(z) - p).abs() < 1e-7, "{z}");
        }
    }

    #[test]
    fn the_log_ratio_treats_divergence_as_the_worst() {
        assert_eq!(log10_ratio(f64::NAN, 1.0), f64::INFINITY);
        assert_eq!(log10_ratio(1.0, f64::INFINITY), f64::NEG_INFINITY);
        assert_eq!(log10_ratio(f64::NAN, f64::NAN), 0.0);
        assert!((log10_ratio(1e-4, 1e-2) + 2.0).abs() < 1e-12);
    }
}
