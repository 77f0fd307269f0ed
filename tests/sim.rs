//! The headless simulation: labels against closed forms, determinism, thread independence, the noise-free
//! pipeline against the core functions composed by hand, and every shipped scenario.

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};
use irsim::imaging::camera::Camera;
use irsim::imaging::frame::Frame;
use irsim::imaging::fusion::{Patch, PoissonFusion};
use irsim::imaging::sky_plane::{SkyImage, SkyPlane};
use irsim::imaging::target_blob::{
    Ellipsoid, EllipsoidProjection, GeneralizedGaussian, attitude_from_velocity, project_ellipsoid,
};
use irsim::scenario::load::{Format, load_str};
use irsim::scenario::{CheckedScenario, load};
use irsim::sim::{RunOptions, build_app, current_frame, step};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scenario(text: &str) -> CheckedScenario {
    load_str(text, Format::Toml, Path::new("test.toml"), &root().join("scenarios")).unwrap()
}

/// A still camera looking north at [0, 0, 8000] and one small sphere flying east at constant velocity.
const CONSTANT_VELOCITY: &str = r#"
[run]
frame_rate_hz = 25
frames = 20
seed = 4
[sensor]
width = 128
height = 96
pixel_pitch_um = 17
focal_length_mm = 50
aperture_mm = 50
band_um = [8, 12]
[observer]
trajectory = { kind = "constant_velocity", position_m = [0, 0, 8000] }
pointing = { mode = "yaw_pitch_roll", yaw_deg = 0, pitch_deg = 0, roll_deg = 0 }
[[targets]]
name = "ball"
trajectory = { kind = "constant_velocity", position_m = [-60, 5000, 8012], velocity_m_s = [150, 10, 0] }
semi_axes_m = [0.5, 0.5, 0.5]
"#;

#[test]
fn constant_velocity_label_follows_the_closed_form_projection() {
    let s = scenario(CONSTANT_VELOCITY);
    let mut app = build_app(&s, RunOptions::default()).unwrap();
    let f = 50e-3 / 17e-6;
    for k in 0..20 {
        let labels = step(&mut app);
        assert_eq!(labels.frame, k);
        let t = k as f64 / 25.0;
        let (x, y, z) = (-60.0 + 150.0 * t, 5000.0 + 10.0 * t, 8012.0);
        // camera looks along +y: u = cx + f·x/y, v = cy − f·(z − 8000)/y
        let u = 64.0 + f * x / y;
        let v = 48.0 - f * (z - 8000.0) / y;
        let c = labels.targets[0].center_px;
        assert!((c[0] - u).abs() < 1e-3 && (c[1] - v).abs() < 1e-3, "frame {k}: label {c:?} vs ({u}, {v})");
        assert!((labels.t_s - t).abs() < 1e-12);
        assert!((labels.targets[0].range_m - DVec3::new(x, y, z - 8000.0).length()).abs() < 1e-6);
    }
}

fn hash(frame: &Frame) -> u64 {
    // FNV-1a over the f32 bit patterns
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in frame.pixels() {
        for b in v.to_bits().to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

fn run_hashes(s: &CheckedScenario, frames: usize, options: RunOptions) -> Vec<u64> {
    let mut app = build_app(s, options).unwrap();
    (0..frames)
        .map(|_| {
            step(&mut app);
            hash(current_frame(&mut app))
        })
        .collect()
}

fn paper() -> CheckedScenario {
    load(&root().join("scenarios/paper_clear_sky.toml")).unwrap()
}

#[test]
fn runs_are_deterministic_and_thread_count_independent() {
    let s = paper();
    let a = run_hashes(&s, 5, RunOptions::default());
    let b = run_hashes(&s, 5, RunOptions::default());
    assert_eq!(a, b);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let c = one.install(|| run_hashes(&s, 5, RunOptions::default()));
    assert_eq!(a, c, "one thread gives other frames than the default pool");
    let three = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
    assert_eq!(a, three.install(|| run_hashes(&s, 5, RunOptions::default())));
    // another seed changes the noise
    let d = run_hashes(&s, 5, RunOptions { seed: Some(123), ..RunOptions::default() });
    assert_ne!(a, d);
}

#[test]
fn many_targets_labels_are_the_same_on_any_number_of_threads() {
    // swarm's ten labels are made side by side (`sim::output`): in the order of their ids, and the same values
    // (bit for bit: compared as equal structs) whatever the pool
    let s = load(&root().join("scenarios/swarm.toml")).unwrap();
    let labels = || {
        let mut app = build_app(&s, RunOptions::default()).unwrap();
        (0..3).map(|_| step(&mut app)).collect::<Vec<_>>()
    };
    let a = labels();
    for frame in &a {
        let ids: Vec<u32> = frame.targets.iter().map(|t| t.id).collect();
        assert_eq!(ids.len(), 10, "{ids:?}");
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "labels out of id order: {ids:?}");
        assert!(frame.targets.iter().any(|t| t.in_frame), "no target in frame");
        assert!(frame.targets.iter().filter(|t| t.in_frame).all(|t| t.scr > 0.0 && t.apparent_temp_k > 0.0));
    }
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        assert_eq!(a, pool.install(labels), "{threads} threads give other labels than the default pool");
    }
}

