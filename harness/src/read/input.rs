//! Bounded reading of participant input: only regular files, never more
//! than a documented number of bytes, before or after gzip decompression.
//!
//! `stepsim score` and `stepsim leaderboard` read files that a participant
//! wrote. A FIFO must not block the scorer, `/dev/zero` must not fill its
//! memory, and a small gzip file must not inflate into gigabytes. So every
//! read goes through [`read_regular_file`]: the path must name a regular file
//! (checked on the metadata before opening, then again on the opened handle,
//! which is opened non-blocking), and at most `cap` bytes are read; a larger
//! file is refused naming the file and the cap. [`open_regular`] and
//! [`CappedReader`] do the same for a file read as a stream. [`GzReader`]
//! inflates a gzip stream as it is read (every member, each CRC-32 and size
//! checked, at most [`MAX_GZIP_MEMBERS`]) and stops at its own cap;
//! [`gunzip_bounded`] is it read to the end.
//!
//! The caps (see `docs/scoring.md`): [`MAX_SUBMISSION_BYTES`], the floor of
//! a run's submission limit (`truth_set::run_submission_limit`; the sum over
//! the files of a directory, raw and after decompression),
//! [`MAX_REPORT_BYTES`] for one `report.json`,
//! [`MAX_DATASETS_JSON_BYTES`] for the truth's `datasets.json`.

use std::io::Read;
use std::path::Path;

/// One mebibyte.
const MIB: u64 = 1 << 20;

/// Smallest submission limit of a run, in bytes, and the limit of
/// [`crate::read::submission::read_submission`]: the sum over its files, counted
/// both as stored and after gzip decompression (256 MiB; about 3 million
/// rows of text). A run's own limit grows with its truth
/// (`truth_set::run_submission_limit`).
pub const MAX_SUBMISSION_BYTES: u64 = 256 * MIB;

/// Largest `report.json` the leaderboard reads (16 MiB; a report is tens of
/// kilobytes).
pub const MAX_REPORT_BYTES: u64 = 16 * MIB;

/// Largest `datasets.json` the harness reads (64 MiB).
pub const MAX_DATASETS_JSON_BYTES: u64 = 64 * MIB;

/// Why a file was not read. The messages are lower-case sentences without the
/// path (the caller's error names the file).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InputError {
    /// The path is missing or its metadata cannot be read.
    #[error("cannot read: {0}")]
    Unreadable(String),
    /// A directory, FIFO, socket or device.
    #[error("not a regular file ({0}); only regular files are read")]
    NotRegular(&'static str),
    /// More bytes than the cap.
    #[error("larger than the limit of {} ({what}); refused without reading it", show_bytes(*.cap))]
    TooLarge {
        /// The limit in bytes.
        cap: u64,
        /// What was measured (`the file`, `after gzip decompression`).
        what: &'static str,
    },
    /// Not a valid gzip stream.
    #[error("not a valid gzip file: {0}")]
    BadGzip(&'static str),
}

/// `n` bytes as a readable size (`256 MiB`, `1.5 KiB`, `12 bytes`).
pub fn show_bytes(n: u64) -> String {
    if n >= MIB && n % MIB == 0 {
        format!("{} MiB", n / MIB)
    } else if n >= 1024 && n % 1024 == 0 {
        format!("{} KiB", n / 1024)
    } else {
        format!("{n} bytes")
    }
}

/// What kind of non-regular file `t` is.
pub fn kind_of(t: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_socket() {
            return "a socket";
        }
        if t.is_char_device() || t.is_block_device() {
            return "a device";
        }
    }
    if t.is_dir() {
        "a directory"
    } else if t.is_symlink() {
        "a symbolic link"
    } else if t.is_file() {
        "a regular file"
    } else {
        "a special file"
    }
}

