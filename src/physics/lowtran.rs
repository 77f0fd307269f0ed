//! Atmospheric transmittance and thermal path radiance from LOWTRAN7 tables, for a band, a geometry and a
//! weather: the model atmosphere, the aerosol model and the visibility.
//!
//! The table (`assets/atmosphere/lowtran7.irat`, built into the program; made by
//! `tools/atmosphere/lowtran_tables.py`) holds two things, both on 108 spectral bins over 1–14 µm (0.05 µm wide in
//! 3–5 µm, 0.1 µm in 8–12 µm, 0.25 µm elsewhere):
//! - per model atmosphere, the **molecular** optical depth `−ln τ` (aerosol off) of LOWTRAN's refracted slant path
//!   between a lower and an upper altitude (23 altitudes, 0–20 km) for 15 ranges up to 100 km, plus the vertical
//!   path;
//! - per model atmosphere, aerosol model and visibility, the **aerosol extinction** per km at those altitudes.
//!
//! A path's spectral transmittance is the molecular part interpolated on the grid, times `exp(−∫β ds)`, the
//! aerosol extinction integrated along the straight line between the ends (spherical Earth). LOWTRAN's own total
//! is the same product, so the split costs only the aerosol's path geometry: within 0.0025 in band τ against
//! direct runs (see the generator's notes).
//!
//! Interpolation, chosen by measured error against direct LOWTRAN runs between the nodes (the generator's
//! `lowtran7_offgrid.json`): the optical depth is interpolated linearly in the range along each altitude pair's
//! own range axis (which starts at the vertical path, the shortest path between the two altitudes), and bilinearly
//! in the two altitudes in the coordinate `−exp(−h / 3 km)`, which follows water vapour's fall with height. On
//! 44 paths up to 50 km (midlatitude summer, no aerosol) that gives at most 0.0020 in band τ (8–12 and 3–5 µm);
//! linear in altitude gives 0.0047. The range axis is linear in √range (short paths saturate strong lines within
//! metres). A path shorter than the vertical path of one of its corner pairs that rises at most 3 km (short
//! against the altitude cells it lies in) is the mean, along it, of the horizontal paths of its own length at
//! its altitudes; a steeper one holds such a corner's vertical path scaled as the horizontal paths at its
//! altitudes grow; a
//! horizontal path shorter than the first range (0.5 km) follows each bin's own curve of growth between the first
//! two ranges as a power law. On 19 such short paths (0.05–3.2 km long, rising up to 3 km; midlatitude summer,
//! rural 23 km) that gives at most 0.0058 in band τ against direct LOWTRAN runs, where the √range axis and the
//! scaled vertical paths erred by up to 0.067 (the test `short_paths_match_direct_runs`). The aerosol extinction is interpolated in altitude as
//! LOWTRAN does between its levels (exponentially, linearly where one regime hands over to the next), and
//! linearly in 1/visibility between the tabulated visibilities.
//!
//! The path radiance is the path's own thermal emission, `∫ B̄(T(s)) dτ(s)` along the line of sight with the model
//! atmosphere's temperature profile and the transmittance from the observer, as LOWTRAN sums it over its layers:
//! over [`PathSteps::radiance`] segments, closer together near the observer (the ends at `(k/N)²` of the path,
//! where τ falls fastest), each with the source linear in its optical depth between the Planck means at its
//! ends (exact for an isothermal path). The error falls as `N⁻²`: against 512 segments, 64 are within 0.13 % of
//! the band path radiance and 16 within 0.43 % on the test's paths and sky rays
//! (`path_integrals_converge_with_their_steps`); 32 equal segments with the temperature at each middle, a rule of
//! first order, had left 41 DN rms in supersonic_climb's clear-sky dome. The aerosol's optical depth is
//! integrated by [`PathSteps::aerosol`] trapezoids along the line of sight.
//!
//! A path outside the grid (an altitude above 20 km or below 0, a range above 100 km or shorter than the
//! altitude difference, a line of sight through the ground, a visibility outside the tabulated ones) is an error,
//! never an extrapolation.

use std::io::Read as _;
use std::ops::Range;
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::planck::{Band, Measure, PlanckMethod, band_radiance, band_radiance_in};
use super::simd::{exp, widest};

/// The shipped table.
const SHIPPED: &[u8] = include_bytes!("../../assets/atmosphere/lowtran7.irat");
/// The table format this program reads.
pub const FORMAT_VERSION: u32 = 3;
/// Earth's radius of the paths' geometry, km (LOWTRAN's).
pub const EARTH_RADIUS_KM: f64 = 6371.23;
/// Scale height of the altitude coordinate `−exp(−h/H)` of the interpolation, km.
pub const ALTITUDE_SCALE_KM: f64 = 3.0;
/// How finely a path's two integrals along the line of sight are taken (`[quality] atmosphere_steps`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PathSteps {
    /// Trapezoids of the aerosol optical depth's integral.
    pub aerosol: usize,
    /// Segments of the path radiance's integral.
    pub radiance: usize,
}

impl PathSteps {
    /// The `standard` preset's.
    pub const STANDARD: Self = Self { aerosol: 128, radiance: 64 };
    /// The `reference` preset's, and the most either may be.
    pub const REFERENCE: Self = Self { aerosol: 512, radiance: 512 };
    /// The `draft` preset's.
    pub const DRAFT: Self = Self { aerosol: 32, radiance: 16 };
    /// The fewest either may be.
    pub const MIN: usize = 2;
}
/// Temperatures (K, whole kelvins) of the path radiance's Planck table; the model atmospheres to 20 km lie inside.
const PLANCK_TABLE_K: (f64, f64) = (150.0, 350.0);
/// A path shorter than one of its corner pairs' vertical paths that rises at most this much, km, is the mean of
/// horizontal paths along it; a steeper one scales its corners' vertical paths.
const SHORT_PATH_MAX_RISE_KM: f64 = 3.0;
/// With `[quality] atmosphere_tolerance` = t, a line of sight is interpolated again once an end's altitude has
/// moved by t times this, km.
pub const ALTITUDE_TOLERANCE_SCALE_KM: f64 = 1.0;
/// Temperature of the blackbody whose photon-to-energy ratio converts a bin's path radiance to photons, K.
pub const PHOTON_REFERENCE_K: f64 = 250.0;
/// LOWTRAN's layers (km) where one aerosol regime hands over to the next.
const REGIME_HANDOVER_KM: [(f64, f64); 2] = [(2.0, 3.0), (10.0, 11.0)];
/// Lowest point of a line of sight above the ground, km, below which it is refused (1 m), except for the
/// horizontal path at 0 km.
const GROUND_CLEARANCE_KM: f64 = -0.001;

/// LOWTRAN's model atmospheres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[derive(clap::ValueEnum)]
pub enum ModelAtmosphere {
    /// Tropical (15° N).
    Tropical,
    /// Mid-latitude summer (45° N, July).
    #[value(alias = "midlatitude_summer")]
    MidlatitudeSummer,
    /// Mid-latitude winter (45° N, January).
    #[value(alias = "midlatitude_winter")]
    MidlatitudeWinter,
    /// Sub-arctic summer (60° N, July).
    #[value(alias = "subarctic_summer")]
    SubarcticSummer,
    /// Sub-arctic winter (60° N, January).
    #[value(alias = "subarctic_winter")]
    SubarcticWinter,
    /// US Standard Atmosphere 1976.
    #[value(name = "us-standard-1976", alias = "us_standard_1976")]
    #[serde(rename = "us_standard_1976")]
    UsStandard1976,
}

impl ModelAtmosphere {
    /// Every model, in the table's order.
    pub const ALL: [ModelAtmosphere; 6] = [
        ModelAtmosphere::Tropical,
        ModelAtmosphere::MidlatitudeSummer,
        ModelAtmosphere::MidlatitudeWinter,
        ModelAtmosphere::SubarcticSummer,
        ModelAtmosphere::SubarcticWinter,
        ModelAtmosphere::UsStandard1976,
    ];

    /// The name in scenario files and the table.
    pub fn name(self) -> &'static str {
        match self {
            ModelAtmosphere::Tropical => "tropical",
            ModelAtmosphere::MidlatitudeSummer => "midlatitude_summer",
            ModelAtmosphere::MidlatitudeWinter => "midlatitude_winter",
            ModelAtmosphere::SubarcticSummer => "subarctic_summer",
            ModelAtmosphere::SubarcticWinter => "subarctic_winter",
            ModelAtmosphere::UsStandard1976 => "us_standard_1976",
        }
    }
}

/// LOWTRAN's boundary-layer aerosol models (above 2 km LOWTRAN's tropospheric and stratospheric background, by
/// season).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[derive(clap::ValueEnum)]
pub enum Aerosol {
    /// No aerosol at all: molecular absorption and continua only.
    None,
    /// Rural (continental, no urban sources).
    Rural,
    /// Maritime (sea salt over the ocean).
    Maritime,
    /// Urban (rural mixed with combustion products).
    Urban,
}

impl Aerosol {
    /// The name in scenario files and the table.
    pub fn name(self) -> &'static str {
        match self {
            Aerosol::None => "none",
            Aerosol::Rural => "rural",
            Aerosol::Maritime => "maritime",
            Aerosol::Urban => "urban",
        }
    }
}

/// The weather of a path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weather {
    /// Model atmosphere (temperature, pressure, water vapour, ozone profiles).
    pub model: ModelAtmosphere,
    /// Aerosol model.
    pub aerosol: Aerosol,
    /// Meteorological range at sea level, km (unused without aerosol).
    pub visibility_km: f64,
}

/// What can go wrong with a table or a path.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AtmosphereError {
    /// The table's bytes are not a valid table.
    #[error("atmosphere table: {0}")]
    Table(String),
    /// A quantity of the path outside the table's grid.
    #[error("{name} = {value} is outside the LOWTRAN table's range {range}")]
    OutsideGrid {
        /// The quantity.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The range the table covers.
        range: String,
    },
    /// The line of sight passes through the ground.
    #[error(
        "the line of sight from {observer_alt_km} km to {target_alt_km} km over {range_km} km passes {below_m:.0} m \
         below the ground (Earth radius {EARTH_RADIUS_KM} km)"
    )]
    BelowGround {
        /// Observer's altitude, km.
        observer_alt_km: f64,
        /// Target's altitude, km.
        target_alt_km: f64,
        /// Range, km.
        range_km: f64,
        /// How far below, m.
        below_m: f64,
    },
}

#[derive(Debug, Deserialize)]
struct Header {
    models: Vec<String>,
    aerosols: Vec<AerosolSetting>,
    altitudes_km: Vec<f64>,
    ranges_km: Vec<f64>,
    bin_edges_um: Vec<f64>,
    bin_samples: Vec<u32>,
    optical_depth_scale: f64,
    profiles: std::collections::BTreeMap<String, Profile>,
    above_top_km: Vec<f64>,
}

#[derive(Debug, Deserialize)]
struct AerosolSetting {
    aerosol: String,
    visibility_km: f64,
}

/// A model atmosphere's levels.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct Profile {
    /// Altitudes of the levels, km, increasing.
    pub altitude_km: Vec<f64>,
    /// Pressure, hPa.
    pub pressure_hpa: Vec<f64>,
    /// Temperature, K.
    pub temperature_k: Vec<f64>,
}

impl Profile {
    /// Temperature at altitude `h_km` (linear between levels).
    pub fn temperature_at(&self, h_km: f64) -> f64 {
        interp_linear(&self.altitude_km, &self.temperature_k, h_km)
    }
}

/// A LOWTRAN7 table, loaded and checked.
#[derive(Debug)]
pub struct AtmosphereTable {
    alt_km: Vec<f64>,
    alt_coord: Vec<f64>,
    ranges_km: Vec<f64>,
    edges_um: Vec<f64>,
    samples: Vec<u32>,
    od_scale: f64,
    settings: Vec<(Aerosol, f64)>,
    profiles: Vec<Profile>,
    /// Levels of the columns above the grid's altitudes, km, the top itself first.
    above_km: Vec<f64>,
    /// The compressed payload, one block per model atmosphere, each decoded into [`Self::data`] when a path
    /// through that model first needs it (the header alone answers a scenario's checks: the grids, the
    /// visibilities, the bands and the profiles).
    packed: Vec<Packed>,
    data: Vec<OnceLock<Result<Payload, AtmosphereError>>>,
    /// Per bin, made when the bin is first asked for (a run's band holds a third of the bins or fewer): the mean
    /// blackbody radiance over the bin at each whole kelvin of [`PLANCK_TABLE_K`], with its logarithm (NaN where
    /// the radiance is not positive).
    planck: Vec<OnceLock<PlanckRow>>,
    /// The aerosol profiles of the weathers asked for last (a run asks for one weather's paths thousands of
    /// times): `(model, settings and weights' bits)` and [`Self::aerosol_profile`]'s result.
    profile_cache: std::sync::Mutex<Vec<(ProfileKey, std::sync::Arc<AerosolProfile>)>>,
}

/// A model atmosphere's block of a table's payload, as the file holds it (no bytes in a table read by
/// [`AtmosphereTable::parse`], whose blocks are decoded as it reads them).
#[derive(Debug, Clone, Copy)]
struct Packed {
    bytes: &'static [u8],
    /// The decoded length the header gives.
    raw_len: u64,
    /// CRC-32 of the decoded payload.
    crc: u32,
}

