//! Bounded reading of participant input: only regular files, never more
//! than a documented number of bytes, before or after gzip decompression.
//!
//! `stepsim score` and `stepsim leaderboard` read files that a participant
//! wrote. A FIFO must not block the scorer, `/dev/zero` must not fill its
//! memory, and a small gzip file must not inflate into gigabytes. So every
//! read goes through [`read_regular_file`]: the path must name a regular file
//! (checked on the metadata before opening, then again on the opened handle,
//! which is opened non-blocking), and at most `cap` bytes are read; a larger
//! file is refused naming the file and the cap. [`gunzip_bounded`] inflates a
//! gzip stream (every member) and stops at its own cap.
//!
//! The caps (see `docs/scoring.md`): [`MAX_SUBMISSION_BYTES`] for a whole
//! submission (the sum over the files of a directory, raw and after
//! decompression), [`MAX_REPORT_BYTES`] for one `report.json`,
//! [`MAX_DATASETS_JSON_BYTES`] for the truth's `datasets.json`.

use std::io::Read;
use std::path::Path;

/// One mebibyte.
const MIB: u64 = 1 << 20;

/// Largest submission read, in bytes: the sum over its files, counted both
/// as stored and after gzip decompression (256 MiB; about 3 million rows of
/// text).
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
    let mut bytes = Vec::with_capacity(usize::try_from(meta.len()).unwrap_or(0));
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

/// True when `bytes` start with the gzip magic number.
pub fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b])
}

/// Inflates a gzip file (RFC 1952; every member in turn) into at most `cap`
/// bytes. Refuses, without producing more than `cap` bytes, a stream that
/// inflates to more; refuses a stream that is not gzip, uses another method
/// than deflate, is corrupt or truncated, whose trailer records another size
/// than the data have, or that has bytes after its last member. (cfitsio,
/// which inflates a gzip FITS file again itself, sizes its buffer from the
/// last trailer: so that buffer never exceeds what was checked here.)
pub fn gunzip_bounded(bytes: &[u8], cap: u64) -> Result<Vec<u8>, InputError> {
    let mut out = Vec::new();
    let mut pos = 0;
    loop {
        pos += skip_gzip_header(&bytes[pos..])?;
        let before = out.len();
        pos += inflate_member(&bytes[pos..], &mut out, cap)?;
        // Trailer: CRC-32 and size mod 2³², 8 bytes.
        let Some(t) = bytes.get(pos + 4..pos + 8) else {
            return Err(InputError::BadGzip("the file ends inside the gzip trailer"));
        };
        if u32::from_le_bytes([t[0], t[1], t[2], t[3]]) != (out.len() - before) as u32 {
            return Err(InputError::BadGzip(
                "the size recorded in the gzip trailer is not the size of the data",
            ));
        }
        pos += 8;
        if pos == bytes.len() {
            return Ok(out);
        }
        if !is_gzip(&bytes[pos..]) {
            return Err(InputError::BadGzip("bytes follow the end of the gzip data"));
        }
    }
}

/// Length of the gzip member header at the start of `b`.
fn skip_gzip_header(b: &[u8]) -> Result<usize, InputError> {
    const SHORT: InputError = InputError::BadGzip("the file ends inside the gzip header");
    if b.len() < 10 {
        return Err(SHORT);
    }
    if !is_gzip(b) {
        return Err(InputError::BadGzip("no gzip magic number"));
    }
    if b[2] != 8 {
        return Err(InputError::BadGzip("compression method is not deflate"));
    }
    let flags = b[3];
    let mut pos = 10;
    if flags & 4 != 0 {
        let n = b.get(pos..pos + 2).ok_or(SHORT)?;
        pos += 2 + usize::from(u16::from_le_bytes([n[0], n[1]]));
    }
    for bit in [8u8, 16] {
        if flags & bit != 0 {
            let end = b.get(pos..).ok_or(SHORT)?.iter().position(|&c| c == 0);
            pos += end.ok_or(SHORT)? + 1;
        }
    }
    if flags & 2 != 0 {
        pos += 2;
    }
    if pos > b.len() {
        return Err(SHORT);
    }
    Ok(pos)
}

/// Inflates one raw deflate stream from `input` onto `out` (which must stay
/// within `cap` bytes); returns the input bytes consumed.
fn inflate_member(input: &[u8], out: &mut Vec<u8>, cap: u64) -> Result<usize, InputError> {
    use miniz_oxide::inflate::stream::{InflateState, inflate};
    use miniz_oxide::{DataFormat, MZFlush, MZStatus};
    let mut state = InflateState::new_boxed(DataFormat::Raw);
    let mut buf = vec![0u8; 1 << 16];
    let mut pos = 0;
    loop {
        let r = inflate(&mut state, &input[pos..], &mut buf, MZFlush::None);
        pos += r.bytes_consumed;
        if out.len() as u64 + r.bytes_written as u64 > cap {
            return Err(InputError::TooLarge {
                cap,
                what: "after gzip decompression",
            });
        }
        out.extend_from_slice(&buf[..r.bytes_written]);
        match r.status {
            Ok(MZStatus::StreamEnd) => return Ok(pos),
            Ok(_) | Err(miniz_oxide::MZError::Buf) => {
                if r.bytes_consumed == 0 && r.bytes_written == 0 {
                    return Err(InputError::BadGzip(
                        "the file ends inside the compressed data",
                    ));
                }
            }
            Err(_) => return Err(InputError::BadGzip("the compressed data are corrupt")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gzip(data: &[u8]) -> Vec<u8> {
        let mut v = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3];
        v.extend(miniz_oxide::deflate::compress_to_vec(data, 6));
        v.extend([0u8; 4]); // CRC (not checked)
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
