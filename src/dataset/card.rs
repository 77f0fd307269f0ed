//! The dataset card: `README.md` in the dataset's directory, with counts per set, class and camera, what the
//! spec asked for beside what the frames hold, and histograms (SNR, target size, range, class) as PNG plots in
//! `card/`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;

use super::{DatasetSpec, Set, TargetClass};

/// Registers the bundled font the plots draw their text with (no system fonts needed).
pub fn register_plot_font() {
    let _ = plotters::style::register_font(
        "sans-serif",
        FontStyle::Normal,
        include_bytes!("../../assets/fonts/DejaVuSans.ttf"),
    );
}

/// Ticks at 1, 2 and 5 times the powers of ten in `[lo, hi]`: a log axis spanning little more than a decade
/// otherwise has one or two labels.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
        return Vec::new();
    }
    let mut ticks = Vec::new();
    for k in lo.log10().floor() as i32..=hi.log10().ceil() as i32 {
        for m in [1, 2, 5] {
            // parsed from decimal text, so that a tick prints as "0.005", not "0.005000000000000001"
            let v: f64 = format!("{m}e{k}").parse().unwrap_or(f64::NAN);
            if v >= lo && v <= hi {
                ticks.push(v);
            }
        }
    }
    ticks
}

/// One annotation as the card counts it.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    /// Index in [`TargetClass::ALL`].
    pub class: usize,
    /// Peak over the temporal noise.
    pub snr: f64,
    /// Mask pixels.
    pub size_px: f64,
    /// Distance from the camera, m.
    pub range_m: f64,
    /// Height above the ground, m.
    pub altitude_m: f64,
    /// SNR at least the scenario's detection threshold.
    pub detectable: bool,
    /// In its sequence's middle frame (where a spec's `snr` and the class altitudes are asked).
    pub middle: bool,
}

/// Counts and distributions of a dataset.
#[derive(Debug, Default)]
pub struct Stats {
    /// Per set: sequences, frames, annotations.
    sets: BTreeMap<Set, (u64, u64, u64)>,
    /// Per class: annotations, and the sequences it appears in.
    classes: Vec<(u64, u64)>,
    /// Per class: the altitudes of its annotations, and of those in the middle frames.
    altitudes: Vec<(Vec<f64>, Vec<f64>)>,
    /// Sequences per camera preset.
    sensors: BTreeMap<String, u64>,
    snr: Vec<f64>,
    snr_middle: Vec<f64>,
    size_px: Vec<f64>,
    range_m: Vec<f64>,
    detectable: u64,
}

impl Stats {
    /// From each sequence's set, camera, annotations and frame count.
    pub fn gather<'a>(seqs: impl Iterator<Item = (Set, &'a str, Vec<Sample>, u64)>) -> Self {
        let n = TargetClass::ALL.len();
        let mut s = Self { classes: vec![(0, 0); n], altitudes: vec![Default::default(); n], ..Self::default() };
        for (set, sensor, samples, frames) in seqs {
            let e = s.sets.entry(set).or_default();
            e.0 += 1;
            e.1 += frames;
            e.2 += samples.len() as u64;
            *s.sensors.entry(sensor.to_owned()).or_default() += 1;
            let mut seen = vec![false; TargetClass::ALL.len()];
            for a in samples {
                s.classes[a.class].0 += 1;
                seen[a.class] = true;
                s.snr.push(a.snr);
                s.altitudes[a.class].0.push(a.altitude_m);
                if a.middle {
                    s.snr_middle.push(a.snr);
                    s.altitudes[a.class].1.push(a.altitude_m);
                }
                s.size_px.push(a.size_px);
                s.range_m.push(a.range_m);
                s.detectable += u64::from(a.detectable);
            }
            for (c, seen) in s.classes.iter_mut().zip(seen) {
                c.1 += u64::from(seen);
            }
        }
        s
    }
}

/// The `q` quantile of `v` (sorted here), nearest rank.
fn quantile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((q * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)]
}

/// A number for the card: 3 significant figures.
fn sig(v: f64) -> String {
    if !v.is_finite() {
        return "–".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.digits$}")
}

