//! The sensor frame: row-major f32 gray values, and its conversions to 8/16-bit images and PNG.

use std::io::Write;
use std::sync::Arc;

use image::{ImageBuffer, Luma};

/// A row-major f32 image of gray values.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    width: usize,
    height: usize,
    pixels: Vec<f32>,
}

impl Frame {
    /// Fills this frame from `coarse`, sampled every `step` pixels of it ([`Upsampler`]), in one parallel pass
    /// over blocks of rows. Where `copy` is given, each row is copied into it as it is made.
    ///
    /// # Panics
    /// If this frame is not `step` times `coarse` each way, or `copy` is not this frame's size.
    pub fn upsample_bilinear(&mut self, coarse: &Frame, step: usize, copy: Option<&mut Frame>) {
        assert!(step >= 1 && self.width == coarse.width * step && self.height == coarse.height * step);
        self.upsample_with(&Upsampler::new(coarse, step), copy);
    }

    /// Fills this frame with `up`'s rows, in one parallel pass over blocks of rows. Where `copy` is given, each
    /// row is copied into it as it is made.
    ///
    /// # Panics
    /// If this frame is not the size `up` makes, or `copy` is not this frame's size.
    pub fn upsample_with(&mut self, up: &Upsampler<'_>, copy: Option<&mut Frame>) {
        use rayon::prelude::*;
        assert!(self.width == up.width && self.height == up.height, "the frame is not the upsampler's size");
        let w = self.width;
        if w == 0 || self.height == 0 {
            return;
        }
        let rows_per_task = crate::physics::simd::rows_per_task(w, 1);
        let block = w * rows_per_task;
        let copies: Vec<Option<&mut [f32]>> = match copy {
            Some(c) => {
                assert!(c.width == w && c.height == self.height, "the copy is not the frame's size");
                c.pixels.chunks_mut(block).map(Some).collect()
            }
            None => (0..self.pixels.len().div_ceil(block)).map(|_| None).collect(),
        };
        self.pixels.par_chunks_mut(block).zip(copies).enumerate().for_each(|(b, (out, copy))| {
            up.rows(b * rows_per_task, out);
            if let Some(c) = copy {
                c.copy_from_slice(out);
            }
        });
    }

    /// A zero frame of `width × height` pixels.
    pub fn new(width: usize, height: usize) -> Self {
        Self { width, height, pixels: vec![0.0; width * height] }
    }

    /// Exchanges this frame's pixels with `pixels` (row-major, the frame's size): what a pass that wrote a whole
    /// new frame elsewhere hands over in place of copying it back.
    ///
    /// # Panics
    /// If `pixels.len() != width·height`.
    pub fn swap_pixels(&mut self, pixels: &mut Vec<f32>) {
        assert_eq!(pixels.len(), self.pixels.len(), "frame data length");
        std::mem::swap(&mut self.pixels, pixels);
    }

    /// A frame from row-major data.
    ///
    /// # Panics
    /// If `pixels.len() != width·height`.
    pub fn from_pixels(width: usize, height: usize, pixels: Vec<f32>) -> Self {
        assert_eq!(pixels.len(), width * height, "frame data length");
        Self { width, height, pixels }
    }

    /// Width, px.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major values.
    pub fn pixels(&self) -> &[f32] {
        &self.pixels
    }

    /// Row-major values, mutable.
    pub fn pixels_mut(&mut self) -> &mut [f32] {
        &mut self.pixels
    }

    /// Value at `(x, y)`.
    ///
    /// # Panics
    /// If the pixel is outside the frame.
    pub fn get(&self, x: usize, y: usize) -> f32 {
        assert!(x < self.width && y < self.height, "pixel ({x}, {y}) outside {}×{}", self.width, self.height);
        self.pixels[y * self.width + x]
    }

    /// Sets the value at `(x, y)`.
    ///
    /// # Panics
    /// If the pixel is outside the frame.
    pub fn set(&mut self, x: usize, y: usize, value: f32) {
        assert!(x < self.width && y < self.height, "pixel ({x}, {y}) outside {}×{}", self.width, self.height);
        self.pixels[y * self.width + x] = value;
    }

    /// Fills the frame with one value.
    pub fn fill(&mut self, value: f32) {
        self.pixels.fill(value);
    }

