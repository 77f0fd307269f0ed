//! The sky as an image placed on a plane in the world, ray cast into the sensor (paper III.B, Figs. 2–3).
//!
//! The plane is fixed by an anchor point P (a world position), the pixel of the image that sits at P, the
//! image's width and height in metres, and its orientation: a unit normal facing the camera and the world
//! direction of the image's "up" (default: vertical plane, facing the camera, image up = world up, as in the
//! paper's example with the camera at [0, 0, 8] km and P at [0, 30, 6] km on a 4 km × 4 km image).
//!
//! Each sensor pixel's ray is intersected with the plane; the hit point's image coordinates are sampled by
//! nearest neighbour, bilinearly, or as an n × n supersampled average over the sensor pixel's area. A ray that
//! misses the image gets 0 (the paper), a constant, or the nearest edge value. Rows are computed in parallel;
//! each row's result depends only on its own pixels, so the output does not depend on the thread count.

use std::path::Path;
use std::sync::Arc;

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::camera::Camera;
use super::frame::Frame;
use super::psf::true_runs;
use crate::physics::simd::{Level, rows_per_task, split_finely, widest};

/// An error loading or placing a sky image.
#[derive(Debug, Error)]
pub enum SkyError {
    /// The image file could not be read or decoded.
    #[error("sky image {path}: {message}")]
    Image {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A placement parameter out of range.
    #[error("sky plane {name}: {message}")]
    Placement {
        /// Parameter name.
        name: &'static str,
        /// What is wrong.
        message: String,
    },
}

/// A grayscale sky image at full precision: 8-bit values 0–255, 16-bit 0–65535, float as given.
///
/// Its values are shared, so a clone is cheap. An image the crate loads or makes holds its rows one after
/// another; a prefiltered texture is a view of a larger grid of values, its rows [`SkyImage::stride`] apart.
#[derive(Clone)]
pub struct SkyImage {
    width: usize,
    height: usize,
    /// Floats from the start of one row to the next.
    stride: usize,
    /// Where the first row starts in `values`.
    offset: usize,
    values: Arc<Vec<f32>>,
}

impl std::fmt::Debug for SkyImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SkyImage")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("stride", &self.stride)
            .finish_non_exhaustive()
    }
}

impl PartialEq for SkyImage {
    /// The same size and values (wherever they are held).
    fn eq(&self, other: &Self) -> bool {
        (self.width, self.height) == (other.width, other.height)
            && (0..self.height).all(|y| self.row(y) == other.row(y))
    }
}

impl SkyImage {
    /// An image from row-major float data.
    ///
    /// # Errors
    /// [`SkyError::Placement`] if the data length is not `width·height`, the image is empty, or a value is not
    /// finite.
    pub fn from_f32(width: usize, height: usize, pixels: Vec<f32>) -> Result<Self, SkyError> {
        if width == 0 || height == 0 || pixels.len() != width * height {
            return Err(SkyError::Placement {
                name: "image",
                message: format!("{} values for a {width}×{height} image", pixels.len()),
            });
        }
        if let Some(i) = pixels.iter().position(|p| !p.is_finite()) {
            return Err(SkyError::Placement {
                name: "image",
                message: format!("value at ({}, {}) is not finite", i % width, i / width),
            });
        }
        Ok(Self::contiguous(width, height, pixels))
    }

    /// An image holding `pixels`, its rows one after another.
    fn contiguous(width: usize, height: usize, pixels: Vec<f32>) -> Self {
        Self { width, height, stride: width, offset: 0, values: Arc::new(pixels) }
    }

    /// As [`SkyImage::from_f32`] for values known to be finite and as many as `width × height` (a blur of a
    /// checked image); checked in debug builds only.
    pub(crate) fn from_finite(width: usize, height: usize, pixels: Vec<f32>) -> Self {
        debug_assert!(width * height == pixels.len() && pixels.iter().all(|p| p.is_finite()));
        Self::contiguous(width, height, pixels)
    }

    /// The `width × height` image whose rows start at `values[offset]`, `stride` floats apart (a region of a
    /// larger grid of finite values, shared with it).
    ///
    /// # Panics
    /// If the image is empty, a row is longer than the stride, or the last row ends beyond `values`.
    pub(crate) fn view(values: Arc<Vec<f32>>, offset: usize, width: usize, height: usize, stride: usize) -> Self {
        assert!(width >= 1 && height >= 1 && width <= stride, "a {width}×{height} view, {stride} floats a row");
        assert!(offset + (height - 1) * stride + width <= values.len(), "a view inside its values");
        Self { width, height, stride, offset, values }
    }

    /// Reads any image the `image` crate decodes (PNG, TIFF, PNM here). Gray images keep their integer values,
    /// float images their floats; colour
    /// images are converted to luma at their bit depth.
    ///
    /// # Errors
    /// [`SkyError::Image`] naming the file if it cannot be read or decoded.
    pub fn load(path: &Path) -> Result<Self, SkyError> {
        let err = |message: String| SkyError::Image { path: path.display().to_string(), message };
        if let Some(gray) = load_gray_tiff(path).map_err(err)? {
            return Ok(gray);
        }
        let img = image::ImageReader::open(path)
            .map_err(|e| err(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| err(e.to_string()))?
            .decode()
            .map_err(|e| err(e.to_string()))?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        use image::DynamicImage as D;
        let pixels: Vec<f32> = match img {
            D::ImageLuma8(b) => b.into_raw().into_iter().map(f32::from).collect(),
            D::ImageLuma16(b) => b.into_raw().into_iter().map(f32::from).collect(),
            D::ImageLumaA8(_) | D::ImageRgb8(_) | D::ImageRgba8(_) => {
                img.to_luma8().into_raw().into_iter().map(f32::from).collect()
            }
            D::ImageLumaA16(_) | D::ImageRgb16(_) | D::ImageRgba16(_) => {
                img.to_luma16().into_raw().into_iter().map(f32::from).collect()
            }
            other => other.to_luma32f().into_raw(),
        };
        Self::from_f32(w, h, pixels).map_err(|e| err(e.to_string()))
    }

    /// Width, px.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major values, each row [`SkyImage::stride`] floats after the one before (the width, but for a
    /// prefiltered texture's view).
    pub fn pixels(&self) -> &[f32] {
        let len = self.height.checked_sub(1).map_or(0, |rows| rows * self.stride + self.width);
        &self.values[self.offset..self.offset + len]
    }

    /// Floats from the start of one row of [`SkyImage::pixels`] to the next.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Row `y`'s values.
    fn row(&self, y: usize) -> &[f32] {
        let start = self.offset + y * self.stride;
        &self.values[start..start + self.width]
    }

    /// The `width × height` block whose top-left pixel is `(x0, y0)`, row-major; pixels beyond the image take the
    /// nearest edge pixel's value.
    pub fn region_clamped(&self, x0: isize, y0: isize, width: usize, height: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(width * height);
        for y in 0..height as isize {
            out.extend((0..width as isize).map(|x| self.at_clamped(x0 + x, y0 + y)));
        }
        out
    }

    /// Value of pixel `(x, y)`, clamped to the image.
    #[inline]
    fn at_clamped(&self, x: isize, y: isize) -> f32 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.values[self.offset + y * self.stride + x]
    }
}

/// A single-channel TIFF of any sample type (8–64-bit integers, 32- or 64-bit floats) at its values; `None` if
/// the file is not a TIFF or not single-channel (the `image` crate reads those).
fn load_gray_tiff(path: &Path) -> Result<Option<SkyImage>, String> {
    use tiff::decoder::{Decoder, DecodingResult as R};
    let mut magic = [0u8; 4];
    {
        use std::io::Read;
        let mut f = std::fs::File::open(path).map_err(|e| e.to_string())?;
        if f.read_exact(&mut magic).is_err() || !(magic == *b"II*\0" || magic == *b"MM\0*") {
            return Ok(None);
        }
    }
    let file = std::io::BufReader::new(std::fs::File::open(path).map_err(|e| e.to_string())?);
    let mut dec = Decoder::new(file).map_err(|e| e.to_string())?;
    if !matches!(dec.colortype().map_err(|e| e.to_string())?, tiff::ColorType::Gray(_)) {
        return Ok(None);
    }
    let (w, h) = dec.dimensions().map_err(|e| e.to_string())?;
    let pixels: Vec<f32> = match dec.read_image().map_err(|e| e.to_string())? {
        R::U8(v) => v.into_iter().map(f32::from).collect(),
        R::U16(v) => v.into_iter().map(f32::from).collect(),
        R::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        R::U64(v) => v.into_iter().map(|x| x as f32).collect(),
        R::I8(v) => v.into_iter().map(f32::from).collect(),
        R::I16(v) => v.into_iter().map(f32::from).collect(),
        R::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        R::I64(v) => v.into_iter().map(|x| x as f32).collect(),
        R::F32(v) => v,
        R::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        R::F16(v) => v.into_iter().map(f32::from).collect(),
    };
    SkyImage::from_f32(w as usize, h as usize, pixels).map(Some).map_err(|e| e.to_string())
}

/// How a ray's hit point is turned into a value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "mode", deny_unknown_fields, from = "SamplingFields")]
pub enum Sampling {
    /// The image pixel containing the hit point.
    Nearest,
    /// Bilinear interpolation between the four nearest pixel centres.
    #[default]
    Bilinear,
    /// Mean of `n × n` bilinear samples spread over the sensor pixel (an area average).
    Supersample {
        /// Samples per side, 1 … 16.
        n: u32,
    },
}

/// What a ray that misses the image gets.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "mode", deny_unknown_fields, from = "MissFillFields")]
pub enum MissFill {
    /// The clear sky and ground along the ray's own direction (the simulation fills these; a render marks
    /// them NaN).
    #[default]
    Dome,
    /// 0, as in the paper.
    Zero,
    /// A constant value.
    Constant {
        /// The value.
        value: f32,
    },
    /// The nearest edge pixel of the image (the image extends to infinity).
    Edge,
}

