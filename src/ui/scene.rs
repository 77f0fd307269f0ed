//! The 3D encounter view: the ground grid with a km scale, the sky plane's outline, trajectories (past solid,
//! future dashed), each aircraft's ellipsoid at its true pose (enlarged by a shown factor where it would be
//! smaller than a few screen pixels), the observer and the sensor's view frustum, drawn as lines; an orbit
//! camera (left drag orbits, right drag pans, wheel zooms, F focuses the first target in the frame).

use bevy::camera::RenderTarget;
use bevy::input::mouse::{AccumulatedMouseMotion, AccumulatedMouseScroll};
use bevy::prelude::*;
use bevy::window::PrimaryWindow;
use glam::DVec3;

use super::Viewer;
use crate::sim::{Aircraft, Body, CameraPose, FlightPath, Kinematics, Observer, SimClock, Sky};

/// World coordinates (m; x east, y north, z up) to the view's (km; Bevy's x right, y up, z toward the viewer):
/// the one place where z-up becomes y-up.
pub fn to_view(p_m: DVec3) -> Vec3 {
    Vec3::new((p_m.x * 1e-3) as f32, (p_m.z * 1e-3) as f32, (-p_m.y * 1e-3) as f32)
}

/// The orbit camera's state.
#[derive(Component, Debug, Clone, Copy)]
pub struct Orbit {
    /// The point orbited, view km.
    pub focus: Vec3,
    /// Azimuth, rad.
    pub yaw: f32,
    /// Elevation, rad.
    pub pitch: f32,
    /// Distance from the focus, km.
    pub distance: f32,
}

impl Orbit {
    fn transform(&self) -> Transform {
        let dir = Vec3::new(self.yaw.sin() * self.pitch.cos(), self.pitch.sin(), self.yaw.cos() * self.pitch.cos());
        Transform::from_translation(self.focus + dir * self.distance).looking_at(self.focus, Vec3::Y)
    }

    /// The distance from the focus (same direction) at which every point lies inside the middle `fill` of a
    /// picture of vertical field of view `fov_y` (rad) and width / height `aspect`.
    fn fit(&self, points: &[Vec3], fov_y: f32, aspect: f32, fill: f32) -> f32 {
        let t = Orbit { distance: 1.0, ..*self }.transform();
        let (right, up, forward) = (t.right(), t.up(), t.forward());
        let tan_y = (fov_y / 2.0).tan() * fill;
        let tan_x = tan_y * aspect;
        points
            .iter()
            .map(|p| {
                let v = *p - self.focus;
                // the point's depth in front of the camera is the distance plus v along the view direction
                let depth_ahead = v.dot(*forward);
                (v.dot(*right).abs() / tan_x).max(v.dot(*up).abs() / tan_y) - depth_ahead
            })
            .filter(|d| d.is_finite())
            .fold(0.05, f32::max)
    }
}

/// What the opening view frames, fitted to the view's shape once it is laid out (and again while the panels
/// settle), until the user moves the view.
#[derive(Resource, Debug, Default)]
pub struct OpeningFrame {
    points: Vec<Vec3>,
    touched: bool,
}

/// The picture the 3D camera draws, copied into the view's rectangle in egui's pass (`blit`). A texture of the
/// view's own size keeps the picture between frames the camera does not draw (`pace_view`).
#[derive(Resource, Debug, Clone)]
pub struct ViewImage {
    /// The render target.
    pub handle: Handle<Image>,
    /// Its size, physical pixels.
    pub size: UVec2,
    /// While playing, the camera draws every this many displayed frames (see [`pace_view`]).
    pub every: u32,
    /// What the picture was drawn from, and how many displayed frames ago.
    drawn: Option<ViewKey>,
    since: u32,
    displayed: u64,
}

/// What the 3D view's picture depends on, bit for bit: the camera's pose, the frame on show, the scenario's
/// revision and the picture's size.
#[derive(Debug, Clone, PartialEq, Eq)]
struct ViewKey {
    pose: [u32; 7],
    shown: Option<u64>,
    revision: u64,
    size: UVec2,
}

