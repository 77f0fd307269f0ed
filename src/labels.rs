//! Ground truth of a frame, as recorded: per-target labels, the MOTChallenge lines, the clutter window and the
//! target mask. Plain data and pure functions (no Bevy), shared by every front end.

use serde::{Deserialize, Serialize};

use crate::imaging::frame::Frame;
use crate::imaging::target_blob::PixelRect;

/// Ground truth of one frame.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameLabels {
    /// Frame index, from 0.
    pub frame: u64,
    /// Time, s.
    pub t_s: f64,
    /// One entry per target, in scenario order.
    pub targets: Vec<TargetLabel>,
}

/// The image ellipse of a target's outline, px.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct EllipseLabel {
    /// Semi-major axis, px.
    pub a: f64,
    /// Semi-minor axis, px.
    pub b: f64,
    /// Angle of the major axis from +u toward +v, rad.
    pub angle_rad: f64,
}

/// Ground truth of one target in one frame.
///
/// Signals are in DN above the target's background (on axis, before non-uniformity); `snr`, `scr` and
/// `local_contrast` are 0 for a target not in the frame.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TargetLabel {
    /// 1-based id.
    pub id: u32,
    /// Name.
    pub name: String,
    /// Centre of the image ellipse (u, v), px; pixel (i, j) covers [i, i+1) × [j, j+1).
    pub center_px: [f64; 2],
    /// Box `[x0, y0, x1, y1]` of the drawn target to its 1/e level (the outline grown by the blur), px,
    /// clipped to the frame.
    pub bbox_px: [f64; 4],
    /// Exact image ellipse of the outline.
    pub ellipse_px: EllipseLabel,
    /// Distance from the camera, m.
    pub range_m: f64,
    /// Height of the target's centre above the ground (the world's z), m.
    #[serde(default)]
    pub altitude_m: f64,
    /// Largest signal the target adds over its background, DN (signed: a target colder than the sky is
    /// negative).
    pub peak_dn: f64,
    /// `|peak_dn|` over the temporal noise σ (DN) at the target's background.
    pub snr: f64,
    /// Signal-to-clutter ratio: `|peak_dn|` over the standard deviation of the noise-free background (DN) in a
    /// window around the target (its own region left out), with σ floored at 0.001 DN.
    pub scr: f64,
    /// Radiance contrast `ΔL / L_background` at the target's centre.
    pub local_contrast: f64,
    /// Apparent brightness temperature of a pixel filled by the target (with the path), K.
    pub apparent_temp_k: f64,
    /// Fraction of a pixel the outline covers, min(1, area) (eq 13's fill factor).
    pub fill_factor: f64,
    /// Mach number used for the skin temperature.
    pub mach: f64,
    /// Skin temperature, K.
    pub skin_temp_k: f64,
    /// In front of the camera, drawn, and its box (the 1/e outline) covering part of the frame (geometric only;
    /// called `visible` before 0.2). Only these targets are in the MOT file.
    pub in_frame: bool,
    /// In the frame with `snr` at least the scenario's `labels.detectable_snr`.
    pub detectable: bool,
}

impl FrameLabels {
    /// Appends this frame's MOTChallenge lines (`frame, id, left, top, width, height, conf, class, visibility`)
    /// for the targets in the frame. MOTChallenge counts frames and pixels from 1 (its tools subtract 1 from
    /// `left` and `top` on loading), so `left, top` are `bbox_px`'s 0-based edges plus 1.
    pub fn push_mot_lines(&self, out: &mut String) {
        use std::fmt::Write as _;
        for t in self.targets.iter().filter(|t| t.in_frame) {
            let [x0, y0, x1, y1] = t.bbox_px;
            let (left, top) = (x0 + 1.0, y0 + 1.0);
            writeln!(out, "{},{},{:.3},{:.3},{:.3},{:.3},1,1,1", self.frame + 1, t.id, left, top, x1 - x0, y1 - y0)
                .expect("writing to a String");
        }
    }
}

/// `|peak|` over the temporal noise σ (both DN); a noiseless sensor divides by 0.001 DN.
pub fn snr(peak_dn: f64, sigma_dn: f64) -> f64 {
    if sigma_dn > 0.0 { peak_dn.abs() / sigma_dn } else { peak_dn.abs() / 1e-3 }
}

