//! Radiometry, atmosphere, sensor and noise: the numbers of the simulation.
//!
//! Pure Rust, no Bevy: plain data in, plain data out, no clocks, no global random state. Every function cites
//! the paper's equation it implements ("eq N", see `DESIGN.md`) and states where it departs from it.

pub mod atmosphere;
pub mod brdf;
pub mod noise;
pub mod planck;
pub mod reflection;
pub mod sensor;
pub mod signal;
pub mod skin;
pub mod transmittance;
