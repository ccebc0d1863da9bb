//! libfreenect, loaded at run time (`dlopen`): every `unsafe` of the Kinect driver
//! lives in this file.
//!
//! The library is opened by its soname, `libfreenect.so.0.5`, so the dynamic
//! loader's search (`LD_LIBRARY_PATH` first) picks the real driver or fakenect's
//! drop-in replacement (`/usr/lib/x86_64-linux-gnu/fakenect/`). Nothing links
//! against libfreenect at build time: a machine without it builds the `kinect`
//! feature and fails only when the backend starts, with a message saying what
//! to install. fakenect lacks the registration functions; they are looked up as
//! optional symbols. Closing the library ([`Library`]'s `Drop`) unloads it, which
//! also resets fakenect's playback, so reopening a device starts afresh.
//!
//! Frames arrive through C callbacks that libfreenect calls from inside
//! `freenect_process_events_timeout`, on the calling thread. The callbacks copy
//! them into the [`FrameSink`] the caller lends for the duration of that call
//! (a thread-local pointer), so no frame memory of libfreenect outlives its
//! callback and nothing is shared between threads.

use std::cell::Cell;
use std::ffi::{c_char, c_int, c_void, CStr};
use std::ptr::NonNull;

/// The soname of libfreenect 0.5 (the real driver and fakenect alike).
pub const LIBRARY: &str = "libfreenect.so.0.5";

/// `FREENECT_RESOLUTION_MEDIUM` (640 x 480).
const RESOLUTION_MEDIUM: c_int = 1;
/// `FREENECT_VIDEO_RGB`.
const VIDEO_RGB: c_int = 0;
/// `FREENECT_DEPTH_11BIT`.
const DEPTH_11BIT: c_int = 0;
/// `FREENECT_DEVICE_MOTOR | FREENECT_DEVICE_CAMERA` (the accelerometer is on the
/// motor's USB device).
const DEVICES_MOTOR_CAMERA: c_int = 0x01 | 0x02;
/// `FREENECT_LOG_ERROR`.
const LOG_ERROR: c_int = 1;

/// Bytes of one 640 x 480 frame of 16-bit depth.
pub const DEPTH_FRAME_BYTES: usize = 640 * 480 * 2;
/// Bytes of one 640 x 480 RGB frame.
pub const VIDEO_FRAME_BYTES: usize = 640 * 480 * 3;

/// `freenect_frame_mode` (24 bytes, passed by value).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct FrameMode {
    reserved: u32,
    resolution: c_int,
    format: i32,
    bytes: i32,
    width: i16,
    height: i16,
    data_bits_per_pixel: i8,
    padding_bits_per_pixel: i8,
    framerate: i8,
    is_valid: i8,
}

/// `freenect_raw_tilt_state`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct RawTiltState {
    accelerometer_x: i16,
    accelerometer_y: i16,
    accelerometer_z: i16,
    tilt_angle: i8,
    tilt_status: c_int,
}

/// `freenect_zero_plane_info`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct ZeroPlaneInfo {
    dcmos_emitter_dist: f32,
    dcmos_rcmos_dist: f32,
    reference_distance: f32,
    reference_pixel_size: f32,
}

/// `freenect_registration`: 29 `int32_t` of `freenect_reg_info`, the three
/// `uint16_t` of `freenect_reg_pad_info`, the zero plane, the constant shift and
/// three tables owned by libfreenect (freed by `freenect_destroy_registration`).
#[repr(C)]
struct RawRegistration {
    reg_info: [i32; 29],
    reg_pad_info: [u16; 3],
    zero_plane_info: ZeroPlaneInfo,
    const_shift: f64,
    raw_to_mm_shift: *mut u16,
    depth_to_rgb_shift: *mut i32,
    registration_table: *mut c_void,
}

type Context = c_void;
type Device = c_void;
type FrameCallback = extern "C" fn(*mut Device, *mut c_void, u32);

