//! `[quality]`: every approximation the simulation makes that has a cheaper or a more exact setting, in one
//! place. A preset (`draft`, `standard`, `reference`) gives every switch a value; a field given next to it
//! overrides the preset's. `irsim record`, `bench` and `view` take `--quality PRESET`, which replaces the whole
//! table (the file's overrides included).
//!
//! `standard` is what a scenario without `[quality]` gets. `reference` puts every switch at its exact setting,
//! or where a switch has none (a truncated kernel, a quadrature), at the finest the program offers; `draft` gives
//! up accuracy for speed: in the committed report (docs/speed-vs-error, made on an AMD EPYC with 2 vCPUs) its
//! frames are 2.47–12.30× faster than `standard`'s on the shipped scenarios (the least on supersonic_climb, a
//! tracking camera's 640 × 512 frame whose detector readout, the same work in both presets but for the normal
//! deviates' sampler, is most of draft's time), its whole runs 2.31–4.38× shorter, and
//! differ from `reference` by 0.46–19.0 DN rms (the most on paper_cloudy_sky, where the
//! blurred sky is read nearest, made on a 2 px grid, from a cloud layer of 2 px texels: cloud edges move and
//! soften; alone, on sense_and_avoid, the 2 px grid costs 9.7 DN rms and its targets' centroids 0.14 px, the
//! 2 px texels 9.5 DN rms and 0.05 px). The texels also shorten the set-up (a layer's generation and bake),
//! which is common to the presets. What each switch costs and saves is measured in
//! `docs/accuracy.md` and by `irsim bench report`.
//!
//! `standard` is chosen so that, noise off, its frames stay within about 0.4 DN rms and its targets' intensity
//! centroids within 0.015 px of `reference` on every shipped scenario (8 frames each: `irsim record S --frames 8
//! --no-noise --format npy --quality P`; in the committed report at most 0.375 DN rms and 0.0098 px, both on
//! swarm). The switches that mattered: the prefiltered sky texture's grid (0.5 px grids erred up to 0.64 DN rms
//! against the reference's 0.25 px, 0.33 px grids up to 0.38; clear skies take coarser grids within an estimated
//! 0.35 DN, which moved paper_clear_sky from 0.115 to 0.122 DN rms in the report of that change; 0.126 in the
//! committed one), the sun's reflection (the paper's facet overstates a glint by up to 3300 DN against the ellipsoid average),
//! the sky blur route (the per-frame blur errs at sub-pixel cloud edges) and the PSF's cut (3 % of the energy
//! left out gave 1.2 DN rms on paper_cloudy_sky, 1 % gives 0.29).
//!
//! Pure: no Bevy.

use serde::{Deserialize, Serialize};

use super::{FieldError, fe};
use crate::imaging::background::SkyBlur;
use crate::imaging::fusion::{Guidance, Solver};
use crate::imaging::prefilter::TEXTURE_SPACING_PX;
use crate::imaging::psf::{ConvolutionMethod, MAX_RADIUS_PX, REGION_ENERGY_CUTOFF};
use crate::imaging::sky_plane::{SPAN_TOLERANCE_PX, Sampling};
use crate::imaging::target_blob::BlobSampling;
use crate::imaging::target_psf::{self, TargetMethod};
use crate::physics::lowtran::PathSteps;
use crate::physics::planck::PlanckMethod;
use crate::physics::random::NormalSampler;
use crate::physics::reflection::ReflectionGeometry;

/// A named set of values for every switch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QualityPreset {
    /// Fast previews: up to a few tens of DN rms from `reference` where clouds are in view, for at least twice
    /// the speed of `standard` per frame.
    Draft,
    /// The default: errors well below the sensor's noise.
    #[default]
    Standard,
    /// Every switch at its exact or finest setting: the yardstick the others are measured against.
    Reference,
}

impl std::str::FromStr for QualityPreset {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "draft" => Ok(Self::Draft),
            "standard" => Ok(Self::Standard),
            "reference" => Ok(Self::Reference),
            other => Err(format!("`{other}` is not a quality preset: give draft, standard or reference")),
        }
    }
}

impl QualityPreset {
    /// Its name in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Draft => "draft",
            Self::Standard => "standard",
            Self::Reference => "reference",
        }
    }
}

