//! `f32` logarithm and exponential without libm: short polynomials with no branches (only
//! selects), so the compiler vectorises the loops that call them, where a libm call per
//! value keeps a loop scalar. The global operators' per-pixel curves use them (Drago: a
//! `ln_1p`, a `powf` and an `ln` per pixel, and an `ln` per pixel for the log-average).
//! Relative errors, measured against `f64` in the tests: `ln` 2e-7 (absolute 1e-7 near 1),
//! `exp` 2e-7, `ln_1p` 3e-7, `pow` 4e-7 plus `|p ln x|` times 2e-7 (the rounding of the
//! exponent `p ln x` in `f32`; Drago's `p ln x` stays within a few units): far below the
//! operators' 1e-5 agreement with their `f64` statements.

const LN2: f32 = std::f32::consts::LN_2;
/// `ln 2` split so that `n * LN2_HI` is exact for the `n` [`exp`] meets.
const LN2_HI: f32 = 0.693_145_75;
const LN2_LO: f32 = 1.428_606_8e-6;

/// `ln x` for `x > 0` finite (subnormals included). Other inputs give a finite or
/// meaningless value, never a trap: callers select those out.
#[inline(always)]
#[must_use]
pub fn ln(x: f32) -> f32 {
    // Subnormals scaled into the normal range first.
    let small = x < f32::MIN_POSITIVE;
    let x = if small { x * 16_777_216.0 } else { x };
    let bits = x.to_bits() as i32;
    // x = 2^k m with m in [sqrt(1/2), sqrt(2)).
    let ix = bits.wrapping_sub(0x3f35_04f3);
    let k = ix >> 23;
    let m = f32::from_bits(((ix & 0x007f_ffff) + 0x3f35_04f3) as u32);
    // ln m = 2 atanh(f), f = (m - 1) / (m + 1), |f| < 0.1716: the odd series to f^9 (the
    // next term is under 1e-9 of the result).
    let f = (m - 1.0) / (m + 1.0);
    let f2 = f * f;
    let p = f * (2.0 + f2 * (2.0 / 3.0 + f2 * (0.4 + f2 * (2.0 / 7.0 + f2 * (2.0 / 9.0)))));
    let k = if small { k - 24 } else { k };
    k as f32 * LN2 + p
}

/// `e^z`, for `z` in about `[-87, 88]` (clamped there: 0 is not reached, and nothing
/// overflows). NaN gives NaN.
#[inline(always)]
#[must_use]
pub fn exp(z: f32) -> f32 {
    let z = z.clamp(-87.0, 88.0);
    // n = round(z / ln 2) by the 1.5 * 2^23 trick (no libm `round`), r = z - n ln 2.
    const MAGIC: f32 = 12_582_912.0;
    let n = (z * std::f32::consts::LOG2_E + MAGIC) - MAGIC;
    let r = (z - n * LN2_HI) - n * LN2_LO;
    // |r| <= ln(2) / 2: Taylor to r^7 (the next term is under 1e-8).
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0
                        + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    // 2^n with n in [-126, 127]: a normal number's exponent field.
    let scale = f32::from_bits(((n as i32 + 127) as u32) << 23);
    p * scale
}

/// `ln(1 + x)` for `x >= 0` finite, accurate for small `x` too (`ln(u) x / (u - 1)` with
/// `u = 1 + x` rounded: the rounding of `u` cancels).
#[inline(always)]
#[must_use]
pub fn ln_1p(x: f32) -> f32 {
    let u = 1.0 + x;
    let d = u - 1.0;
    if d == 0.0 { x } else { ln(u) * (x / d) }
}

/// `x^p` for `x > 0` finite: `e^(p ln x)`.
#[inline(always)]
#[must_use]
pub fn pow(x: f32, p: f32) -> f32 {
    exp(p * ln(x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values across the whole positive range: powers of two and their neighbours, a dense
    /// sweep near 1, a geometric sweep, subnormals.
    fn samples() -> Vec<f32> {
        let mut v = Vec::new();
        for e in -149..=127 {
            let p = 2f64.powi(e) as f32;
            v.extend([
                p,
                f32::from_bits(p.to_bits() + 1),
                f32::from_bits(p.to_bits() - 1),
            ]);
        }
        v.extend((0..20_000).map(|i| 0.9 + 0.2 * i as f32 / 20_000.0));
        v.extend((0..20_000).map(|i| 10f64.powf(-44.0 + 82.0 * f64::from(i) / 20_000.0) as f32));
        v.retain(|x| *x > 0.0 && x.is_finite());
        v
    }

    #[test]
    fn ln_is_within_two_ulps_of_f64() {
        for x in samples() {
            let want = f64::from(x).ln();
            let got = f64::from(ln(x));
            let err = (got - want).abs();
            assert!(
                err <= 2e-7 * want.abs() + 1e-7 * (f64::from(x) - 1.0).abs().min(1.0) + 1e-45,
                "ln({x:e}) = {got} want {want}"
            );
        }
    }

    #[test]
    fn exp_is_within_two_ulps_of_f64() {
        for i in 0..=200_000 {
            let z = -87.0 + 175.0 * i as f32 / 200_000.0;
            let want = f64::from(z).exp();
            let got = f64::from(exp(z));
            assert!(
                (got - want).abs() <= 2e-7 * want,
                "exp({z}) = {got} want {want}"
            );
        }
        assert_eq!(exp(0.0), 1.0);
        assert!(exp(f32::NAN).is_nan());
        assert!(exp(-1e30) > 0.0 && exp(1e30).is_finite());
    }

    #[test]
    fn ln_1p_keeps_small_arguments() {
        let mut xs: Vec<f32> = (0..=400)
            .map(|i| 10f32.powf(-40.0 + i as f32 / 5.0))
            .collect();
        xs.push(0.0);
        for x in xs.into_iter().filter(|x| x.is_finite()) {
            let want = f64::from(x).ln_1p();
            let got = f64::from(ln_1p(x));
            assert!(
                (got - want).abs() <= 3e-7 * want + 1e-45,
                "ln_1p({x:e}) = {got} want {want}"
            );
        }
    }

    #[test]
    fn pow_matches_f64() {
        for x in samples().into_iter().step_by(7) {
            for p in [0.234_f32, 0.5, 1.0, 2.2, -0.7] {
                let want = f64::from(x).powf(f64::from(p));
                if !(1e-37..1e37).contains(&want) {
                    continue;
                }
                let got = f64::from(pow(x, p));
                let lnx = f64::from(x).ln().abs();
                let tol = 4e-7 + 2e-7 * f64::from(p.abs()) * lnx;
                assert!(
                    (got - want).abs() <= tol * want,
                    "{x:e}^{p} = {got} want {want}"
                );
            }
        }
    }
}
