//! The LOWTRAN7 table as a scene's atmosphere: one weather, one sensor band, one observer.
//!
//! A target's line of sight is interpolated from the table itself ([`LowtranAtmosphere::sight`]), once per target
//! per change of geometry. Everything else that needs a path's transmittance many times over (the ground and
//! the limb in the sky's dome, a generated cloud layer's texels) starts at the observer's starting position, so
//! those paths are tabulated once, from the observer's starting altitude to every altitude of the table's grid
//! over 33 ranges from the vertical path to 100 km, spread as the square of their index, and read bilinearly (in
//! the table's altitude coordinate and that range coordinate, in `ln τ` and in path radiance). Their band τ is
//! weighted by a blackbody's spectrum at the air temperature at the observer, in the detector's measure: what
//! they transmit is air, ground or cloud near that temperature, and so an isothermal path's `τ·B(T)` plus its
//! path radiance is `B(T)`, which a uniform band average would break (a step at the horizon). The sun's path is the vertical path from the target's
//! altitude to 20 km stretched bin by bin to the slant length, weighted by the sun's spectrum.
//!
//! Beyond what the table covers, these observer's paths (not a target's line of sight, which is an error
//! there) are extended: past 100 km with the extinction of the last range step (a limb path is nearly opaque
//! there), above 20 km as at 20 km, a path the table cannot trace (through the ground beyond the horizon) with
//! the extinction of the longest traceable one.

use glam::DVec3;

use super::lowtran::{
    AtmosphereError, AtmosphereTable, EARTH_RADIUS_KM, PathSpectrum, PathSteps, Weather, horizon_sin_e,
};
use super::planck::{Band, Measure, band_radiance};
use super::transmittance::PathTransmittance;

/// Nodes of the clear sky's radiance between the horizontal and the zenith, spaced as the square of their index.
pub const SKY_NODES: usize = 96;
/// Nodes between the horizon's dip and the horizontal (the limb), spaced as the square of their index from the
/// horizontal.
pub const LIMB_NODES: usize = 32;

/// Nodes between the nadir and the horizon's dip (the ground), spaced as the square of their index from the dip.
pub const GROUND_NODES: usize = 48;

/// Ranges of the observer's table of band paths.
const RANGE_NODES: usize = 33;
/// Altitudes (km) of the sun path's vertical profile, every 0.5 km.
const VERTICAL_STEP_KM: f64 = 0.5;

/// A scene's LOWTRAN atmosphere (see the module's documentation).
#[derive(Debug)]
pub struct LowtranAtmosphere {
    table: &'static AtmosphereTable,
    /// The weather.
    pub weather: Weather,
    band: Band,
    measure: Measure,
    /// The observer's starting altitude, km.
    eye_alt_km: f64,
    /// The table's altitudes, km.
    alt_km: Vec<f64>,
    /// Their interpolation coordinates `−exp(−h / H)`.
    alt_coord: Vec<f64>,
    /// `ln τ` (weighted by the air's spectrum) from the eye to `alt_km[i]` at range fraction `j`, `[i][j]`.
    ln_tau: Vec<f64>,
    /// Band path radiance in the measure, `[i][j]`.
    path: Vec<f64>,
    /// Per-bin transmittance of the vertical path from `k·VERTICAL_STEP_KM` to the top, `[k][bin]`.
    vertical: Vec<f64>,
    /// The sun's energy radiance in each bin's part of the band (its spectrum's weights).
    sun_energy_weights: Vec<f64>,
    /// A blackbody's at the air temperature at the observer, in the measure: the weights of the band τ here.
    air_weights: Vec<f64>,
    /// The same in the detector's measure (the weights of reflected sunlight reaching the detector).
    sun_weights: Vec<f64>,
    /// Each bin's ratio from energy radiance to the measure's ([`PathSpectrum::measure_ratios`]), for every path's
    /// band path radiance.
    measure_ratios: Vec<f64>,
    /// The table's bins that overlap the band: the only ones its spectra hold ([`AtmosphereTable::path_in`]).
    bins: std::ops::Range<usize>,
    /// How finely every path's integrals are taken.
    steps: PathSteps,
    nbins: usize,
}