/// The 3D camera draws only when its picture would change: while the simulation plays under software rendering,
/// at most every second displayed frame (the sensor image still shows every frame; a CPU renderer spends as much
/// on the 3D view as on all the panels), on a GPU every frame; while paused, when the view is moved or the
/// frame changes. It also draws through the first 60 displayed frames (pipelines compile in the background and
/// an early picture can miss a mesh) and at least every 30th, so a picture is never stale for long.
pub fn pace_view(
    viewer: Res<Viewer>,
    adapter: Option<Res<bevy::render::renderer::RenderAdapterInfo>>,
    mut view_image: ResMut<ViewImage>,
    mut camera: Query<(&mut Camera, &Transform), With<Orbit>>,
) {
    let Ok((mut cam, transform)) = camera.single_mut() else { return };
    let software = adapter.is_some_and(|a| a.0.device_type == wgpu_types::DeviceType::Cpu);
    view_image.every = if software { 2 } else { 1 };
    let (t, r) = (transform.translation, transform.rotation);
    let key = ViewKey {
        pose: [t.x, t.y, t.z, r.x, r.y, r.z, r.w].map(f32::to_bits),
        shown: viewer.playback.shown,
        revision: viewer.built_revision,
        size: view_image.size,
    };
    let v = &mut *view_image;
    v.displayed += 1;
    v.since = v.since.saturating_add(1);
    let changed = v.drawn.as_ref() != Some(&key);
    let due = v.displayed <= 60 || v.since >= 30;
    let paced = !viewer.playback.playing || v.since >= v.every;
    let draw = due || (changed && paced);
    if draw {
        v.drawn = Some(key);
        v.since = 0;
    }
    if cam.is_active != draw {
        cam.is_active = draw;
    }
}

/// How each aircraft's ellipsoid is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drawn {
    /// The target's id.
    pub id: u32,
    /// Enlargement (1 where it is large enough on screen).
    pub factor: f32,
    /// Its largest diameter on screen as drawn, physical pixels.
    pub size_px: f32,
}

/// How each aircraft's ellipsoid is drawn this frame.
#[derive(Resource, Debug, Default, Clone)]
pub struct DrawScale(pub Vec<Drawn>);

impl DrawScale {
    /// The target's entry, if it has one.
    pub fn get(&self, id: u32) -> Option<Drawn> {
        self.0.iter().find(|d| d.id == id).copied()
    }
}

/// The 3D camera, framing every trajectory over the run and the observer, seen from behind and above the
/// observer's line of sight. (The sky plane, 6 to 60 times farther from them than their own extent in the shipped
/// scenarios, is a backdrop: framing it would shrink the encounter to a speck.)
pub fn spawn_view_camera(
    mut commands: Commands,
    mut images: ResMut<Assets<Image>>,
    viewer: Res<Viewer>,
    paths: Query<&FlightPath>,
    observer: Query<&FlightPath, With<Observer>>,
    targets: Query<&FlightPath, With<Aircraft>>,
) {
    let spec = &viewer.built.spec;
    let (t0, dt) = (spec.run.start_time_s, 1.0 / spec.run.frame_rate_hz);
    let t1 = t0 + (spec.run.frames.max(2) - 1) as f64 * dt;
    let mut points: Vec<Vec3> = Vec::new();
    for fp in &paths {
        points.extend((0..=32).map(|i| to_view(fp.0.state(t0 + (t1 - t0) * f64::from(i) / 32.0).0)));
    }
    let (focus, radius) = bounding_sphere(&points);
    // look from the observer toward the targets at mid-run, from 20° to the left and 10° above: low enough that
    // a sky plane behind the targets stands in the background
    let t_mid = (t0 + t1) / 2.0;
    let eye = observer.single().map_or(DVec3::ZERO, |fp| fp.0.state(t_mid).0);
    let n = targets.iter().count().max(1) as f64;
    let aim = targets.iter().map(|fp| fp.0.state(t_mid).0).sum::<DVec3>() / n;
    let boresight = if targets.is_empty() { Vec3::NEG_Z } else { to_view(aim) - to_view(eye) };
    let yaw = (-boresight.x).atan2(-boresight.z) + 20_f32.to_radians();
    // the view is narrower than high in the default layout: fit the sphere in a width half the height
    let half_fov_h = ((PerspectiveProjection::default().fov / 2.0).tan() * 0.5).atan();
    let orbit = Orbit { focus, yaw, pitch: 10_f32.to_radians(), distance: radius / half_fov_h.sin() * 1.1 };
    commands.insert_resource(OpeningFrame { points, touched: false });
    // resized to the view's rectangle by `orbit_camera` once the panels are laid out
    let size = UVec2::splat(64);
    let image = Image::new_target_texture(size.x, size.y, wgpu_types::TextureFormat::Rgba8UnormSrgb, None);
    let handle = images.add(image);
    commands.insert_resource(ViewImage { handle: handle.clone(), size, every: 1, drawn: None, since: 0, displayed: 0 });
    commands.spawn((
        Camera3d::default(),
        Camera { order: 0, clear_color: ClearColorConfig::Custom(BACKGROUND), ..default() },
        RenderTarget::Image(handle.into()),
        Projection::Perspective(PerspectiveProjection { near: 0.01, far: 1e5, ..default() }),
        Msaa::Off,
        // lines need no tonemapping (and its lookup tables are not built in)
        bevy::core_pipeline::tonemapping::Tonemapping::None,
        orbit.transform(),
        orbit,
    ));
    commands.insert_resource(DrawScale::default());
}