    /// 16-bit image: each value rounded and clamped to `[0, max_level]` (NaN → 0).
    pub fn to_gray16(&self, max_level: u16) -> ImageBuffer<Luma<u16>, Vec<u16>> {
        let data = self.pixels.iter().map(|&v| quantize(v, max_level as f32) as u16).collect();
        ImageBuffer::from_raw(self.width as u32, self.height as u32, data).expect("size matches")
    }

    /// 8-bit image: values in `[0, max_level]` scaled to `[0, 255]`, rounded and clamped (NaN → 0).
    pub fn to_gray8(&self, max_level: f32) -> ImageBuffer<Luma<u8>, Vec<u8>> {
        let scale = if max_level > 0.0 { 255.0 / max_level } else { 1.0 };
        let data = self.pixels.iter().map(|&v| quantize(v * scale, 255.0) as u8).collect();
        ImageBuffer::from_raw(self.width as u32, self.height as u32, data).expect("size matches")
    }

    /// Writes the frame as a 16-bit grayscale PNG to `out` ([`PngCompression::Fast`]).
    ///
    /// # Errors
    /// The encoder's error, e.g. on a failed write.
    pub fn write_png16<W: Write>(&self, max_level: u16, out: W) -> image::ImageResult<()> {
        self.write_png16_with(max_level, PngCompression::Fast, out)
    }

    /// Writes the frame as a 16-bit grayscale PNG to `out`, compressed as `compression` says.
    ///
    /// # Errors
    /// The encoder's error, e.g. on a failed write.
    pub fn write_png16_with<W: Write>(
        &self,
        max_level: u16,
        compression: PngCompression,
        out: W,
    ) -> image::ImageResult<()> {
        if compression == PngCompression::Fast {
            let mut bytes = Vec::new();
            crate::imaging::png16::Png16Encoder::new().encode(
                &self.pixels,
                self.width,
                self.height,
                max_level,
                &mut bytes,
            );
            let mut out = out;
            return out.write_all(&bytes).map_err(image::ImageError::IoError);
        }
        let mut samples = Vec::new();
        self.png16_samples(max_level, &mut samples);
        self.write_png16_samples(&samples, compression, out)
    }

    /// The 16-bit samples of [`Frame::write_png16_with`] (quantized to `[0, max_level]`, big-endian, as a PNG
    /// holds them) into `samples`, replacing its contents, in one pass.
    pub fn png16_samples(&self, max_level: u16, samples: &mut Vec<u16>) {
        let max = f32::from(max_level);
        samples.clear();
        samples.resize(self.pixels.len(), 0);
        crate::physics::simd::widest(
            #[inline(always)]
            || {
                for (s, &v) in samples.iter_mut().zip(&self.pixels) {
                    *s = crate::imaging::png16::quantize(v, max).to_be();
                }
            },
        );
    }

    /// Writes the samples made by [`Frame::png16_samples`] as a 16-bit grayscale PNG of this frame's size,
    /// through the `png` crate (for [`PngCompression::Fast`], its own fast deflate, which
    /// [`crate::imaging::png16`] replaces in [`Frame::write_png16_with`]; kept for comparison).
    ///
    /// # Errors
    /// The encoder's error, e.g. on a failed write.
    pub fn write_png16_samples<W: Write>(
        &self,
        samples: &[u16],
        compression: PngCompression,
        out: W,
    ) -> image::ImageResult<()> {
        let (level, filter) = match compression {
            PngCompression::None => (png::Compression::NoCompression, png::Filter::NoFilter),
            PngCompression::Fast => (png::Compression::Fast, png::Filter::Sub),
            PngCompression::Default => (png::Compression::Balanced, png::Filter::Adaptive),
            PngCompression::Best => (png::Compression::High, png::Filter::Adaptive),
        };
        let io = |e: png::EncodingError| image::ImageError::IoError(std::io::Error::other(e));
        let mut encoder = png::Encoder::new(out, self.width as u32, self.height as u32);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        encoder.set_compression(level);
        encoder.set_filter(filter);
        encoder.write_header().map_err(io)?.write_image_data(bytemuck::cast_slice(samples)).map_err(io)
    }