impl LowtranAtmosphere {
    /// Tabulates the observer's paths for `weather` in `band`, radiances in `measure`, from `eye_alt_m`; the sun
    /// is a blackbody at `sun_temp_k`. Every path's integrals, the table's and those asked for later, are taken
    /// in `steps`.
    ///
    /// # Errors
    /// [`AtmosphereError`] if the table cannot be loaded, the band is not inside the table's 1–14 µm, the
    /// visibility is outside the tabulated ones, or the observer is outside 0–20 km.
    pub fn new(
        weather: Weather,
        band: Band,
        measure: Measure,
        eye_alt_m: f64,
        sun_temp_k: f64,
        steps: PathSteps,
    ) -> Result<Self, AtmosphereError> {
        use rayon::prelude::*;
        let table = AtmosphereTable::shipped()?;
        let eye = eye_alt_m / 1000.0;
        let top = table.max_altitude_km();
        let far = table.max_range_km();
        table.check_path(eye, eye, 0.0)?;
        let edges = table.edges_um();
        let (first, last) = (edges[0], edges[edges.len() - 1]);
        if !(band.lo_um() >= first && band.hi_um() <= last) {
            return Err(AtmosphereError::OutsideGrid {
                name: "band_um",
                value: if band.lo_um() < first { band.lo_um() } else { band.hi_um() },
                range: format!("[{first}, {last}] µm"),
            });
        }
        // the band's bins alone: the others would be most of every path's work, for weights of 0
        let bins = table.bins_of(band);
        let probe = table.path_in(&weather, eye, eye, 0.0, bins.clone(), steps)?;
        let nbins = probe.transmittance.len();
        let alt_km: Vec<f64> = table.altitudes_km().to_vec();
        // what these paths pass is air, ground or cloud near the air's temperature: τ weighted by its spectrum, so
        // that an isothermal path's τ·B(T) plus its path radiance is B(T), as it must be
        let air_weights = probe.blackbody_weights(measure, band, table.profile(weather.model).temperature_at(eye));
        let measure_ratios = probe.measure_ratios(measure, band);
        let rows: Vec<(Vec<f64>, Vec<f64>)> = alt_km
            .par_iter()
            .map(|&h| {
                let dh = (h - eye).abs();
                let mut ln_tau = vec![f64::NAN; RANGE_NODES];
                let mut path = vec![f64::NAN; RANGE_NODES];
                for j in 0..RANGE_NODES {
                    let r = range_at(dh, far, j);
                    if let Ok(p) = table.path_in(&weather, eye, h, r, bins.clone(), steps) {
                        ln_tau[j] = p.weighted(&air_weights).max(1e-300).ln();
                        path[j] = p.band_path_radiance_by(band, &measure_ratios);
                    }
                }
                fill_untraceable(&mut ln_tau, &mut path, dh, far);
                (ln_tau, path)
            })
            .collect();
        let (ln_tau, path): (Vec<_>, Vec<_>) = rows.into_iter().unzip();
        let levels = (top / VERTICAL_STEP_KM).round() as usize;
        let vertical: Vec<Vec<f64>> = (0..=levels)
            .into_par_iter()
            .map(|k| {
                let h = (k as f64 * VERTICAL_STEP_KM).min(top);
                table
                    .path_in(&weather, h, top, top - h, bins.clone(), steps)
                    .map(|p| p.transmittance)
                    .unwrap_or_else(|_| vec![1.0; nbins])
            })
            .collect();
        let sun_energy_weights = (0..nbins)
            .map(|b| probe.bin_part(b, band).map_or(0.0, |part| band_radiance(part, sun_temp_k, 1.0)))
            .collect();
        Ok(Self {
            table,
            weather,
            band,
            measure,
            eye_alt_km: eye,
            alt_coord: alt_km.iter().map(|&h| altitude_coord(h)).collect(),
            alt_km,
            ln_tau: ln_tau.concat(),
            path: path.concat(),
            vertical: vertical.concat(),
            sun_weights: probe.blackbody_weights(measure, band, sun_temp_k),
            sun_energy_weights,
            air_weights,
            measure_ratios,
            bins,
            nbins,
            steps,
        })
    }