#[test]
fn handing_the_render_to_the_frame_changes_no_frame_and_no_label() {
    // swarm's camera shakes at every frame, and paper_clear_sky's tracks its target: from the second frame on the
    // render becomes the frame instead of being copied into it, and only the windows the labels read are kept of
    // it. Frames and labels (the targets' clutter among them) are the same bits as in a run that keeps the whole
    // background; that run's background is the render, the other's not outside those windows.
    use irsim::sim::SensorFrame;
    for name in ["swarm", "paper_clear_sky"] {
        let s = load(&root().join(format!("scenarios/{name}.toml"))).unwrap();
        let run = |whole_background: bool| {
            let mut app = build_app(&s, RunOptions { whole_background, ..RunOptions::default() }).unwrap();
            let frames: Vec<_> = (0..4).map(|_| (step(&mut app), current_frame(&mut app).pixels().to_vec())).collect();
            let world = app.world_mut();
            let background = world.query::<&SensorFrame>().single(world).unwrap().background.pixels().to_vec();
            (frames, background)
        };
        let ((handed, partial), (copied, whole)) = (run(false), run(true));
        for (k, ((la, fa), (lb, fb))) in handed.iter().zip(&copied).enumerate() {
            assert_eq!(la, lb, "{name}: frame {k}'s labels");
            assert!(fa.iter().zip(fb).all(|(a, b)| a.to_bits() == b.to_bits()), "{name}: frame {k}'s pixels");
            assert!(la.targets.iter().any(|t| t.in_frame && t.scr > 0.0), "{name}: frame {k} has a target's clutter");
        }
        let differ = partial.iter().zip(&whole).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert!(differ > whole.len() / 2, "{name}: the render was handed over ({differ} pixels differ)");
    }
    // a camera that holds still, moves, stops and moves again (swarm without its shake, its aim turned between
    // frames): the renders reused, handed over and made again give the frames and labels a kept background gives
    use irsim::scenario::Pointing;
    use irsim::sim::Aim;
    let s = load(&root().join("scenarios/swarm.toml")).unwrap();
    let aims = [0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 4.0, 5.0, 5.0];
    let run = |whole_background: bool| {
        let options = RunOptions { whole_background, vibration: false, ..RunOptions::default() };
        let mut app = build_app(&s, options).unwrap();
        let mut frames = Vec::new();
        for &east_m in &aims {
            let world = app.world_mut();
            world.query::<&mut Aim>().single_mut(world).unwrap().pointing =
                Pointing::LookAt { target_m: DVec3::new(east_m, 1200.0, 560.0), roll_deg: 0.0 };
            let labels = step(&mut app);
            let pixels = current_frame(&mut app).pixels().to_vec();
            let world = app.world_mut();
            let background = world.query::<&SensorFrame>().single(world).unwrap().background.pixels().to_vec();
            frames.push((labels, pixels, background));
        }
        frames
    };
    let (handed, copied) = (run(false), run(true));
    let mut kept = Vec::new();
    for (k, ((la, fa, ba), (lb, fb, bb))) in handed.iter().zip(&copied).enumerate() {
        assert_eq!(la, lb, "still and moving: frame {k}'s labels");
        assert!(fa.iter().zip(fb).all(|(a, b)| a.to_bits() == b.to_bits()), "still and moving: frame {k}'s pixels");
        kept.push(ba.iter().zip(bb).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
    // handed over from the second of the moving frames running on (4, 5, 9); rendered whole at the first still
    // frame after them (6, 10), reused while still (1, 2, 7), rendered and copied at the first moving one (3, 8)
    let whole: Vec<bool> = (0..aims.len()).map(|k| ![4, 5, 9].contains(&k)).collect();
    assert_eq!(kept, whole, "frames whose background is the whole render");
}

/// Frame hashes of `scenarios/paper_clear_sky.toml`, frames 0–2, default options.
///
/// If this test fails after a change that is meant to change the output (a new model, a fixed bug), update
/// the hashes with the values printed in the failure message, and say why in the commit. If the change was not
/// meant to change frames, the failure is a regression.
const GOLDEN_PAPER_CLEAR_SKY: [u64; 3] =
    [17_401_206_757_401_501_791, 3_635_925_070_505_861_980, 2_463_220_188_573_473_697];

#[test]
fn golden_frame_hashes() {
    let got = run_hashes(&paper(), 3, RunOptions::default());
    assert_eq!(got, GOLDEN_PAPER_CLEAR_SKY, "frame hashes changed: {got:?}");
}

/// With the optics blur, the non-idealities and the noise off and the paper's target model, the frame is the
/// core functions composed by hand: the calibrated sky plane with the dome in its misses, the target's
/// radiance contrast as a generalized Gaussian, Poisson fusion, the readout's mean DN, rounding.
#[test]
fn noise_free_frames_equal_the_core_pipeline_composed_by_hand() {
    use irsim::imaging::sky_field::{RadianceLut, calibrate, render_dome};
    use irsim::physics::sky::{Dome, DomeInputs};
    let mut s = paper();
    // the paper's own set-up: a user image on the Fig. 8 plane, perfect tracking
    let image = root().join("assets/skies/clear.png");
    s.spec.sky.generate = None;
    s.spec.sky.image = Some(image.display().to_string());
    s.spec.sky.calibration = Some(irsim::imaging::sky_field::SkyCalibration::Temperature {
        value_range: [0.0, 65535.0],
        temp_range_k: [210.0, 260.0],
    });
    s.spec.sky.anchor_m = Some(DVec3::new(0.0, 30000.0, 6000.0));
    s.spec.sky.anchor_px = Some(DVec2::new(512.0, 1024.0));
    (s.spec.sky.width_m, s.spec.sky.height_m) = (Some(24000.0), Some(24000.0));
    s.sky_image = Some(image);
    s.spec.observer.pointing =
        irsim::scenario::Pointing::Track { target: "target".into(), roll_deg: 0.0, lag_s: 0.0, noise_urad: 0.0 };
    s.sensor.psf = None;
    s.sensor.nonideal = irsim::physics::nonideal::NonIdealSpec::default();
    s.sensor.blob.model = irsim::scenario::TargetModel::Paper;
    let options = RunOptions { noise: false, vibration: false, ..RunOptions::default() };
    let mut app = build_app(&s, options).unwrap();
    let spec = &s.spec;
    let model = s.sensor.model;
    let sky_spec = &spec.sky;
    let raw = SkyImage::load(s.sky_image.as_ref().unwrap()).unwrap();
    let lut = RadianceLut::new(model.band, model.measure(), irsim::scenario::Quality::default().radiance_table_step_k);
    let image = calibrate(&raw, &sky_spec.calibration.unwrap(), &lut, "sky").unwrap();
    let eye = DVec3::new(0.0, 0.0, 8000.0);
    let plane = SkyPlane::new(image, &sky_spec.placement().unwrap(), eye).unwrap();
    let dome = Dome::new(&DomeInputs {
        spec: sky_spec.dome,
        band: model.band,
        measure: model.measure(),
        observer_altitude_m: eye.z,
        air: spec.atmosphere.air_temperature().unwrap(),
        atmosphere: &spec.atmosphere.override_transmittance(),
        zenith_emissivity: None,
        clear_sky: None,
    })
    .unwrap();
    let intr = s.sensor.intrinsics;
    let mut fusion = PoissonFusion::new();
    for k in 0..4 {
        let labels = step(&mut app);
        let got = current_frame(&mut app).clone();
        let (pos, vel) = s.target_trajectories[0].state(k as f64 / spec.run.frame_rate_hz);
        let cam = Camera::look_at(intr, eye, pos, 0.0).unwrap();
        let mut frame = Frame::new(intr.width as usize, intr.height as usize);
        plane.render(&cam, s.quality.sky_sampling, sky_spec.miss, &mut frame);
        render_dome(&cam, &dome, &mut frame, true, None);
        let e = Ellipsoid {
            center_m: pos,
            semi_axes_m: spec.targets[0].semi_axes_m,
            body_to_world: attitude_from_velocity(vel),
        };
        let EllipsoidProjection::Visible(el) = project_ellipsoid(&e, &cam) else { panic!("target not visible") };
        // ΔL = L_app − L_sky at the ellipse's centre, spread with integral ΔL·A
        let l_app = irsim::physics::planck::band_radiance_in(
            model.measure(),
            model.band,
            labels.targets[0].apparent_temp_k,
            1.0,
        );
        let bg = f64::from(frame.get(el.center.x.floor() as usize, el.center.y.floor() as usize));
        let mut blob = GeneralizedGaussian::from_ellipse(&el, s.sensor.blob.min_blur_px, s.sensor.blob.beta, 1.0);
        blob.peak = (l_app - bg) * el.area_px2() / blob.integral();
        let roi = blob.region_of_interest(s.sensor.blob.roi_fraction, frame.width(), frame.height());
        let mut patch = vec![0.0; roi.width() * roi.height()];
        blob.render_patch(roi, s.sensor.blob.sampling, &mut patch);
        fusion.fuse(
            &mut frame,
            &[Patch { rect: roi, values: &patch }],
            s.quality.fusion_guidance,
            s.quality.fusion_solver,
        );
        let top = model.adc.max_level() as f32;
        let dark = model.dark_signal();
        for p in frame.pixels_mut() {
            let dn = model.adc.offset_dn + (model.signal_per_radiance() * f64::from(*p) + dark) / model.adc.gain;
            *p = (dn as f32).round().clamp(0.0, top);
        }
        // L_app comes back through the label's brightness temperature, so allow one level of rounding
        let worst = frame.pixels().iter().zip(got.pixels()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst <= 1.0, "frame {k}: differs from the hand-composed pipeline by {worst} DN");
        assert!((labels.targets[0].center_px[0] - el.center.x).abs() < 1e-9);
        assert!(DVec2::from(labels.targets[0].center_px).distance(el.center) < 1e-9);
    }
}

#[test]
fn every_shipped_scenario_validates_and_runs_three_frames() {
    let mut count = 0;
    for entry in std::fs::read_dir(root().join("scenarios")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("toml") {
            continue;
        }
        let s = load(&path).unwrap_or_else(|e| panic!("{e}"));
        let mut app = build_app(&s, RunOptions::default()).unwrap();
        for k in 0..3 {
            let labels = step(&mut app);
            assert_eq!(labels.frame, k);
            assert_eq!(labels.targets.len(), s.spec.targets.len());
            assert!(current_frame(&mut app).pixels().iter().all(|v| v.is_finite()));
        }
        count += 1;
    }
    assert!(count >= 8, "{count} scenarios");
}

#[test]
fn system_sets_have_no_ambiguities() {
    use bevy::ecs::schedule::{LogLevel, ScheduleBuildSettings};
    use bevy::prelude::FixedUpdate;
    let s = paper();
    let mut app = build_app(&s, RunOptions { timings: true, ..RunOptions::default() }).unwrap();
    app.edit_schedule(FixedUpdate, |schedule| {
        schedule.set_build_settings(ScheduleBuildSettings {
            ambiguity_detection: LogLevel::Error,
            ..ScheduleBuildSettings::default()
        });
    });
    // the schedule is rebuilt (and checked) on the next runs
    step(&mut app);
    step(&mut app);
}

#[test]
fn frame_is_mirrored_into_a_bevy_image_when_asked() {
    use irsim::sim::{FrameImage, MirrorFrame};
    let s = scenario(CONSTANT_VELOCITY);
    let mut app = build_app(&s, RunOptions::default()).unwrap();
    step(&mut app);
    {
        let world = app.world_mut();
        assert_eq!(world.query::<&FrameImage>().iter(world).count(), 0, "mirrored without being asked");
        world.insert_resource(MirrorFrame);
    }
    step(&mut app);
    step(&mut app);
    let frame = current_frame(&mut app).clone();
    let world = app.world_mut();
    let image = world.query::<&FrameImage>().single(world).unwrap();
    let data = image.0.data.as_ref().unwrap();
    let mirrored: Vec<f32> = data.chunks_exact(4).map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]])).collect();
    assert_eq!(mirrored, frame.pixels());
    assert_eq!(image.0.width(), 128);
}

