//! The atmosphere rows of `irsim bench report`: the LOWTRAN7 table's interpolation against direct LOWTRAN runs
//! off its grid, the time per path, and the spectrum-weighted against the band-average transmittance.

use std::fmt::Write as _;
use std::time::Instant;

use crate::physics::lowtran::{Aerosol, AtmosphereTable, ModelAtmosphere, Weather};
use crate::physics::planck::Band;

use super::report::median;

/// The generator's direct runs off the table's grid.
const OFFGRID: &str = include_str!("../../assets/atmosphere/lowtran7_offgrid.json");

/// One direct run and the table's value for it.
struct Row {
    band: &'static str,
    lowtran: f64,
    first_try: Option<f64>,
    table: f64,
    radiance_ratio: Option<f64>,
}

/// The weather of one of the generator's runs (`None` if a field is missing or unknown).
fn weather(r: &serde_json::Value) -> Option<Weather> {
    Some(Weather {
        model: serde_json::from_value(r["model"].clone()).ok()?,
        aerosol: serde_json::from_value(r["aerosol"].clone()).ok()?,
        visibility_km: r["visibility_km"].as_f64()?,
    })
}

fn rows(table: &AtmosphereTable) -> Result<(Vec<Row>, Vec<f64>), String> {
    let doc: serde_json::Value = serde_json::from_str(OFFGRID).map_err(|e| e.to_string())?;
    let runs = doc["runs"].as_array().ok_or("no runs")?;
    let mut rows = Vec::new();
    let mut micros = Vec::new();
    for r in runs {
        let w = weather(r).ok_or_else(|| format!("a run's model, aerosol or visibility is not readable: {r}"))?;
        let num = |k: &str| r[k].as_f64().ok_or_else(|| format!("{k} missing"));
        let t = Instant::now();
        let p = table
            .path(&w, num("observer_alt_km")?, num("target_alt_km")?, num("range_km")?)
            .map_err(|e| e.to_string())?;
        micros.push(t.elapsed().as_secs_f64() * 1e6);
        for (key, band) in [("3-5", Band::MWIR_3_5), ("8-12", Band::LWIR_8_12)] {
            let b = &r["bands_um"][key];
            let lr = b["path_radiance"].as_f64().unwrap_or(0.0);
            rows.push(Row {
                band: if key == "3-5" { "3–5 µm" } else { "8–12 µm" },
                lowtran: b["transmittance"].as_f64().ok_or("transmittance missing")?,
                first_try: r["first_try_bands_um"][key]["transmittance"].as_f64(),
                table: p.band_average(band),
                radiance_ratio: (lr > 0.05).then(|| p.band_mean_path_radiance_w_m2_sr_um(band) / lr),
            });
        }
    }
    Ok((rows, micros))
}

/// Appends the section to the report.
pub fn section(md: &mut String) {
    let _ = writeln!(md, "## Atmosphere: the LOWTRAN7 table\n");
    let table = match AtmosphereTable::shipped() {
        Ok(t) => t,
        Err(e) => {
            let _ = writeln!(md, "Not measured: {e}\n");
            return;
        }
    };
    let (rows, mut micros) = match rows(table) {
        Ok(r) => r,
        Err(e) => {
            let _ = writeln!(md, "Not measured: the off-grid runs could not be read ({e})\n");
            return;
        }
    };
    let _ = writeln!(
        md,
        "`irsim calc transmittance` and the `lowtran` atmosphere interpolate the table (`assets/atmosphere/`, made \
         by `tools/atmosphere/lowtran_tables.py`). Against the {} direct LOWTRAN7 runs off its grid that the \
         generator commits (every model atmosphere, aerosol and visibility, including visibilities between the \
         tabulated ones; paths up to 15 km altitude and 50 km range), band-average transmittance (uniform in \
         wavenumber, as LOWTRAN samples). \"LOWTRAN's first try\": LOWTRAN's value at the range asked, whose \
         refracted path can be several percent longer or shorter near the horizontal; the table and the direct \
         runs are for paths of the range asked. Path radiance: mean per µm over the band, runs above 0.05 W m⁻² \
         sr⁻¹ µm⁻¹.\n",
        rows.len() / 2
    );
    let _ = writeln!(
        md,
        "| band | runs | max \\|Δτ\\| | rms Δτ | max \\|Δτ\\| against LOWTRAN's first try | path radiance, median / max relative error |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|");
    for band in ["3–5 µm", "8–12 µm"] {
        let sel: Vec<&Row> = rows.iter().filter(|r| r.band == band).collect();
        let d: Vec<f64> = sel.iter().map(|r| (r.table - r.lowtran).abs()).collect();
        let max = d.iter().copied().fold(0.0, f64::max);
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len().max(1) as f64).sqrt();
        let first = sel.iter().filter_map(|r| r.first_try.map(|f| (r.table - f).abs())).fold(0.0, f64::max);
        let mut rel: Vec<f64> = sel.iter().filter_map(|r| r.radiance_ratio.map(|x| (x - 1.0).abs())).collect();
        let rmax = rel.iter().copied().fold(0.0, f64::max);
        let _ = writeln!(
            md,
            "| {band} | {} | {max:.4} | {rms:.4} | {first:.4} | {:.1} % / {:.1} % |",
            sel.len(),
            100.0 * median(&mut rel),
            100.0 * rmax
        );
    }
    let _ = writeln!(
        md,
        "\nOne path (spectral transmittance and path radiance on 108 bins): median {:.0} µs.\n",
        median(&mut micros)
    );

    let _ = writeln!(
        md,
        "Spectrum-weighted transmittance `∫τ B_λ(T) dλ / ∫B_λ(T) dλ` (what multiplies a gray target's band \
         radiance) against the band average, mid-latitude summer, rural 23 km:\n"
    );
    let _ = writeln!(md, "| path | band | band average | 250 K | 300 K | 500 K | 1000 K |");
    let _ = writeln!(md, "|---|---|---|---|---|---|---|");
    let w = Weather { model: ModelAtmosphere::MidlatitudeSummer, aerosol: Aerosol::Rural, visibility_km: 23.0 };
    for (label, h1, h2, r) in
        [("1 → 1 km, 10 km", 1.0, 1.0, 10.0), ("0 → 8 km, 30 km", 0.0, 8.0, 30.0), ("8 → 8 km, 4 km", 8.0, 8.0, 4.0)]
    {
        let Ok(p) = table.path(&w, h1, h2, r) else { continue };
        for (name, band) in [("3–5 µm", Band::MWIR_3_5), ("8–12 µm", Band::LWIR_8_12)] {
            let _ = write!(md, "| {label} | {name} | {:.4} |", p.band_average(band));
            for t in [250.0, 300.0, 500.0, 1000.0] {
                let _ = write!(md, " {:.4} |", p.spectrum_weighted(band, t));
            }
            let _ = writeln!(md);
        }
    }
    let _ = writeln!(md);
    sky_section(md, table);
    steps_section(md, table);
}

