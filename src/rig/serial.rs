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
///
/// A port another handle still holds (its exclusive lock) is tried again
/// for up to [`BUSY_WAIT`] before the error is returned.
///
/// Why: a handle just dropped can keep its lock for a moment. A process
/// forked in the meantime holds a copy of the descriptor until it execs,
/// and the lock goes with the last copy. The suite saw a reopen fail so.
pub fn open(path: &str, baud: u32) -> serialport::Result<Box<dyn serialport::SerialPort>> {
    let started = std::time::Instant::now();
    loop {
        let port = serialport::new(path, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(Duration::from_millis(20))
            .open();
        match port {
            Err(e) if is_busy(&e) && started.elapsed() < BUSY_WAIT => {
                std::thread::sleep(Duration::from_millis(20));
            }
            other => return other,
        }
    }
}

/// How long [`open`] waits for a port another handle holds.
pub const BUSY_WAIT: Duration = Duration::from_millis(500);

/// Whether opening failed because another handle holds the port's lock.
fn is_busy(e: &serialport::Error) -> bool {
    e.kind() == serialport::ErrorKind::NoDevice && e.description.contains("lock")
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_port_held_for_a_moment_opens_once_it_is_let_go() {
        let device = PtyDevice::start("test-pty", |_| Vec::new()).expect("a pty");
        let held = open(device.path(), 9600).expect("the first open");
        let letting_go = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(150));
            drop(held);
        });
        let started = std::time::Instant::now();
        let again = open(device.path(), 9600);
        let waited = started.elapsed();
        letting_go.join().expect("the thread that lets go");
        assert!(again.is_ok(), "{:?}", again.err());
        assert!(waited >= Duration::from_millis(100), "{waited:?}");
    }

    #[test]
    fn a_port_held_for_good_is_refused_after_the_busy_wait() {
        let device = PtyDevice::start("test-pty", |_| Vec::new()).expect("a pty");
        let _held = open(device.path(), 9600).expect("the first open");
        let started = std::time::Instant::now();
        let Err(e) = open(device.path(), 9600) else {
            panic!("a second open of a held port succeeded");
        };
        let waited = started.elapsed();
        assert!(is_busy(&e), "{e}");
        assert!(waited >= BUSY_WAIT, "{waited:?}");
        assert!(waited < BUSY_WAIT + Duration::from_secs(2), "{waited:?}");
    }

    #[test]
    fn a_missing_port_is_refused_at_once() {
        let started = std::time::Instant::now();
        let Err(e) = open("/dev/polnlos-no-such-port", 9600) else {
            panic!("a port that does not exist opened");
        };
        assert!(!is_busy(&e), "{e}");
        assert!(started.elapsed() < BUSY_WAIT, "{:?}", started.elapsed());
    }
}