/// The functions used, resolved from the library.
#[derive(Clone, Copy)]
struct Api {
    init: unsafe extern "C" fn(*mut *mut Context, *mut c_void) -> c_int,
    shutdown: unsafe extern "C" fn(*mut Context) -> c_int,
    set_log_level: unsafe extern "C" fn(*mut Context, c_int),
    select_subdevices: unsafe extern "C" fn(*mut Context, c_int),
    num_devices: unsafe extern "C" fn(*mut Context) -> c_int,
    open_device: unsafe extern "C" fn(*mut Context, *mut *mut Device, c_int) -> c_int,
    close_device: unsafe extern "C" fn(*mut Device) -> c_int,
    set_depth_callback: unsafe extern "C" fn(*mut Device, FrameCallback),
    set_video_callback: unsafe extern "C" fn(*mut Device, FrameCallback),
    find_depth_mode: unsafe extern "C" fn(c_int, c_int) -> FrameMode,
    find_video_mode: unsafe extern "C" fn(c_int, c_int) -> FrameMode,
    set_depth_mode: unsafe extern "C" fn(*mut Device, FrameMode) -> c_int,
    set_video_mode: unsafe extern "C" fn(*mut Device, FrameMode) -> c_int,
    start_depth: unsafe extern "C" fn(*mut Device) -> c_int,
    start_video: unsafe extern "C" fn(*mut Device) -> c_int,
    stop_depth: unsafe extern "C" fn(*mut Device) -> c_int,
    stop_video: unsafe extern "C" fn(*mut Device) -> c_int,
    process_events_timeout: unsafe extern "C" fn(*mut Context, *mut libc::timeval) -> c_int,
    update_tilt_state: unsafe extern "C" fn(*mut Device) -> c_int,
    get_tilt_state: unsafe extern "C" fn(*mut Device) -> *mut RawTiltState,
    copy_registration: Option<unsafe extern "C" fn(*mut Device) -> RawRegistration>,
    destroy_registration: Option<unsafe extern "C" fn(*mut RawRegistration) -> c_int>,
}

/// Why the library or the device could not be used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FfiError {
    /// `dlopen` failed (the library is not installed, or not on the search path).
    Load(String),
    /// A required function is missing from the library.
    Symbol(&'static str),
    /// A libfreenect call returned an error code.
    Call {
        /// The function.
        function: &'static str,
        /// Its return value.
        code: i32,
    },
    /// No Kinect on the bus.
    NoDevice,
}

/// The dynamically loaded libfreenect.
pub struct Library {
    handle: NonNull<c_void>,
    api: Api,
}

impl std::fmt::Debug for Library {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Library")
            .field("registration", &self.api.copy_registration.is_some())
            .finish()
    }
}

/// A function pointer of type `F` from a symbol's address.
///
/// # Safety
/// `p` must be the address of a function whose C signature `F` restates.
unsafe fn fn_from_symbol<F: Copy>(p: *mut c_void) -> F {
    assert_eq!(
        std::mem::size_of::<F>(),
        std::mem::size_of::<*mut c_void>(),
        "a function pointer type"
    );
    // SAFETY: same size (checked); the caller vouches for the signature.
    unsafe { std::mem::transmute_copy(&p) }
}

fn dl_error() -> String {
    // SAFETY: dlerror returns NULL or a NUL-terminated string valid until the next
    // dl* call on this thread; it is copied at once.
    unsafe {
        let e = libc::dlerror();
        if e.is_null() {
            "unknown dlopen error".to_string()
        } else {
            CStr::from_ptr(e).to_string_lossy().into_owned()
        }
    }
}