/// One geometry of the generator's direct runs: a line of sight `(observer km, target km, range km)` or a sky ray
/// `(observer km, sine of the elevation)`.
enum Geometry {
    Line(f64, f64, f64),
    Sky(f64, f64),
}

/// `[quality] atmosphere_steps`: each preset's steps against the reference's on the generator's lines of sight and
/// sky rays, with the time per path.
fn steps_section(md: &mut String, table: &AtmosphereTable) {
    use crate::physics::lowtran::{PathSpectrum, PathSteps};
    use crate::scenario::{Quality, QualityPreset};
    let Ok(doc) = serde_json::from_str::<serde_json::Value>(OFFGRID) else { return };
    let mut cases: Vec<(Weather, Geometry)> = Vec::new();
    for (key, sky) in [("runs", false), ("sky", true)] {
        for r in doc[key].as_array().map_or(&[][..], |v| &v[..]) {
            let (Some(w), Some(h)) = (weather(r), r["observer_alt_km"].as_f64()) else { continue };
            let geometry = if sky {
                let Some(zenith) = r["zenith_angle_deg"].as_f64() else { continue };
                Geometry::Sky(h, (90.0 - zenith).to_radians().sin())
            } else {
                let (Some(h2), Some(range)) = (r["target_alt_km"].as_f64(), r["range_km"].as_f64()) else { continue };
                Geometry::Line(h, h2, range)
            };
            cases.push((w, geometry));
        }
    }
    let all = 0..table.edges_um().len() - 1;
    let run = |w: &Weather, g: &Geometry, steps: PathSteps| -> Option<(PathSpectrum, f64)> {
        let t = Instant::now();
        let p = match *g {
            Geometry::Line(h1, h2, r) => table.path_in(w, h1, h2, r, all.clone(), steps).ok()?,
            Geometry::Sky(h, sin_e) => table.sky_in(w, h, sin_e, all.clone(), steps).ok()?,
        };
        Some((p, t.elapsed().as_secs_f64() * 1e6))
    };
    let bands = [Band::MWIR_3_5, Band::LWIR_8_12];
    let reference: Vec<Option<PathSpectrum>> =
        cases.iter().map(|(w, g)| run(w, g, PathSteps::REFERENCE).map(|x| x.0)).collect();
    let _ = writeln!(
        md,
        "Steps of the path integrals (`[quality] atmosphere_steps` = [aerosol trapezoids, path-radiance segments]) \
         against the reference's, on the same {} lines of sight and {} sky rays: the largest relative error of the \
         band path radiance (runs whose path radiance is above 1e-3 W m⁻² sr⁻¹ µm⁻¹) and the largest |Δτ| of the \
         band-average transmittance (all runs), 3–5 and 8–12 µm, and the median time per path (108 bins).\n",
        cases.iter().filter(|c| matches!(c.1, Geometry::Line(..))).count(),
        cases.iter().filter(|c| matches!(c.1, Geometry::Sky(..))).count(),
    );
    let _ = writeln!(
        md,
        "| preset | steps | line of sight: µs, max path radiance error, max \\|Δτ\\| | sky ray: µs, max path radiance \
         error, max \\|Δτ\\| |\n|---|---|---|---|"
    );
    for p in [QualityPreset::Reference, QualityPreset::Standard, QualityPreset::Draft] {
        let steps = Quality::preset(p).path_steps();
        // [line, sky]: (µs, relative path radiance error, |Δτ|)
        let mut stats: [(Vec<f64>, f64, f64); 2] = Default::default();
        for ((w, g), exact) in cases.iter().zip(&reference) {
            let (Some((got, micros)), Some(exact)) = (run(w, g, steps), exact) else { continue };
            let s = &mut stats[usize::from(matches!(g, Geometry::Sky(..)))];
            s.0.push(micros);
            for band in bands {
                let want = exact.band_mean_path_radiance_w_m2_sr_um(band);
                if want > 1e-3 {
                    s.1 = s.1.max((got.band_mean_path_radiance_w_m2_sr_um(band) / want - 1.0).abs());
                }
                s.2 = s.2.max((got.band_average(band) - exact.band_average(band)).abs());
            }
        }
        let cell = |s: &mut (Vec<f64>, f64, f64)| format!("{:.0}, {:.2e}, {:.1e}", median(&mut s.0), s.1, s.2);
        let [line, sky] = &mut stats;
        let _ =
            writeln!(md, "| {} | [{}, {}] | {} | {} |", p.name(), steps.aerosol, steps.radiance, cell(line), cell(sky));
    }
    let _ = writeln!(md);
}