#[test]
fn fixed_attitude_orients_a_hovering_target() {
    let f = 50e-3 / 17e-6;
    for (yaw, want_a) in [(90.0, f * 20.0 / 5000.0), (0.0, f * 2.0 / 5000.0)] {
        let text = CONSTANT_VELOCITY.replace("velocity_m_s = [150, 10, 0]", "velocity_m_s = [0, 0, 0]").replace(
            "semi_axes_m = [0.5, 0.5, 0.5]",
            &format!("semi_axes_m = [20, 2, 2]\nattitude = {{ yaw_deg = {yaw} }}"),
        );
        let s = scenario(&text);
        let mut app = build_app(&s, RunOptions::default()).unwrap();
        let l = step(&mut app);
        let e = l.targets[0].ellipse_px;
        assert!((e.a - want_a).abs() / want_a < 0.01, "yaw {yaw}: a = {} px, want {want_a}", e.a);
        if yaw == 90.0 {
            assert!(e.angle_rad.abs() < 1e-6, "long axis should be horizontal: {}", e.angle_rad);
        }
    }
}

#[test]
fn internal_heating_raises_the_skin_and_the_target_signal() {
    let label = |heating: f64| {
        let text = CONSTANT_VELOCITY
            .replace("semi_axes_m = [0.5, 0.5, 0.5]", &format!("semi_axes_m = [0.5, 0.5, 0.5]\nheating_k = {heating}"));
        let mut app = build_app(&scenario(&text), RunOptions { noise: false, ..RunOptions::default() }).unwrap();
        step(&mut app).targets.remove(0)
    };
    let (cold, warm) = (label(0.0), label(10.0));
    assert!((warm.skin_temp_k - cold.skin_temp_k - 10.0).abs() < 1e-9, "{} vs {}", warm.skin_temp_k, cold.skin_temp_k);
    assert!(warm.apparent_temp_k > cold.apparent_temp_k + 1.0, "{} vs {}", warm.apparent_temp_k, cold.apparent_temp_k);
    assert!(warm.peak_dn > cold.peak_dn, "{} vs {}", warm.peak_dn, cold.peak_dn);
    // out of range or not a number: a located error
    for bad in ["-1", "3000", "nan"] {
        let text = CONSTANT_VELOCITY
            .replace("semi_axes_m = [0.5, 0.5, 0.5]", &format!("semi_axes_m = [0.5, 0.5, 0.5]\nheating_k = {bad}"));
        let err = load_str(&text, Format::Toml, Path::new("test.toml"), &root()).unwrap_err().to_string();
        assert!(err.contains("targets[0].heating_k"), "{bad}: {err}");
    }
}