/// The table's arrays for one model atmosphere.
#[derive(Debug)]
struct Payload {
    /// Molecular optical depth, quantized, [pair][range node][bin].
    od: Vec<u16>,
    /// 1 where LOWTRAN could not trace the node's path (it holds a neighbour's values).
    flags: Vec<u8>,
    /// Length LOWTRAN traced on its first try, km.
    traced_km: Vec<f32>,
    /// Aerosol extinction per km, [aerosol setting][altitude][bin].
    ext: Vec<f32>,
    /// Optical depth per bin of the vertical path from each grid altitude to each of `above_km` (0 where the level
    /// is not above it), `[altitude][level][bin]`.
    above_od: Vec<f32>,
    /// Per altitude and bin, the exponent of the power law that carries a horizontal path shorter than the first
    /// range ([`AtmosphereTable::pair_into`]), `[altitude][bin]` (empty for a table of one range).
    short_exponent: Vec<f64>,
}

/// A weather's aerosol extinction per km at the grid's altitudes (`[altitude][bin]`) and its logarithm.
type AerosolProfile = (Vec<f64>, Vec<f64>);
/// A path between altitudes `lo ≤ hi` over a range: `(lo, hi, range)`, km.
type Span = (f64, f64, f64);
/// A bin's mean blackbody radiance at each whole kelvin of [`PLANCK_TABLE_K`], with its logarithm.
type PlanckRow = Box<[(f64, f64)]>;
/// What an aerosol profile depends on: the model's index, and each aerosol setting's index and weight (bits).
type ProfileKey = (usize, Vec<(usize, u64)>);
/// Aerosol profiles kept by a table.
const PROFILE_CACHE: usize = 8;

/// The blackbody weights of [`PathSpectrum::spectrum_weighted_with`] kept for the temperature, measure, band,
/// method and bins they were made for, so that a target whose skin temperature does not change (steady speed at
/// one altitude) does not integrate the blackbody over every bin again at each frame; the same bits either way.
/// Made again whenever any of those differ from the last call's (the temperature and the band in bits, the bins'
/// edges by value).
#[derive(Debug, Default)]
pub struct BinWeights(std::sync::Mutex<KeptWeights>);

#[derive(Debug, Clone, Default)]
struct KeptWeights {
    /// Temperature and band bits, measure, method and the number of bins of the weights held.
    made_for: Option<(u64, Measure, [u64; 2], PlanckMethod, usize)>,
    edges_um: Vec<f64>,
    weights: Vec<(usize, f64)>,
}

impl Clone for BinWeights {
    fn clone(&self) -> Self {
        Self(std::sync::Mutex::new(self.kept().clone()))
    }
}

impl BinWeights {
    fn kept(&self) -> std::sync::MutexGuard<'_, KeptWeights> {
        // a poisoned lock's values are still usable: weights being made are made for nothing until whole
        self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// [`PathSpectrum::spectrum_weighted_with`] of `spectrum`, with the weights kept from the last call when it
    /// was made for the same temperature, measure, band, method and bins.
    pub fn spectrum_weighted_with(
        &self,
        spectrum: &PathSpectrum,
        measure: Measure,
        band: Band,
        temp_k: f64,
        method: PlanckMethod,
    ) -> f64 {
        let bins = spectrum.transmittance.len();
        let key = (temp_k.to_bits(), measure, [band.lo_um().to_bits(), band.hi_um().to_bits()], method, bins);
        let mut kept = self.kept();
        if kept.made_for != Some(key) || kept.edges_um != spectrum.edges_um {
            let KeptWeights { made_for, edges_um, weights } = &mut *kept;
            // made for nothing until whole
            *made_for = None;
            weights.clear();
            weights.extend(spectrum.blackbody_in_bins(measure, band, temp_k, method));
            edges_um.clone_from(&spectrum.edges_um);
            *made_for = Some(key);
        }
        spectrum.weighted_by_bins(band, kept.weights.iter().copied())
    }
}

/// The spectral result for one path.
#[derive(Debug, Clone)]
pub struct PathSpectrum {
    /// Spectral bins' edges, µm (one more than the bins).
    pub edges_um: Vec<f64>,
    /// LOWTRAN's samples (5 cm⁻¹ apart) in each bin: the weights of a band average uniform in wavenumber.
    pub samples: Vec<u32>,
    /// Transmittance per bin (molecular times aerosol), [0, 1].
    pub transmittance: Vec<f64>,
    /// Thermal path radiance per bin, W m⁻² sr⁻¹ µm⁻¹ (mean over the bin).
    pub path_radiance_w_m2_sr_um: Vec<f64>,
    /// The grid cell the path fell in.
    pub cell: GridCell,
}

/// Where a path falls in the table's grid.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GridCell {
    /// Model atmosphere.
    pub model: &'static str,
    /// Lower end's altitude bracket, km.
    pub lower_alt_km: [f64; 2],
    /// Upper end's altitude bracket, km.
    pub upper_alt_km: [f64; 2],
    /// Range bracket of the first corner's pair, km.
    pub range_km: [f64; 2],
    /// Aerosol visibility bracket, km (empty without aerosol).
    pub visibility_km: Vec<f64>,
    /// Whether a corner is a path LOWTRAN could not trace (the result is less accurate there).
    pub untraceable_corner: bool,
    /// Length LOWTRAN traced on its first try at the corners' nodes, km (the table holds the ranges asked for).
    pub lowtran_first_traced_km: Vec<f64>,
}

fn interp_linear(x: &[f64], y: &[f64], at: f64) -> f64 {
    let i = bracket(x, at);
    let f = ((at - x[i]) / (x[i + 1] - x[i])).clamp(0.0, 1.0);
    y[i] + f * (y[i + 1] - y[i])
}

/// The index `i` with `x[i] ≤ at ≤ x[i + 1]` (clamped to the ends).
fn bracket(x: &[f64], at: f64) -> usize {
    let n = x.len();
    let i = x.partition_point(|&v| v <= at);
    i.saturating_sub(1).min(n - 2)
}

fn altitude_coord(h_km: f64) -> f64 {
    -(-h_km / ALTITUDE_SCALE_KM).exp()
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], AtmosphereError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| AtmosphereError::Table(format!("truncated in the {what}")))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u32(&mut self, what: &str) -> Result<u32, AtmosphereError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap_or([0; 4])))
    }
    fn u64(&mut self, what: &str) -> Result<u64, AtmosphereError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or([0; 8])))
    }
}

fn bad(msg: impl Into<String>) -> AtmosphereError {
    AtmosphereError::Table(msg.into())
}

fn increasing(name: &str, v: &[f64], min_len: usize) -> Result<(), AtmosphereError> {
    if v.len() < min_len || v.iter().any(|x| !x.is_finite()) || v.windows(2).any(|w| w[1] <= w[0]) {
        return Err(bad(format!("{name} must be at least {min_len} finite increasing numbers")));
    }
    Ok(())
}

