//! The messages of the cell: `#[repr(C)]` plain data placed in shared memory.
//!
//! Every message starts with `trial_id: u64` (0 = no trial) and `stamp_ns: u64`
//! ([`monotonic_now_ns`](super::monotonic_now_ns) when the sender produced it).
//! Fields whose bit patterns are not all valid in Rust (enumerations, flags, text)
//! are stored as integer codes or bytes and read through checked accessors, so a
//! message from a faulty or different sender gives an error, never undefined
//! behaviour. Poses are 4x4 row-major homogeneous matrices ([`PoseMatrix`]).

use super::services::Topic;
use super::IpcError;
use crate::geometry::{check_finite, matrix_rows, pose_from_matrix_rows, Pose};
use crate::plan::PlannedGrasp;
use iceoryx2::prelude::ZeroCopySend;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use std::fmt::Debug;

/// Columns of the largest cloud (the camera's image width).
pub const MAX_CLOUD_WIDTH: u32 = 640;
/// Rows of the largest cloud (the camera's image height).
pub const MAX_CLOUD_HEIGHT: u32 = 480;
/// Most points in one cloud message (640 x 480).
pub const MAX_CLOUD_POINTS: usize = (MAX_CLOUD_WIDTH * MAX_CLOUD_HEIGHT) as usize;
/// Most model fits in one [`Fits`] message.
pub const MAX_FITS: usize = 32;
/// Most points of the seen surface in one [`Fits`] message (the object's segmented
/// points, thinned: a mug seen from one side keeps about 1,000 on a 4 mm grid).
pub const MAX_SEEN_POINTS: usize = 4096;
/// Capacity in bytes of a [`Name`] (category, task, method).
pub const NAME_CAPACITY: usize = 32;
/// Arm joints of the KUKA LBR4+ (A1, A2, E1, A3, A4, A5, A6).
pub const ARM_JOINTS: usize = 7;
/// Hand joints of the BH8-282: finger 1, finger 2, finger 3 (inner link), spread.
pub const HAND_JOINTS: usize = 4;

/// A message as a receiver sees it in shared memory: `bytes` copied over a default
/// message (zero-padded if short, extra bytes ignored). For tests and fuzzing of the
/// checks a stage does on receipt.
pub fn from_wire_bytes<M: AnyBitPattern>(bytes: &[u8]) -> M {
    let mut message = M::default();
    let len = bytes.len().min(std::mem::size_of::<M>());
    // SAFETY: `M: AnyBitPattern`, so every bit pattern is a valid `M`; `len` is at
    // most the size of `M`, and `bytes` cannot overlap the local `message`.
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), (&mut message as *mut M).cast::<u8>(), len);
    }
    message
}

/// A payload in which every bit pattern is a valid value.
///
/// # Safety
///
/// Implement only for `#[repr(C)]` types made of integers, floats and arrays or
/// structs of them (no `bool`, enumeration, reference or pointer).
pub unsafe trait AnyBitPattern: Copy + Default {}

// SAFETY: each is `#[repr(C)]` plain data made only of integers, floats and arrays
// of them; codes, flags and text are stored as integers and bytes and read through
// checked accessors.
unsafe impl AnyBitPattern for TrialRequest {}
// SAFETY: as above.
unsafe impl AnyBitPattern for CloudHeader {}
// SAFETY: as above.
unsafe impl AnyBitPattern for Fits {}
// SAFETY: as above.
unsafe impl AnyBitPattern for GraspPlan {}
// SAFETY: as above.
unsafe impl AnyBitPattern for JointStates {}
// SAFETY: as above.
unsafe impl AnyBitPattern for ExecutionStatus {}
// SAFETY: as above.
unsafe impl AnyBitPattern for TrialResult {}
// SAFETY: as above.
unsafe impl AnyBitPattern for CameraStatus {}
// SAFETY: as above.
unsafe impl AnyBitPattern for CloudAck {}
// SAFETY: as above.
unsafe impl AnyBitPattern for Point {}

/// A message of a topic (every payload except point clouds).
pub trait Message: Debug + Copy + ZeroCopySend + 'static {
    /// The topic that carries this message.
    const TOPIC: Topic;
    /// Trial the message belongs to (0 = none).
    fn trial_id(&self) -> u64;
    /// Monotonic time (ns) at which the sender produced it.
    fn stamp_ns(&self) -> u64;
}

macro_rules! message {
    ($t:ty, $topic:expr) => {
        impl Message for $t {
            const TOPIC: Topic = $topic;
            fn trial_id(&self) -> u64 {
                self.trial_id
            }
            fn stamp_ns(&self) -> u64 {
                self.stamp_ns
            }
        }
    };
}

