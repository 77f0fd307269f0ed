//! A fast encoder for 16-bit grayscale PNG frames: one Huffman-only deflate block, its rows quantized,
//! filtered, summed and coded a band of about [`PAUSE_BYTES`] at a time (each band coded while it is still in
//! the cache, the filtered rows kept in a band's buffer, not the frame's). Where the whole frame was
//! filtered first and then read twice more (Adler-32, coder), a noisy 640 × 512 frame encoded alone on one thread
//! took as long, but beside the simulation on two cores the band saved memory traffic the simulation shares:
//! sense_and_avoid (640 × 512) recorded at 312–392 frames/s, median 341, against 288–366, median 326 (12
//! alternating pairs on an AMD EPYC with AVX2, 9 faster, 1 tie), its render stage 2178 µs a frame against 2243
//! (medians); a 256 × 256 frame's rows fit the cache either way, and `irsim bench`'s recording case did not move.
//!
//! A sensor frame is a smooth sky under noise. After PNG's `Sub` filter (each byte minus the byte two to its
//! left, so high bytes from high bytes and low bytes from low bytes) the high bytes are nearly all 0 or 255 and
//! the low bytes spread over the noise's width; repeated strings are rare, so a match search (what deflate
//! spends most of its time on) finds little. This encoder skips it: the filtered bytes are coded with one
//! dynamic Huffman table made for the frame from a count of its bytes on a sample of its rows, written 8 codes
//! to a 64-bit store where they fit. With AVX-512 the codes are looked up and joined in vector registers: with
//! VBMI by byte permutes (51–53 against 63–64 µs a noisy 256² frame, AMD EPYC), without it by AVX-512 BW's word
//! permutes (a whole noisy 256² frame encoded in 164–201 µs against 223–283 µs by the scalar coder, 1.2–1.5×,
//! on a 2-vCPU Intel Xeon without VBMI, the two interleaved in one process; docs/accuracy.md). Any inflater reads the result: it is
//! an ordinary zlib stream (RFC 1950/1951) inside an ordinary PNG (one IHDR, one IDAT, IEND).
//!
//! Where the table would code the frame in more bytes than storing it (no frame a sensor makes, but any input
//! can), the frame is written as stored blocks instead. The pixels are those of [`Frame::png16_samples`]:
//! clamped to `[0, max_level]`, rounded half up, NaN as 0.
//!
//! [`Frame::png16_samples`]: crate::imaging::frame::Frame::png16_samples

/// The longest code: 4 codes of at most 14 bits and the ≤ 7 bits waiting fit in one 64-bit word.
const MAX_CODE_BITS: u32 = 14;
/// Literals 0–255 and the end of block.
const SYMBOLS: usize = 257;
const END_OF_BLOCK: usize = 256;
/// About this many filtered bytes are counted to make a frame's table (every k-th row, k fixed by the size).
const SAMPLE_BYTES: usize = 8 * 1024;
/// PNG's `Sub` filter type, the first byte of every row.
const FILTER_SUB: u8 = 1;
/// [`Png16Encoder::encode_pausing`] pauses after about this many bytes of filtered data made and coded (coding
/// them took about 11 µs on an AMD EPYC with AVX2 and no AVX-512); the first pause comes after the rows counted
/// for the Huffman table too.
pub const PAUSE_BYTES: usize = 16 * 1024;
/// A stored deflate block holds at most this many bytes.
const STORED_BLOCK_MAX: usize = 65_535;

/// The encoder's buffers, kept from frame to frame: once the largest frame has been coded (and, where any frame
/// is stored, the largest stored one), encoding allocates nothing beyond what `out` needs.
#[derive(Debug, Default, Clone)]
pub struct Png16Encoder {
    /// One row's quantized samples, big-endian (read as bytes, in the order PNG stores them).
    row: Vec<u16>,
    /// Rows of the zlib stream's uncompressed data (each row's filter byte and filtered samples): the rows
    /// counted for the Huffman table, then a band of the frame's at a time as it is coded; the whole frame's
    /// where it is stored.
    filtered: Vec<u8>,
    /// The deflate bit stream, written 8 bytes at a time (its length is only ever grown, never cleared).
    bits: Vec<u8>,
}

impl Png16Encoder {
    /// An encoder with empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Writes `pixels`, a row-major `width` × `height` frame, into `out` (replacing its contents) as a 16-bit
    /// grayscale PNG of the levels `[0, max_level]`.
    ///
    /// # Panics
    /// If `pixels` does not hold `width · height` values, either side is 0 or over 2³¹ − 1, or the compressed
    /// frame over 2³¹ − 1 bytes (PNG's limits).
    pub fn encode(&mut self, pixels: &[f32], width: usize, height: usize, max_level: u16, out: &mut Vec<u8>) {
        self.encode_pausing(pixels, width, height, max_level, out, &mut || {});
    }

    /// [`Png16Encoder::encode`], calling `pause` after every [`PAUSE_BYTES`] or so of the frame's work, so
    /// that a thread encoding between other work can look for it (a worker of a pool runs waiting tasks there).
    ///
    /// # Panics
    /// As [`Png16Encoder::encode`].
    pub fn encode_pausing(
        &mut self,
        pixels: &[f32],
        width: usize,
        height: usize,
        max_level: u16,
        out: &mut Vec<u8>,
        pause: &mut dyn FnMut(),
    ) {
        assert!(width > 0 && height > 0 && width <= i32::MAX as usize && height <= i32::MAX as usize);
        assert_eq!(pixels.len(), width * height, "pixels for a {width}x{height} frame");
        out.clear();
        out.extend_from_slice(b"\x89PNG\r\n\x1a\n");
        let mut ihdr = [0u8; 13];
        ihdr[0..4].copy_from_slice(&(width as u32).to_be_bytes());
        ihdr[4..8].copy_from_slice(&(height as u32).to_be_bytes());
        // bit depth 16, grayscale, deflate, adaptive filtering, no interlace
        ihdr[8..13].copy_from_slice(&[16, 0, 0, 0, 0]);
        chunk(out, b"IHDR", &ihdr);
        // IDAT: its length is filled in once the stream is written
        let idat = out.len();
        out.extend_from_slice(&[0, 0, 0, 0]);
        out.extend_from_slice(b"IDAT");
        // zlib header: deflate with a 32 KiB window, the fastest level, no dictionary ((0x78·256 + 0x01) % 31 == 0)
        out.extend_from_slice(&[0x78, 0x01]);
        let (coded, adler) = self.deflate_huffman(pixels, width, max_level, pause);
        if coded <= stored_size((1 + 2 * width) * height) {
            out.extend_from_slice(&self.bits[..coded]);
        } else {
            // the whole frame filtered again, to be stored
            self.filter(pixels, width, max_level, pause);
            write_stored(&self.filtered, out);
        }
        out.extend_from_slice(&adler.to_be_bytes());
        let length = out.len() - idat - 8;
        // PNG's limit on a chunk's length
        let length = u32::try_from(length).ok().filter(|&n| n <= i32::MAX as u32).expect("an IDAT chunk under 2 GiB");
        out[idat..idat + 4].copy_from_slice(&length.to_be_bytes());
        let crc = crc32fast::hash(&out[idat + 4..]);
        out.extend_from_slice(&crc.to_be_bytes());
        chunk(out, b"IEND", &[]);
    }

