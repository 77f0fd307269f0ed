//! `irsim calc …`: one radiometric quantity from flags, printed as one JSON object.

use clap::{Args, Subcommand, ValueEnum};
use glam::{DMat3, DVec3};
use serde_json::{Value, json};

use crate::physics::atmosphere::AirTemperature;
use crate::physics::brdf::CookTorrance;
use crate::physics::lowtran::{Aerosol, AtmosphereError, AtmosphereTable, ModelAtmosphere, Weather};
use crate::physics::planck::{Band, band_radiance};
use crate::physics::reflection::{ReflectionGeometry, SphereQuadrature, Sun, direction_from_az_el};
use crate::physics::sensor::{GrayMapping, Radiometer};
use crate::physics::signal::{OwnedSignalContext, TargetState, target_signal};
use crate::physics::skin::{StagnationModel, self_radiance, skin_temperatures, speed_of_sound_m_s};
use crate::physics::transmittance::Transmittance;

use super::CliError;

/// Hand calculations.
#[derive(Debug, Subcommand)]
pub enum CalcCommand {
    /// Blackbody band radiance times emissivity (eq 3), W m⁻² sr⁻¹.
    BandRadiance(BandRadianceArgs),
    /// Ambient (eq 2) and stagnation skin temperature (eq 1), K.
    Skin(SkinArgs),
    /// Cook–Torrance BRDF (eqs 4–8), sr⁻¹.
    Brdf(BrdfArgs),
    /// The whole chain for one target: T∞, T_s, L_self, L_re, τ, V_s, gray.
    Signal(Box<SignalArgs>),
    /// A camera's figures of merit at a scene temperature: NETD, noise-equivalent radiance, electrons per DN,
    /// well fill, saturation temperature.
    Sensor(SensorArgs),
    /// Atmospheric transmittance and thermal path radiance of a slant path from the LOWTRAN7 table: band-average
    /// and spectrum-weighted τ, path radiance and the grid cell used.
    Transmittance(TransmittanceArgs),
    /// The clear sky's thermal radiance toward an elevation from the LOWTRAN7 table: the whole path up (down to a
    /// tangent point and up again below the horizontal), its band τ, radiance and brightness temperature.
    Sky(SkyArgs),
}

/// The LOWTRAN weather flags of `calc transmittance` and `calc sky`.
#[derive(Debug, Args)]
pub struct WeatherArgs {
    /// LOWTRAN model atmosphere.
    #[arg(long, value_enum, default_value = "midlatitude-summer")]
    pub model: ModelAtmosphere,
    /// Aerosol model.
    #[arg(long, value_enum, default_value = "rural")]
    pub aerosol: Aerosol,
    /// Visibility (meteorological range at sea level), km; ignored with `--aerosol none`.
    #[arg(long, default_value_t = 23.0, allow_negative_numbers = true)]
    pub visibility_km: f64,
}

impl WeatherArgs {
    /// The weather, its visibility checked to be finite.
    fn weather(&self) -> Result<Weather, CliError> {
        finite("visibility_km", self.visibility_km, true, "finite")?;
        Ok(Weather { model: self.model, aerosol: self.aerosol, visibility_km: self.visibility_km })
    }

    /// The weather's fields of the JSON answer.
    fn json(&self) -> serde_json::Map<String, Value> {
        let mut m = serde_json::Map::new();
        m.insert("model".into(), json!(self.model.name()));
        m.insert("aerosol".into(), json!(self.aerosol.name()));
        let vis = if self.aerosol == Aerosol::None { Value::Null } else { json!(self.visibility_km) };
        m.insert("visibility_km".into(), vis);
        m
    }
}

/// A table path's error as a flag's error, and a band outside the table's spectrum.
fn table_error(e: AtmosphereError) -> CliError {
    match e {
        AtmosphereError::OutsideGrid { name, value, range } => CliError::Invalid(format!(
            "--{}: {} is outside the LOWTRAN table's range {range}",
            name.replace('_', "-"),
            crate::physics::Num(value)
        )),
        // the built-in table itself (a damaged build), not the user's input
        AtmosphereError::Table(_) => CliError::Failed(e.to_string()),
        other => CliError::Invalid(other.to_string()),
    }
}

