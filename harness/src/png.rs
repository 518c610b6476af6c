//! A minimal PNG writer for the plots: 8-bit palette images compressed with
//! deflate (RFC 1951) using the fixed Huffman code and matches at distance 1
//! (runs along a row) and distance w + 1 (the same pixel one row up), which
//! is what flat-coloured plots need.
//!
//! References kept alongside: [`zlib_stored`] (uncompressed deflate, the
//! obvious encoder) and [`inflate`] (a decoder of stored and fixed-Huffman
//! blocks) with [`decode_indexed`]; tests check that every encoding decodes
//! back to its input.

/// CRC-32 (IEEE, reflected, as PNG and zlib use), bit by bit.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// Adler-32 checksum of zlib.
pub fn adler32(bytes: &[u8]) -> u32 {
    let (mut a, mut b) = (1u32, 0u32);
    for chunk in bytes.chunks(5552) {
        for &x in chunk {
            a += u32::from(x);
            b += a;
        }
        a %= 65521;
        b %= 65521;
    }
    (b << 16) | a
}

/// Reference encoder: zlib stream of `raw` in stored (uncompressed) blocks.
pub fn zlib_stored(raw: &[u8]) -> Vec<u8> {
    let mut z = vec![0x78, 0x01];
    let mut blocks = raw.chunks(65_535).peekable();
    if blocks.peek().is_none() {
        z.extend_from_slice(&[1, 0, 0, 0xff, 0xff]);
    }
    while let Some(b) = blocks.next() {
        z.push(u8::from(blocks.peek().is_none()));
        let n = b.len() as u16;
        z.extend_from_slice(&n.to_le_bytes());
        z.extend_from_slice(&(!n).to_le_bytes());
        z.extend_from_slice(b);
    }
    z.extend_from_slice(&adler32(raw).to_be_bytes());
    z
}

/// Length code table of RFC 1951 §3.2.5: (base length, extra bits).
const LEN_BASE: [(u16, u8); 29] = [
    (3, 0),
    (4, 0),
    (5, 0),
    (6, 0),
    (7, 0),
    (8, 0),
    (9, 0),
    (10, 0),
    (11, 1),
    (13, 1),
    (15, 1),
    (17, 1),
    (19, 2),
    (23, 2),
    (27, 2),
    (31, 2),
    (35, 3),
    (43, 3),
    (51, 3),
    (59, 3),
    (67, 4),
    (83, 4),
    (99, 4),
    (115, 4),
    (131, 5),
    (163, 5),
    (195, 5),
    (227, 5),
    (258, 0),
];

/// Distance code table: (base distance, extra bits).
const DIST_BASE: [(u32, u8); 30] = [
    (1, 0),
    (2, 0),
    (3, 0),
    (4, 0),
    (5, 1),
    (7, 1),
    (9, 2),
    (13, 2),
    (17, 3),
    (25, 3),
    (33, 4),
    (49, 4),
    (65, 5),
    (97, 5),
    (129, 6),
    (193, 6),
    (257, 7),
    (385, 7),
    (513, 8),
    (769, 8),
    (1025, 9),
    (1537, 9),
    (2049, 10),
    (3073, 10),
    (4097, 11),
    (6145, 11),
    (8193, 12),
    (12289, 12),
    (16385, 13),
    (24577, 13),
];

