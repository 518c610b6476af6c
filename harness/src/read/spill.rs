//! A submission's rows grouped by image on disk, so that scoring holds one
//! image's rows at a time, not the catalogue's.
//!
//! The reader passes over a submission once and pushes each row
//! ([`SpillWriter::push`]) into one buffer of at most `buffer_rows` rows
//! ([`DEFAULT_BUFFER_ROWS`]: 65 536 rows, 3.7 MB). When the buffer is full its
//! rows are sorted by image (a stable sort: each image's rows stay in file
//! order) and written to an unnamed temporary file as one chunk per image;
//! each image keeps the list of its chunks. [`SpilledRows::read`] then gives
//! back one image's rows in file order, as if they had all been kept.
//!
//! A row takes [`ROW_BYTES`] (48) bytes on disk: x, y, e1, e2 and the weight
//! as little-endian `f64` (bit for bit) and the line (or FITS row) as `u64`.
//! The file is created with [`tempfile::tempfile`] in the system's temporary
//! directory (`$TMPDIR`, else `/tmp`): it has no name, so the operating system
//! removes it when the last handle closes, on every path out (an error, a
//! panic, a kill).

use crate::read::submission::SubRow;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::sync::Arc;

/// Bytes of one spilled row.
pub const ROW_BYTES: usize = 48;

/// Rows buffered before a spill (65 536 rows of 56 bytes in memory).
pub const DEFAULT_BUFFER_ROWS: usize = 1 << 16;

/// One run of an image's rows in the file: byte offset and row count.
type Chunk = (u64, u32);

/// Writes rows grouped by image ([`SpilledRows`] when finished).
pub struct SpillWriter {
    file: BufWriter<File>,
    pos: u64,
    buf: Vec<(u32, SubRow)>,
    buffer_rows: usize,
    chunks: Vec<Vec<Chunk>>,
    counts: Vec<usize>,
    max_held: usize,
    bytes: Vec<u8>,
}

fn encode(out: &mut Vec<u8>, r: &SubRow) {
    for v in [r.x, r.y, r.e1, r.e2, r.weight] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&r.line.to_le_bytes());
}

fn decode(b: &[u8]) -> SubRow {
    let f = |k: usize| {
        let mut a = [0u8; 8];
        a.copy_from_slice(&b[8 * k..8 * k + 8]);
        a
    };
    SubRow {
        x: f64::from_le_bytes(f(0)),
        y: f64::from_le_bytes(f(1)),
        e1: f64::from_le_bytes(f(2)),
        e2: f64::from_le_bytes(f(3)),
        weight: f64::from_le_bytes(f(4)),
        line: u64::from_le_bytes(f(5)),
    }
}

impl SpillWriter {
    /// A writer for `n_images` images that buffers `buffer_rows` rows
    /// (at least 1) before writing.
    pub fn new(n_images: usize, buffer_rows: usize) -> std::io::Result<Self> {
        let buffer_rows = buffer_rows.max(1);
        Ok(Self {
            file: BufWriter::with_capacity(1 << 16, tempfile::tempfile()?),
            pos: 0,
            buf: Vec::with_capacity(buffer_rows),
            buffer_rows,
            chunks: vec![Vec::new(); n_images],
            counts: vec![0; n_images],
            max_held: 0,
            bytes: Vec::new(),
        })
    }

    /// Adds one row of image `image` (rows of an image in file order).
    pub fn push(&mut self, image: usize, row: SubRow) -> std::io::Result<()> {
        self.buf.push((image as u32, row));
        self.max_held = self.max_held.max(self.buf.len());
        if self.buf.len() >= self.buffer_rows {
            self.flush_buffer()?;
        }
        Ok(())
    }

    /// Adds all the rows of one image at once (a file of a per-image
    /// directory, already held by its reader), as one chunk.
    pub fn push_image(&mut self, image: usize, rows: &[SubRow]) -> std::io::Result<()> {
        for part in rows.chunks(u32::MAX as usize) {
            self.write_chunk(image, part.iter())?;
        }
        Ok(())
    }