#[test]
fn no_cloud_below_the_cloud_base() {
    // the constant-velocity camera at 8 km looking north at a cumulus layer 20 km away spanning 6–10 km
    let frame = |sky: &str| {
        let text = format!(
            "{CONSTANT_VELOCITY}[sky]\n{sky}\nanchor_m = [0, 20000, 8000]\nnormal = [0, -1, 0]\nwidth_m = 8000\nheight_m = 4000\n"
        );
        let text = if sky.is_empty() { CONSTANT_VELOCITY.to_owned() } else { text };
        let mut app = build_app(&scenario(&text), RunOptions { noise: false, ..RunOptions::default() }).unwrap();
        step(&mut app);
        current_frame(&mut app).clone()
    };
    let layer = "generate = { kind = \"cumulus\", cover = 0.9, psd_slope = -3.0, scale = 0.3, seed = 3 }";
    let (clear, cloudy) = (frame(""), frame(layer));
    let based = frame(&format!("{layer}\ncloud_base_m = 11000"));
    let worst = |a: &irsim::imaging::frame::Frame, b: &irsim::imaging::frame::Frame| {
        a.pixels().iter().zip(b.pixels()).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max)
    };
    let (with_clouds, above_base) = (worst(&cloudy, &clear), worst(&based, &clear));
    // clouds change the frame by many DN; a base above the whole layer leaves only the baked dome's resampling
    assert!(with_clouds > 50.0, "clouds change the frame by only {with_clouds} DN");
    assert!(above_base < 0.02 * with_clouds, "{above_base} DN with every cloud below the base");
    let err = load_str(
        &format!("{CONSTANT_VELOCITY}[sky]\n{layer}\ncloud_base_m = -1e9\nanchor_m = [0, 20000, 8000]\nwidth_m = 8000\nheight_m = 4000\n"),
        Format::Toml,
        Path::new("test.toml"),
        &root(),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("sky.cloud_base_m"), "{err}");
}