    /// The spectrum of the line of sight between the observer at `eye_m` and a target at `target_m`,
    /// interpolated from the table, over the bins of the band ([`AtmosphereTable::path_in`]).
    ///
    /// # Errors
    /// [`AtmosphereError`] for a path outside the table's grid (never extrapolated).
    pub fn sight(&self, eye_m: DVec3, target_m: DVec3) -> Result<PathSpectrum, AtmosphereError> {
        let (h1, h2, r) = (eye_m.z / 1000.0, target_m.z / 1000.0, eye_m.distance(target_m) / 1000.0);
        self.table.path_in(&self.weather, h1, h2, r, self.bins.clone(), self.steps)
    }

    /// Checks that the line of sight between two points lies inside the table's grid.
    ///
    /// # Errors
    /// As [`LowtranAtmosphere::sight`].
    pub fn check_sight(table: &AtmosphereTable, eye_m: DVec3, target_m: DVec3) -> Result<(), AtmosphereError> {
        table.check_path(eye_m.z / 1000.0, target_m.z / 1000.0, eye_m.distance(target_m) / 1000.0)
    }

    /// The sun's spectrum in the detector's measure per bin of the band: the weights that give the reflected
    /// sunlight's transmittance ([`PathSpectrum::weighted`]).
    pub fn sun_weights(&self) -> &[f64] {
        &self.sun_weights
    }

    /// Each bin's ratio from energy radiance to the detector's measure ([`PathSpectrum::measure_ratios`]).
    pub fn measure_ratios(&self) -> &[f64] {
        &self.measure_ratios
    }

    /// The band path radiance in the detector's measure of a path of this atmosphere (one of its spectra, over its
    /// bins): [`PathSpectrum::band_path_radiance_in`], with the bins' ratios made once.
    pub fn band_path_radiance(&self, p: &PathSpectrum) -> f64 {
        p.band_path_radiance_by(self.band, &self.measure_ratios)
    }

    /// The band.
    pub fn band(&self) -> Band {
        self.band
    }

    /// The radiances' measure.
    pub fn measure(&self) -> Measure {
        self.measure
    }

    /// Band transmittance of the vertical path from sea level to the table's top (20 km), weighted as the
    /// observer's paths are.
    pub fn zenith_transmittance(&self) -> f64 {
        let top = self.table.max_altitude_km();
        self.table
            .path_in(&self.weather, 0.0, top, top, self.bins.clone(), self.steps)
            .map_or(1.0, |p| p.weighted(&self.air_weights))
    }

    /// Sine of the lowest elevation whose ray from the observer's start misses the ground.
    pub fn horizon_sin_e(&self) -> f64 {
        horizon_sin_e(self.eye_alt_km)
    }

    /// The clear sky's spectrum toward elevation `asin(sin_e)` from the observer's start
    /// ([`AtmosphereTable::sky`]), over the bins of the band.
    ///
    /// # Errors
    /// As [`AtmosphereTable::sky`].
    pub fn sky_spectrum(&self, sin_e: f64) -> Result<PathSpectrum, AtmosphereError> {
        self.table.sky_in(&self.weather, self.eye_alt_km, sin_e, self.bins.clone(), self.steps)
    }

    /// The clear sky's band radiance in the detector's measure toward elevation `asin(sin_e)` (see
    /// [`LowtranAtmosphere::sky_spectrum`]).
    ///
    /// # Errors
    /// As [`LowtranAtmosphere::sky_spectrum`].
    pub fn sky_radiance(&self, sin_e: f64) -> Result<f64, AtmosphereError> {
        Ok(self.band_path_radiance(&self.sky_spectrum(sin_e)?))
    }

