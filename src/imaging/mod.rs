//! Image formation: camera, sky plane ray casting, target blob, Poisson fusion, frames.
//!
//! Pure Rust, no Bevy. Geometry in f64; frame pixels in f32. Every kernel is plain data in, plain data out,
//! and row-parallel kernels give the same result for any thread count.

pub mod agc;
pub mod background;
pub mod camera;
pub mod fft2d;
pub mod frame;
pub mod fusion;
pub mod png16;
pub mod prefilter;
pub mod psd;
pub mod psf;
pub mod sky_field;
pub mod sky_gen;
pub mod sky_plane;
pub mod target_blob;
pub mod target_psf;
pub mod vibration;
