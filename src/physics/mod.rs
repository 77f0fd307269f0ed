//! Radiometry, atmosphere, sensor and noise: the numbers of the simulation.
//!
//! Pure Rust, no Bevy: plain data in, plain data out, no clocks, no global random state. Every function cites
//! the paper's equation it implements ("eq N", see `DESIGN.md`) and states where it departs from it.

pub mod atmosphere;
pub mod brdf;
pub mod detector;
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
pub mod transmittance;

/// A parameter outside its allowed range: the error of every `validate` in the physics layer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("parameter {name} = {value} is outside its allowed range {range}")]
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
            Err(ParamError { name, value, range: format!("[{lo}, {hi}]") })
        }
    }
}