    /// The clear sky's band radiance on [`SKY_NODES`] + [`LIMB_NODES`] elevations from the horizon's dip to the
    /// zenith, for [`ClearSky::radiance`] to interpolate.
    ///
    /// # Errors
    /// As [`LowtranAtmosphere::sky_spectrum`].
    pub fn clear_sky(&self) -> Result<ClearSky, AtmosphereError> {
        use rayon::prelude::*;
        let dip = -self.horizon_sin_e().asin();
        let mut elevation_rad: Vec<f64> = Vec::with_capacity(SKY_NODES + LIMB_NODES + 1);
        if dip > 1e-9 {
            elevation_rad.extend((1..=LIMB_NODES).rev().map(|k| -dip * (k as f64 / LIMB_NODES as f64).powi(2)));
        }
        elevation_rad
            .extend((0..=SKY_NODES).map(|k| std::f64::consts::FRAC_PI_2 * (k as f64 / SKY_NODES as f64).powi(2)));
        let radiance = elevation_rad.par_iter().map(|&e| self.sky_radiance(e.sin())).collect::<Result<Vec<_>, _>>()?;
        let span = std::f64::consts::FRAC_PI_2 - dip;
        let ground_elevation_rad: Vec<f64> =
            (0..=GROUND_NODES).rev().map(|k| -dip - span * (k as f64 / GROUND_NODES as f64).powi(2)).collect();
        let ground = ground_elevation_rad
            .par_iter()
            .map(|&e| {
                let sin_e = e.sin().min(self.horizon_sin_e() - 1e-12);
                let (p, _) = self.table.ray_in(&self.weather, self.eye_alt_km, sin_e, self.bins.clone(), self.steps)?;
                Ok((p.weighted(&self.air_weights), self.band_path_radiance(&p)))
            })
            .collect::<Result<Vec<(f64, f64)>, AtmosphereError>>()?;
        let (ground_tau, ground_path) = ground.into_iter().unzip();
        Ok(ClearSky { elevation_rad, radiance, ground_elevation_rad, ground_tau, ground_path })
    }

    /// `(ln τ, path radiance)` of the band from the observer's starting altitude to altitude `h_km` over `r_km`.
    fn observer_path(&self, h_km: f64, r_km: f64) -> (f64, f64) {
        let top = self.alt_km[self.alt_km.len() - 1];
        let far = self.table.max_range_km();
        let h = h_km.clamp(0.0, top);
        let i = self.alt_km.partition_point(|&v| v <= h).saturating_sub(1).min(self.alt_km.len() - 2);
        let (c0, c1) = (self.alt_coord[i], self.alt_coord[i + 1]);
        let fa = ((altitude_coord(h) - c0) / (c1 - c0)).clamp(0.0, 1.0);
        let dh = (h - self.eye_alt_km).abs();
        let r = r_km.max(dh);
        // the fraction of the way from the vertical path to the longest range, on the nodes' square spacing
        let u = if far > dh { ((r.min(far) - dh) / (far - dh)).sqrt() * (RANGE_NODES - 1) as f64 } else { 0.0 };
        let j = (u as usize).min(RANGE_NODES - 2);
        let fr = u - j as f64;
        let at = |row: usize, v: &[f64]| {
            let base = row * RANGE_NODES;
            v[base + j] + fr * (v[base + j + 1] - v[base + j])
        };
        let mut ln_tau = at(i, &self.ln_tau) + fa * (at(i + 1, &self.ln_tau) - at(i, &self.ln_tau));
        let mut path = at(i, &self.path) + fa * (at(i + 1, &self.path) - at(i, &self.path));
        if r > far {
            // the extinction of the last range step, carried on
            let slope = |row: usize| {
                let base = row * RANGE_NODES;
                let dr = range_at((self.alt_km[row] - self.eye_alt_km).abs(), far, RANGE_NODES - 1)
                    - range_at((self.alt_km[row] - self.eye_alt_km).abs(), far, RANGE_NODES - 2);
                (self.ln_tau[base + RANGE_NODES - 1] - self.ln_tau[base + RANGE_NODES - 2]) / dr.max(1e-9)
            };
            let s = (slope(i) + fa * (slope(i + 1) - slope(i))).min(0.0);
            let before = ln_tau;
            ln_tau += s * (r - far);
            let (e0, e1) = (-before.exp_m1(), -ln_tau.exp_m1());
            if e0 > 1e-12 {
                path *= e1 / e0;
            }
        }
        (ln_tau.min(0.0), path.max(0.0))
    }