    /// Quantizes and `Sub`-filters the frame into `self.filtered`.
    fn filter(&mut self, pixels: &[f32], width: usize, max_level: u16, pause: &mut dyn FnMut()) {
        let stride = 1 + 2 * width;
        let height = pixels.len() / width;
        self.filtered.resize(stride * height, 0);
        self.row.resize(width, 0);
        let max = f32::from(max_level);
        let band = (PAUSE_BYTES / stride).max(1);
        for (src, dst) in pixels.chunks(band * width).zip(self.filtered.chunks_mut(band * stride)) {
            filter_rows(src, dst, &mut self.row, max);
            pause();
        }
    }

    /// Codes the frame's filtered rows as one final dynamic-Huffman deflate block into `self.bits`; returns its
    /// length in bytes and the rows' Adler-32. The rows are filtered, summed and coded a band of about
    /// [`PAUSE_BYTES`] at a time, so that each band is read again from the cache, not from memory; the table
    /// is made first, from a count of every k-th row filtered on its own.
    fn deflate_huffman(
        &mut self,
        pixels: &[f32],
        width: usize,
        max_level: u16,
        pause: &mut dyn FnMut(),
    ) -> (usize, u32) {
        let (stride, height, max) = (1 + 2 * width, pixels.len() / width, f32::from(max_level));
        let band = (PAUSE_BYTES / stride).max(1);
        let every = sample_every(stride * height, height);
        let sampled = height.div_ceil(every);
        self.row.resize(width, 0);
        self.filtered.resize(stride * sampled.max(band), 0);
        let rows = pixels.chunks_exact(width).step_by(every);
        for (src, dst) in rows.zip(self.filtered.chunks_exact_mut(stride)) {
            filter_rows(src, dst, &mut self.row, max);
        }
        let lengths = code_lengths(&count_rows(self.filtered[..stride * sampled].chunks_exact(stride)));
        let codes = canonical_codes(&lengths);
        // each symbol's code, bit-reversed as deflate sends Huffman codes, and its length
        let mut code = [0u64; SYMBOLS];
        let mut len = [0u32; SYMBOLS];
        for (i, (&c, &l)) in codes.iter().zip(&lengths).enumerate() {
            (code[i], len[i]) = (u64::from(c), u32::from(l));
        }
        // the header, the data at ≤ 14 bits a byte, the end of block, and the 8-byte stores' overrun
        let bound = 256 + stride * height * MAX_CODE_BITS as usize / 8 + 16;
        if self.bits.len() < bound {
            self.bits.resize(bound, 0);
        }
        let mut w = BitWriter { out: &mut self.bits[..bound], pos: 0, buf: 0, nbits: 0 };
        write_header(&mut w, &lengths);
        #[cfg(target_arch = "x86_64")]
        let tables = x86::Tables::new(&code, &len, vbmi(), words());
        let mut adler = simd_adler32::Adler32::new();
        for src in pixels.chunks(band * width) {
            let piece = &mut self.filtered[..src.len() / width * stride];
            filter_rows(src, piece, &mut self.row, max);
            adler.write(piece);
            // coded at once, while the band is in the cache (in pieces of PAUSE_BYTES where a row is longer)
            for piece in piece.chunks(PAUSE_BYTES) {
                #[cfg(target_arch = "x86_64")]
                if let Some(tables) = &tables {
                    // SAFETY: the CPU has what the tables were made for, checked by `vbmi` and `words`
                    unsafe { tables.code(piece, &code, &len, &mut w) };
                } else if bmi2() {
                    // SAFETY: the CPU has BMI2, checked by `bmi2`
                    unsafe { code_bytes_bmi2(piece, &code, &len, &mut w) };
                } else {
                    code_bytes(piece, &code, &len, &mut w);
                }
                #[cfg(not(target_arch = "x86_64"))]
                code_bytes(piece, &code, &len, &mut w);
                pause();
            }
        }
        w.put(code[END_OF_BLOCK], len[END_OF_BLOCK]);
        (w.finish(), adler.finish())
    }
}

/// Quantizes and `Sub`-filters whole rows of `pixels` into `filtered` (each row its filter byte and samples),
/// with `row` (one row long) as scratch.
fn filter_rows(pixels: &[f32], filtered: &mut [u8], row: &mut [u16], max: f32) {
    let width = row.len();
    crate::physics::simd::widest(
        #[inline(always)]
        || {
            for (src, dst) in pixels.chunks_exact(width).zip(filtered.chunks_exact_mut(1 + 2 * width)) {
                for (q, &v) in row.iter_mut().zip(src) {
                    *q = quantize(v, max).to_be();
                }
                // the samples' bytes in PNG's order; each byte less the byte two to its left (the same byte of
                // the pixel to the left; 0 left of the first pixel)
                let bytes: &[u8] = bytemuck::cast_slice(row);
                dst[0] = FILTER_SUB;
                let dst = &mut dst[1..];
                dst[..2].copy_from_slice(&bytes[..2]);
                for ((d, &v), &left) in dst[2..].iter_mut().zip(&bytes[2..]).zip(bytes) {
                    *d = v.wrapping_sub(left);
                }
            }
        },
    );
}