/// Every switch, resolved.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Quality {
    /// The preset the values came from (before overrides).
    pub preset: QualityPreset,
    /// How a ray's hit on a sky image becomes a value.
    pub sky_sampling: Sampling,
    /// Largest departure of an interpolated ray-cast coordinate from the exact one, px (0: every ray exact).
    pub span_tolerance_px: f64,
    /// Step of the temperature → band radiance table used to calibrate sky images and bake cloud layers, K
    /// (0: the Planck series for every value).
    pub radiance_table_step_k: f64,
    /// How the optics kernel is applied to a frame.
    pub psf_method: ConvolutionMethod,
    /// The PSF kernel is cut where the energy outside falls below this fraction.
    pub psf_energy_cutoff: f64,
    /// A target's region (where it is drawn and Poisson-fused) ends where the PSF's energy outside falls below
    /// this fraction.
    pub region_energy_cutoff: f64,
    /// A 16 × 16 px tile is not blurred when the blur cannot change a pixel of it by more than this, DN (0:
    /// always blur).
    pub psf_skip_below_dn: f64,
    /// How the optics blur reaches a sky image.
    pub sky_blur: SkyBlur,
    /// Largest relative difference between a tile's plane-to-sensor Jacobian and its prefiltered texture's.
    pub prefilter_tolerance: f64,
    /// Largest spacing of a prefiltered texture's grid, in pixels of the grid the background is made on: an image
    /// magnified more than this allows is prefiltered onto a grid an integer number of times finer than its
    /// texels.
    pub prefilter_spacing_px: f64,
    /// Largest estimated error of a prefiltered texture's grid, DN rms in any 64-texel block of a sky image
    /// (its bilinear reads against the exact blurred image): the grid is the coarsest, never finer than
    /// `prefilter_spacing_px` allows, that an estimate from the image's own spectrum, the PSF and the view's
    /// Jacobian keeps within it (a smooth sky needs fewer nodes than clouds' edges); 0 keeps
    /// `prefilter_spacing_px`'s grid.
    pub prefilter_grid_error_dn: f64,
    /// The sky background (image, dome and their blur) is made on a grid this many sensor pixels apart each
    /// way, as a camera with pixels this many times larger but the detector's own photosensitive area would see
    /// it, and interpolated bilinearly between (1: at every pixel; a frame whose width or height is not a
    /// multiple of it is made at every pixel).
    pub background_step_px: usize,
    /// On the coarse grid (`background_step_px` > 1) of a camera whose steady view holds still while it shakes,
    /// each shaken view is read from one render of the steady view (with a margin the shake cannot leave),
    /// shifted, when the shift puts the frame's corners, edge midpoints and centre within this many pixels of
    /// where their rays fall in that render (0: every view is rendered). A small turn of a camera about its own
    /// centre moves the image almost as a whole: by a shift, up to a term quadratic in the distance from the
    /// frame's centre, largest at its edges, which those points bound; a roll is not a shift, and a shake whose
    /// peak roll moves the corners by more than this renders every view.
    pub view_shift_tolerance_px: f64,
    /// A generated cloud or haze layer's texel, in sensor pixels at the plane's distance (1: a texel a pixel, up
    /// to the layer's `max_texels`). A coarser layer is the same clouds without their finest detail: its
    /// spectrum holds the same coefficients at the frequencies it has ([`crate::imaging::sky_gen`]), and it costs
    /// the square of this fewer texels to generate and bake.
    pub sky_texel_px: f64,
    /// A generated layer is baked with a margin of clear sky this many sensor pixels wide (at the plane's
    /// distance from the observer's start) on every side, where misses take the dome and a planned view comes
    /// within that many pixels of the layer's edge: texels of the dome along each texel's direction from the
    /// observer's start, which is what the layer's clear texels already hold. The frame's tiles where the layer
    /// ends are then read from the prefiltered texture like the rest, where otherwise the dome beyond the layer's
    /// edge took a per-frame blur there (0: no margin; each ray past the layer takes the dome along its own
    /// direction from where the observer is).
    pub layer_margin_px: f64,
    /// A sky image's prefiltered texture is made from the image widened by this many sensor pixels (at the
    /// plane's distance from the observer's start) of the dome on every side, where misses take the dome, the sky
    /// is read by point samples (`nearest` or `bilinear`), and a planned view comes within that many pixels of the
    /// image's edge: texels of the dome along each texel's direction from the observer's start. The frame's tiles
    /// whose blur reaches past the image's edge are then read from a texture too (on the finest grid of the
    /// spacing), where otherwise the image was ray cast there and blurred every frame. The edge's step becomes a
    /// ramp over one texel, blurred as a continuous image; the per-frame blur read the step at pixel centres, up
    /// to half a pixel off (0: no margin). The margin is at most 1024 texels wide (narrower than asked for an image
    /// of texels under about 0.1 px), and an image whose widened copy would pass 2²⁶ texels gets none.
    pub image_margin_px: f64,
    /// Quadrature of a target's ellipse ⊗ PSF.
    pub target_method: TargetMethod,
    /// Spacing of the quadrature's nodes in a target's ellipse (rings, or columns and the nodes along them), px
    /// (every method; `auto` and `rings` take seven points instead for ellipses smaller than the PSF).
    pub target_node_spacing_px: f64,
    /// Radius of the PSF's core drawn at each of a target's nodes, px: beyond it the PSF's tail is drawn once from
    /// the nodes binned to pixels, between its whole-pixel samples taken as bilinear (at 4 px within 6.5e-4 of a
    /// point's peak on an F/4 MWIR PSF; 0, or a core as large as the kernel: the whole PSF at each node).
    pub target_psf_core_px: usize,
    /// Pixel sampling of the paper's blob model.
    pub blob_sampling: BlobSampling,
    /// The paper's blob is cut where it falls below this fraction of its peak.
    pub blob_roi_fraction: f64,
    /// Shot noise is an exact Poisson count below this mean, electrons, and normal above.
    pub poisson_normal_threshold_e: f64,
    /// How the noise's normal deviates are drawn: the ziggurat (exact), Box–Muller with polynomial functions
    /// (vectorized, within 1e-6 of the exact transform, the tail cut at 5.77 σ) or the quantile picked by 16
    /// bits, from a polynomial per octave (`table`: cheaper, within 6.4e-5 σ, the tail cut at 4.32 σ).
    pub normal_sampler: NormalSampler,
    /// How the Poisson fusion equation is solved (`draft`: the direct solve in f32, of the difference from the
    /// background).
    pub fusion_solver: Solver,
    /// A target whose peak is below this many noise σ (at its background) is added to the frame instead of
    /// fused (0: every target fused).
    pub fusion_skip_below_sigma: f64,
    /// The gradient field that guides the fusion.
    pub fusion_guidance: Guidance,
    /// The sun's reflection: the paper's facet or the average over the ellipsoid.
    pub reflection: ReflectionGeometry,
    /// The ellipsoid average's grid: steps in cos θ and in azimuth.
    pub reflection_grid: [usize; 2],
    /// The sun's reflection is not computed (taken as 0) when a bound on what it adds to a pixel is below this,
    /// DN (0: always computed). The bound is the BRDF's largest value times the sun's irradiance: what a target
    /// filling the pixel with its brightest facet would add.
    pub reflection_skip_below_dn: f64,
    /// How a target's band radiances (its own, and the path's) are integrated over the band.
    pub planck: PlanckMethod,
    /// A target's radiometry is computed again only when its range, or the observer's or target's position
    /// relative to the range, its heading (rad) or its speed changes by more than this fraction since the
    /// last computation (0: at every change).
    pub radiometry_tolerance: f64,
    /// With a LOWTRAN atmosphere, a target's line of sight is interpolated from the table again only when its
    /// range has changed by more than this fraction, or either end's altitude by more than this many km, since
    /// the last interpolation; in between, that spectrum is stretched to the new range bin by bin, Beer–Lambert
    /// (0: at every change).
    pub atmosphere_tolerance: f64,
    /// With a LOWTRAN atmosphere, how finely each path's integrals along the line of sight are taken:
    /// `[aerosol trapezoids, path-radiance segments]` ([`PathSteps`]). Most of the set-up of a scene with a
    /// LOWTRAN atmosphere is these paths (the observer's tables and the clear sky), in proportion to the two.
    pub atmosphere_steps: [usize; 2],
}