/// Refuses a band the table's spectrum does not cover.
fn check_covers(p: &crate::physics::lowtran::PathSpectrum, band: Band) -> Result<(), CliError> {
    if p.covers(band) {
        return Ok(());
    }
    Err(CliError::Invalid(format!(
        "--band-um: {}–{} µm is outside the table's 1–14 µm",
        crate::physics::Num(band.lo_um()),
        crate::physics::Num(band.hi_um())
    )))
}

/// Flags of `calc sky`.
#[derive(Debug, Args)]
pub struct SkyArgs {
    /// The weather.
    #[command(flatten)]
    pub weather: WeatherArgs,
    /// Observer's altitude, km.
    #[arg(long, allow_negative_numbers = true)]
    pub observer_alt_km: f64,
    /// Elevation of the view above the horizontal, degrees (negative: below it, down to the horizon's dip).
    #[arg(long, allow_negative_numbers = true)]
    pub elevation_deg: f64,
    /// Band bounds, µm: LO HI.
    #[arg(long, num_args = 2, value_names = ["LO", "HI"], default_values_t = [8.0, 12.0], allow_negative_numbers = true)]
    pub band_um: Vec<f64>,
}

/// Flags of `calc transmittance`.
#[derive(Debug, Args)]
pub struct TransmittanceArgs {
    /// The weather.
    #[command(flatten)]
    pub weather: WeatherArgs,
    /// Observer's altitude, km.
    #[arg(long, allow_negative_numbers = true)]
    pub observer_alt_km: f64,
    /// Target's altitude, km.
    #[arg(long, allow_negative_numbers = true)]
    pub target_alt_km: f64,
    /// Range between them (length of the line of sight), km.
    #[arg(long, allow_negative_numbers = true)]
    pub range_km: f64,
    /// Band bounds, µm: LO HI.
    #[arg(long, num_args = 2, value_names = ["LO", "HI"], default_values_t = [8.0, 12.0], allow_negative_numbers = true)]
    pub band_um: Vec<f64>,
    /// Target temperature for the spectrum-weighted τ, K.
    #[arg(long, default_value_t = 300.0, allow_negative_numbers = true)]
    pub temp_k: f64,
}

/// Flags of `calc sensor`.
#[derive(Debug, Args)]
pub struct SensorArgs {
    /// A camera preset: cooled_mwir_insb, uncooled_lwir_microbolometer, paper_lwir_256.
    #[arg(long, conflicts_with = "scenario")]
    pub preset: Option<String>,
    /// Or the `[sensor]` of a scenario file.
    #[arg(long)]
    pub scenario: Option<std::path::PathBuf>,
    /// Scene temperature (a blackbody filling the view), K.
    #[arg(long, default_value_t = 300.0, allow_negative_numbers = true)]
    pub scene_temp_k: f64,
}

/// Flags of `calc band-radiance`.
#[derive(Debug, Args)]
pub struct BandRadianceArgs {
    /// Temperature, K.
    #[arg(long, allow_negative_numbers = true)]
    pub temp_k: f64,
    /// Band bounds, µm: LO HI.
    #[arg(long, num_args = 2, value_names = ["LO", "HI"], allow_negative_numbers = true)]
    pub band_um: Vec<f64>,
    /// Emissivity, [0, 1].
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub emissivity: f64,
}

