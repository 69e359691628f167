//! Aravis's GigE Vision fake camera set up to show the wall image of a
//! known hidden scene, and the bench around it ([`FakeBench`], the rig's
//! [`Bench`] for the fake camera).
//!
//! A capture moves the bench to a (pose, polarizer angle) and, for dark frames,
//! turns the hidden scene off. [`FakeBench`] runs `arv-fake-gv-camera`'s
//! engine in this process on a loopback address and fills each frame with
//! the wall image of the selected block, rendered by the numeric core
//! through the pose's homography; a bench set by hand is the rig's
//! `ManualBench`.

use std::ffi::c_void;
use std::sync::Arc;

use super::shown::{BenchImages, Shown};
use crate::rig::bench::Bench;

/// State shared with the fill callback (which runs on Aravis's thread).
struct Shared {
    /// What the bench shows.
    shown: Shown,
    /// The `ArvFakeCamera` whose buffers the callback fills (owned by the
    /// `GvFakeCamera`, alive until [`FakeBench`]'s drop clears the callback).
    camera: *mut aravis_sys::ArvFakeCamera,
}

// SAFETY: `camera` is only passed to `arv_fake_camera_get_payload`, which
// reads registers and may be called from any thread; everything else in
// `Shared` is Sync.
unsafe impl Sync for Shared {}
// SAFETY: as above; the pointer does not own anything.
unsafe impl Send for Shared {}

/// The sensor the fake camera plays (`[camera] fake_sensor`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FakeSensor {
    /// A monochrome sensor (Aravis's own fake camera).
    #[default]
    Mono,
    /// A Sony Polarsens polarizer-mosaic sensor presenting itself as Lucid's
    /// cameras do (PixelFormat `PolarizeMono8`, `PolarizeMono16`), its
    /// 0-degree micro-polarizers at crossed, ideal.
    Polarsens,
    /// A colour sensor behind an RGGB Bayer filter, read out raw
    /// (`BayerRG16`, also `BayerRG8`): each pixel sees the wall through its
    /// colour's filter (`BAYER_RESPONSE` in `camera/shown.rs`).
    Bayer,
}

/// Aravis's own fake-camera description (0.8.26) with Lucid's two
/// polarization formats added (`PolarizeMono8` 0x81080001,
/// `PolarizeMono16` 0x81100007): the fake camera then lists, sets and reads
/// them back like any format, and its payload follows their bit depth.
const POLARSENS_XML: &str = include_str!("fake_polarsens.xml");

/// Aravis's own fake-camera description (0.8.26) with `BayerRG16`
/// (0x01100011) added beside its 8-bit Bayer formats.
const BAYER_XML: &str = include_str!("fake_bayer.xml");

/// `BayerRG16`'s GenICam value (PFNC).
const BAYER_RG16: u32 = 0x0110_0011;

/// The fake camera's PixelFormat register (Aravis `ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT`).
const PIXEL_FORMAT_REGISTER: u32 = 0x128;

/// `PolarizeMono16`'s GenICam value (Lucid Arena SDK).
const POLARIZE_MONO16: u32 = 0x8110_0007;

/// Aravis's GigE Vision fake camera on a loopback address, showing a scene.
pub struct FakeBench {
    gv: Option<aravis::GvFakeCamera>,
    shared: *const Shared,
    address: String,
    switches_scene: bool,
}

/// A file removed when this is dropped (also on an early error return).
struct Removed(std::path::PathBuf);