impl Quality {
    /// The preset's values.
    pub fn preset(p: QualityPreset) -> Self {
        let standard = Self {
            preset: QualityPreset::Standard,
            sky_sampling: Sampling::Bilinear,
            span_tolerance_px: SPAN_TOLERANCE_PX,
            radiance_table_step_k: 0.02,
            psf_method: ConvolutionMethod::Separable,
            psf_energy_cutoff: 0.01,
            region_energy_cutoff: REGION_ENERGY_CUTOFF,
            psf_skip_below_dn: 0.1,
            sky_blur: SkyBlur::Prefilter,
            prefilter_tolerance: 0.05,
            prefilter_spacing_px: TEXTURE_SPACING_PX,
            prefilter_grid_error_dn: STANDARD_PREFILTER_GRID_ERROR_DN,
            background_step_px: 1,
            view_shift_tolerance_px: 0.0,
            sky_texel_px: 1.0,
            layer_margin_px: LAYER_MARGIN_PX,
            image_margin_px: IMAGE_MARGIN_PX,
            target_method: TargetMethod::Auto,
            target_node_spacing_px: target_psf::NODE_SPACING_PX,
            target_psf_core_px: target_psf::CORE_PX,
            blob_sampling: BlobSampling::Auto,
            blob_roi_fraction: 1e-3,
            poisson_normal_threshold_e: 100.0,
            normal_sampler: NormalSampler::BoxMuller,
            fusion_solver: Solver::Direct,
            fusion_skip_below_sigma: 0.0,
            fusion_guidance: Guidance::Normal,
            reflection: ReflectionGeometry::Ellipsoid,
            reflection_grid: [24, 48],
            reflection_skip_below_dn: 0.0,
            planck: PlanckMethod::Series,
            radiometry_tolerance: 0.0,
            atmosphere_tolerance: STANDARD_ATMOSPHERE_TOLERANCE,
            atmosphere_steps: steps(PathSteps::STANDARD),
        };
        // the other two say where they differ from it (the fusion guidance and the reflection geometry are the
        // same in all three)
        match p {
            QualityPreset::Standard => standard,
            QualityPreset::Reference => Self {
                preset: p,
                span_tolerance_px: 0.0,
                radiance_table_step_k: 0.0,
                psf_method: ConvolutionMethod::Direct,
                psf_energy_cutoff: MIN_ENERGY_CUTOFF,
                psf_skip_below_dn: 0.0,
                prefilter_tolerance: REFERENCE_PREFILTER_TOLERANCE,
                prefilter_spacing_px: REFERENCE_PREFILTER_SPACING_PX,
                prefilter_grid_error_dn: 0.0,
                target_method: TargetMethod::Reference,
                target_node_spacing_px: target_psf::REFERENCE_NODE_SPACING_PX,
                target_psf_core_px: 0,
                blob_sampling: BlobSampling::Integrated { n: 16 },
                blob_roi_fraction: MIN_ROI_FRACTION,
                poisson_normal_threshold_e: MAX_POISSON_THRESHOLD_E,
                normal_sampler: NormalSampler::Ziggurat,
                reflection_grid: [192, 384],
                atmosphere_tolerance: 0.0,
                atmosphere_steps: steps(PathSteps::REFERENCE),
                layer_margin_px: 0.0,
                ..standard
            },
            QualityPreset::Draft => Self {
                preset: p,
                sky_sampling: Sampling::Nearest,
                span_tolerance_px: 0.02,
                radiance_table_step_k: 0.1,
                psf_energy_cutoff: 0.1,
                fusion_skip_below_sigma: DRAFT_FUSION_SKIP_BELOW_SIGMA,
                fusion_solver: Solver::DirectF32,
                psf_skip_below_dn: 1.0,
                sky_blur: SkyBlur::Auto,
                prefilter_tolerance: 0.2,
                prefilter_spacing_px: DRAFT_PREFILTER_SPACING_PX,
                prefilter_grid_error_dn: DRAFT_PREFILTER_GRID_ERROR_DN,
                background_step_px: DRAFT_BACKGROUND_STEP_PX,
                view_shift_tolerance_px: DRAFT_VIEW_SHIFT_TOLERANCE_PX,
                sky_texel_px: DRAFT_SKY_TEXEL_PX,
                layer_margin_px: 0.0,
                image_margin_px: 0.0,
                target_node_spacing_px: DRAFT_TARGET_NODE_SPACING_PX,
                target_psf_core_px: DRAFT_TARGET_PSF_CORE_PX,
                blob_sampling: BlobSampling::Point,
                blob_roi_fraction: 1e-2,
                poisson_normal_threshold_e: 10.0,
                normal_sampler: NormalSampler::Table,
                reflection_grid: [8, 16],
                reflection_skip_below_dn: DRAFT_REFLECTION_SKIP_BELOW_DN,
                planck: PlanckMethod::GaussLegendre { points: DRAFT_PLANCK_POINTS },
                radiometry_tolerance: DRAFT_RADIOMETRY_TOLERANCE,
                atmosphere_tolerance: DRAFT_ATMOSPHERE_TOLERANCE,
                atmosphere_steps: steps(PathSteps::DRAFT),
                ..standard
            },
        }
    }

