//! The Kinect v1 through libfreenect: depth (raw 11-bit disparity converted with
//! the device's registration data), colour and the accelerometer, plus the
//! fakenect recording format that libfreenect's playback library reads.
//!
//! - [`registration`]: the depth model (raw to metres, intrinsics) from the
//!   device's zero-plane data, as libfreenect computes it.
//! - [`convert`]: frames to organised clouds (the per-frame conversion) and
//!   clouds to frames (recording any camera as a Kinect).
//! - [`gravity`]: the accelerometer's gravity in the camera frame and the check
//!   of the calibrated mount against it.
//! - [`fakenect`]: reading and writing fakenect directories.
//! - `device` (feature `kinect`): the driver, [`device::Kinect`]; its FFI, all
//!   the `unsafe` of this module, is `ffi`.
//!
//! Stopping: dropping the driver stops the depth and colour streams and closes
//! the device and libfreenect's context; the tilt motor is never commanded.

pub mod convert;
#[cfg(feature = "kinect")]
pub mod device;
pub mod fakenect;
#[cfg(feature = "kinect")]
mod ffi;
pub mod gravity;
pub mod registration;

use std::path::PathBuf;

/// The udev rule that gives users access to the Kinect's USB devices.
pub const UDEV_RULE: &str = "/etc/udev/rules.d/51-kinect.rules with SUBSYSTEM==\"usb\", \
ATTR{idVendor}==\"045e\", ATTR{idProduct}==\"02ae|02b0|02ad\", MODE=\"0660\", GROUP=\"plugdev\"";

/// Errors of the Kinect driver and of fakenect recordings; each names the device,
/// file or call concerned and, for a missing device, what to check.
#[derive(Debug, thiserror::Error)]
pub enum KinectError {
    /// libfreenect could not be loaded.
    #[error(
        "libfreenect ({library}) could not be loaded: {detail}; install it (apt-get install \
         libfreenect-dev), or to play a recording set LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect \
         and FAKENECT_PATH=DIR"
    )]
    Library {
        /// The library's soname.
        library: &'static str,
        /// The loader's message.
        detail: String,
    },
    /// No Kinect at the configured index.
    #[error(
        "no Kinect found (device index {index}): check that it is plugged in with its own power \
         supply (lsusb lists 045e:02ae Xbox NUI Camera and 045e:02b0 Xbox NUI Motor) and that the \
         udev rule gives this user access ({UDEV_RULE}; then udevadm control --reload-rules and replug)"
    )]
    NoDevice {
        /// The device index asked for.
        index: i32,
    },
    /// A libfreenect call failed.
    #[error("libfreenect {function} failed with code {code} (USB access: check the udev rule, {UDEV_RULE})")]
    Driver {
        /// The function.
        function: &'static str,
        /// Its return value.
        code: i32,
    },
    /// The device stopped answering mid-run (unplugged; for fakenect, the recording ended).
    #[error("the Kinect vanished: {detail}")]
    Vanished {
        /// What the driver reported.
        detail: String,
    },
    /// No depth frame arrived within the frame timeout.
    #[error("the Kinect's frames stalled: no depth frame within {timeout_s} s")]
    Stalled {
        /// The timeout (s).
        timeout_s: f64,
    },
    /// A frame has the wrong size.
    #[error("{what}: {len} values, expected {expected}")]
    FrameSize {
        /// Which frame.
        what: &'static str,
        /// Its length.
        len: usize,
        /// The expected length.
        expected: usize,
    },
    /// A recording is malformed or in the way.
    #[error("recording {path}: {problem}")]
    Recording {
        /// The file or directory.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] crate::fsio::FileError),
}