/// Writes `README.md` and `card/*.png` into `dir`.
///
/// # Errors
/// A message naming the file that could not be written.
pub fn write(dir: &Path, spec: &DatasetSpec, st: &Stats) -> Result<(), String> {
    register_plot_font();
    let card = dir.join("card");
    std::fs::create_dir_all(&card).map_err(|e| format!("{}: {e}", card.display()))?;
    let frames: u64 = st.sets.values().map(|v| v.1).sum();
    let annotations: u64 = st.sets.values().map(|v| v.2).sum();
    histogram(
        &card.join("snr.png"),
        "Signal-to-noise ratio of the targets in frame",
        "SNR (peak over temporal σ)",
        &st.snr,
        true,
    )?;
    histogram(&card.join("size.png"), "Target size", "mask pixels", &st.size_px, true)?;
    histogram(&card.join("range.png"), "Range from the camera", "range, m", &st.range_m, false)?;
    bars(
        &card.join("class.png"),
        "Annotations per class",
        &TargetClass::ALL.iter().zip(&st.classes).map(|(c, n)| (c.name.to_owned(), n.0)).collect::<Vec<_>>(),
    )?;

    let mut md = String::new();
    let _ = writeln!(md, "# Dataset `{}`\n", spec.name);
    let _ = writeln!(
        md,
        "Synthetic infrared sequences of airborne targets, drawn and recorded by irsim {} from `spec.toml` (seed {}): {} sequences of {} frames at {} Hz, {frames} frames, {annotations} annotated targets in frame ({} with SNR at least their scenario's detection threshold).\n",
        env!("CARGO_PKG_VERSION"),
        spec.seed,
        spec.sequences,
        spec.frames,
        spec.frame_rate_hz,
        st.detectable
    );
    let _ = writeln!(
        md,
        "Every sequence is `sequences/seq_NNNNNN/` with the scenario it was drawn as (`scenario.toml`: record it again with `irsim record`, or open it with `irsim view`), its 16-bit frames, target masks, `labels.jsonl` and `gt_mot.txt`. The whole dataset is made again, byte for byte, by `irsim dataset spec.toml --out DIR`; `sha256sum -c checksums.sha256` checks every file.\n"
    );
    md.push_str("## Sets\n\nWhole sequences go to one set each.\n\n| set | sequences | frames | annotations |\n|---|---:|---:|---:|\n");
    for set in Set::ALL {
        let (n, f, a) = st.sets.get(&set).copied().unwrap_or_default();
        let _ = writeln!(md, "| {} | {n} | {f} | {a} |", set.name());
    }
    md.push_str(
        "\n## Classes\n\nAltitudes above the ground (5th percentile, median, 95th percentile of the annotations), \
         and how many targets of the middle frames fly within their class's altitudes",
    );
    md.push_str(if spec.class_altitudes {
        " (asked: each target is placed within them where its view reaches them).\n\n"
    } else {
        " (not asked: `class_altitudes = false`).\n\n"
    });
    md.push_str("| class | annotations | sequences | altitude, m | p5 | median | p95 | middle frames within |\n|---|---:|---:|---|---:|---:|---:|---:|\n");
    for ((c, (a, s)), (alts, middle)) in TargetClass::ALL.iter().zip(&st.classes).zip(&st.altitudes) {
        if *a > 0 || spec.classes.iter().any(|n| n == c.name) {
            let [lo, hi] = c.altitude_m;
            let within = middle.iter().filter(|&&z| z >= lo - 1.0 && z <= hi + 1.0).count();
            let _ = writeln!(
                md,
                "| `{}` | {a} | {s} | {lo} – {hi} | {} | {} | {} | {within} of {} |",
                c.name,
                sig(quantile(alts, 0.05)),
                sig(quantile(alts, 0.5)),
                sig(quantile(alts, 0.95)),
                middle.len()
            );
        }
    }
    md.push_str("\n![annotations per class](card/class.png)\n\n## Cameras\n\n| preset | sequences |\n|---|---:|\n");
    for (sensor, n) in &st.sensors {
        let _ = writeln!(md, "| `{sensor}` | {n} |");
    }
    md.push_str("\n## Distributions\n\nOver the annotated targets (5th percentile, median, 95th percentile):\n\n| quantity | spec | p5 | median | p95 |\n|---|---|---:|---:|---:|\n");
    let row = |md: &mut String, name: &str, asked: String, v: &[f64]| {
        let _ = writeln!(
            md,
            "| {name} | {asked} | {} | {} | {} |",
            sig(quantile(v, 0.05)),
            sig(quantile(v, 0.5)),
            sig(quantile(v, 0.95))
        );
    };
    row(&mut md, "SNR", "–".into(), &st.snr);
    if let Some([a, b]) = spec.snr {
        // the solve reaches the asked SNR within 1 %, or stops at an end of range_m
        let inside = st.snr_middle.iter().filter(|&&v| v >= a * 0.99 && v <= b * 1.01).count();
        let draw = match spec.snr_draw {
            super::SnrDraw::Uniform => "uniform",
            super::SnrDraw::LogUniform => "log-uniform",
        };
        row(
            &mut md,
            "SNR at the middle frames",
            format!("{a} – {b} ({draw}); {inside} of {} targets there within it", st.snr_middle.len()),
            &st.snr_middle,
        );
    }
    row(&mut md, "size, mask pixels", "–".into(), &st.size_px);
    let [r0, r1] = spec.range_m();
    let placed = if spec.snr.is_some() { "solved for the SNR within" } else { "at each sequence's middle:" };
    row(&mut md, "range, m", format!("{placed} {r0} – {r1}"), &st.range_m);
    md.push_str("\n![SNR](card/snr.png)\n\n![size](card/size.png)\n\n![range](card/range.png)\n\n");
    md.push_str(
        "## Files\n\n| path | format |\n|---|---|\n\
         | `coco/{all,train,val,test}.json` | COCO detection: boxes `[x, y, w, h]` in 0-based pixels, `area` and `segmentation` (uncompressed RLE) from the masks, `track_id`, and per-target `attributes` (class, SNR, SCR, range, peak DN, contrast, sequence, frame); `file_name` is relative to this folder |\n\
         | `yolo/data.yaml`, `yolo/{images,labels}/<set>/` | YOLO: `class x_center y_center width height` divided by the image size, one file per frame |\n\
         | `sirst/{images,masks}/`, `sirst/{train,val,test}.txt` | single-frame infrared small-target layout: binary masks (0, 255) beside the frames, split files of image names |\n\
         | `mot/<set>/seq_NNNNNN/` | MOTChallenge: `img1/` (frames from 000001), `gt/gt.txt` (1-based pixels), `seqinfo.ini` |\n\
         | `splits/{train,val,test}.txt` | the sequences of each set |\n\
         | `manifest.json`, `checksums.sha256` | program version, spec hash, counts; SHA-256 of every file |\n\n\
         Image folders in the exports are hard links to the sequences' frames (copies where the file system has none).\n",
    );
    let path = dir.join("README.md");
    std::fs::write(&path, md).map_err(|e| format!("{}: {e}", path.display()))
}