    /// Each switch as `(name, value as TOML, whether it differs from the preset's)`, for `irsim validate` and
    /// the viewer.
    pub fn describe(&self) -> Vec<(&'static str, String, bool)> {
        let base = Self::preset(self.preset);
        let json = |q: &Self| serde_json::to_value(q).unwrap_or_default();
        let (mine, theirs) = (json(self), json(&base));
        SWITCHES.iter().map(|&name| (name, toml_value(&mine[name]), mine[name] != theirs[name])).collect()
    }

    /// [`Quality::atmosphere_steps`] as the atmosphere takes them.
    pub fn path_steps(&self) -> PathSteps {
        let [aerosol, radiance] = self.atmosphere_steps;
        PathSteps { aerosol, radiance }
    }
}

/// A [`PathSteps`] as `[aerosol, radiance]`.
const fn steps(s: PathSteps) -> [usize; 2] {
    [s.aerosol, s.radiance]
}

/// A JSON value as TOML writes it inline: `"auto"`, `0.02`, `[24, 48]`, `{ mode = "bilinear" }`.
pub fn toml_value(v: &serde_json::Value) -> String {
    use serde_json::Value;
    match v {
        Value::String(s) => format!("\"{s}\""),
        Value::Array(a) => format!("[{}]", a.iter().map(toml_value).collect::<Vec<_>>().join(", ")),
        Value::Object(o) => {
            format!(
                "{{ {} }}",
                o.iter().map(|(k, v)| format!("{k} = {}", toml_value(v))).collect::<Vec<_>>().join(", ")
            )
        }
        other => other.to_string(),
    }
}

impl Default for Quality {
    fn default() -> Self {
        Self::preset(QualityPreset::Standard)
    }
}

/// The switches' names, in the order of the table.
pub const SWITCHES: [&str; 34] = [
    "preset",
    "sky_sampling",
    "span_tolerance_px",
    "radiance_table_step_k",
    "psf_method",
    "psf_energy_cutoff",
    "region_energy_cutoff",
    "psf_skip_below_dn",
    "sky_blur",
    "prefilter_tolerance",
    "prefilter_spacing_px",
    "prefilter_grid_error_dn",
    "background_step_px",
    "view_shift_tolerance_px",
    "sky_texel_px",
    "layer_margin_px",
    "image_margin_px",
    "target_method",
    "target_node_spacing_px",
    "target_psf_core_px",
    "blob_sampling",
    "blob_roi_fraction",
    "poisson_normal_threshold_e",
    "normal_sampler",
    "fusion_solver",
    "fusion_skip_below_sigma",
    "fusion_guidance",
    "reflection",
    "reflection_grid",
    "reflection_skip_below_dn",
    "planck",
    "radiometry_tolerance",
    "atmosphere_tolerance",
    "atmosphere_steps",
];