/// Flags of `calc skin`.
#[derive(Debug, Args)]
pub struct SkinArgs {
    /// Altitude, km.
    #[arg(long, allow_negative_numbers = true)]
    pub altitude_km: f64,
    /// Mach number.
    #[arg(long, allow_negative_numbers = true)]
    pub mach: f64,
    /// Sea-level temperature, K.
    #[arg(long, default_value_t = 288.15, allow_negative_numbers = true)]
    pub t0_k: f64,
    /// Recovery factor r of eq 1.
    #[arg(long, default_value_t = 0.87, allow_negative_numbers = true)]
    pub recovery: f64,
    /// Ratio of specific heats k of eq 1.
    #[arg(long, default_value_t = 1.3, allow_negative_numbers = true)]
    pub gamma: f64,
    /// Also print the skin's self-emitted radiance in this band, µm: LO HI.
    #[arg(long, num_args = 2, value_names = ["LO", "HI"], allow_negative_numbers = true)]
    pub band_um: Option<Vec<f64>>,
    /// Emissivity for the radiance, [0, 1].
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub emissivity: f64,
}

/// Flags of `calc brdf`.
#[derive(Debug, Args)]
pub struct BrdfArgs {
    /// Beckmann roughness m.
    #[arg(long, allow_negative_numbers = true)]
    pub roughness: f64,
    /// Reflectance at normal incidence.
    #[arg(long, default_value_t = 0.04, allow_negative_numbers = true)]
    pub f0: f64,
    /// Diffuse coefficient.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub kd: f64,
    /// Specular coefficient.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub ks: f64,
    /// Zenith angle of the view direction from the normal, degrees.
    #[arg(long, allow_negative_numbers = true)]
    pub view_zenith_deg: f64,
    /// Zenith angle of the light direction from the normal, degrees.
    #[arg(long, allow_negative_numbers = true)]
    pub light_zenith_deg: f64,
    /// Azimuth between view and light, degrees (180 = mirror side).
    #[arg(long, default_value_t = 180.0, allow_negative_numbers = true)]
    pub azimuth_deg: f64,
    /// Use the paper's facet form (normal = half vector) instead of the general form.
    #[arg(long)]
    pub facet: bool,
}

/// How to model the reflection in `calc signal`.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ReflectionArg {
    /// The paper's facet (normal = half vector).
    Facet,
    /// General form averaged over the ellipsoid's visible surface.
    Ellipsoid,
}