/// Whether [`code_bytes_bmi2`] may run: the CPU has BMI2 and `IRSIM_SIMD` does not ask for the baseline.
#[cfg(target_arch = "x86_64")]
fn bmi2() -> bool {
    static BMI2: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *BMI2.get_or_init(|| {
        std::arch::is_x86_feature_detected!("bmi2")
            && crate::physics::simd::Level::detect() != crate::physics::simd::Level::Baseline
    })
}

/// Whether [`x86::code_bytes_words`] may run: the CPU has AVX-512 (F, BW) and BMI2, and `IRSIM_SIMD` does not
/// cap the vectors below AVX-512.
#[cfg(target_arch = "x86_64")]
fn words() -> bool {
    crate::physics::simd::Level::detect() == crate::physics::simd::Level::Avx512 && bmi2()
}

/// Whether [`x86::code_bytes_vbmi`] may run: the CPU has AVX-512 (F, BW, VBMI) and BMI2, and `IRSIM_SIMD` does
/// not cap the vectors below AVX-512.
#[cfg(target_arch = "x86_64")]
fn vbmi() -> bool {
    static VBMI: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *VBMI.get_or_init(|| {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vbmi")
            && std::arch::is_x86_feature_detected!("bmi2")
            && crate::physics::simd::Level::detect() == crate::physics::simd::Level::Avx512
    })
}

/// Each byte of `data` as its code: eight codes to a store where they fit in one (a sensor frame's filtered
/// bytes take about 5 bits each), else four. The codes of eight bytes are gathered off the [`Chain`] of stores,
/// so that it runs once per eight bytes.
#[inline(always)]
fn code_bytes(data: &[u8], code: &[u64; SYMBOLS], len: &[u32; SYMBOLS], w: &mut BitWriter<'_>) {
    let mut chain = Chain::start(w, data.len() * MAX_CODE_BITS as usize);
    let mut octets = data.chunks_exact(8);
    for o in &mut octets {
        let ((low, nl), (high, nh)) = (quad(&o[..4], code, len), quad(&o[4..], code, len));
        // `nl` ≤ 56, so the shift is defined; the sum is used only where it fits a store (≤ 7 bits wait)
        // SAFETY (all three loops): the piece's bytes, each coded once, at most MAX_CODE_BITS each
        if nl + nh <= 56 {
            unsafe { chain.put(low | (high << nl), nl + nh) };
        } else {
            unsafe {
                chain.put(low, nl);
                chain.put(high, nh);
            }
        }
    }
    let mut quads = octets.remainder().chunks_exact(4);
    for q in &mut quads {
        let (bits, n) = quad(q, code, len);
        unsafe { chain.put(bits, n) };
    }
    for &byte in quads.remainder() {
        unsafe { chain.put(code[byte as usize], len[byte as usize]) };
    }
    chain.finish(w);
}

/// The codes of four bytes, the first lowest, and their length in bits (at most 56).
#[inline(always)]
fn quad(q: &[u8], code: &[u64; SYMBOLS], len: &[u32; SYMBOLS]) -> (u64, u32) {
    let (a, b, c, d) = (q[0] as usize, q[1] as usize, q[2] as usize, q[3] as usize);
    let (la, lb, lc) = (len[a], len[b], len[c]);
    let bits = code[a] | (code[b] << la) | (code[c] << (la + lb)) | (code[d] << (la + lb + lc));
    (bits, la + lb + lc + len[d])
}

/// A [`BitWriter`]'s state held in registers while a piece is coded: the store is a chain of dependent steps
/// (the bits waiting, their count, the position), and through the writer it went to memory and back at every
/// store. Each store writes 8 bytes at the position through a pointer, in bounds for the piece checked once.
struct Chain {
    out: *mut u8,
    pos: usize,
    buf: u64,
    nbits: u32,
}

impl Chain {
    /// The chain of `w` for at most `bits` bits: each store writes 8 bytes at the position, which stays at or
    /// before where those bits end. `w` must not be used until [`Chain::finish`] hands the state back.
    ///
    /// # Panics
    /// If `w`'s buffer has no room for them.
    #[inline(always)]
    fn start(w: &mut BitWriter<'_>, bits: usize) -> Self {
        let end = w.pos + (bits + w.nbits as usize).div_ceil(8);
        assert!(end + 8 <= w.out.len(), "room for the piece's codes");
        Self { out: w.out.as_mut_ptr(), pos: w.pos, buf: w.buf, nbits: w.nbits }
    }

    /// Appends the low `n` bits of `bits` (`n` ≤ 56; no bits above them set).
    ///
    /// # Safety
    /// The bits put since [`Chain::start`] must be at most as many as it was given (so that the position stays
    /// at or before the end it checked), and its writer's buffer must not have moved.
    #[inline(always)]
    unsafe fn put(&mut self, bits: u64, n: u32) {
        self.buf |= bits << self.nbits;
        self.nbits += n;
        // at most 7 bits wait between calls, so `nbits` ≤ 63 and `whole` ≤ 56
        debug_assert!(self.nbits < 64);
        // SAFETY: `pos` ≤ the end `start` checked (each code's bits are counted in it), whose `+ 8` is in bounds
        unsafe { self.out.add(self.pos).cast::<[u8; 8]>().write_unaligned(self.buf.to_le_bytes()) };
        let whole = self.nbits & !7;
        self.pos += (whole >> 3) as usize;
        self.buf >>= whole;
        self.nbits -= whole;
    }

    /// Hands the state back to the writer it started from.
    #[inline(always)]
    fn finish(self, w: &mut BitWriter<'_>) {
        (w.pos, w.buf, w.nbits) = (self.pos, self.buf, self.nbits);
    }
}

/// [`code_bytes`] compiled with BMI2's shifts by any register (the same bits; a quarter fewer instructions).
///
/// # Safety
/// The CPU must have BMI2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "bmi2")]
unsafe fn code_bytes_bmi2(data: &[u8], code: &[u64; SYMBOLS], len: &[u32; SYMBOLS], w: &mut BitWriter<'_>) {
    code_bytes(data, code, len, w);
}

