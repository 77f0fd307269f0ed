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
    let plane = world.query::<&Sky>().single(world).unwrap().plane().cloned().unwrap();
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
    // measured: prefilter worst 12.2 DN, rms 4.5; frame worst 37.3, rms 19.4 (the camera's temporal noise is 2 DN;
    // the bounds hold for a realization of the clouds, whose sharpest edges set the worst pixel: the layer drawn
    // texel by texel gave prefilter 8.6 / 3.4, frame 31.1 / 19.7).
    // With the parametric clear sky the clouds stood out less against it (prefilter 3.1 / 1.3, frame 12.1 / 6.7):
    // LOWTRAN's sky behind them is colder (the parametric one was 10–25 K too warm at 2–30° elevation from 0–3 km
    // against direct LOWTRAN runs), so their edges carry more DN
    assert!(worst_pre < 0.5 * worst_ref && rms_pre < 0.5 * rms_ref);
    assert!(worst_pre < 16.0 && rms_pre < 6.0, "{worst_pre} DN, rms {rms_pre}");
}

/// A frame's background depends on its own camera alone, not on what its buffer held before: sense_and_avoid's
/// first frame (the horizon's tiles blurred per frame, whose skip test reads a pixel into the texture's tiles
/// beyond them, and whose FFT blur reads the whole frame) is the same bits over a buffer of zeros, of a large
/// value and of NaN, with the separable kernel and with the FFT.
#[test]
fn a_frame_s_background_does_not_depend_on_its_buffer_s_old_pixels() {
    use irsim::imaging::psf::ConvolutionMethod;
    for (method, skip_below_dn) in [(ConvolutionMethod::Separable, None), (ConvolutionMethod::Fft, Some(0.0))] {
        let mut s = load(&root().join("scenarios/sense_and_avoid.toml")).unwrap();
        let mut psf = s.sensor.psf.unwrap();
        psf.method = method;
        if let Some(dn) = skip_below_dn {
            // the whole frame blurred at once
            psf.skip_below_dn = dn;
        }
        s.sensor.psf = Some(psf);
        let first = |old: Option<f32>| {
            let mut app = build_app(&s, RunOptions { noise: false, ..RunOptions::default() }).unwrap();
            if let Some(v) = old {
                let world = app.world_mut();
                let mut sf = world.query::<&mut SensorFrame>().single_mut(world).unwrap();
                let (w, h) = (sf.background.width(), sf.background.height());
                sf.background = Frame::from_pixels(w, h, vec![v; w * h]);
            }
            step(&mut app);
            let world = app.world_mut();
            let sf = world.query::<&SensorFrame>().single(world).unwrap();
            assert!(sf.background_stats.tiles_prefiltered > 0, "part of the frame from the texture");
            sf.background.clone()
        };
        let blank = first(None);
        for old in [1e6, -1.0, f32::NAN] {
            let again = first(Some(old));
            for (i, (a, b)) in blank.pixels().iter().zip(again.pixels()).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{method:?}: pixel {i} over a buffer of {old}");
            }
        }
    }
}