/// Smallest `psf_energy_cutoff` (the kernel's radius is also capped at 12 px).
pub const MIN_ENERGY_CUTOFF: f64 = 1e-6;
/// Smallest `prefilter_tolerance`.
pub const MIN_PREFILTER_TOLERANCE: f64 = 1e-3;
/// The reference preset's `prefilter_tolerance`. Not the smallest: a tile whose Jacobian is farther than this
/// from its texture's is blurred per frame from point samples, the less accurate of the two routes (6.7 DN rms
/// against 0.63 at cloud edges, docs/accuracy.md), and at 0.001 perspective alone sends 94 % of crossing_pair's
/// frame that way.
pub const REFERENCE_PREFILTER_TOLERANCE: f64 = 0.01;
/// The reference preset's `prefilter_spacing_px`. Against it, on the shipped scenarios' generated layers (a
/// texel a pixel, so grids of 1/m px), a grid of 0.5 px erred 0.41–0.64 DN rms and one of 0.33 px 0.12–0.24
/// (noise off, 8 frames, docs/accuracy.md).
pub const REFERENCE_PREFILTER_SPACING_PX: f64 = 0.25;
/// The draft preset's `prefilter_spacing_px`.
pub const DRAFT_PREFILTER_SPACING_PX: f64 = 0.75;
/// The standard preset's `prefilter_grid_error_dn`: clear skies take coarser grids (paper_clear_sky two nodes a
/// texel, estimated 0.30 DN; head_on one, 0.14 DN), cumulus keeps three (estimated 0.9–1.2 DN at three). The
/// estimate is the largest over the image's blocks, a layer's margin of clear sky (`layer_margin_px`) included:
/// head_on's 250 frames come near its layer's edge, so its layer has the margin and reads two nodes a texel (one
/// without it), and so does paper_clear_sky's in runs longer than about 200 frames (three, against two).
/// Against the reference preset (`irsim record S --frames 8 --no-noise --format npy`) paper_clear_sky moved
/// from 0.115 to 0.123 DN rms and head_on from 0.019 to 0.042 (docs/accuracy.md; the report's own 8 frames give
/// 0.122 and 0.042).
pub const STANDARD_PREFILTER_GRID_ERROR_DN: f64 = 0.35;
/// The draft preset's `prefilter_grid_error_dn`: a clear sky whose estimate at one node a texel is under 1 DN
/// (head_on's, 0.14 DN at the standard spacing) is read from one node a texel.
pub const DRAFT_PREFILTER_GRID_ERROR_DN: f64 = 1.0;
/// Largest `prefilter_grid_error_dn`.
pub const MAX_PREFILTER_GRID_ERROR_DN: f64 = 100.0;
/// Smallest and largest `prefilter_spacing_px`.
pub const PREFILTER_SPACING_RANGE_PX: (f64, f64) = (0.1, 4.0);
/// The draft preset's `fusion_skip_below_sigma`: a target whose peak is under the noise σ is not detectable in
/// one frame.
pub const DRAFT_FUSION_SKIP_BELOW_SIGMA: f64 = 1.0;
/// The draft preset's `reflection_skip_below_dn`: half a gray level, the rounding's own error.
pub const DRAFT_REFLECTION_SKIP_BELOW_DN: f64 = 0.5;
/// The draft preset's Gauss–Legendre nodes for band radiances.
pub const DRAFT_PLANCK_POINTS: usize = 4;
/// The draft preset's `radiometry_tolerance`.
pub const DRAFT_RADIOMETRY_TOLERANCE: f64 = 1e-3;
/// Largest `radiometry_tolerance`.
pub const MAX_RADIOMETRY_TOLERANCE: f64 = 0.1;
/// The standard preset's `atmosphere_tolerance`.
pub const STANDARD_ATMOSPHERE_TOLERANCE: f64 = 0.01;
/// The draft preset's `atmosphere_tolerance`.
pub const DRAFT_ATMOSPHERE_TOLERANCE: f64 = 0.05;
/// Largest `atmosphere_tolerance`.
pub const MAX_ATMOSPHERE_TOLERANCE: f64 = 0.2;
/// The draft preset's `target_node_spacing_px`: on crossing_pair a quarter of the nodes of 0.3 px (targets
/// stage 117 -> 34 µs a frame), pixels moved by at most 4.6 DN (noise off, 30 frames).
pub const DRAFT_TARGET_NODE_SPACING_PX: f64 = 0.6;
/// The draft preset's `target_psf_core_px`: within 2.4e-3 of a point's peak on an F/4 MWIR PSF cut at 12 px
/// (`split_psf_error`). Draft's own `psf_energy_cutoff` gives kernels no larger than the core on the shipped lenses,
/// so it splits only where the cut-off is set finer.
pub const DRAFT_TARGET_PSF_CORE_PX: usize = 3;
/// The draft preset's `background_step_px`.
pub const DRAFT_BACKGROUND_STEP_PX: usize = 2;
/// Largest `background_step_px`.
pub const MAX_BACKGROUND_STEP_PX: usize = 4;
/// The draft preset's `view_shift_tolerance_px`: a tenth of a pixel, under the error of draft's own
/// interpolation between the nodes of its 2 px grid.
pub const DRAFT_VIEW_SHIFT_TOLERANCE_PX: f64 = 0.1;
/// Largest `view_shift_tolerance_px`.
pub const MAX_VIEW_SHIFT_TOLERANCE_PX: f64 = 2.0;
/// The draft preset's `sky_texel_px`: the texels of the background's own 2 px grid.
pub const DRAFT_SKY_TEXEL_PX: f64 = 2.0;
/// Smallest and largest `sky_texel_px`.
pub const SKY_TEXEL_RANGE_PX: (f64, f64) = (0.5, 8.0);
/// The standard preset's `layer_margin_px`. A tile whose blur reads past the layer's edge (the tile's 16 px and the
/// PSF's reach on both sides, 13 px for the shipped cameras) is read from the texture only where the margin holds
/// all it reads: 48 px left 3 % of swarm's frame and 9 % of sense_and_avoid's to the per-frame blur (their views
/// reach farther below the layer's lower edge than 48 px less that reach), 96 px none of either. The draft preset
/// keeps 0: on sense_and_avoid the margin's blocks raised draft's grid estimate, and on that finer grid draft's
/// frames are farther from standard's (26 DN rms against 17.7 on the coarser one, with or without the margin).
pub const LAYER_MARGIN_PX: f64 = 96.0;
/// Largest `layer_margin_px`.
pub const MAX_LAYER_MARGIN_PX: f64 = 512.0;
/// The standard and reference presets' `image_margin_px`: as [`LAYER_MARGIN_PX`], the tile's 16 px and the PSF's
/// reach on both sides with room for the view's motion. Against the brute-force blur at an image's edge (`cargo
/// test --lib an_image_widened`, a step of 14.5 radiance units) the margin's texture errs 0.02–0.12 rms where
/// the per-frame blur of the image's point samples erred 0.06–0.39 (up to 3.95 where the edge lies on a row of
/// pixel centres); the reference keeps it for that reason. The draft preset keeps 0 (its nearest reads gained no
/// speed from it).
pub const IMAGE_MARGIN_PX: f64 = 96.0;
/// Largest `image_margin_px`.
pub const MAX_IMAGE_MARGIN_PX: f64 = 512.0;
/// Smallest `blob_roi_fraction`.
pub const MIN_ROI_FRACTION: f64 = 1e-9;
/// Largest `poisson_normal_threshold_e`: every count exact.
pub const MAX_POISSON_THRESHOLD_E: f64 = 1e9;