/// Flags of `calc signal`.
#[derive(Debug, Args)]
pub struct SignalArgs {
    /// Target altitude, km.
    #[arg(long, default_value_t = 8.0, allow_negative_numbers = true)]
    pub altitude_km: f64,
    /// Target Mach number.
    #[arg(long, default_value_t = 0.8, allow_negative_numbers = true)]
    pub mach: f64,
    /// Target heading, degrees clockwise from north.
    #[arg(long, default_value_t = 90.0, allow_negative_numbers = true)]
    pub heading_deg: f64,
    /// Ellipsoid semi-axes, m: along the velocity, across, up.
    #[arg(long, num_args = 3, value_names = ["A", "B", "C"], default_values_t = [6.0, 1.5, 1.5], allow_negative_numbers = true)]
    pub semi_axes_m: Vec<f64>,
    /// Skin emissivity.
    #[arg(long, default_value_t = 0.8, allow_negative_numbers = true)]
    pub emissivity: f64,
    /// Beckmann roughness.
    #[arg(long, default_value_t = 0.3, allow_negative_numbers = true)]
    pub roughness: f64,
    /// Reflectance at normal incidence.
    #[arg(long, default_value_t = 0.04, allow_negative_numbers = true)]
    pub f0: f64,
    /// Diffuse coefficient.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub kd: f64,
    /// Specular coefficient.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    pub ks: f64,
    /// Reflection model.
    #[arg(long, value_enum, default_value = "facet")]
    pub reflection: ReflectionArg,
    /// Range from sensor to target, km.
    #[arg(long, default_value_t = 5.0, allow_negative_numbers = true)]
    pub range_km: f64,
    /// Sensor altitude, km; the target lies due north of the sensor at the given range.
    #[arg(long, default_value_t = 8.0, allow_negative_numbers = true)]
    pub sensor_altitude_km: f64,
    /// Sea-level temperature, K.
    #[arg(long, default_value_t = 288.15, allow_negative_numbers = true)]
    pub t0_k: f64,
    /// Sensor band, µm: LO HI.
    #[arg(long, num_args = 2, value_names = ["LO", "HI"], default_values_t = [8.0, 12.0], allow_negative_numbers = true)]
    pub band_um: Vec<f64>,
    /// Sun azimuth, degrees clockwise from north.
    #[arg(long, default_value_t = 135.0, allow_negative_numbers = true)]
    pub sun_azimuth_deg: f64,
    /// Sun elevation, degrees.
    #[arg(long, default_value_t = 45.0, allow_negative_numbers = true)]
    pub sun_elevation_deg: f64,
    /// Fixed atmospheric transmittance (default 1 unless --extinction-per-km is given).
    #[arg(long, conflicts_with = "extinction_per_km", allow_negative_numbers = true)]
    pub tau: Option<f64>,
    /// Sea-level extinction coefficient, km⁻¹ (Beer–Lambert).
    #[arg(long, allow_negative_numbers = true)]
    pub extinction_per_km: Option<f64>,
    /// Scale height of the extinction, km.
    #[arg(long, default_value_t = 2.0, allow_negative_numbers = true)]
    pub scale_height_km: f64,
    /// Aperture diameter, mm.
    #[arg(long, default_value_t = 100.0, allow_negative_numbers = true)]
    pub aperture_mm: f64,
    /// Focal length, mm.
    #[arg(long, default_value_t = 100.0, allow_negative_numbers = true)]
    pub focal_mm: f64,
    /// Pixel pitch, µm.
    #[arg(long, default_value_t = 17.0, allow_negative_numbers = true)]
    pub pitch_um: f64,
    /// Optics transmittance.
    #[arg(long, default_value_t = 0.8, allow_negative_numbers = true)]
    pub optics_transmittance: f64,
    /// Responsivity, V/W.
    #[arg(long, default_value_t = 1e8, allow_negative_numbers = true)]
    pub responsivity_v_per_w: f64,
    /// Voltage at the lowest gray level, V.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub v_low: f64,
    /// Voltage at the highest gray level, V.
    #[arg(long, default_value_t = 2.0, allow_negative_numbers = true)]
    pub v_high: f64,
    /// Bit depth.
    #[arg(long, default_value_t = 16)]
    pub bit_depth: u32,
    /// Lowest gray level.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub g_min: f64,
    /// Highest gray level (default 2^bit_depth − 1).
    #[arg(long, allow_negative_numbers = true)]
    pub g_max: Option<f64>,
    /// Assume the target fills the pixel footprint, as the paper does (no sub-pixel fill factor).
    #[arg(long)]
    pub no_fill_factor: bool,
}

/// Runs a `calc` subcommand and returns the JSON it prints.
///
/// # Errors
/// [`CliError::Invalid`] for an input out of range.
pub fn run(cmd: &CalcCommand) -> Result<Value, CliError> {
    match cmd {
        CalcCommand::Sensor(a) => sensor(a),
        CalcCommand::BandRadiance(a) => {
            let band = band_from(&a.band_um)?;
            finite("temp_k", a.temp_k, a.temp_k >= 0.0 && a.temp_k <= 1e6, "[0, 1e6]")?;
            finite("emissivity", a.emissivity, (0.0..=1.0).contains(&a.emissivity), "[0, 1]")?;
            Ok(json!({ "radiance_w_m2_sr": band_radiance(band, a.temp_k, a.emissivity) }))
        }
        CalcCommand::Skin(a) => {
            let model = StagnationModel { recovery: a.recovery, gamma: a.gamma };
            let t =
                skin_temperatures(&model, a.altitude_km * 1000.0, a.mach, &AirTemperature::Standard { t0_k: a.t0_k })
                    .map_err(invalid)?;
            let mut out = json!({
                "ambient_temp_k": t.ambient_temp_k,
                "skin_temp_k": t.skin_temp_k,
                "speed_of_sound_m_s": speed_of_sound_m_s(t.ambient_temp_k),
            });
            if let Some(b) = &a.band_um {
                let l = self_radiance(band_from(b)?, t.skin_temp_k, a.emissivity).map_err(invalid)?;
                out["self_radiance_w_m2_sr"] = json!(l);
            }
            Ok(out)
        }
        CalcCommand::Brdf(a) => {
            let ct = CookTorrance { kd: a.kd, ks: a.ks, f0: a.f0, roughness: a.roughness };
            ct.validate().map_err(invalid)?;
            for (name, v) in [
                ("view_zenith_deg", a.view_zenith_deg),
                ("light_zenith_deg", a.light_zenith_deg),
                ("azimuth_deg", a.azimuth_deg),
            ] {
                finite(name, v, true, "finite")?;
            }
            let value = if a.facet {
                let v = crate::physics::brdf::direction_from_zenith(a.view_zenith_deg, 0.0);
                let l = crate::physics::brdf::direction_from_zenith(a.light_zenith_deg, a.azimuth_deg);
                ct.evaluate_facet(v, l)
            } else {
                ct.evaluate_angles(a.view_zenith_deg, a.light_zenith_deg, a.azimuth_deg)
            };
            Ok(serde_json::to_value(value).expect("plain struct serializes"))
        }
        CalcCommand::Signal(a) => signal(a),
        CalcCommand::Transmittance(a) => transmittance(a),
        CalcCommand::Sky(a) => sky(a),
    }
}