/// [`Sampling`] as a scenario writes it, every variant a table of its fields: serde reads a variant without fields
/// from the tag alone and ignores any key beside it (`{ mode = "bilinear", n = 3 }` would pass), so [`Sampling`] is read through this and
/// such a key is refused as unknown.
#[derive(Deserialize)]
#[serde(
    rename_all = "snake_case",
    tag = "mode",
    deny_unknown_fields,
    expecting = "a table with `mode`: nearest, bilinear or supersample"
)]
enum SamplingFields {
    Nearest {},
    Bilinear {},
    Supersample { n: u32 },
}

impl From<SamplingFields> for Sampling {
    fn from(s: SamplingFields) -> Self {
        match s {
            SamplingFields::Nearest {} => Self::Nearest,
            SamplingFields::Bilinear {} => Self::Bilinear,
            SamplingFields::Supersample { n } => Self::Supersample { n },
        }
    }
}

/// [`MissFill`] as a scenario writes it, every variant a table of its fields: serde reads a variant without fields
/// from the tag alone and ignores any key beside it (`{ mode = "zero", value = 3 }` would pass), so [`MissFill`] is read through this and
/// such a key is refused as unknown.
#[derive(Deserialize)]
#[serde(
    rename_all = "snake_case",
    tag = "mode",
    deny_unknown_fields,
    expecting = "a table with `mode`: dome, zero, constant or edge"
)]
enum MissFillFields {
    Dome {},
    Zero {},
    Constant { value: f32 },
    Edge {},
}

impl From<MissFillFields> for MissFill {
    fn from(m: MissFillFields) -> Self {
        match m {
            MissFillFields::Dome {} => Self::Dome,
            MissFillFields::Zero {} => Self::Zero,
            MissFillFields::Constant { value } => Self::Constant { value },
            MissFillFields::Edge {} => Self::Edge,
        }
    }
}

/// Where and how the sky image sits in the world.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkyPlacement {
    /// World position of the anchor point P, m.
    pub anchor_m: DVec3,
    /// Image coordinates of P, px (pixel centres at `i + 0.5`); `None` is the image centre.
    #[serde(default)]
    pub anchor_px: Option<DVec2>,
    /// Width of the whole image in the world, m.
    pub width_m: f64,
    /// Height of the whole image in the world, m.
    pub height_m: f64,
    /// Unit normal of the plane, pointing toward the camera; `None` faces the camera horizontally (vertical
    /// plane).
    #[serde(default)]
    pub normal: Option<DVec3>,
    /// World direction of the image's up, projected into the plane; default world +z.
    #[serde(default)]
    pub up: Option<DVec3>,
}

impl SkyPlacement {
    /// The paper's Fig. 8 placement: P at [0, 30, 6] km at the image centre, 4 km × 4 km, vertical, facing the
    /// camera (which the paper puts at [0, 0, 8] km).
    pub fn paper_fig8() -> Self {
        Self {
            anchor_m: DVec3::new(0.0, 30_000.0, 6000.0),
            anchor_px: None,
            width_m: 4000.0,
            height_m: 4000.0,
            normal: None,
            up: None,
        }
    }

    /// The plane's unit normal (toward the camera), and the image's right and down directions in the world,
    /// for a camera at `camera_position_m`: the one place these are derived and checked.
    ///
    /// # Errors
    /// [`SkyError::Placement`] naming `normal` or `up` (zero, non-finite, or an up along the normal; `normal`
    /// when `up` is the default +z) or `anchor_m` (no normal given and the camera straight above or below it).
    pub fn axes(&self, camera_position_m: DVec3) -> Result<(DVec3, DVec3, DVec3), SkyError> {
        let bad = |name, message: &str| SkyError::Placement { name, message: message.to_owned() };
        // scaled by the largest component first, so that huge finite vectors normalize too
        let unit = |v: DVec3| (v / v.abs().max_element()).try_normalize();
        let normal = match self.normal {
            Some(n) => unit(n).ok_or_else(|| bad("normal", "must be a finite, non-zero vector"))?,
            None => {
                let d = camera_position_m - self.anchor_m;
                if !(d.x.hypot(d.y) >= 1e-9 * (1.0 + d.z.abs())) {
                    return Err(bad("anchor_m", "the camera starts straight above or below it: give `normal`"));
                }
                DVec3::new(d.x, d.y, 0.0).normalize()
            }
        };
        let up = match self.up {
            Some(u) => unit(u).ok_or_else(|| bad("up", "must be a finite, non-zero vector"))?,
            None => DVec3::Z,
        };
        let up_in_plane = (up - normal * up.dot(normal)).try_normalize().filter(|_| up.cross(normal).length() >= 1e-6);
        let up_in_plane = up_in_plane.ok_or_else(|| {
            bad(
                if self.up.is_some() { "up" } else { "normal" },
                "the image's up (default +z) must not be parallel to the plane's normal",
            )
        })?;
        // image right = up × normal (facing the camera, right is to the viewer's right); down = right × normal
        Ok((normal, up_in_plane.cross(normal), -up_in_plane))
    }
}

/// The sky plane, ready to be ray cast.
#[derive(Debug, Clone)]
pub struct SkyPlane {
    image: SkyImage,
    anchor_m: DVec3,
    anchor_px: DVec2,
    normal: DVec3,
    /// World displacement per image pixel along +u (right) and +v (down).
    du_m: DVec3,
    dv_m: DVec3,
    /// Image pixels per metre along `right` and `down`.
    px_per_m: DVec2,
    right: DVec3,
    down: DVec3,
    /// Largest departure of an interpolated ray-cast coordinate from the exact one, px.
    span_tolerance_px: f64,
    /// The image widened by texels of the dome, for the prefiltered texture ([`DomeMargin`]).
    dome_margin: Option<Arc<DomeMargin>>,
}

/// A sky image's plane widened by `texels` texels of the dome on every side, each texel where it was: the source
/// of the image's prefiltered texture where a view comes near the image's edge (`[quality] image_margin_px`),
/// so that the tiles there are read from the texture instead of taking a per-frame blur. The widened image's
/// bilinear read ramps over one texel from the image's edge texels to the dome's, where a ray cast of the image
/// steps from its edge to the dome along the rays that miss it (docs/accuracy.md measures what that does).
#[derive(Debug, Clone)]
pub struct DomeMargin {
    /// The widened plane.
    pub plane: SkyPlane,
    /// Texels of the dome on every side.
    pub texels: usize,
}

