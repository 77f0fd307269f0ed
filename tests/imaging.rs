//! Image formation against independent exact solutions: homography, conic outlines, centroids, Poisson.

use glam::{DMat3, DVec2, DVec3};
use irsim::imaging::camera::{Camera, Intrinsics, Projection};
use irsim::imaging::frame::Frame;
use irsim::imaging::fusion::{Guidance, Patch, PoissonFusion, Solver, max_residual};
use irsim::imaging::sky_plane::{MissFill, Sampling, SkyImage, SkyPlacement, SkyPlane};
use irsim::imaging::target_blob::{
    BlobSampling, Ellipsoid, EllipsoidProjection, GeneralizedGaussian, ImageEllipse, PixelRect, project_ellipsoid,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SQUARE: usize = 4; // checker squares, sky pixels

fn checkerboard(n: usize) -> SkyImage {
    let px = (0..n * n)
        .map(|i| if ((i % n) / SQUARE + (i / n) / SQUARE).is_multiple_of(2) { 0.0 } else { 1000.0 })
        .collect();
    SkyImage::from_f32(n, n, px).unwrap()
}

/// Sky-pixel → sensor-pixel homography of a plane facing −y, built from the matrices directly.
fn homography(cam: &Camera, anchor: DVec3, anchor_px: DVec2, m_per_px: f64) -> DMat3 {
    let right = DVec3::X * m_per_px;
    let down = -DVec3::Z * m_per_px;
    let origin = anchor - right * anchor_px.x - down * anchor_px.y - cam.position_m;
    cam.k_matrix() * cam.world_to_camera() * DMat3::from_cols(right, down, origin)
}

fn apply(h: &DMat3, p: DVec2) -> DVec2 {
    let q = *h * p.extend(1.0);
    DVec2::new(q.x / q.z, q.y / q.z)
}

#[test]
fn checkerboard_edges_follow_the_plane_homography() {
    let n = 64;
    let width_m = 2000.0;
    let anchor = DVec3::new(0.0, 30_000.0, 6000.0);
    let placement = SkyPlacement {
        anchor_m: anchor,
        anchor_px: Some(DVec2::new(20.0, 40.0)),
        width_m,
        height_m: width_m,
        normal: Some(-DVec3::Y),
        up: None,
    };
    let cam_pos = DVec3::new(3000.0, 0.0, 8000.0);
    let plane = SkyPlane::new(checkerboard(n), &placement, cam_pos).unwrap();
    let intr = Intrinsics::try_new(128, 96, 0.1, 17e-6).unwrap();
    // tilted (looking down and sideways at an oblique plane) and rolled
    let look = plane.world_point(DVec2::new(32.0, 32.0));
    let cam = Camera::look_at(intr, cam_pos, look, 17.0).unwrap();
    let mut frame = Frame::new(128, 96);
    plane.render(&cam, Sampling::Bilinear, MissFill::Zero, &mut frame);
    let h = homography(&cam, anchor, DVec2::new(20.0, 40.0), width_m / n as f64);
    let h_inv = h.inverse();

    let mut checked = 0;
    let mut worst: f64 = 0.0;
    // along rows (v fixed) and along columns (u fixed)
    for along_rows in [true, false] {
        let (lines, len) = if along_rows { (96, 128) } else { (128, 96) };
        for line in 0..lines {
            let value = |k: usize| if along_rows { frame.get(k, line) } else { frame.get(line, k) } as f64;
            for k in 0..len - 1 {
                let (a, b) = (value(k), value(k + 1));
                if (a - 500.0) * (b - 500.0) >= 0.0 || a == b {
                    continue;
                }
                let t = k as f64 + 0.5 + (500.0 - a) / (b - a);
                let est = if along_rows { DVec2::new(t, line as f64 + 0.5) } else { DVec2::new(line as f64 + 0.5, t) };
                let s = apply(&h_inv, est);
                // which sky edge: the coordinate nearest a square boundary, away from corners
                let near = |c: f64| (c / SQUARE as f64).round() * SQUARE as f64;
                let (dx, dy) = ((s.x - near(s.x)).abs(), (s.y - near(s.y)).abs());
                let vertical_edge = dx < dy;
                if dx.min(dy) > 0.5
                    || dx.max(dy) < 0.75
                    || !(0.0..n as f64).contains(&s.x)
                    || !(0.0..n as f64).contains(&s.y)
                {
                    continue; // near a corner, where bilinear mixing is two-dimensional
                }
                // exact crossing of that edge's image with this sensor line
                let (p1, p2) = if vertical_edge {
                    (apply(&h, DVec2::new(near(s.x), s.y - 0.5)), apply(&h, DVec2::new(near(s.x), s.y + 0.5)))
                } else {
                    (apply(&h, DVec2::new(s.x - 0.5, near(s.y))), apply(&h, DVec2::new(s.x + 0.5, near(s.y))))
                };
                let want = if along_rows {
                    p1.x + (est.y - p1.y) * (p2.x - p1.x) / (p2.y - p1.y)
                } else {
                    p1.y + (est.x - p1.x) * (p2.y - p1.y) / (p2.x - p1.x)
                };
                let err = (t - want).abs();
                worst = worst.max(err);
                checked += 1;
                assert!(err <= 0.01, "line {line} rows={along_rows}: edge at {t}, homography says {want}");
            }
        }
    }
    eprintln!("checked {checked} edge crossings, worst {worst:.2e} px");
    assert!(checked > 100, "only {checked} edge crossings checked");
}

#[test]
fn sky_rendering_does_not_depend_on_thread_count() {
    let placement = SkyPlacement::paper_fig8();
    let cam_pos = DVec3::new(0.0, 0.0, 8000.0);
    let plane = SkyPlane::new(checkerboard(64), &placement, cam_pos).unwrap();
    let cam =
        Camera::look_at(Intrinsics::try_new(64, 48, 0.05, 17e-6).unwrap(), cam_pos, placement.anchor_m, 5.0).unwrap();
    for sampling in [Sampling::Nearest, Sampling::Bilinear, Sampling::Supersample { n: 3 }] {
        let mut a = Frame::new(64, 48);
        plane.render(&cam, sampling, MissFill::Edge, &mut a);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut b = Frame::new(64, 48);
        pool.install(|| plane.render(&cam, sampling, MissFill::Edge, &mut b));
        assert_eq!(a, b, "{sampling:?}");
    }
}

#[test]
fn sixteen_bit_sky_keeps_full_precision() {
    let dir = std::env::temp_dir().join(format!("irsim-sky16-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("sky.png");
    let data: Vec<u16> = (0..64u32).map(|i| (i * 1000 + 7) as u16).collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(8, 8, data.clone()).unwrap().save(&path).unwrap();
    let sky = SkyImage::load(&path).unwrap();
    assert_eq!(sky.pixels().iter().map(|&v| v as u16).collect::<Vec<_>>(), data);
    // 16-bit TIFF and PGM as well
    for ext in ["tiff", "pgm"] {
        let other = dir.join(format!("sky.{ext}"));
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(8, 8, data.clone()).unwrap().save(&other).unwrap();
        let sky = SkyImage::load(&other).unwrap();
        assert_eq!(sky.pixels().iter().map(|&v| v as u16).collect::<Vec<_>>(), data, "{ext}");
    }
    // float data keeps its fractions
    let float = dir.join("sky_f32.tiff");
    let rgb: Vec<f32> = (0..64).flat_map(|i| [i as f32 * 0.25; 3]).collect();
    image::DynamicImage::ImageRgb32F(image::ImageBuffer::from_raw(8, 8, rgb).unwrap()).save(&float).unwrap();
    let sky = SkyImage::load(&float).unwrap();
    assert!((sky.pixels()[5] - 1.25).abs() < 1e-6, "{}", sky.pixels()[5]);
    let err = SkyImage::load(&dir.join("missing.png")).unwrap_err().to_string();
    assert!(err.contains("missing.png"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

fn camera() -> Camera {
    Camera::new(Intrinsics::try_new(256, 256, 0.1, 17e-6).unwrap(), DVec3::ZERO, Default::default())
}

#[test]
fn ellipsoid_seen_along_each_axis() {
    let cam = camera();
    let f = cam.intrinsics.focal_px();
    let (a, b, c) = (6.0, 1.5, 2.5);
    let d = 400.0;
    // body axes laid along world axes so that the camera (looking along +y) sees along each body axis in turn
    let cases = [
        // body x along world y: outline semi-axes b (horizontal) and c (vertical), seen along a
        (DMat3::from_cols(DVec3::Y, -DVec3::X, DVec3::Z), b, c, a),
        // body y along world y: a horizontal, c vertical, seen along b
        (DMat3::from_cols(DVec3::X, DVec3::Y, DVec3::Z), a, c, b),
        // body z along world y: a horizontal, b vertical, seen along c
        (DMat3::from_cols(DVec3::X, DVec3::Z, -DVec3::Y), a, b, c),
    ];
    for (rot, horiz, vert, along) in cases {
        let e = Ellipsoid { center_m: DVec3::new(0.0, d, 0.0), semi_axes_m: DVec3::new(a, b, c), body_to_world: rot };
        let EllipsoidProjection::Visible(el) = project_ellipsoid(&e, &cam) else { panic!() };
        let sx = f * horiz / (d * d - along * along).sqrt();
        let sy = f * vert / (d * d - along * along).sqrt();
        let (major, minor) = if sx >= sy { (sx, sy) } else { (sy, sx) };
        assert!((el.a - major).abs() < 1e-9 && (el.b - minor).abs() < 1e-9, "{el:?} vs {major}, {minor}");
        assert!((el.center - DVec2::splat(128.0)).length() < 1e-9);
        let want_angle = if sx >= sy { 0.0 } else { std::f64::consts::FRAC_PI_2 };
        assert!((el.angle_rad.abs() - want_angle).abs() < 1e-9, "{}", el.angle_rad);
    }
}

#[test]
fn off_axis_sphere_outline_is_exact() {
    // A sphere off the axis: its outline is an ellipse elongated radially, centred beyond the centre's image.
    let cam = camera();
    let r = 20.0;
    let center = DVec3::new(150.0, 1000.0, -60.0);
    let e = Ellipsoid { center_m: center, semi_axes_m: DVec3::splat(r), body_to_world: DMat3::IDENTITY };
    let EllipsoidProjection::Visible(el) = project_ellipsoid(&e, &cam) else { panic!() };
    // every point on the outline is the image of a tangent ray: check by sampling the ellipse boundary
    let (s, c) = el.angle_rad.sin_cos();
    for k in 0..36 {
        let t = k as f64 * std::f64::consts::TAU / 36.0;
        let p = el.center + DVec2::new(c, s) * el.a * t.cos() + DVec2::new(-s, c) * el.b * t.sin();
        let dir = cam.ray(p);
        let to_center = center - cam.position_m;
        let dist = (to_center - dir * to_center.dot(dir)).length();
        assert!((dist - r).abs() < 1e-6, "outline point {p}: ray passes {dist} m from the centre");
    }
    let Projection::InFront { pixel, .. } = cam.project(center) else { panic!() };
    assert!((el.center - pixel).length() > 1e-3, "outline centre differs from the centre's image");
}

fn centroid(frame: &Frame) -> DVec2 {
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for y in 0..frame.height() {
        for x in 0..frame.width() {
            let v = frame.get(x, y) as f64;
            sx += v * (x as f64 + 0.5);
            sy += v * (y as f64 + 0.5);
            s += v;
        }
    }
    DVec2::new(sx / s, sy / s)
}

#[test]
fn blob_centroid_matches_the_projected_centre() {
    let shapes = [
        (0.3, 0.3, 0.0, 2.0),
        (1.5, 1.5, 0.0, 2.0),
        (4.0, 1.0, 0.5, 2.0),
        (3.0, 2.0, std::f64::consts::FRAC_PI_6, 3.0),
    ];
    let mut worst: f64 = 0.0;
    for (a, b, angle, beta) in shapes {
        for sampling in [BlobSampling::Auto, BlobSampling::Integrated { n: 8 }] {
            for i in 0..10 {
                for j in 0..10 {
                    let center = DVec2::new(32.0 + i as f64 / 10.0, 31.0 + j as f64 / 10.0);
                    let el = ImageEllipse { center, a, b, angle_rad: angle };
                    let blob = GeneralizedGaussian::from_ellipse(&el, 0.7, beta, 1000.0);
                    let mut frame = Frame::new(64, 64);
                    blob.add_to(&mut frame, 1e-9, sampling);
                    let err = (centroid(&frame) - center).length();
                    worst = worst.max(err);
                    assert!(err <= 0.02, "a={a} b={b} angle={angle} {sampling:?} centre {center}: error {err}");
                }
            }
        }
    }
    eprintln!("worst centroid error {worst:.2e} px");
}

#[test]
fn blob_shapes() {
    let base = GeneralizedGaussian {
        center: DVec2::new(20.0, 20.0),
        alpha_x: 3.0,
        alpha_y: 2.0,
        beta_x: 2.0,
        beta_y: 2.0,
        angle_rad: std::f64::consts::FRAC_PI_4,
        peak: 1.0,
    };
    // ρ = π/4 is not degenerate: second moments give back the two scales (Gaussian: variance α²/2)
    let mut frame = Frame::new(40, 40);
    base.add_to(&mut frame, 1e-12, BlobSampling::Integrated { n: 8 });
    let c = centroid(&frame);
    let (mut sxx, mut syy, mut sxy, mut s) = (0.0, 0.0, 0.0, 0.0);
    for y in 0..40 {
        for x in 0..40 {
            let v = frame.get(x, y) as f64;
            let d = DVec2::new(x as f64 + 0.5, y as f64 + 0.5) - c;
            sxx += v * d.x * d.x;
            syy += v * d.y * d.y;
            sxy += v * d.x * d.y;
            s += v;
        }
    }
    let (sxx, syy, sxy) = (sxx / s, syy / s, sxy / s);
    let mean = 0.5 * (sxx + syy);
    let diff = (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
    // pixel integration adds 1/12 px² of variance per axis
    let (big, small) = (mean + diff - 1.0 / 12.0, mean - diff - 1.0 / 12.0);
    assert!((big - 4.5).abs() < 0.01 && (small - 2.0).abs() < 0.01, "{big} {small}");
    // β = 2: exp(−1) at one scale length along each axis
    let g = GeneralizedGaussian { angle_rad: 0.0, ..base };
    assert!((g.value(DVec2::new(23.0, 20.0)) - (-1.0f64).exp()).abs() < 1e-12);
    assert!((g.value(DVec2::new(20.0, 22.0)) - (-1.0f64).exp()).abs() < 1e-12);
    // large β: flat top inside the scale, nothing outside
    let flat = GeneralizedGaussian { beta_x: 200.0, beta_y: 200.0, angle_rad: 0.0, ..base };
    assert!(flat.value(DVec2::new(22.7, 21.7)) > 0.99);
    assert!(flat.value(DVec2::new(23.3, 20.0)) < 1e-3);
    assert!(flat.value(DVec2::new(20.0, 22.2)) < 1e-3);
}

/// A background with texture and a blob patch on a region.
fn scene(w: usize, h: usize, seed: u64) -> (Frame, GeneralizedGaussian) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut frame = Frame::new(w, h);
    for p in frame.pixels_mut() {
        *p = 0.3 + 0.2 * rng.random::<f32>();
    }
    let blob = GeneralizedGaussian {
        center: DVec2::new(w as f64 / 2.0 + 0.3, h as f64 / 2.0 - 0.2),
        alpha_x: 4.0,
        alpha_y: 2.5,
        beta_x: 2.0,
        beta_y: 2.0,
        angle_rad: 0.4,
        peak: 0.4,
    };
    (frame, blob)
}

fn region(frame: &Frame, blob: &GeneralizedGaussian) -> (PixelRect, Vec<f32>) {
    let rect = blob.region_of_interest(1e-3, frame.width(), frame.height());
    let mut patch = vec![0.0; rect.width() * rect.height()];
    blob.render_patch(rect, BlobSampling::Point, &mut patch);
    (rect, patch)
}

fn region_values(frame: &Frame, rect: PixelRect) -> Vec<f64> {
    let mut v = Vec::new();
    for y in rect.y0..rect.y1 {
        for x in rect.x0..rect.x1 {
            v.push(frame.get(x, y) as f64);
        }
    }
    v
}

#[test]
fn direct_solver_satisfies_the_discrete_equation_in_f64() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut fusion = PoissonFusion::new();
    for (nx, ny) in [(1, 1), (5, 3), (14, 14), (62, 62), (126, 125)] {
        let rhs: Vec<f64> = (0..nx * ny).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut x = rhs.clone();
        fusion.solve_dirichlet(nx, ny, &mut x);
        let at = |i: isize, j: isize| {
            if i < 0 || j < 0 || i >= nx as isize || j >= ny as isize { 0.0 } else { x[j as usize * nx + i as usize] }
        };
        let mut worst: f64 = 0.0;
        for j in 0..ny as isize {
            for i in 0..nx as isize {
                let lap = 4.0 * at(i, j) - at(i - 1, j) - at(i + 1, j) - at(i, j - 1) - at(i, j + 1);
                worst = worst.max((lap - rhs[j as usize * nx + i as usize]).abs());
            }
        }
        assert!(worst <= 1e-9, "{nx}×{ny}: residual {worst}");
    }
}

#[test]
fn fusion_solves_the_equation_keeps_the_boundary_and_touches_nothing_else() {
    // the f64 solve to the f32 frame's rounding; the f32 one (of the difference from the background) to its own
    let cases = [Guidance::Normal, Guidance::Mixed]
        .into_iter()
        .flat_map(|g| [(g, Solver::Direct, 1e-4), (g, Solver::DirectF32, RESIDUAL_F32)]);
    for (guidance, solver, bound) in cases {
        let (mut frame, blob) = scene(64, 48, 1);
        let before = frame.clone();
        let (patch_rect, patch) = region(&frame, &blob);
        let mut fusion = PoissonFusion::new();
        fusion.fuse(&mut frame, &[Patch { rect: patch_rect, values: &patch }], guidance, solver);
        let rect = fusion.regions()[0];
        assert!(
            rect.x0 <= patch_rect.x0
                && rect.x1 >= patch_rect.x1
                && rect.y0 <= patch_rect.y0
                && rect.y1 >= patch_rect.y1
        );
        // the patch on the (possibly grown) region
        let mut u = vec![0.0; rect.width() * rect.height()];
        for y in patch_rect.y0..patch_rect.y1 {
            for x in patch_rect.x0..patch_rect.x1 {
                u[(y - rect.y0) * rect.width() + x - rect.x0] =
                    f64::from(patch[(y - patch_rect.y0) * patch_rect.width() + x - patch_rect.x0]);
            }
        }
        let bg = region_values(&before, rect);
        let res = max_residual(&frame, rect, &u, &bg, guidance);
        assert!(res <= bound, "{guidance:?}, {solver:?}: residual {res}");
        for y in 0..48 {
            for x in 0..64 {
                let inside = x > rect.x0 && x + 1 < rect.x1 && y > rect.y0 && y + 1 < rect.y1;
                if !inside {
                    assert_eq!(frame.get(x, y), before.get(x, y), "({x}, {y}) changed outside the interior");
                }
            }
        }
        assert_ne!(frame, before);
    }
}

/// Largest residual of the fused equation that [`Solver::DirectF32`] may leave on the test scene (measured
/// 5.1e-7 with the normal guidance, 2.8e-7 with the mixed; the f64 solve 1.2e-7 and 1.5e-7).
const RESIDUAL_F32: f64 = 1e-5;

#[test]
fn one_fusion_engine_gives_each_frame_what_a_fresh_one_does_with_either_direct_solver() {
    // regions growing and shrinking from frame to frame, two at once (solved side by side on their own buffers),
    // the two direct solvers in turn on one engine
    let (w, h) = (120, 90);
    let bg: Vec<f32> = (0..w * h).map(|i| 500.0 + ((i * 7919) % 613) as f32).collect();
    let mut engine = PoissonFusion::new();
    for (k, size) in [9usize, 17, 33, 12, 40, 40].into_iter().enumerate() {
        let solver = if k % 2 == 0 { Solver::DirectF32 } else { Solver::Direct };
        let patches: Vec<(PixelRect, Vec<f32>)> = [(5, 5), (60, 40)]
            .into_iter()
            .map(|(x0, y0)| {
                let rect = PixelRect { x0, y0, x1: x0 + size, y1: y0 + size };
                (rect, (0..size * size).map(|i| ((i * 31) % 97) as f32).collect())
            })
            .collect();
        let list: Vec<Patch<'_>> = patches.iter().map(|(rect, values)| Patch { rect: *rect, values }).collect();
        let mut reused = Frame::from_pixels(w, h, bg.clone());
        let stats = engine.fuse(&mut reused, &list, Guidance::Normal, solver);
        assert_eq!(stats.regions, 2, "two regions, size {size}");
        let mut fresh = Frame::from_pixels(w, h, bg.clone());
        PoissonFusion::new().fuse(&mut fresh, &list, Guidance::Normal, solver);
        assert_ne!(reused.pixels(), &bg[..]);
        let same = reused.pixels().iter().zip(fresh.pixels()).all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "frame {k}: {solver:?} on a reused engine, size {size}");
    }
}

#[test]
fn direct_solution_equals_converged_jacobi_and_sor() {
    let (frame0, blob) = scene(40, 36, 2);
    let (rect, patch) = region(&frame0, &blob);
    let patches = [Patch { rect, values: &patch }];
    let mut fusion = PoissonFusion::new();
    let mut direct = frame0.clone();
    fusion.fuse(&mut direct, &patches, Guidance::Normal, Solver::Direct);
    for solver in [
        Solver::Jacobi { tolerance: 1e-9, max_iterations: 200_000 },
        Solver::Sor { tolerance: 1e-10, max_iterations: 20_000 },
    ] {
        let mut it = frame0.clone();
        let stats = fusion.fuse(&mut it, &patches, Guidance::Normal, solver);
        let worst = direct.pixels().iter().zip(it.pixels()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst <= 1e-5, "{solver:?}: max difference {worst} after {} iterations", stats.iterations);
    }
}

#[test]
fn overlapping_targets_are_solved_together_and_clipped_at_the_edge() {
    let (mut frame, blob) = scene(64, 48, 4);
    let other = GeneralizedGaussian { center: blob.center + DVec2::new(5.0, 1.0), ..blob };
    let edge = GeneralizedGaussian { center: DVec2::new(1.0, 46.5), ..blob };
    let mut patches_data = Vec::new();
    for b in [blob, other, edge] {
        patches_data.push(region(&frame, &b));
    }
    let patches: Vec<Patch> = patches_data.iter().map(|(r, v)| Patch { rect: *r, values: v }).collect();
    let mut fusion = PoissonFusion::new();
    let stats = fusion.fuse(&mut frame, &patches, Guidance::Normal, Solver::Direct);
    assert_eq!(stats.regions, 2);
    assert!(frame.pixels().iter().all(|v| v.is_finite()));
}

#[test]
fn additive_adds_the_patch() {
    let (mut frame, blob) = scene(32, 32, 5);
    let before = frame.clone();
    let (rect, patch) = region(&frame, &blob);
    PoissonFusion::new().fuse(&mut frame, &[Patch { rect, values: &patch }], Guidance::Additive, Solver::Direct);
    let (x, y) = (rect.x0 + 3, rect.y0 + 2);
    let p = patch[2 * rect.width() + 3];
    assert!((frame.get(x, y) - (before.get(x, y) + p)).abs() < 1e-6);
}
