//! Pseudo-terminals for the simulated serial devices (the Elliptec mount,
//! the relay): the device speaks on the master side, and the driver opens
//! the slave's path (`/dev/pts/N`) like any serial port, so the driver's
//! real serial code runs in tests and on the fake bench.

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

/// A new pseudo-terminal in raw mode: the master side as a file, the slave
/// side (held so the pty stays up between the driver's opens) and its path.
pub fn open() -> std::io::Result<(std::fs::File, OwnedFd, String)> {
    let (mut master, mut slave) = (-1, -1);
    // SAFETY: openpty writes two descriptors into the given places (valid
    // i32s) and reads no name, termios or window size (null pointers
    // are allowed for those).
    let r = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    if r != 0 || master < 0 || slave < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: both descriptors were just opened by openpty (checked
    // above) and are owned by nothing else.
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    let path = pty_path(&slave)?;
    raw_mode(&slave)?;
    Ok((std::fs::File::from(master), slave, path))
}

/// Whether `port` has input within `ms` milliseconds (so that a device
/// loop sees its stop flag between reads).
pub fn readable(port: &std::fs::File, ms: i32) -> bool {
    let mut poll = libc::pollfd {
        fd: port.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid pollfd for an open descriptor.
    unsafe { libc::poll(&mut poll, 1, ms) > 0 }
}

/// The path of the pty whose slave side is `slave`.
fn pty_path(slave: &OwnedFd) -> std::io::Result<String> {
    let mut buf = [0u8; 128];
    // SAFETY: `slave` is an open descriptor; ttyname_r writes at most
    // `buf.len()` bytes (a NUL-terminated name) into `buf`.
    let r = unsafe { libc::ttyname_r(slave.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
    if r != 0 {
        return Err(std::io::Error::from_raw_os_error(r));
    }
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    Ok(String::from_utf8_lossy(&buf[..end]).into_owned())
}

/// Puts the pty in raw mode: no echo, no line editing, bytes as they come.
fn raw_mode(slave: &OwnedFd) -> std::io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it from the open
    // descriptor before it is read.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    // SAFETY: `slave` is open; `t` is a valid termios to fill.
    if unsafe { libc::tcgetattr(slave.as_raw_fd(), &mut t) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: `t` was filled by tcgetattr above.
    unsafe { libc::cfmakeraw(&mut t) };
    // SAFETY: `slave` is open; `t` is a valid termios.
    if unsafe { libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}