/// The coders with AVX-512: each 64 bytes' codes looked up and joined in vector registers.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{BitWriter, Chain, MAX_CODE_BITS, SYMBOLS, quad};

    /// The codes as tables the vector registers look them up in: bytes with VBMI's byte permutes, 16-bit words
    /// with AVX-512 BW's word permutes where the CPU has no VBMI.
    // made once a frame on the stack, where boxing the larger variant would allocate once a frame
    #[allow(clippy::large_enum_variant)]
    pub(super) enum Tables {
        Bytes(ByteTables),
        Words(WordTables),
    }

    impl Tables {
        /// The widest tables this CPU can use (`vbmi` and `words` say which it may), or `None`.
        pub(super) fn new(code: &[u64; SYMBOLS], len: &[u32; SYMBOLS], vbmi: bool, words: bool) -> Option<Self> {
            if vbmi {
                Some(Self::Bytes(ByteTables::new(code, len)))
            } else if words {
                Some(Self::Words(WordTables::new(code, len)))
            } else {
                None
            }
        }

        /// `data`'s codes into `w`, as [`super::code_bytes`] writes them.
        ///
        /// # Safety
        /// The CPU must have what the tables were made for: AVX-512 (F, BW, VBMI) and BMI2 for bytes, AVX-512 (F,
        /// BW) and BMI2 for words.
        pub(super) unsafe fn code(
            &self,
            data: &[u8],
            code: &[u64; SYMBOLS],
            len: &[u32; SYMBOLS],
            w: &mut BitWriter<'_>,
        ) {
            // SAFETY: the caller's promise
            unsafe {
                match self {
                    Self::Bytes(t) => code_bytes_vbmi(data, t, code, len, w),
                    Self::Words(t) => code_bytes_words(data, t, code, len, w),
                }
            }
        }
    }

    /// The codes' low and high bytes and their lengths as 256-byte tables, for byte lookups in registers.
    #[repr(C, align(64))]
    pub(super) struct ByteTables {
        len: [u8; 256],
        low: [u8; 256],
        high: [u8; 256],
    }

    impl ByteTables {
        pub(super) fn new(code: &[u64; SYMBOLS], len: &[u32; SYMBOLS]) -> Self {
            // codes are at most 14 bits long: two bytes hold each
            Self {
                len: std::array::from_fn(|i| len[i] as u8),
                low: std::array::from_fn(|i| code[i] as u8),
                high: std::array::from_fn(|i| (code[i] >> 8) as u8),
            }
        }
    }

    /// The codes and their lengths as 256-entry tables of 16-bit words, for word lookups in registers.
    #[repr(C, align(64))]
    pub(super) struct WordTables {
        code: [u16; 256],
        len: [u16; 256],
    }

    impl WordTables {
        pub(super) fn new(code: &[u64; SYMBOLS], len: &[u32; SYMBOLS]) -> Self {
            // codes are at most 14 bits long
            Self { code: std::array::from_fn(|i| code[i] as u16), len: std::array::from_fn(|i| len[i] as u16) }
        }
    }

    /// [`code_bytes`](super::code_bytes), the same bits: each 64 bytes' codes are looked up in registers
    /// (VBMI's two-table byte permutes) and joined in the vector lanes ([`join`], [`put_eights`]). The tail of
    /// `data` short of 64 bytes goes to the scalar coder.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, BW, VBMI) and BMI2.
    #[target_feature(enable = "avx512f,avx512bw,avx512vbmi,bmi2")]
    pub(super) unsafe fn code_bytes_vbmi(
        data: &[u8],
        tables: &ByteTables,
        code: &[u64; SYMBOLS],
        len: &[u32; SYMBOLS],
        w: &mut BitWriter<'_>,
    ) {
        // SAFETY: each table is 256 bytes, four rows of 64
        let rows = |t: &[u8; 256]| {
            let p = t.as_ptr();
            unsafe { [0, 64, 128, 192].map(|k| _mm512_loadu_si512(p.add(k).cast())) }
        };
        let (tl, tc0, tc1) = (rows(&tables.len), rows(&tables.low), rows(&tables.high));
        // a 256-entry table: the low 7 bits pick from rows 0–1 or 2–3, the top bit which pair
        let lookup = |x: __m512i, t: &[__m512i; 4]| {
            let low = _mm512_permutex2var_epi8(t[0], x, t[1]);
            let high = _mm512_permutex2var_epi8(t[2], x, t[3]);
            _mm512_mask_blend_epi8(_mm512_movepi8_mask(x), low, high)
        };
        let zero = _mm512_setzero_si512();
        // the eights in order: lane k of the even eights is eight 2k, of the odd ones 2k + 1
        let order = _mm512_setr_epi64(0, 8, 2, 10, 4, 12, 6, 14);
        let eights = |block: &[u8]| {
            // SAFETY: `block` is 64 bytes
            let x = unsafe { _mm512_loadu_si512(block.as_ptr().cast()) };
            let (l8, c0, c1) = (lookup(x, &tl), lookup(x, &tc0), lookup(x, &tc1));
            // per 128-bit lane, bytes 0–7 (the even eights) and 8–15 (the odd ones) as 16-bit lanes
            let (even, odd) = (
                join(_mm512_unpacklo_epi8(c0, c1), _mm512_unpacklo_epi8(l8, zero)),
                join(_mm512_unpackhi_epi8(c0, c1), _mm512_unpackhi_epi8(l8, zero)),
            );
            (_mm512_permutex2var_epi64(even.0, order, odd.0), _mm512_permutex2var_epi64(even.1, order, odd.1))
        };
        // SAFETY: the CPU has AVX-512 F (the caller's promise)
        unsafe { code_blocks(data, code, len, w, eights) };
    }

    /// [`code_bytes`](super::code_bytes), the same bits, on CPUs with AVX-512 but not VBMI: each 32 bytes
    /// widened to 16-bit words, their codes and lengths looked up in registers (AVX-512 BW's two-table word
    /// permutes, 64 entries each, four to a table of 256 and the index's bits 6 and 7 choosing among them) and
    /// joined in the vector lanes ([`join`], [`put_eights`]). The tail of `data` short of 64 bytes goes to the
    /// scalar coder.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, BW) and BMI2.
    #[target_feature(enable = "avx512f,avx512bw,bmi2")]
    pub(super) unsafe fn code_bytes_words(
        data: &[u8],
        tables: &WordTables,
        code: &[u64; SYMBOLS],
        len: &[u32; SYMBOLS],
        w: &mut BitWriter<'_>,
    ) {
        // SAFETY: each table is 256 words, eight rows of 32
        let rows = |t: &[u16; 256]| {
            let p = t.as_ptr();
            unsafe { std::array::from_fn::<_, 8, _>(|k| _mm512_loadu_si512(p.add(32 * k).cast())) }
        };
        let (tc, tl) = (rows(&tables.code), rows(&tables.len));
        let (bit6, bit7) = (_mm512_set1_epi16(64), _mm512_set1_epi16(128));
        // a 256-entry table: the low 6 bits pick within a pair of rows, bits 6 and 7 which pair
        let lookup = |x: __m512i, t: &[__m512i; 8], m6: __mmask32, m7: __mmask32| {
            let q: [__m512i; 4] = std::array::from_fn(|k| _mm512_permutex2var_epi16(t[2 * k], x, t[2 * k + 1]));
            let low = _mm512_mask_blend_epi16(m6, q[0], q[1]);
            let high = _mm512_mask_blend_epi16(m6, q[2], q[3]);
            _mm512_mask_blend_epi16(m7, low, high)
        };
        // the eights of 32 bytes, each in its 128-bit lane's low half
        let eights = |half: &[u8]| {
            // SAFETY: `half` is 32 bytes
            let x = _mm512_cvtepu8_epi16(unsafe { _mm256_loadu_si256(half.as_ptr().cast()) });
            let (m6, m7) = (_mm512_test_epi16_mask(x, bit6), _mm512_test_epi16_mask(x, bit7));
            join(lookup(x, &tc, m6, m7), lookup(x, &tl, m6, m7))
        };
        // the low halves of the first 32 bytes' lanes, then the second's
        let order = _mm512_setr_epi64(0, 2, 4, 6, 8, 10, 12, 14);
        let block_eights = |block: &[u8]| {
            let (first, second) = (eights(&block[..32]), eights(&block[32..]));
            (_mm512_permutex2var_epi64(first.0, order, second.0), _mm512_permutex2var_epi64(first.1, order, second.1))
        };
        // SAFETY: the CPU has AVX-512 F (the caller's promise)
        unsafe { code_blocks(data, code, len, w, block_eights) };
    }

    /// What both vector coders share: `data`'s whole blocks of 64 bytes, each block's eight joined codes and
    /// lengths in order from `eights` (as [`join`] leaves them, one eight to a 64-bit lane), onto one chain of
    /// stores ([`put_eights`]), and the tail short of 64 bytes to the scalar coder. Always inlined into the
    /// coder, so that its tables stay in vector registers.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F.
    #[inline(always)]
    unsafe fn code_blocks(
        data: &[u8],
        code: &[u64; SYMBOLS],
        len: &[u32; SYMBOLS],
        w: &mut BitWriter<'_>,
        eights: impl Fn(&[u8]) -> (__m512i, __m512i),
    ) {
        let blocks = data.chunks_exact(64);
        let tail = blocks.remainder();
        let mut chain = Chain::start(w, (data.len() - tail.len()) * MAX_CODE_BITS as usize);
        for block in blocks {
            let (c, l) = eights(block);
            // SAFETY: the block's bytes, each coded once; the caller's promise for the CPU
            unsafe { put_eights(&mut chain, block, c, l, code, len) };
        }
        chain.finish(w);
        super::code_bytes(tail, code, len, w);
    }

    /// Sixteen-bit codes `c` and lengths `l`, eight to a 128-bit lane, joined into the lane's low 64 bits, the
    /// first code lowest (valid where the eight lengths sum to at most 56), and the sum in the lane's low length:
    /// pairs into 32-bit lanes, fours into 64-bit lanes, eights into the 128-bit lane.
    #[target_feature(enable = "avx512f,avx512bw")]
    #[inline]
    fn join(c: __m512i, l: __m512i) -> (__m512i, __m512i) {
        let (m16, m32) = (_mm512_set1_epi32(0xffff), _mm512_set1_epi64(0xffff_ffff));
        let le = _mm512_and_si512(l, m16);
        let c = _mm512_or_si512(_mm512_and_si512(c, m16), _mm512_sllv_epi32(_mm512_srli_epi32::<16>(c), le));
        let l = _mm512_add_epi32(le, _mm512_srli_epi32::<16>(l));
        let le = _mm512_and_si512(l, m32);
        let c = _mm512_or_si512(_mm512_and_si512(c, m32), _mm512_sllv_epi64(_mm512_srli_epi64::<32>(c), le));
        let l = _mm512_add_epi64(le, _mm512_srli_epi64::<32>(l));
        let c = _mm512_or_si512(c, _mm512_sllv_epi64(_mm512_unpackhi_epi64(c, c), l));
        (c, _mm512_add_epi64(l, _mm512_unpackhi_epi64(l, l)))
    }

    /// The eight joined codes `c` and lengths `l` of the 64 bytes of `block`, in order, onto the chain: one store
    /// each where every eight fits one (at most 56 bits), else an eight that does not as two fours. Always
    /// inlined: a call here would spill the coder's tables, held in vector registers, at every block.
    ///
    /// # Safety
    /// As [`Chain::put`]: the block's bytes must be among those the chain was started for. The CPU must have
    /// AVX-512 F.
    #[inline(always)]
    unsafe fn put_eights(
        chain: &mut Chain,
        block: &[u8],
        c: __m512i,
        l: __m512i,
        code: &[u64; SYMBOLS],
        len: &[u32; SYMBOLS],
    ) {
        let (mut bits, mut lens) = ([0u64; 8], [0u64; 8]);
        // SAFETY: each array is 64 bytes; the CPU has AVX-512 F (the caller's promise)
        let fits = unsafe {
            _mm512_storeu_si512(bits.as_mut_ptr().cast(), c);
            _mm512_storeu_si512(lens.as_mut_ptr().cast(), l);
            _mm512_cmpgt_epu64_mask(l, _mm512_set1_epi64(56)) == 0
        };
        // SAFETY (both branches): the caller's promise
        if fits {
            for e in 0..8 {
                unsafe { chain.put(bits[e], lens[e] as u32) };
            }
        } else {
            for (e, o) in block.chunks_exact(8).enumerate() {
                if lens[e] <= 56 {
                    unsafe { chain.put(bits[e], lens[e] as u32) };
                } else {
                    let ((low, nl), (high, nh)) = (quad(&o[..4], code, len), quad(&o[4..], code, len));
                    unsafe {
                        chain.put(low, nl);
                        chain.put(high, nh);
                    }
                }
            }
        }
    }
}