    /// Writes the frame as an 8-bit grayscale PNG to `out`, scaling `[0, max_level]` to `[0, 255]`.
    ///
    /// # Errors
    /// The encoder's error, e.g. on a failed write.
    pub fn write_png8<W: Write>(&self, max_level: f32, out: W) -> image::ImageResult<()> {
        write_gray8_png(self.to_gray8(max_level).as_raw(), self.width, self.height, out)
    }
}

/// Writes 8-bit gray `pixels` (`width × height`, row-major) as a PNG to `out`, as [`Frame::write_png8`] does (the
/// `Sub` filter, fast deflate): masks are written from their bytes this way.
///
/// # Errors
/// The encoder's error, e.g. on a failed write or a size that does not match.
pub fn write_gray8_png<W: Write>(pixels: &[u8], width: usize, height: usize, out: W) -> image::ImageResult<()> {
    use image::ImageEncoder;
    image::codecs::png::PngEncoder::new_with_quality(
        out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Sub,
    )
    .write_image(pixels, width as u32, height as u32, image::ExtendedColorType::L8)
}

/// How hard a 16-bit PNG frame is compressed: the files are the same pixels at every setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum PngCompression {
    /// Stored, no deflate (the largest files, the least CPU).
    None,
    /// The `Sub` filter and a Huffman-only deflate made for 16-bit frames (the default; irsim's own encoder,
    /// `imaging::png16`).
    #[default]
    Fast,
    /// zlib's default level with adaptive filters.
    Default,
    /// The strongest level with adaptive filters (the smallest files, the most CPU).
    Best,
}

/// Bilinear interpolation of a frame `step` times larger each way than `coarse` (coarse pixel `k` covers the
/// frame's pixels `k·step … k·step + step − 1`): between coarse pixel centres, the edge values held beyond the
/// outermost centres; along x first (each coarse row once per block of rows), then between two such rows.
/// [`Frame::upsample_bilinear`] makes a whole frame with it; the readout of a frame made on a coarse grid
/// ([`crate::physics::noise::Readout::apply`]) makes each block of rows just before it reads it.
///
/// [`Upsampler::shifted`] reads a frame from a larger coarse frame at a sub-pixel offset instead: a camera's
/// view shifted within the render of a wider view (`crate::scenario::Quality::view_shift_tolerance_px`).
#[derive(Debug, Clone)]
pub struct Upsampler<'a> {
    coarse: &'a Frame,
    step: usize,
    /// The frame's width.
    width: usize,
    /// The frame's height.
    height: usize,
    /// How a coarse row is interpolated along x.
    columns: Columns,
    /// Of a shifted view: the coarse row coordinate added to every row's (whose rows then all lie between two
    /// coarse rows inside the coarse frame).
    row_offset: Option<f64>,
}

/// The largest step [`Upsampler::shifted`] takes.
pub const MAX_SHIFTED_STEP: usize = 8;

/// How an [`Upsampler`] interpolates a coarse row along x.
#[derive(Debug, Clone)]
enum Columns {
    /// A step of 2 (and a coarse frame at least 2 wide): the fixed ¾–¼ weights, no table.
    Halves,
    /// Each column's `(x0, x1, fx)` (the last table made on this thread, shared: a frame's readout makes an
    /// upsampler at every frame, which allocates nothing then).
    Table(Arc<[(usize, usize, f32)]>),
    /// A shifted view: pixel `k·step + r` from coarse pixels `k + n` and `k + n + 1` with weight `f` on the
    /// second, `(n, f)` the `r`th pair (every pixel between two coarse centres inside the row).
    Phases([(usize, f32); MAX_SHIFTED_STEP]),
}

impl<'a> Upsampler<'a> {
    /// The interpolation of `coarse` to a frame `step` times larger each way.
    ///
    /// # Panics
    /// If `step` is 0.
    pub fn new(coarse: &'a Frame, step: usize) -> Self {
        assert!(step >= 1, "a step of 0");
        let (cw, width) = (coarse.width, coarse.width * step);
        let columns = if step == 2 && cw >= 2 {
            Columns::Halves
        } else {
            Columns::Table(UPSAMPLE_COLUMNS.with_borrow_mut(|last| match last {
                Some((s, w, table)) if (*s, *w) == (step, cw) => Arc::clone(table),
                _ => {
                    let table: Arc<[_]> = (0..width).map(|i| Self::place(step, i, cw)).collect();
                    *last = Some((step, cw, Arc::clone(&table)));
                    table
                }
            }))
        };
        Self { coarse, step, width, height: coarse.height * step, columns, row_offset: None }
    }

