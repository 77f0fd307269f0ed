//! Pictures that change a part at a time (the sensor image every frame, the plot's new columns), written straight
//! into their GPU textures. Changing a Bevy `Image` asset instead keeps a copy in the main world that is cloned
//! for the renderer and written whole each time, and egui's own textures take that path after converting each
//! changed pixel; here only the changed rectangle is copied, once. Under llvmpipe the frame rate measured the same
//! either way (the copies are small next to drawing the window), but the plot's picture has to be a Bevy image
//! for [`super::blit`] to copy it into the window, and one way serves both pictures.
//!
//! A [`LiveImage`] is a Bevy image registered with egui once; [`LiveImages::write`] queues a rectangle of new
//! pixels, which the render world takes during extraction (so a frame's pixels arrive with that frame's labels
//! and plots, never a frame early) and writes with `write_texture` once the texture exists.

use std::sync::{Arc, Mutex, PoisonError};

use bevy::asset::{AssetId, RenderAssetUsages};
use bevy::prelude::*;
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::TexelCopyTextureInfo;
use bevy::render::renderer::RenderQueue;
use bevy::render::texture::GpuImage;
use bevy::render::{Extract, ExtractSchedule, Render, RenderApp, RenderSystems};
use bevy_egui::{EguiContexts, EguiTextureHandle, egui};
use wgpu_types::{Extent3d, Origin3d, TexelCopyBufferLayout, TextureAspect, TextureDimension, TextureFormat};

/// Registers the queue in both worlds and the systems that empty it.
pub struct LiveImagesPlugin;

impl Plugin for LiveImagesPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<Writes>();
    }

    fn finish(&self, app: &mut App) {
        let spare = app.world().resource::<Writes>().spare.clone();
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app
                .insert_resource(PendingWrites { writes: Vec::new(), spare })
                .add_systems(ExtractSchedule, take_writes)
                .add_systems(Render, apply_writes.in_set(RenderSystems::PrepareResources));
        }
    }
}

/// New pixels for a rectangle of a texture: `rgba` is `size[1]` rows of `size[0]` sRGBA pixels.
struct Write {
    image: AssetId<Image>,
    origin: [u32; 2],
    size: [u32; 2],
    rgba: Vec<u8>,
    /// Render frames waited for the texture to exist.
    waited: u32,
}

/// Writes queued by the main world since the last extraction, and buffers written that can be used again.
#[derive(Resource, Default, Clone)]
pub struct Writes {
    queued: Arc<Mutex<Vec<Write>>>,
    spare: Arc<Mutex<Vec<Vec<u8>>>>,
}

/// Spare buffers kept at most (a frame's worth: the sensor image and a few columns of the plot).
const MAX_SPARE: usize = 4;

/// Writes taken by the render world and not yet applied (their texture not made yet), and where their buffers
/// go back to (the main world's [`Writes::spare`]).
#[derive(Resource)]
struct PendingWrites {
    writes: Vec<Write>,
    spare: Arc<Mutex<Vec<Vec<u8>>>>,
}

/// Render frames a write waits for its texture before it is dropped (the image was replaced or removed).
const MAX_WAIT_FRAMES: u32 = 120;

fn take_writes(writes: Extract<Res<Writes>>, mut pending: ResMut<PendingWrites>) {
    let mut queued = writes.queued.lock().unwrap_or_else(PoisonError::into_inner);
    pending.writes.append(&mut queued);
}

fn apply_writes(mut pending: ResMut<PendingWrites>, images: Res<RenderAssets<GpuImage>>, queue: Res<RenderQueue>) {
    let PendingWrites { writes, spare } = &mut *pending;
    let mut done = Vec::new();
    writes.retain_mut(|w| {
        let Some(gpu) = images.get(w.image) else {
            w.waited += 1;
            return w.waited < MAX_WAIT_FRAMES;
        };
        let [x, y] = w.origin;
        let [width, height] = w.size;
        let texture = &gpu.texture;
        // a rectangle that does not fit (the image was replaced by a smaller one of the same id) is dropped
        if x + width <= texture.width() && y + height <= texture.height() {
            queue.write_texture(
                TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: Origin3d { x, y, z: 0 },
                    aspect: TextureAspect::All,
                },
                &w.rgba,
                TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * width), rows_per_image: Some(height) },
                Extent3d { width, height, depth_or_array_layers: 1 },
            );
        }
        done.push(std::mem::take(&mut w.rgba));
        false
    });
    let mut spare = spare.lock().unwrap_or_else(PoisonError::into_inner);
    for buffer in done {
        if spare.len() < MAX_SPARE {
            spare.push(buffer);
        }
    }
}