/// Clamped to `[0, max]`, rounded half up, NaN as 0: [`Frame::png16_samples`]'s sample.
///
/// [`Frame::png16_samples`]: crate::imaging::frame::Frame::png16_samples
#[inline(always)]
pub fn quantize(v: f32, max: f32) -> u16 {
    // `max` is held to [0, 65535] (NaN to 0); `v.max(0.0)` returns 0 for NaN; the value is then in
    // [0.5, 65535.5], so the truncating conversion cannot overflow
    let max = if max >= 0.0 { max.min(65_535.0) } else { 0.0 };
    let c = v.max(0.0).min(max) + 0.5;
    // SAFETY: `c` is finite and within [0.5, 65535.5], inside i32's range
    (unsafe { c.to_int_unchecked::<i32>() }) as u16
}

/// The k of [`count_rows`]'s every k-th row for `bytes` of filtered data in `rows` rows: about
/// [`SAMPLE_BYTES`] bytes are counted.
fn sample_every(bytes: usize, rows: usize) -> usize {
    (bytes / SAMPLE_BYTES).clamp(1, rows.max(1))
}

/// The counts of the byte values in `rows`, plus one for every symbol so that any byte has a code.
fn count_rows<'a>(rows: impl Iterator<Item = &'a [u8]>) -> [u32; SYMBOLS] {
    // four tables, so that a run of equal bytes does not wait on its own increments
    let mut parts = [[0u32; 256]; 4];
    for row in rows {
        let mut quads = row.chunks_exact(4);
        for q in &mut quads {
            parts[0][q[0] as usize] += 1;
            parts[1][q[1] as usize] += 1;
            parts[2][q[2] as usize] += 1;
            parts[3][q[3] as usize] += 1;
        }
        for &b in quads.remainder() {
            parts[0][b as usize] += 1;
        }
    }
    let mut counts = [1u32; SYMBOLS];
    for (i, c) in counts.iter_mut().take(256).enumerate() {
        *c += parts[0][i] + parts[1][i] + parts[2][i] + parts[3][i];
    }
    counts
}