    /// Band transmittance of the path from `from_m` toward the sun along `direction`, weighted by the sun's
    /// spectrum: the vertical path's bins stretched to the slant length to 20 km.
    fn sun_path(&self, from_m: DVec3, direction: DVec3) -> f64 {
        let sin_e = direction.normalize_or_zero().z;
        if sin_e <= 0.0 {
            return 0.0;
        }
        let top = self.alt_km[self.alt_km.len() - 1];
        let h = (from_m.z / 1000.0).clamp(0.0, top);
        if h >= top {
            return 1.0;
        }
        let (rh, rt) = (EARTH_RADIUS_KM + h, EARTH_RADIUS_KM + top);
        let slant = -rh * sin_e + (rh * rh * sin_e * sin_e + rt * rt - rh * rh).sqrt();
        let k = slant / (top - h);
        let x = h / VERTICAL_STEP_KM;
        let levels = self.vertical.len() / self.nbins;
        let i = (x as usize).min(levels - 2);
        let f = x - i as f64;
        let (a, b) = (&self.vertical[i * self.nbins..(i + 1) * self.nbins], &self.vertical[(i + 1) * self.nbins..]);
        let (mut num, mut den) = (0.0, 0.0);
        for (bin, &w) in self.sun_energy_weights.iter().enumerate() {
            if w > 0.0 {
                let t = a[bin] + f * (b[bin] - a[bin]);
                num += w * if t > 0.0 { t.powf(k) } else { 0.0 };
                den += w;
            }
        }
        if den > 0.0 { num / den } else { 1.0 }
    }

    /// The end of a segment that is not at the observer's starting altitude, if the other one is (1 m).
    fn far_end(&self, a_m: DVec3, b_m: DVec3) -> Option<DVec3> {
        let eye = self.eye_alt_km * 1000.0;
        if (a_m.z - eye).abs() <= 1.0 {
            Some(b_m)
        } else if (b_m.z - eye).abs() <= 1.0 {
            Some(a_m)
        } else {
            None
        }
    }
}

/// The clear sky's band radiance from one observer, on elevation nodes ([`LowtranAtmosphere::clear_sky`]).
#[derive(Debug, Clone)]
pub struct ClearSky {
    /// Elevations, rad, increasing from the horizon's dip to the zenith.
    pub elevation_rad: Vec<f64>,
    /// Band radiance in the detector's measure at each.
    pub radiance: Vec<f64>,
    /// Elevations of the rays that meet the ground, rad, increasing from the nadir to the horizon's dip.
    pub ground_elevation_rad: Vec<f64>,
    /// Their band transmittance to the ground, weighted by the air's spectrum at the observer.
    pub ground_tau: Vec<f64>,
    /// Their band path radiance in the detector's measure.
    pub ground_path: Vec<f64>,
}

impl ClearSky {
    /// Sine of the lowest elevation covered (the horizon's dip).
    pub fn lowest_sin_e(&self) -> f64 {
        self.elevation_rad[0].sin()
    }

    /// Radiance toward elevation `asin(sin_e)`, linear in the elevation between the nodes (clamped to them).
    pub fn radiance(&self, sin_e: f64) -> f64 {
        interpolate(&self.elevation_rad, &self.radiance, sin_e.clamp(-1.0, 1.0).asin())
    }

    /// Band transmittance and path radiance of the ray toward elevation `asin(sin_e)` down to the ground (clamped
    /// to the ground's nodes).
    pub fn ground(&self, sin_e: f64) -> (f64, f64) {
        let e = sin_e.clamp(-1.0, 1.0).asin();
        (
            interpolate(&self.ground_elevation_rad, &self.ground_tau, e),
            interpolate(&self.ground_elevation_rad, &self.ground_path, e),
        )
    }
}

/// `y` at `at`, linear between the increasing nodes `x` (clamped to them).
fn interpolate(x: &[f64], y: &[f64], at: f64) -> f64 {
    let n = x.len();
    let i = x.partition_point(|&v| v <= at).saturating_sub(1).min(n - 2);
    let f = ((at - x[i]) / (x[i + 1] - x[i])).clamp(0.0, 1.0);
    y[i] + f * (y[i + 1] - y[i])
}

/// The table's altitude coordinate.
fn altitude_coord(h_km: f64) -> f64 {
    -(-h_km / super::lowtran::ALTITUDE_SCALE_KM).exp()
}

