//! The optics blur of a shipped scenario's sky, both ways (prefiltered texture, per-frame blur), against the
//! brute-force blur of the same sky.

use std::path::PathBuf;

use irsim::imaging::background::{SkyBlur, exact_blurred_pixel};
use irsim::imaging::frame::Frame;
use irsim::scenario::load;
use irsim::sim::{CameraPose, Observer, RunOptions, Sensor, SensorFrame, Sky, build_app, step};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Frame 0's blurred background (radiance) of `name` with the sky blur forced to `how`, and the app.
fn background(name: &str, how: SkyBlur) -> (bevy::app::App, Frame) {
    let mut s = load(&root().join(format!("scenarios/{name}.toml"))).unwrap();
    let mut psf = s.sensor.psf.unwrap();
    psf.sky_blur = how;
    s.sensor.psf = Some(psf);
    let mut app = build_app(&s, RunOptions { noise: false, vibration: false, ..RunOptions::default() }).unwrap();
    step(&mut app);
    let world = app.world_mut();
    let frame = world.query::<&SensorFrame>().single(world).unwrap().background.clone();
    (app, frame)
}

/// On sense_and_avoid's broken cumulus (sharp cloud edges, about one texel per pixel), at the 120 pixels where
/// the two ways differ most and 80 more spread over the frame (those whose blur sees only the image): the
/// prefiltered texture is closer to the brute-force blur than the per-frame blur, which errs most at sharp edges
/// because it treats the frame as linear between pixel centres.
#[test]
fn prefiltered_sky_is_closer_to_the_exact_blur_than_the_frame_blur() {
    let name = "sense_and_avoid";
    let (mut app, pre) = background(name, SkyBlur::Prefilter);
    let (_, reference) = background(name, SkyBlur::Frame);
    let world = app.world_mut();
    let camera =
        world.query_filtered::<&CameraPose, bevy::ecs::prelude::With<Observer>>().single(world).unwrap().current;
    let plane = world.query::<&Sky>().single(world).unwrap().plane.clone().unwrap();
    let sensor = world.query::<&Sensor>().single(world).unwrap().clone();
    let psf = sensor.psf.clone().unwrap();
    let (w, h) = (pre.width(), pre.height());
    let r = psf.radius_px() + 1;
    let mut by_difference: Vec<(usize, usize)> = (r..h - r).flat_map(|y| (r..w - r).map(move |x| (x, y))).collect();
    by_difference.sort_by(|a, b| {
        let d = |&(x, y): &(usize, usize)| (pre.get(x, y) - reference.get(x, y)).abs();
        d(b).total_cmp(&d(a))
    });
    let mut pixels: Vec<(usize, usize)> = by_difference[..120].to_vec();
    pixels.extend((0..80).map(|i| (r + (i * 97) % (w - 2 * r), r + (i * 61) % (h - 2 * r))));
    let dn = sensor.dn_per_radiance;
    let (mut worst_pre, mut worst_ref, mut sq_pre, mut sq_ref, mut counted) = (0.0f64, 0.0f64, 0.0, 0.0, 0);
    for &(x, y) in &pixels {
        let Some(exact) = exact_blurred_pixel(&plane, &camera, &psf, x, y, 8) else { continue };
        let (e_pre, e_ref) = ((f64::from(pre.get(x, y)) - exact) * dn, (f64::from(reference.get(x, y)) - exact) * dn);
        worst_pre = worst_pre.max(e_pre.abs());
        worst_ref = worst_ref.max(e_ref.abs());
        sq_pre += e_pre * e_pre;
        sq_ref += e_ref * e_ref;
        counted += 1;
    }
    assert!(counted >= 150, "{counted} pixels see the plane");
    let (rms_pre, rms_ref) = ((sq_pre / counted as f64).sqrt(), (sq_ref / counted as f64).sqrt());
    eprintln!(
        "{name}, {counted} pixels, DN against the brute-force blur: prefilter worst {worst_pre:.3} rms {rms_pre:.3}; \
         frame worst {worst_ref:.3} rms {rms_ref:.3}"
    );
    // measured: prefilter worst 8.6 DN, rms 3.4; frame worst 31.1, rms 19.7 (the camera's temporal noise is 2 DN).
    // With the parametric clear sky the clouds stood out less against it (prefilter 3.1 / 1.3, frame 12.1 / 6.7):
    // LOWTRAN's sky behind them is colder (the parametric one was 10–25 K too warm at 2–30° elevation from 0–3 km
    // against direct LOWTRAN runs), so their edges carry more DN
    assert!(worst_pre < 0.5 * worst_ref && rms_pre < 0.5 * rms_ref);
    assert!(worst_pre < 12.0 && rms_pre < 5.0, "{worst_pre} DN, rms {rms_pre}");
}