/// A second front end drives the same world: its own app with the plugin group and the spawned scenario, stepped
/// by hand, reading `FrameReady` messages, gets exactly the frames and labels of the headless app.
#[test]
fn frames_leave_the_schedule_as_frame_ready_messages() {
    use bevy::app::App;
    use bevy::prelude::MinimalPlugins;
    use bevy::time::{Fixed, Time, TimeUpdateStrategy};
    use irsim::sim::{BEVY_STEP, IrSimPlugins, drain_frames, headless_app, spawn_scenario};

    let s = scenario(CONSTANT_VELOCITY);
    let options = RunOptions { masks: true, keep_float: true, ..RunOptions::default() };
    let mut headless = headless_app(&s, options).unwrap();
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .insert_resource(Time::<Fixed>::from_duration(BEVY_STEP))
        .insert_resource(TimeUpdateStrategy::FixedTimesteps(1))
        .add_plugins(IrSimPlugins);
    spawn_scenario(app.world_mut(), &s, options).unwrap();
    app.update();
    assert!(drain_frames(&mut app).is_empty(), "the first update runs Startup only");
    for k in 0..5 {
        app.update();
        let mut got = drain_frames(&mut app);
        assert_eq!(got.len(), 1, "one frame per step");
        let ready = got.pop().unwrap();
        assert_eq!(ready.labels.frame, k);
        let labels = step(&mut headless);
        assert_eq!(ready.labels, labels);
        assert_eq!(ready.frame.pixels(), current_frame(&mut headless).pixels());
        let mask = ready.mask.expect("masks were asked for");
        assert_eq!(mask.len(), 128 * 96);
        assert!(mask.contains(&1), "frame {k}: the target is in the mask");
        let float = ready.float_frame.expect("the float frame was asked for");
        // quantization moves a value by at most half a level
        assert!(float.pixels().iter().zip(ready.frame.pixels()).all(|(f, q)| (f - q).abs() <= 0.5 + 1e-3));
    }
}