/// The `[quality]` table: a preset and overrides of any of its switches.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QualitySpec {
    /// `draft`, `standard` (default) or `reference`.
    pub preset: QualityPreset,
    /// See [`Quality::sky_sampling`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sky_sampling: Option<Sampling>,
    /// See [`Quality::span_tolerance_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub span_tolerance_px: Option<f64>,
    /// See [`Quality::radiance_table_step_k`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radiance_table_step_k: Option<f64>,
    /// See [`Quality::psf_method`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psf_method: Option<ConvolutionMethod>,
    /// See [`Quality::psf_energy_cutoff`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psf_energy_cutoff: Option<f64>,
    /// See [`Quality::region_energy_cutoff`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub region_energy_cutoff: Option<f64>,
    /// See [`Quality::psf_skip_below_dn`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psf_skip_below_dn: Option<f64>,
    /// See [`Quality::sky_blur`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sky_blur: Option<SkyBlur>,
    /// See [`Quality::prefilter_tolerance`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prefilter_tolerance: Option<f64>,
    /// See [`Quality::prefilter_spacing_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prefilter_spacing_px: Option<f64>,
    /// See [`Quality::prefilter_grid_error_dn`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prefilter_grid_error_dn: Option<f64>,
    /// See [`Quality::background_step_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub background_step_px: Option<usize>,
    /// See [`Quality::view_shift_tolerance_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view_shift_tolerance_px: Option<f64>,
    /// See [`Quality::sky_texel_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sky_texel_px: Option<f64>,
    /// See [`Quality::layer_margin_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layer_margin_px: Option<f64>,
    /// See [`Quality::image_margin_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image_margin_px: Option<f64>,
    /// See [`Quality::target_method`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_method: Option<TargetMethod>,
    /// See [`Quality::target_node_spacing_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_node_spacing_px: Option<f64>,
    /// See [`Quality::target_psf_core_px`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_psf_core_px: Option<usize>,
    /// See [`Quality::blob_sampling`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blob_sampling: Option<BlobSampling>,
    /// See [`Quality::blob_roi_fraction`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blob_roi_fraction: Option<f64>,
    /// See [`Quality::poisson_normal_threshold_e`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub poisson_normal_threshold_e: Option<f64>,
    /// See [`Quality::normal_sampler`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_sampler: Option<NormalSampler>,
    /// See [`Quality::fusion_solver`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fusion_solver: Option<Solver>,
    /// See [`Quality::fusion_skip_below_sigma`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fusion_skip_below_sigma: Option<f64>,
    /// See [`Quality::fusion_guidance`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fusion_guidance: Option<Guidance>,
    /// See [`Quality::reflection`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflection: Option<ReflectionGeometry>,
    /// See [`Quality::reflection_grid`].
    #[serde(skip_serializing_if = "Option::is_none", with = "crate::physics::exact::opt_counts2")]
    pub reflection_grid: Option<[usize; 2]>,
    /// See [`Quality::reflection_skip_below_dn`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflection_skip_below_dn: Option<f64>,
    /// See [`Quality::planck`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub planck: Option<PlanckMethod>,
    /// See [`Quality::radiometry_tolerance`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radiometry_tolerance: Option<f64>,
    /// See [`Quality::atmosphere_tolerance`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub atmosphere_tolerance: Option<f64>,
    /// See [`Quality::atmosphere_steps`].
    #[serde(skip_serializing_if = "Option::is_none", with = "crate::physics::exact::opt_counts2")]
    pub atmosphere_steps: Option<[usize; 2]>,
}

impl QualitySpec {
    /// Only the preset: what `--quality` puts in place of a file's table.
    pub fn of(preset: QualityPreset) -> Self {
        Self { preset, ..Self::default() }
    }

