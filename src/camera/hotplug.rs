//! USB3 Vision hot-plug through libusb: when a device with a USB3 Vision
//! interface (class 0xEF, subclass 0x05) arrives or leaves, the camera thread
//! is told to rescan at once instead of waiting for its backoff. On a machine
//! without USB (or without hot-plug support) this does nothing.

use std::ffi::c_void;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use libusb1_sys as usb;
use libusb1_sys::constants::*;

/// A running hot-plug watcher; stops when dropped.
pub struct Hotplug {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

struct Ctx(*mut usb::libusb_context);
// SAFETY: a libusb context may be used from any thread.
unsafe impl Send for Ctx {}

type Notify = Box<dyn Fn() + Send + Sync>;

fn is_usb3_vision(dev: *mut usb::libusb_device) -> bool {
    // SAFETY: `dev` comes from libusb for the duration of the callback. The
    // descriptor is libusb's own: `interface` holds `bNumInterfaces` entries
    // and each `altsetting` holds `num_altsetting` (both pointers checked for
    // null before use); it is freed once, after the last read.
    unsafe {
        let mut cfg: *const usb::libusb_config_descriptor = std::ptr::null();
        if usb::libusb_get_active_config_descriptor(dev, &mut cfg) != 0 || cfg.is_null() {
            return false;
        }
        let c = &*cfg;
        let mut found = false;
        let interfaces = if c.interface.is_null() {
            0
        } else {
            c.bNumInterfaces as usize
        };
        for i in 0..interfaces {
            let iface = &*c.interface.add(i);
            if iface.altsetting.is_null() {
                continue;
            }
            for a in 0..iface.num_altsetting.max(0) as usize {
                let alt = &*iface.altsetting.add(a);
                found |= alt.bInterfaceClass == 0xEF && alt.bInterfaceSubClass == 0x05;
            }
        }
        usb::libusb_free_config_descriptor(cfg);
        found
    }
}

extern "system" fn callback(
    _ctx: *mut usb::libusb_context,
    dev: *mut usb::libusb_device,
    event: usb::libusb_hotplug_event,
    data: *mut c_void,
) -> i32 {
    // SAFETY: `data` is the `Notify` boxed in `start`, alive while registered.
    let notify = unsafe { &*(data as *const Notify) };
    // A departing device has no readable descriptor any more: rescan on any leave.
    if event == LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT || is_usb3_vision(dev) {
        notify();
    }
    0
}

impl Hotplug {
    /// Starts watching; `None` (with a log line) when libusb or hot-plug is unavailable.
    pub fn start(notify: impl Fn() + Send + Sync + 'static) -> Option<Self> {
        // SAFETY: plain libusb calls; the context lives in the watcher thread.
        unsafe {
            if usb::libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG) == 0 {
                tracing::info!("libusb has no hot-plug support here; USB3 Vision cameras are found by the reconnect backoff");
                return None;
            }
            let mut ctx = std::ptr::null_mut();
            if usb::libusb_init(&mut ctx) != 0 {
                tracing::info!("libusb cannot start (no USB on this machine?); hot-plug disabled");
                return None;
            }
            let data: *mut Notify = Box::into_raw(Box::new(Box::new(notify)));
            let mut handle = 0;
            let rc = usb::libusb_hotplug_register_callback(
                ctx,
                LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED | LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT,
                LIBUSB_HOTPLUG_NO_FLAGS,
                LIBUSB_HOTPLUG_MATCH_ANY,
                LIBUSB_HOTPLUG_MATCH_ANY,
                LIBUSB_HOTPLUG_MATCH_ANY,
                callback,
                data as *mut c_void,
                &mut handle,
            );
            if rc != 0 {
                drop(Box::from_raw(data));
                usb::libusb_exit(ctx);
                tracing::info!("libusb hot-plug registration failed ({rc}); hot-plug disabled");
                return None;
            }
            let stop = Arc::new(AtomicBool::new(false));
            let s = stop.clone();
            let ctx = Ctx(ctx);
            let data = data as usize;
            let thread = std::thread::Builder::new()
                .name("usb-hotplug".into())
                .spawn(move || {
                    let ctx = ctx;
                    let tv = libc::timeval {
                        tv_sec: 0,
                        tv_usec: 200_000,
                    };
                    while !s.load(Ordering::Relaxed) {
                        usb::libusb_handle_events_timeout_completed(
                            ctx.0,
                            &tv,
                            std::ptr::null_mut(),
                        );
                    }
                    usb::libusb_hotplug_deregister_callback(ctx.0, handle);
                    usb::libusb_exit(ctx.0);
                    drop(Box::from_raw(data as *mut Notify));
                })
                .ok()?;
            Some(Self {
                stop,
                thread: Some(thread),
            })
        }
    }
}

impl Drop for Hotplug {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