    fn write_chunk<'r>(
        &mut self,
        image: usize,
        rows: impl ExactSizeIterator<Item = &'r SubRow>,
    ) -> std::io::Result<()> {
        let n = rows.len();
        if n == 0 {
            return Ok(());
        }
        self.bytes.clear();
        for r in rows {
            encode(&mut self.bytes, r);
        }
        self.file.write_all(&self.bytes)?;
        self.chunks[image].push((self.pos, n as u32));
        self.counts[image] += n;
        self.pos += self.bytes.len() as u64;
        Ok(())
    }

    fn flush_buffer(&mut self) -> std::io::Result<()> {
        let mut buf = std::mem::take(&mut self.buf);
        buf.sort_by_key(|(i, _)| *i);
        let mut start = 0;
        while start < buf.len() {
            let image = buf[start].0;
            let end = start + buf[start..].partition_point(|(i, _)| *i == image);
            self.write_chunk(image as usize, buf[start..end].iter().map(|(_, r)| r))?;
            start = end;
        }
        buf.clear();
        self.buf = buf;
        Ok(())
    }

    /// Writes what is buffered and hands the rows over for reading.
    pub fn finish(mut self) -> std::io::Result<SpilledRows> {
        self.flush_buffer()?;
        let file = self.file.into_inner().map_err(|e| e.into_error())?;
        Ok(SpilledRows {
            file: Arc::new(file),
            chunks: self.chunks,
            counts: self.counts,
            max_held: self.max_held,
        })
    }
}

/// Rows spilled by a [`SpillWriter`], read one image at a time (from any
/// thread: positioned reads of a shared file).
#[derive(Debug, Clone)]
pub struct SpilledRows {
    file: Arc<File>,
    chunks: Vec<Vec<Chunk>>,
    counts: Vec<usize>,
    max_held: usize,
}

impl SpilledRows {
    /// Number of images.
    pub fn n_images(&self) -> usize {
        self.counts.len()
    }

    /// Rows of image `i`.
    pub fn len(&self, i: usize) -> usize {
        self.counts[i]
    }

    /// Most rows the writer ever held in memory at once.
    pub fn max_rows_held(&self) -> usize {
        self.max_held
    }

    /// The rows of image `i`, in file order.
    pub fn read(&self, i: usize) -> std::io::Result<Vec<SubRow>> {
        use std::os::unix::fs::FileExt;
        let mut out = Vec::with_capacity(self.counts[i]);
        let mut bytes = Vec::new();
        for &(offset, n) in &self.chunks[i] {
            bytes.resize(n as usize * ROW_BYTES, 0);
            self.file.read_exact_at(&mut bytes, offset)?;
            out.extend(bytes.chunks_exact(ROW_BYTES).map(decode));
        }
        Ok(out)
    }

    /// The images `which` (indices into these), in that order, sharing the
    /// file.
    pub fn select(&self, which: &[usize]) -> Self {
        Self {
            file: Arc::clone(&self.file),
            chunks: which.iter().map(|&i| self.chunks[i].clone()).collect(),
            counts: which.iter().map(|&i| self.counts[i]).collect(),
            max_held: self.max_held,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_come_back_by_image_in_file_order_bit_for_bit() {
        let mut w = SpillWriter::new(3, 5).unwrap();
        let mut want = vec![Vec::new(); 3];
        for k in 0..40u64 {
            let i = ((k * 7) % 3) as usize;
            let r = SubRow {
                x: k as f64 + 0.1,
                y: -0.0,
                e1: f64::MIN_POSITIVE * k as f64,
                e2: 1.0 / (k as f64 + 3.0),
                weight: if k % 5 == 0 { 0.0 } else { 1e300 },
                line: k + 1,
            };
            w.push(i, r).unwrap();
            want[i].push(r);
        }
        w.push_image(2, &want[0][..2]).unwrap();
        let head = want[0][..2].to_vec();
        want[2].extend_from_slice(&head);
        let s = w.finish().unwrap();
        assert_eq!(s.max_rows_held(), 5);
        for (i, rows) in want.iter().enumerate() {
            let got = s.read(i).unwrap();
            assert_eq!(got.len(), s.len(i));
            for (a, b) in got.iter().zip(rows) {
                assert_eq!(a.x.to_bits(), b.x.to_bits());
                assert_eq!(a.y.to_bits(), b.y.to_bits());
                assert_eq!(
                    (a.e1, a.e2, a.weight, a.line),
                    (b.e1, b.e2, b.weight, b.line)
                );
            }
            assert_eq!(got.len(), rows.len());
        }
        let sel = s.select(&[2, 0]);
        assert_eq!(sel.read(1).unwrap(), want[0]);
        assert_eq!(sel.len(0), want[2].len());
    }
}