/// Reads the regular file `path` (a symbolic link is followed) whole, refusing
/// anything that is not a regular file and any file of more than `cap`
/// bytes. A FIFO is refused without blocking: the metadata is checked before
/// opening, and the file is opened non-blocking and checked again, so that a
/// file swapped for a FIFO in between cannot block either. At most `cap + 1`
/// bytes are ever read, whatever the metadata says.
pub fn read_regular_file(path: &Path, cap: u64) -> Result<Vec<u8>, InputError> {
    read_regular(path, cap, true)
}

/// [`read_regular_file`] for an entry of a submission directory: a symbolic
/// link is refused, not followed (checked on the metadata, and the file is
/// opened with `O_NOFOLLOW`, so a link swapped in meanwhile is refused too).
pub fn read_entry_file(path: &Path, cap: u64) -> Result<Vec<u8>, InputError> {
    read_regular(path, cap, false)
}

fn read_regular(path: &Path, cap: u64, follow: bool) -> Result<Vec<u8>, InputError> {
    let (file, len) = open_regular(path, cap, follow)?;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(cap.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| InputError::Unreadable(e.to_string()))?;
    if bytes.len() as u64 > cap {
        return Err(InputError::TooLarge {
            cap,
            what: "the file",
        });
    }
    Ok(bytes)
}

/// Opens the regular file `path` for reading with the checks of
/// [`read_regular_file`] (`follow`) or [`read_entry_file`] (links refused),
/// without reading it: refused when not a regular file or when its metadata
/// say more than `cap` bytes. Returns the handle and the length the metadata
/// give; a reader must still stop after `cap` bytes (the file may grow),
/// which [`CappedReader`] does.
pub fn open_regular(
    path: &Path,
    cap: u64,
    follow: bool,
) -> Result<(std::fs::File, u64), InputError> {
    let meta = if follow {
        std::fs::metadata(path)
    } else {
        std::fs::symlink_metadata(path)
    }
    .map_err(|e| InputError::Unreadable(e.to_string()))?;
    if !meta.is_file() {
        return Err(InputError::NotRegular(kind_of(&meta.file_type())));
    }
    if meta.len() > cap {
        return Err(InputError::TooLarge {
            cap,
            what: "the file",
        });
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        let nofollow = if follow { 0 } else { libc::O_NOFOLLOW };
        options.custom_flags(libc::O_NONBLOCK | nofollow);
    }
    let file = options
        .open(path)
        .map_err(|e| InputError::Unreadable(e.to_string()))?;
    let meta = file
        .metadata()
        .map_err(|e| InputError::Unreadable(e.to_string()))?;
    if !meta.is_file() {
        return Err(InputError::NotRegular(kind_of(&meta.file_type())));
    }
    Ok((file, meta.len()))
}

/// A reader that fails with [`InputError::TooLarge`] (`what`) instead of
/// yielding more than `cap` bytes in all.
pub struct CappedReader<R> {
    inner: R,
    left: u64,
    cap: u64,
    what: &'static str,
}

impl<R: Read> CappedReader<R> {
    /// At most `cap` bytes of `inner`; `what` names what was measured.
    pub fn new(inner: R, cap: u64, what: &'static str) -> Self {
        Self {
            inner,
            left: cap,
            cap,
            what,
        }
    }
}

impl<R: Read> Read for CappedReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if buf.is_empty() {
            return Ok(0);
        }
        // One byte more than allowed tells a file of exactly `cap` bytes
        // from a longer one.
        let want = buf
            .len()
            .min(usize::try_from(self.left.saturating_add(1)).unwrap_or(usize::MAX));
        let n = self.inner.read(&mut buf[..want])?;
        if n as u64 > self.left {
            return Err(std::io::Error::other(InputError::TooLarge {
                cap: self.cap,
                what: self.what,
            }));
        }
        self.left -= n as u64;
        Ok(n)
    }
}

/// The [`InputError`] inside an I/O error raised by this module's readers,
/// or the I/O error as [`InputError::Unreadable`].
pub fn input_error(e: std::io::Error) -> InputError {
    input_error_ref(&e)
}