impl SkyPlane {
    /// Places `image` in the world. `camera_position_m` orients a plane given without a normal: vertical, facing
    /// the camera.
    ///
    /// # Errors
    /// [`SkyError::Placement`] for a non-positive size, a zero or non-finite normal, an up direction along
    /// the normal, or a camera on the anchor's vertical line when no normal is given.
    pub fn new(image: SkyImage, placement: &SkyPlacement, camera_position_m: DVec3) -> Result<Self, SkyError> {
        let bad = |name, message: &str| SkyError::Placement { name, message: message.to_owned() };
        for (name, v) in [("width_m", placement.width_m), ("height_m", placement.height_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(name, &format!("{v} must be a finite number > 0")));
            }
        }
        if !placement.anchor_m.is_finite() {
            return Err(bad("anchor_m", "must be finite"));
        }
        let (normal, right, down) = placement.axes(camera_position_m)?;
        let (w, h) = (image.width as f64, image.height as f64);
        let anchor_px = placement.anchor_px.unwrap_or(DVec2::new(w / 2.0, h / 2.0));
        let px_per_m = DVec2::new(w / placement.width_m, h / placement.height_m);
        Ok(Self {
            du_m: right / px_per_m.x,
            dv_m: down / px_per_m.y,
            image,
            anchor_m: placement.anchor_m,
            anchor_px,
            normal,
            px_per_m,
            right,
            down,
            span_tolerance_px: SPAN_TOLERANCE_PX,
            dome_margin: None,
        })
    }

    /// Sets how far an interpolated ray-cast coordinate may depart from the exact one, px (default
    /// [`SPAN_TOLERANCE_PX`]; 0 casts every ray exactly). Negative or NaN values count as 0.
    pub fn set_span_tolerance(&mut self, px: f64) {
        self.span_tolerance_px = if px > 0.0 { px } else { 0.0 };
        if let Some(margin) = self.dome_margin.as_mut() {
            Arc::make_mut(margin).plane.set_span_tolerance(px);
        }
    }

    /// The image.
    pub fn image(&self) -> &SkyImage {
        &self.image
    }

    /// The same plane holding `image`, a region of this plane's image whose top-left corner is this image's pixel
    /// `origin_px`, at `per_px` of its pixels per pixel of this image (a crop, a filtered copy, a finer grid),
    /// where that region lies in the world.
    pub fn with_region(&self, image: SkyImage, origin_px: [usize; 2], per_px: usize) -> Self {
        let origin = DVec2::new(origin_px[0] as f64, origin_px[1] as f64);
        let m = per_px.max(1) as f64;
        Self {
            image,
            anchor_m: self.anchor_m,
            anchor_px: (self.anchor_px - origin) * m,
            normal: self.normal,
            du_m: self.du_m / m,
            dv_m: self.dv_m / m,
            px_per_m: self.px_per_m * m,
            right: self.right,
            down: self.down,
            span_tolerance_px: self.span_tolerance_px,
            dome_margin: None,
        }
    }

    /// This plane with `margin` (its image widened by texels of the dome, each texel where it was here) as the
    /// source of its prefiltered texture, cast at this plane's span tolerance.
    pub fn with_dome_margin(mut self, mut margin: DomeMargin) -> Self {
        margin.plane.set_span_tolerance(self.span_tolerance_px);
        self.dome_margin = Some(Arc::new(margin));
        self
    }

    /// The image widened by texels of the dome, if set ([`SkyPlane::with_dome_margin`]).
    pub fn dome_margin(&self) -> Option<&DomeMargin> {
        self.dome_margin.as_deref()
    }

    /// The image at image coordinates `image_px` (px), interpolated bilinearly between pixel centres; beyond the
    /// edges, the nearest edge value.
    pub fn value_at(&self, image_px: DVec2) -> f32 {
        self.sample(image_px, Sampling::Bilinear, MissFill::Edge)
    }

    /// Where `camera`'s rays meet the plane, in image coordinates ([`PlaneProjection::image_point`]).
    pub fn projection(&self, camera: &Camera) -> PlaneProjection {
        PlaneProjection(RowGeometry::new(self, camera))
    }

    /// As [`SkyPlane::render`] with bilinear or nearest sampling, only on the `tile_px`-square tiles of the frame
    /// whose entry in `tiles` (row-major, `⌈width/tile_px⌉` per row) is true; other pixels keep their values.
    pub fn render_tiles(
        &self,
        camera: &Camera,
        sampling: Sampling,
        fill: MissFill,
        tile_px: usize,
        tiles: &[bool],
        frame: &mut Frame,
    ) {
        use rayon::prelude::*;
        let width = frame.width();
        let tiles_x = width.div_ceil(tile_px);
        let sampling = if matches!(sampling, Sampling::Nearest) { sampling } else { Sampling::Bilinear };
        let geometry = RowGeometry::new(self, camera);
        // half a tile's rows a task at most: the tiles to render are often a strip of the frame, which in a
        // handful of large tasks fell to one thread
        let most = split_finely(tile_px / 2);
        frame.pixels_mut().par_chunks_mut(width).enumerate().with_max_len(most).for_each(|(j, row)| {
            let flags = &tiles[(j / tile_px) * tiles_x..(j / tile_px + 1) * tiles_x];
            // one cast per run of consecutive tiles
            for run in true_runs(flags) {
                let (x0, x1) = (run.start * tile_px, (run.end * tile_px).min(width));
                widest(
                    #[inline(always)]
                    || {
                        geometry.cast_row(
                            self,
                            j as f64 + 0.5,
                            x0 as f64 + 0.5,
                            sampling,
                            fill,
                            &mut row[x0..x1],
                            false,
                        )
                    },
                );
            }
        });
    }

    /// Whether any ray of `camera`'s render may see the image (false: every pixel is a miss).
    pub fn seen_by(&self, camera: &Camera) -> bool {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        RowGeometry::new(self, camera).sees_image(f64::from(w), f64::from(h))
    }

    /// Unit normal, toward the camera side.
    pub fn normal(&self) -> DVec3 {
        self.normal
    }

    /// World position of image coordinates `(x, y)` (px, pixel centres at `i + 0.5`).
    pub fn world_point(&self, image_px: DVec2) -> DVec3 {
        let d = image_px - self.anchor_px;
        self.anchor_m + self.du_m * d.x + self.dv_m * d.y
    }

    /// Samples the image at image coordinates `p` (px).
    #[inline]
    fn sample(&self, p: DVec2, sampling: Sampling, fill: MissFill) -> f32 {
        let (w, h) = (self.image.width as f64, self.image.height as f64);
        let inside = p.x >= 0.0 && p.y >= 0.0 && p.x < w && p.y < h;
        if !inside {
            match fill {
                MissFill::Dome => return f32::NAN,
                MissFill::Zero => return 0.0,
                MissFill::Constant { value } => return value,
                MissFill::Edge => {}
            }
        }
        // beyond the edge every value is the edge's: bring far coordinates (up to ±inf) next to the image so that
        // the pixel arithmetic below stays small
        let p = DVec2::new(p.x.clamp(-2.0, w + 2.0), p.y.clamp(-2.0, h + 2.0));
        match sampling {
            Sampling::Nearest => self.image.at_clamped(floor_isize(p.x), floor_isize(p.y)),
            _ => {
                // pixel centres at i + 0.5
                let x = p.x - 0.5;
                let y = p.y - 0.5;
                let (x0, y0) = (floor_isize(x), floor_isize(y));
                let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
                let (w, h) = (self.image.width as isize, self.image.height as isize);
                let (a, b, c, d) = if x0 >= 0 && y0 >= 0 && x0 + 1 < w && y0 + 1 < h {
                    let stride = self.image.stride;
                    let i = y0 as usize * stride + x0 as usize;
                    let px = self.image.pixels();
                    (px[i], px[i + 1], px[i + stride], px[i + stride + 1])
                } else {
                    (
                        self.image.at_clamped(x0, y0),
                        self.image.at_clamped(x0 + 1, y0),
                        self.image.at_clamped(x0, y0 + 1),
                        self.image.at_clamped(x0 + 1, y0 + 1),
                    )
                };
                bilinear_mix(a, b, c, d, fx, fy)
            }
        }
    }

    /// Ray casts the sky into `frame` as seen by `camera` (the frame's size must match the camera's).
    ///
    /// Along a row of sensor pixels the ray direction is linear in `u`, so its dot products with the plane's
    /// normal and in-plane axes are too: the image coordinates are a ratio of linear functions of `u` (the
    /// plane-to-image homography). They are evaluated exactly at the ends and the middle of spans short enough
    /// that the quadratic through those values is within the plane's span tolerance of them (a bound from the
    /// ratio's third derivative, not a test), and stepped by forward differences in 24.40 fixed point inside a
    /// span, so a pixel costs integer additions and the sample.
    pub fn render(&self, camera: &Camera, sampling: Sampling, fill: MissFill, frame: &mut Frame) {
        self.render_mapped(camera, sampling, fill, 1.0, 0.0, frame);
    }

    /// As [`SkyPlane::render`], then maps each value `x` (misses included) to `offset + gain·x` in the same
    /// pass.
    pub fn render_mapped(
        &self,
        camera: &Camera,
        sampling: Sampling,
        fill: MissFill,
        gain: f32,
        offset: f32,
        frame: &mut Frame,
    ) {
        use rayon::prelude::*;
        let width = frame.width();
        debug_assert_eq!(width as u32, camera.intrinsics.width);
        let n = match sampling {
            Sampling::Supersample { n } => n.clamp(1, 16) as usize,
            _ => 1,
        };
        let point_sampling = if n == 1 { sampling } else { Sampling::Bilinear };
        let geometry = RowGeometry::new(self, camera);
        let inv = 1.0 / (n * n) as f32;
        let mapped = gain != 1.0 || offset != 0.0;
        // rows in batches: one row is too little work to be worth a task
        let rows_per_task = rows_per_task(width, 2 * n * n);
        frame.pixels_mut().par_chunks_mut(width).enumerate().with_min_len(rows_per_task).for_each(|(j, row)| {
            if n == 1 {
                widest(
                    #[inline(always)]
                    || geometry.cast_row(self, j as f64 + 0.5, 0.5, point_sampling, fill, row, false),
                );
            } else {
                row.fill(0.0);
                for sy in 0..n {
                    let v = j as f64 + (sy as f64 + 0.5) / n as f64;
                    for sx in 0..n {
                        let u0 = (sx as f64 + 0.5) / n as f64;
                        geometry.cast_row(self, v, u0, point_sampling, fill, row, true);
                    }
                }
                for p in row.iter_mut() {
                    *p *= inv;
                }
            }
            if mapped {
                for p in row.iter_mut() {
                    *p = offset + gain * *p;
                }
            }
        });
    }
}

/// Bilinear interpolation between `top_left`, `top_right` (the next pixel along the row), `bottom_left` and
/// `bottom_right` at fractions `fx` along the row and `fy` down.
#[inline]
fn bilinear_mix(top_left: f32, top_right: f32, bottom_left: f32, bottom_right: f32, fx: f32, fy: f32) -> f32 {
    let top = top_left + (top_right - top_left) * fx;
    let bottom = bottom_left + (bottom_right - bottom_left) * fx;
    top + (bottom - top) * fy
}

/// `⌊x⌋` as an integer without a libm call (the baseline x86-64 target has no rounding instruction);
/// saturates for values beyond `isize`.
#[inline]
fn floor_isize(x: f64) -> isize {
    // `as` saturates (NaN to 0); the callers keep |x| small
    let i = x as isize;
    if (i as f64) > x { i.saturating_sub(1) } else { i }
}

/// The plane as one camera sees it.
pub struct PlaneProjection(RowGeometry);

impl PlaneProjection {
    /// Image coordinates (px) where the ray through sensor point `sensor_px` (pixel centres at `i + 0.5`) meets
    /// the plane; `None` if it runs parallel to the plane or meets it behind the camera.
    pub fn image_point(&self, sensor_px: DVec2) -> Option<DVec2> {
        let g = &self.0;
        g.coordinates(g.base + g.dv * sensor_px.y, sensor_px.x)
    }
}

/// Per-frame constants of the ray cast: how the ray's dot products with the plane axes vary over the image.
struct RowGeometry {
    /// `(a − o)·n`: the numerator of the ray parameter.
    numerator: f64,
    /// `(o − a)·right·ppm_x` and `(o − a)·down·ppm_y`: image coordinates of the ray origin's projection.
    origin_px: DVec2,
    /// Dot products of the camera ray `K⁻¹(u, v, 1)` with (n, right·ppm_x, down·ppm_y) as affine functions of
    /// u and v: value = base + u·du + v·dv.
    base: DVec3,
    du: DVec3,
    dv: DVec3,
    /// The linear forms that bound where a ray may see the image ([`RowGeometry::seen_forms`]).
    seen: Option<[DVec3; 5]>,
    /// Every ray of the camera's sensor may see the image ([`RowGeometry::sees_all`]).
    sees_all: bool,
    /// Whether a row's ray cast skips the pixels that cannot see the image (off only to test that skipping
    /// changes nothing).
    clip: bool,
}

