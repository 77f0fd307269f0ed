//! The 3D view's solid things: the sky plane as a textured quad where the scenario puts it (its radiance image
//! stretched as the sensor panel stretches frames, in the panel's colour map), and each aircraft as an ellipsoid
//! mesh at its true pose, enlarged by the factor [`super::scene::DrawScale`] shows where it would be smaller than a
//! few screen pixels. Both use [`ViewMaterial`], an unlit (sky) or simply shaded (ellipsoids) material whose
//! fragment shader is a texture read and a dot product: under software rendering the view's cost is fill, and
//! Bevy's `StandardMaterial` costs several times more per pixel.

use std::sync::Arc;

use bevy::asset::RenderAssetUsages;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use bevy::render::render_resource::AsBindGroup;
use bevy::shader::ShaderRef;
use glam::DVec2;
use wgpu_types::{Extent3d, TextureDimension, TextureFormat};

use super::Viewer;
use super::scene::{DrawScale, palette, to_view};
use super::state::{ColorMap, Stretch, StretchScratch, display_window, to_rgba};
use crate::imaging::frame::Frame;
use crate::imaging::sky_plane::SkyPlane;
use crate::sim::{Aircraft, Body, Kinematics, Sky};

/// The longest side of the sky texture, px: larger sky images are box-averaged down to it.
const SKY_TEXTURE_MAX_PX: usize = 1024;

/// Registers the material and its embedded shader.
pub struct ViewMeshesPlugin;

impl Plugin for ViewMeshesPlugin {
    fn build(&self, app: &mut App) {
        bevy::asset::embedded_asset!(app, "view_material.wgsl");
        app.add_plugins(MaterialPlugin::<ViewMaterial>::default()).init_resource::<SkyQuad>();
    }
}

/// A colour times a texture, unlit or shaded by a fixed light (see `view_material.wgsl`).
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct ViewMaterial {
    /// Linear colour (alpha blends when below 1).
    #[uniform(0)]
    pub color: LinearRgba,
    /// `x` = 1 shades by a fixed light; the rest is padding.
    #[uniform(0)]
    pub shade: Vec4,
    /// The texture (white when `None`).
    #[texture(1)]
    #[sampler(2)]
    pub texture: Option<Handle<Image>>,
}

impl Material for ViewMaterial {
    fn fragment_shader() -> ShaderRef {
        "embedded://irsim/ui/view_material.wgsl".into()
    }

    fn alpha_mode(&self) -> AlphaMode {
        if self.color.alpha < 1.0 { AlphaMode::Blend } else { AlphaMode::Opaque }
    }
}

/// The sky quad on show: which plane and colour map it was made from.
#[derive(Resource, Default)]
pub(super) struct SkyQuad {
    entity: Option<Entity>,
    plane: Option<Arc<SkyPlane>>,
    map: Option<ColorMap>,
}

/// Keeps the sky quad in step with the world's sky plane (rebuilt after an edit) and the panel's colour map.
pub(super) fn sync_sky_quad(
    mut commands: Commands,
    viewer: Res<Viewer>,
    sky: Query<&Sky>,
    mut quad: ResMut<SkyQuad>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut images: ResMut<Assets<Image>>,
    mut materials: ResMut<Assets<ViewMaterial>>,
) {
    let plane = sky.iter().find_map(|s| s.plane().cloned());
    let same_plane = match (&plane, &quad.plane) {
        (Some(a), Some(b)) => Arc::ptr_eq(a, b),
        (None, None) => true,
        _ => false,
    };
    if same_plane && quad.map == Some(viewer.color_map) {
        return;
    }
    if let Some(e) = quad.entity.take() {
        commands.entity(e).despawn();
    }
    quad.plane = plane.clone();
    quad.map = Some(viewer.color_map);
    let Some(plane) = plane else { return };
    let image = images.add(sky_texture(&plane, viewer.color_map));
    let material = materials.add(ViewMaterial { color: LinearRgba::WHITE, shade: Vec4::ZERO, texture: Some(image) });
    let entity = commands.spawn((Mesh3d(meshes.add(sky_mesh(&plane))), MeshMaterial3d(material), SkyQuadMarker)).id();
    quad.entity = Some(entity);
}

/// Marks the sky quad.
#[derive(Component)]
struct SkyQuadMarker;

/// The plane's four corners in the view (km), as two triangles seen from both sides, image texture coordinates
/// (0, 0) top left.
fn sky_mesh(plane: &SkyPlane) -> Mesh {
    let (w, h) = (plane.image().width() as f64, plane.image().height() as f64);
    let corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)];
    let positions: Vec<[f32; 3]> =
        corners.iter().map(|&(x, y)| to_view(plane.world_point(DVec2::new(x, y))).to_array()).collect();
    let normal = to_view(plane.normal() * 1e3).normalize_or_zero().to_array();
    let uvs: Vec<[f32; 2]> = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    // both windings, so the plane shows from behind as well
    let indices = vec![0, 2, 1, 0, 3, 2, 0, 1, 2, 0, 2, 3];
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, vec![normal; 4])
        .with_inserted_attribute(Mesh::ATTRIBUTE_UV_0, uvs)
        .with_inserted_indices(Indices::U32(indices))
}

