//! Real roots of low-degree polynomials by derivative-based isolation + bisection.
//!
//! Chosen over closed forms (Ferrari) because it never loses a root to catastrophic cancellation:
//! the roots of p′ split the line into monotone intervals and each interval holds at most one root.

/// Real roots of `c[0] + c[1]x + … + c[n]xⁿ`, ascending. Leading zeros are dropped.
pub(crate) fn real_roots(c: &[f64]) -> Vec<f64> {
    let mut n = c.len();
    while n > 0 && c[n - 1] == 0.0 {
        n -= 1;
    }
    let c = &c[..n];
    match n {
        0 | 1 => Vec::new(),
        2 => vec![-c[0] / c[1]],
        _ => {
            let deriv: Vec<f64> = c
                .iter()
                .enumerate()
                .skip(1)
                .map(|(i, v)| i as f64 * v)
                .collect();
            let crit = real_roots(&deriv);
            // Cauchy bound: every root lies in |x| ≤ 1 + max|c_i / c_n|.
            let lead = c[n - 1];
            let bound = 1.0
                + c[..n - 1]
                    .iter()
                    .map(|v| (v / lead).abs())
                    .fold(0.0, f64::max);
            let mut edges = Vec::with_capacity(crit.len() + 2);
            edges.push(-bound);
            edges.extend(crit.into_iter().filter(|x| x.abs() < bound));
            edges.push(bound);
            let mut roots = Vec::new();
            for w in edges.windows(2) {
                if let Some(r) = bisect(c, w[0], w[1]) {
                    if roots
                        .last()
                        .is_none_or(|l: &f64| (r - l).abs() > 1e-12 * (1.0 + r.abs()))
                    {
                        roots.push(r);
                    }
                }
            }
            roots
        }
    }
}

fn eval(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, v| acc * x + v)
}

/// Root of a monotone stretch, including a double root touching zero at an edge.
fn bisect(c: &[f64], mut lo: f64, mut hi: f64) -> Option<f64> {
    let (flo, fhi) = (eval(c, lo), eval(c, hi));
    let scale = c.iter().map(|v| v.abs()).fold(0.0, f64::max) * 1e-12;
    if flo.abs() <= scale {
        return Some(lo);
    }
    if fhi.abs() <= scale {
        return Some(hi);
    }
    if flo.signum() == fhi.signum() {
        return None;
    }
    let rising = fhi > flo;
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if (eval(c, mid) > 0.0) == rising {
            hi = mid
        } else {
            lo = mid
        }
    }
    Some(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_roots(r: &[f64]) -> Vec<f64> {
        let mut c = vec![1.0];
        for &x in r {
            let mut n = vec![0.0; c.len() + 1];
            for (i, v) in c.iter().enumerate() {
                n[i] -= x * v;
                n[i + 1] += v;
            }
            c = n;
        }
        c
    }

    #[test]
    fn quartic_roots() {
        let want = [-3.5, -0.25, 0.1, 7.0];
        let got = real_roots(&from_roots(&want));
        assert_eq!(got.len(), 4);
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-9, "{got:?}");
        }
        // x⁴ + 1 has no real roots; (x−1)²(x²+1) has a double root.
        assert!(real_roots(&[1.0, 0.0, 0.0, 0.0, 1.0]).is_empty());
        let d = real_roots(&[1.0, -2.0, 2.0, -2.0, 1.0]);
        assert!(
            !d.is_empty() && d.iter().all(|r| (r - 1.0).abs() < 1e-6),
            "{d:?}"
        );
    }
}