/// True when `bytes` start with the gzip magic number.
pub fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b])
}

/// Most members read from one gzip file: 65 536. `gzip` and `pigz` write one
/// member, `cat a.gz b.gz` a few; `bgzip` writes a member per 64 KiB of data,
/// so 65 536 members hold 4 GiB, more than any submission the harness takes.
/// Each member costs a little setup, so without a bound a small file of
/// empty members (20 bytes each) would cost seconds of CPU.
pub const MAX_GZIP_MEMBERS: u64 = 65_536;

/// Inflates a gzip file (RFC 1952; every member in turn) into at most `cap`
/// bytes: [`GzReader`] read to the end. Refuses, without producing more than
/// `cap` bytes, a stream that inflates to more; refuses a stream that is not
/// gzip, uses another method than deflate, is corrupt or truncated, whose
/// trailer records another size or CRC-32 than the data have, that has more
/// than [`MAX_GZIP_MEMBERS`] members, or that has bytes after its last
/// member.
pub fn gunzip_bounded(bytes: &[u8], cap: u64) -> Result<Vec<u8>, InputError> {
    let mut out = Vec::new();
    GzReader::new(bytes, cap)
        .read_to_end(&mut out)
        .map_err(input_error)?;
    Ok(out)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum GzPhase {
    Header,
    Data,
    Done,
}

/// A streaming gzip decoder (every member in turn; the checks of
/// [`gunzip_bounded`]) that yields at most `cap` inflated bytes. Errors are
/// I/O errors holding an [`InputError`] ([`input_error`] gets it back). It
/// holds 64 KiB of input and miniz_oxide's inflate state (about 43 KiB),
/// reused from member to member.
pub struct GzReader<R> {
    input: R,
    inbuf: Box<[u8]>,
    in_pos: usize,
    in_len: usize,
    in_eof: bool,
    state: Box<miniz_oxide::inflate::stream::InflateState>,
    crc: crc32fast::Hasher,
    member_out: u64,
    total_out: u64,
    cap: u64,
    members: u64,
    phase: GzPhase,
    /// The error already returned, returned again by every later read.
    failed: Option<InputError>,
}

fn gz_err(e: InputError) -> std::io::Error {
    std::io::Error::other(e)
}

const GZ_SHORT_HEADER: InputError = InputError::BadGzip("the file ends inside the gzip header");

impl<R: Read> GzReader<R> {
    /// Decodes the gzip stream `input` into at most `cap` bytes.
    pub fn new(input: R, cap: u64) -> Self {
        use miniz_oxide::DataFormat;
        use miniz_oxide::inflate::stream::InflateState;
        Self {
            input,
            inbuf: vec![0u8; 1 << 16].into_boxed_slice(),
            in_pos: 0,
            in_len: 0,
            in_eof: false,
            state: InflateState::new_boxed(DataFormat::Raw),
            crc: crc32fast::Hasher::new(),
            member_out: 0,
            total_out: 0,
            cap,
            members: 0,
            phase: GzPhase::Header,
            failed: None,
        }
    }

    /// Members begun so far.
    #[cfg(test)]
    pub fn members(&self) -> u64 {
        self.members
    }

    /// Refills the input buffer when it is empty; false at the end.
    fn fill(&mut self) -> std::io::Result<bool> {
        if self.in_pos < self.in_len {
            return Ok(true);
        }
        if self.in_eof {
            return Ok(false);
        }
        loop {
            match self.input.read(&mut self.inbuf) {
                Ok(0) => {
                    self.in_eof = true;
                    return Ok(false);
                }
                Ok(n) => {
                    self.in_pos = 0;
                    self.in_len = n;
                    return Ok(true);
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
    }

    fn byte(&mut self) -> std::io::Result<Option<u8>> {
        if !self.fill()? {
            return Ok(None);
        }
        self.in_pos += 1;
        Ok(Some(self.inbuf[self.in_pos - 1]))
    }

    fn need(&mut self, short: InputError) -> std::io::Result<u8> {
        self.byte()?.ok_or_else(|| gz_err(short))
    }

    /// Reads one member header; the magic number is checked by the caller
    /// for members after the first.
    fn header(&mut self, magic_read: bool) -> std::io::Result<()> {
        if self.members >= MAX_GZIP_MEMBERS {
            return Err(gz_err(InputError::BadGzip(
                "more than 65536 gzip members (the limit); compress the file as one member",
            )));
        }
        let mut fixed = [0u8; 10];
        let start = if magic_read {
            fixed[0] = 0x1f;
            fixed[1] = 0x8b;
            2
        } else {
            0
        };
        for b in fixed.iter_mut().skip(start) {
            *b = self.need(GZ_SHORT_HEADER)?;
        }
        if !is_gzip(&fixed) {
            return Err(gz_err(InputError::BadGzip("no gzip magic number")));
        }
        if fixed[2] != 8 {
            return Err(gz_err(InputError::BadGzip(
                "compression method is not deflate",
            )));
        }
        let flags = fixed[3];
        if flags & 4 != 0 {
            let lo = self.need(GZ_SHORT_HEADER)?;
            let hi = self.need(GZ_SHORT_HEADER)?;
            for _ in 0..u16::from_le_bytes([lo, hi]) {
                self.need(GZ_SHORT_HEADER)?;
            }
        }
        for bit in [8u8, 16] {
            if flags & bit != 0 {
                while self.need(GZ_SHORT_HEADER)? != 0 {}
            }
        }
        if flags & 2 != 0 {
            self.need(GZ_SHORT_HEADER)?;
            self.need(GZ_SHORT_HEADER)?;
        }
        self.members += 1;
        self.state.reset(miniz_oxide::DataFormat::Raw);
        self.crc = crc32fast::Hasher::new();
        self.member_out = 0;
        self.phase = GzPhase::Data;
        Ok(())
    }

    /// Checks the trailer of the member just inflated and looks for the
    /// next member.
    fn trailer(&mut self) -> std::io::Result<()> {
        const SHORT: InputError = InputError::BadGzip("the file ends inside the gzip trailer");
        let mut t = [0u8; 8];
        for b in &mut t {
            *b = self.need(SHORT)?;
        }
        if u32::from_le_bytes([t[4], t[5], t[6], t[7]]) != self.member_out as u32 {
            return Err(gz_err(InputError::BadGzip(
                "the size recorded in the gzip trailer is not the size of the data",
            )));
        }
        let crc = std::mem::take(&mut self.crc).finalize();
        if u32::from_le_bytes([t[0], t[1], t[2], t[3]]) != crc {
            return Err(gz_err(InputError::BadGzip(
                "the CRC-32 recorded in the gzip trailer is not that of the data (the file is corrupt)",
            )));
        }
        const TRAILING: InputError = InputError::BadGzip("bytes follow the end of the gzip data");
        match self.byte()? {
            None => {
                self.phase = GzPhase::Done;
                Ok(())
            }
            Some(0x1f) => match self.byte()? {
                Some(0x8b) => self.header(true),
                _ => Err(gz_err(TRAILING)),
            },
            Some(_) => Err(gz_err(TRAILING)),
        }
    }
}

impl<R: Read> Read for GzReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if let Some(e) = &self.failed {
            return Err(gz_err(e.clone()));
        }
        let r = self.read_more(buf);
        if let Err(e) = &r {
            self.failed = Some(input_error_ref(e));
        }
        r
    }
}

/// [`input_error`] of a borrowed error.
fn input_error_ref(e: &std::io::Error) -> InputError {
    match e.get_ref().and_then(|r| r.downcast_ref::<InputError>()) {
        Some(ie) => ie.clone(),
        None => InputError::Unreadable(e.to_string()),
    }
}

impl<R: Read> GzReader<R> {
    fn read_more(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        use miniz_oxide::inflate::stream::inflate;
        use miniz_oxide::{MZError, MZFlush, MZStatus};
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            match self.phase {
                GzPhase::Done => return Ok(0),
                GzPhase::Header => self.header(false)?,
                GzPhase::Data => {
                    self.fill()?;
                    let r = inflate(
                        &mut self.state,
                        &self.inbuf[self.in_pos..self.in_len],
                        buf,
                        MZFlush::None,
                    );
                    self.in_pos += r.bytes_consumed;
                    let n = r.bytes_written;
                    if self.total_out + n as u64 > self.cap {
                        return Err(gz_err(InputError::TooLarge {
                            cap: self.cap,
                            what: "after gzip decompression",
                        }));
                    }
                    self.total_out += n as u64;
                    self.member_out += n as u64;
                    self.crc.update(&buf[..n]);
                    match r.status {
                        Ok(MZStatus::StreamEnd) => self.trailer()?,
                        Ok(_) | Err(MZError::Buf) => {
                            if r.bytes_consumed == 0 && n == 0 {
                                if self.in_pos < self.in_len {
                                    return Err(gz_err(InputError::BadGzip(
                                        "the compressed data are corrupt",
                                    )));
                                }
                                if !self.fill()? {
                                    return Err(gz_err(InputError::BadGzip(
                                        "the file ends inside the compressed data",
                                    )));
                                }
                            }
                        }
                        Err(_) => {
                            return Err(gz_err(InputError::BadGzip(
                                "the compressed data are corrupt",
                            )));
                        }
                    }
                    if n > 0 {
                        return Ok(n);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gzip(data: &[u8]) -> Vec<u8> {
        let mut v = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3];
        v.extend(miniz_oxide::deflate::compress_to_vec(data, 6));
        v.extend(crc32fast::hash(data).to_le_bytes());
        v.extend((data.len() as u32).to_le_bytes());
        v
    }

    #[test]
    fn gzip_members_inflate_within_the_cap_and_not_beyond() {
        let a = b"# image x y e1 e2\n".repeat(100);
        let mut two = gzip(&a);
        two.extend(gzip(b"tail"));
        let got = gunzip_bounded(&two, 10_000).unwrap();
        assert_eq!(got.len(), a.len() + 4);
        assert!(got.ends_with(b"tail"));
        // A bomb: 4 MiB of zeros in a few kilobytes, refused at a 1 MiB cap.
        let bomb = gzip(&vec![0u8; 4 << 20]);
        assert!(bomb.len() < 10_000);
        let e = gunzip_bounded(&bomb, 1 << 20).unwrap_err();
        assert_eq!(
            e.to_string(),
            "larger than the limit of 1 MiB (after gzip decompression); refused without reading it"
        );
        assert_eq!(gunzip_bounded(&bomb, 4 << 20).unwrap().len(), 4 << 20);
        // Truncations and corruptions are refused, never a panic.
        let small = gzip(&b"x y e1 e2\n".repeat(50));
        for n in 0..small.len() {
            assert!(gunzip_bounded(&small[..n], 8 << 20).is_err());
        }
        assert!(matches!(
            gunzip_bounded(&bomb[..bomb.len() - 9], 8 << 20),
            Err(InputError::BadGzip(_))
        ));
        let mut lying = gzip(b"abc");
        let n = lying.len();
        lying[n - 4..].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            gunzip_bounded(&lying, 100).unwrap_err().to_string(),
            "not a valid gzip file: the size recorded in the gzip trailer is not the size of \
             the data"
        );
        let mut trailing = gzip(b"abc");
        trailing.extend(b"\xff\xff\xff\xff");
        assert_eq!(
            gunzip_bounded(&trailing, 100).unwrap_err().to_string(),
            "not a valid gzip file: bytes follow the end of the gzip data"
        );
        let mut bad = gzip(b"abc");
        bad[2] = 7;
        assert_eq!(
            gunzip_bounded(&bad, 100).unwrap_err().to_string(),
            "not a valid gzip file: compression method is not deflate"
        );
    }

    /// A reader that hands out its bytes a few at a time.
    struct Trickle<'a>(&'a [u8], usize);

    impl Read for Trickle<'_> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            self.1 = self.1 % 7 + 1;
            let n = self.1.min(buf.len()).min(self.0.len());
            buf[..n].copy_from_slice(&self.0[..n]);
            self.0 = &self.0[n..];
            Ok(n)
        }
    }

    #[test]
    fn a_trickled_stream_inflates_as_a_whole_one() {
        let a: Vec<u8> = (0..200_000u32)
            .flat_map(|k| k.wrapping_mul(2_654_435_761).to_le_bytes())
            .collect();
        let mut two = gzip(&a);
        two.extend(gzip(b"tail"));
        for out in [1usize, 9, 1000, 1 << 16] {
            let mut r = GzReader::new(Trickle(&two, 0), 1 << 30);
            let mut got = Vec::new();
            let mut buf = vec![0u8; out];
            loop {
                let n = r.read(&mut buf).unwrap();
                if n == 0 {
                    break;
                }
                got.extend_from_slice(&buf[..n]);
            }
            assert_eq!(got.len(), a.len() + 4, "{out}");
            assert!(got.starts_with(&a) && got.ends_with(b"tail"));
            assert_eq!(r.members(), 2);
        }
        let mut bad = gzip(&a);
        let n = bad.len();
        bad[n - 6] ^= 1;
        let e = input_error(
            GzReader::new(Trickle(&bad, 0), 1 << 30)
                .read_to_end(&mut Vec::new())
                .unwrap_err(),
        );
        assert!(e.to_string().contains("CRC-32"), "{e}");
    }

    #[test]
    fn only_regular_files_within_the_cap_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        std::fs::write(&p, b"0123456789").unwrap();
        assert_eq!(read_regular_file(&p, 10).unwrap(), b"0123456789");
        assert_eq!(
            read_regular_file(&p, 9).unwrap_err(),
            InputError::TooLarge {
                cap: 9,
                what: "the file"
            }
        );
        assert_eq!(
            read_regular_file(dir.path(), 9).unwrap_err(),
            InputError::NotRegular("a directory")
        );
        assert!(matches!(
            read_regular_file(&dir.path().join("none"), 9),
            Err(InputError::Unreadable(_))
        ));
        #[cfg(unix)]
        {
            // A device whose metadata says 0 bytes and that never ends.
            assert_eq!(
                read_regular_file(Path::new("/dev/zero"), 9).unwrap_err(),
                InputError::NotRegular("a device")
            );
            // A FIFO with no writer: refused at once, never opened blocking.
            let fifo = dir.path().join("f");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            assert_eq!(
                read_regular_file(&fifo, 9).unwrap_err(),
                InputError::NotRegular("a FIFO")
            );
        }
        #[cfg(unix)]
        {
            // A link: followed by read_regular_file, refused as an entry.
            let link = dir.path().join("l.txt");
            std::os::unix::fs::symlink(&p, &link).unwrap();
            assert_eq!(read_regular_file(&link, 10).unwrap(), b"0123456789");
            assert_eq!(
                read_entry_file(&link, 10).unwrap_err(),
                InputError::NotRegular("a symbolic link")
            );
            assert_eq!(read_entry_file(&p, 10).unwrap(), b"0123456789");
        }
        assert_eq!(show_bytes(256 << 20), "256 MiB");
        assert_eq!(show_bytes(3 << 10), "3 KiB");
        assert_eq!(show_bytes(9), "9 bytes");
    }
}
