//! The Kinect driver: opens the device (or fakenect's playback), grabs snapshots
//! (depth, colour when asked, the accelerometer) with a frame timeout, and
//! converts them to organised clouds in the camera optical frame.

use super::convert::{depth_to_cloud, DepthEncoding};
use super::ffi::{FfiError, FrameSink, Library, Session, LIBRARY};
use super::gravity::AccelCounts;
use super::registration::{KinectIntrinsics, Registration, ZeroPlane, FRAME_HEIGHT, FRAME_WIDTH};
use super::{fakenect, KinectError};
use crate::cloud::PointCloud;
use std::time::{Duration, Instant};

/// How the driver is used.
#[derive(Debug, Clone, PartialEq)]
pub struct KinectOptions {
    /// libfreenect's device index.
    pub index: i32,
    /// Stream colour too.
    pub rgb: bool,
    /// Longest wait for a frame (s).
    pub frame_timeout_s: f64,
    /// Depth frames dropped before the one kept (frames buffered while nobody
    /// was reading may predate the request).
    pub settle_frames: u32,
    /// The library to load instead of `libfreenect.so.0.5` by the loader's
    /// search (e.g. fakenect's, for a benchmark).
    pub library: Option<std::path::PathBuf>,
}

/// Where the depth model came from.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RegistrationSource {
    /// The device reported it (libfreenect `freenect_copy_registration`).
    Device,
    /// The recording's `device.json` (fakenect cannot report it).
    Recording,
    /// Neither: the nominal Kinect v1 values.
    Nominal,
}

/// One snapshot as the device delivered it.
#[derive(Debug, Clone, PartialEq)]
pub struct KinectFrame {
    /// Raw 11-bit depth, 640 x 480, row-major.
    pub depth_raw: Vec<u16>,
    /// RGB bytes, 640 x 480 x 3, when colour was asked for and arrived.
    pub rgb: Option<Vec<u8>>,
    /// The accelerometer reading at the snapshot, when the device has one.
    pub accel: Option<AccelCounts>,
    /// The depth frame's device timestamp.
    pub timestamp: u32,
}

/// An open Kinect.
#[derive(Debug)]
pub struct Kinect {
    session: Session,
    options: KinectOptions,
    registration: Registration,
    source: RegistrationSource,
    encoding: DepthEncoding,
    sink: FrameSink,
}

fn driver_error(e: FfiError, index: i32) -> KinectError {
    match e {
        FfiError::Load(detail) => KinectError::Library {
            library: LIBRARY,
            detail,
        },
        FfiError::Symbol(name) => KinectError::Library {
            library: LIBRARY,
            detail: format!("it lacks {name} (not libfreenect 0.5?)"),
        },
        FfiError::NoDevice => KinectError::NoDevice { index },
        // libusb could not be initialised or the device not opened: there is
        // no usable Kinect for this user.
        FfiError::Call {
            function: "freenect_init" | "freenect_open_device",
            ..
        } => KinectError::NoDevice { index },
        FfiError::Call { function, code } => KinectError::Driver { function, code },
    }
}