impl Library {
    /// Opens `path`, or [`LIBRARY`] by the loader's search, and resolves the
    /// functions.
    pub fn open(path: Option<&std::path::Path>) -> Result<Library, FfiError> {
        use std::os::unix::ffi::OsStrExt;
        let name = match path {
            Some(p) => std::ffi::CString::new(p.as_os_str().as_bytes()),
            None => std::ffi::CString::new(LIBRARY),
        }
        .map_err(|e| FfiError::Load(e.to_string()))?;
        // SAFETY: `name` is a valid C string; loading libfreenect runs no
        // initialisers with preconditions (it has no constructors that need
        // arguments); RTLD_LOCAL keeps its symbols out of the global namespace.
        let handle = unsafe { libc::dlopen(name.as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
        let handle = NonNull::new(handle).ok_or_else(|| FfiError::Load(dl_error()))?;
        let lookup = |symbol: &'static str| -> Option<*mut c_void> {
            let c = std::ffi::CString::new(symbol).ok()?;
            // SAFETY: `handle` is a live handle from dlopen, `c` a valid C string.
            let p = unsafe { libc::dlsym(handle.as_ptr(), c.as_ptr() as *const c_char) };
            (!p.is_null()).then_some(p)
        };
        macro_rules! required {
            ($name:literal) => {{
                let Some(p) = lookup($name) else {
                    // SAFETY: the handle came from dlopen and is closed once.
                    unsafe { libc::dlclose(handle.as_ptr()) };
                    return Err(FfiError::Symbol($name));
                };
                // SAFETY: the symbol is the libfreenect 0.5 function of this name,
                // whose C signature (libfreenect.h) the field's type restates.
                unsafe { fn_from_symbol(p) }
            }};
        }
        macro_rules! optional {
            ($name:literal) => {
                // SAFETY: as for `required!`.
                lookup($name).map(|p| unsafe { fn_from_symbol(p) })
            };
        }
        let api = Api {
            init: required!("freenect_init"),
            shutdown: required!("freenect_shutdown"),
            set_log_level: required!("freenect_set_log_level"),
            select_subdevices: required!("freenect_select_subdevices"),
            num_devices: required!("freenect_num_devices"),
            open_device: required!("freenect_open_device"),
            close_device: required!("freenect_close_device"),
            set_depth_callback: required!("freenect_set_depth_callback"),
            set_video_callback: required!("freenect_set_video_callback"),
            find_depth_mode: required!("freenect_find_depth_mode"),
            find_video_mode: required!("freenect_find_video_mode"),
            set_depth_mode: required!("freenect_set_depth_mode"),
            set_video_mode: required!("freenect_set_video_mode"),
            start_depth: required!("freenect_start_depth"),
            start_video: required!("freenect_start_video"),
            stop_depth: required!("freenect_stop_depth"),
            stop_video: required!("freenect_stop_video"),
            process_events_timeout: required!("freenect_process_events_timeout"),
            update_tilt_state: required!("freenect_update_tilt_state"),
            get_tilt_state: required!("freenect_get_tilt_state"),
            copy_registration: optional!("freenect_copy_registration"),
            destroy_registration: optional!("freenect_destroy_registration"),
        };
        Ok(Library { handle, api })
    }
}

impl Drop for Library {
    fn drop(&mut self) {
        // SAFETY: the handle came from dlopen and is closed exactly once; a
        // `Session` owns its library and closes its device before the library
        // is dropped (fields drop after `Session::drop`).
        unsafe { libc::dlclose(self.handle.as_ptr()) };
    }
}

/// Where the callbacks put the frames (lent for one `process_events` call).
#[derive(Debug, Default)]
pub struct FrameSink {
    /// The latest depth frame (640 x 480 raw values).
    pub depth: Vec<u16>,
    /// Depth frames received so far.
    pub depth_frames: u64,
    /// The latest depth frame's device timestamp.
    pub depth_timestamp: u32,
    /// The latest colour frame (640 x 480 x 3 bytes).
    pub rgb: Vec<u8>,
    /// Colour frames received so far.
    pub rgb_frames: u64,
}

thread_local! {
    static SINK: Cell<*mut FrameSink> = const { Cell::new(std::ptr::null_mut()) };
}

extern "C" fn on_depth(_dev: *mut Device, data: *mut c_void, timestamp: u32) {
    let sink = SINK.with(Cell::get);
    if sink.is_null() || data.is_null() {
        return;
    }
    // SAFETY: `sink` is the `&mut FrameSink` that `Session::process_events` lent
    // for this call on this thread (cleared before it returns); `data` points to
    // a depth frame of the mode set at start (11-bit, 640 x 480 native `u16`),
    // valid for the duration of the callback. It is read as bytes: fakenect's
    // frame follows the PGM header, so it need not be aligned for `u16`.
    unsafe {
        let sink = &mut *sink;
        let frame = std::slice::from_raw_parts(data as *const u8, DEPTH_FRAME_BYTES);
        sink.depth.clear();
        sink.depth.extend(
            frame
                .chunks_exact(2)
                .map(|b| u16::from_ne_bytes([b[0], b[1]])),
        );
        sink.depth_frames += 1;
        sink.depth_timestamp = timestamp;
    }
}

extern "C" fn on_video(_dev: *mut Device, data: *mut c_void, _timestamp: u32) {
    let sink = SINK.with(Cell::get);
    if sink.is_null() || data.is_null() {
        return;
    }
    // SAFETY: as in `on_depth`; `data` is an RGB frame of 640 x 480 x 3 bytes.
    unsafe {
        let sink = &mut *sink;
        let frame = std::slice::from_raw_parts(data as *const u8, VIDEO_FRAME_BYTES);
        sink.rgb.clear();
        sink.rgb.extend_from_slice(frame);
        sink.rgb_frames += 1;
    }
}

/// An open device with its depth (11-bit) and, when asked, colour streams running.
pub struct Session {
    lib: Library,
    ctx: *mut Context,
    dev: *mut Device,
    video: bool,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("video", &self.video)
            .finish()
    }
}