    /// A `width × height` frame read from `coarse` as if it were `step` times finer and shifted: pixel centre
    /// `(i + ½, j + ½)` falls at coarse coordinates `((i + ½)/step − ½ + offset[0], (j + ½)/step − ½ +
    /// offset[1])` (coarse pixel `k`'s centre at `k`), and takes the bilinear interpolation there. `None`
    /// unless every pixel falls between two coarse centres inside `coarse` each way (nothing is held at an
    /// edge), the sizes are whole multiples of `step` and `step` is 1 to [`MAX_SHIFTED_STEP`].
    pub fn shifted(coarse: &'a Frame, step: usize, (width, height): (usize, usize), offset: [f64; 2]) -> Option<Self> {
        if !(1..=MAX_SHIFTED_STEP).contains(&step) {
            return None;
        }
        let whole = |n: usize| n > 0 && n.is_multiple_of(step);
        let at = |i: usize, o: f64| Self::centre(step, i) + o;
        // the first pixel at or past the first centre each way; the last row's lower neighbour inside (each row is
        // placed by `at` itself, which grows with the row)
        if !(whole(width)
            && whole(height)
            && offset.iter().all(|o| o.abs() < 1e9)
            && at(0, offset[0]) >= 0.0
            && at(0, offset[1]) >= 0.0
            && at(height - 1, offset[1]).floor() + 2.0 <= coarse.height as f64)
        {
            return None;
        }
        let mut phases = [(0, 0.0); MAX_SHIFTED_STEP];
        for (r, phase) in phases.iter_mut().enumerate().take(step) {
            let c = at(r, offset[0]);
            *phase = (c.floor() as usize, (c - c.floor()) as f32);
        }
        // the last column's right neighbour inside, by the phase the loop reads it with (the largest)
        if phases[step - 1].0 + width / step + 1 > coarse.width {
            return None;
        }
        let columns = Columns::Phases(phases);
        Some(Self { coarse, step, width, height, columns, row_offset: Some(offset[1]) })
    }

    /// Where pixel centre `i + ½` falls on the coarse grid, coarse pixel `k`'s centre at `k`.
    fn centre(step: usize, i: usize) -> f64 {
        (i as f64 + 0.5) / step as f64 - 0.5
    }

    /// Where pixel centre `i` falls between coarse centres (of `n`): the lower one's index, the upper one's, the
    /// weight.
    fn place(step: usize, i: usize, n: usize) -> (usize, usize, f32) {
        let c = Self::centre(step, i);
        if c <= 0.0 {
            (0, 0, 0.0)
        } else if c >= (n - 1) as f64 {
            (n - 1, n - 1, 0.0)
        } else {
            let k = c as usize;
            (k, k + 1, (c - k as f64) as f32)
        }
    }

    /// The frame's rows from `first_row` on into `out` (whole rows: its length a multiple of the width, rows
    /// past the frame's last left as they are).
    pub fn rows(&self, first_row: usize, out: &mut [f32]) {
        let (w, cw, ch) = (self.width, self.coarse.width, self.coarse.height);
        if w == 0 || ch == 0 {
            return;
        }
        let row_x = |y: usize, out: &mut [f32]| {
            along_x(&self.coarse.pixels[y * cw..(y + 1) * cw], out, self.step, &self.columns);
        };
        let place = |row: usize| match self.row_offset {
            Some(o) => {
                // inside the coarse frame (`shifted` checked it): the rows on either side
                let c = Self::centre(self.step, row) + o;
                let k = c.floor();
                (k as usize, k as usize + 1, (c - k) as f32)
            }
            None => Self::place(self.step, row, ch),
        };
        UPSAMPLE_ROWS.with_borrow_mut(|scratch| {
            scratch.resize(2 * w, 0.0);
            let (mut upper, mut lower) = scratch.split_at_mut(w);
            // which coarse rows `upper` and `lower` hold, interpolated along x; going down the block, the lower
            // row becomes the next upper one
            let (mut upper_y, mut lower_y) = (usize::MAX, usize::MAX);
            for (r, line) in out.chunks_exact_mut(w).enumerate().take(self.height.saturating_sub(first_row)) {
                let (y0, y1, fy) = place(first_row + r);
                if upper_y != y0 {
                    if lower_y == y0 {
                        std::mem::swap(&mut upper, &mut lower);
                        std::mem::swap(&mut upper_y, &mut lower_y);
                    } else {
                        row_x(y0, upper);
                        upper_y = y0;
                    }
                }
                if y1 != y0 && lower_y != y1 {
                    row_x(y1, lower);
                    lower_y = y1;
                }
                blend_rows(line, upper, if y1 == y0 { upper } else { lower }, fy);
            }
        });
    }
}