/// The `j`-th range of a row whose vertical path is `dh` long, km: from `dh` to `far` as the square of `j`.
fn range_at(dh: f64, far: f64, j: usize) -> f64 {
    let u = j as f64 / (RANGE_NODES - 1) as f64;
    dh + (far - dh).max(0.0) * u * u
}

/// Fills the nodes of a row that the table could not trace (NaN) from the last traceable one, with its
/// extinction per km (the row's first node, the vertical path, always traces).
fn fill_untraceable(ln_tau: &mut [f64], path: &mut [f64], dh: f64, far: f64) {
    let Some(last) = ln_tau.iter().rposition(|v| v.is_finite()) else {
        ln_tau.fill(0.0);
        path.fill(0.0);
        return;
    };
    let r_last = range_at(dh, far, last);
    let per_km = if r_last > 0.0 { ln_tau[last] / r_last } else { 0.0 };
    for j in 0..ln_tau.len() {
        if !ln_tau[j].is_finite() {
            let r = range_at(dh, far, j);
            let lt = if j > last { per_km * r } else { ln_tau[j.saturating_sub(1)] };
            let (e0, e1) = (-ln_tau[last].exp_m1(), -lt.exp_m1());
            path[j] = if e0 > 1e-12 { path[last] * e1 / e0 } else { path[last] };
            ln_tau[j] = lt;
        }
    }
}

impl PathTransmittance for LowtranAtmosphere {
    fn along_segment(&self, a_m: DVec3, b_m: DVec3) -> f64 {
        let r_km = a_m.distance(b_m) / 1000.0;
        if r_km == 0.0 {
            return 1.0;
        }
        match self.far_end(a_m, b_m) {
            Some(other) => self.observer_path(other.z / 1000.0, r_km).0.exp(),
            None => {
                let top = self.alt_km[self.alt_km.len() - 1];
                let (ha, hb) = ((a_m.z / 1000.0).clamp(0.0, top), (b_m.z / 1000.0).clamp(0.0, top));
                let r = r_km.clamp((ha - hb).abs(), self.table.max_range_km());
                match self.table.path_in(&self.weather, ha, hb, r, self.bins.clone(), self.steps) {
                    Ok(p) => p.weighted(&self.air_weights).powf(r_km / r),
                    // untraceable away from the observer: as if from the observer's altitude
                    Err(_) => self.observer_path(hb, r_km).0.exp(),
                }
            }
        }
    }

    fn to_space(&self, from_m: DVec3, direction: DVec3) -> f64 {
        self.sun_path(from_m, direction)
    }

    fn path_radiance(&self, a_m: DVec3, b_m: DVec3) -> Option<f64> {
        let r_km = a_m.distance(b_m) / 1000.0;
        if r_km == 0.0 {
            return Some(0.0);
        }
        self.far_end(a_m, b_m).map(|other| self.observer_path(other.z / 1000.0, r_km).1)
    }