impl Drop for Removed {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

// SAFETY: the GvFakeCamera runs its own threads; the object itself is only
// started, stopped and given a packet-loss ratio from the owner (`&mut self`). `shared` is an `Arc` of a Sync type kept
// alive until drop, and only read through `&`.
unsafe impl Send for FakeBench {}
// SAFETY: as above.
unsafe impl Sync for FakeBench {}

/// The GigE Vision control port (GVCP) a fake camera answers on.
pub(crate) const GVCP_PORT: u16 = 3956;

/// Why the fake camera could not start.
#[derive(Debug, thiserror::Error)]
pub enum FakeError {
    /// Another device already answers on the address's control port: a
    /// second fake camera there would start, and the daemon would then talk
    /// to the first one's.
    #[error("another GigE Vision camera already answers on {address}:{GVCP_PORT} (a second polnlos, or arv-fake-gv-camera): this daemon's fake camera would talk to it. Give this daemon its own loopback address, [camera] address = \"127.0.0.2\" (after `ip addr add 127.0.0.2/8 dev lo`), or stop the other one")]
    AddressInUse {
        /// The address asked for.
        address: String,
    },
    /// No network interface holds the address: Linux answers all of
    /// 127.0.0.0/8 on `lo`, but Aravis's fake camera listens only on an
    /// address an interface has.
    #[error("no network interface has the address {address}, and Aravis's fake camera listens only on an interface's own address: add it (`sudo ip addr add {address}/8 dev lo`, for a loopback address), or set [camera] address to one `ip -brief addr` lists, such as 127.0.0.1")]
    NotOnInterface {
        /// The address asked for.
        address: String,
    },
    /// The fake camera did not come up on the address.
    #[error("Aravis fake camera did not start on {0}; is another fake camera (or arv-fake-gv-camera) using that address?")]
    NotRunning(String),
    /// The Polarsens fake camera's description could not be written.
    #[error("could not write the Polarsens fake camera's description to the temporary directory ({0}); set TMPDIR to a writable directory")]
    Description(String),
}

/// Whether a network interface of this machine holds `address` (IPv4), or
/// None when the interfaces cannot be listed.
pub fn interface_has(address: std::net::Ipv4Addr) -> Option<bool> {
    let mut list: *mut libc::ifaddrs = std::ptr::null_mut();
    // SAFETY: getifaddrs writes a list head into `list` (a valid place) and
    // returns 0, or returns -1 and writes nothing usable.
    if unsafe { libc::getifaddrs(&mut list) } != 0 {
        return None;
    }
    let mut found = false;
    let mut node = list;
    while !node.is_null() {
        // SAFETY: `node` is a non-null element of the list getifaddrs made,
        // alive until freeifaddrs below; its fields are only read.
        let (addr, next) = unsafe { ((*node).ifa_addr, (*node).ifa_next) };
        // SAFETY: a non-null `ifa_addr` points to a sockaddr whose family
        // says its type; it is read as a sockaddr_in only for AF_INET.
        if !addr.is_null() && i32::from(unsafe { (*addr).sa_family }) == libc::AF_INET {
            // SAFETY: as above: the family is AF_INET, so it is a sockaddr_in.
            let sin = unsafe { &*(addr as *const libc::sockaddr_in) };
            if u32::from_be(sin.sin_addr.s_addr) == u32::from(address) {
                found = true;
            }
        }
        node = next;
    }
    // SAFETY: `list` came from a successful getifaddrs and is freed once;
    // no pointer into it is used after this.
    unsafe { libc::freeifaddrs(list) };
    Some(found)
}

impl FakeBench {
    /// Starts a fake GigE Vision camera on `address` (e.g. `127.0.0.1`) showing
    /// `frames` (per pose name and polarizer angle, values in fractions of full
    /// scale at `reference_exposure_us`).
    pub fn start(
        address: &str,
        serial: &str,
        images: BenchImages,
        reference_exposure_us: f64,
    ) -> Result<Self, FakeError> {
        Self::start_with(
            address,
            serial,
            images,
            reference_exposure_us,
            FakeSensor::Mono,
        )
    }