struct BitWriter {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl BitWriter {
    /// Appends the low `n` bits of `v`, least significant first.
    fn bits(&mut self, v: u32, n: u32) {
        self.acc |= u64::from(v) << self.n;
        self.n += n;
        while self.n >= 8 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }
    /// Appends a Huffman code of `n` bits, most significant first.
    fn code(&mut self, c: u32, n: u32) {
        let rev = c.reverse_bits() >> (32 - n);
        self.bits(rev, n);
    }
    fn finish(mut self) -> Vec<u8> {
        if self.n > 0 {
            self.out.push(self.acc as u8);
        }
        self.out
    }
}

/// Fixed-Huffman code of a literal/length symbol: (code, bits).
fn fixed_litlen(sym: u16) -> (u32, u32) {
    let s = u32::from(sym);
    match sym {
        0..=143 => (0x30 + s, 8),
        144..=255 => (0x190 + s - 144, 9),
        256..=279 => (s - 256, 7),
        _ => (0xc0 + s - 280, 8),
    }
}

fn put_length(w: &mut BitWriter, len: usize) {
    let k = LEN_BASE
        .iter()
        .rposition(|&(b, _)| usize::from(b) <= len)
        .unwrap_or(0);
    let (base, extra) = LEN_BASE[k];
    let (c, n) = fixed_litlen(257 + k as u16);
    w.code(c, n);
    w.bits((len - usize::from(base)) as u32, u32::from(extra));
}

fn put_distance(w: &mut BitWriter, dist: usize) {
    let k = DIST_BASE
        .iter()
        .rposition(|&(b, _)| b as usize <= dist)
        .unwrap_or(0);
    let (base, extra) = DIST_BASE[k];
    w.code(k as u32, 5);
    w.bits((dist - base as usize) as u32, u32::from(extra));
}

/// zlib stream of `raw` in one fixed-Huffman block, with greedy matches at
/// distances 1 and `stride` (≤ 32768; 0 to disable).
pub fn zlib_fixed(raw: &[u8], stride: usize) -> Vec<u8> {
    let mut w = BitWriter {
        out: vec![0x78, 0x01],
        acc: 0,
        n: 0,
    };
    w.bits(1, 1); // BFINAL
    w.bits(1, 2); // BTYPE = 01, fixed Huffman
    let run = |i: usize, d: usize| -> usize {
        if d == 0 || d > i {
            return 0;
        }
        let mut l = 0;
        while l < 258 && i + l < raw.len() && raw[i + l] == raw[i + l - d] {
            l += 1;
        }
        l
    };
    let stride = if stride <= 32_768 { stride } else { 0 };
    let mut i = 0;
    while i < raw.len() {
        let (l1, l2) = (run(i, 1), run(i, stride));
        let (len, dist) = if l2 > l1 { (l2, stride) } else { (l1, 1) };
        if len >= 3 {
            put_length(&mut w, len);
            put_distance(&mut w, dist);
            i += len;
        } else {
            let (c, n) = fixed_litlen(u16::from(raw[i]));
            w.code(c, n);
            i += 1;
        }
    }
    let (c, n) = fixed_litlen(256);
    w.code(c, n);
    let mut z = w.finish();
    z.extend_from_slice(&adler32(raw).to_be_bytes());
    z
}

struct BitReader<'a> {
    data: &'a [u8],
    pos: usize, // in bits
}

impl BitReader<'_> {
    fn bit(&mut self) -> Option<u32> {
        let b = self.data.get(self.pos / 8)?;
        let v = (b >> (self.pos % 8)) & 1;
        self.pos += 1;
        Some(u32::from(v))
    }
    fn bits(&mut self, n: u32) -> Option<u32> {
        let mut v = 0;
        for k in 0..n {
            v |= self.bit()? << k;
        }
        Some(v)
    }
    /// Reads a fixed-Huffman literal/length symbol.
    fn litlen(&mut self) -> Option<u16> {
        let mut code = 0u32;
        for len in 1..=9 {
            code = (code << 1) | self.bit()?;
            for sym in 0..=287u16 {
                if fixed_litlen(sym) == (code, len) {
                    return Some(sym);
                }
            }
        }
        None
    }
}

/// Reference decoder of a zlib stream made of stored and fixed-Huffman
/// blocks (what this module writes); checks the Adler-32. `None` on any
/// error.
pub fn inflate(z: &[u8]) -> Option<Vec<u8>> {
    if z.len() < 6 || (u16::from(z[0]) << 8 | u16::from(z[1])) % 31 != 0 {
        return None;
    }
    let mut r = BitReader {
        data: &z[..z.len() - 4],
        pos: 16,
    };
    let mut out: Vec<u8> = Vec::new();
    loop {
        let last = r.bit()?;
        match r.bits(2)? {
            0 => {
                r.pos = r.pos.div_ceil(8) * 8;
                let p = r.pos / 8;
                let n = u16::from_le_bytes(r.data.get(p..p + 2)?.try_into().ok()?);
                let nn = u16::from_le_bytes(r.data.get(p + 2..p + 4)?.try_into().ok()?);
                if n != !nn {
                    return None;
                }
                out.extend_from_slice(r.data.get(p + 4..p + 4 + usize::from(n))?);
                r.pos = (p + 4 + usize::from(n)) * 8;
            }
            1 => loop {
                let sym = r.litlen()?;
                match sym {
                    0..=255 => out.push(sym as u8),
                    256 => break,
                    257..=285 => {
                        let (base, extra) = LEN_BASE[usize::from(sym - 257)];
                        let len = usize::from(base) + r.bits(u32::from(extra))? as usize;
                        let mut dcode = 0;
                        for _ in 0..5 {
                            dcode = (dcode << 1) | r.bit()?;
                        }
                        let (dbase, dextra) = *DIST_BASE.get(dcode as usize)?;
                        let dist = dbase as usize + r.bits(u32::from(dextra))? as usize;
                        if dist > out.len() {
                            return None;
                        }
                        for _ in 0..len {
                            out.push(out[out.len() - dist]);
                        }
                    }
                    _ => return None,
                }
            },
            _ => return None,
        }
        if last == 1 {
            break;
        }
    }
    let want = u32::from_be_bytes(z[z.len() - 4..].try_into().ok()?);
    (adler32(&out) == want).then_some(out)
}

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