/// The sky image, box-averaged to at most [`SKY_TEXTURE_MAX_PX`] on its longer side, stretched from its 1st to
/// its 99th percentile into `map`'s colours.
fn sky_texture(plane: &SkyPlane, map: ColorMap) -> Image {
    let sky = plane.image();
    let (w, h) = (sky.width(), sky.height());
    let step = w.max(h).div_ceil(SKY_TEXTURE_MAX_PX).max(1);
    let (tw, th) = (w.div_ceil(step), h.div_ceil(step));
    let pixels = sky.pixels();
    let mut small = Vec::with_capacity(tw * th);
    for ty in 0..th {
        for tx in 0..tw {
            let (mut sum, mut n) = (0.0_f64, 0_u32);
            for y in ty * step..((ty + 1) * step).min(h) {
                for &v in &pixels[y * w + tx * step..(y * w + (tx + 1) * step).min(y * w + w)] {
                    sum += f64::from(v);
                    n += 1;
                }
            }
            small.push((sum / f64::from(n.max(1))) as f32);
        }
    }
    let frame = Frame::from_pixels(tw, th, small);
    let window = display_window(&frame, Stretch::Percentile { low: 1.0, high: 99.0 }, &mut StretchScratch::default());
    let mut rgba = Vec::new();
    to_rgba(&frame, window, map, &mut rgba);
    Image::new(
        Extent3d { width: tw as u32, height: th as u32, depth_or_array_layers: 1 },
        TextureDimension::D2,
        rgba,
        TextureFormat::Rgba8UnormSrgb,
        RenderAssetUsages::RENDER_WORLD,
    )
}

/// One aircraft's ellipsoid mesh.
#[derive(Component)]
pub(super) struct Ellipsoid(u32);

/// The shared unit spheres, coarse and fine, and a material per target colour.
#[derive(Default)]
pub(super) struct EllipsoidAssets {
    spheres: Option<[Handle<Mesh>; 2]>,
    materials: Vec<(u32, Handle<ViewMaterial>)>,
}

/// An ellipsoid drawn smaller than this (px across) uses the coarse sphere: 12 × 6 faces look round at that size,
/// and under software rendering each triangle costs (ten aircraft of 24 × 12 faces were 5 760 triangles).
const COARSE_BELOW_PX: f32 = 48.0;

/// One ellipsoid per aircraft, at its pose, scaled by its semi-axes times the draw factor.
#[allow(clippy::too_many_arguments)]
pub(super) fn sync_ellipsoids(
    mut commands: Commands,
    scale: Option<Res<DrawScale>>,
    aircraft: Query<(&Aircraft, &Kinematics, &Body)>,
    mut shown: Query<(Entity, &Ellipsoid, &mut Transform, &mut Mesh3d)>,
    mut assets: Local<EllipsoidAssets>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<ViewMaterial>>,
) {
    let drawn = |id: u32| scale.as_ref().and_then(|s| s.get(id));
    let factor = |id: u32| drawn(id).map_or(1.0, |d| d.factor);
    let spheres = assets
        .spheres
        .get_or_insert_with(|| {
            [meshes.add(Sphere::new(1.0).mesh().uv(12, 6)), meshes.add(Sphere::new(1.0).mesh().uv(32, 16))]
        })
        .clone();
    let mesh = |id: u32| spheres[usize::from(drawn(id).is_some_and(|d| d.size_px >= COARSE_BELOW_PX))].clone();
    let pose = |k: &Kinematics, body: &Body, f: f32| {
        let m = body.body_to_world(k.velocity_m_s);
        // to_view is a rotation (x, y, z) → (x, z, −y): it maps the body's axes as it maps points
        let axes = [m.x_axis, m.y_axis, m.z_axis].map(|c| to_view(c * 1e3));
        let x = axes[0].normalize_or(Vec3::X);
        let z = (axes[2] - x * x.dot(axes[2])).normalize_or(x.any_orthonormal_vector());
        let rotation = Quat::from_mat3(&Mat3::from_cols(x, z.cross(x), z));
        Transform { translation: to_view(k.position_m), rotation, scale: (body.semi_axes_m * 1e-3).as_vec3() * f }
    };
    let mut seen = Vec::new();
    for (entity, ellipsoid, mut transform, mut mesh3d) in &mut shown {
        match aircraft.iter().find(|(a, _, _)| a.id == ellipsoid.0) {
            Some((a, k, body)) => {
                *transform = pose(k, body, factor(a.id));
                let want = mesh(a.id);
                if mesh3d.0 != want {
                    mesh3d.0 = want;
                }
                seen.push(a.id);
            }
            None => commands.entity(entity).despawn(),
        }
    }
    for (a, k, body) in &aircraft {
        if seen.contains(&a.id) {
            continue;
        }
        let material = match assets.materials.iter().find(|(id, _)| *id == a.id) {
            Some((_, m)) => m.clone(),
            None => {
                let m = materials.add(ViewMaterial { color: palette(a.id).to_linear(), shade: Vec4::X, texture: None });
                assets.materials.push((a.id, m.clone()));
                m
            }
        };
        commands.spawn((Mesh3d(mesh(a.id)), MeshMaterial3d(material), pose(k, body, factor(a.id)), Ellipsoid(a.id)));
    }
}