    /// The switches this table overrides, by name.
    pub fn overrides(&self) -> Vec<&'static str> {
        let v = serde_json::to_value(self).unwrap_or_default();
        SWITCHES.iter().copied().filter(|&n| n != "preset" && v.get(n).is_some()).collect()
    }

    /// The preset with the overrides applied, every value checked.
    ///
    /// # Errors
    /// A [`FieldError`] under `quality.`.
    pub fn resolve(&self) -> Result<Quality, FieldError> {
        let mut q = Quality::preset(self.preset);
        macro_rules! set {
            ($($f:ident),*) => {$(
                if let Some(v) = self.$f {
                    q.$f = v;
                }
            )*};
        }
        set!(
            sky_sampling,
            span_tolerance_px,
            radiance_table_step_k,
            psf_method,
            psf_energy_cutoff,
            region_energy_cutoff,
            psf_skip_below_dn,
            sky_blur,
            prefilter_tolerance,
            prefilter_spacing_px,
            prefilter_grid_error_dn,
            background_step_px,
            view_shift_tolerance_px,
            sky_texel_px,
            layer_margin_px,
            image_margin_px,
            target_method,
            target_node_spacing_px,
            target_psf_core_px,
            blob_sampling,
            blob_roi_fraction,
            poisson_normal_threshold_e,
            normal_sampler,
            fusion_solver,
            fusion_skip_below_sigma,
            fusion_guidance,
            reflection,
            reflection_grid,
            reflection_skip_below_dn,
            planck,
            radiometry_tolerance,
            atmosphere_tolerance,
            atmosphere_steps
        );
        let range = |name: &str, v: f64, lo: f64, hi: f64, unit: &str| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(fe(format!("quality.{name}"), format!("{} must be in [{lo}, {hi}]{unit}", super::num(v))))
            }
        };
        if let Sampling::Supersample { n } = q.sky_sampling
            && !(1..=16).contains(&n)
        {
            return Err(fe("quality.sky_sampling.n", format!("{n} must be in 1 … 16")));
        }
        range("span_tolerance_px", q.span_tolerance_px, 0.0, 0.5, " px")?;
        if q.radiance_table_step_k != 0.0 {
            range("radiance_table_step_k", q.radiance_table_step_k, 0.001, 5.0, " K (or 0: no table)")?;
        }
        range("psf_energy_cutoff", q.psf_energy_cutoff, MIN_ENERGY_CUTOFF, 0.2, "")?;
        range("target_node_spacing_px", q.target_node_spacing_px, 0.01, 2.0, " px")?;
        if q.target_psf_core_px > MAX_RADIUS_PX {
            return Err(fe(
                "quality.target_psf_core_px",
                format!("{} must be in 0 … {MAX_RADIUS_PX} px", q.target_psf_core_px),
            ));
        }
        range("region_energy_cutoff", q.region_energy_cutoff, REGION_ENERGY_CUTOFF, 0.2, "")?;
        range("psf_skip_below_dn", q.psf_skip_below_dn, 0.0, 1e6, " DN")?;
        range("fusion_skip_below_sigma", q.fusion_skip_below_sigma, 0.0, 100.0, " σ")?;
        range("prefilter_tolerance", q.prefilter_tolerance, MIN_PREFILTER_TOLERANCE, 0.5, "")?;
        let (lo, hi) = PREFILTER_SPACING_RANGE_PX;
        range("prefilter_spacing_px", q.prefilter_spacing_px, lo, hi, " px")?;
        range("prefilter_grid_error_dn", q.prefilter_grid_error_dn, 0.0, MAX_PREFILTER_GRID_ERROR_DN, " DN")?;
        if !(1..=MAX_BACKGROUND_STEP_PX).contains(&q.background_step_px) {
            return Err(fe(
                "quality.background_step_px",
                format!("{} must be in 1 … {MAX_BACKGROUND_STEP_PX} px", q.background_step_px),
            ));
        }
        range("view_shift_tolerance_px", q.view_shift_tolerance_px, 0.0, MAX_VIEW_SHIFT_TOLERANCE_PX, " px")?;
        range("sky_texel_px", q.sky_texel_px, SKY_TEXEL_RANGE_PX.0, SKY_TEXEL_RANGE_PX.1, " px")?;
        range("layer_margin_px", q.layer_margin_px, 0.0, MAX_LAYER_MARGIN_PX, " px")?;
        range("image_margin_px", q.image_margin_px, 0.0, MAX_IMAGE_MARGIN_PX, " px")?;
        if let BlobSampling::Integrated { n } = q.blob_sampling
            && !(1..=16).contains(&n)
        {
            return Err(fe("quality.blob_sampling.n", format!("{n} must be in 1 … 16")));
        }
        if !(q.blob_roi_fraction >= MIN_ROI_FRACTION && q.blob_roi_fraction < 1.0) {
            return Err(fe(
                "quality.blob_roi_fraction",
                format!("{} must be in [{MIN_ROI_FRACTION}, 1)", super::num(q.blob_roi_fraction)),
            ));
        }
        range("poisson_normal_threshold_e", q.poisson_normal_threshold_e, 0.0, MAX_POISSON_THRESHOLD_E, " e⁻")?;
        match q.fusion_solver {
            Solver::Direct | Solver::DirectF32 => {}
            Solver::Jacobi { tolerance, max_iterations } | Solver::Sor { tolerance, max_iterations } => {
                if !(tolerance > 0.0 && tolerance.is_finite()) {
                    return Err(fe(
                        "quality.fusion_solver.tolerance",
                        format!("{} must be a finite number > 0", super::num(tolerance)),
                    ));
                }
                if !(1..=super::MAX_SOLVER_ITERATIONS).contains(&max_iterations) {
                    return Err(fe(
                        "quality.fusion_solver.max_iterations",
                        format!("{max_iterations} must be in 1 … {}", super::MAX_SOLVER_ITERATIONS),
                    ));
                }
            }
        }
        range("reflection_skip_below_dn", q.reflection_skip_below_dn, 0.0, 1e6, " DN")?;
        range("radiometry_tolerance", q.radiometry_tolerance, 0.0, MAX_RADIOMETRY_TOLERANCE, "")?;
        range("atmosphere_tolerance", q.atmosphere_tolerance, 0.0, MAX_ATMOSPHERE_TOLERANCE, "")?;
        if let Err(e) = q.planck.check() {
            let field = match q.planck {
                PlanckMethod::Simpson { .. } => "quality.planck.intervals",
                _ => "quality.planck.points",
            };
            return Err(fe(field, e));
        }
        let [n_z, n_phi] = q.reflection_grid;
        if !((2..=2000).contains(&n_z) && (4..=4000).contains(&n_phi)) {
            return Err(fe(
                "quality.reflection_grid",
                format!("[{n_z}, {n_phi}] must be [2 … 2000 steps in cos θ, 4 … 4000 in azimuth]"),
            ));
        }
        let [aerosol, radiance] = q.atmosphere_steps;
        let (lo, hi) = (PathSteps::MIN, PathSteps::REFERENCE.aerosol.max(PathSteps::REFERENCE.radiance));
        if !((lo..=hi).contains(&aerosol) && (lo..=hi).contains(&radiance)) {
            return Err(fe(
                "quality.atmosphere_steps",
                format!(
                    "[{aerosol}, {radiance}] must be [{lo} … {hi} aerosol trapezoids, {lo} … {hi} path-radiance segments]"
                ),
            ));
        }
        Ok(q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_is_valid_and_described_in_full() {
        for p in [QualityPreset::Draft, QualityPreset::Standard, QualityPreset::Reference] {
            let q = QualitySpec::of(p).resolve().unwrap();
            assert_eq!(q, Quality::preset(p));
            let d = q.describe();
            assert_eq!(d.len(), SWITCHES.len());
            assert!(d.iter().all(|(_, v, changed)| !v.is_empty() && v != "null" && !changed), "{d:?}");
            // the values read back as the table's own syntax
            let text: String = d.iter().map(|(n, v, _)| format!("{n} = {v}\n")).collect();
            let again: QualitySpec = toml::from_str(&text).unwrap();
            assert_eq!(again.resolve().unwrap(), q, "{text}");
        }
    }

    #[test]
    fn overrides_apply_and_are_reported() {
        let spec: QualitySpec = toml::from_str(
            "preset = \"draft\"\nreflection = \"facet\"\nfusion_solver = { method = \"sor\", tolerance = 1e-3, \
             max_iterations = 500 }",
        )
        .unwrap();
        assert_eq!(spec.overrides(), ["fusion_solver", "reflection"]);
        let q = spec.resolve().unwrap();
        assert_eq!(q.reflection, ReflectionGeometry::Facet);
        assert_eq!(q.blob_sampling, BlobSampling::Point);
        let changed: Vec<_> = q.describe().into_iter().filter(|d| d.2).map(|d| d.0).collect();
        assert_eq!(changed, ["fusion_solver", "reflection"]);
    }

    #[test]
    fn bad_values_name_their_field() {
        for (text, field) in [
            ("span_tolerance_px = -1", "quality.span_tolerance_px"),
            ("psf_energy_cutoff = 0.5", "quality.psf_energy_cutoff"),
            ("sky_sampling = { mode = \"supersample\", n = 40 }", "quality.sky_sampling.n"),
            ("reflection_grid = [1, 48]", "quality.reflection_grid"),
            ("atmosphere_steps = [1, 32]", "quality.atmosphere_steps"),
            ("atmosphere_steps = [128, 100000]", "quality.atmosphere_steps"),
            ("radiance_table_step_k = 1e-9", "quality.radiance_table_step_k"),
            ("planck = { method = \"simpson\", intervals = 3 }", "quality.planck.intervals"),
            ("planck = { method = \"gauss_legendre\", points = 0 }", "quality.planck.points"),
            ("radiometry_tolerance = 0.5", "quality.radiometry_tolerance"),
            ("reflection_skip_below_dn = -1", "quality.reflection_skip_below_dn"),
            ("background_step_px = 0", "quality.background_step_px"),
            ("background_step_px = 9", "quality.background_step_px"),
            ("target_psf_core_px = 13", "quality.target_psf_core_px"),
            ("view_shift_tolerance_px = -0.1", "quality.view_shift_tolerance_px"),
            ("view_shift_tolerance_px = 3", "quality.view_shift_tolerance_px"),
            ("view_shift_tolerance_px = nan", "quality.view_shift_tolerance_px"),
            ("sky_texel_px = 0.1", "quality.sky_texel_px"),
            ("sky_texel_px = nan", "quality.sky_texel_px"),
            ("layer_margin_px = -1", "quality.layer_margin_px"),
            ("layer_margin_px = 1e9", "quality.layer_margin_px"),
            ("layer_margin_px = nan", "quality.layer_margin_px"),
            ("image_margin_px = -1", "quality.image_margin_px"),
            ("image_margin_px = 1e9", "quality.image_margin_px"),
            ("image_margin_px = nan", "quality.image_margin_px"),
            ("prefilter_spacing_px = 0", "quality.prefilter_spacing_px"),
            ("prefilter_spacing_px = 5", "quality.prefilter_spacing_px"),
            ("prefilter_spacing_px = inf", "quality.prefilter_spacing_px"),
            ("prefilter_spacing_px = nan", "quality.prefilter_spacing_px"),
            ("prefilter_grid_error_dn = -1", "quality.prefilter_grid_error_dn"),
            ("prefilter_grid_error_dn = nan", "quality.prefilter_grid_error_dn"),
            ("prefilter_grid_error_dn = inf", "quality.prefilter_grid_error_dn"),
            (
                "fusion_solver = { method = \"jacobi\", tolerance = 0, max_iterations = 10 }",
                "quality.fusion_solver.tolerance",
            ),
        ] {
            let spec: QualitySpec = toml::from_str(text).unwrap();
            assert_eq!(spec.resolve().unwrap_err().path, field, "{text}");
        }
        assert!(toml::from_str::<QualitySpec>("preset = \"best\"").is_err());
        assert!(toml::from_str::<QualitySpec>("psf_cutoff = 0.1").is_err());
        for text in ["target_psf_core_px = -1", "target_psf_core_px = 2.5", "target_psf_core_px = \"4\""] {
            assert!(toml::from_str::<QualitySpec>(text).is_err(), "{text}");
        }
        // a grid of three numbers is not read as its first two
        assert!(toml::from_str::<QualitySpec>("reflection_grid = [24, 48, 3]").is_err());
    }
}