/// An enumeration stored as a `u32` code in messages.
macro_rules! coded_enum {
    ($(#[$doc:meta])* $name:ident, $field:literal, { $($(#[$vdoc:meta])* $variant:ident = $code:literal),+ $(,)? }) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        #[serde(rename_all = "snake_case")]
        pub enum $name {
            $($(#[$vdoc])* $variant = $code),+
        }

        impl $name {
            /// Every variant.
            pub const ALL: &'static [$name] = &[$($name::$variant),+];

            /// The code stored in messages.
            pub fn code(self) -> u32 {
                self as u32
            }

            /// The variant of a received code.
            pub fn from_code(code: u32) -> Result<$name, IpcError> {
                match code {
                    $($code => Ok($name::$variant),)+
                    _ => Err(IpcError::UnknownCode { field: $field, code }),
                }
            }
        }
    };
}

coded_enum!(
    /// The frame a cloud's points are expressed in.
    Frame, "frame", {
        /// The camera's optical frame (x right, y down, z forward along the view).
        CameraOptical = 0,
        /// The robot base (world) frame, REP 103.
        Base = 1,
    }
);

coded_enum!(
    /// Whose settings a trial's perception and planning use (issue 19): the cell's,
    /// or the paper's ([`crate::plan::PlanMode`], [`crate::register::RegisterParams::paper`]).
    Protocol, "trial request protocol", {
        /// The cell's own: two-sided fit score, its kernels, reachability repair for
        /// every method.
        Cell = 0,
        /// The paper's simulation setting (s = b = 50), one-sided fit score, poor fits
        /// kept, no repair.
        PaperSimulation = 1,
        /// The paper's robot setting (Table 2: s = b = 700), otherwise as
        /// `PaperSimulation`.
        PaperRobot = 2,
    }
);

impl Protocol {
    /// The planner's mode of this protocol.
    pub fn plan_mode(self) -> crate::plan::PlanMode {
        use crate::plan::{PaperProtocol, PlanMode};
        match self {
            Protocol::Cell => PlanMode::Cell,
            Protocol::PaperSimulation => PlanMode::Paper {
                protocol: PaperProtocol::Simulation,
            },
            Protocol::PaperRobot => PlanMode::Paper {
                protocol: PaperProtocol::Robot,
            },
        }
    }

    /// Whether this is one of the paper's settings.
    pub fn is_paper(self) -> bool {
        self != Protocol::Cell
    }
}

coded_enum!(
    /// Outcome of registering one model to the observed object.
    FitStatus, "fit status", {
        /// ICP converged; the fit is usable.
        Converged = 0,
        /// ICP stopped without converging; the fit may be poor.
        NotConverged = 1,
        /// Registration failed (too few points or correspondences).
        Failed = 2,
    }
);

coded_enum!(
    /// What the executor is doing.
    Phase, "execution phase", {
        /// Waiting for a grasp plan.
        Idle = 0,
        /// Moving to the pre-grasp pose.
        MovingToPregrasp = 1,
        /// Approaching the grasp pose.
        Approaching = 2,
        /// Closing the hand.
        Closing = 3,
        /// Lifting the object.
        Lifting = 4,
        /// Holding the object lifted.
        Holding = 5,
        /// Opening the hand and retreating.
        Releasing = 6,
        /// The grasp sequence finished.
        Done = 7,
        /// Stopped on a fault; the arm is held still.
        Stopped = 8,
    }
);

coded_enum!(
    /// The observer's grade of a trial.
    Grade, "grade", {
        /// Object lifted and held stably (+1).
        Success = 0,
        /// Object lifted but slipped or moved in the hand (0).
        Partial = 1,
        /// Object not lifted (-1).
        Failure = 2,
    }
);

impl Grade {
    /// The paper's score: success +1, partial 0, failure -1.
    pub fn score(self) -> i32 {
        match self {
            Grade::Success => 1,
            Grade::Partial => 0,
            Grade::Failure => -1,
        }
    }
}

coded_enum!(
    /// Why a trial failed (the paper's causes plus the cell's own).
    FailureCause, "failure cause", {
        /// No failure.
        None = 0,
        /// No reachable grasp (inverse kinematics or collision).
        Reachability = 1,
        /// Registration did not find the object's pose.
        RegistrationFailure = 2,
        /// The category models differ too much from the object.
        ShapeDissimilarity = 3,
        /// Any other cause the observer names.
        Other = 4,
        /// A stage process died during the trial.
        StageDied = 5,
        /// A stage did not answer in time.
        Timeout = 6,
        /// A device reported a fault.
        HardwareFault = 7,
        /// The execution went wrong (refused motion, collision, slip, no contact).
        Execution = 8,
        /// The camera gave no snapshot (device missing, vanished or stalled).
        Camera = 9,
    }
);

/// The trial log's grade on the wire.
impl From<crate::trial::Grade> for Grade {
    fn from(grade: crate::trial::Grade) -> Grade {
        match grade {
            crate::trial::Grade::Success => Grade::Success,
            crate::trial::Grade::Partial => Grade::Partial,
            crate::trial::Grade::Failure => Grade::Failure,
        }
    }
}

/// A grade from the wire as the trial log's.
impl From<Grade> for crate::trial::Grade {
    fn from(grade: Grade) -> crate::trial::Grade {
        match grade {
            Grade::Success => crate::trial::Grade::Success,
            Grade::Partial => crate::trial::Grade::Partial,
            Grade::Failure => crate::trial::Grade::Failure,
        }
    }
}

/// The trial log's cause on the wire.
impl From<crate::trial::FailureCause> for FailureCause {
    fn from(cause: crate::trial::FailureCause) -> FailureCause {
        match cause {
            crate::trial::FailureCause::Reachability => FailureCause::Reachability,
            crate::trial::FailureCause::Registration => FailureCause::RegistrationFailure,
            crate::trial::FailureCause::ShapeDissimilarity => FailureCause::ShapeDissimilarity,
            crate::trial::FailureCause::Execution => FailureCause::Execution,
            crate::trial::FailureCause::Other => FailureCause::Other,
        }
    }
}

/// The trial log's cause of a grading on the wire: no cause is [`FailureCause::None`].
impl From<Option<crate::trial::FailureCause>> for FailureCause {
    fn from(cause: Option<crate::trial::FailureCause>) -> FailureCause {
        cause.map_or(FailureCause::None, FailureCause::from)
    }
}

/// A cause from the wire (a plan's failure) as the trial log's: a hardware fault is an
/// execution failure; the cell's own causes (stage died, timeout, camera) and
/// [`FailureCause::None`] are `Other`.
impl From<FailureCause> for crate::trial::FailureCause {
    fn from(cause: FailureCause) -> crate::trial::FailureCause {
        match cause {
            FailureCause::Reachability => crate::trial::FailureCause::Reachability,
            FailureCause::RegistrationFailure => crate::trial::FailureCause::Registration,
            FailureCause::ShapeDissimilarity => crate::trial::FailureCause::ShapeDissimilarity,
            FailureCause::Execution | FailureCause::HardwareFault => {
                crate::trial::FailureCause::Execution
            }
            FailureCause::None
            | FailureCause::Other
            | FailureCause::StageDied
            | FailureCause::Timeout
            | FailureCause::Camera => crate::trial::FailureCause::Other,
        }
    }
}

coded_enum!(
    /// Why the camera gave no snapshot for a trial.
    CameraFault, "camera fault", {
        /// A snapshot was published.
        None = 0,
        /// No device at start (or since it vanished): USB, power, udev rule.
        NoDevice = 1,
        /// The device stopped answering mid-run (unplugged; a recording ended).
        Vanished = 2,
        /// No frame within the frame timeout.
        Stalled = 3,
        /// Any other failure of the backend (unreadable recording, ...).
        Failed = 4,
    }
);

/// Text in a fixed 32-byte field, NUL-padded (category, task, method names).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::Name")]
pub struct Name {
    bytes: [u8; NAME_CAPACITY],
}

impl Name {
    /// `text` as the field `field`: at most 32 bytes of UTF-8 without NUL.
    pub fn new(field: &'static str, text: &str) -> Result<Name, IpcError> {
        if text.len() > NAME_CAPACITY {
            return Err(IpcError::NameTooLong {
                field,
                len: text.len(),
                max: NAME_CAPACITY,
            });
        }
        if let Some(offset) = text.bytes().position(|b| b == 0) {
            return Err(IpcError::NameHasNul { field, offset });
        }
        let mut bytes = [0u8; NAME_CAPACITY];
        bytes[..text.len()].copy_from_slice(text.as_bytes());
        Ok(Name { bytes })
    }

    /// The text up to the first NUL; an error names `field` if it is not UTF-8.
    pub fn to_str(&self, field: &'static str) -> Result<&str, IpcError> {
        let len = self
            .bytes
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(NAME_CAPACITY);
        std::str::from_utf8(&self.bytes[..len]).map_err(|e| IpcError::NameNotUtf8 {
            field,
            valid_up_to: e.valid_up_to(),
        })
    }

    /// The raw bytes (for tests and diagnostics).
    pub fn as_bytes(&self) -> &[u8; NAME_CAPACITY] {
        &self.bytes
    }

    /// A name from raw bytes, unchecked (as received from another process).
    pub fn from_bytes(bytes: [u8; NAME_CAPACITY]) -> Name {
        Name { bytes }
    }
}

/// A rigid transform as a 4x4 homogeneous matrix, row-major (`rows[r][c]`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("graspcell::ipc::PoseMatrix")]
pub struct PoseMatrix {
    /// The rows of the homogeneous matrix; translation in metres in the last column.
    pub rows: [[f64; 4]; 4],
}

impl Default for PoseMatrix {
    fn default() -> Self {
        PoseMatrix::from_pose(&Pose::identity())
    }
}

/// Largest deviation of a received rotation from orthonormal that is accepted.
const RIGID_TOLERANCE: f64 = 1e-6;

impl PoseMatrix {
    /// The matrix of `pose`.
    pub fn from_pose(pose: &Pose) -> PoseMatrix {
        PoseMatrix {
            rows: matrix_rows(pose),
        }
    }

    /// The pose, checked: finite, last row `0 0 0 1`, rotation orthonormal with
    /// determinant +1 (to 1e-6); `field` names the message field in errors.
    pub fn to_pose(&self, field: &'static str) -> Result<Pose, IpcError> {
        let flat: Vec<f64> = self.rows.iter().flatten().copied().collect();
        check_finite(&flat, field)?;
        let last = self.rows[3];
        let last_error = (last[0].abs())
            .max(last[1].abs())
            .max(last[2].abs())
            .max((last[3] - 1.0).abs());
        if last_error > RIGID_TOLERANCE {
            return Err(IpcError::NotRigid {
                field,
                problem: "last row is not 0 0 0 1",
                error: last_error,
            });
        }
        let r = nalgebra::Matrix3::from_fn(|i, j| self.rows[i][j]);
        let orth_error = (r.transpose() * r - nalgebra::Matrix3::identity())
            .abs()
            .max();
        if orth_error > RIGID_TOLERANCE {
            return Err(IpcError::NotRigid {
                field,
                problem: "rotation is not orthonormal",
                error: orth_error,
            });
        }
        let det = r.determinant();
        if (det - 1.0).abs() > RIGID_TOLERANCE {
            return Err(IpcError::NotRigid {
                field,
                problem: "rotation is a reflection",
                error: (det - 1.0).abs(),
            });
        }
        Ok(pose_from_matrix_rows(&self.rows))
    }
}

fn flag_from_code(field: &'static str, code: u32) -> Result<bool, IpcError> {
    match code {
        0 => Ok(false),
        1 => Ok(true),
        _ => Err(IpcError::UnknownCode { field, code }),
    }
}

/// Operator -> cell: grasp an object of `category` for `task` with `method`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::TrialRequest")]
pub struct TrialRequest {
    /// Trial id (> 0), chosen by the requester.
    pub trial_id: u64,
    /// Monotonic time of the request (ns).
    pub stamp_ns: u64,
    category: Name,
    task: Name,
    method: Name,
    protocol: u32,
}
message!(TrialRequest, Topic::TrialRequest);

impl TrialRequest {
    /// A request; each text must fit [`NAME_CAPACITY`] bytes.
    pub fn new(
        trial_id: u64,
        stamp_ns: u64,
        category: &str,
        task: &str,
        method: &str,
    ) -> Result<TrialRequest, IpcError> {
        Ok(TrialRequest {
            trial_id,
            stamp_ns,
            category: Name::new("trial request category", category)?,
            task: Name::new("trial request task", task)?,
            method: Name::new("trial request method", method)?,
            protocol: Protocol::Cell.code(),
        })
    }

    /// The same request under `protocol` (a new request is the cell's).
    pub fn with_protocol(mut self, protocol: Protocol) -> TrialRequest {
        self.protocol = protocol.code();
        self
    }

    /// Whose settings perception and planning use.
    pub fn protocol(&self) -> Result<Protocol, IpcError> {
        Protocol::from_code(self.protocol)
    }

    /// Object category (`mug`, `bottle`, ...).
    pub fn category(&self) -> Result<&str, IpcError> {
        self.category.to_str("trial request category")
    }

    /// Task (`top`, `side`, `handle`, `use`).
    pub fn task(&self) -> Result<&str, IpcError> {
        self.task.to_str("trial request task")
    }

    /// Method (`laplace`, `gaussian`, `gaussian-r`, `best-single`).
    pub fn method(&self) -> Result<&str, IpcError> {
        self.method.to_str("trial request method")
    }

    /// Checks every field a receiver reads: the texts and the protocol's code.
    pub fn check(&self) -> Result<(), IpcError> {
        self.category()?;
        self.task()?;
        self.method()?;
        self.protocol()?;
        Ok(())
    }
}

/// One point of a cloud (metres); NaN coordinates mark a missing return.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::Point")]
pub struct Point {
    /// x (m).
    pub x: f32,
    /// y (m).
    pub y: f32,
    /// z (m).
    pub z: f32,
}

impl Point {
    /// A point from coordinates (m).
    pub fn new(x: f32, y: f32, z: f32) -> Point {
        Point { x, y, z }
    }

    /// True when all coordinates are finite (the point was observed).
    pub fn is_valid(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
}

impl From<Point3<f32>> for Point {
    fn from(p: Point3<f32>) -> Point {
        Point::new(p.x, p.y, p.z)
    }
}

impl From<Point> for Point3<f32> {
    fn from(p: Point) -> Point3<f32> {
        Point3::new(p.x, p.y, p.z)
    }
}

/// Pinhole intrinsics of the depth camera (pixels).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend, Serialize, Deserialize)]
#[type_name("graspcell::ipc::Intrinsics")]
pub struct Intrinsics {
    /// Focal length along x (px).
    pub fx: f64,
    /// Focal length along y (px).
    pub fy: f64,
    /// Principal point x (px).
    pub cx: f64,
    /// Principal point y (px).
    pub cy: f64,
}

/// The header of a point cloud message; the points follow as a slice of [`Point`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("graspcell::ipc::CloudHeader")]
pub struct CloudHeader {
    /// Trial id (0 = none).
    pub trial_id: u64,
    /// Monotonic time of the snapshot (ns).
    pub stamp_ns: u64,
    /// Columns of the organised cloud (or the number of points when `height == 1`).
    pub width: u32,
    /// Rows of the organised cloud (1 = unorganised).
    pub height: u32,
    /// Camera intrinsics of the snapshot.
    pub intrinsics: Intrinsics,
    frame: u32,
    reserved: u32,
    /// The camera's pose in the robot base frame at the snapshot.
    pub base_from_camera: PoseMatrix,
}

impl Default for CloudHeader {
    fn default() -> Self {
        CloudHeader {
            trial_id: 0,
            stamp_ns: 0,
            width: 0,
            height: 0,
            intrinsics: Intrinsics::default(),
            frame: Frame::CameraOptical.code(),
            reserved: 0,
            base_from_camera: PoseMatrix::default(),
        }
    }
}

impl CloudHeader {
    /// A header; [`CloudHeader::validate`] checks it against the points.
    pub fn new(
        trial_id: u64,
        stamp_ns: u64,
        width: u32,
        height: u32,
        intrinsics: Intrinsics,
        frame: Frame,
        base_from_camera: &Pose,
    ) -> CloudHeader {
        CloudHeader {
            trial_id,
            stamp_ns,
            width,
            height,
            intrinsics,
            frame: frame.code(),
            reserved: 0,
            base_from_camera: PoseMatrix::from_pose(base_from_camera),
        }
    }

    /// The frame the points are expressed in.
    pub fn frame(&self) -> Result<Frame, IpcError> {
        Frame::from_code(self.frame)
    }

    /// Sets the frame the points are expressed in.
    pub fn set_frame(&mut self, frame: Frame) {
        self.frame = frame.code();
    }

    /// Number of points the shape calls for (`width * height`).
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// True when the shape holds no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Checks that `points` points match the shape and fit [`MAX_CLOUD_POINTS`], that
    /// the intrinsics are positive and finite, the frame known and the pose rigid.
    pub fn validate(&self, points: usize) -> Result<(), IpcError> {
        if self.len() != points || points > MAX_CLOUD_POINTS {
            return Err(IpcError::CloudShape {
                width: self.width,
                height: self.height,
                points,
                max: MAX_CLOUD_POINTS,
            });
        }
        let i = &self.intrinsics;
        for (field, value) in [("intrinsics fx", i.fx), ("intrinsics fy", i.fy)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(IpcError::NotPositive { field, value });
            }
        }
        check_finite(&[i.cx, i.cy], "intrinsics cx, cy")?;
        self.frame()?;
        self.base_from_camera.to_pose("base_from_camera")?;
        Ok(())
    }
}

/// The registration of one category model to the observed object.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::ModelFit")]
pub struct ModelFit {
    /// Index of the model in the category database.
    pub model_id: u32,
    status: u32,
    /// `T_i`: the model frame to the robot base (world) frame.
    pub base_from_model: PoseMatrix,
    /// Fitting error `eps_i`: mean squared nearest-neighbour distance (m^2).
    pub eps: f64,
    /// `sigma_i`: standard deviation of the squared distances (m^2).
    pub sigma: f64,
    /// Fraction of target points with a correspondence within the ICP threshold.
    pub inlier_fraction: f64,
}

impl ModelFit {
    /// A fit of model `model_id`.
    pub fn new(
        model_id: u32,
        status: FitStatus,
        base_from_model: &Pose,
        eps: f64,
        sigma: f64,
        inlier_fraction: f64,
    ) -> ModelFit {
        ModelFit {
            model_id,
            status: status.code(),
            base_from_model: PoseMatrix::from_pose(base_from_model),
            eps,
            sigma,
            inlier_fraction,
        }
    }

    /// Outcome of the registration.
    pub fn status(&self) -> Result<FitStatus, IpcError> {
        FitStatus::from_code(self.status)
    }

    /// Checks a received fit: a known status, a rigid pose and finite, non-negative
    /// errors (a NaN `eps` would otherwise win or poison the planner's weights).
    pub fn check(&self) -> Result<(), IpcError> {
        self.status()?;
        self.base_from_model.to_pose("fit base_from_model")?;
        check_finite(
            &[self.eps, self.sigma, self.inlier_fraction],
            "fit eps, sigma, inlier fraction",
        )?;
        for (field, value) in [("fit eps", self.eps), ("fit sigma", self.sigma)] {
            if value < 0.0 {
                return Err(IpcError::NotPositive { field, value });
            }
        }
        Ok(())
    }
}

/// Perception -> planner: the fits of every model of the category (up to 32), and
/// the surface they were fitted to (the object's segmented points in the robot base
/// frame, thinned; up to [`MAX_SEEN_POINTS`]), which the open hand must not enter.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("graspcell::ipc::Fits")]
pub struct Fits {
    /// Trial id.
    pub trial_id: u64,
    /// Monotonic time the fits were computed (ns).
    pub stamp_ns: u64,
    count: u32,
    seen_count: u32,
    models: [ModelFit; MAX_FITS],
    seen: [Point; MAX_SEEN_POINTS],
}
message!(Fits, Topic::Fits);

impl Default for Fits {
    fn default() -> Self {
        Fits {
            trial_id: 0,
            stamp_ns: 0,
            count: 0,
            seen_count: 0,
            models: [ModelFit::default(); MAX_FITS],
            seen: [Point::default(); MAX_SEEN_POINTS],
        }
    }
}

impl Fits {
    /// Fits of at most [`MAX_FITS`] models.
    pub fn new(trial_id: u64, stamp_ns: u64, fits: &[ModelFit]) -> Result<Fits, IpcError> {
        let mut out = Fits {
            trial_id,
            stamp_ns,
            count: fits.len() as u32,
            ..Fits::default()
        };
        counted("fits", &out.models, fits.len())?;
        out.models[..fits.len()].copy_from_slice(fits);
        Ok(out)
    }

    /// The fits (checked count).
    pub fn fits(&self) -> Result<&[ModelFit], IpcError> {
        counted("fits", &self.models, self.count as usize)
    }

    /// These fits with the seen surface `points` (base frame, at most
    /// [`MAX_SEEN_POINTS`]).
    pub fn with_seen(mut self, points: &[Point]) -> Result<Fits, IpcError> {
        counted("seen points", &self.seen, points.len())?;
        self.seen_count = points.len() as u32;
        self.seen[..points.len()].copy_from_slice(points);
        Ok(self)
    }

    /// The seen surface (checked count; empty when perception sent none).
    pub fn seen(&self) -> Result<&[Point], IpcError> {
        counted("seen points", &self.seen, self.seen_count as usize)
    }
}

/// The first `count` items of the fixed-capacity array `items` of message field
/// `field`, or [`IpcError::TooMany`] when they do not fit.
fn counted<'a, T>(field: &'static str, items: &'a [T], count: usize) -> Result<&'a [T], IpcError> {
    items.get(..count).ok_or(IpcError::TooMany {
        field,
        count,
        max: items.len(),
    })
}

/// Planner -> executor: the grasp to execute.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::GraspPlan")]
pub struct GraspPlan {
    /// Trial id.
    pub trial_id: u64,
    /// Monotonic time the plan was finished (ns).
    pub stamp_ns: u64,
    /// Palm pose of the grasp in the robot base frame.
    pub base_from_palm: PoseMatrix,
    /// Palm pose before the approach in the robot base frame.
    pub base_from_pregrasp_palm: PoseMatrix,
    /// Arm joint angles at the grasp (rad).
    pub joints_rad: [f64; ARM_JOINTS],
    /// Arm joint angles at the pre-grasp (rad).
    pub pregrasp_joints_rad: [f64; ARM_JOINTS],
    /// Value of the objective at the grasp (eq. 2 with normalising constants).
    pub objective: f64,
    reachable: u32,
    failure: u32,
    method: Name,
    /// Hand spread of the grasp (rad).
    pub spread_rad: f64,
    /// Pre-shape of the grasp: each finger's flex (F1, F2, F3) before the approach
    /// (rad); zero is the open hand.
    pub preshape_rad: [f64; 3],
    /// How far beyond the palm pose the approach to contact may go (m), when
    /// `own_overtravel` is 1; else the executor's configured overtravel.
    pub max_overtravel_m: f64,
    own_overtravel: u32,
}
message!(GraspPlan, Topic::GraspPlan);

impl GraspPlan {
    /// The plan to execute `grasp` (with its joint solutions) for trial `trial_id`.
    /// `method` must fit [`NAME_CAPACITY`] bytes.
    pub fn new(
        trial_id: u64,
        stamp_ns: u64,
        grasp: &PlannedGrasp,
        method: &str,
    ) -> Result<GraspPlan, IpcError> {
        let (Some(joints_rad), Some(pregrasp_joints_rad)) = (grasp.joints, grasp.pregrasp_joints)
        else {
            return Err(IpcError::Missing {
                field: "grasp plan joint solutions",
            });
        };
        Ok(GraspPlan {
            trial_id,
            stamp_ns,
            base_from_palm: PoseMatrix::from_pose(&grasp.pose),
            base_from_pregrasp_palm: PoseMatrix::from_pose(&grasp.pregrasp_pose),
            joints_rad,
            pregrasp_joints_rad,
            objective: grasp.objective,
            reachable: 1,
            failure: FailureCause::None.code(),
            method: Name::new("grasp plan method", method)?,
            spread_rad: grasp.spread_rad,
            preshape_rad: grasp.preshape_rad.0,
            max_overtravel_m: grasp.max_overtravel_m.unwrap_or(0.0),
            own_overtravel: grasp.max_overtravel_m.is_some().into(),
        })
    }

    /// A plan that could not be made, for trial `trial_id`: nothing to execute, and
    /// why (`cause` is not [`FailureCause::None`]).
    pub fn failed(
        trial_id: u64,
        stamp_ns: u64,
        cause: FailureCause,
        method: &str,
    ) -> Result<GraspPlan, IpcError> {
        Ok(GraspPlan {
            trial_id,
            stamp_ns,
            failure: cause.code(),
            method: Name::new("grasp plan method", method)?,
            ..GraspPlan::default()
        })
    }

    /// Why no grasp was planned ([`FailureCause::None`] for a plan to execute).
    pub fn failure(&self) -> Result<FailureCause, IpcError> {
        FailureCause::from_code(self.failure)
    }

    /// True when inverse kinematics found both joint vectors within limits.
    pub fn reachable(&self) -> Result<bool, IpcError> {
        flag_from_code("grasp plan reachable", self.reachable)
    }

    /// The method that produced the plan.
    pub fn method(&self) -> Result<&str, IpcError> {
        self.method.to_str("grasp plan method")
    }

    /// The plan's own overtravel of the approach (m), if it names one.
    pub fn overtravel(&self) -> Result<Option<f64>, IpcError> {
        Ok(
            flag_from_code("grasp plan own_overtravel", self.own_overtravel)?
                .then_some(self.max_overtravel_m),
        )
    }

    /// Checks the fields that make bytes a plan at all: its failure code and method
    /// text (the numbers are the executor's to validate).
    pub fn check(&self) -> Result<(), IpcError> {
        self.failure()?;
        self.method()?;
        self.overtravel()?;
        Ok(())
    }
}

/// Joint angles of arm and hand.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::JointState")]
pub struct JointState {
    /// Arm A1, A2, E1, A3, A4, A5, A6 (rad).
    pub arm_rad: [f64; ARM_JOINTS],
    /// Hand finger 1, finger 2, finger 3 (inner link), spread (rad).
    pub hand_rad: [f64; HAND_JOINTS],
}

impl JointState {
    /// Checks that every angle is finite (a received state with NaN must not become
    /// the arm's current position).
    pub fn check(&self) -> Result<(), IpcError> {
        check_finite(&self.arm_rad, "joint state arm_rad")?;
        check_finite(&self.hand_rad, "joint state hand_rad")?;
        Ok(())
    }
}

/// Executor -> anyone: the measured joint angles.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::JointStates")]
pub struct JointStates {
    /// Trial id (0 between trials).
    pub trial_id: u64,
    /// Monotonic time of the measurement (ns).
    pub stamp_ns: u64,
    /// The angles.
    pub joints: JointState,
    /// 1 when the executor can start a grasp at once: the arm in command mode and
    /// the hand initialised; else 0.
    pub devices_ready: u32,
    reserved: u32,
}
message!(JointStates, Topic::JointStates);

impl JointStates {
    /// Joint states measured at `stamp_ns`.
    pub fn new(
        trial_id: u64,
        stamp_ns: u64,
        joints: JointState,
        devices_ready: bool,
    ) -> JointStates {
        JointStates {
            trial_id,
            stamp_ns,
            joints,
            devices_ready: u32::from(devices_ready),
            reserved: 0,
        }
    }
}

/// Executor -> log: phase, error and joints of the execution.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::ExecutionStatus")]
pub struct ExecutionStatus {
    /// Trial id.
    pub trial_id: u64,
    /// Monotonic time of the status (ns).
    pub stamp_ns: u64,
    phase: u32,
    /// 0 = no error; otherwise the executor's error code.
    pub error_code: u32,
    /// Joint angles at the time of the status.
    pub joints: JointState,
}
message!(ExecutionStatus, Topic::ExecutionStatus);

impl ExecutionStatus {
    /// A status.
    pub fn new(
        trial_id: u64,
        stamp_ns: u64,
        phase: Phase,
        error_code: u32,
        joints: JointState,
    ) -> ExecutionStatus {
        ExecutionStatus {
            trial_id,
            stamp_ns,
            phase: phase.code(),
            error_code,
            joints,
        }
    }

    /// The phase.
    pub fn phase(&self) -> Result<Phase, IpcError> {
        Phase::from_code(self.phase)
    }
}

/// Durations of a trial's steps (s); NaN for a step that did not run.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("graspcell::ipc::Timings")]
pub struct Timings {
    /// Camera snapshot to cloud published.
    pub capture_s: f64,
    /// Cloud received to fits published.
    pub perceive_s: f64,
    /// Fits received to grasp plan published.
    pub plan_s: f64,
    /// Grasp plan received to the end of the grasp sequence.
    pub execute_s: f64,
    /// Snapshot to the first grasp command sent to the arm.
    pub snapshot_to_grasp_command_s: f64,
    /// Trial request to trial result.
    pub total_s: f64,
}

impl Default for Timings {
    fn default() -> Self {
        Timings {
            capture_s: f64::NAN,
            perceive_s: f64::NAN,
            plan_s: f64::NAN,
            execute_s: f64::NAN,
            snapshot_to_grasp_command_s: f64::NAN,
            total_s: f64::NAN,
        }
    }
}

/// Log -> operator: the graded outcome of a trial.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("graspcell::ipc::TrialResult")]
pub struct TrialResult {
    /// Trial id.
    pub trial_id: u64,
    /// Monotonic time of the grading (ns).
    pub stamp_ns: u64,
    grade: u32,
    cause: u32,
    /// How long each step took.
    pub timings: Timings,
}
message!(TrialResult, Topic::TrialResult);

impl Default for TrialResult {
    fn default() -> Self {
        TrialResult::new(
            0,
            0,
            Grade::Failure,
            FailureCause::Other,
            Timings::default(),
        )
    }
}

impl TrialResult {
    /// A result.
    pub fn new(
        trial_id: u64,
        stamp_ns: u64,
        grade: Grade,
        cause: FailureCause,
        timings: Timings,
    ) -> TrialResult {
        TrialResult {
            trial_id,
            stamp_ns,
            grade: grade.code(),
            cause: cause.code(),
            timings,
        }
    }

    /// The observer's grade.
    pub fn grade(&self) -> Result<Grade, IpcError> {
        Grade::from_code(self.grade)
    }

    /// Why the trial failed ([`FailureCause::None`] on success).
    pub fn cause(&self) -> Result<FailureCause, IpcError> {
        FailureCause::from_code(self.cause)
    }
}

/// Camera -> log: for every trial request, the snapshot's accelerometer and
/// gravity check, or why there is no snapshot.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("graspcell::ipc::CameraStatus")]
pub struct CameraStatus {
    /// Trial id.
    pub trial_id: u64,
    /// Monotonic time of the snapshot or of the failure (ns).
    pub stamp_ns: u64,
    fault: u32,
    /// 1 when the gravity check exceeded its limit (camera bumped or calibration stale).
    pub gravity_warning: u32,
    /// Gravity measured by the camera's accelerometer in the camera optical frame
    /// (m/s^2); NaN when the camera has none.
    pub gravity_camera_m_s2: [f64; 3],
    /// Angle between the measured gravity and the base's -z through the calibrated
    /// mount (rad); NaN when not measured.
    pub gravity_angle_rad: f64,
}
message!(CameraStatus, Topic::CameraStatus);

impl Default for CameraStatus {
    fn default() -> Self {
        CameraStatus::new(0, 0, CameraFault::None)
    }
}

impl CameraStatus {
    /// A status without gravity data.
    pub fn new(trial_id: u64, stamp_ns: u64, fault: CameraFault) -> CameraStatus {
        CameraStatus {
            trial_id,
            stamp_ns,
            fault: fault.code(),
            gravity_warning: 0,
            gravity_camera_m_s2: [f64::NAN; 3],
            gravity_angle_rad: f64::NAN,
        }
    }

    /// Why there is no snapshot ([`CameraFault::None`] when there is one).
    pub fn fault(&self) -> Result<CameraFault, IpcError> {
        CameraFault::from_code(self.fault)
    }
}

/// Diagnostics: a receiver's acknowledgement of one cloud.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("graspcell::ipc::CloudAck")]
pub struct CloudAck {
    /// Trial id of the acknowledged cloud.
    pub trial_id: u64,
    /// Monotonic time at which the receiver had read the cloud (ns).
    pub stamp_ns: u64,
    /// The cloud's own stamp (ns), so `stamp_ns - cloud_stamp_ns` is the latency.
    pub cloud_stamp_ns: u64,
    /// Number of points received.
    pub points: u64,
    /// Sum of x + y + z over the points the receiver read (f64).
    pub checksum: f64,
}
message!(CloudAck, Topic::CloudAck);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose_from_params;
    use std::mem::{align_of, size_of};

    #[test]
    fn a_request_is_the_cells_unless_given_the_papers_protocol() {
        let r = TrialRequest::new(7, 11, "mug", "handle", "laplace").unwrap();
        assert_eq!(r.protocol().unwrap(), Protocol::Cell);
        assert_eq!(
            r.protocol().unwrap().plan_mode(),
            crate::plan::PlanMode::Cell
        );
        let paper = r.with_protocol(Protocol::PaperRobot);
        assert!(paper.protocol().unwrap().is_paper());
        assert_eq!(
            paper.protocol().unwrap().plan_mode(),
            crate::plan::PlanMode::Paper {
                protocol: crate::plan::PaperProtocol::Robot
            }
        );
        let garbled = TrialRequest {
            protocol: 7,
            ..paper
        };
        assert!(matches!(
            garbled.protocol(),
            Err(IpcError::UnknownCode { code: 7, .. })
        ));
        assert!(paper.check().is_ok());
        assert!(garbled.check().is_err());
    }

    /// Random bytes are no plan: an unknown failure code or a method that is not
    /// text is refused before anyone reads the numbers.
    #[test]
    fn a_plan_of_random_bytes_does_not_check() {
        let plan = GraspPlan {
            method: Name::new("grasp plan method", "laplace").unwrap(),
            ..GraspPlan::default()
        };
        assert!(plan.check().is_ok());
        let bad_code = GraspPlan {
            failure: 0xdead_beef,
            ..plan
        };
        assert!(matches!(
            bad_code.check(),
            Err(IpcError::UnknownCode { .. })
        ));
        let bytes = [0xffu8; size_of::<GraspPlan>()];
        assert!(from_wire_bytes::<GraspPlan>(&bytes).check().is_err());
    }

    #[test]
    fn names_round_trip_and_limits_are_enforced() {
        let r = TrialRequest::new(7, 11, "mug", "handle", "laplace").unwrap();
        assert_eq!(
            (
                r.category().unwrap(),
                r.task().unwrap(),
                r.method().unwrap()
            ),
            ("mug", "handle", "laplace")
        );
        // Exactly 32 bytes of multi-byte UTF-8 fits and round-trips.
        let full = "é".repeat(16);
        assert_eq!(full.len(), NAME_CAPACITY);
        assert_eq!(Name::new("f", &full).unwrap().to_str("f").unwrap(), full);
        assert_eq!(Name::new("f", "").unwrap().to_str("f").unwrap(), "");
        match Name::new("trial request task", &"x".repeat(33)) {
            Err(IpcError::NameTooLong { field, len, max }) => {
                assert_eq!((field, len, max), ("trial request task", 33, 32))
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            Name::new("f", "a\0b"),
            Err(IpcError::NameHasNul { offset: 1, .. })
        ));
        assert!(TrialRequest::new(1, 1, "mug", "top", &"m".repeat(40)).is_err());
    }

    #[test]
    fn garbage_names_and_codes_give_errors() {
        let mut bytes = [0u8; NAME_CAPACITY];
        bytes[..3].copy_from_slice(&[b'a', 0xff, b'b']);
        assert!(matches!(
            Name::from_bytes(bytes).to_str("task"),
            Err(IpcError::NameNotUtf8 {
                field: "task",
                valid_up_to: 1
            })
        ));
        // A name cut in the middle of a multi-byte character is invalid too.
        let mut cut = [0u8; NAME_CAPACITY];
        cut[..2].copy_from_slice(&"é".as_bytes()[..1].repeat(2));
        assert!(Name::from_bytes(cut).to_str("x").is_err());

        let mut status = ExecutionStatus::new(3, 4, Phase::Closing, 0, JointState::default());
        assert_eq!(status.phase().unwrap(), Phase::Closing);
        status.phase = 99;
        assert!(matches!(
            status.phase(),
            Err(IpcError::UnknownCode { code: 99, .. })
        ));
        let mut plan = GraspPlan {
            reachable: 2,
            ..GraspPlan::default()
        };
        assert!(plan.reachable().is_err());
        plan.reachable = 1;
        assert!(plan.reachable().unwrap());
    }

    #[test]
    fn every_code_round_trips_and_codes_are_unique() {
        fn check<T: Copy + PartialEq + Debug>(
            all: &[T],
            code: fn(T) -> u32,
            from: fn(u32) -> Result<T, IpcError>,
        ) {
            let mut codes: Vec<u32> = all.iter().map(|&v| code(v)).collect();
            for &v in all {
                assert_eq!(from(code(v)).unwrap(), v);
            }
            codes.sort();
            codes.dedup();
            assert_eq!(codes.len(), all.len());
            assert!(from(1000).is_err());
        }
        check(Frame::ALL, Frame::code, Frame::from_code);
        check(FitStatus::ALL, FitStatus::code, FitStatus::from_code);
        check(Phase::ALL, Phase::code, Phase::from_code);
        check(Grade::ALL, Grade::code, Grade::from_code);
        check(CameraFault::ALL, CameraFault::code, CameraFault::from_code);
        check(
            FailureCause::ALL,
            FailureCause::code,
            FailureCause::from_code,
        );
        assert_eq!(
            Grade::ALL.iter().map(|g| g.score()).collect::<Vec<_>>(),
            [1, 0, -1]
        );
    }

    #[test]
    fn grades_and_causes_convert_at_the_wire_boundary() {
        use crate::trial::{FailureCause as LogCause, Grade as LogGrade};
        for grade in [LogGrade::Success, LogGrade::Partial, LogGrade::Failure] {
            assert_eq!(LogGrade::from(Grade::from(grade)), grade);
        }
        for cause in LogCause::ALL {
            assert_eq!(
                LogCause::from(FailureCause::from(cause)),
                cause,
                "{cause:?}"
            );
            assert_eq!(FailureCause::from(Some(cause)), FailureCause::from(cause));
        }
        assert_eq!(FailureCause::from(None), FailureCause::None);
        assert_eq!(
            FailureCause::from(LogCause::Registration),
            FailureCause::RegistrationFailure
        );
        assert_eq!(
            LogCause::from(FailureCause::HardwareFault),
            LogCause::Execution
        );
        for cell_own in [
            FailureCause::None,
            FailureCause::StageDied,
            FailureCause::Timeout,
            FailureCause::Camera,
        ] {
            assert_eq!(LogCause::from(cell_own), LogCause::Other);
        }
    }

    #[test]
    fn pose_matrix_round_trips_and_rejects_non_rigid() {
        let pose = pose_from_params(&[0.4, -0.2, 0.9, 0.3, -1.1, 2.5]);
        let m = PoseMatrix::from_pose(&pose);
        // Row-major: translation in the last column.
        assert_eq!([m.rows[0][3], m.rows[1][3], m.rows[2][3]], [0.4, -0.2, 0.9]);
        let back = m.to_pose("p").unwrap();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).abs().max() < 1e-12);

        let mut scaled = m;
        scaled.rows[0][0] *= 1.1;
        assert!(matches!(
            scaled.to_pose("p"),
            Err(IpcError::NotRigid { problem, .. }) if problem.contains("orthonormal")
        ));
        let mut mirrored = PoseMatrix::default();
        mirrored.rows[2][2] = -1.0;
        assert!(matches!(
            mirrored.to_pose("p"),
            Err(IpcError::NotRigid { problem, .. }) if problem.contains("reflection")
        ));
        let mut projective = PoseMatrix::default();
        projective.rows[3][0] = 0.5;
        assert!(projective.to_pose("p").is_err());
        let mut nan = PoseMatrix::default();
        nan.rows[1][3] = f64::NAN;
        assert!(matches!(nan.to_pose("p"), Err(IpcError::Geometry(_))));
    }

    #[test]
    fn cloud_header_validation() {
        let intr = Intrinsics {
            fx: 525.0,
            fy: 525.0,
            cx: 319.5,
            cy: 239.5,
        };
        let base_from_camera = pose_from_params(&[1.0, 0.0, 1.2, 0.0, 2.0, 0.0]);
        let h = CloudHeader::new(
            5,
            6,
            640,
            480,
            intr,
            Frame::CameraOptical,
            &base_from_camera,
        );
        h.validate(MAX_CLOUD_POINTS).unwrap();
        assert_eq!(h.frame().unwrap(), Frame::CameraOptical);
        assert!(matches!(
            h.validate(MAX_CLOUD_POINTS - 1),
            Err(IpcError::CloudShape {
                points: 307_199,
                ..
            })
        ));
        let big = CloudHeader::new(5, 6, 641, 480, intr, Frame::Base, &base_from_camera);
        assert!(big.validate(641 * 480).is_err());
        let mut bad = h;
        bad.intrinsics.fy = 0.0;
        assert!(matches!(
            bad.validate(MAX_CLOUD_POINTS),
            Err(IpcError::NotPositive {
                field: "intrinsics fy",
                ..
            })
        ));
        let mut bad = h;
        bad.frame = 7;
        assert!(bad.validate(MAX_CLOUD_POINTS).is_err());
    }

    #[test]
    fn fits_hold_up_to_capacity() {
        let pose = pose_from_params(&[0.1, 0.2, 0.3, 0.0, 0.0, 1.0]);
        let fits: Vec<ModelFit> = (0..MAX_FITS as u32)
            .map(|i| ModelFit::new(i, FitStatus::Converged, &pose, 1e-6 * i as f64, 0.0, 0.9))
            .collect();
        let msg = Fits::new(3, 4, &fits[..5]).unwrap();
        assert_eq!(msg.fits().unwrap(), &fits[..5]);
        assert_eq!(
            Fits::new(3, 4, &fits).unwrap().fits().unwrap().len(),
            MAX_FITS
        );
        let too_many = [fits.clone(), fits].concat();
        assert!(matches!(
            Fits::new(3, 4, &too_many),
            Err(IpcError::TooMany {
                count: 64,
                max: 32,
                ..
            })
        ));
        let mut corrupt = msg;
        corrupt.count = 33;
        assert!(corrupt.fits().is_err());
        assert_eq!(
            msg.fits().unwrap()[2].status().unwrap(),
            FitStatus::Converged
        );
    }

    #[test]
    fn a_plan_carries_its_grasp_and_needs_its_joint_solutions() {
        let pose = pose_from_params(&[0.6, 0.0, 0.2, 3.1, 0.0, 0.0]);
        let mut grasp = PlannedGrasp {
            pose,
            pregrasp_pose: pose_from_params(&[0.6, 0.0, 0.3, 3.1, 0.0, 0.0]),
            spread_rad: 0.4,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
            joints: Some([0.1; ARM_JOINTS]),
            pregrasp_joints: Some([0.2; ARM_JOINTS]),
            reachable: true,
            unreachable: None,
            objective: 0.5,
            log_objective: 0.5f64.ln(),
        };
        let plan = GraspPlan::new(3, 4, &grasp, "laplace").unwrap();
        let (dp, dr) =
            crate::geometry::pose_error(&plan.base_from_palm.to_pose("palm").unwrap(), &pose);
        assert!(dp < 1e-12 && dr < 1e-12, "{dp} {dr}");
        assert_eq!((plan.joints_rad, plan.spread_rad), ([0.1; ARM_JOINTS], 0.4));
        assert_eq!(plan.preshape_rad, [0.0; 3]);
        assert!(plan.reachable().unwrap());
        // A pre-shape goes over the wire, field for field, and back into the
        // executor's request.
        grasp.preshape_rad = crate::robot::PreshapeRad([1.2, 1.1, 1.3]);
        let plan = GraspPlan::new(3, 4, &grasp, "laplace").unwrap();
        assert_eq!(plan.preshape_rad, [1.2, 1.1, 1.3]);
        // Appended after the spread: the fields before it keep their offsets.
        assert_eq!(
            std::mem::offset_of!(GraspPlan, preshape_rad),
            std::mem::offset_of!(GraspPlan, spread_rad) + 8
        );
        assert_eq!(
            std::mem::offset_of!(GraspPlan, preshape_rad) + 24,
            std::mem::offset_of!(GraspPlan, max_overtravel_m)
        );
        let request = crate::cell::execute::execution_request(&plan).unwrap();
        assert_eq!(request.preshape_rad, grasp.preshape_rad);
        // So does a grasp's own overtravel, and its absence (the executor's).
        assert_eq!(request.max_overtravel_m, None);
        for own in [0.0, 0.02] {
            grasp.max_overtravel_m = Some(own);
            let plan = GraspPlan::new(3, 4, &grasp, "laplace").unwrap();
            let request = crate::cell::execute::execution_request(&plan).unwrap();
            assert_eq!(request.max_overtravel_m, Some(own));
        }
        let mut garbled = GraspPlan::new(3, 4, &grasp, "laplace").unwrap();
        garbled.own_overtravel = 7;
        assert!(garbled
            .check()
            .unwrap_err()
            .to_string()
            .contains("own_overtravel"));
        garbled.own_overtravel = 1;
        garbled.max_overtravel_m = f64::NAN;
        let err = crate::cell::execute::execution_request(&garbled).unwrap_err();
        assert!(err.to_string().contains("max_overtravel_m"), "{err}");
        assert_eq!(plan.failure().unwrap(), FailureCause::None);
        grasp.pregrasp_joints = None;
        let err = GraspPlan::new(3, 4, &grasp, "laplace").unwrap_err();
        assert!(err.to_string().contains("joint solutions"), "{err}");
    }

    #[test]
    fn fits_carry_the_seen_surface_up_to_capacity() {
        let fits = Fits::new(3, 4, &[]).unwrap();
        assert!(
            fits.seen().unwrap().is_empty(),
            "none unless perception sends it"
        );
        let points: Vec<Point> = (0..MAX_SEEN_POINTS)
            .map(|i| Point::new(i as f32 * 1e-3, 0.1, 0.2))
            .collect();
        let full = fits.with_seen(&points).unwrap();
        assert_eq!(full.seen().unwrap(), &points[..]);
        let more = [points.clone(), vec![Point::default()]].concat();
        assert!(matches!(
            fits.with_seen(&more),
            Err(IpcError::TooMany { count, .. }) if count == MAX_SEEN_POINTS + 1
        ));
        let mut corrupt = full;
        corrupt.seen_count = MAX_SEEN_POINTS as u32 + 1;
        assert!(corrupt
            .seen()
            .unwrap_err()
            .to_string()
            .contains("seen points"));
    }

    #[test]
    fn received_fits_and_joint_states_with_nan_are_refused() {
        let pose = pose_from_params(&[0.1, 0.2, 0.3, 0.0, 0.0, 1.0]);
        let good = ModelFit::new(0, FitStatus::Converged, &pose, 1e-6, 1e-7, 0.9);
        good.check().unwrap();
        let nan = ModelFit::new(0, FitStatus::Converged, &pose, f64::NAN, 1e-7, 0.9);
        assert!(nan.check().unwrap_err().to_string().contains("eps"));
        let negative = ModelFit::new(0, FitStatus::Converged, &pose, 1e-6, -1.0, 0.9);
        assert!(negative
            .check()
            .unwrap_err()
            .to_string()
            .contains("fit sigma"));
        let mut bad_pose = good;
        bad_pose.base_from_model.rows[0][0] = f64::NAN;
        assert!(bad_pose.check().is_err());
        let mut joints = JointState::default();
        joints.check().unwrap();
        joints.arm_rad[3] = f64::INFINITY;
        let err = joints.check().unwrap_err().to_string();
        assert!(err.contains("arm_rad"), "{err}");
        joints.arm_rad[3] = 0.0;
        joints.hand_rad[1] = f64::NAN;
        assert!(joints.check().unwrap_err().to_string().contains("hand_rad"));
    }

    #[test]
    fn wire_bytes_are_read_as_the_message_they_encode() {
        let request = TrialRequest::new(7, 11, "mug", "handle", "laplace").unwrap();
        // SAFETY (test): reads the bytes of a plain-data message with no padding.
        let bytes = unsafe {
            std::slice::from_raw_parts(
                (&request as *const TrialRequest).cast::<u8>(),
                size_of::<TrialRequest>(),
            )
        };
        assert_eq!(from_wire_bytes::<TrialRequest>(bytes), request);
        // Short input is zero-padded, long input cut.
        let short: TrialRequest = from_wire_bytes(&bytes[..16]);
        assert_eq!((short.trial_id, short.stamp_ns), (7, 11));
        assert_eq!(short.category().unwrap(), "");
        let long = [bytes, &[0xff; 64][..]].concat();
        assert_eq!(from_wire_bytes::<TrialRequest>(&long), request);
    }

    #[test]
    fn layouts_are_fixed() {
        // Sizes as laid out by repr(C) by hand; a change breaks other processes.
        assert_eq!(size_of::<Point>(), 12);
        assert_eq!(align_of::<Point>(), 4);
        assert_eq!(size_of::<PoseMatrix>(), 128);
        assert_eq!(size_of::<CloudHeader>(), 8 + 8 + 4 + 4 + 32 + 4 + 4 + 128);
        // The protocol code (4 bytes) and padding to the 8-byte alignment.
        assert_eq!(size_of::<TrialRequest>(), 16 + 3 * 32 + 8);
        assert_eq!(size_of::<ModelFit>(), 8 + 128 + 24);
        // The fits, then the seen surface (12-byte points; 8-byte alignment).
        assert_eq!(size_of::<Fits>(), 24 + 32 * 160 + MAX_SEEN_POINTS * 12);
        assert_eq!(size_of::<JointState>(), 11 * 8);
        // ... the pre-shape, the grasp's own overtravel and its flag (4 + 4 padding).
        assert_eq!(
            size_of::<GraspPlan>(),
            16 + 256 + 112 + 8 + 8 + 32 + 8 + 24 + 8 + 8
        );
        // The header's stamp sits at byte 8 (the socket benchmark relies on it).
        assert_eq!(std::mem::offset_of!(CloudHeader, stamp_ns), 8);
    }
}