/// A picture egui shows whose pixels change in place.
#[derive(Debug, Clone)]
pub struct LiveImage {
    handle: Handle<Image>,
    /// egui's name for it.
    pub id: egui::TextureId,
    /// Width and height, px.
    pub size: [u32; 2],
}

impl LiveImage {
    /// The Bevy image (for [`super::blit::blit`]).
    pub fn asset(&self) -> AssetId<Image> {
        self.handle.id()
    }
}

/// What making and writing live images needs, borrowed from a system's parameters.
pub struct LiveImages<'a, 'w, 's> {
    images: &'a mut Assets<Image>,
    contexts: &'a mut EguiContexts<'w, 's>,
    writes: &'a Writes,
}

impl<'a, 'w, 's> LiveImages<'a, 'w, 's> {
    /// Borrows the parts.
    pub fn new(images: &'a mut Assets<Image>, contexts: &'a mut EguiContexts<'w, 's>, writes: &'a Writes) -> Self {
        Self { images, contexts, writes }
    }

    /// An image of `size` with pixels `rgba` (sRGBA, premultiplied where egui draws it blended), shown with
    /// nearest sampling. `old` is forgotten by egui and dropped (with its last handle the renderer drops its
    /// texture).
    pub fn create(&mut self, size: [u32; 2], rgba: Vec<u8>, old: Option<LiveImage>) -> LiveImage {
        if let Some(old) = old {
            self.contexts.remove_image(&old.handle);
        }
        let extent = Extent3d { width: size[0].max(1), height: size[1].max(1), depth_or_array_layers: 1 };
        let mut rgba = rgba;
        rgba.resize(extent.width as usize * extent.height as usize * 4, 0);
        let mut image = Image::new(
            extent,
            TextureDimension::D2,
            rgba,
            TextureFormat::Rgba8UnormSrgb,
            // the renderer keeps the only copy: the main world never reads it back, and a copy kept here would be
            // uploaded whole again if anything touched the asset
            RenderAssetUsages::RENDER_WORLD,
        );
        image.sampler = bevy::image::ImageSampler::nearest();
        let handle = self.images.add(image);
        let id = self.contexts.add_image(EguiTextureHandle::Strong(handle.clone()));
        LiveImage { handle, id, size: [extent.width, extent.height] }
    }

    /// Replaces the pixels of the rectangle at `origin` of `size` in `image` by `rgba` (rows of sRGBA pixels), in
    /// the picture this update renders. A rectangle reaching outside the image is ignored.
    pub fn write(&self, image: &LiveImage, origin: [u32; 2], size: [u32; 2], rgba: Vec<u8>) {
        let fits = origin[0] + size[0] <= image.size[0] && origin[1] + size[1] <= image.size[1];
        if !fits || size[0] == 0 || size[1] == 0 || rgba.len() != size[0] as usize * size[1] as usize * 4 {
            return;
        }
        let write = Write { image: image.asset(), origin, size, rgba, waited: 0 };
        self.writes.queued.lock().unwrap_or_else(PoisonError::into_inner).push(write);
    }

    /// An empty buffer for `len` bytes: the smallest spare one already written from that holds them (its memory
    /// reused, so that the plot's few columns do not take the sensor image's buffer), else a new one.
    pub fn buffer(&self, len: usize) -> Vec<u8> {
        let mut spare = self.writes.spare.lock().unwrap_or_else(PoisonError::into_inner);
        let fitting = (0..spare.len()).filter(|&i| spare[i].capacity() >= len).min_by_key(|&i| spare[i].capacity());
        let mut buffer = fitting.map_or_else(|| Vec::with_capacity(len), |i| spare.swap_remove(i));
        buffer.clear();
        buffer
    }
}
