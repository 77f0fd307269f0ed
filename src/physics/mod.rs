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