/// An [`Upsampler`]'s column table for a step and a coarse width.
type ColumnTable = (usize, usize, Arc<[(usize, usize, f32)]>);

thread_local! {
    /// Each thread's two coarse rows interpolated along x, for [`Upsampler::rows`] (kept from frame to frame: no
    /// allocation per frame).
    static UPSAMPLE_ROWS: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    /// The last column table [`Upsampler::new`] made on this thread.
    static UPSAMPLE_COLUMNS: std::cell::RefCell<Option<ColumnTable>> = const { std::cell::RefCell::new(None) };
}

/// Coarse row `a` interpolated along x into `out`: at the half-pixel offsets of a step of 2, from each output
/// pixel's `(x0, x1, fx)`, or `step` pixels at a time at a shifted view's phases.
fn along_x(a: &[f32], out: &mut [f32], step: usize, columns: &Columns) {
    crate::physics::simd::widest(
        #[inline(always)]
        || match columns {
            Columns::Halves => {
                // centres at k ∓ ¼: ¾ of the nearest coarse pixel and ¼ of the next one out
                let (w, cw) = (out.len(), a.len());
                out[0] = a[0];
                out[w - 1] = a[cw - 1];
                for ((pair, &a0), &a1) in out[1..w - 1].chunks_exact_mut(2).zip(a).zip(&a[1..]) {
                    pair[0] = 0.75 * a0 + 0.25 * a1;
                    pair[1] = 0.25 * a0 + 0.75 * a1;
                }
            }
            Columns::Table(columns) => {
                for (o, &(x0, x1, fx)) in out.iter_mut().zip(columns.iter()) {
                    *o = a[x0] + (a[x1] - a[x0]) * fx;
                }
            }
            Columns::Phases(phases) if step == 2 => {
                // the even pixels from one pair of neighbours, the odd ones from the same pair or the next
                let [(n0, f0), (n1, f1)] = [phases[0], phases[1]];
                let (even, odd) = (&a[n0..], &a[n1..]);
                let pairs = even.iter().zip(&even[1..]).zip(odd.iter().zip(&odd[1..]));
                for (pair, ((&e0, &e1), (&o0, &o1))) in out.chunks_exact_mut(2).zip(pairs) {
                    pair[0] = e0 + (e1 - e0) * f0;
                    pair[1] = o0 + (o1 - o0) * f1;
                }
            }
            Columns::Phases(phases) => {
                for (k, pixels) in out.chunks_exact_mut(step).enumerate() {
                    for (o, &(n, f)) in pixels.iter_mut().zip(phases) {
                        let (a0, a1) = (a[k + n], a[k + n + 1]);
                        *o = a0 + (a1 - a0) * f;
                    }
                }
            }
        },
    );
}

/// `line = top + (bottom − top)·fy`, pixel by pixel.
fn blend_rows(line: &mut [f32], top: &[f32], bottom: &[f32], fy: f32) {
    crate::physics::simd::widest(
        #[inline(always)]
        || {
            for ((o, &t), &b) in line.iter_mut().zip(top).zip(bottom) {
                *o = t + (b - t) * fy;
            }
        },
    );
}