/// `calc transmittance`: one path through the LOWTRAN7 table.
fn transmittance(a: &TransmittanceArgs) -> Result<Value, CliError> {
    let band = band_from(&a.band_um)?;
    finite("temp_k", a.temp_k, a.temp_k > 0.0 && a.temp_k <= 1e4, "(0, 1e4]")?;
    for (name, v) in
        [("observer_alt_km", a.observer_alt_km), ("target_alt_km", a.target_alt_km), ("range_km", a.range_km)]
    {
        finite(name, v, true, "finite")?;
    }
    let weather = a.weather.weather()?;
    let table = AtmosphereTable::shipped().map_err(|e| CliError::Failed(e.to_string()))?;
    let p = table.path(&weather, a.observer_alt_km, a.target_alt_km, a.range_km).map_err(table_error)?;
    check_covers(&p, band)?;
    let mut out = json!({
        "observer_alt_km": a.observer_alt_km,
        "target_alt_km": a.target_alt_km,
        "range_km": a.range_km,
        "band_um": [band.lo_um(), band.hi_um()],
        "temp_k": a.temp_k,
        "transmittance_spectrum_weighted": p.spectrum_weighted(band, a.temp_k),
        "transmittance_band_average": p.band_average(band),
        "path_radiance_w_m2_sr": p.band_path_radiance_w_m2_sr(band),
        "path_radiance_band_mean_w_m2_sr_um": p.band_mean_path_radiance_w_m2_sr_um(band),
        "grid_cell": p.cell,
        "source": "LOWTRAN7 table assets/atmosphere/lowtran7.irat (built in)",
    });
    if let Some(fields) = out.as_object_mut() {
        fields.extend(a.weather.json());
    }
    Ok(out)
}

