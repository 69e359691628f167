//! The serial ports of the bench's devices (the Elliptec mount, the light
//! relay): opened as every driver opens one, and pseudo-terminals for their
//! simulated devices, which answer on the master side while the driver
//! opens the slave's path (`/dev/pts/N`) like any serial port, so the
//! driver's real serial code runs in tests and on the fake bench.

use std::io::{Read, Write};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Opens `path` at `baud`, 8N1, no flow control, reads timing out after
/// 20 ms (the drivers wait for their replies themselves).
pub fn open(path: &str, baud: u32) -> serialport::Result<Box<dyn serialport::SerialPort>> {
    serialport::new(path, baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(Duration::from_millis(20))
        .open()
}

/// A simulated device on a pseudo-terminal: a thread answers what the
/// driver writes until the device is unplugged (its pty closed) or dropped.
pub struct PtyDevice {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// The slave side, held so the pty stays up between the driver's opens.
    slave: Option<OwnedFd>,
}

impl PtyDevice {
    /// Starts a thread named `name` that hands each chunk of bytes the
    /// driver writes to `answer` and writes back what it returns.
    pub fn start(
        name: &str,
        mut answer: impl FnMut(&[u8]) -> Vec<u8> + Send + 'static,
    ) -> std::io::Result<Self> {
        let (mut port, slave, path) = pty()?;
        let stop = Arc::new(AtomicBool::new(false));
        let halt = stop.clone();
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let mut buf = [0u8; 64];
                while !halt.load(Ordering::SeqCst) {
                    // Wait for input at most 20 ms, so that a stop is seen.
                    if !readable(&port, 20) {
                        continue;
                    }
                    let n = match port.read(&mut buf) {
                        Ok(0) | Err(_) => {
                            // The driver closed its side: wait for the next open.
                            std::thread::sleep(Duration::from_millis(20));
                            continue;
                        }
                        Ok(n) => n,
                    };
                    let reply = answer(&buf[..n]);
                    if !reply.is_empty() {
                        let _ = port.write_all(&reply);
                        let _ = port.flush();
                    }
                }
            })?;
        Ok(Self {
            path,
            stop,
            thread: Some(thread),
            slave: Some(slave),
        })
    }

    /// The serial port's path to open (`/dev/pts/N`).
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Pulls the cable: the device stops and its pty closes.
    pub fn unplug(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.slave = None;
    }
}

impl Drop for PtyDevice {
    fn drop(&mut self) {
        self.unplug();
    }
}

/// A new pseudo-terminal in raw mode: the master side as a file, the slave
/// side (held so the pty stays up between the driver's opens) and its path.
fn pty() -> std::io::Result<(std::fs::File, OwnedFd, String)> {
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
fn readable(port: &std::fs::File, ms: i32) -> bool {
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