impl AtmosphereTable {
    /// The table built into the program: its header read and checked once, each model's block when a path
    /// through that model first needs it ([`AtmosphereTable::path`] and the others then give a damaged block's
    /// [`AtmosphereError::Table`]).
    ///
    /// # Errors
    /// [`AtmosphereError::Table`] if the built-in table's header is damaged (a build problem).
    pub fn shipped() -> Result<&'static AtmosphereTable, AtmosphereError> {
        static TABLE: OnceLock<Result<AtmosphereTable, AtmosphereError>> = OnceLock::new();
        TABLE.get_or_init(|| AtmosphereTable::read(SHIPPED)).as_ref().map_err(Clone::clone)
    }

    /// Reads and checks a table: magic, version, header, lengths, CRC-32 and grids.
    ///
    /// # Errors
    /// [`AtmosphereError::Table`] saying what is wrong.
    pub fn parse(bytes: &[u8]) -> Result<Self, AtmosphereError> {
        // every block decoded now, from the borrowed bytes
        let mut blocks = Vec::new();
        let mut table = Self::read_with(bytes, |packed| {
            blocks.push(packed);
            &[]
        })?;
        let data =
            blocks.iter().enumerate().map(|(m, packed)| decode(packed, &table, m)).collect::<Result<Vec<_>, _>>()?;
        table.data = data.into_iter().map(|d| OnceLock::from(Ok(d))).collect();
        Ok(table)
    }

    /// [`AtmosphereTable::parse`] of a table that lives as long as the program, each model's block decoded when a
    /// path through that model first needs it ([`Self::data`]): a scenario's checks read the header alone, a run
    /// inflates one block of six, and it does so beside the rest of its set-up.
    fn read(bytes: &'static [u8]) -> Result<Self, AtmosphereError> {
        Self::read_with(bytes, |packed| packed)
    }

    /// The header read and checked, each block's bytes kept as `keep` gives them.
    fn read_with<'a>(
        bytes: &'a [u8],
        mut keep: impl FnMut(&'a [u8]) -> &'static [u8],
    ) -> Result<Self, AtmosphereError> {
        let mut r = Reader { bytes, at: 0 };
        if r.take(8, "magic")? != b"IRSIMATM" {
            return Err(bad("not an irsim atmosphere table (no IRSIMATM magic)"));
        }
        let version = r.u32("version")?;
        if version != FORMAT_VERSION {
            return Err(bad(format!("format version {version}, this program reads {FORMAT_VERSION}")));
        }
        let hlen = r.u32("header length")? as usize;
        let head: Header = serde_json::from_slice(r.take(hlen, "header")?).map_err(|e| bad(format!("header: {e}")))?;
        let count = r.u32("block count")? as usize;
        if count != ModelAtmosphere::ALL.len() {
            return Err(bad(format!(
                "{count} blocks, one per model atmosphere ({}) expected",
                ModelAtmosphere::ALL.len()
            )));
        }
        let mut sizes = Vec::with_capacity(count);
        for _ in 0..count {
            let plen = r.u64("block's compressed length")?;
            let crc = r.u32("block's checksum")?;
            let raw_len = r.u64("block's length")?;
            sizes.push((plen, crc, raw_len));
        }
        let mut packed = Vec::with_capacity(count);
        for (plen, crc, raw_len) in sizes {
            let bytes = r.take(usize::try_from(plen).map_err(|_| bad("payload too long"))?, "payload")?;
            packed.push(Packed { bytes: keep(bytes), raw_len, crc });
        }
        if r.at != bytes.len() {
            return Err(bad(format!("{} bytes after the payload", bytes.len() - r.at)));
        }
        Self::from_header(head, packed)
    }

    fn from_header(head: Header, packed: Vec<Packed>) -> Result<Self, AtmosphereError> {
        increasing("altitudes_km", &head.altitudes_km, 2)?;
        increasing("ranges_km", &head.ranges_km, 2)?;
        increasing("bin_edges_um", &head.bin_edges_um, 2)?;
        if head.altitudes_km[0] != 0.0 || head.ranges_km[0] <= 0.0 {
            return Err(bad("altitudes must start at 0 km and ranges above 0"));
        }
        let nbins = head.bin_edges_um.len() - 1;
        if head.bin_samples.len() != nbins || head.bin_samples.contains(&0) {
            return Err(bad("bin_samples must give a positive count per bin"));
        }
        if !(head.optical_depth_scale > 0.0 && head.optical_depth_scale.is_finite()) {
            return Err(bad("optical_depth_scale must be positive"));
        }
        let model_names: Vec<&str> = ModelAtmosphere::ALL.iter().map(|m| m.name()).collect();
        if head.models != model_names {
            return Err(bad(format!("models must be {model_names:?}")));
        }
        let mut profiles = Vec::new();
        for m in ModelAtmosphere::ALL {
            let p = head.profiles.get(m.name()).ok_or_else(|| bad(format!("no profile for {}", m.name())))?;
            increasing("profile altitudes", &p.altitude_km, 2)?;
            if p.temperature_k.len() != p.altitude_km.len() || p.temperature_k.iter().any(|t| !(*t > 0.0)) {
                return Err(bad(format!("{}: temperatures must be positive, one per level", m.name())));
            }
            profiles.push(p.clone());
        }
        let top = head.altitudes_km[head.altitudes_km.len() - 1];
        let above_km = head.above_top_km.clone();
        increasing("above_top_km", &above_km, 2)?;
        if above_km[0] != top {
            return Err(bad("above_top_km must start at the grid's top altitude"));
        }
        let mut settings = Vec::new();
        for s in &head.aerosols {
            let a = match s.aerosol.as_str() {
                "rural" => Aerosol::Rural,
                "maritime" => Aerosol::Maritime,
                "urban" => Aerosol::Urban,
                other => return Err(bad(format!("unknown aerosol {other:?}"))),
            };
            if !(s.visibility_km > 0.0 && s.visibility_km.is_finite()) {
                return Err(bad("aerosol visibilities must be positive"));
            }
            settings.push((a, s.visibility_km));
        }
        let table = AtmosphereTable {
            alt_coord: head.altitudes_km.iter().map(|&h| altitude_coord(h)).collect(),
            alt_km: head.altitudes_km,
            ranges_km: head.ranges_km,
            edges_um: head.bin_edges_um,
            samples: head.bin_samples,
            od_scale: head.optical_depth_scale,
            settings,
            profiles,
            above_km,
            data: packed.iter().map(|_| OnceLock::new()).collect(),
            packed,
            planck: (0..nbins).map(|_| OnceLock::new()).collect(),
            profile_cache: std::sync::Mutex::new(Vec::new()),
        };
        for (m, p) in table.packed.iter().enumerate() {
            if usize::try_from(p.raw_len).ok() != Some(table.block_len()) {
                return Err(bad(format!("block {m} is {} bytes, the grid needs {}", p.raw_len, table.block_len())));
            }
        }
        Ok(table)
    }

    /// A model's decoded block's length the grid needs, bytes.
    fn block_len(&self) -> usize {
        let (nodes, nod, next, nabove) = self.block_parts();
        2 * nod + nodes + 4 * nodes + 4 * next + 4 * nabove
    }

    /// A model's nodes of the molecular grid, their values (nodes × bins), aerosol values and values above the top.
    fn block_parts(&self) -> (usize, usize, usize, usize) {
        let (nalt, nbins) = (self.alt_km.len(), self.nbins());
        let nodes = self.npairs() * self.nodes_per_pair();
        (nodes, nodes * nbins, self.settings.len() * nalt * nbins, nalt * self.above_km.len() * nbins)
    }

    /// Model `m`'s arrays, decoded from its block the first time they are asked for.
    ///
    /// # Errors
    /// [`AtmosphereError::Table`] for a block that does not decode, or does not match its checksum or grid.
    fn data(&self, m: usize) -> Result<&Payload, AtmosphereError> {
        self.data[m].get_or_init(|| decode(self.packed[m].bytes, self, m)).as_ref().map_err(Clone::clone)
    }

    fn nbins(&self) -> usize {
        self.edges_um.len() - 1
    }

    fn nodes_per_pair(&self) -> usize {
        1 + self.ranges_km.len()
    }

    /// The index of altitude pair `(i, j ≥ i)`, pairs numbered with `i` slowest.
    fn pair_index(&self, i: usize, j: usize) -> usize {
        let n = self.alt_km.len();
        i * n - i * i.saturating_sub(1) / 2 + (j - i)
    }

    /// The spectral bins' edges, µm, increasing.
    pub fn edges_um(&self) -> &[f64] {
        &self.edges_um
    }

    /// The grid's altitudes, km, increasing.
    pub fn altitudes_km(&self) -> &[f64] {
        &self.alt_km
    }

    /// Highest altitude of the grid, km.
    pub fn max_altitude_km(&self) -> f64 {
        self.alt_km[self.alt_km.len() - 1]
    }

    /// Longest range of the grid, km.
    pub fn max_range_km(&self) -> f64 {
        self.ranges_km[self.ranges_km.len() - 1]
    }

    /// The model atmosphere's profile.
    pub fn profile(&self, model: ModelAtmosphere) -> &Profile {
        &self.profiles[model_index(model)]
    }

    /// Visibilities tabulated for an aerosol model, km, increasing.
    pub fn visibilities_km(&self, aerosol: Aerosol) -> Vec<f64> {
        let mut v: Vec<f64> = self.settings.iter().filter(|s| s.0 == aerosol).map(|s| s.1).collect();
        v.sort_by(f64::total_cmp);
        v
    }

    /// Molecular optical depth per bin of the path between altitudes `lo ≤ hi` (km) over `range_km`, into `out`
    /// (the bins from `b0` on, as many as it holds); the flags and first traced lengths of the nodes used are
    /// collected in `info`.
    fn molecular_into(&self, d: &Payload, (lo, hi, range_km): Span, b0: usize, out: &mut [f64], info: &mut CornerInfo) {
        let ia = bracket(&self.alt_km, lo);
        let ib = bracket(&self.alt_km, hi);
        let c = altitude_coord;
        let fa = ((c(lo) - self.alt_coord[ia]) / (self.alt_coord[ia + 1] - self.alt_coord[ia])).clamp(0.0, 1.0);
        let fb = ((c(hi) - self.alt_coord[ib]) / (self.alt_coord[ib + 1] - self.alt_coord[ib])).clamp(0.0, 1.0);
        out.iter_mut().for_each(|v| *v = 0.0);
        // a short path nearly level: the mean, along it, of horizontal paths of its length
        let corners = [
            (ia, ib, (1.0 - fa) * (1.0 - fb)),
            (ia, ib + 1, (1.0 - fa) * fb),
            (ia + 1, ib, fa * (1.0 - fb)),
            (ia + 1, ib + 1, fa * fb),
        ];
        let short = corners.iter().any(|&(x, y, w)| w > 0.0 && (self.alt_km[x] - self.alt_km[y]).abs() > range_km);
        if short && hi - lo <= SHORT_PATH_MAX_RISE_KM {
            self.horizontal_mean_into(d, (lo, hi, range_km), b0, out, info);
            return;
        }
        let mut buf = Vec::new();
        for &(x, y, w) in &corners {
            if w == 0.0 {
                continue;
            }
            let (p, q) = (x.min(y), x.max(y));
            let dhc = self.alt_km[q] - self.alt_km[p];
            if range_km >= dhc {
                self.pair_into(d, p, q, (range_km, w), b0, out, info);
                continue;
            }
            // a corner whose shortest path (vertical, dhc) is longer than the path asked: its vertical path
            // scaled by how the horizontal paths at its two altitudes grow from range_km to dhc (strong lines
            // saturate within metres, so optical depth is far from proportional to length there)
            let nb = out.len();
            // zeroed for each such corner: the pair sums add into what they are given
            buf.clear();
            buf.resize(5 * nb, 0.0);
            let (v, rest) = buf.split_at_mut(nb);
            let (ar, rest) = rest.split_at_mut(nb);
            let (ad, rest) = rest.split_at_mut(nb);
            let (br, bd) = rest.split_at_mut(nb);
            self.pair_into(d, p, q, (dhc, 1.0), b0, v, info);
            self.pair_into(d, p, p, (range_km, 1.0), b0, ar, info);
            self.pair_into(d, p, p, (dhc, 1.0), b0, ad, info);
            self.pair_into(d, q, q, (range_km, 1.0), b0, br, info);
            self.pair_into(d, q, q, (dhc, 1.0), b0, bd, info);
            let ratio = |x: f64, y: f64| if y > 0.0 { x / y } else { range_km / dhc };
            for b in 0..nb {
                out[b] += w * v[b] * 0.5 * (ratio(ar[b], ad[b]) + ratio(br[b], bd[b]));
            }
        }
    }

    /// Molecular optical depth of a path short against the grid's altitude cells: the mean along it of the
    /// horizontal paths of the same length at its altitudes (the same curve of growth: strong lines saturate
    /// within metres, so a short path's depth is far from proportional to its length), each interpolated
    /// between the horizontal paths at the bracketing altitudes, in the altitude coordinate.
    fn horizontal_mean_into(
        &self,
        d: &Payload,
        (lo, hi, range_km): Span,
        b0: usize,
        out: &mut [f64],
        info: &mut CornerInfo,
    ) {
        const SAMPLES: usize = 16;
        let mut weights = vec![0.0; self.alt_km.len()];
        for k in 0..SAMPLES {
            let h = lo + (hi - lo) * (k as f64 + 0.5) / SAMPLES as f64;
            let i = bracket(&self.alt_km, h);
            let f =
                ((altitude_coord(h) - self.alt_coord[i]) / (self.alt_coord[i + 1] - self.alt_coord[i])).clamp(0.0, 1.0);
            weights[i] += (1.0 - f) / SAMPLES as f64;
            weights[i + 1] += f / SAMPLES as f64;
        }
        for (node, &w) in weights.iter().enumerate() {
            if w > 0.0 {
                self.pair_into(d, node, node, (range_km, w), b0, out, info);
            }
        }
    }

    /// Adds `weight` × the optical depth of altitude pair `(p, q)` at `range_km` along that pair's range axis, for
    /// the bins from `b0` on (as many as `out` holds).
    #[allow(clippy::too_many_arguments)]
    fn pair_into(
        &self,
        d: &Payload,
        p: usize,
        q: usize,
        (range_km, weight): (f64, f64),
        b0: usize,
        out: &mut [f64],
        info: &mut CornerInfo,
    ) {
        let nb = self.nbins();
        let n = out.len();
        let row = |node: usize| &d.od[node * nb + b0..][..n];
        let dh = self.alt_km[q] - self.alt_km[p];
        // the pair's axis: node 0 at the vertical range dh, then the grid's ranges beyond it (range k is node k + 1)
        let first = self.ranges_km.partition_point(|&r| r <= dh + 1e-9);
        let r = range_km.max(dh);
        let n = self.ranges_km.len();
        let (n0, r0, n1, r1) = if first >= n {
            (0, dh, 0, dh)
        } else if r <= self.ranges_km[first] || n - first < 2 {
            (0, dh, first + 1, self.ranges_km[first])
        } else {
            let k = first + bracket(&self.ranges_km[first..], r);
            (k + 1, self.ranges_km[k], k + 2, self.ranges_km[k + 1])
        };
        // linear in √range: short paths' optical depth grows like √range (saturated lines), long ones' nearly
        // linearly, and √ follows both between the nodes better than linear does (measured)
        let f = if r1 > r0 { ((r.sqrt() - r0.sqrt()) / (r1.sqrt() - r0.sqrt())).clamp(0.0, 1.0) } else { 0.0 };
        let base = self.pair_index(p, q) * self.nodes_per_pair();
        if dh == 0.0 && n0 == 0 && n > 1 && r < r1 {
            // a horizontal path shorter than the first range: each bin's own curve of growth between the first two
            // ranges, carried down as a power law (its exponent between ½, saturated lines, and 1, weak ones)
            let (a, b) = (base + 1, base + 2);
            info.untraceable |= d.flags[a] != 0 || d.flags[b] != 0;
            if info.range.is_none() {
                info.range = Some([0.0, r1]);
            }
            // (r/x₁)^γ as e^(γ·ln(r/x₁)), the logarithm shared by the bins, which vectorizes
            let ln_ratio = (r / self.ranges_km[0]).ln();
            let exponents = &d.short_exponent[p * nb + b0..][..out.len()];
            let scale = self.od_scale;
            widest(
                #[inline(always)]
                || {
                    for ((o, &v1), &gamma) in out.iter_mut().zip(row(a)).zip(exponents) {
                        *o += weight * (f64::from(v1) * scale) * exp(gamma * ln_ratio);
                    }
                },
            );
            return;
        }
        for (node, w) in [(n0, 1.0 - f), (n1, f)] {
            if w == 0.0 {
                continue;
            }
            let idx = base + node;
            info.untraceable |= d.flags[idx] != 0;
            if d.traced_km[idx] > 0.0 {
                // stored as f32: to the metre LOWTRAN prints
                info.traced.push((f64::from(d.traced_km[idx]) * 1000.0).round() / 1000.0);
            }
            for (o, &v) in out.iter_mut().zip(row(idx)) {
                *o += weight * w * f64::from(v) * self.od_scale;
            }
        }
        if info.range.is_none() {
            info.range = Some([r0, r1]);
        }
    }

    fn npairs(&self) -> usize {
        let n = self.alt_km.len();
        n * (n + 1) / 2
    }

    /// The weather's aerosol extinction per km at the grid's altitudes (`[altitude][bin]`, weighted over the
    /// bracketing visibilities), and its logarithm.
    fn aerosol_profile(&self, d: &Payload, m: usize, vis: &[(usize, f64)]) -> std::sync::Arc<AerosolProfile> {
        let key: ProfileKey = (m, vis.iter().map(|&(s, w)| (s, w.to_bits())).collect());
        let cache = || self.profile_cache.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((_, p)) = cache().iter().find(|(k, _)| *k == key) {
            return std::sync::Arc::clone(p);
        }
        let profile = std::sync::Arc::new(self.aerosol_profile_uncached(d, vis));
        let mut kept = cache();
        if kept.len() >= PROFILE_CACHE {
            kept.remove(0);
        }
        kept.push((key, std::sync::Arc::clone(&profile)));
        profile
    }

    /// [`Self::aerosol_profile`], computed.
    fn aerosol_profile_uncached(&self, d: &Payload, vis: &[(usize, f64)]) -> AerosolProfile {
        let nb = self.nbins();
        let nalt = self.alt_km.len();
        let mut rows = vec![0.0; nalt * nb];
        for &(s, w) in vis {
            let base = s * nalt * nb;
            for (o, &e) in rows.iter_mut().zip(&d.ext[base..base + nalt * nb]) {
                *o += w * f64::from(e);
            }
        }
        let logs = rows.iter().map(|&x| if x > 0.0 { x.ln() } else { f64::NEG_INFINITY }).collect();
        (rows, logs)
    }

    /// Aerosol extinction per km at altitude `h_km`, per bin from `b0` on (as many as `out` holds), into `out`,
    /// from [`Self::aerosol_profile`].
    fn extinction_at(&self, profile: &AerosolProfile, h_km: f64, b0: usize, out: &mut [f64]) {
        let nb = self.nbins();
        let n = out.len();
        let i = bracket(&self.alt_km, h_km);
        let f = ((h_km - self.alt_km[i]) / (self.alt_km[i + 1] - self.alt_km[i])).clamp(0.0, 1.0);
        // LOWTRAN varies each aerosol regime's extinction exponentially between its levels, and linearly where
        // one end is zero: in the layers where one regime hands over to the next (boundary layer to troposphere
        // at 2–3 km, troposphere to stratosphere at 10–11 km) the total is linear. Either way wrong costs up to
        // 0.02 in band τ (measured on paths through those layers).
        let (a0, a1) = (self.alt_km[i], self.alt_km[i + 1]);
        let linear = REGIME_HANDOVER_KM.iter().any(|&(lo, hi)| a0 >= lo && a1 <= hi);
        let (rows, logs) = profile;
        let (a, b) = (&rows[i * nb + b0..][..n], &rows[(i + 1) * nb + b0..][..n]);
        let (la, lb) = (&logs[i * nb + b0..][..n], &logs[(i + 1) * nb + b0..][..n]);
        widest(
            #[inline(always)]
            || {
                for (((o, (&x, &y)), &l0), &l1) in out.iter_mut().zip(a.iter().zip(b)).zip(la).zip(lb) {
                    // both sides, then the choice: the loop vectorizes
                    let log_linear = exp(l0 + f * (l1 - l0));
                    *o = if linear | (x <= 0.0) | (y <= 0.0) { x + f * (y - x) } else { log_linear };
                }
            },
        );
    }

    /// The aerosol settings and weights for a weather (linear in 1/visibility between the tabulated ones).
    fn visibility_weights(&self, w: &Weather) -> Result<VisibilityWeights, AtmosphereError> {
        if w.aerosol == Aerosol::None {
            return Ok((Vec::new(), Vec::new()));
        }
        let mut idx: Vec<(usize, f64)> =
            self.settings.iter().enumerate().filter(|(_, s)| s.0 == w.aerosol).map(|(i, s)| (i, s.1)).collect();
        idx.sort_by(|a, b| a.1.total_cmp(&b.1));
        let (lo, hi) = (idx[0].1, idx[idx.len() - 1].1);
        let v = w.visibility_km;
        if !(v >= lo && v <= hi) {
            return Err(AtmosphereError::OutsideGrid {
                name: "visibility_km",
                value: v,
                range: format!("[{lo}, {hi}] km for {} aerosol", w.aerosol.name()),
            });
        }
        if let Some(&(i, at)) = idx.iter().find(|s| s.1 == v) {
            return Ok((vec![(i, 1.0)], vec![at]));
        }
        let k = idx.windows(2).position(|p| v >= p[0].1 && v <= p[1].1).unwrap_or(0);
        let (a, b) = (idx[k], idx[k + 1]);
        let f = (1.0 / v - 1.0 / a.1) / (1.0 / b.1 - 1.0 / a.1);
        Ok((vec![(a.0, 1.0 - f), (b.0, f)], vec![a.1, b.1]))
    }

    /// Checks a path's geometry against the grid.
    ///
    /// # Errors
    /// [`AtmosphereError::OutsideGrid`] or [`AtmosphereError::BelowGround`] for a path the table does not cover.
    pub fn check_path(&self, observer_alt_km: f64, target_alt_km: f64, range_km: f64) -> Result<(), AtmosphereError> {
        let top = self.max_altitude_km();
        for (name, v) in [("observer_alt_km", observer_alt_km), ("target_alt_km", target_alt_km)] {
            if !(v >= 0.0 && v <= top) {
                return Err(AtmosphereError::OutsideGrid { name, value: v, range: format!("[0, {top}] km") });
            }
        }
        let dh = (target_alt_km - observer_alt_km).abs();
        let far = self.max_range_km();
        if !(range_km >= dh * (1.0 - 1e-9) && range_km <= far) {
            return Err(AtmosphereError::OutsideGrid {
                name: "range_km",
                value: range_km,
                range: format!("[{dh}, {far}] km (at least the altitude difference)"),
            });
        }
        if !(observer_alt_km == 0.0 && target_alt_km == 0.0) {
            let low = lowest_point_km(observer_alt_km, target_alt_km, range_km);
            if low < GROUND_CLEARANCE_KM {
                return Err(AtmosphereError::BelowGround {
                    observer_alt_km,
                    target_alt_km,
                    range_km,
                    below_m: -low * 1000.0,
                });
            }
        }
        Ok(())
    }

    /// Spectral transmittance and path radiance of the path from the observer to the target, its integrals taken
    /// in the `standard` preset's [`PathSteps::STANDARD`] (a scene's own steps: [`AtmosphereTable::path_in`]).
    ///
    /// # Errors
    /// [`AtmosphereError::OutsideGrid`] or [`AtmosphereError::BelowGround`] for a path the table does not cover;
    /// [`AtmosphereError::Table`] if the weather's model block of the table is damaged (every path through that
    /// model, one of no length too).
    pub fn path(
        &self,
        weather: &Weather,
        observer_alt_km: f64,
        target_alt_km: f64,
        range_km: f64,
    ) -> Result<PathSpectrum, AtmosphereError> {
        self.path_in(weather, observer_alt_km, target_alt_km, range_km, 0..self.nbins(), PathSteps::STANDARD)
    }

    /// The bins that overlap `band` (by a positive width), a range of the table's bins: what a spectrum needs for
    /// that band alone ([`AtmosphereTable::path_in`]).
    pub fn bins_of(&self, band: Band) -> Range<usize> {
        let e = &self.edges_um;
        let overlaps = |&b: &usize| e[b + 1] > band.lo_um() && e[b] < band.hi_um();
        // the edges increase, so the bins that overlap are one run
        let start = (0..self.nbins()).find(overlaps).unwrap_or(0);
        start..(start..self.nbins()).rev().find(overlaps).map_or(start, |b| b + 1)
    }

    /// [`AtmosphereTable::path`] over `bins` alone, its integrals taken in `steps`: a spectrum whose bins are
    /// those of `bins` (its edges and samples theirs), each the same bits as in the whole spectrum. A band's
    /// transmittance and path radiance need only the bins that overlap it ([`AtmosphereTable::bins_of`]); the
    /// others are most of a path's work.
    ///
    /// # Errors
    /// As [`AtmosphereTable::path`].
    ///
    /// # Panics
    /// If `bins` is not inside the table's bins, or a step count is below [`PathSteps::MIN`].
    pub fn path_in(
        &self,
        weather: &Weather,
        observer_alt_km: f64,
        target_alt_km: f64,
        range_km: f64,
        bins: Range<usize>,
        steps: PathSteps,
    ) -> Result<PathSpectrum, AtmosphereError> {
        assert!(bins.start <= bins.end && bins.end <= self.nbins(), "bins {bins:?} of {}", self.nbins());
        assert!(steps.aerosol >= PathSteps::MIN && steps.radiance >= PathSteps::MIN, "{steps:?}");
        let PathSteps { aerosol: aerosol_steps, radiance: segments } = steps;
        self.check_path(observer_alt_km, target_alt_km, range_km)?;
        let (vis, vis_bracket) = self.visibility_weights(weather)?;
        let m = model_index(weather.model);
        let (b0, nb) = (bins.start, bins.len());
        let (h1, h2) = (observer_alt_km, target_alt_km);
        let (lo, hi) = if h1 <= h2 { (h1, h2) } else { (h2, h1) };
        let ia = bracket(&self.alt_km, lo);
        let ib = bracket(&self.alt_km, hi);
        let finish = |transmittance: Vec<f64>, path_radiance_w_m2_sr_um: Vec<f64>, info: CornerInfo| PathSpectrum {
            edges_um: self.edges_um[bins.start..=bins.end].to_vec(),
            samples: self.samples[bins.clone()].to_vec(),
            transmittance,
            path_radiance_w_m2_sr_um,
            cell: GridCell {
                model: weather.model.name(),
                lower_alt_km: [self.alt_km[ia], self.alt_km[ia + 1]],
                upper_alt_km: [self.alt_km[ib], self.alt_km[ib + 1]],
                range_km: info.range.unwrap_or([0.0, 0.0]),
                visibility_km: vis_bracket,
                untraceable_corner: info.untraceable,
                lowtran_first_traced_km: info.traced,
            },
        };
        // the model's block, decoded (or its damage found) by the first path through the model, even one of no
        // length: the observer's tables start with one and are left clear where a later path fails
        let d = self.data(m)?;
        if range_km == 0.0 {
            return Ok(finish(vec![1.0; nb], vec![0.0; nb], CornerInfo::default()));
        }
        let chord = Chord::new(h1, h2, range_km);
        // cumulative aerosol optical depth along the line of sight, at aerosol_steps + 1 points
        let mut aer = vec![vec![0.0; nb]; aerosol_steps + 1];
        if !vis.is_empty() {
            // the visibilities are weighted at LOWTRAN's levels, then interpolated in altitude, as LOWTRAN does
            let profile = self.aerosol_profile(d, m, &vis);
            let mut prev = vec![0.0; nb];
            let mut cur = vec![0.0; nb];
            self.extinction_at(&profile, chord.altitude_km(0.0), b0, &mut prev);
            let ds = range_km / aerosol_steps as f64;
            for k in 1..=aerosol_steps {
                self.extinction_at(&profile, chord.altitude_km(k as f64 / aerosol_steps as f64), b0, &mut cur);
                let (done, rest) = aer.split_at_mut(k);
                for ((o, &a), (&p, &c)) in rest[0].iter_mut().zip(&done[k - 1]).zip(prev.iter().zip(&cur)) {
                    *o = a + 0.5 * ds * (p + c);
                }
                std::mem::swap(&mut prev, &mut cur);
            }
        }
        // the optical depth (molecular + aerosol) from the observer to fraction t of the path, per bin
        let depth_at = |t: f64, od: &[f64], out: &mut [f64]| {
            let x = t * aerosol_steps as f64;
            let k = (x.floor() as usize).min(aerosol_steps - 1);
            let f = x - k as f64;
            let (a0, a1) = (&aer[k], &aer[k + 1]);
            for ((o, &d), (&x0, &x1)) in out.iter_mut().zip(od).zip(a0.iter().zip(a1)) {
                *o = d + (x0 + f * (x1 - x0));
            }
        };
        let mut info = CornerInfo::default();
        let mut od = vec![0.0; nb];
        self.molecular_into(d, (lo, hi, range_km), b0, &mut od, &mut info);
        let mut depth_end = vec![0.0; nb];
        depth_at(1.0, &od, &mut depth_end);
        let mut transmittance = vec![0.0; nb];
        widest(
            #[inline(always)]
            || {
                for (o, &x) in transmittance.iter_mut().zip(&depth_end) {
                    // clamped by comparisons (a NaN passes through), which vectorize
                    *o = exp(-x).clamp(0.0, 1.0);
                }
            },
        );
        let cell_info = info;

        // path radiance: the emission of each segment, seen through the path before it, with the source (the
        // bins' Planck means) linear in the optical depth between the segment's ends: exact for an isothermal
        // path, the trapezoid rule where the segment is thin, the near end's emission where it is opaque
        let profile = &self.profiles[m];
        let mut radiance = vec![0.0; nb];
        // the optical depth reached so far (the largest along the path: τ from the observer never rises), τ there
        let mut depth_prev = vec![0.0; nb];
        let mut tau_prev = vec![1.0; nb];
        let mut depth_cur = vec![0.0; nb];
        let mut planck_prev = vec![0.0; nb];
        let mut planck_cur = vec![0.0; nb];
        self.bin_mean_planck_into(b0, profile.temperature_at(chord.altitude_km(0.0)), &mut planck_prev);
        let mut scratch = CornerInfo::default();
        for k in 1..=segments {
            let t = (k as f64 / segments as f64).powi(2);
            if k == segments {
                depth_cur.copy_from_slice(&depth_end);
            } else {
                let h = chord.altitude_km(t).clamp(0.0, self.max_altitude_km());
                let s = (t * range_km).max((h - h1).abs());
                let (l, u) = if h1 <= h { (h1, h) } else { (h, h1) };
                self.molecular_into(d, (l, u, s), b0, &mut od, &mut scratch);
                depth_at(t, &od, &mut depth_cur);
            }
            self.bin_mean_planck_into(b0, profile.temperature_at(chord.altitude_km(t)), &mut planck_cur);
            widest(
                #[inline(always)]
                || {
                    for ((((r, xp), tp), &xc), (&bp, &bc)) in radiance
                        .iter_mut()
                        .zip(depth_prev.iter_mut())
                        .zip(tau_prev.iter_mut())
                        .zip(&depth_cur)
                        .zip(planck_prev.iter().zip(&planck_cur))
                    {
                        // selects, not branches, so that the loop vectorizes; a NaN depth adds nothing
                        let x = if xc > *xp { xc } else { *xp };
                        let delta = x - *xp;
                        let tau = exp(-x);
                        let drop = *tp - tau;
                        // the weight of the far end's source: ∫ (u/Δ) τ_prev e^−u du over the segment's depth Δ,
                        // = drop/Δ − τ, by its series where Δ is small (the difference would cancel)
                        let series = *tp * delta * (0.5 - delta * (1.0 / 3.0 - delta * (0.125 - delta / 30.0)));
                        let far = if delta < 1e-2 { series } else { drop / delta - tau };
                        let add = bp * drop + (bc - bp) * far;
                        *r += if delta > 0.0 { add } else { 0.0 };
                        *xp = x;
                        *tp = tau;
                    }
                },
            );
            std::mem::swap(&mut planck_prev, &mut planck_cur);
        }
        Ok(finish(transmittance, radiance, cell_info))
    }

    /// The clear sky's spectrum toward elevation `asin(sin_e)` from an observer at `observer_alt_km`, for a ray
    /// that misses the ground: its transmittance and thermal radiance per bin all the way up. The straight ray
    /// (down to its tangent point and up again, below the horizontal) is cut where it leaves the table's top
    /// (20 km) and into pieces of at most the table's longest range, each an interpolated path of the table,
    /// chained bin by bin (`L += τ_before·L_piece`, `τ ×= τ_piece`); above the top, LOWTRAN's layers up to 100 km
    /// seen through the observer's column. Its paths' integrals are taken in [`PathSteps::STANDARD`] (other
    /// steps: [`AtmosphereTable::sky_in`]).
    ///
    /// # Errors
    /// [`AtmosphereError::OutsideGrid`] for an observer outside the table's altitudes, or a ray below the
    /// horizon's dip (it meets the ground).
    pub fn sky(&self, weather: &Weather, observer_alt_km: f64, sin_e: f64) -> Result<PathSpectrum, AtmosphereError> {
        self.sky_in(weather, observer_alt_km, sin_e, 0..self.nbins(), PathSteps::STANDARD)
    }

    /// [`AtmosphereTable::sky`] over `bins` alone, its paths' integrals taken in `steps` (see
    /// [`AtmosphereTable::path_in`]).
    ///
    /// # Errors
    /// As [`AtmosphereTable::sky`].
    pub fn sky_in(
        &self,
        weather: &Weather,
        observer_alt_km: f64,
        sin_e: f64,
        bins: Range<usize>,
        steps: PathSteps,
    ) -> Result<PathSpectrum, AtmosphereError> {
        match self.ray_in(weather, observer_alt_km, sin_e, bins, steps)? {
            (p, false) => Ok(p),
            (_, true) => Err(AtmosphereError::OutsideGrid {
                name: "sin_elevation",
                value: sin_e,
                range: format!("[{}, 1] (below it the ray meets the ground)", horizon_sin_e(observer_alt_km)),
            }),
        }
    }

    /// The spectrum of the straight ray from an observer at `observer_alt_km` toward elevation `asin(sin_e)`, as
    /// [`AtmosphereTable::sky`] chains it, up through the whole atmosphere, or down to the ground where it meets it
    /// (then `true`, and the path ends there); its paths' integrals in [`PathSteps::STANDARD`] (other steps:
    /// [`AtmosphereTable::ray_in`]).
    ///
    /// # Errors
    /// [`AtmosphereError::OutsideGrid`] for an observer outside the table's altitudes; [`AtmosphereError::Table`]
    /// as for [`AtmosphereTable::path`].
    pub fn ray(
        &self,
        weather: &Weather,
        observer_alt_km: f64,
        sin_e: f64,
    ) -> Result<(PathSpectrum, bool), AtmosphereError> {
        self.ray_in(weather, observer_alt_km, sin_e, 0..self.nbins(), PathSteps::STANDARD)
    }

    /// [`AtmosphereTable::ray`] over `bins` alone, its paths' integrals taken in `steps` (see
    /// [`AtmosphereTable::path_in`]).
    ///
    /// # Errors
    /// As [`AtmosphereTable::ray`].
    pub fn ray_in(
        &self,
        weather: &Weather,
        observer_alt_km: f64,
        sin_e: f64,
        bins: Range<usize>,
        steps: PathSteps,
    ) -> Result<(PathSpectrum, bool), AtmosphereError> {
        let s = sin_e.clamp(-1.0, 1.0);
        let top = self.max_altitude_km();
        let far = self.max_range_km();
        let h = observer_alt_km;
        if !(h >= 0.0 && h <= top) {
            return Err(AtmosphereError::OutsideGrid {
                name: "observer_alt_km",
                value: h,
                range: format!("[0, {top}] km"),
            });
        }
        let r0 = EARTH_RADIUS_KM + h;
        let alt = |t: f64| ((r0 * r0 + t * t + 2.0 * r0 * t * s).max(0.0).sqrt() - EARTH_RADIUS_KM).clamp(0.0, top);
        let rt = EARTH_RADIUS_KM + top;
        let t_end = -r0 * s + (r0 * r0 * s * s + rt * rt - r0 * r0).max(0.0).sqrt();
        let mut legs = vec![(0.0, t_end)];
        if s < 0.0 {
            let t_tan = -r0 * s;
            let tangent = r0 * (1.0 - s * s).sqrt() - EARTH_RADIUS_KM;
            legs = if tangent < -1e-3 {
                let e = EARTH_RADIUS_KM;
                vec![(0.0, t_tan - (r0 * r0 * s * s - (r0 * r0 - e * e)).max(0.0).sqrt())]
            } else {
                vec![(0.0, t_tan), (t_tan, t_end)]
            };
        }
        let ground = legs.len() == 1 && s < 0.0;
        let b0 = bins.start;
        let mut out = self.path_in(weather, h, h, 0.0, bins.clone(), steps)?;
        for (a, b) in legs {
            let pieces = ((b - a) / far).ceil().max(1.0) as usize;
            let len = (b - a) / pieces as f64;
            for k in 0..pieces {
                if len <= 0.0 {
                    break;
                }
                let (ta, tb) = (a + k as f64 * len, a + (k + 1) as f64 * len);
                let (za, zb) = (alt(ta), alt(tb));
                let piece = self.path_in(weather, za, zb, len.max((zb - za).abs()), bins.clone(), steps)?;
                for ((t, l), (&pt, &pl)) in out
                    .transmittance
                    .iter_mut()
                    .zip(out.path_radiance_w_m2_sr_um.iter_mut())
                    .zip(piece.transmittance.iter().zip(&piece.path_radiance_w_m2_sr_um))
                {
                    *l += *t * pl;
                    *t *= pt;
                }
            }
        }
        if ground {
            return Ok((out, true));
        }
        let PathSpectrum { transmittance, path_radiance_w_m2_sr_um, .. } = &mut out;
        self.add_above_top(
            self.data(model_index(weather.model))?,
            weather.model,
            (h, (t_end + r0 * s) / rt),
            b0,
            transmittance,
            path_radiance_w_m2_sr_um,
        );
        Ok((out, false))
    }

    /// Adds to `tau` and `radiance` (per bin, W m⁻² sr⁻¹ µm⁻¹: what a ray has gathered up to the table's top)
    /// the air above the top, for a ray from an observer at `observer_alt_km` whose elevation at the top has sine
    /// `sin_e_top`. The layers between LOWTRAN's levels up to 100 km are seen through the observer's own vertical
    /// column (LOWTRAN's path from the observer's altitude through each level, interpolated between the grid's
    /// altitudes), so that lines already saturated below neither absorb nor emit again; each layer's optical depth
    /// is stretched by the ray's straight length through its spherical shell and emits at the profile's
    /// temperature at its mid-height. `tau` and `radiance` hold the bins from `b0` on.
    fn add_above_top(
        &self,
        d: &Payload,
        model: ModelAtmosphere,
        (observer_alt_km, sin_e_top): (f64, f64),
        b0: usize,
        tau: &mut [f64],
        radiance: &mut [f64],
    ) {
        let m = model_index(model);
        let nb = self.nbins();
        let nl = self.above_km.len();
        let i = bracket(&self.alt_km, observer_alt_km);
        let f = ((altitude_coord(observer_alt_km) - self.alt_coord[i]) / (self.alt_coord[i + 1] - self.alt_coord[i]))
            .clamp(0.0, 1.0);
        let od = |level: usize, b: usize| -> f64 {
            let at = |row: usize| f64::from(d.above_od[(row * nl + level) * nb + b]);
            at(i) + f * (at(i + 1) - at(i))
        };
        let profile = &self.profiles[m];
        let r0 = EARTH_RADIUS_KM + self.above_km[0];
        let sin_e = sin_e_top.clamp(1e-6, 1.0);
        // the ray's distance from the top to radius r
        let reach = |r: f64| -r0 * sin_e + (r0 * r0 * sin_e * sin_e + r * r - r0 * r0).max(0.0).sqrt();
        let mut planck = vec![0.0; tau.len()];
        let mut depth = vec![0.0; tau.len()];
        for l in 0..nl - 1 {
            let (z0, z1) = (self.above_km[l], self.above_km[l + 1]);
            let stretch = (reach(EARTH_RADIUS_KM + z1) - reach(EARTH_RADIUS_KM + z0)) / (z1 - z0);
            let temp = profile.temperature_at(0.5 * (z0 + z1));
            self.bin_mean_planck_into(b0, temp, &mut planck);
            for (k, d) in depth.iter_mut().enumerate() {
                *d = (od(l + 1, b0 + k) - od(l, b0 + k)).max(0.0) * stretch;
            }
            widest(
                #[inline(always)]
                || {
                    for ((t, r), (&d, &p)) in tau.iter_mut().zip(radiance.iter_mut()).zip(depth.iter().zip(&planck)) {
                        let after = *t * exp(-d);
                        *r += (*t - after) * p;
                        *t = after;
                    }
                },
            );
        }
    }

    /// The blackbody's mean spectral radiance over bin `b`, W m⁻² sr⁻¹ µm⁻¹: inside [`PLANCK_TABLE_K`] from a
    /// table at whole kelvins, its logarithm interpolated linearly in 1/T (exact in Wien's limit; the test
    /// `planck_table_is_close_to_exact` bounds the error), the exact integral outside.
    #[cfg(test)]
    fn bin_mean_planck(&self, b: usize, temp_k: f64) -> f64 {
        let mut out = [0.0];
        self.bin_mean_planck_into(b, temp_k, &mut out);
        out[0]
    }

    /// [`Self::bin_mean_planck`] for the bins from `b0` on (as many as `out` holds), into `out`.
    fn bin_mean_planck_into(&self, b0: usize, temp_k: f64, out: &mut [f64]) {
        let (t0, t1) = PLANCK_TABLE_K;
        let edges = |b: usize| (self.edges_um[b], self.edges_um[b + 1]);
        if !(temp_k >= t0 && temp_k < t1) {
            for (k, o) in out.iter_mut().enumerate() {
                let (lo, hi) = edges(b0 + k);
                *o = exact_bin_mean_planck(lo, hi, temp_k);
            }
            return;
        }
        let i = (temp_k - t0) as usize;
        let (ta, tc) = (t0 + i as f64, t0 + i as f64 + 1.0);
        let u = (1.0 / temp_k - 1.0 / ta) / (1.0 / tc - 1.0 / ta);
        // each bin's logarithms at the bracketing kelvins, then their interpolation's exponentials side by side
        for (k, o) in out.iter_mut().enumerate() {
            let b = b0 + k;
            let row = self.planck[b].get_or_init(|| {
                let (lo, hi) = edges(b);
                (0..=(t1 - t0) as usize)
                    .map(|k| {
                        let v = exact_bin_mean_planck(lo, hi, t0 + k as f64);
                        (v, if v > 0.0 { v.ln() } else { f64::NAN })
                    })
                    .collect()
            });
            let ((a, la), (c, lc)) = (row[i], row[i + 1]);
            // a bin with no emission at either kelvin: NaN marks it for the exact integral
            *o = if a > 0.0 && c > 0.0 { la + u * (lc - la) } else { f64::NAN };
        }
        widest(
            #[inline(always)]
            || {
                for o in out.iter_mut() {
                    *o = exp(*o);
                }
            },
        );
        for (k, o) in out.iter_mut().enumerate() {
            if o.is_nan() {
                let (lo, hi) = edges(b0 + k);
                *o = exact_bin_mean_planck(lo, hi, temp_k);
            }
        }
    }
}