/// Huffman code lengths for `counts` (every count ≥ 1), none longer than [`MAX_CODE_BITS`]: the optimal
/// lengths, with the counts halved until the longest fits (a handful of bytes' cost on a frame).
fn code_lengths(counts: &[u32; SYMBOLS]) -> [u8; SYMBOLS] {
    let mut counts = *counts;
    loop {
        let lengths = huffman_lengths(&counts);
        if lengths.iter().all(|&l| u32::from(l) <= MAX_CODE_BITS) {
            return lengths;
        }
        for c in &mut counts {
            *c = (*c >> 1).max(1);
        }
    }
}

/// Optimal (unlimited) Huffman code lengths by the two-queue method: the leaves sorted by count (ties by
/// symbol), the merged trees made in order of weight, the two lightest of both queues merged until one tree is
/// left. The lengths depend on the counts alone.
fn huffman_lengths(counts: &[u32; SYMBOLS]) -> [u8; SYMBOLS] {
    const NODES: usize = 2 * SYMBOLS - 1;
    let mut leaves = [0u64; SYMBOLS];
    for (l, (i, &c)) in leaves.iter_mut().zip(counts.iter().enumerate()) {
        *l = (u64::from(c) << 9) | i as u64;
    }
    leaves.sort_unstable();
    // node k < SYMBOLS is the k-th lightest leaf; node SYMBOLS + j the j-th merged tree
    let mut weight = [0u64; NODES];
    let mut parent = [0u16; NODES];
    for (w, &l) in weight.iter_mut().zip(&leaves) {
        *w = l >> 9;
    }
    let (mut leaf, mut tree, mut made) = (0usize, SYMBOLS, SYMBOLS);
    // the lighter front of the two queues (a leaf on a tie, which keeps the trees shallow)
    let lightest = |leaf: &mut usize, tree: &mut usize, made: usize, weight: &[u64; NODES]| {
        if *leaf < SYMBOLS && (*tree >= made || weight[*leaf] <= weight[*tree]) {
            *leaf += 1;
            *leaf - 1
        } else {
            *tree += 1;
            *tree - 1
        }
    };
    while made < NODES {
        let a = lightest(&mut leaf, &mut tree, made, &weight);
        let b = lightest(&mut leaf, &mut tree, made, &weight);
        weight[made] = weight[a] + weight[b];
        parent[a] = made as u16;
        parent[b] = made as u16;
        made += 1;
    }
    // a node's depth is its parent's plus one; parents come after their children, so go from the root down
    let mut depth = [0u8; NODES];
    for n in (0..NODES - 1).rev() {
        depth[n] = depth[parent[n] as usize].saturating_add(1);
    }
    let mut lengths = [0u8; SYMBOLS];
    for (k, &l) in leaves.iter().enumerate() {
        lengths[(l & 511) as usize] = depth[k];
    }
    lengths
}

/// The canonical codes of RFC 1951 §3.2.2 for `lengths`, each bit-reversed (deflate sends a Huffman code's
/// most significant bit first, into a stream packed from the least significant bit).
fn canonical_codes<const N: usize>(lengths: &[u8; N]) -> [u16; N] {
    let mut count = [0u16; 16];
    for &l in lengths {
        count[l as usize] += 1;
    }
    count[0] = 0;
    let mut next = [0u16; 16];
    let mut code = 0u16;
    for bits in 1..16 {
        code = (code + count[bits - 1]) << 1;
        next[bits] = code;
    }
    let mut codes = [0u16; N];
    for (c, &l) in codes.iter_mut().zip(lengths) {
        if l > 0 {
            *c = next[l as usize].reverse_bits() >> (16 - l);
            next[l as usize] += 1;
        }
    }
    codes
}