/// The part of the view's width and height the opening view's points fill at most.
const OPENING_FILL: f32 = 0.9;

/// The centre of the points' bounding box and the farthest point's distance from it (at least 0.5 km).
fn bounding_sphere(points: &[Vec3]) -> (Vec3, f32) {
    let (lo, hi) = points
        .iter()
        .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let centre = if points.is_empty() { Vec3::ZERO } else { (lo + hi) / 2.0 };
    (centre, points.iter().map(|p| p.distance(centre)).fold(0.5_f32, f32::max))
}

/// Orbit, pan, zoom and focus from the mouse and F, only while the pointer is over the 3D view and egui does
/// not want it; keeps the camera's picture the size of the view's rectangle.
#[allow(clippy::too_many_arguments)]
pub fn orbit_camera(
    viewer: Res<Viewer>,
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    motion: Res<AccumulatedMouseMotion>,
    scroll: Res<AccumulatedMouseScroll>,
    egui: Res<bevy_egui::input::EguiWantsInput>,
    window: Single<&Window, With<PrimaryWindow>>,
    mut view_image: ResMut<ViewImage>,
    mut images: ResMut<Assets<Image>>,
    mut camera: Query<(&mut Transform, &mut Orbit, &Projection)>,
    targets: Query<(&Aircraft, &Kinematics)>,
    mut opening: ResMut<OpeningFrame>,
) {
    let Ok((mut transform, mut orbit, projection)) = camera.single_mut() else { return };
    let [x0, y0, x1, y1] = viewer.view_rect;
    let scale = window.scale_factor();
    let most = UVec2::new(window.physical_width(), window.physical_height()).max(UVec2::ONE);
    let size =
        UVec2::new(((x1 - x0) * scale).round() as u32, ((y1 - y0) * scale).round() as u32).clamp(UVec2::ONE, most);
    if size != view_image.size
        && let Some(mut image) = images.get_mut(&view_image.handle)
    {
        image.resize(wgpu_types::Extent3d { width: size.x, height: size.y, depth_or_array_layers: 1 });
        view_image.size = size;
        if !opening.touched
            && let Projection::Perspective(p) = projection
        {
            orbit.distance = orbit.fit(&opening.points, p.fov, size.x as f32 / size.y as f32, OPENING_FILL);
        }
    }
    let over_view = window.cursor_position().is_some_and(|c| c.x >= x0 && c.x < x1 && c.y >= y0 && c.y < y1);
    let free = over_view && !egui.wants_pointer_input() && !egui.is_using_pointer();
    if free {
        let d = motion.delta;
        let pressed = buttons.pressed(MouseButton::Left) || buttons.pressed(MouseButton::Right);
        if pressed && d != Vec2::ZERO || scroll.delta.y != 0.0 {
            opening.touched = true;
        }
        if buttons.pressed(MouseButton::Left) {
            orbit.yaw -= d.x * 0.005;
            orbit.pitch = (orbit.pitch + d.y * 0.005).clamp(-1.5, 1.5);
        }
        if buttons.pressed(MouseButton::Right) {
            let t = orbit.transform();
            let k = orbit.distance * 0.0015;
            orbit.focus += (-t.right() * d.x + t.up() * d.y) * k;
        }
        if scroll.delta.y != 0.0 {
            orbit.distance = (orbit.distance * (1.0 - 0.1 * scroll.delta.y.clamp(-5.0, 5.0))).clamp(0.01, 1e4);
        }
    }
    if keys.just_pressed(KeyCode::KeyF) && !egui.wants_keyboard_input() {
        let first = viewer.labels.targets.iter().find(|t| t.in_frame).or(viewer.labels.targets.first()).map(|t| t.id);
        if let Some((_, k)) = targets.iter().find(|(a, _)| Some(a.id) == first) {
            opening.touched = true;
            orbit.focus = to_view(k.position_m);
            orbit.distance = orbit.distance.min(5.0);
        }
    }
    *transform = orbit.transform();
}