/// A histogram of `values` (20 bins; logarithmic when `log` and every value is positive) as a PNG.
fn histogram(path: &Path, title: &str, x_desc: &str, values: &[f64], log: bool) -> Result<(), String> {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite() && (!log || *v > 0.0)).collect();
    let (lo, hi) = finite.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let (lo, hi) = if finite.is_empty() {
        (1.0, 10.0)
    } else if hi > lo {
        (lo, hi)
    } else {
        (lo * 0.9 - 0.5, hi * 1.1 + 0.5)
    };
    let (lo, hi) = if log { (lo.max(1e-3), hi.max(lo.max(1e-3) * 1.01)) } else { (lo, hi) };
    let bins = 20usize;
    let (a, b) = if log { (lo.log10(), hi.log10()) } else { (lo, hi) };
    let mut counts = vec![0u64; bins];
    for &v in &finite {
        let x = if log { v.max(lo).log10() } else { v };
        let i = (((x - a) / (b - a)) * bins as f64).floor().clamp(0.0, (bins - 1) as f64) as usize;
        counts[i] += 1;
    }
    let edge = |i: usize| {
        let x = a + (b - a) * i as f64 / bins as f64;
        if log { 10f64.powf(x) } else { x }
    };
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64 * 1.1;
    let bar =
        |i: usize| Rectangle::new([(edge(i), 0.0), (edge(i + 1), counts[i] as f64)], RGBColor(40, 100, 170).filled());
    draw(path, |root| {
        let mut b = ChartBuilder::on(root);
        b.caption(title, ("sans-serif", 22)).margin(16).x_label_area_size(50).y_label_area_size(70);
        // the two axis kinds are two types: the same drawing for each
        macro_rules! finish {
            ($c:expr) => {{
                let mut c = $c.map_err(|e| e.to_string())?;
                c.configure_mesh()
                    .x_desc(x_desc)
                    .y_desc("targets × frames")
                    .y_label_formatter(&|v| format!("{v:.0}"))
                    .x_label_formatter(&|v| if log { format!("{v}") } else { sig(*v) })
                    .label_style(("sans-serif", 15))
                    .axis_desc_style(("sans-serif", 17))
                    .draw()
                    .map_err(|e| e.to_string())?;
                c.draw_series((0..bins).map(bar)).map_err(|e| e.to_string())?;
            }};
        }
        if log {
            finish!(b.build_cartesian_2d((lo..hi).log_scale().with_key_points(log_ticks(lo, hi)), 0.0..top));
        } else {
            finish!(b.build_cartesian_2d(lo..hi, 0.0..top));
        }
        Ok(())
    })
}