/// The block header: final, dynamic; 257 literal/length codes, 2 distance codes (both 1 bit: none is used, and
/// a complete code is what every inflater takes); the code-length code gives each length 0–15 four bits.
fn write_header(w: &mut BitWriter<'_>, lengths: &[u8; SYMBOLS]) {
    // BFINAL = 1, BTYPE = 2
    w.put(0b101, 3);
    // HLIT = 257 − 257, HDIST = 2 − 1, HCLEN = 19 − 4
    w.put(0, 5);
    w.put(1, 5);
    w.put(15, 4);
    // the code-length code's lengths, in RFC 1951's order 16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2,
    // 14, 1, 15: 16–18 unused, 0–15 four bits each
    w.put(0, 9);
    for _ in 0..16 {
        w.put(4, 3);
    }
    // with sixteen 4-bit codes, length value v's code is v itself, bit-reversed
    let code = |v: u8| u64::from(v.reverse_bits() >> 4);
    for &l in lengths {
        w.put(code(l), 4);
    }
    w.put(code(1), 4);
    w.put(code(1), 4);
}

/// A deflate bit stream written into a buffer that has room for 8 bytes past the last one written.
struct BitWriter<'a> {
    out: &'a mut [u8],
    pos: usize,
    buf: u64,
    nbits: u32,
}

impl BitWriter<'_> {
    /// Appends the low `n` bits of `bits` (`n` ≤ 56; no bits above them set).
    #[inline(always)]
    fn put(&mut self, bits: u64, n: u32) {
        let mut chain = Chain::start(self, n as usize);
        // SAFETY: `n` bits, as `start` was given
        unsafe { chain.put(bits, n) };
        chain.finish(self);
    }

    /// Pads to a whole byte; returns the stream's length in bytes.
    fn finish(self) -> usize {
        self.pos + usize::from(self.nbits > 0)
    }
}

/// The length of `n` bytes as stored deflate blocks.
fn stored_size(n: usize) -> usize {
    n + 5 * n.div_ceil(STORED_BLOCK_MAX).max(1)
}

/// `data` as stored deflate blocks (each: a header byte, its length and the length's complement, the bytes).
fn write_stored(data: &[u8], out: &mut Vec<u8>) {
    let mut blocks = data.chunks(STORED_BLOCK_MAX).peekable();
    if blocks.peek().is_none() {
        out.extend_from_slice(&[1, 0, 0, 0xff, 0xff]);
    }
    while let Some(block) = blocks.next() {
        out.push(u8::from(blocks.peek().is_none()));
        let n = block.len() as u16;
        out.extend_from_slice(&n.to_le_bytes());
        out.extend_from_slice(&(!n).to_le_bytes());
        out.extend_from_slice(block);
    }
}