/// The registration data libfreenect reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceRegistration {
    /// `dcmos_emitter_dist`, `dcmos_rcmos_dist`, `reference_distance`,
    /// `reference_pixel_size`.
    pub zero_plane: [f64; 4],
    /// `const_shift`.
    pub const_shift: f64,
}

impl Session {
    /// Initialises libfreenect, opens device `index` and starts its depth stream
    /// (and colour stream when `video`).
    pub fn open(lib: Library, index: i32, video: bool) -> Result<Session, FfiError> {
        let api = lib.api;
        let mut ctx: *mut Context = std::ptr::null_mut();
        // SAFETY: `ctx` is a valid out pointer; a NULL usb context asks
        // libfreenect for its own.
        let rc = unsafe { (api.init)(&mut ctx, std::ptr::null_mut()) };
        if rc < 0 || ctx.is_null() {
            return Err(FfiError::Call {
                function: "freenect_init",
                code: rc,
            });
        }
        let mut session = Session {
            lib,
            ctx,
            dev: std::ptr::null_mut(),
            video,
        };
        // SAFETY: `ctx` is the live context from freenect_init (until `Drop`).
        let count = unsafe {
            (api.set_log_level)(ctx, LOG_ERROR);
            (api.select_subdevices)(ctx, DEVICES_MOTOR_CAMERA);
            (api.num_devices)(ctx)
        };
        if count <= index {
            return Err(FfiError::NoDevice);
        }
        let mut dev: *mut Device = std::ptr::null_mut();
        // SAFETY: live context, valid out pointer.
        let rc = unsafe { (api.open_device)(ctx, &mut dev, index) };
        if rc < 0 || dev.is_null() {
            return Err(FfiError::Call {
                function: "freenect_open_device",
                code: rc,
            });
        }
        session.dev = dev;
        // SAFETY: `dev` is the live device; the modes come from the library's
        // own tables for the medium resolution, which every version supports
        // (fakenect 0.5 asserts on anything but 11-bit depth and RGB).
        unsafe {
            (api.set_depth_callback)(dev, on_depth);
            let mode = (api.find_depth_mode)(RESOLUTION_MEDIUM, DEPTH_11BIT);
            check("freenect_set_depth_mode", (api.set_depth_mode)(dev, mode))?;
            if video {
                (api.set_video_callback)(dev, on_video);
                let mode = (api.find_video_mode)(RESOLUTION_MEDIUM, VIDEO_RGB);
                check("freenect_set_video_mode", (api.set_video_mode)(dev, mode))?;
            }
            check("freenect_start_depth", (api.start_depth)(dev))?;
            if video {
                check("freenect_start_video", (api.start_video)(dev))?;
            }
        }
        Ok(session)
    }