impl Kinect {
    /// Loads libfreenect, opens the device and starts its streams; the depth model
    /// comes from the device, else from the recording fakenect plays
    /// (`$FAKENECT_PATH/device.json`), else the nominal values (with a warning).
    pub fn open(options: KinectOptions) -> Result<Kinect, KinectError> {
        if !(options.frame_timeout_s.is_finite() && options.frame_timeout_s > 0.0) {
            return Err(KinectError::Stalled {
                timeout_s: options.frame_timeout_s,
            });
        }
        let lib = Library::open(options.library.as_deref())
            .map_err(|e| driver_error(e, options.index))?;
        let mut session = Session::open(lib, options.index, options.rgb)
            .map_err(|e| driver_error(e, options.index))?;
        let (registration, source) = match session.registration() {
            Some(r) => (
                Registration {
                    zero_plane: ZeroPlane {
                        dcmos_emitter_dist: r.zero_plane[0],
                        dcmos_rcmos_dist: r.zero_plane[1],
                        reference_distance: r.zero_plane[2],
                        reference_pixel_size: r.zero_plane[3],
                    },
                    const_shift: r.const_shift,
                },
                RegistrationSource::Device,
            ),
            None => match std::env::var_os("FAKENECT_PATH") {
                Some(dir) => match fakenect::read_registration(std::path::Path::new(&dir))? {
                    Some(r) => (r, RegistrationSource::Recording),
                    None => (Registration::nominal(), RegistrationSource::Nominal),
                },
                None => (Registration::nominal(), RegistrationSource::Nominal),
            },
        };
        registration
            .validate()
            .map_err(|e| KinectError::Recording {
                path: "device registration".into(),
                problem: e.to_string(),
            })?;
        if source == RegistrationSource::Nominal {
            tracing::warn!(
                "the Kinect's registration data is unavailable: nominal Kinect v1 depth model"
            );
        }
        tracing::info!(
            ?source,
            focal_px = registration.intrinsics(FRAME_WIDTH, FRAME_HEIGHT).focal_px,
            "Kinect open"
        );
        Ok(Kinect {
            session,
            options,
            encoding: DepthEncoding::Disparity11 {
                table_m: registration.depth_table_m(),
            },
            registration,
            source,
            sink: FrameSink::default(),
        })
    }

    /// The depth model in use.
    pub fn registration(&self) -> &Registration {
        &self.registration
    }

    /// Where the depth model came from.
    pub fn registration_source(&self) -> &RegistrationSource {
        &self.source
    }

    /// The depth image's intrinsics.
    pub fn intrinsics(&self) -> KinectIntrinsics {
        self.registration.intrinsics(FRAME_WIDTH, FRAME_HEIGHT)
    }

    /// Waits for a fresh depth frame (after dropping `settle_frames`), a colour
    /// frame after it when colour is on, and reads the accelerometer.
    /// [`KinectError::Vanished`] when the device stops answering,
    /// [`KinectError::Stalled`] when the frames do not come within the timeout.
    pub fn grab(&mut self) -> Result<KinectFrame, KinectError> {
        let timeout = Duration::from_secs_f64(self.options.frame_timeout_s);
        let started = Instant::now();
        let want_depth = self.sink.depth_frames + 1 + u64::from(self.options.settle_frames);
        // The colour frame must follow the depth frame kept.
        let mut rgb_mark: Option<u64> = None;
        loop {
            if rgb_mark.is_none() && self.sink.depth_frames >= want_depth {
                rgb_mark = Some(self.sink.rgb_frames);
            }
            let done = match rgb_mark {
                Some(mark) => !self.options.rgb || self.sink.rgb_frames > mark,
                None => false,
            };
            if done {
                break;
            }
            if started.elapsed() > timeout {
                return Err(KinectError::Stalled {
                    timeout_s: self.options.frame_timeout_s,
                });
            }
            self.session
                .process_events(&mut self.sink, 0.1)
                .map_err(|e| KinectError::Vanished {
                    detail: match e {
                        FfiError::Call { function, code } => format!("{function} returned {code}"),
                        other => format!("{other:?}"),
                    },
                })?;
        }
        let accel = match self.session.accelerometer() {
            Ok([x, y, z]) => Some(AccelCounts { x, y, z }),
            Err(e) => {
                tracing::warn!("accelerometer unreadable: {e:?}");
                None
            }
        };
        Ok(KinectFrame {
            depth_raw: self.sink.depth.clone(),
            rgb: self.options.rgb.then(|| self.sink.rgb.clone()),
            accel,
            timestamp: self.sink.depth_timestamp,
        })
    }

    /// The accelerometer's reading now, when the device has one (fakenect: the
    /// last record played, none before the first).
    pub fn accelerometer(&mut self) -> Option<AccelCounts> {
        let [x, y, z] = self.session.accelerometer().ok()?;
        let counts = AccelCounts { x, y, z };
        counts.gravity_camera_m_s2().map(|_| counts)
    }

    /// The organised cloud (camera optical frame) of `frame`'s depth within `range_m`.
    pub fn to_cloud(&self, frame: &KinectFrame, range_m: [f32; 2]) -> PointCloud {
        depth_to_cloud(
            &frame.depth_raw,
            FRAME_WIDTH,
            &self.encoding,
            &self.intrinsics(),
            range_m,
        )
    }
}