impl RowGeometry {
    fn new(plane: &SkyPlane, camera: &Camera) -> Self {
        let axes = [plane.normal, plane.right * plane.px_per_m.x, plane.down * plane.px_per_m.y];
        // camera ray (unnormalised, world) = R·(ray_camera(u, v)) = R·((u − cx)/f, (v − cy)/f, 1)
        let r = camera.camera_to_world;
        let f = camera.intrinsics.focal_px();
        let c = camera.intrinsics.principal_point();
        let d_u = r.x_axis / f;
        let d_v = r.y_axis / f;
        let d0 = r.z_axis - d_u * c.x - d_v * c.y;
        let dot = |d: DVec3| DVec3::new(d.dot(axes[0]), d.dot(axes[1]), d.dot(axes[2]));
        let rel = camera.position_m - plane.anchor_m;
        let numerator = -rel.dot(plane.normal);
        let origin_px = plane.anchor_px + DVec2::new(rel.dot(axes[1]), rel.dot(axes[2]));
        let size = DVec2::new(plane.image.width as f64, plane.image.height as f64);
        let (base, du, dv) = (dot(d0), dot(d_u), dot(d_v));
        let seen = Self::seen_forms(numerator, origin_px, size);
        let sensor = DVec2::new(f64::from(camera.intrinsics.width), f64::from(camera.intrinsics.height));
        Self {
            numerator,
            origin_px,
            base,
            du,
            dv,
            seen,
            sees_all: Self::sees_all(seen, [base, du, dv], sensor),
            clip: true,
        }
    }

    /// Whether every one of [`RowGeometry::seen_forms`] is positive over the sensor rectangle `sensor` (px)
    /// widened by two pixels all round, by a margin that no rounding of [`RowGeometry::seen_pixels`]'s
    /// arithmetic can cross. Each form is affine in `(u, v)`, so it is smallest at a corner; then every row's
    /// (or a tile row's) range of pixels that may see the image is the whole of it, and is not worked out.
    fn sees_all(seen: Option<[DVec3; 5]>, [base, du, dv]: [DVec3; 3], sensor: DVec2) -> bool {
        let Some(forms) = seen else {
            return false;
        };
        let corners = [(-2.0, -2.0), (sensor.x + 2.0, -2.0), (-2.0, sensor.y + 2.0), (sensor.x + 2.0, sensor.y + 2.0)]
            .map(|(u, v)| base + du * u + dv * v);
        forms.iter().all(|c| {
            // the size of the terms a form's value at a ray sums: its rounding is some 1e-16 of that
            let scale = corners.iter().map(|d| c.abs().dot(d.abs())).fold(0.0, f64::max);
            scale.is_finite() && corners.iter().all(|&d| c.dot(d) > 1e-9 * scale)
        })
    }

    /// Casts the rays of one sensor row at `v`, pixel `i` at `u = i + u0`, writing (or adding, if `accumulate`)
    /// into `out`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn cast_row(
        &self,
        plane: &SkyPlane,
        v: f64,
        u0: f64,
        sampling: Sampling,
        fill: MissFill,
        out: &mut [f32],
        accumulate: bool,
    ) {
        // (D, Nx, Ny)(i) = d0 + i·du: image coordinates are origin_px + numerator·(Nx, Ny)/D
        let d0 = self.base + self.dv * v + self.du * u0;
        let miss = match fill {
            MissFill::Constant { value } => value,
            MissFill::Dome => f32::NAN,
            _ => 0.0,
        };
        let bilinear = !matches!(sampling, Sampling::Nearest);
        let exact = |i: f64| self.coordinates(d0, i);
        let sample = |p: DVec2| plane.sample(p, sampling, fill);
        let span = self.span_length(d0, out.len(), plane.span_tolerance_px);
        // pixels outside `seen` miss the image (an edge fill samples every pixel)
        let seen = if matches!(fill, MissFill::Edge) { 0..out.len() } else { self.seen_pixels(d0, out.len()) };
        let put_miss = |block: &mut [f32]| {
            for o in block {
                *o = if accumulate { *o + miss } else { miss };
            }
        };
        let mut i0 = 0;
        let mut p0 = None;
        while i0 < out.len() {
            let len = span.min(out.len() - i0);
            let block = &mut out[i0..i0 + len];
            // a span wholly outside: what the spans below would give it, without a ray cast
            if i0 + len <= seen.start || i0 >= seen.end {
                put_miss(block);
                i0 += len;
                p0 = None;
                continue;
            }
            let p_start = match p0 {
                Some(p) => p,
                None => exact(i0 as f64),
            };
            let p1 = exact((i0 + len) as f64);
            let mid = if len > 2 { exact(i0 as f64 + len as f64 / 2.0) } else { None };
            match (p_start, mid, p1) {
                (Some(a), Some(m), Some(b)) => {
                    let span = Quadratic::through(a, m, b, len as f64);
                    if !self.fast_span(&plane.image, &span, bilinear, block, accumulate) {
                        for (k, o) in block.iter_mut().enumerate() {
                            let value = sample(span.at(k as f64));
                            *o = if accumulate { *o + value } else { value };
                        }
                    }
                }
                _ => {
                    for (k, o) in block.iter_mut().enumerate() {
                        let value =
                            if seen.contains(&(i0 + k)) { exact((i0 + k) as f64).map_or(miss, sample) } else { miss };
                        *o = if accumulate { *o + value } else { value };
                    }
                }
            }
            i0 += len;
            p0 = Some(p1);
        }
    }

    /// The linear forms `c` whose values `c·d` at a ray's dot products `d` are all ≥ 0 wherever the ray meets the
    /// plane in front of the camera within one image pixel of the image (`None`: no ray does, the camera lies on
    /// the plane). The ray parameter is `t = n / D` and the image coordinates `o + n·N/D`; where `t > 0`, `D` has
    /// the sign `s` of `n`, so each bound of the image widened by one pixel, multiplied by `s·D`, is linear in
    /// `d = (D, Nx, Ny)`.
    fn seen_forms(numerator: f64, origin_px: DVec2, image_size: DVec2) -> Option<[DVec3; 5]> {
        let n = numerator;
        if n == 0.0 || !n.is_finite() {
            return None;
        }
        let s = n.signum();
        let (w, h) = (image_size.x, image_size.y);
        let o = origin_px;
        Some([
            DVec3::new(s, 0.0, 0.0),                // in front of the camera
            s * DVec3::new(o.x + 1.0, n, 0.0),      // x ≥ −1
            s * DVec3::new(w + 1.0 - o.x, -n, 0.0), // x ≤ width + 1
            s * DVec3::new(o.y + 1.0, 0.0, n),      // y ≥ −1
            s * DVec3::new(h + 1.0 - o.y, 0.0, -n), // y ≤ height + 1
        ])
    }

    /// The pixels of the row whose pixel 0 has dot products `d0` that may see the image: every pixel outside
    /// the range has exact image coordinates more than one image pixel outside the image, or its ray misses
    /// the plane, so neither its exact sample nor an interpolated one (within the span tolerance, at most ½ px,
    /// of the exact coordinates) lies inside. Along the row each of [`RowGeometry::seen_forms`] is `a + b·i`;
    /// the range is where all are ≥ 0, widened by one pixel for rounding.
    fn seen_pixels(&self, d0: DVec3, pixels: usize) -> std::ops::Range<usize> {
        if !self.clip || self.sees_all {
            return 0..pixels;
        }
        let Some(forms) = self.seen else {
            return 0..0;
        };
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for c in forms {
            let (a, b) = (c.dot(d0), c.dot(self.du));
            if !(a.is_finite() && b.is_finite()) {
                return 0..pixels;
            }
            if b > 0.0 {
                lo = lo.max(-a / b);
            } else if b < 0.0 {
                hi = hi.min(-a / b);
            } else if a < 0.0 {
                return 0..0;
            }
        }
        if lo.is_nan() || hi.is_nan() {
            return 0..pixels;
        }
        if lo > hi {
            return 0..0;
        }
        let first = (lo - 1.0).ceil().clamp(0.0, pixels as f64) as usize;
        let end = ((hi + 1.0).floor() + 1.0).clamp(0.0, pixels as f64) as usize;
        first..end.max(first)
    }

    /// Whether some ray through the sensor `width × height` px (widened by a pixel all round) may see the image:
    /// the sensor rectangle clipped by each of [`RowGeometry::seen_forms`], affine in the sensor point `(u, v)`,
    /// is not empty. False only when every pixel of a render misses the image.
    fn sees_image(&self, width: f64, height: f64) -> bool {
        let Some(forms) = self.seen else {
            return false;
        };
        let mut poly = vec![
            DVec2::new(-1.0, -1.0),
            DVec2::new(width + 1.0, -1.0),
            DVec2::new(width + 1.0, height + 1.0),
            DVec2::new(-1.0, height + 1.0),
        ];
        let mut next = Vec::with_capacity(8);
        for c in forms {
            let (a, gu, gv) = (c.dot(self.base), c.dot(self.du), c.dot(self.dv));
            if !(a.is_finite() && gu.is_finite() && gv.is_finite()) {
                return true;
            }
            let f = |p: DVec2| a + gu * p.x + gv * p.y;
            next.clear();
            for (k, &p) in poly.iter().enumerate() {
                let q = poly[(k + 1) % poly.len()];
                let (fp, fq) = (f(p), f(q));
                if fp >= 0.0 {
                    next.push(p);
                }
                if (fp >= 0.0) != (fq >= 0.0) {
                    next.push(p + (q - p) * (fp / (fp - fq)));
                }
            }
            std::mem::swap(&mut poly, &mut next);
            if poly.is_empty() {
                return false;
            }
        }
        true
    }

    /// Image coordinates of the ray through pixel `i` of the row whose pixel 0 has dot products `d0` (None:
    /// parallel to the plane, or behind the camera).
    #[inline]
    fn coordinates(&self, d0: DVec3, i: f64) -> Option<DVec2> {
        let d = d0 + self.du * i;
        let t = self.numerator / d.x;
        (t > 0.0 && t.is_finite()).then(|| DVec2::new(self.origin_px.x + t * d.y, self.origin_px.y + t * d.z))
    }

    /// How many pixels a span of this row may hold so that the image coordinates, interpolated by the quadratic
    /// through exact values at the span's ends and middle, stay within `tolerance_px` of the exact ones (in
    /// sensor pixels, and in image pixels where the image is magnified less than 1:1); 1 if some ray of the
    /// row misses the plane or the tolerance is 0.
    ///
    /// A coordinate is `f(i) = c + m·N(i)/D(i)` with `N`, `D` linear in `i`, so `f′(i) = m·C/D(i)²` and
    /// `f‴(i) = 6·m·D′²·C/D(i)⁴`, where `C = N′·D − N·D′` is the same for every `i`. The quadratic through
    /// `0, L/2, L` errs by at most `max|f‴|/6 · max|t(t − L/2)(t − L)| = max|f‴| · L³·√3/216`; `|D|` is linear
    /// and keeps its sign along the row, so it is smallest and largest at the row's ends.
    fn span_length(&self, d0: DVec3, pixels: usize, tolerance_px: f64) -> usize {
        const MAX_SPAN: usize = 256;
        if tolerance_px <= 0.0 {
            return 1;
        }
        let d_end = d0 + self.du * pixels as f64;
        let (t0, t1) = (self.numerator / d0.x, self.numerator / d_end.x);
        if !(t0 > 0.0 && t1 > 0.0 && t0.is_finite() && t1.is_finite()) {
            return 1;
        }
        let (min_d, max_d) = (d0.x.abs().min(d_end.x.abs()), d0.x.abs().max(d_end.x.abs()));
        let slope = self.du;
        let (cx, cy) = (slope.y * d0.x - slope.x * d0.y, slope.z * d0.x - slope.x * d0.z);
        let m = self.numerator.abs();
        // image pixels per sensor pixel along the row, at its smallest
        let scale = m * cx.hypot(cy) / (max_d * max_d);
        let tolerance = tolerance_px * scale.min(1.0);
        let third = 6.0 * m * slope.x * slope.x * cx.abs().max(cy.abs()) / min_d.powi(4);
        let cube = tolerance * 216.0 / (3f64.sqrt() * third);
        // the longest span (or a NaN) without the cube root, a libm call that was a tenth of a draft frame's
        // sky on paper_vibration (rows of 128 px there, each its own span)
        if !(cube < (MAX_SPAN * MAX_SPAN * MAX_SPAN) as f64) {
            return MAX_SPAN;
        }
        let span = cube.cbrt();
        if span >= MAX_SPAN as f64 { MAX_SPAN } else { (span as usize).max(1) }
    }

    /// Samples the span's pixels in 24.40 fixed point, stepping the quadratic by forward differences, when
    /// every sample (with its bilinear neighbours) lies inside the image (of fewer than 2²³ pixels a side), so no
    /// pixel needs a bounds test or a float-to-int conversion; returns false, touching nothing, otherwise.
    ///
    /// The differences are truncated to 2⁻⁴⁰ image px, so after `k` steps a position is off by less than
    /// `k²/2·2⁻⁴⁰`: 3·10⁻⁸ image px over a span of [`RowGeometry::span_length`]'s longest, 256 pixels (in 32.32
    /// it had been 8·10⁻⁶, near the 1e-5 px span tolerance `standard` then had).
    #[inline(always)]
    fn fast_span(&self, img: &SkyImage, span: &Quadratic, bilinear: bool, out: &mut [f32], accumulate: bool) -> bool {
        const ONE: f64 = 1_099_511_627_776.0; // 2⁴⁰
        let (w, h) = (img.width, img.height);
        if w >= 1 << 23 || h >= 1 << 23 {
            return false;
        }
        // bilinear samples sit at p − ½ and need the next pixel right and down; nearest ones at p
        let (shift, limit) = if bilinear {
            (0.5, DVec2::new((w - 1) as f64, (h - 1) as f64))
        } else {
            (0.0, DVec2::new(w as f64, h as f64))
        };
        // Every sample lies between the quadratic's values at the span's ends and, on an axis where it turns
        // inside the span, its value there (the exact coordinates are monotonic along the row, but a quadratic
        // within a coarse tolerance of them need not be); the margin covers the fixed-point stepping's drift
        // (below 1e-7 px over a span).
        const MARGIN: f64 = 1e-3;
        let end = (out.len() - 1) as f64;
        let (first, last) = (span.at(0.0) - shift, span.at(end) - shift);
        let (mut lo, mut hi) = (first.min(last), first.max(last));
        for axis in 0..2 {
            let (b, c) = (span.b[axis], span.c[axis]);
            let k = -b / (2.0 * c);
            if k > 0.0 && k < end {
                let turn = span.at(k)[axis] - shift;
                lo[axis] = lo[axis].min(turn);
                hi[axis] = hi[axis].max(turn);
            }
        }
        if !(lo.x >= MARGIN && lo.y >= MARGIN && hi.x < limit.x - MARGIN && hi.y < limit.y - MARGIN) {
            return false;
        }
        let fixed = |v: f64| (v * ONE) as i64;
        let (mut x, mut y) = (fixed(first.x), fixed(first.y));
        // first and second differences: q(k+1) − q(k) = b + c(2k + 1), and 2c
        let (mut dx, mut dy) = (fixed(span.b.x + span.c.x), fixed(span.b.y + span.c.y));
        let (ddx, ddy) = (fixed(2.0 * span.c.x), fixed(2.0 * span.c.y));
        // rows `stride` apart: the row pitch of every index below
        let (px, w) = (img.pixels(), img.stride);
        #[cfg(target_arch = "x86_64")]
        if px.len() < i32::MAX as usize {
            let (q, d, dd) = ([x, y], [dx, dy], [ddx, ddy]);
            match Level::detect() {
                // SAFETY: the CPU has AVX-512; every sample (and its neighbours, bilinear) lies inside the image
                // (checked above)
                Level::Avx512 => unsafe { x86::span(px, w, q, d, dd, bilinear, out, accumulate) },
                // SAFETY: as above, with AVX2
                Level::Avx2 => unsafe { x86::span_avx2(px, w, q, d, dd, bilinear, out, accumulate) },
                Level::Baseline => {}
            }
            if Level::detect() != Level::Baseline {
                return true;
            }
        }
        for o in out.iter_mut() {
            let value = fixed_sample(px, w, x, y, bilinear);
            *o = if accumulate { *o + value } else { value };
            // wrapping, as the vector path steps: the step after the last pixel is never read
            x = x.wrapping_add(dx);
            y = y.wrapping_add(dy);
            dx = dx.wrapping_add(ddx);
            dy = dy.wrapping_add(ddy);
        }
        true
    }
}