/// Nearest level in `[0, max]` (`max` whole); NaN → 0. `⌊x + 0.5⌋` of the clamped value is its rounding and
/// needs no libm call.
#[inline]
fn quantize(v: f32, max: f32) -> f32 {
    ((v.clamp(0.0, max) + 0.5) as u32) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upsampling_is_exact_on_a_plane_and_holds_the_edges() {
        // a linear ramp is reproduced wherever a pixel lies between coarse centres
        let (cw, ch) = (5, 4);
        let coarse = Frame::from_pixels(cw, ch, (0..cw * ch).map(|i| (3 * (i % cw) + 7 * (i / cw)) as f32).collect());
        for step in [1, 2, 3] {
            let mut fine = Frame::new(cw * step, ch * step);
            let mut copy = Frame::new(cw * step, ch * step);
            fine.upsample_bilinear(&coarse, step, Some(&mut copy));
            assert_eq!(copy, fine, "step {step}: the copy");
            for y in 0..ch * step {
                for x in 0..cw * step {
                    let c = |i: usize, n: usize| ((i as f64 + 0.5) / step as f64 - 0.5).clamp(0.0, (n - 1) as f64);
                    let want = 3.0 * c(x, cw) + 7.0 * c(y, ch);
                    assert!((f64::from(fine.get(x, y)) - want).abs() < 1e-5, "step {step} ({x}, {y})");
                }
            }
        }
    }

    /// A `cw × ch` frame of hashed values, `bits` bits each (no plane hides a wrong neighbour).
    fn hashed(cw: usize, ch: usize, bits: u32) -> Frame {
        let values = (0..cw * ch).map(|i| ((i as u32).wrapping_mul(2_654_435_761) >> (32 - bits)) as f32);
        Frame::from_pixels(cw, ch, values.collect())
    }

    #[test]
    fn shifted_views_are_bilinear_at_their_offset_and_stay_inside() {
        // wide enough for several blocks of rows
        let (cw, ch) = (150, 90);
        let coarse = hashed(cw, ch, 10);
        let at = |x: usize, y: usize| f64::from(coarse.get(x, y));
        for step in [1, 2, 3, 4] {
            let (w, h) = ((cw - 20) / step * step, (ch - 20) / step * step);
            // (from the first offset that puts the first pixel on the first centre)
            let first = 0.5 - 0.5 / step as f64;
            for [x, y] in [[0.0, 0.0], [3.0, 5.0], [7.3, 2.9], [9.99, 0.01], [0.26, 8.74]] {
                let offset = [first + x, first + y];
                let up = Upsampler::shifted(&coarse, step, (w, h), offset).unwrap();
                let mut fine = Frame::new(w, h);
                let mut copy = Frame::new(w, h);
                fine.upsample_with(&up, Some(&mut copy));
                assert_eq!(copy, fine);
                let c = |i: usize, o: f64| (i as f64 + 0.5) / step as f64 - 0.5 + o;
                for y in 0..h {
                    let (fy, y0) = (c(y, offset[1]), c(y, offset[1]).floor() as usize);
                    for x in 0..w {
                        let (fx, x0) = (c(x, offset[0]), c(x, offset[0]).floor() as usize);
                        let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
                        let top = at(x0, y0) + (at(x0 + 1, y0) - at(x0, y0)) * tx;
                        let bottom = at(x0, y0 + 1) + (at(x0 + 1, y0 + 1) - at(x0, y0 + 1)) * tx;
                        let want = top + (bottom - top) * ty;
                        let got = f64::from(fine.get(x, y));
                        assert!((got - want).abs() < 1e-3 * (1.0 + want.abs()), "step {step} {offset:?} ({x}, {y})");
                    }
                }
            }
            // a pixel before the first centre, or past the last one's left neighbour, is not read shifted
            let last = |n: usize, len: usize| len as f64 - 1.0 - ((n as f64 - 0.5) / step as f64 - 0.5);
            let (ox, oy) = (last(w, cw), last(h, ch));
            // (exact where the step is a power of two: the last pixel then falls on the last centre itself)
            let beyond = if step.is_power_of_two() { 0.0 } else { 1e-9 };
            assert!(Upsampler::shifted(&coarse, step, (w, h), [ox - 1e-9, oy - 1e-9]).is_some(), "step {step}");
            assert!(Upsampler::shifted(&coarse, step, (w, h), [ox + beyond, 1.0]).is_none(), "step {step}");
            assert!(Upsampler::shifted(&coarse, step, (w, h), [1.0, oy + beyond]).is_none(), "step {step}");
            assert!(Upsampler::shifted(&coarse, step, (w, h), [first + 1e-9, first + 1e-9]).is_some(), "step {step}");
            assert!(Upsampler::shifted(&coarse, step, (w, h), [first - 1e-9, 1.0]).is_none(), "step {step}");
            assert!(Upsampler::shifted(&coarse, step, (w, h), [f64::NAN, 1.0]).is_none(), "step {step}");
            assert!(Upsampler::shifted(&coarse, step, (w + 1, h), [1.0, 1.0]).is_none() || step == 1);
        }
        assert!(Upsampler::shifted(&coarse, 9, (9, 9), [1.0, 1.0]).is_none());
    }

    #[test]
    fn upsampling_across_many_row_blocks_is_bilinear() {
        // wide enough that the rows are shared out in several blocks, each starting its own coarse rows
        let (cw, ch) = (300, 70);
        let coarse = hashed(cw, ch, 12);
        for step in [2, 3] {
            let (w, h) = (cw * step, ch * step);
            let mut fine = Frame::new(w, h);
            let mut copy = Frame::new(w, h);
            fine.upsample_bilinear(&coarse, step, Some(&mut copy));
            assert_eq!(copy, fine);
            let mut alone = Frame::new(w, h);
            alone.upsample_bilinear(&coarse, step, None);
            assert_eq!(alone, fine);
            let c = |i: usize, n: usize| ((i as f64 + 0.5) / step as f64 - 0.5).clamp(0.0, (n - 1) as f64);
            let at = |x: usize, y: usize| f64::from(coarse.get(x, y));
            for y in 0..h {
                let (fy, y0) = (c(y, ch), c(y, ch) as usize);
                let y1 = (y0 + 1).min(ch - 1);
                for x in 0..w {
                    let (fx, x0) = (c(x, cw), c(x, cw) as usize);
                    let x1 = (x0 + 1).min(cw - 1);
                    let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
                    let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * tx;
                    let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * tx;
                    let want = top + (bottom - top) * ty;
                    let got = f64::from(fine.get(x, y));
                    assert!((got - want).abs() < 1e-3 * (1.0 + want.abs()), "step {step} ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn png16_round_trip() {
        let mut f = Frame::new(3, 2);
        f.pixels_mut().copy_from_slice(&[0.0, 1.4, 65535.0, 70000.0, -5.0, f32::NAN]);
        let mut bytes = Vec::new();
        f.write_png16(65535, &mut bytes).unwrap();
        let back = image::load_from_memory(&bytes).unwrap().into_luma16();
        assert_eq!(back.into_raw(), vec![0, 1, 65535, 65535, 0, 0]);
    }

    #[test]
    fn every_png_compression_holds_the_same_pixels() {
        // a smooth sky with noise: what frames are
        let (w, h) = (96, 64);
        let pixels: Vec<f32> = (0..w * h)
            .map(|i| 3000.0 + (i / w) as f32 * 7.0 + ((i as u32).wrapping_mul(2_654_435_761) >> 28) as f32)
            .collect();
        let f = Frame::from_pixels(w, h, pixels);
        let mut sizes = Vec::new();
        for c in [PngCompression::None, PngCompression::Fast, PngCompression::Default, PngCompression::Best] {
            let mut bytes = Vec::new();
            f.write_png16_with(16383, c, &mut bytes).unwrap();
            let back = image::load_from_memory(&bytes).unwrap().into_luma16();
            assert_eq!(back.into_raw(), f.to_gray16(16383).into_raw(), "{c:?}");
            sizes.push(bytes.len());
        }
        // stored is the largest; the strongest level no larger than the fast one
        assert!(sizes[0] > sizes[1] && sizes[3] <= sizes[1], "{sizes:?}");
    }

    #[test]
    fn gray8_scales_the_bit_depth() {
        let f = Frame::from_pixels(2, 1, vec![4095.0, 2047.5]);
        assert_eq!(f.to_gray8(4095.0).into_raw(), vec![255, 128]);
    }
}