/// A PNG chunk: length, type, data, CRC of type and data.
fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32fast::hash(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (u32, u32, Vec<u16>) {
        let img = image::load_from_memory(bytes).expect("a PNG image reads back").into_luma16();
        (img.width(), img.height(), img.into_raw())
    }

    fn reference(pixels: &[f32], max: u16) -> Vec<u16> {
        pixels.iter().map(|&v| quantize(v, f32::from(max))).collect()
    }

    /// A smooth sky under noise, as frames are.
    fn sky(w: usize, h: usize, sigma: f32, seed: u32) -> Vec<f32> {
        let mut s = seed.wrapping_mul(2_654_435_761) | 1;
        (0..w * h)
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                let u = (s >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
                3000.0 + (i / w) as f32 * 3.0 + (i % w) as f32 * 0.5 + u * sigma * 3.46
            })
            .collect()
    }

    #[test]
    fn frames_read_back_exactly_through_other_decoders() {
        let mut enc = Png16Encoder::new();
        let mut out = Vec::new();
        // (8200 × 3: a row longer than a band's bytes, coded in pieces)
        let sizes =
            [(256, 256, 8.0), (640, 512, 3.0), (8200, 3, 5.0), (1, 1, 0.0), (1, 7, 5.0), (7, 1, 5.0), (3, 5, 900.0)];
        for &(w, h, sigma) in &sizes {
            let px = sky(w, h, sigma, (w * h) as u32);
            enc.encode(&px, w, h, 16383, &mut out);
            assert_eq!(decode(&out), (w as u32, h as u32, reference(&px, 16383)), "{w}x{h}");
            // another inflater (miniz_oxide, through flate2) reads the IDAT's stream into the filtered rows
            let idat = out.windows(4).position(|t| t == b"IDAT").unwrap();
            let n = u32::from_be_bytes(out[idat - 4..idat].try_into().unwrap()) as usize;
            let mut inflated = Vec::new();
            std::io::Read::read_to_end(
                &mut flate2::read::ZlibDecoder::new(&out[idat + 4..idat + 4 + n]),
                &mut inflated,
            )
            .unwrap();
            // (the encoder keeps a band of them; the whole frame's, filtered apart)
            let mut whole = Png16Encoder::new();
            whole.filter(&px, w, 16383, &mut || {});
            assert_eq!(inflated, whole.filtered, "{w}x{h}");
        }
    }

    #[test]
    fn hostile_values_clamp_and_incompressible_frames_are_stored() {
        let mut enc = Png16Encoder::new();
        let mut out = Vec::new();
        let px = [0.0, 1.4, 1.5, 65535.0, 70000.0, -5.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        enc.encode(&px, 3, 3, 65535, &mut out);
        assert_eq!(decode(&out).2, vec![0, 1, 2, 65535, 65535, 0, 0, 65535, 0]);
        // uniform random bytes: the Huffman table cannot beat storing them
        let mut s = 12_345u32;
        let px: Vec<f32> = (0..300 * 300)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 16) as f32
            })
            .collect();
        enc.encode(&px, 300, 300, 65535, &mut out);
        assert_eq!(decode(&out).2, reference(&px, 65535));
        assert!(out.len() < 300 * 300 * 2 + 301 + 200, "{} bytes", out.len());
    }

    #[test]
    fn a_constant_frame_costs_about_a_bit_a_byte() {
        let mut enc = Png16Encoder::new();
        let mut out = Vec::new();
        let px = vec![1234.0; 256 * 256];
        enc.encode(&px, 256, 256, 16383, &mut out);
        assert_eq!(decode(&out).2, reference(&px, 16383));
        // a bit for each byte, the rows' filter bytes and first pixels, the header
        assert!(out.len() < 256 * 513 / 8 + 256 * 5 + 400, "{} bytes", out.len());
    }

    #[test]
    fn code_lengths_are_complete_and_limited() {
        // counts spanning many octaves force the limit
        let mut counts = [1u32; SYMBOLS];
        for (i, c) in counts.iter_mut().enumerate().take(30) {
            *c = 1 << (i.min(30));
        }
        for counts in [counts, [1u32; SYMBOLS], count_rows([0u8; 1000].chunks_exact(10))] {
            let lengths = code_lengths(&counts);
            let kraft: f64 = lengths.iter().map(|&l| 0.5f64.powi(i32::from(l))).sum();
            assert!((kraft - 1.0).abs() < 1e-12, "Kraft sum {kraft}");
            assert!(lengths.iter().all(|&l| (1..=MAX_CODE_BITS as u8).contains(&l)));
        }
        // optimal where no limit binds: cost equals a textbook Huffman's on a small case
        let mut small = [1u32; SYMBOLS];
        small[0] = 1000;
        small[1] = 500;
        let l = huffman_lengths(&small);
        assert_eq!((l[0], l[1]), (1, 2));
    }

    #[test]
    fn code_lengths_cost_what_huffman_merging_costs() {
        // a Huffman code's cost Σ count·length is the sum of the weights of the trees merged to make it
        let mut s = 7u64;
        for round in 0..20 {
            let mut counts = [1u32; SYMBOLS];
            for c in &mut counts {
                s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                *c = 1 + ((s >> 33) % [2, 50, 10_000, 1_000_000][round % 4]) as u32;
            }
            let lengths = huffman_lengths(&counts);
            let cost: u64 = counts.iter().zip(&lengths).map(|(&c, &l)| u64::from(c) * u64::from(l)).sum();
            let mut heap: std::collections::BinaryHeap<std::cmp::Reverse<u64>> =
                counts.iter().map(|&c| std::cmp::Reverse(u64::from(c))).collect();
            let mut merged = 0;
            while heap.len() > 1 {
                let (a, b) = (heap.pop().unwrap().0, heap.pop().unwrap().0);
                merged += a + b;
                heap.push(std::cmp::Reverse(a + b));
            }
            assert_eq!(cost, merged, "round {round}");
        }
    }

    #[test]
    fn eight_codes_to_a_store_write_the_stream_one_code_at_a_time_writes() {
        // short codes (eight fit a store), long ones (they do not), and mixes, over lengths not a multiple of 8; in
        // the last round short codes for bytes from every quarter of the table (a filtered frame's high bytes are
        // mostly 0 and 255; the vector coder looks the quarters up apart), from the table the encoder makes for them
        let mut s = 99u64;
        let quarters: Vec<u8> = [0u8, 64, 128, 192, 252].iter().flat_map(|&q| (0..4).map(move |k| q + k)).collect();
        for (round, spread) in [2u32, 40, 256, 256, 7, 20].into_iter().enumerate() {
            let data: Vec<u8> = (0..1000 + round * 67)
                .map(|_| {
                    s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                    let r = (s >> 40) as u32 % spread;
                    if round == 5 { quarters[r as usize] } else { r as u8 }
                })
                .collect();
            let counts = if round == 5 {
                count_rows(std::iter::once(&data[..]))
            } else {
                let mut counts = [1u32; SYMBOLS];
                counts[0] = [100_000, 10, 1, 1, 5000][round];
                counts
            };
            let lengths = code_lengths(&counts);
            let codes = canonical_codes(&lengths);
            let code: [u64; SYMBOLS] = std::array::from_fn(|i| u64::from(codes[i]));
            let len: [u32; SYMBOLS] = std::array::from_fn(|i| u32::from(lengths[i]));
            if round == 5 {
                assert!(quarters.iter().all(|&b| len[b as usize] <= 7), "eight codes fit a store");
            }
            // the stream's bytes, its length as the writer finishes it, after `head` and `code_all`'s codes
            let write = |head: Option<(u64, u32)>, code_all: &dyn Fn(&mut BitWriter<'_>)| {
                let mut out = vec![0u8; data.len() * 2 + 16];
                let mut w = BitWriter { out: &mut out, pos: 0, buf: 0, nbits: 0 };
                if let Some((bits, n)) = head {
                    w.put(bits, n);
                }
                code_all(&mut w);
                let n = w.finish();
                out.truncate(n);
                out
            };
            let one_at_a_time = |w: &mut BitWriter<'_>| {
                for &b in &data {
                    w.put(code[b as usize], len[b as usize]);
                }
            };
            let fast = write(None, &|w| code_bytes(&data, &code, &len, w));
            assert_eq!(fast, write(None, &one_at_a_time), "round {round}");
            // the vector coders, where the CPU has them, from a stream already under way (3 bits waiting)
            #[cfg(target_arch = "x86_64")]
            for (name, tables) in [
                ("bytes", x86::Tables::new(&code, &len, vbmi(), false)),
                ("words", x86::Tables::new(&code, &len, false, words())),
            ] {
                let Some(tables) = tables else { continue };
                // SAFETY: `vbmi` and `words` checked the CPU
                let vector = write(Some((0b101, 3)), &|w| unsafe { tables.code(&data, &code, &len, w) });
                assert_eq!(vector, write(Some((0b101, 3)), &one_at_a_time), "round {round}, {name}");
            }
        }
    }

    #[test]
    fn buffers_are_reused() {
        let mut enc = Png16Encoder::new();
        let mut out = Vec::new();
        let px = sky(64, 48, 4.0, 1);
        enc.encode(&px, 64, 48, 16383, &mut out);
        let first = out.clone();
        enc.encode(&sky(200, 100, 4.0, 2), 200, 100, 16383, &mut out);
        enc.encode(&px, 64, 48, 16383, &mut out);
        assert_eq!(out, first, "the same frame encodes to the same bytes after a larger one");
    }
}