/// [`CONSTANT_VELOCITY`]'s camera at 2 km looking at `target` (a point in TOML), with a generated cumulus layer
/// on a vertical plane 30 km north (1–5 km up).
fn layer_ahead(target: &str) -> String {
    let observer = r#"pointing = { mode = "yaw_pitch_roll", yaw_deg = 0, pitch_deg = 0, roll_deg = 0 }"#;
    let text = CONSTANT_VELOCITY
        .replace("position_m = [0, 0, 8000] }", "position_m = [0, 0, 2000] }")
        .replace(observer, &format!(r#"pointing = {{ mode = "look_at", target_m = {target} }}"#));
    text + r#"[sky]
generate = { kind = "cumulus", cover = 0.45, seed = 3 }
anchor_m = [0, 30000, 3000]
normal = [0, -1, 0]
width_m = 20000
height_m = 4000
max_texels = 512
[atmosphere]
model = "us_standard_1976"
aerosol = "rural"
visibility_km = 23
"#
}

/// A generated layer that no planned view sees is made only when a camera first may see it, and then holds the
/// pixels a run that sees it from the start makes at set-up: the frame that first sees it is the same bits in
/// both runs, whatever the deferred run rendered before.
#[test]
fn an_unseen_sky_layer_is_made_when_first_seen_as_at_set_up() {
    use irsim::imaging::background::SkyBlur;
    use irsim::sim::{Aim, SensorFrame, Sky};
    let load = |target: &str| {
        let mut s = scenario(&layer_ahead(target));
        // the same blur in both runs (`auto` plans it from the run's views)
        let mut psf = s.sensor.psf.expect("the lens has a PSF");
        psf.sky_blur = SkyBlur::Prefilter;
        s.sensor.psf = Some(psf);
        // no margin of clear sky in either: whether a layer gets one is planned from the run's views, which
        // differ between the two runs
        s.quality.layer_margin_px = 0.0;
        s
    };
    // 30° up, and at the layer
    let (away, toward) = (load("[0, 5000, 4887]"), load("[0, 30000, 3000]"));
    let options = RunOptions { noise: false, vibration: false, ..RunOptions::default() };
    let mut deferred = build_app(&away, options).unwrap();
    let mut eager = build_app(&toward, options).unwrap();
    let sky = |app: &mut bevy::app::App| {
        let world = app.world_mut();
        world.query::<&Sky>().single(world).unwrap().clone()
    };
    assert!(sky(&mut deferred).plane_pending(), "no planned view sees the layer");
    assert!(!sky(&mut eager).plane_pending(), "every planned view sees the layer");
    for _ in 0..2 {
        step(&mut deferred);
        step(&mut eager);
    }
    assert!(sky(&mut deferred).plane_pending(), "frames looking away leave it unmade");
    {
        let world = deferred.world_mut();
        let mut aim = world.query::<&mut Aim>().single_mut(world).unwrap();
        aim.pointing = toward.spec.observer.pointing.clone();
    }
    step(&mut deferred);
    step(&mut eager);
    let (made, built) = (sky(&mut deferred), sky(&mut eager));
    assert!(!made.plane_pending(), "the frame that sees it made it");
    let (a, b) = (made.plane().unwrap().image(), built.plane().unwrap().image());
    assert_eq!((a.width(), a.height()), (b.width(), b.height()));
    assert!(a.pixels().iter().zip(b.pixels()).all(|(x, y)| x.to_bits() == y.to_bits()), "the layer's texels");
    let background = |app: &mut bevy::app::App| {
        let world = app.world_mut();
        world.query::<&SensorFrame>().single(world).unwrap().background.clone()
    };
    let (fa, fb) = (background(&mut deferred), background(&mut eager));
    assert!(fa.pixels().iter().zip(fb.pixels()).all(|(x, y)| x.to_bits() == y.to_bits()), "frame 2's background");
    let lo = fb.pixels().iter().copied().fold(f32::INFINITY, f32::min);
    let hi = fb.pixels().iter().copied().fold(f32::NEG_INFINITY, f32::max);
    assert!(hi > 1.05 * lo, "the view holds cloud against sky ({lo} … {hi})");
}

#[test]
fn a_coarser_sky_texel_makes_the_same_clouds_on_fewer_texels() {
    use irsim::sim::Sky;
    let layer = |texel_px: f64| {
        // a layer under its largest side (the fine one 1961 × 393 texels)
        let mut s = scenario(&layer_ahead("[0, 30000, 3000]").replace("max_texels = 512", "max_texels = 4096"));
        s.quality.sky_texel_px = texel_px;
        // the layer alone, without the clear sky baked around it
        s.quality.layer_margin_px = 0.0;
        let mut app = build_app(&s, RunOptions { noise: false, vibration: false, ..RunOptions::default() }).unwrap();
        let world = app.world_mut();
        let sky = world.query::<&Sky>().single(world).unwrap().clone();
        sky.plane().unwrap().image().clone()
    };
    let (fine, coarse) = (layer(1.0), layer(2.0));
    let (w, h) = (fine.width(), fine.height());
    let (cw, ch) = (coarse.width(), coarse.height());
    assert_eq!((cw, ch), (w.div_ceil(2), h.div_ceil(2)), "{w}x{h}");
    // each coarse texel against the fine texels over its place on the plane (the 2 × 2 from where it starts):
    // the same clouds correlate near 1, another realization of the same spectrum near 0
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for y in 0..ch {
        for x in 0..cw {
            // the 2 × 2 fine texels centred nearest the coarse texel's centre, (x + ½)·w/cw in fine texels
            let start = |x: usize, w: usize, cw: usize| ((2 * x + 1) * w / (2 * cw)).saturating_sub(1).min(w - 2);
            let (fx, fy) = (start(x, w, cw), start(y, h, ch));
            let at = |dx: usize, dy: usize| f64::from(fine.pixels()[(fy + dy) * w + fx + dx]);
            a.push(0.25 * (at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1)));
            b.push(f64::from(coarse.pixels()[y * cw + x]));
        }
    }
    // less each row's mean: the baked radiance's fall with elevation is common to any clouds
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    for v in [&mut a, &mut b] {
        for row in v.chunks_mut(cw) {
            let m = mean(row);
            row.iter_mut().for_each(|x| *x -= m);
        }
    }
    let (ma, mb) = (mean(&a), mean(&b));
    let cov = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum::<f64>();
    let var = |v: &[f64], m: f64| v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
    let r = cov / (var(&a, ma) * var(&b, mb)).sqrt();
    assert!(r > 0.99, "correlation {r}");
}

/// The largest change the margin may make to a frame of the test below: 16 DN measured, where the layer's edge
/// cuts a cloud (130 DN over the sky): without the margin the cloud stops at the layer's edge, with it the
/// bilinear read ramps from the cloud's last texel to the margin's first.
const WORST_DN: f32 = 20.0;

/// A generated layer baked with a margin of clear sky (`[quality] layer_margin_px`): the layer's texels are
/// where they were, the margin holds the dome along each texel's direction from the observer, and the frame's
/// tiles where the layer ends, which without the margin took the dome along each ray and a per-frame blur, are
/// read from the prefiltered texture, within [`WORST_DN`] of that (noise off).
#[test]
fn a_margin_of_clear_sky_serves_the_layer_edge_from_the_texture() {
    use irsim::imaging::background::SkyBlur;
    use irsim::sim::{SensorFrame, Sky};
    // looking at the layer's top edge (5 km up), which crosses the frame; a still observer
    let run = |margin_px: f64| {
        let mut s = scenario(&layer_ahead("[0, 30000, 5000]"));
        let mut psf = s.sensor.psf.expect("the lens has a PSF");
        psf.sky_blur = SkyBlur::Prefilter;
        s.sensor.psf = Some(psf);
        s.quality.layer_margin_px = margin_px;
        let mut app = build_app(&s, RunOptions { noise: false, ..RunOptions::default() }).unwrap();
        let mut frames = Vec::new();
        let mut stats = Vec::new();
        for _ in 0..4 {
            step(&mut app);
            frames.push(current_frame(&mut app).clone());
            let world = app.world_mut();
            stats.push(world.query::<&SensorFrame>().single(world).unwrap().background_stats);
        }
        let world = app.world_mut();
        let sky = world.query::<&Sky>().single(world).unwrap().clone();
        (sky, frames, stats)
    };
    let (bare, bare_frames, bare_stats) = run(0.0);
    let (padded, padded_frames, padded_stats) = run(96.0);
    let (a, b) = (bare.plane().unwrap(), padded.plane().unwrap());
    let (w, h) = (a.image().width(), a.image().height());
    let m = (b.image().width() - w) / 2;
    assert!(m > 0 && (b.image().width(), b.image().height()) == (w + 2 * m, h + 2 * m), "a margin all round");
    for y in 0..b.image().height() {
        for x in 0..b.image().width() {
            let texel = f64::from(b.image().pixels()[y * b.image().stride() + x]);
            let centre = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            let expected = if (m..m + w).contains(&x) && (m..m + h).contains(&y) {
                // the layer's own texel, at the same world point
                let own = DVec2::new((x - m) as f64 + 0.5, (y - m) as f64 + 0.5);
                assert!(b.world_point(centre).distance(a.world_point(own)) < 1e-6, "texel ({x}, {y}) moved");
                f64::from(a.image().pixels()[(y - m) * a.image().stride() + x - m])
            } else {
                f64::from(bare.dome.radiance_toward(b.world_point(centre) - DVec3::new(0.0, 0.0, 2000.0)))
            };
            assert!((texel - expected).abs() <= 1e-5 * expected.abs(), "texel ({x}, {y}): {texel} against {expected}");
        }
    }
    for (k, (sa, sb)) in bare_stats.iter().zip(&padded_stats).enumerate() {
        assert!(sa.blur.tiles_needed > 0, "frame {k}: without the margin the layer's edge is blurred each frame");
        assert_eq!(sb.blur.tiles_needed, 0, "frame {k}: with it, no tile is");
        assert_eq!(sb.tiles_prefiltered, sb.blur.tiles, "frame {k}: every tile from the texture");
    }
    let mut worst = 0.0f32;
    for (fa, fb) in bare_frames.iter().zip(&padded_frames) {
        for (x, y) in fa.pixels().iter().zip(fb.pixels()) {
            worst = worst.max((x - y).abs());
        }
    }
    assert!(worst > 0.0 && worst <= WORST_DN, "largest change {worst} DN");
}

/// A layer whose planned views all stay farther than the margin from its edge is baked without one (the same
/// texels as with the switch at 0), and one whose views reach its edge with one: the margin costs nothing where
/// no view would read it.
#[test]
fn a_layer_no_view_comes_near_gets_no_margin() {
    use irsim::sim::Sky;
    let image = |target: &str, margin_px: f64| {
        let mut s = scenario(&layer_ahead(target));
        s.quality.layer_margin_px = margin_px;
        let mut app = build_app(&s, RunOptions { noise: false, vibration: false, ..RunOptions::default() }).unwrap();
        let world = app.world_mut();
        let sky = world.query::<&Sky>().single(world).unwrap().clone();
        sky.plane().unwrap().image().clone()
    };
    // the 128 × 96 px view at the layer's middle (2 km up, 30 km off: the layer 392 px tall) and at its top edge
    let (middle, bare) = (image("[0, 30000, 3000]", 96.0), image("[0, 30000, 3000]", 0.0));
    assert_eq!((middle.width(), middle.height()), (bare.width(), bare.height()), "no margin in the middle");
    assert!(middle.pixels().iter().zip(bare.pixels()).all(|(a, b)| a.to_bits() == b.to_bits()), "the same texels");
    let edge = image("[0, 30000, 5000]", 96.0);
    assert!(edge.height() > bare.height() && edge.width() > bare.width(), "a margin at the edge");
}

/// The targets' shapes drawn beside the sky render and scaled in the targets stage give every patch, peak and
/// fusion mode, to the bit, that the targets stage gives drawing each target whole itself (one target, and ten
/// drawn side by side).
#[test]
fn target_shapes_drawn_beside_the_render_are_the_patches_drawn_whole() {
    use bevy::ecs::system::RunSystemOnce;
    use irsim::sim::{Footprint, TargetPatches, draw_targets};

    for name in ["paper_clear_sky", "swarm"] {
        let s = load(&root().join(format!("scenarios/{name}.toml"))).unwrap();
        let mut app = build_app(&s, RunOptions::default()).unwrap();
        step(&mut app);
        step(&mut app);
        let world = app.world_mut();
        let state = |world: &mut bevy::ecs::world::World| {
            let p = world.resource::<TargetPatches>();
            let patches: Vec<_> = p.patches[..p.used].iter().map(|(r, v)| (*r, v.clone())).collect();
            let additive = p.additive.clone();
            let mut q = world.query::<&Footprint>();
            let peaks: Vec<_> = q.iter(world).map(|f| (f.patch, f.peak_radiance.to_bits())).collect();
            (patches, additive, peaks)
        };
        let beside = state(world);
        assert!(!beside.0.is_empty(), "{name}: a target is drawn");
        assert!(beside.0.iter().all(|(_, v)| v.iter().any(|&x| x != 0.0)), "{name}: every patch holds its target");
        // every target's shape was drawn beside the render and taken by the targets stage
        let p = world.resource::<TargetPatches>();
        assert!(p.shapes.len() >= beside.0.len() && p.shapes_used == 0, "{name}: the shapes became the patches");
        // no shapes: the targets stage draws each target whole
        world.run_system_once(draw_targets).unwrap();
        assert_eq!(state(world), beside, "{name}");
    }
}
