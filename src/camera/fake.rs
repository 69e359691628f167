//! The bench around the camera, and Aravis's GigE Vision fake camera set up to
//! show the wall image of a known hidden scene.
//!
//! A capture moves the bench to a (pose, polarizer angle) and, for dark frames,
//! turns the hidden scene off. On a real bench an operator (or a motorized
//! stage) does that; [`ManualBench`] only logs. [`FakeBench`] runs
//! `arv-fake-gv-camera`'s engine in this process on a loopback address and
//! fills each frame with the wall image of the selected block, rendered by the
//! numeric core through the pose's homography.

use std::collections::HashMap;
use std::ffi::c_void;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::Frame;

/// What a capture asks of the bench before acquiring.
pub trait Bench: Send + Sync {
    /// Puts the camera at `pose` with the polarizer at `polarizer_deg` (None: no polarizer).
    fn select(&self, pose: &str, polarizer_deg: Option<f64>);
    /// Turns the hidden scene on (captures) or off (dark frames).
    fn scene_on(&self, on: bool);
}

/// A bench set by hand: polnlos logs what the operator should have done.
pub struct ManualBench;

impl Bench for ManualBench {
    fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        tracing::info!(
            pose,
            ?polarizer_deg,
            "capture expects the camera at this pose and polarizer angle"
        );
    }
    fn scene_on(&self, on: bool) {
        tracing::info!(
            on,
            "capture expects the hidden scene switched {}",
            if on { "on" } else { "off" }
        );
    }
}

/// Key of a block: pose name and polarizer angle in millidegrees (None: no polarizer).
fn key(pose: &str, deg: Option<f64>) -> String {
    match deg {
        Some(d) => format!("{pose}@{}", (d * 1000.0).round() as i64),
        None => format!("{pose}@none"),
    }
}

/// State shared with the fill callback (which runs on Aravis's thread).
struct Shared {
    /// Wall frames per block, in fractions of full scale at the reference exposure.
    frames: HashMap<String, Frame>,
    selected: Mutex<Option<String>>,
    scene_on: AtomicBool,
    reference_exposure_us: f64,
    dark_level: f64,
    counter: AtomicU64,
}

/// Aravis's GigE Vision fake camera on a loopback address, showing a scene.
pub struct FakeBench {
    gv: Option<aravis::GvFakeCamera>,
    shared: *const Shared,
    address: String,
}

// The GvFakeCamera runs its own threads; the object itself is only started and
// stopped from the owner. `shared` is an `Arc` kept alive until drop.
unsafe impl Send for FakeBench {}
unsafe impl Sync for FakeBench {}

/// Why the fake camera could not start.
#[derive(Debug, thiserror::Error)]
pub enum FakeError {
    /// The fake camera did not come up on the address.
    #[error("Aravis fake camera did not start on {0}; is another fake camera (or arv-fake-gv-camera) using that address?")]
    NotRunning(String),
}

impl FakeBench {
    /// Starts a fake GigE Vision camera on `address` (e.g. `127.0.0.1`) showing
    /// `frames` (per pose name and polarizer angle, values in fractions of full
    /// scale at `reference_exposure_us`).
    pub fn start(
        address: &str,
        serial: &str,
        frames: Vec<(String, Option<f64>, Frame)>,
        reference_exposure_us: f64,
    ) -> Result<Self, FakeError> {
        let shared = Arc::new(Shared {
            frames: frames
                .into_iter()
                .map(|(p, d, f)| (key(&p, d), f))
                .collect(),
            selected: Mutex::new(None),
            scene_on: AtomicBool::new(true),
            reference_exposure_us,
            dark_level: 0.01,
            counter: AtomicU64::new(0),
        });
        let gv = aravis::GvFakeCamera::new(Some(address), Some(serial));
        let fake = gv
            .fake_camera()
            .ok_or_else(|| FakeError::NotRunning(address.to_string()))?;
        let ptr = Arc::into_raw(shared);
        // SAFETY: `ptr` stays valid until `Drop`, which clears the pattern first.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(
                aravis::glib::translate::ToGlibPtr::to_glib_none(&fake).0,
                Some(fill),
                ptr as *mut c_void,
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
        if !gv.is_running() {
            // SAFETY: the pattern was set with this pointer; reclaim it.
            drop(unsafe { Arc::from_raw(ptr) });
            return Err(FakeError::NotRunning(address.to_string()));
        }
        Ok(Self {
            gv: Some(gv),
            shared: ptr,
            address: address.to_string(),
        })
    }