/// The clear sky (`sky.dome.clear_sky = "lowtran"`) against the generator's direct LOWTRAN runs up to 100 km.
fn sky_section(md: &mut String, table: &AtmosphereTable) {
    use crate::physics::planck::{Measure, brightness_temperature};
    let Ok(doc) = serde_json::from_str::<serde_json::Value>(OFFGRID) else { return };
    let Some(runs) = doc["sky"].as_array() else {
        let _ = writeln!(md, "Clear sky: not measured (the off-grid file has no sky runs).\n");
        return;
    };
    // (band, low elevation, observer above 3 km) -> (ΔT_b K, Δτ) of each run
    type Group<'a> = (&'a str, bool, bool);
    let mut groups: std::collections::BTreeMap<Group<'_>, Vec<(f64, f64)>> = Default::default();
    let mut micros = Vec::new();
    for r in runs {
        let (Some(w), Some(h), Some(zenith)) =
            (weather(r), r["observer_alt_km"].as_f64(), r["zenith_angle_deg"].as_f64())
        else {
            continue;
        };
        let t = Instant::now();
        let Ok(p) = table.sky(&w, h, (90.0 - zenith).to_radians().sin()) else { continue };
        micros.push(t.elapsed().as_secs_f64() * 1e6);
        for (key, name, band) in [("3-5", "3–5 µm", Band::MWIR_3_5), ("8-12", "8–12 µm", Band::LWIR_8_12)] {
            let width = band.hi_um() - band.lo_um();
            let (Some(l), Some(tau)) =
                (r["bands_um"][key]["path_radiance"].as_f64(), r["bands_um"][key]["transmittance"].as_f64())
            else {
                continue;
            };
            let bt = |x: f64| brightness_temperature(Measure::Energy, band, x);
            let (Some(want), Some(got)) = (bt(l * width), bt(p.band_mean_path_radiance_w_m2_sr_um(band) * width))
            else {
                continue;
            };
            groups.entry((name, zenith > 75.0, h > 3.0)).or_default().push((got - want, p.band_average(band) - tau));
        }
    }
    let _ = writeln!(
        md,
        "Clear sky (`sky.dome.clear_sky = \"lowtran\"`, `irsim calc sky`): the ray from the observer up to the table's \
         top in pieces of at most 100 km chained bin by bin, LOWTRAN's layers from 20 to 100 km seen through the \
         observer's own vertical column and stretched to the ray. Against the generator's {} direct LOWTRAN7 runs from the observer up to 100 km (six model \
         atmospheres, no aerosol and rural 23 km, observers at 0–15 km, zenith angles 0–91.5°), brightness \
         temperature of the band radiance and band-average τ. Chaining the pieces and the layers above the top \
         ignores how the lines of one piece correlate with the next, so τ comes out low and the radiance high, most \
         on long and high paths. One sky path: median {:.0} µs.\n",
        runs.len(),
        median(&mut micros)
    );
    let _ = writeln!(md, "| band | elevation | observer | runs | max \\|ΔT\\| | median ΔT | max \\|Δτ\\| |");
    let _ = writeln!(md, "|---|---|---|---|---|---|---|");
    for ((band, low, high), v) in &groups {
        let max_t = v.iter().map(|x| x.0.abs()).fold(0.0, f64::max);
        let mut dt: Vec<f64> = v.iter().map(|x| x.0).collect();
        let max_tau = v.iter().map(|x| x.1.abs()).fold(0.0, f64::max);
        let _ = writeln!(
            md,
            "| {band} | {} | {} | {} | {max_t:.2} K | {:+.2} K | {max_tau:.4} |",
            if *low { "below 15°" } else { "15° and above" },
            if *high { "6–15 km" } else { "0–3 km" },
            v.len(),
            median(&mut dt)
        );
    }
    let _ = writeln!(md);
}