/// The sample at a 24.40 fixed-point position (its whole pixel and, bilinear, the top 24 bits of its fraction,
/// exact in f32) of a row-major image whose rows are `w` floats apart: [`SkyPlane::fast_span`]'s per-pixel step, which its vector
/// paths reproduce bit for bit.
#[inline(always)]
fn fixed_sample(px: &[f32], w: usize, x: i64, y: i64, bilinear: bool) -> f32 {
    const FRACTION: f32 = 1.0 / 16_777_216.0; // 2⁻²⁴
    let (xi, yi) = ((x >> 40) as usize, (y >> 40) as usize);
    if bilinear {
        let fx = (((x >> 16) as u32) & 0xff_ffff) as f32 * FRACTION;
        let fy = (((y >> 16) as u32) & 0xff_ffff) as f32 * FRACTION;
        let i = yi * w + xi;
        bilinear_mix(px[i], px[i + 1], px[i + w], px[i + w + 1], fx, fy)
    } else {
        px[yi * w + xi]
    }
}

/// The span with AVX-512 or AVX2 vectors, its texels fetched by windows where they lie close together, else
/// gathered (AVX-512) or loaded a pair of floats per lane and row (AVX2).
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use crate::physics::simd::{sample8_avx2, sample16_avx512};

    /// [`SkyPlane::fast_span`](super::SkyPlane)'s loop (nearest or bilinear), sixteen pixels at a time, the last
    /// block masked. The positions are the scalar recurrence's
    /// (`q(k) = q₀ + k·d₀ + k(k−1)/2·dd` in 24.40 fixed point), stepped sixteen pixels at a time in each lane by
    /// the same identity (`q(k + 16) − q(k) = 16·d₀ + 120·dd + 16k·dd`, exact in wrapping integer arithmetic),
    /// and the mix is the scalar [`bilinear_mix`](super::bilinear_mix)'s operations in its order, so every value
    /// is the same. The texels are read by [`sample16_avx512`]: along a row of a view not turned much against the
    /// image, sixteen lanes' texels lie within one or two windows of 32 floats, two loads and a permute each; a
    /// gather of sixteen had been 90 % of this loop's time (`perf annotate`). The sampler is a const parameter of
    /// the loop ([`span_512`]) so that the nearest sampler's copy leaves out the fractions it does not read (a
    /// quarter of the loop's vector operations).
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL); every position's pixel (and, bilinear, its right and lower
    /// neighbours) must lie inside `px` (rows `w` floats apart), and `px.len()` must fit an `i32`.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn span(
        px: &[f32],
        w: usize,
        q: [i64; 2],
        d: [i64; 2],
        dd: [i64; 2],
        bilinear: bool,
        out: &mut [f32],
        accumulate: bool,
    ) {
        // SAFETY: the caller's promises, passed on
        unsafe {
            if bilinear {
                span_512::<true>(px, w, q, d, dd, out, accumulate)
            } else {
                span_512::<false>(px, w, q, d, dd, out, accumulate)
            }
        }
    }

    /// [`span`] for one sampler.
    ///
    /// # Safety
    /// As [`span`]'s.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    unsafe fn span_512<const BILINEAR: bool>(
        px: &[f32],
        w: usize,
        q: [i64; 2],
        d: [i64; 2],
        dd: [i64; 2],
        out: &mut [f32],
        accumulate: bool,
    ) {
        let lanes_lo = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
        let lanes_hi = _mm512_setr_epi64(8, 9, 10, 11, 12, 13, 14, 15);
        // k(k−1)/2 per lane
        let tri_lo = _mm512_setr_epi64(0, 0, 1, 3, 6, 10, 15, 21);
        let tri_hi = _mm512_setr_epi64(28, 36, 45, 55, 66, 78, 91, 105);
        // the low 32 bits of sixteen 64-bit lanes held in two vectors, in lane order
        let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let top_bits = _mm512_set1_epi32(0xff_ffff);
        let fraction = _mm512_set1_ps(1.0 / 16_777_216.0);
        let width = _mm512_set1_epi32(w as i32);
        // one axis: the sixteen lanes' positions (low lanes, high lanes), the step to the next block's, and the
        // step's own change from block to block
        let axis = |q: i64, d: i64, dd: i64| {
            let (d_, dd_) = (_mm512_set1_epi64(d), _mm512_set1_epi64(dd));
            let at = |lanes: __m512i, tri: __m512i| {
                _mm512_add_epi64(
                    _mm512_set1_epi64(q),
                    _mm512_add_epi64(_mm512_mullo_epi64(lanes, d_), _mm512_mullo_epi64(tri, dd_)),
                )
            };
            let first = d.wrapping_mul(16).wrapping_add(dd.wrapping_mul(120));
            let step = |lanes: __m512i| {
                _mm512_add_epi64(
                    _mm512_set1_epi64(first),
                    _mm512_mullo_epi64(lanes, _mm512_set1_epi64(dd.wrapping_mul(16))),
                )
            };
            ([at(lanes_lo, tri_lo), at(lanes_hi, tri_hi)], [step(lanes_lo), step(lanes_hi)], dd.wrapping_mul(256))
        };
        // whole pixels (i32) and the fraction's top 24 bits as f32 of sixteen positions (0 for nearest samples,
        // which do not read it)
        let split = |p: [__m512i; 2]| {
            let low = |a: __m512i, b: __m512i| _mm512_permutex2var_epi32(a, even, b);
            let whole = low(_mm512_srli_epi64::<40>(p[0]), _mm512_srli_epi64::<40>(p[1]));
            if !BILINEAR {
                return (whole, _mm512_setzero_ps());
            }
            let top24 = _mm512_and_si512(low(_mm512_srli_epi64::<16>(p[0]), _mm512_srli_epi64::<16>(p[1])), top_bits);
            (whole, _mm512_mul_ps(_mm512_cvtepi32_ps(top24), fraction))
        };
        let (mut qx, mut sx, bend_x) = axis(q[0], d[0], dd[0]);
        let (mut qy, mut sy, bend_y) = axis(q[1], d[1], dd[1]);
        let (bend_x, bend_y) = (_mm512_set1_epi64(bend_x), _mm512_set1_epi64(bend_y));
        let n = out.len();
        let mut k = 0;
        while k < n {
            // all sixteen lanes, or the first n − k of them
            let mask: __mmask16 = if n - k >= 16 { 0xffff } else { (1u16 << (n - k)) - 1 };
            let (ix, fx) = split(qx);
            let (iy, fy) = split(qy);
            let i = _mm512_add_epi32(_mm512_mullo_epi32(iy, width), ix);
            // SAFETY: the caller guarantees every written pixel's index and its neighbours are inside `px`; the
            // lanes past the span's end are masked off
            let mut v = unsafe { sample16_avx512(px, i, w, fx, fy, mask, BILINEAR) };
            let at = out[k..].as_mut_ptr();
            // SAFETY: the masked lanes are inside `out`
            unsafe {
                if accumulate {
                    v = _mm512_add_ps(_mm512_maskz_loadu_ps(mask, at), v);
                }
                _mm512_mask_storeu_ps(at, mask, v);
            }
            // sixteen steps of the recurrence in every lane
            qx = [_mm512_add_epi64(qx[0], sx[0]), _mm512_add_epi64(qx[1], sx[1])];
            qy = [_mm512_add_epi64(qy[0], sy[0]), _mm512_add_epi64(qy[1], sy[1])];
            sx = [_mm512_add_epi64(sx[0], bend_x), _mm512_add_epi64(sx[1], bend_x)];
            sy = [_mm512_add_epi64(sy[0], bend_y), _mm512_add_epi64(sy[1], bend_y)];
            k += 16;
        }
    }

    /// [`span`] with AVX2 vectors, eight pixels at a time and the last few (fewer than eight) one by one. The
    /// positions are the scalar recurrence's: the first sixteen by the recurrence itself, then each lane steps
    /// eight pixels at a time by `q(k + 8) − q(k)`, which grows by `64·dd` from one block to the next (exact in
    /// wrapping integer arithmetic). The texels come from [`sample8_avx2`], whose mix is the scalar one.
    ///
    /// # Safety
    /// The CPU must have AVX2; otherwise as [`span`]'s.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2")]
    pub unsafe fn span_avx2(
        px: &[f32],
        w: usize,
        q: [i64; 2],
        d: [i64; 2],
        dd: [i64; 2],
        bilinear: bool,
        out: &mut [f32],
        accumulate: bool,
    ) {
        // SAFETY: the caller's promises, passed on
        unsafe {
            if bilinear {
                span_256::<true>(px, w, q, d, dd, out, accumulate)
            } else {
                span_256::<false>(px, w, q, d, dd, out, accumulate)
            }
        }
    }

    /// [`span_avx2`] for one sampler.
    ///
    /// # Safety
    /// As [`span_avx2`]'s.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2")]
    unsafe fn span_256<const BILINEAR: bool>(
        px: &[f32],
        w: usize,
        q: [i64; 2],
        d: [i64; 2],
        dd: [i64; 2],
        out: &mut [f32],
        accumulate: bool,
    ) {
        let load = |v: &[i64]| {
            // SAFETY: four i64 from a slice of at least four
            unsafe { _mm256_loadu_si256(v.as_ptr().cast()) }
        };
        // one axis: the eight lanes' positions (lanes 0–3, 4–7), their step to the next block's, and the step's
        // own change from block to block
        let axis = |q: i64, d: i64, dd: i64| {
            let mut walk = [0i64; 16];
            let (mut p, mut s) = (q, d);
            for v in &mut walk {
                *v = p;
                p = p.wrapping_add(s);
                s = s.wrapping_add(dd);
            }
            let step: [i64; 8] = std::array::from_fn(|j| walk[j + 8].wrapping_sub(walk[j]));
            ([load(&walk[..4]), load(&walk[4..8])], [load(&step[..4]), load(&step[4..])], dd.wrapping_mul(64))
        };
        let low = crate::physics::simd::low_halves_256;
        let top_bits = _mm256_set1_epi32(0xff_ffff);
        let fraction = _mm256_set1_ps(1.0 / 16_777_216.0);
        let width = _mm256_set1_epi32(w as i32);
        // whole pixels (i32) and the fraction's top 24 bits as f32 (0 for nearest samples, which do not read it)
        let split = |p: [__m256i; 2]| {
            let whole = low(_mm256_srli_epi64::<40>(p[0]), _mm256_srli_epi64::<40>(p[1]));
            if !BILINEAR {
                return (whole, _mm256_setzero_ps());
            }
            let top24 = _mm256_and_si256(low(_mm256_srli_epi64::<16>(p[0]), _mm256_srli_epi64::<16>(p[1])), top_bits);
            (whole, _mm256_mul_ps(_mm256_cvtepi32_ps(top24), fraction))
        };
        let (mut qx, mut sx, bend_x) = axis(q[0], d[0], dd[0]);
        let (mut qy, mut sy, bend_y) = axis(q[1], d[1], dd[1]);
        let (bend_x, bend_y) = (_mm256_set1_epi64x(bend_x), _mm256_set1_epi64x(bend_y));
        let n = out.len();
        let mut k = 0;
        while k + 8 <= n {
            let (ix, fx) = split(qx);
            let (iy, fy) = split(qy);
            let i = _mm256_add_epi32(_mm256_mullo_epi32(iy, width), ix);
            // SAFETY: the caller guarantees every pixel's index and its neighbours are inside `px`
            let mut v = unsafe { sample8_avx2(px, i, w, fx, fy, BILINEAR) };
            let at = out[k..k + 8].as_mut_ptr();
            // SAFETY: eight floats inside `out`
            unsafe {
                if accumulate {
                    v = _mm256_add_ps(_mm256_loadu_ps(at), v);
                }
                _mm256_storeu_ps(at, v);
            }
            // eight steps of the recurrence in every lane
            qx = [_mm256_add_epi64(qx[0], sx[0]), _mm256_add_epi64(qx[1], sx[1])];
            qy = [_mm256_add_epi64(qy[0], sy[0]), _mm256_add_epi64(qy[1], sy[1])];
            sx = [_mm256_add_epi64(sx[0], bend_x), _mm256_add_epi64(sx[1], bend_x)];
            sy = [_mm256_add_epi64(sy[0], bend_y), _mm256_add_epi64(sy[1], bend_y)];
            k += 8;
        }
        if k < n {
            // the last pixels at the lanes' positions, one by one
            let mut at = [[0i64; 8]; 2];
            for (lanes, p) in at.iter_mut().zip([qx, qy]) {
                // SAFETY: eight i64 into an array of eight
                unsafe {
                    _mm256_storeu_si256(lanes.as_mut_ptr().cast(), p[0]);
                    _mm256_storeu_si256(lanes.as_mut_ptr().add(4).cast(), p[1]);
                }
            }
            for (j, o) in out[k..].iter_mut().enumerate() {
                let value = super::fixed_sample(px, w, at[0][j], at[1][j], BILINEAR);
                *o = if accumulate { *o + value } else { value };
            }
        }
    }
}