    /// [`FakeBench::start`] with the camera playing `sensor`: a Polarsens
    /// one offers the polarization formats, starts in `PolarizeMono16` and
    /// shows every pixel through its own micro-polarizer.
    pub fn start_with(
        address: &str,
        serial: &str,
        images: BenchImages,
        reference_exposure_us: f64,
        sensor: FakeSensor,
    ) -> Result<Self, FakeError> {
        if let Ok(ip) = address.parse::<std::net::Ipv4Addr>() {
            if interface_has(ip) == Some(false) {
                return Err(FakeError::NotOnInterface {
                    address: address.to_string(),
                });
            }
        }
        // Aravis would start a second fake camera on a port in use; a plain
        // bind (no SO_REUSEADDR) fails there, and is released at once.
        if let Err(e) = std::net::UdpSocket::bind((address, GVCP_PORT)) {
            if e.kind() == std::io::ErrorKind::AddrInUse {
                return Err(FakeError::AddressInUse {
                    address: address.to_string(),
                });
            }
        }
        let xml = match sensor {
            FakeSensor::Mono => None,
            FakeSensor::Polarsens => Some(("polarsens", POLARSENS_XML)),
            FakeSensor::Bayer => Some(("bayer", BAYER_XML)),
        };
        let description = match xml {
            None => None,
            Some((name, xml)) => {
                let path = std::env::temp_dir().join(format!(
                    "polnlos-fake-{name}-{}-{serial}.xml",
                    std::process::id()
                ));
                std::fs::write(&path, xml)
                    .map_err(|e| FakeError::Description(format!("{}: {e}", path.display())))?;
                Some(Removed(path))
            }
        };
        let gv = match description.as_ref().and_then(|p| p.0.to_str()) {
            Some(path) => aravis::GvFakeCamera::new_full(Some(address), Some(serial), Some(path)),
            None => aravis::GvFakeCamera::new(Some(address), Some(serial)),
        };
        let fake = gv
            .fake_camera()
            .ok_or_else(|| FakeError::NotRunning(address.to_string()))?;
        // Aravis read the whole description when it made the fake camera
        // (`arv_fake_camera_new_full`'s g_file_get_contents): the file goes
        // now, so a daemon that is killed leaves none in the temporary folder.
        drop(description);
        let camera: *mut aravis_sys::ArvFakeCamera =
            aravis::glib::translate::ToGlibPtr::to_glib_none(&fake).0;
        let (format, mosaic, bayer) = match sensor {
            FakeSensor::Mono => (None, None, None),
            FakeSensor::Polarsens => (
                Some(POLARIZE_MONO16),
                Some(crate::scene::MosaicLayout::Polarsens),
                None,
            ),
            FakeSensor::Bayer => (
                Some(BAYER_RG16),
                None,
                Some(crate::measure::colour::BayerPattern::RG),
            ),
        };
        if let Some(format) = format {
            // SAFETY: `camera` is the live fake camera of `gv`; writing one
            // of its registers only changes its register memory.
            unsafe {
                aravis_sys::arv_fake_camera_write_register(camera, PIXEL_FORMAT_REGISTER, format);
            }
        }
        let shared = Arc::new(Shared {
            shown: Shown::new(images, reference_exposure_us)
                .with_mosaic(mosaic)
                .with_bayer(bayer),
            camera,
        });
        let ptr = Arc::into_raw(shared);
        // SAFETY: `camera` is the live fake camera of `gv`; `ptr` stays valid
        // until `Drop`, which restores Aravis's own pattern (under Aravis's
        // fill mutex, so no callback is running) before freeing it.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(camera, Some(fill), ptr as *mut c_void);
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
        if !gv.is_running() {
            // SAFETY: restore Aravis's pattern (no call with `ptr` runs after
            // this returns), then reclaim the Arc made by `into_raw` above.
            unsafe {
                aravis_sys::arv_fake_camera_set_fill_pattern(camera, None, std::ptr::null_mut());
            }
            drop(unsafe { Arc::from_raw(ptr) });
            return Err(FakeError::NotRunning(address.to_string()));
        }
        Ok(Self {
            gv: Some(gv),
            shared: ptr,
            address: address.to_string(),
            switches_scene: true,
        })
    }

    /// Gives the camera a sensor's shot and read noise (see
    /// `Shown::set_sensor_noise`); without it its frames carry only dither.
    pub fn with_sensor_noise(self, full_well_e: f64, read_noise_e: f64) -> Self {
        self.shared()
            .shown
            .set_sensor_noise(full_well_e, read_noise_e);
        self
    }

    /// Plays a bench whose hidden scene an operator switches by hand: dark
    /// frames then need an explicit dark capture (the scene stays lit unless
    /// a dark capture asks for it).
    pub fn operated_by_hand(mut self) -> Self {
        self.switches_scene = false;
        self
    }

    /// Drops this fraction of the stream's packets (0 to 1), as a lossy
    /// link or an overloaded switch would: the capture path's handling of
    /// broken frames is then testable on loopback.
    pub fn lose_packets(&mut self, ratio: f64) {
        if let Some(gv) = &self.gv {
            gv.set_gvsp_lost_ratio(ratio.clamp(0.0, 1.0));
        }
    }

    /// The address to open the camera at.
    pub fn address(&self) -> &str {
        &self.address
    }

    fn shared(&self) -> &Shared {
        // SAFETY: `shared` came from `Arc::into_raw` in `start` and is freed
        // only in drop, after which `self` is gone.
        unsafe { &*self.shared }
    }
}

impl Bench for FakeBench {
    fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        self.shared().shown.select(pose, polarizer_deg);
    }
    fn scene_on(&self, on: bool) {
        self.shared().shown.scene_on(on);
    }
    fn show_target(&self, on: bool) {
        self.shared().shown.show_target(on);
    }
    fn show_source(&self, on: bool) {
        self.shared().shown.show_source(on);
    }
    fn switches_scene(&self) -> bool {
        self.switches_scene
    }
}

