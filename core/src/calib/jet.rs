//! Forward-mode automatic differentiation: a value with its gradient over `N` parameters.
//!
//! The calibrator's Jacobian comes from evaluating the very projection formula on jets, so the
//! derivatives cannot drift from the model (a hand-derived Jacobian of the Mei model with skew and
//! tangential terms is easy to get subtly wrong, and finite differences cost accuracy).

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Number of parameters a residual depends on: up to 10 intrinsics plus 6 for its view's pose.
pub(crate) const N: usize = 16;

/// Arithmetic the projection formulas need, for plain `f64` and for [`Jet`].
pub(crate) trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + Add<f64, Output = Self>
    + Mul<f64, Output = Self>
{
    /// The value (without derivatives).
    fn val(self) -> f64;
    /// Square root.
    fn sqrt(self) -> Self;
    /// `atan2(self, x)`.
    fn atan2(self, x: Self) -> Self;
}

impl Real for f64 {
    fn val(self) -> f64 {
        self
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    fn atan2(self, x: Self) -> Self {
        f64::atan2(self, x)
    }
}

/// A value and its partial derivatives with respect to `N` parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Jet {
    /// The value.
    pub v: f64,
    /// ∂value/∂parameter.
    pub d: [f64; N],
}

impl Jet {
    /// The parameter with index `i` at value `v` (derivative 1 with respect to itself).
    pub(super) fn var(v: f64, i: usize) -> Self {
        let mut d = [0.0; N];
        d[i] = 1.0;
        Jet { v, d }
    }

    #[inline]
    fn map(self, v: f64, dv: f64) -> Self {
        let mut d = self.d;
        for x in &mut d {
            *x *= dv;
        }
        Jet { v, d }
    }
}

impl Add for Jet {
    type Output = Jet;
    #[inline]
    fn add(mut self, o: Jet) -> Jet {
        self.v += o.v;
        for (a, b) in self.d.iter_mut().zip(&o.d) {
            *a += b;
        }
        self
    }
}

impl Sub for Jet {
    type Output = Jet;
    #[inline]
    fn sub(mut self, o: Jet) -> Jet {
        self.v -= o.v;
        for (a, b) in self.d.iter_mut().zip(&o.d) {
            *a -= b;
        }
        self
    }
}

impl Mul for Jet {
    type Output = Jet;
    #[inline]
    fn mul(self, o: Jet) -> Jet {
        let mut d = [0.0; N];
        for (i, x) in d.iter_mut().enumerate() {
            *x = self.d[i] * o.v + self.v * o.d[i];
        }
        Jet { v: self.v * o.v, d }
    }
}

impl Div for Jet {
    type Output = Jet;
    #[inline]
    fn div(self, o: Jet) -> Jet {
        let q = self.v / o.v;
        let mut d = [0.0; N];
        for (i, x) in d.iter_mut().enumerate() {
            *x = (self.d[i] - q * o.d[i]) / o.v;
        }
        Jet { v: q, d }
    }
}

impl Neg for Jet {
    type Output = Jet;
    #[inline]
    fn neg(self) -> Jet {
        self.map(-self.v, -1.0)
    }
}

impl Add<f64> for Jet {
    type Output = Jet;
    #[inline]
    fn add(mut self, o: f64) -> Jet {
        self.v += o;
        self
    }
}

impl Mul<f64> for Jet {
    type Output = Jet;
    #[inline]
    fn mul(self, o: f64) -> Jet {
        self.map(self.v * o, o)
    }
}

impl Real for Jet {
    fn val(self) -> f64 {
        self.v
    }
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.map(s, 0.5 / s)
    }
    fn atan2(self, x: Self) -> Self {
        // d atan2(y, x) = (x dy − y dx) / (x² + y²)
        let r2 = self.v * self.v + x.v * x.v;
        let mut d = [0.0; N];
        for (i, o) in d.iter_mut().enumerate() {
            *o = (x.v * self.d[i] - self.v * x.d[i]) / r2;
        }
        Jet {
            v: self.v.atan2(x.v),
            d,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_finite_differences() {
        // f(a, b) = atan2(sqrt(a·b + 1), a − b) / (a + 2) · 3 − b
        fn f<T: Real>(a: T, b: T) -> T {
            (a * b + 1.0).sqrt().atan2(a - b) / (a + 2.0) * 3.0 - b
        }
        let (a, b) = (0.7, -0.3);
        let j = f(Jet::var(a, 0), Jet::var(b, 1));
        assert_eq!(j.v, f(a, b));
        let h = 1e-6;
        let da = (f(a + h, b) - f(a - h, b)) / (2.0 * h);
        let db = (f(a, b + h) - f(a, b - h)) / (2.0 * h);
        assert!((j.d[0] - da).abs() < 1e-8, "{} vs {da}", j.d[0]);
        assert!((j.d[1] - db).abs() < 1e-8, "{} vs {db}", j.d[1]);
        assert!(j.d[2..].iter().all(|x| *x == 0.0));
    }
}