    fn transmittance_and_path(&self, a_m: DVec3, b_m: DVec3) -> (f64, Option<f64>) {
        let r_km = a_m.distance(b_m) / 1000.0;
        match self.far_end(a_m, b_m) {
            _ if r_km == 0.0 => (1.0, Some(0.0)),
            Some(other) => {
                let (ln_tau, path) = self.observer_path(other.z / 1000.0, r_km);
                (ln_tau.exp(), Some(path))
            }
            None => (self.along_segment(a_m, b_m), None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::lowtran::{Aerosol, ModelAtmosphere};

    const W: Weather =
        Weather { model: ModelAtmosphere::MidlatitudeSummer, aerosol: Aerosol::Rural, visibility_km: 23.0 };

    fn lwir() -> Band {
        Band::try_new(8.0, 12.0).unwrap()
    }

    #[test]
    fn observer_table_follows_the_table() {
        let band = lwir();
        let atm = LowtranAtmosphere::new(W, band, Measure::Energy, 1500.0, 5778.0, PathSteps::STANDARD).unwrap();
        let table = AtmosphereTable::shipped().unwrap();
        let eye = DVec3::new(0.0, 0.0, 1500.0);
        let mut worst_tau = 0.0f64;
        let mut worst_rel = 0.0f64;
        for (h, r) in [(0.0, 3.0), (0.3, 7.0), (1.2, 0.4), (2.7, 12.0), (5.5, 33.0), (9.0, 60.0), (14.0, 95.0)] {
            let z = h * 1000.0;
            let target = DVec3::new(0.0, ((r * 1000.0f64).powi(2) - (z - eye.z).powi(2)).max(0.0).sqrt(), z);
            let exact = table.path(&W, 1.5, h, target.distance(eye) / 1000.0).unwrap();
            let tau = atm.along_segment(eye, target);
            let t_air = table.profile(W.model).temperature_at(1.5);
            worst_tau = worst_tau.max((tau - exact.spectrum_weighted(band, t_air)).abs());
            let lp = atm.path_radiance(eye, target).unwrap();
            let lp_exact = exact.band_path_radiance_w_m2_sr(band);
            worst_rel = worst_rel.max((lp / lp_exact - 1.0).abs());
        }
        eprintln!("observer table: |Δτ| ≤ {worst_tau:.4}, path radiance ≤ {:.2} %", 100.0 * worst_rel);
        assert!(worst_tau < 0.01, "{worst_tau}");
        assert!(worst_rel < 0.03, "{worst_rel}");
    }

    #[test]
    fn sun_path_is_the_vertical_path_at_the_zenith_and_falls_toward_the_horizon() {
        let band = lwir();
        let atm = LowtranAtmosphere::new(W, band, Measure::Energy, 0.0, 5778.0, PathSteps::STANDARD).unwrap();
        let table = AtmosphereTable::shipped().unwrap();
        let zenith = atm.to_space(DVec3::new(0.0, 0.0, 1000.0), DVec3::Z);
        let p = table.path(&W, 1.0, 20.0, 19.0).unwrap();
        assert!((zenith - p.spectrum_weighted(band, 5778.0)).abs() < 1e-9, "{zenith}");
        let low = atm.to_space(DVec3::new(0.0, 0.0, 1000.0), DVec3::new(1.0, 0.0, 0.2));
        assert!(low < zenith && low > 0.0, "{low} {zenith}");
        assert_eq!(atm.to_space(DVec3::ZERO, DVec3::new(1.0, 0.0, -0.1)), 0.0);
        assert_eq!(atm.along_segment(DVec3::ZERO, DVec3::ZERO), 1.0);
    }

    #[test]
    fn beyond_the_table_is_continued_not_refused() {
        let atm = LowtranAtmosphere::new(W, lwir(), Measure::Energy, 8000.0, 5778.0, PathSteps::STANDARD).unwrap();
        let eye = DVec3::new(0.0, 0.0, 8000.0);
        let near = atm.along_segment(eye, DVec3::new(99_000.0, 0.0, 8000.0));
        let far = atm.along_segment(eye, DVec3::new(300_000.0, 0.0, 8000.0));
        assert!(far < near && far >= 0.0 && far.is_finite(), "{near} {far}");
        let ground = atm.along_segment(eye, DVec3::new(400_000.0, 0.0, 0.0));
        assert!(ground.is_finite() && (0.0..=1.0).contains(&ground));
        assert!(atm.path_radiance(eye, DVec3::new(400_000.0, 0.0, 0.0)).unwrap().is_finite());
    }

    #[test]
    fn the_dome_has_no_step_at_the_horizon() {
        use crate::physics::sky::{Dome, DomeInputs, DomeSpec};
        let w = Weather { model: ModelAtmosphere::UsStandard1976, aerosol: Aerosol::Rural, visibility_km: 23.0 };
        for (lo, hi) in [(7.5, 13.5), (3.0, 5.0)] {
            let band = Band::try_new(lo, hi).unwrap();
            let atm = LowtranAtmosphere::new(w, band, Measure::Energy, 2000.0, 5778.0, PathSteps::STANDARD).unwrap();
            let clear = atm.clear_sky().unwrap();
            for lowtran_sky in [false, true] {
                let dome = Dome::new(&DomeInputs {
                    spec: DomeSpec::default(),
                    band,
                    measure: Measure::Energy,
                    observer_altitude_m: 2000.0,
                    air: crate::physics::atmosphere::AirTemperature::default(),
                    atmosphere: &atm,
                    zenith_emissivity: Some(1.0 - atm.zenith_transmittance()),
                    clear_sky: lowtran_sky.then_some(&clear),
                })
                .unwrap();
                let at = |deg: f64| {
                    let e = deg.to_radians();
                    f64::from(dome.radiance_toward(DVec3::new(0.0, e.cos(), e.sin())))
                };
                let dip = -atm.horizon_sin_e().asin().to_degrees();
                // no step: across the edge the radiance changes no more than the local gradient gives
                for edge in [0.0, -dip] {
                    let (above, below) = (at(edge + 0.02), at(edge - 0.02));
                    let gradient = (at(edge + 0.06) - above).abs().max((below - at(edge - 0.06)).abs());
                    assert!(
                        (above - below).abs() <= 1.5 * gradient + 0.002 * above,
                        "{lo}–{hi} µm, LOWTRAN sky {lowtran_sky}, at {edge:.3}°: {above} above, {below} below, \
                         {gradient} over the next 0.04°"
                    );
                }
            }
        }
    }

    /// Against direct LOWTRAN runs up to 100 km (the generator's `sky` runs), the LOWTRAN clear sky is closer than
    /// the parametric one, whose zenith emissivity comes from LOWTRAN's vertical path.
    #[test]
    fn the_lowtran_sky_is_closer_to_lowtran_than_the_parametric_one() {
        use crate::physics::planck::brightness_temperature;
        use crate::physics::sky::{Dome, DomeInputs, DomeSpec};
        let doc = crate::physics::lowtran::offgrid_runs();
        let band = Band::LWIR_8_12;
        let w = Weather { model: ModelAtmosphere::UsStandard1976, aerosol: Aerosol::Rural, visibility_km: 23.0 };
        let (mut lowtran_worst, mut parametric_worst) = (0.0f64, 0.0f64);
        for h in [0.0, 3.0, 10.0] {
            let atm =
                LowtranAtmosphere::new(w, band, Measure::Energy, h * 1000.0, 5778.0, PathSteps::STANDARD).unwrap();
            let clear = atm.clear_sky().unwrap();
            let dome = Dome::new(&DomeInputs {
                spec: DomeSpec::default(),
                band,
                measure: Measure::Energy,
                observer_altitude_m: h * 1000.0,
                air: crate::physics::atmosphere::AirTemperature::default(),
                atmosphere: &atm,
                zenith_emissivity: Some(1.0 - atm.zenith_transmittance()),
                clear_sky: None,
            })
            .unwrap();
            for r in doc["sky"].as_array().unwrap() {
                if r["model"] != "us_standard_1976"
                    || r["aerosol"] != "rural"
                    || r["observer_alt_km"].as_f64() != Some(h)
                {
                    continue;
                }
                let zenith = r["zenith_angle_deg"].as_f64().unwrap();
                let sin_e = (90.0 - zenith).to_radians().sin();
                let bt = |l: f64| brightness_temperature(Measure::Energy, band, l).unwrap();
                let want = bt(r["bands_um"]["8-12"]["path_radiance"].as_f64().unwrap() * 4.0);
                let lowtran = bt(clear.radiance(sin_e)) - want;
                let parametric = bt(f64::from(dome.radiance(sin_e))) - want;
                eprintln!("{h} km, zenith {zenith}°: LOWTRAN sky {lowtran:+.2} K, parametric {parametric:+.2} K");
                lowtran_worst = lowtran_worst.max(lowtran.abs());
                parametric_worst = parametric_worst.max(parametric.abs());
            }
        }
        eprintln!(
            "largest brightness-temperature error: LOWTRAN sky {lowtran_worst:.2} K, parametric {parametric_worst:.2} K"
        );
        assert!(lowtran_worst < parametric_worst);
    }

    #[test]
    fn a_band_outside_the_table_is_refused() {
        let band = Band::try_new(0.4, 0.7).unwrap();
        assert!(LowtranAtmosphere::new(W, band, Measure::Energy, 0.0, 5778.0, PathSteps::STANDARD).is_err());
        assert!(LowtranAtmosphere::new(W, lwir(), Measure::Energy, 25_000.0, 5778.0, PathSteps::STANDARD).is_err());
    }
}