/// `q(k) = a + b·k + c·k²`: image coordinates along a span, `k` in sensor pixels from its start.
struct Quadratic {
    a: DVec2,
    b: DVec2,
    c: DVec2,
}

impl Quadratic {
    /// The quadratic with values `start`, `mid` and `end` at `0`, `len/2` and `len`.
    fn through(start: DVec2, mid: DVec2, end: DVec2, len: f64) -> Self {
        let c = (start + end - mid * 2.0) * (2.0 / (len * len));
        let b = (end - start) / len - c * len;
        Self { a: start, b, c }
    }

    fn at(&self, k: f64) -> DVec2 {
        self.a + (self.b + self.c * k) * k
    }
}

/// Largest departure of an interpolated ray-cast coordinate from the exact one, in sensor pixels (and in
/// sky-image pixels where the image is magnified less than 1:1), unless [`SkyPlane::set_span_tolerance`] says
/// otherwise: the `standard` quality's value. A sky moved by 0.001 px changes a pixel by at most a thousandth of
/// its gradient in DN per pixel: on the shipped scenarios the frames (noise off) moved by at most 0.006 DN
/// against 1e-5 px, and the render stage of the two whose tracking camera sees the sky image in perspective took
/// about 30 % less time (docs/accuracy.md).
pub const SPAN_TOLERANCE_PX: f64 = 1e-3;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::camera::{Intrinsics, YawPitchRoll};

    fn plane(image: SkyImage) -> SkyPlane {
        let placement = SkyPlacement::paper_fig8();
        SkyPlane::new(image, &placement, DVec3::new(0.0, 0.0, 8000.0)).unwrap()
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_vector_span_is_the_scalar_recurrence_bit_for_bit() {
        let avx512 = is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512dq")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512vl");
        let avx2 = is_x86_feature_detected!("avx2");
        let fixed = |v: f64| (v * 1_099_511_627_776.0) as i64;
        // forwards and backwards, bending either way, over spans of 1 to 100 pixels (whole blocks and tails);
        // and along rows, where the texels are fetched by windows (`physics::simd::texel_windows`): sixteen lanes
        // in one (1.31 texels a pixel), in two of eight (2.7), either way along the row, and on the last rows,
        // where the windows of the later blocks would end past the image and those blocks are gathered (the
        // last path nearest only: its bilinear samples would read the row below the image); and along rows that
        // cross to the next image row inside a block of sixteen, at its fourth lane or its ninth (two windows);
        // and, for AVX2's eight lanes and one window of 16 or 24 floats, rows at 2 texels a pixel (the last lane's
        // right neighbour is the 16 floats' last), at 2.05 (one float more in some blocks: those take 24 floats;
        // nearest samples stay in 16), at 3 (24),
        // and at 3.2, either way along the row (some blocks in 24 floats, others gathered), these three on an image
        // wider than the others' 300 texels, so that their 100 pixels stay inside it
        let both = [(true, false), (true, true), (false, false), (false, true)];
        let nearest = [(false, false), (false, true)];
        let paths: [(_, _, _, &[(bool, bool)]); 12] = [
            ([10.37, 150.2], [0.731, -0.52], [0.0013, -0.0007], &both),
            ([280.9, 20.6], [-1.9, 0.41], [-0.002, 0.003], &both),
            ([5.2, 10.3], [1.31, 0.0004], [0.0001, 0.0], &both),
            ([3.7, 50.5], [2.7, 0.0003], [0.0, 0.0], &both),
            ([280.2, 30.6], [-1.31, 0.0004], [-0.0001, 0.0], &both),
            ([290.1, 60.5], [-2.7, 0.0003], [0.0, 0.0], &both),
            ([250.3, 198.4], [0.4, 0.0], [0.0, 0.0], &both),
            ([250.3, 199.4], [0.4, 0.0], [0.0, 0.0], &nearest),
            ([5.2, 20.975], [1.31, 0.01], [0.0, 0.0], &both),
            ([280.2, 40.925], [-1.31, 0.01], [0.0, 0.0], &both),
            ([7.9, 70.5], [2.0, 0.0], [0.0, 0.0], &both),
            ([7.9, 80.5], [2.05, 0.0], [0.0, 0.0], &both),
        ];
        let wide: [(_, _, _, &[(bool, bool)]); 3] = [
            ([4.6, 90.5], [3.0, 0.0], [0.0, 0.0], &both),
            ([2.3, 100.5], [3.2, 0.0001], [0.0, 0.0], &both),
            ([396.4, 110.5], [-3.2, 0.0], [0.0, 0.0], &both),
        ];
        for (w, paths) in [(300usize, &paths[..]), (400, &wide[..])] {
            let px: Vec<f32> = (0..w * 200).map(|i| (i as f32 * 0.37).sin() * 50.0 + 100.0).collect();
            for &(start, step, bend, modes) in paths {
                for len in 1..=100 {
                    for &(bilinear, accumulate) in modes {
                        let (q, d, dd) = (start.map(fixed), step.map(fixed), bend.map(fixed));
                        let before: Vec<f32> = (0..len).map(|k| k as f32 * 0.25).collect();
                        let mut scalar = before.clone();
                        let (mut x, mut y, mut dx, mut dy) = (q[0], q[1], d[0], d[1]);
                        for o in &mut scalar {
                            let (xi, yi) = ((x >> 40) as usize, (y >> 40) as usize);
                            let i = yi * w + xi;
                            let value = if bilinear {
                                let fx = (((x >> 16) as u32) & 0xff_ffff) as f32 / 16_777_216.0;
                                let fy = (((y >> 16) as u32) & 0xff_ffff) as f32 / 16_777_216.0;
                                bilinear_mix(px[i], px[i + 1], px[i + w], px[i + w + 1], fx, fy)
                            } else {
                                px[i]
                            };
                            *o = if accumulate { *o + value } else { value };
                            (x, y, dx, dy) = (x + dx, y + dy, dx + dd[0], dy + dd[1]);
                        }
                        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                        if avx512 {
                            let mut vector = before.clone();
                            // SAFETY: AVX-512 checked above; the paths stay inside the image
                            unsafe { x86::span(&px, w, q, d, dd, bilinear, &mut vector, accumulate) };
                            assert_eq!(bits(&vector), bits(&scalar), "avx512, len {len}, {bilinear} {accumulate}");
                        }
                        if avx2 {
                            let mut vector = before.clone();
                            // SAFETY: AVX2 checked above; the paths stay inside the image
                            unsafe { x86::span_avx2(&px, w, q, d, dd, bilinear, &mut vector, accumulate) };
                            assert_eq!(bits(&vector), bits(&scalar), "avx2, len {len}, {bilinear} {accumulate}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn paper_placement_is_vertical_and_faces_the_camera() {
        let p = plane(SkyImage::from_f32(4, 4, vec![1.0; 16]).unwrap());
        assert!((p.normal() + DVec3::Y).length() < 1e-15);
        // image centre at P, top-left corner 2 km up and 2 km west
        assert!((p.world_point(DVec2::new(2.0, 2.0)) - DVec3::new(0.0, 30_000.0, 6000.0)).length() < 1e-9);
        assert!((p.world_point(DVec2::ZERO) - DVec3::new(-2000.0, 30_000.0, 8000.0)).length() < 1e-9);
    }

    #[test]
    fn misses_get_the_fill() {
        let p = plane(SkyImage::from_f32(2, 2, vec![5.0; 4]).unwrap());
        let intr = Intrinsics::try_new(8, 8, 0.1, 17e-6).unwrap();
        // looking away from the plane
        let cam =
            Camera::new(intr, DVec3::new(0.0, 0.0, 8000.0), YawPitchRoll { yaw_deg: 180.0, ..Default::default() });
        let mut f = Frame::new(8, 8);
        p.render(&cam, Sampling::Bilinear, MissFill::Zero, &mut f);
        assert!(f.pixels().iter().all(|&v| v == 0.0));
        p.render(&cam, Sampling::Bilinear, MissFill::Constant { value: 7.0 }, &mut f);
        assert!(f.pixels().iter().all(|&v| v == 7.0));
        // looking at P
        let cam = Camera::look_at(intr, DVec3::new(0.0, 0.0, 8000.0), DVec3::new(0.0, 30_000.0, 6000.0), 0.0).unwrap();
        p.render(&cam, Sampling::Nearest, MissFill::Zero, &mut f);
        assert!(f.pixels().iter().all(|&v| v == 5.0));
    }

    #[test]
    fn interpolated_coordinates_stay_within_the_tolerance() {
        // oblique planes, rolled and tilted cameras, magnified and minified images, views near grazing
        let intr = Intrinsics::try_new(320, 240, 0.1, 17e-6).unwrap();
        let mut checked = 0;
        for (normal, camera_x, roll, look_px) in [
            (-DVec3::Y, 0.0, 0.0, 256.0),
            (-DVec3::Y, 3000.0, 17.0, 100.0),
            (DVec3::new(0.5, -1.0, 0.2), -8000.0, -40.0, 400.0),
            (DVec3::new(0.99, -0.1, 0.0), 12_000.0, 5.0, 30.0),
            (DVec3::new(0.0, -0.2, -1.0), 500.0, 70.0, 256.0),
        ] {
            for size_m in [100.0, 4000.0, 200_000.0] {
                let placement = SkyPlacement {
                    anchor_m: DVec3::new(0.0, 30_000.0, 6000.0),
                    anchor_px: None,
                    width_m: size_m,
                    height_m: size_m,
                    normal: Some(normal),
                    up: None,
                };
                let cam_pos = DVec3::new(camera_x, 0.0, 8000.0);
                let p = SkyPlane::new(SkyImage::from_f32(512, 512, vec![0.0; 512 * 512]).unwrap(), &placement, cam_pos)
                    .unwrap();
                let Ok(cam) = Camera::look_at(intr, cam_pos, p.world_point(DVec2::splat(look_px)), roll) else {
                    continue;
                };
                let g = RowGeometry::new(&p, &cam);
                // the standard tolerance, and a coarse one (draft's is 0.02 px)
                for (row, tolerance) in (0..240).step_by(7).flat_map(|r| [(r, SPAN_TOLERANCE_PX), (r, 0.05)]) {
                    let d0 = g.base + g.dv * (row as f64 + 0.5) + g.du * 0.5;
                    let span = g.span_length(d0, 320, tolerance);
                    let mut i0 = 0;
                    while i0 + span <= 320 && span > 2 {
                        let at = |k: usize| g.coordinates(d0, (i0 + k) as f64).unwrap();
                        let mid = g.coordinates(d0, i0 as f64 + span as f64 / 2.0).unwrap();
                        let q = Quadratic::through(at(0), mid, at(span), span as f64);
                        for k in 0..span {
                            let err = (q.at(k as f64) - at(k)).abs().max_element();
                            // local image pixels per sensor pixel
                            let scale = (at(k + 1) - at(k)).length();
                            let allowed = tolerance * scale.min(1.0) * 1.05 + 1e-9 * at(k).length();
                            assert!(err <= allowed, "row {row} pixel {}: error {err:e} > {allowed:e}", i0 + k);
                            checked += 1;
                        }
                        i0 += span;
                    }
                }
            }
        }
        assert!(checked > 10_000, "{checked}");
    }

    #[test]
    fn a_view_of_a_larger_grid_renders_as_its_own_copy_bit_for_bit() {
        // a 200 × 150 image held at (37, 11) in a grid 301 floats a row whose other values are far off (any read
        // of them would show), against the same image on its own: views into it, across its edges and past it,
        // every sampler and fill, turned and not, exact and interpolated spans (the vector paths where the CPU
        // has them)
        let (w, h, stride, at) = (200, 150, 301, (37, 11));
        let value = |x: usize, y: usize| (x % 23) as f32 + 0.37 * y as f32 + 0.01 * ((x * y) % 7) as f32;
        let own: Vec<f32> = (0..w * h).map(|i| value(i % w, i / w)).collect();
        let mut grid = vec![1.0e6f32; stride * (h + 20)];
        for y in 0..h {
            for x in 0..w {
                grid[(at.1 + y) * stride + at.0 + x] = value(x, y);
            }
        }
        let view = SkyImage::view(Arc::new(grid), at.1 * stride + at.0, w, h, stride);
        assert_eq!(view.stride(), stride);
        assert_eq!(view, SkyImage::from_f32(w, h, own.clone()).unwrap());
        let intr = Intrinsics::try_new(96, 80, 0.1, 17e-6).unwrap();
        let cam_pos = DVec3::new(0.0, 0.0, 8000.0);
        let placement = SkyPlacement::paper_fig8();
        let mut a = SkyPlane::new(SkyImage::from_f32(w, h, own).unwrap(), &placement, cam_pos).unwrap();
        let mut b = SkyPlane::new(view, &placement, cam_pos).unwrap();
        let mut compared = 0;
        for (look_x, look_y) in [(100.0, 75.0), (0.0, 40.0), (190.0, 149.0), (400.0, -30.0), (60.0, 10.0)] {
            for roll in [0.0, 27.0] {
                let cam = Camera::look_at(intr, cam_pos, a.world_point(DVec2::new(look_x, look_y)), roll).unwrap();
                for tolerance in [0.0, SPAN_TOLERANCE_PX, 0.5] {
                    a.set_span_tolerance(tolerance);
                    b.set_span_tolerance(tolerance);
                    for sampling in [Sampling::Nearest, Sampling::Bilinear] {
                        for fill in [MissFill::Edge, MissFill::Zero, MissFill::Constant { value: -3.0 }] {
                            let (mut fa, mut fb) = (Frame::new(96, 80), Frame::new(96, 80));
                            a.render(&cam, sampling, fill, &mut fa);
                            b.render(&cam, sampling, fill, &mut fb);
                            let differs =
                                fa.pixels().iter().zip(fb.pixels()).position(|(x, y)| x.to_bits() != y.to_bits());
                            assert_eq!(differs, None, "look {look_x} {look_y}, roll {roll}, {sampling:?}, {fill:?}");
                            assert!(fb.pixels().iter().all(|&v| v < 1.0e5), "a value beyond the view read");
                            compared += 1;
                        }
                    }
                }
            }
        }
        assert_eq!(compared, 5 * 2 * 3 * 2 * 3);
    }

    #[test]
    fn a_span_that_turns_beyond_the_image_is_not_stepped_in_fixed_point() {
        let intr = Intrinsics::try_new(160, 120, 0.1, 17e-6).unwrap();
        let cam_pos = DVec3::new(0.0, 0.0, 8000.0);
        let image = SkyImage::from_f32(64, 64, vec![1.0; 64 * 64]).unwrap();
        let p = SkyPlane::new(image, &SkyPlacement::paper_fig8(), cam_pos).unwrap();
        let cam = Camera::look_at(intr, cam_pos, p.world_point(DVec2::splat(32.0)), 0.0).unwrap();
        let g = RowGeometry::new(&p, &cam);
        for bilinear in [false, true] {
            // both ends inside the image, the middle 30 px beyond its left edge (x = 10 − 1.6k + 0.016k²), and
            // the same on y
            for (b, c) in
                [(DVec2::new(-1.6, 0.0), DVec2::new(0.016, 0.0)), (DVec2::new(0.0, -1.6), DVec2::new(0.0, 0.016))]
            {
                let span = Quadratic { a: DVec2::splat(10.0), b, c };
                let mut out = vec![-7.0f32; 100];
                assert!(!g.fast_span(&p.image, &span, bilinear, &mut out, false), "{b:?}");
                assert!(out.iter().all(|&v| v == -7.0), "nothing written");
                // turning inside the image: sampled
                let span = Quadratic { a: DVec2::splat(50.0), b, c };
                assert!(g.fast_span(&p.image, &span, bilinear, &mut out, false));
                assert!(out.iter().all(|&v| v == 1.0));
            }
        }
    }

    #[test]
    fn skipping_the_pixels_that_cannot_see_the_image_changes_no_pixel() {
        // views into the image, across its edges, past it, grazing it and away from it; every fill but the edge
        // one (which samples every pixel); exact and interpolated spans
        let intr = Intrinsics::try_new(160, 120, 0.1, 17e-6).unwrap();
        let image: Vec<f32> = (0..640 * 480).map(|i| (i % 61) as f32 + 0.25 * (i / 640) as f32).collect();
        let mut skipped = 0usize;
        let mut rows_all_seen = 0usize;
        let mut seen = 0usize;
        let mut views = [0usize; 2];
        for (normal, camera_x, roll) in [
            (-DVec3::Y, 0.0, 0.0),
            (DVec3::new(0.5, -1.0, 0.2), -8000.0, -40.0),
            (DVec3::new(0.99, -0.1, 0.0), 9000.0, 5.0),
        ] {
            let placement = SkyPlacement {
                anchor_m: DVec3::new(0.0, 30_000.0, 6000.0),
                anchor_px: None,
                width_m: 4000.0,
                height_m: 3000.0,
                normal: Some(normal),
                up: None,
            };
            let cam_pos = DVec3::new(camera_x, 0.0, 8000.0);
            let mut p =
                SkyPlane::new(SkyImage::from_f32(640, 480, image.clone()).unwrap(), &placement, cam_pos).unwrap();
            for (look_x, look_y) in
                [(320.0, 240.0), (0.0, 100.0), (700.0, -50.0), (2000.0, 300.0), (-30000.0, 240.0), (320.0, 9000.0)]
            {
                for roll_extra in [0.0, 33.0] {
                    let target = p.world_point(DVec2::new(look_x, look_y));
                    for look in [target, cam_pos * 2.0 - target, cam_pos + (target - cam_pos).cross(DVec3::Z)] {
                        let Ok(cam) = Camera::look_at(intr, cam_pos, look, roll + roll_extra) else {
                            continue;
                        };
                        let mut g = RowGeometry::new(&p, &cam);
                        // a camera that cannot see the image renders misses only
                        p.set_span_tolerance(SPAN_TOLERANCE_PX);
                        let mut f = Frame::new(160, 120);
                        p.render(&cam, Sampling::Bilinear, MissFill::Dome, &mut f);
                        let sees = f.pixels().iter().any(|v| !v.is_nan());
                        assert!(sees <= p.seen_by(&cam), "look {look_x} {look_y}: seen but said unseen");
                        views[usize::from(p.seen_by(&cam))] += 1;
                        for tolerance in [0.0, SPAN_TOLERANCE_PX, 0.5] {
                            p.set_span_tolerance(tolerance);
                            for sampling in [Sampling::Nearest, Sampling::Bilinear] {
                                for fill in [MissFill::Dome, MissFill::Zero, MissFill::Constant { value: -3.0 }] {
                                    for row in (0..120).step_by(3) {
                                        let v = row as f64 + 0.5;
                                        let (mut a, mut b) = (vec![1.0f32; 160], vec![1.0f32; 160]);
                                        g.clip = true;
                                        g.cast_row(&p, v, 0.5, sampling, fill, &mut a, true);
                                        let range = g.seen_pixels(g.base + g.dv * v + g.du * 0.5, 160);
                                        if g.sees_all {
                                            // what the row's bounds would have been: all of it
                                            g.sees_all = false;
                                            let bounds = g.seen_pixels(g.base + g.dv * v + g.du * 0.5, 160);
                                            assert_eq!(bounds, 0..160, "row {row}, look {look_x} {look_y}");
                                            g.sees_all = true;
                                            rows_all_seen += 1;
                                        }
                                        g.clip = false;
                                        g.cast_row(&p, v, 0.5, sampling, fill, &mut b, true);
                                        let same = a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits());
                                        assert!(same, "row {row}, look {look_x} {look_y}, {sampling:?}, {fill:?}");
                                        skipped += 160 - range.len();
                                        seen += range.len();
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        // the test covers both kinds of pixel, and views whose every ray may see the image
        assert!(skipped > 100_000 && seen > 100_000, "{skipped} skipped, {seen} cast");
        assert!(rows_all_seen > 1000, "{rows_all_seen} rows of views that see the image everywhere");
        assert!(views[0] >= 10 && views[1] >= 10, "{views:?} views unseen and seen");
    }

    #[test]
    fn rejects_bad_placement() {
        let img = || SkyImage::from_f32(2, 2, vec![0.0; 4]).unwrap();
        let base = SkyPlacement {
            anchor_m: DVec3::ZERO,
            anchor_px: None,
            width_m: 10.0,
            height_m: 10.0,
            normal: None,
            up: None,
        };
        assert!(SkyPlane::new(img(), &SkyPlacement { width_m: 0.0, ..base }, DVec3::Y).is_err());
        assert!(SkyPlane::new(img(), &base, DVec3::Z).is_err()); // camera straight above, no normal
        assert!(SkyPlane::new(img(), &SkyPlacement { normal: Some(DVec3::Z), ..base }, DVec3::Y).is_err());
        assert!(SkyImage::from_f32(2, 2, vec![0.0; 3]).is_err());
        assert!(SkyImage::from_f32(1, 1, vec![f32::NAN]).is_err());
    }
}
