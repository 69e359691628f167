//! What the machine can hold: free disk space under a folder and available
//! memory. Asked before a capture or a transport matrix is admitted, so that
//! a request too big for the machine is refused with numbers, not an abort.

use std::path::Path;

use crate::transport::MemoryBudget;

/// Bytes an unprivileged process may still write on the file system of `dir`
/// (`statvfs`: available blocks times fragment size).
pub fn free_disk_bytes(dir: &Path) -> std::io::Result<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).map_err(|_| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has a NUL byte")
    })?;
    let mut st = std::mem::MaybeUninit::<libc::statvfs>::zeroed();
    // SAFETY: `c` is a NUL-terminated path alive for the call, and `st` points
    // to a writable, properly sized and aligned `statvfs` that the call fills;
    // it is read only after the call returned 0 (success).
    let rc = unsafe { libc::statvfs(c.as_ptr(), st.as_mut_ptr()) };
    if rc != 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: statvfs returned 0, so it initialized the whole struct.
    let st = unsafe { st.assume_init() };
    Ok(st.f_bavail.saturating_mul(st.f_frsize))
}

/// `MemAvailable` from `/proc/meminfo`, in bytes (None where there is none).
pub(crate) fn available_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    parse_mem_available(&text)
}

fn parse_mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// The transport matrix's memory budget on this machine: a quarter of the
/// available memory, because what follows T (an SVD or a solver's working
/// copy of it, the wall samples, the Gram matrix) takes about as much again
/// and the daemon keeps T cached; [`MemoryBudget::DEFAULT`] where the
/// available memory is unknown.
pub fn transport_memory_budget() -> MemoryBudget {
    available_memory_bytes()
        .map(|m| MemoryBudget::new(m / 4))
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mem_available_is_read_in_bytes() {
        let text = "MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:   2048 kB\n";
        assert_eq!(parse_mem_available(text), Some(2048 * 1024));
        assert_eq!(parse_mem_available("MemTotal: 1 kB\n"), None);
        assert_eq!(parse_mem_available("MemAvailable: lots kB\n"), None);
    }

    #[test]
    fn free_disk_of_a_real_folder_is_positive_and_of_a_missing_one_an_error() {
        let dir = tempfile::tempdir().unwrap();
        assert!(free_disk_bytes(dir.path()).unwrap() > 0);
        assert!(free_disk_bytes(&dir.path().join("missing")).is_err());
    }
}