/// Inflates `packed`, model `m`'s block of `table`, and checks its length, CRC-32 and values.
fn decode(packed: &[u8], table: &AtmosphereTable, m: usize) -> Result<Payload, AtmosphereError> {
    let block_error =
        |msg: String| AtmosphereError::Table(format!("{}'s block: {msg}", ModelAtmosphere::ALL[m].name()));
    let Packed { raw_len, crc, .. } = table.packed[m];
    let mut payload = Vec::with_capacity(usize::try_from(raw_len.min(1 << 30)).unwrap_or(0));
    flate2::read::ZlibDecoder::new(packed)
        .take(raw_len.saturating_add(1))
        .read_to_end(&mut payload)
        .map_err(|e| block_error(format!("payload: {e}")))?;
    if payload.len() as u64 != raw_len {
        return Err(block_error(format!("payload is {} bytes, the header says {raw_len}", payload.len())));
    }
    if crc32fast::hash(&payload) != crc {
        return Err(block_error("payload checksum (CRC-32) does not match".into()));
    }
    let (nodes, nod, next, _) = table.block_parts();
    if payload.len() != table.block_len() {
        return Err(block_error(format!("{} bytes, the grid needs {}", payload.len(), table.block_len())));
    }
    let (hi, rest) = payload.split_at(nod);
    let (lo, rest) = rest.split_at(nod);
    let od = hi.iter().zip(lo).map(|(&h, &l)| u16::from(h) << 8 | u16::from(l)).collect();
    let (flags, rest) = rest.split_at(nodes);
    let (traced, rest) = rest.split_at(4 * nodes);
    let f32s =
        |b: &[u8]| -> Vec<f32> { b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect() };
    let (ext, above) = rest.split_at(4 * next);
    let ext = f32s(ext);
    if ext.iter().any(|e| !(e.is_finite() && *e >= 0.0)) {
        return Err(block_error("aerosol extinction must be finite and not negative".into()));
    }
    let above_od = f32s(above);
    if above_od.iter().any(|e| !(e.is_finite() && *e >= 0.0)) {
        return Err(block_error("optical depths above the top must be finite and not negative".into()));
    }
    let od: Vec<u16> = od;
    // each horizontal pair's curve of growth between the first two ranges, per bin, as a power law's exponent:
    // between ½ (saturated lines) and 1 (weak ones)
    let nb = table.nbins();
    let short_exponent = match table.ranges_km[..] {
        [x1, x2, ..] => (0..table.alt_km.len())
            .flat_map(|p| {
                let base = table.pair_index(p, p) * table.nodes_per_pair();
                let value = |node: usize, b: usize| f64::from(od[node * nb + b]) * table.od_scale;
                (0..nb)
                    .map(|b| {
                        let (d1, d2) = (value(base + 1, b), value(base + 2, b));
                        if d1 > 0.0 && d2 > 0.0 { ((d2 / d1).ln() / (x2 / x1).ln()).clamp(0.5, 1.0) } else { 1.0 }
                    })
                    .collect::<Vec<_>>()
            })
            .collect(),
        _ => Vec::new(),
    };
    Ok(Payload { od, flags: flags.to_vec(), traced_km: f32s(traced), ext, above_od, short_exponent })
}

