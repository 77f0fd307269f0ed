//! Radiometry, atmosphere, sensor and noise: the numbers of the simulation.
//!
//! Pure Rust, no Bevy: plain data in, plain data out, no clocks, no global random state. Every function cites
//! the paper's equation it implements ("eq N", see `DESIGN.md`) and states where it departs from it.

pub mod atmosphere;
pub mod brdf;
pub mod detector;
pub mod exact;
pub mod lowtran;
pub mod lowtran_paths;
pub mod noise;
pub mod nonideal;
pub mod planck;
pub mod random;
pub mod reflection;
pub mod sensor;
pub mod signal;
pub mod simd;
pub mod skin;
pub mod sky;
pub mod trajectory;
pub mod transmittance;

/// A number as a person writes it in a message: plain for everyday magnitudes, in exponent form for tiny and
/// huge ones (`1e-300`, not three hundred zeros), to 12 significant digits, which drops the binary rounding of
/// decimal steps (`0.1 + 0.2` shows as 0.3, not 0.30000000000000004) and keeps any digit a person typed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = if self.0.is_finite() { format!("{:.11e}", self.0).parse().unwrap_or(self.0) } else { self.0 };
        if v == 0.0 || !v.is_finite() || (1e-4..1e15).contains(&v.abs()) {
            write!(f, "{v}")
        } else {
            write!(f, "{v:e}")
        }
    }
}

/// A parameter outside its allowed range: the error of every `validate` in the physics layer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("parameter {name} = {} is outside its allowed range {range}", Num(*.value))]
pub struct ParamError {
    /// Parameter name.
    pub name: &'static str,
    /// The value given.
    pub value: f64,
    /// The allowed range, in words.
    pub range: String,
}

impl ParamError {
    /// `Ok` if `value` is finite and in `[lo, hi]`, else the error naming `name` and the range.
    ///
    /// # Errors
    /// The [`ParamError`].
    pub fn check_range(name: &'static str, value: f64, lo: f64, hi: f64) -> Result<(), ParamError> {
        if value.is_finite() && value >= lo && value <= hi {
            Ok(())
        } else {
            Err(ParamError { name, value, range: format!("[{}, {}]", Num(lo), Num(hi)) })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn numbers_in_messages_drop_binary_rounding_but_keep_typed_digits() {
        assert_eq!(Num(0.1 + 0.2).to_string(), "0.3");
        assert_eq!(Num(-0.05000000000000002).to_string(), "-0.05");
        assert_eq!(Num(1.0000001).to_string(), "1.0000001");
        assert_eq!(Num(123456.789).to_string(), "123456.789");
        assert_eq!(Num(1e-300).to_string(), "1e-300");
        assert_eq!(Num(0.0).to_string(), "0");
        assert_eq!(Num(f64::NAN).to_string(), "NaN");
        assert_eq!(Num(f64::NEG_INFINITY).to_string(), "-inf");
    }
}