    /// Handles the USB events pending within `timeout_s` (fakenect: plays one
    /// record), delivering frames into `sink`. An error means the device is gone
    /// (fakenect: the recording ended).
    pub fn process_events(&mut self, sink: &mut FrameSink, timeout_s: f64) -> Result<(), FfiError> {
        let mut tv = libc::timeval {
            tv_sec: timeout_s.trunc() as libc::time_t,
            tv_usec: (timeout_s.fract() * 1e6) as libc::suseconds_t,
        };
        SINK.with(|s| s.set(sink as *mut FrameSink));
        // SAFETY: live context; the callbacks it runs only touch `sink` through
        // the thread-local pointer, which is cleared right after.
        let rc = unsafe { (self.lib.api.process_events_timeout)(self.ctx, &mut tv) };
        SINK.with(|s| s.set(std::ptr::null_mut()));
        check("freenect_process_events_timeout", rc)
    }

    /// The accelerometer's latest reading (counts x, y, z).
    pub fn accelerometer(&mut self) -> Result<[i16; 3], FfiError> {
        // SAFETY: live device; libfreenect returns a pointer into the device
        // (fakenect: a static) valid until the next update, read at once.
        unsafe {
            check(
                "freenect_update_tilt_state",
                (self.lib.api.update_tilt_state)(self.dev),
            )?;
            let state = (self.lib.api.get_tilt_state)(self.dev);
            if state.is_null() {
                return Err(FfiError::Call {
                    function: "freenect_get_tilt_state",
                    code: 0,
                });
            }
            let s = *state;
            Ok([s.accelerometer_x, s.accelerometer_y, s.accelerometer_z])
        }
    }

    /// The device's registration data, when the library reports it.
    pub fn registration(&mut self) -> Option<DeviceRegistration> {
        let (copy, destroy) = (
            self.lib.api.copy_registration?,
            self.lib.api.destroy_registration?,
        );
        // SAFETY: live device; the copy owns three tables that
        // freenect_destroy_registration frees, after the plain values are read.
        unsafe {
            let mut reg = copy(self.dev);
            let z = reg.zero_plane_info;
            let out = DeviceRegistration {
                zero_plane: [
                    f64::from(z.dcmos_emitter_dist),
                    f64::from(z.dcmos_rcmos_dist),
                    f64::from(z.reference_distance),
                    f64::from(z.reference_pixel_size),
                ],
                const_shift: reg.const_shift,
            };
            destroy(&mut reg);
            Some(out)
        }
    }
}

fn check(function: &'static str, code: c_int) -> Result<(), FfiError> {
    if code < 0 {
        Err(FfiError::Call { function, code })
    } else {
        Ok(())
    }
}

impl Drop for Session {
    /// Stops the streams, closes the device and the context: the Kinect stops
    /// streaming (its IR projector turns off); the motor is not moved.
    fn drop(&mut self) {
        let api = &self.lib.api;
        // SAFETY: `dev` and `ctx` are live (or NULL, skipped) and released once.
        unsafe {
            if !self.dev.is_null() {
                (api.stop_depth)(self.dev);
                if self.video {
                    (api.stop_video)(self.dev);
                }
                (api.close_device)(self.dev);
            }
            (api.shutdown)(self.ctx);
        }
    }
}