/// The window of a `width` × `height` frame that [`clutter_sigma`] reads around `roi`: the region grown by 10 px
/// on each side, and by up to 15 px more where it is under 30 px across, clipped to the frame (`None` where
/// nothing is left).
pub fn clutter_window(roi: PixelRect, width: usize, height: usize) -> Option<PixelRect> {
    let grow_x = 10 + 15usize.saturating_sub(roi.width() / 2);
    let grow_y = 10 + 15usize.saturating_sub(roi.height() / 2);
    let (x0, y0) = (roi.x0.saturating_sub(grow_x), roi.y0.saturating_sub(grow_y));
    let (x1, y1) = ((roi.x1 + grow_x).min(width), (roi.y1 + grow_y).min(height));
    (x0 < x1 && y0 < y1).then_some(PixelRect { x0, y0, x1, y1 })
}

/// Standard deviation of `background` (its units) in the window [`clutter_window`] gives around `roi`, the region
/// itself left out.
///
/// Two passes (the mean, then the squared deviations from it) over the window's rows as runs of pixels, each
/// summed in eight f64 lanes: a scene's targets each take one at every frame, and the pixel-by-pixel version
/// with one sum was most of swarm's output stage.
pub fn clutter_sigma(background: &Frame, roi: PixelRect) -> f64 {
    let w = background.width();
    let Some(PixelRect { x0, y0, x1, y1 }) = clutter_window(roi, w, background.height()) else { return 0.0 };
    // each row of the window as its runs outside the region (the region's columns, clipped to the window, cut
    // a row that crosses it in two)
    let (cut0, cut1) = (roi.x0.clamp(x0, x1), roi.x1.clamp(x0, x1).max(roi.x0.clamp(x0, x1)));
    let pixels = background.pixels();
    let runs = || {
        (y0..y1).flat_map(move |y| {
            let row = &pixels[y * w..(y + 1) * w];
            if (roi.y0..roi.y1).contains(&y) { [&row[x0..cut0], &row[cut1..x1]] } else { [&row[x0..x1], &row[x1..x1]] }
        })
    };
    let sum = |f: &dyn Fn(f32) -> f64| -> f64 {
        let mut lanes = [0.0f64; 8];
        for run in runs() {
            let mut chunks = run.chunks_exact(8);
            for c in &mut chunks {
                for (l, &v) in lanes.iter_mut().zip(c) {
                    *l += f(v);
                }
            }
            for (l, &v) in lanes.iter_mut().zip(chunks.remainder()) {
                *l += f(v);
            }
        }
        lanes.iter().sum()
    };
    let n = runs().map(<[f32]>::len).sum::<usize>();
    if n < 2 {
        return 0.0;
    }
    let mean = sum(&|v| f64::from(v)) / n as f64;
    let var = sum(&|v| (f64::from(v) - mean).powi(2)) / (n as f64 - 1.0);
    var.sqrt()
}

/// One target's drawn patch, for the mask.
#[derive(Debug, Clone, Copy)]
pub struct MaskPatch<'a> {
    /// Label id (clamped to 255 in the mask).
    pub id: u32,
    /// Distance from the camera, m: nearer targets are painted last and win.
    pub range_m: f64,
    /// The patch's pixels.
    pub rect: PixelRect,
    /// Its values, row-major over `rect`.
    pub values: &'a [f32],
    /// The value at its brightest pixel (signed).
    pub peak: f64,
}