impl Drop for FakeBench {
    fn drop(&mut self) {
        if let Some(fake) = self.gv.as_ref().and_then(|g| g.fake_camera()) {
            // SAFETY: restores Aravis's own pattern before the data is freed;
            // Aravis swaps it under the mutex it holds while calling `fill`,
            // so no call with the old data is running when this returns.
            unsafe {
                aravis_sys::arv_fake_camera_set_fill_pattern(
                    aravis::glib::translate::ToGlibPtr::to_glib_none(&fake).0,
                    None,
                    std::ptr::null_mut(),
                );
            }
        }
        // Stop the camera threads before freeing what the callback reads.
        drop(self.gv.take());
        // SAFETY: created by Arc::into_raw in `start`.
        drop(unsafe { Arc::from_raw(self.shared) });
    }
}

/// Aravis fill-pattern callback: writes the selected block's wall image.
///
/// # Safety
/// Called by Aravis only, with the `Shared` registered in [`FakeBench::start`]
/// as `data` and a buffer of at least `arv_fake_camera_get_payload` bytes.
unsafe extern "C" fn fill(
    buffer: *mut aravis_sys::ArvBuffer,
    data: *mut c_void,
    exposure_us: u32,
    gain: u32,
    format: aravis_sys::ArvPixelFormat,
) {
    if buffer.is_null() || data.is_null() {
        return;
    }
    // SAFETY: `data` is the `Shared` registered with this callback, alive
    // until the callback is unregistered (see `FakeBench`'s drop).
    let shared = unsafe { &*(data as *const Shared) };
    // SAFETY: `buffer` is the non-null buffer Aravis is filling; these getters only read it.
    let (w, h, ox, oy) = unsafe {
        (
            aravis_sys::arv_buffer_get_image_width(buffer),
            aravis_sys::arv_buffer_get_image_height(buffer),
            aravis_sys::arv_buffer_get_image_x(buffer),
            aravis_sys::arv_buffer_get_image_y(buffer),
        )
    };
    let mut received = 0usize;
    // SAFETY: as above; `received` is a valid place for the size.
    let ptr = unsafe { aravis_sys::arv_buffer_get_data(buffer, &mut received) };
    // The bound on what may be written: Aravis 0.8 sets the received size only
    // after this callback (0 now), and has checked just before calling that the
    // buffer holds at least the payload it computes from the Width, Height and
    // PixelFormat registers (in 32-bit arithmetic, which can wrap for a huge
    // region: then the payload is small and nothing is written).
    // SAFETY: `camera` is the live fake camera that owns this callback.
    let payload = unsafe { aravis_sys::arv_fake_camera_get_payload(shared.camera) };
    let capacity = if received > 0 {
        received.min(payload)
    } else {
        payload
    };
    // Bits per pixel are bits 16-23 of a GenICam pixel-format code (Mono8 0x01080001).
    let bpp: usize = if ((format >> 16) & 0xff) > 8 { 2 } else { 1 };
    let dims = (
        usize::try_from(w),
        usize::try_from(h),
        usize::try_from(ox),
        usize::try_from(oy),
    );
    let (Ok(w), Ok(h), Ok(ox), Ok(oy)) = dims else {
        return;
    };
    let needed = w.checked_mul(h).and_then(|p| p.checked_mul(bpp));
    let Some(needed) = needed.filter(|&n| n > 0 && n <= capacity) else {
        return;
    };
    if ptr.is_null() {
        return;
    }
    // SAFETY: `ptr` is the buffer's data and `needed <= capacity`, the number
    // of bytes Aravis guarantees it holds; the slice lives only for this call,
    // during which Aravis does not touch the buffer.
    let bytes = unsafe { std::slice::from_raw_parts_mut(ptr, needed) };
    // A panic must not unwind into C: it would abort the daemon.
    let filled = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        render(shared, bytes, (w, h, ox, oy), bpp, exposure_us, gain)
    }));
    if filled.is_err() {
        bytes.fill(0);
    }
}

/// Writes the selected block's image (or the dark level) into `bytes`, which
/// holds exactly `w * h * bpp` bytes.
fn render(
    shared: &Shared,
    bytes: &mut [u8],
    geometry: (usize, usize, usize, usize),
    bpp: usize,
    exposure_us: u32,
    gain: u32,
) {
    let full = if bpp == 2 { 65535.0 } else { 255.0 };
    let put = |i: usize, v: f64| {
        if bpp == 2 {
            if let Some(px) = bytes.get_mut(2 * i..2 * i + 2) {
                px.copy_from_slice(&(v as u16).to_le_bytes());
            }
        } else if let Some(px) = bytes.get_mut(i) {
            *px = v as u8;
        }
    };
    shared
        .shown
        .expose(geometry, full, f64::from(exposure_us), f64::from(gain), put);
}
