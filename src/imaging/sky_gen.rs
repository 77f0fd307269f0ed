//! Procedural infrared skies, so the project depends on no image it did not make.
//!
//! Rows of the image span elevations from `elevation_top_deg` (row 0) to `elevation_bottom_deg`. A clear sky's
//! long-wave radiance rises toward the horizon as the path through warm, humid air lengthens: with zenith
//! emissivity `ε_z`, the emissivity at elevation `e` is `1 − (1 − ε_z)^{1/sin e}` (a plane-parallel slab), and
//! the gray level runs from `zenith_gray` to `horizon_gray` with it. Broken cumulus is fractal value noise
//! (fBm) thresholded to the requested cover with soft edges; cloud bases are warmer than clear sky, so clouds
//! are brighter, with their own internal texture. Every value is a deterministic function of the seed and the
//! pixel (a hash of the lattice point), so images are reproducible.

use serde::{Deserialize, Serialize};

/// What kind of sky to make.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkyKind {
    /// Clear sky: the elevation gradient plus faint texture.
    Clear,
    /// Broken cumulus over the clear-sky gradient.
    Cumulus,
}

/// Parameters of a generated sky.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkyGenSpec {
    /// Kind of sky.
    pub kind: SkyKind,
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Seed.
    pub seed: u64,
    /// Elevation at the top row, degrees.
    pub elevation_top_deg: f64,
    /// Elevation at the bottom row, degrees.
    pub elevation_bottom_deg: f64,
    /// Clear-sky gray at the zenith (16-bit levels).
    pub zenith_gray: f64,
    /// Clear-sky gray at the horizon.
    pub horizon_gray: f64,
    /// Zenith emissivity of the clear sky, (0, 1).
    pub zenith_emissivity: f64,
    /// Fraction of the sky covered by cloud, [0, 1] (cumulus only).
    pub cloud_cover: f64,
    /// Gray of cloud bases.
    pub cloud_gray: f64,
    /// Size of the largest cloud features, px.
    pub cloud_scale_px: f64,
}

impl SkyGenSpec {
    /// Defaults for `kind`: 1024 × 1024, elevations 12° to −2°, a 16-bit LWIR look.
    pub fn new(kind: SkyKind) -> Self {
        Self {
            kind,
            width: 1024,
            height: 1024,
            seed: 1,
            elevation_top_deg: 12.0,
            elevation_bottom_deg: -2.0,
            zenith_gray: 9000.0,
            horizon_gray: 30000.0,
            zenith_emissivity: 0.3,
            cloud_cover: 0.45,
            cloud_gray: 26000.0,
            cloud_scale_px: 256.0,
        }
    }
}

/// Makes the sky as row-major 16-bit levels.
pub fn generate(spec: &SkyGenSpec) -> Vec<u16> {
    let (w, h) = (spec.width, spec.height);
    let mut out = vec![0u16; w * h];
    let eps_z = spec.zenith_emissivity.clamp(1e-3, 0.999);
    // threshold of the fBm (roughly uniform on [0, 1]) that leaves `cloud_cover` above it
    let threshold = 1.0 - spec.cloud_cover.clamp(0.0, 1.0);
    for y in 0..h {
        let el =
            spec.elevation_top_deg + (spec.elevation_bottom_deg - spec.elevation_top_deg) * (y as f64 + 0.5) / h as f64;
        let s = el.to_radians().sin();
        let eps = if s <= 1e-3 { 1.0 } else { 1.0 - (1.0 - eps_z).powf(1.0 / s) };
        let clear = spec.zenith_gray + (spec.horizon_gray - spec.zenith_gray) * (eps - eps_z) / (1.0 - eps_z);
        for x in 0..w {
            let (fx, fy) = (x as f64, y as f64);
            // faint texture of the clear sky: 0.5% of its level
            let texture = fbm(fx / 64.0, fy / 64.0, 4, spec.seed ^ 0x5EED) - 0.5;
            let mut g = clear * (1.0 + 0.01 * texture);
            if spec.kind == SkyKind::Cumulus {
                // clouds flatten toward the horizon: stretch the noise horizontally
                let n = fbm(fx / spec.cloud_scale_px, fy / (0.6 * spec.cloud_scale_px), 6, spec.seed);
                let c = smoothstep(threshold, threshold + 0.12, n);
                let inner = fbm(fx / 24.0, fy / 24.0, 3, spec.seed ^ 0xC10D) - 0.5;
                let cloud = spec.cloud_gray * (1.0 + 0.06 * inner) + 0.25 * (clear - spec.zenith_gray);
                g = g + c * (cloud - g);
            }
            out[y * w + x] = g.round().clamp(0.0, 65535.0) as u16;
        }
    }
    out
}

fn smoothstep(a: f64, b: f64, x: f64) -> f64 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Fractal value noise in [0, 1): `octaves` layers of doubling frequency and halving amplitude.
fn fbm(x: f64, y: f64, octaves: u32, seed: u64) -> f64 {
    let (mut sum, mut amp, mut norm, mut f) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * value_noise(x * f, y * f, seed.wrapping_add(u64::from(o) * 0x9E37_79B9));
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

/// Smoothly interpolated lattice noise in [0, 1).
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = (x - x0, y - y0);
    let (ix, iy) = (x0 as i64, y0 as i64);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let v = |dx: i64, dy: i64| lattice(ix + dx, iy + dy, seed);
    let top = v(0, 0) + (v(1, 0) - v(0, 0)) * sx;
    let bottom = v(0, 1) + (v(1, 1) - v(0, 1)) * sx;
    top + (bottom - top) * sy
}

/// A value in [0, 1) for a lattice point (SplitMix64 of the point and seed).
fn lattice(ix: i64, iy: i64, seed: u64) -> f64 {
    let mut z =
        seed ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clear_sky_brightens_toward_the_horizon() {
        let spec = SkyGenSpec { width: 32, height: 64, ..SkyGenSpec::new(SkyKind::Clear) };
        let img = generate(&spec);
        let row_mean = |y: usize| img[y * 32..(y + 1) * 32].iter().map(|&v| v as f64).sum::<f64>() / 32.0;
        assert!(row_mean(60) > row_mean(30) && row_mean(30) > row_mean(2));
        assert_eq!(img, generate(&spec));
    }

    #[test]
    fn cumulus_cover_is_roughly_as_asked() {
        let spec = SkyGenSpec { width: 256, height: 256, cloud_scale_px: 64.0, ..SkyGenSpec::new(SkyKind::Cumulus) };
        let clouds = generate(&spec);
        let clear = generate(&SkyGenSpec { kind: SkyKind::Clear, ..spec });
        let covered = clouds.iter().zip(&clear).filter(|(c, s)| **c as f64 > **s as f64 + 2000.0).count();
        let frac = covered as f64 / clouds.len() as f64;
        assert!(frac > 0.1 && frac < 0.8, "cover {frac}");
    }
}
