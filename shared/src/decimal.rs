//! Floats in error messages by integer formatting alone: core's float formatting would add
//! some 20 KiB of flash to a flight image for messages it prints only on a fault.

use core::fmt;

/// `self.0` with six decimals, rounded to nearest (`-0.500000`, `12.345679`); from 1e9 up in
/// magnitude as a mantissa of six decimals and a power of ten (`1.500000e15`); `NaN`, `inf`,
/// `-inf` as such.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decimal6(pub f64);

/// Below this magnitude the value times 1e6 stays below 2^53, so it is rounded to millionths
/// as core's formatting does, up to ties.
const FIXED_BELOW: f64 = 1e9;

impl fmt::Display for Decimal6 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        if v.is_nan() {
            return f.write_str("NaN");
        }
        let sign = if v.is_sign_negative() { "-" } else { "" };
        let magnitude = libm::fabs(v);
        if magnitude.is_infinite() {
            return write!(f, "{sign}inf");
        }
        let (mantissa, exponent) = if magnitude < FIXED_BELOW {
            (magnitude, None)
        } else {
            // 1e9 <= magnitude < 1.8e308: a power of ten from 9 to 308.
            let mut exponent = libm::floor(libm::log10(magnitude)) as i32;
            let mut mantissa = magnitude / libm::pow(10.0, f64::from(exponent));
            if mantissa >= 10.0 {
                mantissa /= 10.0;
                exponent += 1;
            }
            (mantissa, Some(exponent))
        };
        // Below 1e9 * 1e6 < 2^53: an integer the cast keeps.
        let mut millionths = libm::round(mantissa * 1e6) as u64;
        let exponent = match exponent {
            // A mantissa that rounds up to 10.
            Some(e) if millionths >= 10_000_000 => {
                millionths = libm::round(mantissa * 1e5) as u64;
                Some(e + 1)
            }
            other => other,
        };
        write!(f, "{sign}{}.{:06}", millionths / 1_000_000, millionths % 1_000_000)?;
        match exponent {
            Some(e) => write!(f, "e{e}"),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::format;

    use super::Decimal6;

    /// Against core's own formatting with six decimals, which rounds the exact binary value
    /// (ties to even) where this rounds the product by 1e6: the two agree wherever that
    /// product is not within an ulp of a tie.
    #[test]
    fn six_decimals_agree_with_core_formatting() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..20_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let unit = (s >> 11) as f64 / (1u64 << 53) as f64;
            // Magnitudes from 1e-5 to 1e9.
            let v = (unit - 0.5) * libm::pow(10.0, f64::from((s % 14) as u32) - 4.0);
            let scaled = libm::fabs(v) * 1e6;
            if (scaled - libm::floor(scaled) - 0.5).abs() < 1e-6 {
                continue;
            }
            assert_eq!(format!("{}", Decimal6(v)), format!("{v:.6}"), "{v:e}");
        }
    }

    #[test]
    fn specials_large_and_signed_zero() {
        assert_eq!(format!("{}", Decimal6(f64::NAN)), "NaN");
        assert_eq!(format!("{}", Decimal6(f64::INFINITY)), "inf");
        assert_eq!(format!("{}", Decimal6(f64::NEG_INFINITY)), "-inf");
        assert_eq!(format!("{}", Decimal6(-0.0)), "-0.000000");
        assert_eq!(format!("{}", Decimal6(-0.5)), "-0.500000");
        assert_eq!(format!("{}", Decimal6(1.5e15)), "1.500000e15");
        assert_eq!(format!("{}", Decimal6(-2.5e300)), "-2.500000e300");
        assert_eq!(format!("{}", Decimal6(f64::MAX)), "1.797693e308");
        assert_eq!(format!("{}", Decimal6(999_999_999.999_999_9)), "1000000000.000000");
        assert_eq!(format!("{}", Decimal6(9.999_999_9e15)), "1.000000e16");
        assert_eq!(format!("{}", Decimal6(123.456_789_4)), "123.456789");
    }
}
