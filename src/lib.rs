//! irsim: infrared imaging simulation of small aerial targets.
//!
//! It simulates what an infrared camera sees when small aircraft fly through its field of view against the sky:
//! sequences of sensor frames with exact ground truth. It implements, and corrects where needed, the method of
//! "Dynamic infrared imaging simulation of small aerial target": skin temperature from Mach and altitude
//! (eqs 1–2), Planck band radiance (eq 3), Cook–Torrance sun reflection (eqs 4–9), atmospheric transmittance,
//! the sensor's optics, gray mapping and noise (eqs 13–15).
//!
//! Layers, dependencies pointing down only:
//! - [`physics`]: radiometry, atmosphere, sensor and noise — pure numerics, no Bevy;
//! - [`imaging`]: camera, sky-plane ray casting, target blob, Poisson fusion, frames — pure, no Bevy;
//! - [`labels`]: ground truth of a frame (labels, MOT lines, masks) — pure, no Bevy;
//! - [`scenario`]: the scenario schema, validation and trajectory building — pure, no Bevy;
//! - [`sim`]: the Bevy ECS simulation — entities, system sets, plugins, the headless app;
//! - [`record`]: writers of frames, labels, MOT ground truth and manifest;
//! - `ui` (feature `gui`, on by default): `irsim view`, the window — Bevy's renderer and egui;
//! - [`cli`]: the `irsim` command line.

pub mod cli;
pub mod dataset;
pub mod imaging;
pub mod labels;
pub mod physics;
pub mod record;
pub mod scenario;
pub mod sim;
#[cfg(feature = "gui")]
pub mod ui;
