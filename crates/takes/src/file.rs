//! A take's file: its name, creating it without overwriting or following links, writing
//! it no faster than the configured rate, syncing it, and the folder's free space.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::TakeError;

/// Creates `name` in `folder`, or `name` with `-2`, `-3`, ... before `.mcap` when a file
/// (or a link) of that name exists: `O_CREAT | O_EXCL` neither truncates nor follows links.
pub fn create_new_take_file(
    folder: &Path,
    name: &str,
) -> Result<(PathBuf, std::fs::File), TakeError> {
    let stem = name.strip_suffix(".mcap").unwrap_or(name);
    let mut last_error = None;
    for n in 1..=1000u32 {
        let candidate = if n == 1 {
            name.to_owned()
        } else {
            format!("{stem}-{n}.mcap")
        };
        let path = folder.join(&candidate);
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(file) => return Ok((path, file)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_error = Some(e),
            Err(source) => return Err(TakeError::Folder { path, source }),
        }
    }
    Err(TakeError::Folder {
        path: folder.join(name),
        source: last_error.unwrap_or_else(|| std::io::Error::other("no free file name")),
    })
}

/// A take's file, written no faster than `[takes] max_write_mb_s` when that is set: each
/// write waits until the bytes written so far fit the rate since the file was created.
pub(crate) struct TakeFile {
    file: std::fs::File,
    max_bytes_s: Option<f64>,
    created: Instant,
    written: u64,
    /// Bytes the disk has room for (tests: a disk that fills up mid-take); `None`: the disk's.
    space: Option<u64>,
}

impl TakeFile {
    pub(crate) fn new(file: std::fs::File, max_bytes_s: Option<f64>) -> Self {
        TakeFile {
            file,
            max_bytes_s,
            created: Instant::now(),
            written: 0,
            space: None,
        }
    }

    /// A file on a disk with room for `space` bytes: beyond them a write fails with ENOSPC,
    /// after writing what fits, as a full disk does.
    #[cfg(test)]
    pub(crate) fn with_space(file: std::fs::File, space: u64) -> Self {
        TakeFile {
            space: Some(space),
            ..TakeFile::new(file, None)
        }
    }
}

impl std::io::Write for TakeFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let buf = match self.space {
            Some(space) if self.written + buf.len() as u64 > space => {
                let room = space.saturating_sub(self.written) as usize;
                if room == 0 {
                    return Err(std::io::Error::from_raw_os_error(28)); // ENOSPC
                }
                &buf[..room]
            }
            _ => buf,
        };
        let n = self.file.write(buf)?;
        self.written += n as u64;
        if let Some(rate) = self.max_bytes_s {
            let due = Duration::from_secs_f64(self.written as f64 / rate);
            if let Some(wait) = due.checked_sub(self.created.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl std::io::Seek for TakeFile {
    fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
        self.file.seek(pos)
    }
}

/// `fsync` of the take's file and of its folder (so the new name survives a power cut).
pub(crate) fn sync_take(file: &std::fs::File, path: &Path) -> std::io::Result<()> {
    file.sync_all()?;
    if let Some(folder) = path.parent() {
        std::fs::File::open(folder)?.sync_all()?;
    }
    Ok(())
}

/// `<slate>_T<take>_<YYYYMMDDTHHMMSSZ>.mcap`
pub fn file_name(slate: &str, take: u32, started: SystemTime) -> String {
    format!("{slate}_T{take:03}_{}.mcap", utc_stamp(started))
}

/// One more than the highest take number of `slate` in `folder` (1 when none).
pub fn next_take(folder: &Path, slate: &str) -> u32 {
    let prefix = format!("{slate}_T");
    let highest = std::fs::read_dir(folder)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|entry| {
            let name = entry.file_name().into_string().ok()?;
            let rest = name.strip_prefix(&prefix)?;
            let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
            if rest[digits.len()..].starts_with('_') {
                digits.parse::<u32>().ok()
            } else {
                None
            }
        })
        .max();
    highest.map_or(1, |h| h.saturating_add(1))
}

/// `YYYYMMDDTHHMMSSZ` in UTC.
pub fn utc_stamp(time: SystemTime) -> String {
    let secs = time.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let (y, m, d) = civil_from_days(days);
    format!(
        "{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// Days since 1970-01-01 → (year, month, day), proleptic Gregorian (H. Hinnant's algorithm).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

pub fn unix_us(time: SystemTime) -> i64 {
    time.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

/// Free space for unprivileged users on the file system holding `path`, MB.
pub fn free_mb(path: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c_path = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs is plain data; all-zero is a valid value to be overwritten.
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c_path` is a valid NUL-terminated string and `stat` a valid out-pointer.
    let rc = unsafe { libc::statvfs(c_path.as_ptr(), &mut stat) };
    if rc != 0 {
        return None;
    }
    Some((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64) / (1024 * 1024))
}