fn exact_bin_mean_planck(lo_um: f64, hi_um: f64, temp_k: f64) -> f64 {
    Band::try_new(lo_um, hi_um).map_or(0.0, |band| band_radiance(band, temp_k, 1.0) / (hi_um - lo_um))
}

/// The model's place in the table (the declaration order, as in [`ModelAtmosphere::ALL`]).
fn model_index(m: ModelAtmosphere) -> usize {
    m as usize
}

/// Aerosol settings with their weights, and the visibilities bracketing the weather's.
type VisibilityWeights = (Vec<(usize, f64)>, Vec<f64>);

#[derive(Debug, Clone, Default)]
struct CornerInfo {
    untraceable: bool,
    traced: Vec<f64>,
    range: Option<[f64; 2]>,
}

/// The straight line between two points at altitudes `h1`, `h2` (km) `range_km` apart, above a spherical Earth.
struct Chord {
    a: f64,
    b: f64,
    ab_cos: f64,
}

impl Chord {
    fn new(h1: f64, h2: f64, range_km: f64) -> Self {
        let (a, b) = (EARTH_RADIUS_KM + h1, EARTH_RADIUS_KM + h2);
        // a·b·cos γ from the law of cosines
        Chord { a, b, ab_cos: 0.5 * (a * a + b * b - range_km * range_km) }
    }