/// Draws the encounter.
#[allow(clippy::too_many_arguments)]
pub fn draw_encounter(
    mut gizmos: Gizmos,
    clock: Res<SimClock>,
    viewer: Res<Viewer>,
    mut scale: ResMut<DrawScale>,
    view_image: Res<ViewImage>,
    camera: Query<(&Transform, &Projection), With<Orbit>>,
    observer: Query<(&CameraPose, &FlightPath), With<Observer>>,
    aircraft: Query<(&Aircraft, &Kinematics, &Body, &FlightPath)>,
    sky: Query<&Sky>,
) {
    let Ok((view_t, projection)) = camera.single() else { return };
    // screen pixels per km at 1 km distance, to size the ellipsoids
    let fov = match projection {
        Projection::Perspective(p) => p.fov,
        _ => 0.8,
    };
    let px_per_rad = view_image.size.y as f32 / fov;
    scale.0.clear();
    for (a, k, body, _) in &aircraft {
        let distance = to_view(k.position_m).distance(view_t.translation).max(1e-6);
        let size_px = (body.semi_axes_m.max_element() as f32 * 1e-3 / distance) * px_per_rad;
        let factor = if size_px < MIN_DRAWN_PX { MIN_DRAWN_PX / size_px.max(1e-6) } else { 1.0 };
        // the ellipsoid itself is a mesh (`meshes::sync_ellipsoids`)
        scale.0.push(Drawn { id: a.id, factor, size_px: 2.0 * size_px * factor });
    }
    let spec = &viewer.built.spec;
    let t_now = viewer.playback.shown.map_or(clock.t_s(), |k| spec.run.start_time_s + k as f64 * clock.dt_s);
    let t0 = spec.run.start_time_s;
    let t1 = t0 + (viewer.playback.frames.max(2) - 1) as f64 * clock.dt_s;
    // ground grid, 1 km cells, 40 km across, with a 10 km scale bar
    gizmos.grid(
        Isometry3d::from_rotation(Quat::from_rotation_x(std::f32::consts::FRAC_PI_2)),
        UVec2::splat(40),
        Vec2::splat(1.0),
        Color::srgba(0.5, 0.5, 0.5, 0.25),
    );
    gizmos.line(Vec3::new(0.0, 0.01, 0.0), Vec3::new(10.0, 0.01, 0.0), Color::srgb(0.9, 0.9, 0.9));
    // sky plane outline
    if let Ok(sky) = sky.single()
        && let Some(plane) = sky.plane_geometry()
    {
        let (w, h) = (plane.image().width() as f64, plane.image().height() as f64);
        let corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h), (0.0, 0.0)]
            .map(|(x, y)| to_view(plane.world_point(glam::DVec2::new(x, y))));
        gizmos.linestrip(corners, Color::srgb(0.3, 0.6, 1.0));
    }
    let path = |gizmos: &mut Gizmos, fp: &FlightPath, color: Color| {
        const N: usize = 120;
        let at = |i: usize| to_view(fp.0.state(t0 + (t1 - t0) * i as f64 / N as f64).0);
        let now = to_view(fp.0.state(t_now).0);
        let split = (((t_now - t0) / (t1 - t0).max(1e-9)) * N as f64).clamp(0.0, N as f64) as usize;
        gizmos.linestrip((0..=split).map(at).chain(std::iter::once(now)), color);
        // the future dashed
        let mut prev = now;
        for i in split + 1..=N {
            let p = at(i);
            if i % 2 == 0 {
                gizmos.line(prev, p, color.with_alpha(0.5));
            }
            prev = p;
        }
    };
    for (a, _, _, fp) in &aircraft {
        path(&mut gizmos, fp, palette(a.id));
    }
    if let Ok((pose, fp)) = observer.single() {
        path(&mut gizmos, fp, Color::srgb(0.9, 0.9, 0.9));
        let cam = pose.current;
        let eye = to_view(cam.position_m);
        gizmos.cross(Isometry3d::from_translation(eye), 0.3, Color::WHITE);
        // the frustum to the farthest target (at least 2 km)
        let reach = aircraft.iter().map(|(_, k, _, _)| k.position_m.distance(cam.position_m)).fold(2000.0, f64::max);
        let plane = sky.single().ok().and_then(|s| s.plane_geometry());
        let (w, h) = (f64::from(cam.intrinsics.width), f64::from(cam.intrinsics.height));
        let f = cam.intrinsics.focal_px();
        // each corner's ray to the sky plane where it meets it ahead (within 100 km): the frustum ends on the part
        // of the sky image the sensor sees; otherwise to the farthest target
        let corner = |u: f64, v: f64| {
            let d = cam.camera_to_world * DVec3::new((u - w / 2.0) / f, (v - h / 2.0) / f, 1.0);
            let on_plane = plane.and_then(|p| {
                let (a, n) = (p.world_point(glam::DVec2::ZERO), p.normal());
                let t = (a - cam.position_m).dot(n) / d.dot(n);
                (t.is_finite() && t > 0.0 && t * d.length() < 1e5).then_some(t)
            });
            to_view(cam.position_m + d * on_plane.unwrap_or(reach))
        };
        let c = [corner(0.0, 0.0), corner(w, 0.0), corner(w, h), corner(0.0, h)];
        let frustum = Color::srgb(1.0, 0.85, 0.2);
        for p in c {
            gizmos.line(eye, p, frustum.with_alpha(0.6));
        }
        gizmos.linestrip([c[0], c[1], c[2], c[3], c[0]], frustum);
    }
}