/// `calc sky`: the clear sky toward one elevation through the LOWTRAN7 table.
fn sky(a: &SkyArgs) -> Result<Value, CliError> {
    let band = band_from(&a.band_um)?;
    finite("observer_alt_km", a.observer_alt_km, true, "finite")?;
    finite("elevation_deg", a.elevation_deg, (-90.0..=90.0).contains(&a.elevation_deg), "[−90, 90]")?;
    let weather = a.weather.weather()?;
    let table = AtmosphereTable::shipped().map_err(|e| CliError::Failed(e.to_string()))?;
    let sin_e = a.elevation_deg.to_radians().sin();
    let lowest = crate::physics::lowtran::horizon_sin_e(a.observer_alt_km);
    if a.observer_alt_km >= 0.0 && sin_e < lowest {
        return Err(CliError::Invalid(format!(
            "--elevation-deg: {} looks at the ground from {} km; the horizon's dip there is {:.4}°",
            crate::physics::Num(a.elevation_deg),
            crate::physics::Num(a.observer_alt_km),
            lowest.asin().to_degrees()
        )));
    }
    let p = table.sky(&weather, a.observer_alt_km, sin_e).map_err(table_error)?;
    check_covers(&p, band)?;
    let radiance = p.band_path_radiance_w_m2_sr(band);
    let mut out = json!({
        "observer_alt_km": a.observer_alt_km,
        "elevation_deg": a.elevation_deg,
        "band_um": [band.lo_um(), band.hi_um()],
        "transmittance_band_average": p.band_average(band),
        "radiance_w_m2_sr": radiance,
        "radiance_band_mean_w_m2_sr_um": p.band_mean_path_radiance_w_m2_sr_um(band),
        "brightness_temp_k": crate::physics::planck::brightness_temperature(
            crate::physics::planck::Measure::Energy, band, radiance),
        "source": "LOWTRAN7 table assets/atmosphere/lowtran7.irat (built in): paths to 20 km chained, LOWTRAN's \
                   layers above seen through the observer's column",
    });
    if let Some(fields) = out.as_object_mut() {
        fields.extend(a.weather.json());
    }
    Ok(out)
}

fn signal(a: &SignalArgs) -> Result<Value, CliError> {
    let band = band_from(&a.band_um)?;
    for (name, v) in
        [("range_km", a.range_km), ("altitude_km", a.altitude_km), ("sensor_altitude_km", a.sensor_altitude_km)]
    {
        finite(name, v, true, "finite")?;
    }
    let dz = (a.altitude_km - a.sensor_altitude_km) * 1000.0;
    let range_m = a.range_km * 1000.0;
    finite("range_km", a.range_km, range_m > dz.abs(), "greater than the altitude difference")?;
    let sensor = DVec3::new(0.0, 0.0, a.sensor_altitude_km * 1000.0);
    let target_pos = sensor + DVec3::new(0.0, (range_m * range_m - dz * dz).sqrt(), dz);
    let axes = DVec3::from_slice(&a.semi_axes_m);
    if !axes.cmpgt(DVec3::ZERO).all() || !axes.is_finite() {
        return Err(CliError::Invalid(format!(
            "--semi-axes-m {:?}: each semi-axis must be a finite number > 0",
            a.semi_axes_m
        )));
    }
    finite("heading_deg", a.heading_deg, a.heading_deg.abs() <= 1e6, "[−1e6, 1e6]")?;
    let forward = direction_from_az_el(a.heading_deg, 0.0);
    let attitude = DMat3::from_cols(forward, DVec3::Z.cross(forward), DVec3::Z);
    let target = TargetState {
        position_m: target_pos,
        mach: a.mach,
        emissivity: a.emissivity,
        heating_k: 0.0,
        brdf: CookTorrance { kd: a.kd, ks: a.ks, f0: a.f0, roughness: a.roughness },
        semi_axes_m: axes,
        attitude,
    };
    finite("emissivity", a.emissivity, (0.0..=1.0).contains(&a.emissivity), "[0, 1]")?;
    let atmosphere = match (a.tau, a.extinction_per_km) {
        (_, Some(e)) => Transmittance::BeerLambert { extinction_per_km: e, scale_height_km: a.scale_height_km },
        (Some(tau), None) => Transmittance::Fixed { tau },
        (None, None) => Transmittance::Fixed { tau: 1.0 },
    };
    atmosphere.validate().map_err(invalid)?;
    let gray = GrayMapping {
        v_low: a.v_low,
        v_high: a.v_high,
        g_min: a.g_min,
        g_max: a.g_max.unwrap_or(((1u64 << a.bit_depth.min(32)) - 1) as f64),
        bit_depth: a.bit_depth,
    };
    let ctx = OwnedSignalContext {
        band,
        air: AirTemperature::Standard { t0_k: a.t0_k },
        stagnation: StagnationModel::default(),
        sun: Sun { azimuth_deg: a.sun_azimuth_deg, elevation_deg: a.sun_elevation_deg, ..Sun::default() },
        atmosphere,
        reflection: match a.reflection {
            ReflectionArg::Facet => ReflectionGeometry::Facet,
            ReflectionArg::Ellipsoid => ReflectionGeometry::Ellipsoid,
        },
        quadrature: {
            let [n_z, n_phi] = crate::scenario::Quality::default().reflection_grid;
            SphereQuadrature::new(n_z, n_phi)
        },
        radiometer: Radiometer {
            aperture_m: a.aperture_mm * 1e-3,
            focal_length_m: a.focal_mm * 1e-3,
            pixel_pitch_m: a.pitch_um * 1e-6,
            detector_fill: 1.0,
            optics_transmittance: a.optics_transmittance,
            responsivity_v_per_w: a.responsivity_v_per_w,
        },
        gray,
        fill_factor: !a.no_fill_factor,
    };
    let s = target_signal(&target, sensor, &ctx.as_context()).map_err(invalid)?;
    Ok(serde_json::to_value(s).expect("plain struct serializes"))
}