/// Paints the target mask (`width`-wide, row-major, 0 = sky): a pixel belongs to a target where its patch
/// reaches `fraction` of the patch's peak (in magnitude; the scenario's `labels.mask_fraction`, 0.1 by default);
/// where targets overlap the nearest wins.
pub fn paint_mask(mask: &mut Vec<u8>, width: usize, height: usize, fraction: f64, patches: &mut [MaskPatch<'_>]) {
    mask.clear();
    mask.resize(width * height, 0);
    patches.sort_by(|a, b| b.range_m.total_cmp(&a.range_m));
    for p in patches.iter() {
        let peak = p.peak.abs() as f32;
        if !(peak > 0.0) {
            continue;
        }
        let threshold = fraction as f32 * peak;
        let rw = p.rect.width();
        for y in p.rect.y0..p.rect.y1 {
            for x in p.rect.x0..p.rect.x1 {
                if p.values[(y - p.rect.y0) * rw + x - p.rect.x0].abs() >= threshold {
                    mask[y * width + x] = p.id.min(255) as u8;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clutter_is_the_window_s_deviation_without_the_region() {
        // a frame of distinct values; regions inside, at the edges and corners, and one past the frame
        let (w, h) = (97, 61);
        let frame = Frame::from_pixels(w, h, (0..w * h).map(|i| (i as f32 * 0.37).sin() * 5.0 + 100.0).collect());
        for roi in [
            PixelRect { x0: 40, y0: 20, x1: 52, y1: 31 },
            PixelRect { x0: 0, y0: 0, x1: 3, y1: 4 },
            PixelRect { x0: 90, y0: 55, x1: 97, y1: 61 },
            PixelRect { x0: 10, y0: 30, x1: 11, y1: 31 },
            PixelRect { x0: 0, y0: 0, x1: 97, y1: 61 },
        ] {
            // pixel by pixel, one sum each pass
            let (gx, gy) =
                (10 + 15usize.saturating_sub(roi.width() / 2), 10 + 15usize.saturating_sub(roi.height() / 2));
            let mut v = Vec::new();
            for y in roi.y0.saturating_sub(gy)..(roi.y1 + gy).min(h) {
                for x in roi.x0.saturating_sub(gx)..(roi.x1 + gx).min(w) {
                    if !((roi.x0..roi.x1).contains(&x) && (roi.y0..roi.y1).contains(&y)) {
                        v.push(f64::from(frame.get(x, y)));
                    }
                }
            }
            let want = if v.len() < 2 {
                0.0
            } else {
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)).sqrt()
            };
            let got = clutter_sigma(&frame, roi);
            assert!((got - want).abs() <= 1e-12 * want.max(1.0), "{roi:?}: {got} against {want}");
        }
    }

    #[test]
    fn mot_lines_list_the_targets_in_the_frame() {
        let target = |id: u32, in_frame: bool| TargetLabel {
            id,
            bbox_px: [1.0, 2.0, 4.5, 8.0],
            in_frame,
            ..TargetLabel::default()
        };
        let labels = FrameLabels { frame: 6, t_s: 0.2, targets: vec![target(1, true), target(2, false)] };
        let mut text = String::new();
        labels.push_mot_lines(&mut text);
        // frames and pixels counted from 1: the 0-based box [1, 2, 4.5, 8] starts at MOT's (2, 3)
        assert_eq!(text, "7,1,2.000,3.000,3.500,6.000,1,1,1\n");
    }

    #[test]
    fn nearer_targets_win_the_mask() {
        let rect = PixelRect { x0: 1, y0: 1, x1: 3, y1: 2 };
        let far = [1.0f32, 0.05];
        let near = [0.0f32, 2.0];
        let mut patches = [
            MaskPatch { id: 2, range_m: 10.0, rect, values: &near, peak: 2.0 },
            MaskPatch { id: 1, range_m: 90.0, rect, values: &far, peak: 1.0 },
        ];
        let mut mask = Vec::new();
        paint_mask(&mut mask, 4, 3, 0.1, &mut patches);
        assert_eq!(mask, vec![0, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn the_mask_fraction_sets_how_much_of_a_target_is_masked() {
        let rect = PixelRect { x0: 0, y0: 0, x1: 4, y1: 1 };
        // a dark target (negative contribution) counts by magnitude
        let values = [-0.04f32, -0.2, -1.0, -0.5];
        let masked = |fraction: f64| {
            let mut patches = [MaskPatch { id: 3, range_m: 1.0, rect, values: &values, peak: -1.0 }];
            let mut mask = Vec::new();
            paint_mask(&mut mask, 4, 1, fraction, &mut patches);
            mask
        };
        assert_eq!(masked(0.1), vec![0, 3, 3, 3]);
        assert_eq!(masked(0.5), vec![0, 0, 3, 3]);
        assert_eq!(masked(1.0), vec![0, 0, 3, 0]);
        assert_eq!(masked(0.01), vec![3, 3, 3, 3]);
    }
}