/// An aircraft is drawn at least this large on screen (px), enlarged by the factor the targets table shows.
const MIN_DRAWN_PX: f32 = 8.0;

/// The window's background: the 3D view's and, since they paint none, the panels'.
pub const BACKGROUND: Color = Color::srgb(0.106, 0.106, 0.106);

/// A colour per target id.
pub fn palette(id: u32) -> Color {
    const COLORS: [(f32, f32, f32); 6] =
        [(1.0, 0.35, 0.3), (0.3, 0.85, 0.4), (0.35, 0.6, 1.0), (1.0, 0.7, 0.2), (0.8, 0.4, 1.0), (0.2, 0.9, 0.9)];
    let (r, g, b) = COLORS[(id as usize).wrapping_sub(1) % COLORS.len()];
    Color::srgb(r, g, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Where `p` lands in the picture, as fractions of its half width and half height from the centre.
    fn on_screen(orbit: &Orbit, p: Vec3, fov_y: f32, aspect: f32) -> (f32, f32) {
        let t = orbit.transform();
        let v = p - t.translation;
        let depth = v.dot(*t.forward());
        let tan_y = (fov_y / 2.0).tan();
        (v.dot(*t.right()) / depth / (tan_y * aspect), v.dot(*t.up()) / depth / tan_y)
    }

    #[test]
    fn the_opening_view_fits_its_points_to_the_pictures_shape() {
        let points = [Vec3::new(-3.0, 0.5, 1.0), Vec3::new(4.0, 2.0, -6.0), Vec3::new(0.5, -1.0, 3.0)];
        let fov = 0.8;
        for aspect in [0.4, 1.0, 2.5] {
            let mut orbit = Orbit { focus: Vec3::new(0.5, 0.5, -1.0), yaw: 0.7, pitch: 0.2, distance: 1.0 };
            orbit.distance = orbit.fit(&points, fov, aspect, 0.9);
            let spots: Vec<(f32, f32)> = points.iter().map(|p| on_screen(&orbit, *p, fov, aspect)).collect();
            // every point inside the middle 90 %, and one on its edge (no closer would do)
            assert!(spots.iter().all(|(x, y)| x.abs() <= 0.9 + 1e-4 && y.abs() <= 0.9 + 1e-4), "{aspect}: {spots:?}");
            let widest = spots.iter().map(|(x, y)| x.abs().max(y.abs())).fold(0.0, f32::max);
            assert!((widest - 0.9).abs() < 1e-3, "{aspect}: {widest}");
        }
        // nothing to frame: a small distance, not a NaN
        let orbit = Orbit { focus: Vec3::ZERO, yaw: 0.0, pitch: 0.0, distance: 1.0 };
        assert_eq!(orbit.fit(&[], fov, 1.0, 0.9), 0.05);
    }
}