fn band_from(v: &[f64]) -> Result<Band, CliError> {
    Band::try_new(v[0], v[1]).map_err(|e| CliError::Invalid(format!("--band-um: {e}")))
}

fn finite(name: &str, value: f64, ok: bool, range: &str) -> Result<(), CliError> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(CliError::Invalid(format!(
            "--{}: {} is outside the allowed range {range}",
            name.replace('_', "-"),
            crate::physics::Num(value)
        )))
    }
}

fn invalid(e: impl std::fmt::Display) -> CliError {
    CliError::Invalid(e.to_string())
}

/// `calc sensor`: the resolved camera and its [`crate::physics::detector::SensorReport`].
fn sensor(a: &SensorArgs) -> Result<Value, CliError> {
    use crate::physics::detector::Preset;
    finite("scene_temp_k", a.scene_temp_k, (100.0..=2000.0).contains(&a.scene_temp_k), "[100, 2000]")?;
    let resolved = match (&a.preset, &a.scenario) {
        (Some(name), None) => {
            let Some(preset) = Preset::ALL.iter().copied().find(|p| p.name() == name) else {
                let names: Vec<_> = Preset::ALL.iter().map(|p| p.name()).collect();
                return Err(CliError::Invalid(format!("--preset `{name}` is not one of {}", names.join(", "))));
            };
            crate::scenario::SensorSpec { preset: Some(preset), ..Default::default() }
                .resolve(&crate::scenario::Quality::default())
                .map_err(|e| CliError::Invalid(format!("{}: {}", e.path, e.message)))?
        }
        (None, Some(path)) => crate::scenario::load(path).map_err(|e| CliError::Invalid(e.to_string()))?.sensor,
        _ => return Err(CliError::Invalid("give --preset NAME or --scenario FILE".into())),
    };
    let m = &resolved.model;
    let report = m.report(a.scene_temp_k);
    Ok(json!({
        "width": resolved.intrinsics.width,
        "height": resolved.intrinsics.height,
        "pixel_pitch_um": m.detector.pixel_pitch_m * 1e6,
        "focal_length_mm": m.optics.focal_length_m * 1e3,
        "aperture_mm": m.optics.aperture_m * 1e3,
        "ifov_urad": resolved.intrinsics.pixel_pitch_m / resolved.intrinsics.focal_length_m * 1e6,
        "band_um": [m.band.lo_um(), m.band.hi_um()],
        "detector": format!("{:?}", m.detector.kind).to_lowercase(),
        "optics_transmittance": m.optics.transmittance,
        "fill_factor": m.detector.fill_factor,
        "quantum_efficiency": m.detector.quantum_efficiency,
        "integration_time_s": m.detector.integration_time_s,
        "well_capacity_e": m.detector.well_capacity_e,
        "bit_depth": m.adc.bit_depth,
        "offset_dn": m.adc.offset_dn,
        "report": report,
    }))
}
