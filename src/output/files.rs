//! The flight log's files: text files that start a new part when they grow
//! past a size ([`RotatingFile`]), and the free space of the file system
//! they are on ([`free_bytes`]).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// A text file with a header line, split into parts by size:
/// `STEM.EXT`, then `STEM.1.EXT`, `STEM.2.EXT`, ..., each starting with the
/// header. Lines are never split across parts.
pub struct RotatingFile {
    dir: PathBuf,
    stem: &'static str,
    ext: &'static str,
    header: &'static str,
    max_bytes: u64,
    part: u32,
    bytes: u64,
    path: PathBuf,
    out: BufWriter<File>,
}

impl RotatingFile {
    /// Creates (truncates) `DIR/STEM.EXT` and writes `header` (a line,
    /// without its newline).
    pub fn create(
        dir: &Path,
        stem: &'static str,
        ext: &'static str,
        header: &'static str,
        max_bytes: u64,
    ) -> std::io::Result<Self> {
        let path = part_path(dir, stem, ext, 0);
        let out = open(&path, header)?;
        Ok(Self {
            dir: dir.to_owned(),
            stem,
            ext,
            header,
            max_bytes,
            part: 0,
            bytes: header.len() as u64 + 1,
            path,
            out,
        })
    }

    /// Appends `line` (with its newline), first starting a new part when
    /// this one would grow past the size limit. Returns the bytes written
    /// to disk by this call's rotation and write (roughly).
    pub fn write_line(&mut self, line: &[u8]) -> std::io::Result<u64> {
        let header_bytes = self.header.len() as u64 + 1;
        let mut written = 0;
        if self.bytes + line.len() as u64 > self.max_bytes && self.bytes > header_bytes {
            self.out.flush()?;
            self.part += 1;
            self.path = part_path(&self.dir, self.stem, self.ext, self.part);
            self.out = open(&self.path, self.header)?;
            tracing::info!(file = %self.path.display(), "flight log: new part");
            self.bytes = header_bytes;
            written += header_bytes;
        }
        self.out.write_all(line)?;
        self.bytes += line.len() as u64;
        Ok(written + line.len() as u64)
    }

    /// Writes the buffered lines to the file.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    /// The part being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Parts started so far (1 before any rotation).
    pub fn parts(&self) -> u32 {
        self.part + 1
    }
}

/// `DIR/STEM.EXT` for part 0, `DIR/STEM.N.EXT` after.
pub fn part_path(dir: &Path, stem: &str, ext: &str, part: u32) -> PathBuf {
    if part == 0 {
        dir.join(format!("{stem}.{ext}"))
    } else {
        dir.join(format!("{stem}.{part}.{ext}"))
    }
}

fn open(path: &Path, header: &str) -> std::io::Result<BufWriter<File>> {
    let mut out = BufWriter::with_capacity(64 * 1024, File::create(path)?);
    out.write_all(header.as_bytes())?;
    out.write_all(b"\n")?;
    Ok(out)
}

/// Bytes available to an unprivileged writer on the file system holding
/// `path` (statvfs: `f_bavail * f_frsize`).
pub fn free_bytes(path: &Path) -> std::io::Result<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c_path = std::ffi::CString::new(path.as_os_str().as_bytes())
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
    // SAFETY: `statvfs` is plain old data, for which all zeroes is valid.
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a NUL-terminated path and a valid out-pointer.
    let rc = unsafe { libc::statvfs(c_path.as_ptr(), &mut stat) };
    if rc != 0 {
        return Err(std::io::Error::last_os_error());
    }
    #[allow(clippy::unnecessary_cast)] // the field types differ by platform
    Ok((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotates_by_size_with_a_header_in_each_part() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut f = RotatingFile::create(dir.path(), "frames", "csv", "a,b", 20).expect("create");
        for i in 0..6 {
            f.write_line(format!("{i},xxxxx\n").as_bytes())
                .expect("write");
        }
        f.flush().expect("flush");
        assert_eq!(f.parts(), 3);
        let part0 = std::fs::read_to_string(dir.path().join("frames.csv")).expect("part 0");
        let part1 = std::fs::read_to_string(dir.path().join("frames.1.csv")).expect("part 1");
        assert_eq!(part0, "a,b\n0,xxxxx\n1,xxxxx\n");
        assert_eq!(part1, "a,b\n2,xxxxx\n3,xxxxx\n");
        assert!(dir.path().join("frames.2.csv").exists());
    }

    #[test]
    fn free_space_of_a_folder_and_an_error_for_a_missing_one() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert!(free_bytes(dir.path()).expect("statvfs") > 0);
        assert!(free_bytes(&dir.path().join("missing")).is_err());
    }
}