/// A bar chart of counts by name.
fn bars(path: &Path, title: &str, items: &[(String, u64)]) -> Result<(), String> {
    let top = items.iter().map(|i| i.1).max().unwrap_or(0).max(1) as f64 * 1.15;
    let n = items.len();
    draw(path, |root| {
        let mut c = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(16)
            .x_label_area_size(50)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..n as f64, 0.0..top)
            .map_err(|e| e.to_string())?;
        c.configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc("targets × frames")
            .y_label_formatter(&|v| format!("{v:.0}"))
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()
            .map_err(|e| e.to_string())?;
        c.draw_series(items.iter().enumerate().map(|(i, (_, v))| {
            Rectangle::new([(i as f64 + 0.15, 0.0), (i as f64 + 0.85, *v as f64)], RGBColor(40, 100, 170).filled())
        }))
        .map_err(|e| e.to_string())?;
        for (i, (name, v)) in items.iter().enumerate() {
            let at = |dy: f64| (i as f64 + 0.12, *v as f64 + top * dy);
            c.draw_series([
                Text::new(name.clone(), at(0.075), ("sans-serif", 13)),
                Text::new(v.to_string(), at(0.04), ("sans-serif", 13)),
            ])
            .map_err(|e| e.to_string())?;
        }
        Ok(())
    })
}

/// A 900×600 white canvas drawn by `f`, written as a PNG.
fn draw(
    path: &Path,
    f: impl FnOnce(&DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> Result<(), String>,
) -> Result<(), String> {
    let (w, h) = (900u32, 600u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        f(&root)?;
        root.present().map_err(|e| e.to_string())?;
    }
    let png = rgb_png(w, h, buf).map_err(|e| format!("{}: {e}", path.display()))?;
    std::fs::write(path, png).map_err(|e| format!("{}: {e}", path.display()))
}

/// A plot's RGB buffer (`w × h × 3` bytes) as PNG bytes.
///
/// # Errors
/// A message when the buffer is not `w × h × 3` bytes or the encoder fails.
pub fn rgb_png(w: u32, h: u32, buf: Vec<u8>) -> Result<Vec<u8>, String> {
    let image = image::RgbImage::from_raw(w, h, buf).ok_or("plot buffer size")?;
    let mut png = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).map_err(|e| e.to_string())?;
    Ok(png)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_one_two_five() {
        assert_eq!(log_ticks(70.0, 3000.0), vec![100.0, 200.0, 500.0, 1000.0, 2000.0]);
        assert_eq!(log_ticks(0.003, 0.02), vec![0.005, 0.01, 0.02]);
        assert_eq!(log_ticks(1.99, 60.0), vec![2.0, 5.0, 10.0, 20.0, 50.0]);
    }
}