    /// The address to open the camera at.
    pub fn address(&self) -> &str {
        &self.address
    }

    fn shared(&self) -> &Shared {
        // SAFETY: valid until drop.
        unsafe { &*self.shared }
    }
}

impl Bench for FakeBench {
    fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        if let Ok(mut s) = self.shared().selected.lock() {
            *s = Some(key(pose, polarizer_deg));
        }
    }
    fn scene_on(&self, on: bool) {
        self.shared().scene_on.store(on, Ordering::SeqCst);
    }
}

impl Drop for FakeBench {
    fn drop(&mut self) {
        if let Some(fake) = self.gv.as_ref().and_then(|g| g.fake_camera()) {
            // SAFETY: restores Aravis's own pattern before the data is freed.
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
unsafe extern "C" fn fill(
    buffer: *mut aravis_sys::ArvBuffer,
    data: *mut c_void,
    exposure_us: u32,
    gain: u32,
    format: aravis_sys::ArvPixelFormat,
) {
    let shared = &*(data as *const Shared);
    let w = aravis_sys::arv_buffer_get_image_width(buffer).max(0) as usize;
    let h = aravis_sys::arv_buffer_get_image_height(buffer).max(0) as usize;
    let ox = aravis_sys::arv_buffer_get_image_x(buffer).max(0) as usize;
    let oy = aravis_sys::arv_buffer_get_image_y(buffer).max(0) as usize;
    let mut size = 0usize;
    let ptr = aravis_sys::arv_buffer_get_data(buffer, &mut size);
    if ptr.is_null() || w == 0 || h == 0 {
        return;
    }
    // Bits per pixel are bits 16-23 of a GenICam pixel-format code (Mono8 0x01080001).
    let bpp = if ((format >> 16) & 0xff) > 8 { 2 } else { 1 };
    // `size` here is the received size, which Aravis 0.8 only sets after this
    // callback (0 now). The fake camera has already checked that the buffer
    // holds the full payload (width x height x bytes per pixel) before calling.
    let size = w * h * bpp;
    let bytes = std::slice::from_raw_parts_mut(ptr, size);
    let full = if bpp == 2 { 65535.0 } else { 255.0 };
    let scale =
        f64::from(exposure_us) / shared.reference_exposure_us * (1.0 + 0.1 * f64::from(gain));
    let selected = shared.selected.lock().ok().and_then(|s| s.clone());
    let frame = if shared.scene_on.load(Ordering::SeqCst) {
        selected.and_then(|k| shared.frames.get(&k))
    } else {
        None
    };
    let mut seed = shared
        .counter
        .fetch_add(1, Ordering::Relaxed)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        | 1;
    for y in 0..h {
        for x in 0..w {
            let signal = frame
                .and_then(|f| {
                    (x + ox < f.width && y + oy < f.height)
                        .then(|| f64::from(f.pixels[(y + oy) * f.width + x + ox]))
                })
                .unwrap_or(0.0);
            // xorshift dither of +-0.5 DN so that averaging frames means something.
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let dither = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            let v = ((shared.dark_level + signal) * scale * full + dither)
                .round()
                .clamp(0.0, full);
            let i = y * w + x;
            if bpp == 2 {
                let b = (v as u16).to_le_bytes();
                if 2 * i + 1 < size {
                    bytes[2 * i] = b[0];
                    bytes[2 * i + 1] = b[1];
                }
            } else if i < size {
                bytes[i] = v as u8;
            }
        }
    }
}