/// Encodes a `w` × `h` image of palette indices (row-major from the top).
pub fn encode_indexed(w: usize, h: usize, palette: &[[u8; 3]], pix: &[u8]) -> Vec<u8> {
    let mut out = SIGNATURE.to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&(w as u32).to_be_bytes());
    ihdr.extend_from_slice(&(h as u32).to_be_bytes());
    ihdr.extend_from_slice(&[8, 3, 0, 0, 0]);
    chunk(&mut out, b"IHDR", &ihdr);
    let plte: Vec<u8> = palette.iter().flatten().copied().collect();
    chunk(&mut out, b"PLTE", &plte);
    let mut raw = Vec::with_capacity((w + 1) * h);
    for row in pix.chunks(w.max(1)).take(h) {
        raw.push(0);
        raw.extend_from_slice(row);
    }
    chunk(&mut out, b"IDAT", &zlib_fixed(&raw, w + 1));
    chunk(&mut out, b"IEND", &[]);
    out
}

/// Reference decoder of what [`encode_indexed`] writes (checks every CRC
/// and the Adler-32): returns (w, h, palette indices).
pub fn decode_indexed(png: &[u8]) -> Option<(usize, usize, Vec<u8>)> {
    if png.get(..8)? != SIGNATURE {
        return None;
    }
    let (mut i, mut w, mut h, mut idat) = (8, 0, 0, Vec::new());
    while i + 12 <= png.len() {
        let n = u32::from_be_bytes(png[i..i + 4].try_into().ok()?) as usize;
        let kind = png.get(i + 4..i + 8)?;
        let data = png.get(i + 8..i + 8 + n)?;
        let crc = u32::from_be_bytes(png.get(i + 8 + n..i + 12 + n)?.try_into().ok()?);
        if crc32(&png[i + 4..i + 8 + n]) != crc {
            return None;
        }
        match kind {
            b"IHDR" => {
                w = u32::from_be_bytes(data.get(0..4)?.try_into().ok()?) as usize;
                h = u32::from_be_bytes(data.get(4..8)?.try_into().ok()?) as usize;
            }
            b"IDAT" => idat.extend_from_slice(data),
            _ => {}
        }
        i += 12 + n;
    }
    let raw = inflate(&idat)?;
    if raw.len() != (w + 1) * h {
        return None;
    }
    let mut pix = Vec::with_capacity(w * h);
    for row in raw.chunks(w + 1) {
        if row[0] != 0 {
            return None;
        }
        pix.extend_from_slice(&row[1..]);
    }
    Some((w, h, pix))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn checksums_match_their_published_check_values() {
        assert_eq!(crc32(b"123456789"), 0xcbf4_3926);
        assert_eq!(adler32(b"Wikipedia"), 0x11e6_0398);
    }

    #[test]
    fn both_encoders_round_trip_through_the_reference_inflater() {
        let mut rng = stepsim_sim::seed::SimRng::seed_from_u64(3);
        for case in 0..40 {
            let n = rng.random_range(0..3000);
            let k = rng.random_range(1..=256u32);
            let runny = case % 2 == 0;
            let mut v: Vec<u8> = Vec::with_capacity(n);
            while v.len() < n {
                let b = rng.random_range(0..k) as u8;
                let r = if runny { rng.random_range(1..400) } else { 1 };
                v.extend(std::iter::repeat_n(b, r.min(n - v.len())));
            }
            let stride = rng.random_range(0..100);
            assert_eq!(inflate(&zlib_fixed(&v, stride)).as_deref(), Some(&v[..]));
            assert_eq!(inflate(&zlib_stored(&v)).as_deref(), Some(&v[..]));
        }
        // Every length and distance code of the tables is exercised by
        // long runs at strides up to 32768.
        let v: Vec<u8> = (0..70_000).map(|i| ((i / 700) % 3) as u8).collect();
        for stride in [1, 5, 100, 4097, 32_768] {
            assert_eq!(inflate(&zlib_fixed(&v, stride)).as_deref(), Some(&v[..]));
        }
    }

    #[test]
    fn png_round_trips_and_flat_images_compress() {
        let (w, h) = (300, 250);
        let pix: Vec<u8> = (0..w * h)
            .map(|i| ((i % w) / 37 + (i / w) / 50) as u8 % 8)
            .collect();
        let png = encode_indexed(w, h, &[[0, 0, 0]; 8], &pix);
        let (dw, dh, dp) = decode_indexed(&png).unwrap();
        assert_eq!((dw, dh), (w, h));
        assert_eq!(dp, pix);
        assert!(png.len() < pix.len() / 20, "{} bytes", png.len());
        let mut bad = png.clone();
        bad[40] ^= 1;
        assert!(decode_indexed(&bad).is_none(), "a flipped bit is caught");
    }
}