    /// Altitude (km) at fraction `t` of the way from the first point.
    fn altitude_km(&self, t: f64) -> f64 {
        let u = 1.0 - t;
        let r2 = u * u * self.a * self.a + t * t * self.b * self.b + 2.0 * t * u * self.ab_cos;
        r2.max(0.0).sqrt() - EARTH_RADIUS_KM
    }
}

/// Sine of the lowest elevation whose straight ray from altitude `observer_alt_km` misses the ground (minus the
/// sine of the horizon's dip on the spherical Earth; 0 on the ground).
pub fn horizon_sin_e(observer_alt_km: f64) -> f64 {
    let r0 = EARTH_RADIUS_KM + observer_alt_km.max(0.0);
    -(1.0 - (EARTH_RADIUS_KM / r0).powi(2)).max(0.0).sqrt()
}

/// The lowest altitude (km) of the straight line between the two points.
pub fn lowest_point_km(h1: f64, h2: f64, range_km: f64) -> f64 {
    let c = Chord::new(h1, h2, range_km);
    // |P(t)|² is a quadratic in t; its minimum over [0, 1]
    let (a2, b2, ab) = (c.a * c.a, c.b * c.b, c.ab_cos);
    let denom = a2 + b2 - 2.0 * ab;
    let t = if denom > 0.0 { ((a2 - ab) / denom).clamp(0.0, 1.0) } else { 0.0 };
    c.altitude_km(t).min(h1).min(h2)
}

impl PathSpectrum {
    /// Bin `b`'s part of `band` (`None` where they do not overlap by a positive width).
    pub(crate) fn bin_part(&self, b: usize, band: Band) -> Option<Band> {
        let (l, h) = (self.edges_um[b].max(band.lo_um()), self.edges_um[b + 1].min(band.hi_um()));
        if h <= l { None } else { Band::try_new(l, h).ok() }
    }

    fn overlaps(&self, band: Band) -> impl Iterator<Item = (usize, f64, f64)> + '_ {
        // (bin, fraction of the bin's wavenumber extent inside the band, µm inside)
        (0..self.transmittance.len()).filter_map(move |b| {
            let (lo, hi) = (self.edges_um[b], self.edges_um[b + 1]);
            let (l, h) = (lo.max(band.lo_um()), hi.min(band.hi_um()));
            if h <= l {
                return None;
            }
            let frac = (1.0 / l - 1.0 / h) / (1.0 / lo - 1.0 / hi);
            Some((b, frac, h - l))
        })
    }

    /// Whether the table's bins cover the band.
    pub fn covers(&self, band: Band) -> bool {
        band.lo_um() >= self.edges_um[0] && band.hi_um() <= self.edges_um[self.edges_um.len() - 1]
    }

    /// Mean of per-bin `values` over the band, uniform in wavenumber (weighted by LOWTRAN's samples); `empty`
    /// where the band holds no sample.
    fn sample_mean(&self, values: &[f64], band: Band, empty: f64) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for (b, frac, _) in self.overlaps(band) {
            let w = f64::from(self.samples[b]) * frac;
            num += w * values[b];
            den += w;
        }
        if den > 0.0 { num / den } else { empty }
    }

    /// Band-average transmittance, uniform in wavenumber (the mean of LOWTRAN's samples in the band).
    pub fn band_average(&self, band: Band) -> f64 {
        self.sample_mean(&self.transmittance, band, 1.0)
    }

    /// Transmittance weighted by a blackbody's spectrum at `temp_k` over the band: `∫τ B_λ dλ / ∫B_λ dλ`, the τ
    /// that multiplies a gray target's band radiance exactly (to the bins' resolution).
    pub fn spectrum_weighted(&self, band: Band, temp_k: f64) -> f64 {
        self.spectrum_weighted_in(Measure::Energy, band, temp_k)
    }

    /// [`PathSpectrum::spectrum_weighted`] with the blackbody's spectrum in `measure` (photon radiance for a
    /// photon detector: the τ that multiplies a gray target's photon band radiance).
    pub fn spectrum_weighted_in(&self, measure: Measure, band: Band, temp_k: f64) -> f64 {
        self.spectrum_weighted_with(measure, band, temp_k, PlanckMethod::Series)
    }

    /// [`PathSpectrum::spectrum_weighted_in`] with each bin's weight (the blackbody's band radiance over the bin's
    /// part of the band) integrated by `method` (`[quality] planck`): a scene's targets take their τ this way at
    /// every computation of their radiometry, and the exact series over every bin was a tenth of a `draft`
    /// frame of swarm. [`PlanckMethod::Series`] gives [`PathSpectrum::spectrum_weighted_in`]'s bits.
    pub fn spectrum_weighted_with(&self, measure: Measure, band: Band, temp_k: f64, method: PlanckMethod) -> f64 {
        self.weighted_by_bins(band, self.blackbody_in_bins(measure, band, temp_k, method))
    }

    /// The transmittance weighted by `(bin, weight)` pairs over the band, in their order; the band's average
    /// without any weight.
    fn weighted_by_bins(&self, band: Band, weights: impl Iterator<Item = (usize, f64)>) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for (b, w) in weights {
            num += w * self.transmittance[b];
            den += w;
        }
        if den > 0.0 { num / den } else { self.band_average(band) }
    }

    /// `(bin, a blackbody's band radiance at temp_k in measure over the bin's part of the band)` for each bin
    /// overlapping the band.
    fn blackbody_in_bins(
        &self,
        measure: Measure,
        band: Band,
        temp_k: f64,
        method: PlanckMethod,
    ) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.overlaps(band).map(move |(b, _, _)| {
            (b, self.bin_part(b, band).map_or(0.0, |part| method.band_radiance(measure, part, temp_k, 1.0)))
        })
    }

    /// A blackbody's band radiance at `temp_k` in `measure` over each bin's part of the band (0 outside it): the
    /// weights of [`PathSpectrum::spectrum_weighted_in`], for [`PathSpectrum::weighted`].
    pub fn blackbody_weights(&self, measure: Measure, band: Band, temp_k: f64) -> Vec<f64> {
        let mut w = vec![0.0; self.transmittance.len()];
        for (b, v) in self.blackbody_in_bins(measure, band, temp_k, PlanckMethod::Series) {
            w[b] = v;
        }
        w
    }

    /// The transmittance weighted by per-bin `weights` (from [`PathSpectrum::blackbody_weights`]); 1 without any
    /// weight.
    pub fn weighted(&self, weights: &[f64]) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for (&w, &t) in weights.iter().zip(&self.transmittance) {
            num += w * t;
            den += w;
        }
        if den > 0.0 { num / den } else { 1.0 }
    }

    /// Path radiance integrated over the band, W m⁻² sr⁻¹.
    pub fn band_path_radiance_w_m2_sr(&self, band: Band) -> f64 {
        self.overlaps(band).map(|(b, _, width)| self.path_radiance_w_m2_sr_um[b] * width).sum()
    }

    /// Path radiance integrated over the band in `measure`. For photons each bin's energy radiance is converted
    /// with the photon-to-energy ratio of a [`PHOTON_REFERENCE_K`] blackbody over that part of the bin (exact for a
    /// path at that temperature; between 200 and 300 K the ratio changes by under 0.1 % in the bins beyond 3 µm,
    /// and by up to 0.6 % in the 0.25 µm bins below, where the air's own radiance is tiny; tested).
    pub fn band_path_radiance_in(&self, measure: Measure, band: Band) -> f64 {
        self.band_path_radiance_by(band, &self.measure_ratios(measure, band))
    }

    /// Each bin's ratio from energy radiance to radiance in `measure` over its part inside `band`
    /// ([`PathSpectrum::band_path_radiance_in`]'s: 1 for energy, a [`PHOTON_REFERENCE_K`] blackbody's for photons;
    /// 0 outside the band). The same for every path over these bins: a caller with many paths makes it once.
    pub fn measure_ratios(&self, measure: Measure, band: Band) -> Vec<f64> {
        let mut ratios = vec![0.0; self.transmittance.len()];
        for (b, _, _) in self.overlaps(band) {
            ratios[b] = match measure {
                Measure::Energy => 1.0,
                Measure::Photon => self.bin_part(b, band).map_or(0.0, |part| {
                    let e = band_radiance(part, PHOTON_REFERENCE_K, 1.0);
                    if e > 0.0 { band_radiance_in(Measure::Photon, part, PHOTON_REFERENCE_K, 1.0) / e } else { 0.0 }
                }),
            };
        }
        ratios
    }

    /// [`PathSpectrum::band_path_radiance_in`] with its bins' `ratios` ([`PathSpectrum::measure_ratios`] of a
    /// path over the same bins, for the same band): the same value, to the bit.
    pub fn band_path_radiance_by(&self, band: Band, ratios: &[f64]) -> f64 {
        self.overlaps(band).map(|(b, _, width)| self.path_radiance_w_m2_sr_um[b] * width * ratios[b]).sum()
    }

    /// The spectrum of the same path stretched to `new_length / old_length` of its length, bin by bin as
    /// Beer–Lambert scales it (`τ' = τ^k`), its path radiance scaled with the emissivity `(1 − τ')/(1 − τ)`: what
    /// [`crate::scenario::Quality::atmosphere_tolerance`] uses between two interpolations of a moving path.
    pub fn stretched(&self, k: f64, out: &mut PathSpectrum) {
        out.edges_um.clone_from(&self.edges_um);
        out.samples.clone_from(&self.samples);
        out.cell.clone_from(&self.cell);
        out.transmittance.clear();
        out.path_radiance_w_m2_sr_um.clear();
        for (&t, &l) in self.transmittance.iter().zip(&self.path_radiance_w_m2_sr_um) {
            let t2 = if t > 0.0 { t.powf(k) } else { 0.0 };
            let emissivity = 1.0 - t;
            out.transmittance.push(t2);
            out.path_radiance_w_m2_sr_um.push(if emissivity > 1e-12 { l * (1.0 - t2) / emissivity } else { l });
        }
    }

    /// Path radiance per µm averaged uniformly in wavenumber over the band (the mean of LOWTRAN's samples),
    /// W m⁻² sr⁻¹ µm⁻¹.
    pub fn band_mean_path_radiance_w_m2_sr_um(&self, band: Band) -> f64 {
        self.sample_mean(&self.path_radiance_w_m2_sr_um, band, 0.0)
    }
}

