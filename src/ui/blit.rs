//! Opaque pictures (the 3D view's, the sensor image, the plot) drawn into egui's pass by a paint callback with its own,
//! trivial pipeline (`view_blit.wgsl`): the nearest texel copied to each pixel. egui's image shader converts every
//! pixel to gamma space and back and blends it, which under software rendering cost about 7 ms a frame for a 330 × 780
//! view.

use bevy::asset::AssetId;
use bevy::prelude::*;
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::binding_types::texture_2d;
use bevy::render::render_resource::{
    BindGroup, BindGroupEntries, BindGroupLayoutDescriptor, BindGroupLayoutEntries, CachedRenderPipelineId,
    ColorTargetState, ColorWrites, FragmentState, MultisampleState, PipelineCache, PrimitiveState,
    RenderPipelineDescriptor, ShaderStages, SpecializedRenderPipeline, SpecializedRenderPipelines, TextureSampleType,
    VertexState,
};
use bevy::render::renderer::RenderDevice;
use bevy::render::sync_world::RenderEntity;
use bevy::render::texture::GpuImage;
use bevy::render::{RenderApp, render_phase::TrackedRenderPass};
use bevy_egui::egui;
use bevy_egui::render::{EguiBevyPaintCallback, EguiBevyPaintCallbackImpl, EguiPipelineKey};

/// Registers the shader and the pipeline.
pub struct ViewBlitPlugin;

impl Plugin for ViewBlitPlugin {
    fn build(&self, app: &mut App) {
        bevy::asset::embedded_asset!(app, "view_blit.wgsl");
    }

    fn finish(&self, app: &mut App) {
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.init_resource::<SpecializedRenderPipelines<BlitPipeline>>().init_resource::<BlitPipeline>();
        }
    }
}

/// A paint callback that draws `image`, opaque, stretched over `rect` with nearest sampling, as an egui image
/// with a white tint and nearest sampling would. The rectangle must lie inside the window (a paint callback's
/// viewport is clamped to it): [`fits`] says whether it does.
pub fn blit(rect: egui::Rect, image: AssetId<Image>) -> egui::PaintCallback {
    EguiBevyPaintCallback::new_paint_callback(rect, ViewBlit(image))
}

/// Whether `rect` lies inside the window `ctx` draws.
pub fn fits(ctx: &egui::Context, rect: egui::Rect) -> bool {
    ctx.viewport_rect().contains_rect(rect)
}

struct ViewBlit(AssetId<Image>);

/// The pipeline and each picture's bind group (made again every frame the picture is drawn), on the render entity
/// of egui's view: every callback of a frame is updated before any is drawn.
#[derive(Component, Default)]
struct BlitState {
    pipeline: Option<CachedRenderPipelineId>,
    bind_groups: Vec<(AssetId<Image>, BindGroup)>,
}

#[derive(Resource)]
struct BlitPipeline {
    shader: Handle<Shader>,
    layout: BindGroupLayoutDescriptor,
}

impl FromWorld for BlitPipeline {
    fn from_world(world: &mut World) -> Self {
        let shader = world.resource::<AssetServer>().load("embedded://irsim/ui/view_blit.wgsl");
        let layout = BindGroupLayoutDescriptor::new(
            "irsim_view_blit_layout",
            &BindGroupLayoutEntries::single(
                ShaderStages::FRAGMENT,
                texture_2d(TextureSampleType::Float { filterable: false }),
            ),
        );
        Self { shader, layout }
    }
}

impl SpecializedRenderPipeline for BlitPipeline {
    type Key = EguiPipelineKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        RenderPipelineDescriptor {
            label: Some("irsim_view_blit".into()),
            layout: vec![self.layout.clone()],
            immediate_size: 0,
            vertex: VertexState {
                shader: self.shader.clone(),
                shader_defs: vec![],
                entry_point: Some("vertex".into()),
                buffers: vec![],
            },
            fragment: Some(FragmentState {
                shader: self.shader.clone(),
                shader_defs: vec![],
                entry_point: Some("fragment".into()),
                targets: vec![Some(ColorTargetState {
                    format: key.target_format,
                    blend: None,
                    write_mask: ColorWrites::ALL,
                })],
            }),
            primitive: PrimitiveState::default(),
            depth_stencil: None,
            multisample: MultisampleState::default(),
            zero_initialize_workgroup_memory: false,
        }
    }
}

impl EguiBevyPaintCallbackImpl for ViewBlit {
    fn update(
        &self,
        _info: egui::PaintCallbackInfo,
        render_entity: RenderEntity,
        key: EguiPipelineKey,
        world: &mut World,
    ) {
        let pipeline = world.resource_scope(|world, mut pipelines: Mut<SpecializedRenderPipelines<BlitPipeline>>| {
            pipelines.specialize(world.resource::<PipelineCache>(), world.resource::<BlitPipeline>(), key)
        });
        let bind_group = world.resource::<RenderAssets<GpuImage>>().get(self.0).map(|image| {
            let layout =
                world.resource::<PipelineCache>().get_bind_group_layout(&world.resource::<BlitPipeline>().layout);
            world.resource::<RenderDevice>().create_bind_group(
                "irsim_view_blit",
                &layout,
                &BindGroupEntries::single(&image.texture_view),
            )
        });
        let mut entity = world.entity_mut(render_entity.id());
        if !entity.contains::<BlitState>() {
            entity.insert(BlitState::default());
        }
        if let Some(mut state) = entity.get_mut::<BlitState>() {
            state.pipeline = Some(pipeline);
            state.bind_groups.retain(|(id, _)| *id != self.0);
            // a handful of pictures at most; a texture replaced (a new frame size) leaves an entry, forgotten here
            if state.bind_groups.len() > 8 {
                state.bind_groups.clear();
            }
            if let Some(bind_group) = bind_group {
                state.bind_groups.push((self.0, bind_group));
            }
        }
    }

    fn render<'pass>(
        &self,
        _info: egui::PaintCallbackInfo,
        render_pass: &mut TrackedRenderPass<'pass>,
        render_entity: RenderEntity,
        _key: EguiPipelineKey,
        world: &'pass World,
    ) {
        let Some(state) = world.get_entity(render_entity.id()).ok().and_then(|e| e.get::<BlitState>()) else { return };
        let bind_group = state.bind_groups.iter().find(|(id, _)| *id == self.0).map(|(_, b)| b);
        let pipeline = state.pipeline.and_then(|p| world.resource::<PipelineCache>().get_render_pipeline(p));
        let (Some(bind_group), Some(pipeline)) = (bind_group, pipeline) else {
            // the pipeline still compiling, or the picture not yet on the GPU: the view stays empty this frame
            return;
        };
        render_pass.set_render_pipeline(pipeline);
        render_pass.set_bind_group(0, bind_group, &[]);
        render_pass.draw(0..3, 0..1);
    }
}