/// The generator's direct LOWTRAN runs (`lowtran7_offgrid.json`), for the accuracy tests.
#[cfg(test)]
pub(crate) fn offgrid_runs() -> serde_json::Value {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/atmosphere/lowtran7_offgrid.json"))
        .expect("the off-grid runs are committed");
    serde_json::from_str(&text).expect("the off-grid runs are JSON")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> &'static AtmosphereTable {
        AtmosphereTable::shipped().expect("the shipped table loads")
    }

    const MLS_RURAL_23: Weather =
        Weather { model: ModelAtmosphere::MidlatitudeSummer, aerosol: Aerosol::Rural, visibility_km: 23.0 };

    #[test]
    fn shipped_table_covers_what_it_says() {
        let t = table();
        assert_eq!(t.max_altitude_km(), 20.0);
        assert_eq!(t.max_range_km(), 100.0);
        assert_eq!(t.nbins(), 108);
        assert_eq!(t.visibilities_km(Aerosol::Rural), vec![2.0, 5.0, 10.0, 23.0, 50.0]);
        assert!((t.profile(ModelAtmosphere::MidlatitudeSummer).temperature_at(0.0) - 294.2).abs() < 0.05);
    }

    #[test]
    fn planck_table_is_close_to_exact() {
        let t = table();
        let mut worst = 0.0f64;
        for temp in [150.3, 183.7, 215.2, 250.5, 288.9, 299.5, 349.9] {
            for b in 0..t.nbins() {
                let exact = exact_bin_mean_planck(t.edges_um[b], t.edges_um[b + 1], temp);
                if exact > 1e-12 {
                    worst = worst.max((t.bin_mean_planck(b, temp) / exact - 1.0).abs());
                }
            }
        }
        eprintln!("Planck table: largest relative error {worst:.2e}");
        assert!(worst < 1e-5, "{worst}");
    }

    #[test]
    fn photon_ratio_of_a_bin_hardly_depends_on_temperature() {
        // the claim of band_path_radiance_in: converting a bin with a 250 K ratio is within 0.1 % at 200–300 K
        // beyond 3 µm (0.6 % in the wide bins below, where the air's own radiance is tiny)
        let t = table();
        let (mut worst, mut worst_short) = (0.0f64, 0.0f64);
        for b in 0..t.nbins() {
            let part = Band::try_new(t.edges_um[b], t.edges_um[b + 1]).unwrap();
            let ratio = |k: f64| band_radiance_in(Measure::Photon, part, k, 1.0) / band_radiance(part, k, 1.0);
            for k in [200.0, 300.0] {
                let e = (ratio(k) / ratio(PHOTON_REFERENCE_K) - 1.0).abs();
                if t.edges_um[b] >= 3.0 { worst = worst.max(e) } else { worst_short = worst_short.max(e) }
            }
        }
        eprintln!(
            "photon/energy ratio of a bin, 200–300 K against 250 K: within {:.3} % beyond 3 µm, {:.2} % below",
            100.0 * worst,
            100.0 * worst_short
        );
        assert!(worst < 1e-3 && worst_short < 7e-3, "{worst} {worst_short}");
    }

    /// The path radiance's segments: errors against [`PathSteps::REFERENCE`] fall as the square of the segments
    /// (the quadratic spacing and the source linear in depth; 32 equal segments with the temperature at each
    /// middle erred by 41 DN rms in supersonic_climb's sky, a rule of first order), and the presets' steps stay
    /// within their bounds. The transmittance does not depend on the radiance's segments.
    #[test]
    fn path_integrals_converge_with_their_steps() {
        let t = table();
        let w = MLS_RURAL_23;
        let lines: [(&str, f64, f64, f64); 4] = [
            ("0 → 0 km, 10 km", 0.0, 0.0, 10.0),
            ("0 → 8 km, 30 km", 0.0, 8.0, 30.0),
            ("1 → 15 km, 60 km", 1.0, 15.0, 60.0),
            ("8 → 8 km, 4 km", 8.0, 8.0, 4.0),
        ];
        let rays: [(&str, f64, f64); 3] =
            [("sky from 0 km at 20°", 0.0, 20.0), ("from 3 km at 60°", 3.0, 60.0), ("from 10 km at 3°", 10.0, 3.0)];
        let spectrum = |i: usize, steps: PathSteps| -> PathSpectrum {
            let all = 0..t.nbins();
            if i < lines.len() {
                let (_, h1, h2, r) = lines[i];
                t.path_in(&w, h1, h2, r, all, steps).unwrap()
            } else {
                let (_, h, e) = rays[i - lines.len()];
                t.sky_in(&w, h, e.to_radians().sin(), all, steps).unwrap()
            }
        };
        let name = |i: usize| if i < lines.len() { lines[i].0 } else { rays[i - lines.len()].0 };
        let bands = [Band::MWIR_3_5, Band::LWIR_8_12];
        let radiance_error = |p: &PathSpectrum, exact: &PathSpectrum| {
            bands
                .iter()
                .map(|&b| {
                    (p.band_mean_path_radiance_w_m2_sr_um(b) / exact.band_mean_path_radiance_w_m2_sr_um(b) - 1.0).abs()
                })
                .fold(0.0, f64::max)
        };
        let tau_error = |p: &PathSpectrum, exact: &PathSpectrum| {
            bands.iter().map(|&b| (p.band_average(b) - exact.band_average(b)).abs()).fold(0.0, f64::max)
        };
        let segments = [8, 16, 32, 64, 128];
        let aerosol = [8, 32, 128];
        // [case][segments], [case][aerosol]
        let mut by_segments = Vec::new();
        let (mut by_aerosol, mut tau_moved) = (Vec::new(), 0.0f64);
        for i in 0..lines.len() + rays.len() {
            let exact = spectrum(i, PathSteps::REFERENCE);
            let e: Vec<f64> = segments
                .iter()
                .map(|&radiance| {
                    let p = spectrum(i, PathSteps { aerosol: PathSteps::REFERENCE.aerosol, radiance });
                    tau_moved = tau_moved.max(
                        p.transmittance
                            .iter()
                            .zip(&exact.transmittance)
                            .map(|(a, b)| (a - b).abs())
                            .fold(0.0, f64::max),
                    );
                    radiance_error(&p, &exact)
                })
                .collect();
            let a: Vec<f64> = aerosol
                .iter()
                .map(|&aerosol| {
                    tau_error(&spectrum(i, PathSteps { aerosol, radiance: PathSteps::REFERENCE.radiance }), &exact)
                })
                .collect();
            let sci = |v: &[f64]| v.iter().map(|x| format!("{x:.1e}")).collect::<Vec<_>>().join(", ");
            eprintln!(
                "{}: path radiance, relative error with {segments:?} segments: {}; band τ with {aerosol:?} aerosol \
                 steps: {}",
                name(i),
                sci(&e),
                sci(&a)
            );
            by_segments.push(e);
            by_aerosol.push(a);
        }
        let worst = |rows: &[Vec<f64>], k: usize| rows.iter().map(|r| r[k]).fold(0.0, f64::max);
        assert_eq!(tau_moved, 0.0, "the transmittance depends on the radiance's segments");
        // the presets: 64 segments and 128 trapezoids (standard), 16 and 32 (draft)
        assert!(worst(&by_segments, 3) < 2e-3 && worst(&by_segments, 1) < 6e-3, "{by_segments:?}");
        assert!(worst(&by_aerosol, 2) < 1e-4 && worst(&by_aerosol, 1) < 1e-3, "{by_aerosol:?}");
        // second order on the slant lines of sight: 4× the segments, at least 8× less error (16× in the limit)
        for e in &by_segments[1..3] {
            assert!(e[3] < e[1] / 8.0, "{e:?}");
        }
    }

    #[test]
    fn stretching_between_interpolations_is_close() {
        // what [quality] atmosphere_tolerance costs: the path re-interpolated at the new geometry against the old
        // one stretched to the new range (the range moved by the tolerance), or kept (an end's altitude moved by
        // the tolerance times ALTITUDE_TOLERANCE_SCALE_KM)
        let t = table();
        let bands = [Band::try_new(3.0, 5.0).unwrap(), Band::try_new(8.0, 12.0).unwrap()];
        for tol in [0.01, 0.05] {
            let dh = tol * ALTITUDE_TOLERANCE_SCALE_KM;
            let (mut worst_range, mut worst_alt, mut worst_path) = (0.0f64, 0.0f64, 0.0f64);
            for (h1, h2, r) in [(1.0, 9.0, 17.0), (0.5, 0.5, 5.0), (1.5, 1.52, 0.3), (8.0, 8.0, 30.0), (0.1, 0.3, 20.0)]
            {
                let base = t.path(&MLS_RURAL_23, h1, h2, r).unwrap();
                let cases = [
                    (h1, h2, r * (1.0 + tol), false),
                    (h1, h2, r * (1.0 - tol), false),
                    (h1, h2 + dh, r, true),
                    (h1 + dh, h2, r, true),
                    ((h1 - dh).max(0.0), h2, r, true),
                ];
                for (a, b, rr, altitude) in cases {
                    let Ok(exact) = t.path(&MLS_RURAL_23, a, b, rr) else { continue };
                    let mut got = base.clone();
                    base.stretched(rr / r, &mut got);
                    for band in bands {
                        let d = (got.spectrum_weighted(band, 300.0) - exact.spectrum_weighted(band, 300.0)).abs();
                        if altitude {
                            worst_alt = worst_alt.max(d)
                        } else {
                            worst_range = worst_range.max(d)
                        }
                        let lp = exact.band_path_radiance_w_m2_sr(band);
                        if lp > 1e-3 {
                            worst_path = worst_path.max((got.band_path_radiance_w_m2_sr(band) / lp - 1.0).abs());
                        }
                    }
                }
            }
            eprintln!(
                "atmosphere_tolerance {tol}: |Δτ| ≤ {worst_range:.5} (range moved, stretched), ≤ {worst_alt:.5} \
                 (an altitude moved), path radiance within {:.2} %",
                100.0 * worst_path
            );
            assert!(worst_range < 0.1 * tol && worst_alt < 0.5 * tol, "{tol}: {worst_range} {worst_alt}");
        }
    }

    #[test]
    fn unity_at_zero_range() {
        for h in [0.0, 0.3, 8.0, 20.0] {
            let p = table().path(&MLS_RURAL_23, h, h, 0.0).unwrap();
            assert!(p.transmittance.iter().all(|&t| t == 1.0), "{h}");
            assert_eq!(p.band_path_radiance_w_m2_sr(Band::LWIR_8_12), 0.0);
        }
    }

    #[test]
    fn falls_with_range_on_a_horizontal_path() {
        for h in [0.0, 1.0, 5.5, 12.0] {
            let mut last = 1.0;
            for r in [0.1, 0.5, 1.0, 2.0, 4.0, 7.0, 12.0, 20.0, 35.0, 50.0] {
                let Ok(p) = table().path(&MLS_RURAL_23, h, h, r) else { continue };
                for band in [Band::LWIR_8_12, Band::MWIR_3_5] {
                    let tau = p.band_average(band);
                    assert!(tau > 0.0 && tau <= 1.0);
                    if band == Band::LWIR_8_12 {
                        assert!(tau < last, "h {h} r {r}: {tau} after {last}");
                        last = tau;
                    }
                }
            }
        }
    }

    #[test]
    fn paths_outside_the_grid_are_errors() {
        let t = table();
        let w = MLS_RURAL_23;
        assert!(matches!(
            t.path(&w, 25.0, 1.0, 30.0),
            Err(AtmosphereError::OutsideGrid { name: "observer_alt_km", .. })
        ));
        assert!(matches!(t.path(&w, 1.0, -0.1, 3.0), Err(AtmosphereError::OutsideGrid { name: "target_alt_km", .. })));
        assert!(matches!(t.path(&w, 1.0, 5.0, 3.0), Err(AtmosphereError::OutsideGrid { name: "range_km", .. })));
        assert!(matches!(t.path(&w, 1.0, 1.0, 150.0), Err(AtmosphereError::OutsideGrid { name: "range_km", .. })));
        assert!(matches!(t.path(&w, 0.05, 0.05, 80.0), Err(AtmosphereError::BelowGround { .. })));
        let foggy = Weather { visibility_km: 0.5, ..w };
        assert!(matches!(
            t.path(&foggy, 1.0, 1.0, 3.0),
            Err(AtmosphereError::OutsideGrid { name: "visibility_km", .. })
        ));
        assert!(t.path(&w, f64::NAN, 1.0, 3.0).is_err());
    }

    #[test]
    fn damaged_tables_are_refused() {
        let mut bytes = SHIPPED.to_vec();
        let n = bytes.len();
        bytes[n - 100] ^= 0x40;
        assert!(AtmosphereTable::parse(&bytes).is_err());
        assert!(AtmosphereTable::parse(&SHIPPED[..n - 1]).is_err());
        assert!(AtmosphereTable::parse(b"IRSIMATX").is_err());
        let mut v = SHIPPED.to_vec();
        v[8] = 9;
        assert!(matches!(AtmosphereTable::parse(&v), Err(AtmosphereError::Table(m)) if m.contains("version")));
    }

    #[test]
    fn a_table_read_lazily_decodes_its_payload_when_a_path_needs_it() {
        let w = MLS_RURAL_23;
        let eager = AtmosphereTable::parse(SHIPPED).unwrap();
        assert!(eager.data.iter().all(|d| d.get().is_some()), "parse decodes every block");
        let lazy = AtmosphereTable::read(SHIPPED).unwrap();
        assert!(lazy.data.iter().all(|d| d.get().is_none()), "the header alone was read");
        lazy.check_path(1.0, 3.0, 10.0).unwrap();
        assert_eq!(lazy.visibilities_km(Aerosol::Rural), eager.visibilities_km(Aerosol::Rural));
        assert!(lazy.data.iter().all(|d| d.get().is_none()), "checks need the header alone");
        let (a, b) = (lazy.path(&w, 1.0, 3.0, 10.0).unwrap(), eager.path(&w, 1.0, 3.0, 10.0).unwrap());
        assert_eq!(a.transmittance, b.transmittance);
        assert_eq!(a.path_radiance_w_m2_sr_um, b.path_radiance_w_m2_sr_um);
        let (a, _) = lazy.ray(&w, 2.0, 0.1).unwrap();
        let (b, _) = eager.ray(&w, 2.0, 0.1).unwrap();
        assert_eq!(a.path_radiance_w_m2_sr_um, b.path_radiance_w_m2_sr_um);
        // the last model's block damaged: the header reads, every path through that model that needs its block
        // is an error (not a panic), and the other models' paths are as before
        let mut bytes = SHIPPED.to_vec();
        let n = bytes.len();
        bytes[n - 100] ^= 0x40;
        let damaged = AtmosphereTable::read(Vec::leak(bytes)).unwrap();
        let last = Weather { model: ModelAtmosphere::ALL[ModelAtmosphere::ALL.len() - 1], ..w };
        assert_ne!(last.model, w.model);
        // even a path of no length (the observer's tables start with one, and fill what fails later as clear air)
        assert!(matches!(damaged.path(&last, 1.0, 1.0, 0.0), Err(AtmosphereError::Table(_))));
        let named = |r: Result<PathSpectrum, AtmosphereError>| match r {
            Err(AtmosphereError::Table(m)) => m.starts_with(&format!("{}'s block: ", last.model.name())),
            _ => false,
        };
        assert!(named(damaged.path(&last, 1.0, 3.0, 10.0)), "the error names the model's block");
        assert!(matches!(damaged.ray(&last, 2.0, 0.1), Err(AtmosphereError::Table(_))));
        let (a, b) = (damaged.path(&w, 1.0, 3.0, 10.0).unwrap(), eager.path(&w, 1.0, 3.0, 10.0).unwrap());
        assert_eq!(a.transmittance, b.transmittance);
        let decoded = damaged.data.iter().filter(|d| d.get().is_some()).count();
        assert_eq!(decoded, 2, "the blocks of the two models asked for, not the others");
    }

    #[test]
    fn aerosol_lowers_the_transmittance() {
        let t = table();
        let clear = Weather { aerosol: Aerosol::None, ..MLS_RURAL_23 };
        let hazy = Weather { visibility_km: 5.0, ..MLS_RURAL_23 };
        let a = t.path(&clear, 1.0, 1.0, 10.0).unwrap().band_average(Band::LWIR_8_12);
        let b = t.path(&hazy, 1.0, 1.0, 10.0).unwrap().band_average(Band::LWIR_8_12);
        // the issue's check: no aerosol against rural 5 km differ by about a factor of two
        assert!(a / b > 1.6 && a / b < 2.6, "{a} {b}");
    }

    #[test]
    fn spectrum_weighting_follows_the_target() {
        let p = table().path(&MLS_RURAL_23, 2.0, 4.0, 20.0).unwrap();
        let band = Band::try_new(3.0, 5.0).unwrap();
        let (cool, hot) = (p.spectrum_weighted(band, 250.0), p.spectrum_weighted(band, 1000.0));
        assert!(cool > 0.0 && cool < 1.0 && hot > 0.0 && hot < 1.0);
        assert!((cool - hot).abs() > 1e-3, "{cool} {hot}");
        let flat = p.band_average(band);
        assert!((flat - cool).abs() < 0.2);
    }

    #[test]
    fn kept_blackbody_weights_give_the_weighting_s_bits_and_follow_every_input() {
        let near = table().path(&MLS_RURAL_23, 2.0, 4.0, 20.0).unwrap();
        let far = table().path(&MLS_RURAL_23, 2.0, 4.0, 60.0).unwrap();
        // the last call's spectrum on bins 1 % narrower: weights made for the table's bins must not serve it
        let mut rebinned = far.clone();
        for e in &mut rebinned.edges_um {
            *e *= 0.99;
        }
        let (mwir, lwir) = (Band::try_new(3.0, 5.0).unwrap(), Band::try_new(8.0, 12.0).unwrap());
        let gl = PlanckMethod::GaussLegendre { points: 4 };
        let kept = BinWeights::default();
        // each call against the weighting made anew: the same temperature again (a target in level flight), then
        // each input changed alone, then back
        let calls = [
            (&near, Measure::Photon, mwir, 320.0, PlanckMethod::Series),
            (&far, Measure::Photon, mwir, 320.0, PlanckMethod::Series),
            (&far, Measure::Photon, mwir, 320.5, PlanckMethod::Series),
            (&far, Measure::Energy, mwir, 320.5, PlanckMethod::Series),
            (&far, Measure::Energy, lwir, 320.5, PlanckMethod::Series),
            (&far, Measure::Energy, lwir, 320.5, gl),
            (&rebinned, Measure::Energy, lwir, 320.5, gl),
            (&near, Measure::Photon, mwir, 320.0, PlanckMethod::Series),
        ];
        for (i, (p, measure, band, temp_k, method)) in calls.into_iter().enumerate() {
            let fresh = p.spectrum_weighted_with(measure, band, temp_k, method);
            let again = kept.spectrum_weighted_with(p, measure, band, temp_k, method);
            assert_eq!(again.to_bits(), fresh.to_bits(), "call {i}: {again} against {fresh}");
            if i > 0 {
                let (q, m0, b0, t0, me0) = calls[i - 1];
                assert_ne!(q.spectrum_weighted_with(m0, b0, t0, me0), fresh, "call {i} changes the result");
            }
        }
        // a copy keeps them, and gives the same bits
        let copy = kept.clone();
        assert!(copy.kept().made_for.is_some(), "the copy holds the weights");
        let from_copy = copy.spectrum_weighted_with(&near, Measure::Photon, mwir, 320.0, PlanckMethod::Series);
        let fresh = near.spectrum_weighted_with(Measure::Photon, mwir, 320.0, PlanckMethod::Series);
        assert_eq!(from_copy.to_bits(), fresh.to_bits());
    }

    /// Short paths, against direct LOWTRAN runs (`python3 tools/atmosphere/lowtran_tables.py --point
    /// --observer-alt-km H1 --target-alt-km H2 --range-km R --band-um LO HI`, midlatitude summer, rural 23 km):
    /// `(h1, h2, range, τ 3–5 µm, τ 8–12 µm)`.
    const SHORT_PATHS: [(f64, f64, f64, f64, f64); 19] = [
        (1.49, 1.52, 0.3, 0.7495, 0.9351),
        (1.5, 1.52, 0.3, 0.7496, 0.9352),
        (0.2, 0.3, 0.2, 0.7318, 0.9184),
        (0.95, 1.05, 0.9, 0.6006, 0.8299),
        (0.95, 1.05, 1.1, 0.5735, 0.8049),
        (0.1, 0.1, 0.1, 0.7851, 0.9459),
        (1.0, 1.0, 0.2, 0.7631, 0.9391),
        (3.0, 3.0, 0.05, 0.8920, 0.9887),
        (0.55, 0.6, 0.8, 0.5895, 0.8134),
        (0.4, 0.6, 0.45, 0.6580, 0.8708),
        (1.9, 2.6, 0.8, 0.6916, 0.9094),
        (1.9, 2.35, 0.6, 0.7141, 0.9207),
        (0.3, 0.75, 0.5, 0.6466, 0.8621),
        (5.2, 5.6, 0.45, 0.8519, 0.9814),
        (1.0, 2.8, 2.0, 0.5492, 0.7966),
        (3.1, 4.9, 1.9, 0.7015, 0.9247),
        (6.2, 8.9, 2.8, 0.8024, 0.9629),
        (0.1, 2.9, 2.95, 0.4533, 0.6709),
        (12.5, 15.5, 3.2, 0.8859, 0.9721),
    ];

    #[test]
    fn short_paths_match_direct_runs() {
        let mut worst = 0.0f64;
        for (h1, h2, r, mwir, lwir) in SHORT_PATHS {
            let p = table().path(&MLS_RURAL_23, h1, h2, r).unwrap();
            for (band, want) in [(Band::MWIR_3_5, mwir), (Band::LWIR_8_12, lwir)] {
                let d = (p.band_average(band) - want).abs();
                assert!(d < 0.01, "{h1} → {h2} km over {r} km: {} against {want}", p.band_average(band));
                worst = worst.max(d);
            }
        }
        eprintln!("short paths: largest |Δτ| {worst:.4}");
    }

    /// Direct LOWTRAN runs off the grid (the generator's `lowtran7_offgrid.json`): band τ within 0.01, band-mean
    /// path radiance within 8 % where it is above 0.05 W m⁻² sr⁻¹ µm⁻¹.
    #[test]
    fn matches_direct_lowtran_runs_off_the_grid() {
        let doc = offgrid_runs();
        let runs = doc["runs"].as_array().unwrap();
        assert!(runs.len() > 100);
        let (mut worst, mut worst_at, mut rad_worst) = (0.0f64, String::new(), 0.0f64);
        for r in runs {
            let model = serde_json::from_value(r["model"].clone()).unwrap();
            let aerosol = serde_json::from_value(r["aerosol"].clone()).unwrap();
            let w = Weather { model, aerosol, visibility_km: r["visibility_km"].as_f64().unwrap() };
            let (h1, h2, s) = (
                r["observer_alt_km"].as_f64().unwrap(),
                r["target_alt_km"].as_f64().unwrap(),
                r["range_km"].as_f64().unwrap(),
            );
            let p = table().path(&w, h1, h2, s).unwrap();
            for (key, band) in [("3-5", Band::MWIR_3_5), ("8-12", Band::LWIR_8_12)] {
                let want = r["bands_um"][key]["transmittance"].as_f64().unwrap();
                let got = p.band_average(band);
                if (got - want).abs() > worst {
                    worst = (got - want).abs();
                    worst_at = format!("{r}: {key} µm {got} against {want}");
                }
                let lr = r["bands_um"][key]["path_radiance"].as_f64().unwrap();
                let gr = p.band_mean_path_radiance_w_m2_sr_um(band);
                if lr > 0.05 {
                    rad_worst = rad_worst.max((gr / lr - 1.0).abs());
                }
            }
        }
        eprintln!("largest |Δτ| {worst:.4} at {worst_at}; largest relative path-radiance error {rad_worst:.3}");
        assert!(worst <= 0.01, "{worst_at}");
        // measured: 0.070 (0.228 while a steep path's second scaled corner added into the first one's buffers)
        assert!(rad_worst <= 0.08, "path radiance off by {rad_worst:.3} of LOWTRAN's");
    }
    /// The clear sky against direct LOWTRAN runs from the observer up to 100 km (the generator's `sky` runs):
    /// brightness-temperature error of the band radiance, largest per observer altitude.
    #[test]
    fn the_clear_sky_matches_direct_lowtran_sky_paths() {
        use crate::physics::planck::{Measure, brightness_temperature};
        let doc = offgrid_runs();
        let runs = doc["sky"].as_array().unwrap();
        assert!(runs.len() > 500);
        let mut worst: std::collections::BTreeMap<String, (f64, f64, String)> = Default::default();
        for r in runs {
            let model = serde_json::from_value(r["model"].clone()).unwrap();
            let aerosol = serde_json::from_value(r["aerosol"].clone()).unwrap();
            let w = Weather { model, aerosol, visibility_km: r["visibility_km"].as_f64().unwrap() };
            let h = r["observer_alt_km"].as_f64().unwrap();
            let zenith = r["zenith_angle_deg"].as_f64().unwrap();
            let p = table().sky(&w, h, (90.0 - zenith).to_radians().sin()).unwrap();
            for (key, band) in [("3-5", Band::MWIR_3_5), ("8-12", Band::LWIR_8_12)] {
                let width = band.hi_um() - band.lo_um();
                let want = r["bands_um"][key]["path_radiance"].as_f64().unwrap() * width;
                let got = p.band_mean_path_radiance_w_m2_sr_um(band) * width;
                let bt = |l: f64| brightness_temperature(Measure::Energy, band, l).unwrap_or(0.0);
                let dt = bt(got) - bt(want);
                let dtau = p.band_average(band) - r["bands_um"][key]["transmittance"].as_f64().unwrap();
                let view = if zenith <= 75.0 { "elevation ≥ 15°" } else { "elevation < 15°" };
                let e = worst.entry(format!("{key} µm, {view}, from {h:>4} km")).or_default();
                if dt.abs() > e.0.abs() {
                    *e = (dt, e.1, format!("{} {} at {zenith}°", model.name(), aerosol.name()));
                }
                if dtau.abs() > e.1.abs() {
                    e.1 = dtau;
                }
            }
        }
        let mut failed = Vec::new();
        for (k, (dt, dtau, at)) in &worst {
            eprintln!("{k}: brightness temperature {dt:+.2} K ({at}), τ {dtau:+.4}");
            // measured: at most 1.29 K from 0–3 km at 15° and above, 3.9 K below, 5.9 K from anywhere. Our path
            // radiance is the converged integral along the path; LOWTRAN's sums isothermal layers (1 km thick near
            // the ground) and so puts the emission of lines opaque within the first layer at its mean temperature,
            // colder than the air at the observer: with 32 equal segments and the temperature at each middle, a
            // rule with the same bias, the first row was 0.61 K
            let low = k.ends_with(" 0 km") || k.ends_with(" 1 km") || k.ends_with(" 3 km");
            let bound = match (low, k.contains("≥ 15°")) {
                (true, true) => 1.5,
                (true, false) => 4.5,
                _ => 6.5,
            };
            if dt.abs() > bound {
                failed.push(format!("{k}: {dt} K at {at} (bound {bound} K)"));
            }
        }
        assert!(failed.is_empty(), "{failed:#?}");
    }

    #[test]
    fn a_band_s_bins_alone_are_the_whole_spectrum_s_bins_bit_for_bit() {
        let t = table();
        let hazy = Weather { aerosol: Aerosol::Maritime, visibility_km: 7.0, ..MLS_RURAL_23 };
        for band in [Band::LWIR_8_12, Band::MWIR_3_5, Band::try_new(7.6, 13.3).unwrap()] {
            let bins = t.bins_of(band);
            // exactly the bins a band's sums read
            let whole = t.path(&MLS_RURAL_23, 1.0, 1.0, 0.0).unwrap();
            let overlapping: Vec<usize> = whole.overlaps(band).map(|(b, _, _)| b).collect();
            assert_eq!(overlapping, bins.clone().collect::<Vec<_>>(), "{band:?}");
            let same = |a: &PathSpectrum, b: &PathSpectrum| {
                assert_eq!(b.edges_um, a.edges_um[bins.start..=bins.end]);
                assert_eq!(b.samples, a.samples[bins.clone()]);
                for (x, y) in
                    [(&a.transmittance, &b.transmittance), (&a.path_radiance_w_m2_sr_um, &b.path_radiance_w_m2_sr_um)]
                {
                    let x: Vec<u64> = x[bins.clone()].iter().map(|v| v.to_bits()).collect();
                    assert_eq!(x, y.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
                }
                assert_eq!(a.cell, b.cell);
                assert_eq!(a.spectrum_weighted(band, 290.0).to_bits(), b.spectrum_weighted(band, 290.0).to_bits());
                assert_eq!(
                    a.band_path_radiance_in(Measure::Photon, band).to_bits(),
                    b.band_path_radiance_in(Measure::Photon, band).to_bits()
                );
            };
            // level, slant, steep (the corners' vertical paths scaled), short, long, through the aerosol layers
            for (w, h1, h2, r) in [
                (&MLS_RURAL_23, 1.0, 1.0, 5.0),
                (&hazy, 0.2, 3.0, 12.0),
                (&MLS_RURAL_23, 1.0, 9.0, 8.2),
                (&hazy, 0.5, 0.5, 0.05),
                (&MLS_RURAL_23, 2.0, 15.0, 90.0),
            ] {
                same(
                    &t.path(w, h1, h2, r).unwrap(),
                    &t.path_in(w, h1, h2, r, bins.clone(), PathSteps::STANDARD).unwrap(),
                );
            }
            // rays up through the top, and down to the ground
            for (h, sin_e) in [(1.0, 0.3), (0.1, 0.02), (5.0, -0.2)] {
                let (a, ground_a) = t.ray(&hazy, h, sin_e).unwrap();
                let (b, ground_b) = t.ray_in(&hazy, h, sin_e, bins.clone(), PathSteps::STANDARD).unwrap();
                assert_eq!(ground_a, ground_b);
                same(&a, &b);
            }
        }
    }
}
