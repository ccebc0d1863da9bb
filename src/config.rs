//! The cell's configuration (`robot/cell.toml`): typed, validated, units in names.
//!
//! Every section rejects unknown fields so a typo is an error, not a silent
//! default. Paths are relative to the directory of the configuration file.
//!
//! Without `--config`, the configuration is found as a Unix tool's would be
//! ([`locate`]): `$GRASPCELL_CONFIG`, then `./robot/cell.toml`, then
//! `/etc/graspcell/cell.toml`, then the defaults built into the binary (the shipped
//! `robot/cell.toml` with the shipped URDF), named [`BUILTIN_CONFIG`].

use crate::fsio::FileError;
use crate::geometry::{Pose, PoseJson};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Default location of the cell configuration, relative to the repository root.
pub const DEFAULT_CONFIG_PATH: &str = "robot/cell.toml";

/// The environment variable that names the configuration file.
pub const CONFIG_ENV: &str = "GRASPCELL_CONFIG";

/// The system-wide configuration of an installed cell.
pub const SYSTEM_CONFIG_PATH: &str = "/etc/graspcell/cell.toml";

/// The name of the configuration built into the binary (`--config builtin:cell.toml`).
pub const BUILTIN_CONFIG: &str = "builtin:cell.toml";

/// The name of the URDF built into the binary (`robot.urdf = "builtin:lbr4_bh8_282.urdf"`).
pub const BUILTIN_URDF: &str = "builtin:lbr4_bh8_282.urdf";

/// The shipped configuration and URDF, compiled in.
const BUILTIN_CONFIG_TEXT: &str = include_str!("../robot/cell.toml");
/// The shipped URDF, compiled in.
pub const BUILTIN_URDF_TEXT: &str = include_str!("../robot/lbr4_bh8_282.urdf");

/// Where the configuration comes from when `--config` is not given, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Located {
    /// The file, or [`BUILTIN_CONFIG`].
    pub path: PathBuf,
    /// Which rule chose it, for `cell print-config`.
    pub rule: &'static str,
}

/// Finds the configuration: `$GRASPCELL_CONFIG` (used even when the file is missing,
/// so loading names it), `./robot/cell.toml`, `/etc/graspcell/cell.toml`, else the
/// built-in defaults.
pub fn locate() -> Located {
    locate_in(
        std::env::var_os(CONFIG_ENV).map(PathBuf::from),
        Path::new(DEFAULT_CONFIG_PATH),
        Path::new(SYSTEM_CONFIG_PATH),
    )
}

fn locate_in(env: Option<PathBuf>, local: &Path, system: &Path) -> Located {
    let absolute = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    if let Some(path) = env.filter(|p| !p.as_os_str().is_empty()) {
        return Located {
            path: absolute(&path),
            rule: "$GRASPCELL_CONFIG",
        };
    }
    for (path, rule) in [
        (local, "./robot/cell.toml in the working directory"),
        (system, "the system configuration"),
    ] {
        if path.is_file() {
            return Located {
                path: absolute(path),
                rule,
            };
        }
    }
    Located {
        path: PathBuf::from(BUILTIN_CONFIG),
        rule: "no configuration file found: the built-in defaults",
    }
}

/// The configuration path `--config` defaults to ([`locate`]).
pub fn default_config_path() -> PathBuf {
    locate().path
}

/// Errors of loading or validating the configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {}: {}", .0.path.display(), .0.source)]
    Read(FileError),
    /// The file is not valid TOML for this schema.
    #[error("config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A value is out of its valid range.
    #[error("config {path}: {field} = {value}: {problem}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The dotted field name.
        field: String,
        /// The offending value, as text.
        value: String,
        /// What is wrong with it.
        problem: String,
    },
}

/// The whole cell.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellConfig {
    /// The arm and hand description.
    pub robot: RobotConfig,
    /// The table the objects stand on.
    pub table: TableConfig,
    /// The fixed RGB-D camera.
    pub camera: CameraConfig,
    /// The box the palm must stay inside (robot base frame).
    pub workspace: WorkspaceConfig,
    /// Speed limits on top of the URDF's.
    pub limits: LimitsConfig,
    /// The KUKA FRI link.
    pub fri: FriConfig,
    /// The hand's CAN bus.
    pub can: CanConfig,
    /// Approach to contact: shared by the executor's guarded move and every grasp
    /// simulation (absent: the defaults).
    #[serde(default)]
    pub approach: ApproachConfig,
}

/// The robot description.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// URDF of the arm with the hand, relative to the config file.
    pub urdf: PathBuf,
    /// Names of the seven arm joints, base to flange.
    pub arm_joints: Vec<String>,
    /// Link of the arm's flange.
    pub flange_link: String,
    /// Link of the hand's palm frame (z out of the palm).
    pub palm_link: String,
    /// Distance (m) the pre-grasp pose backs off from the grasp along the palm's -z.
    pub pregrasp_offset_m: f64,
    /// Joints A1..A7 (rad) where the arm rests between trials, out of the camera's
    /// view of the table: the executor parks there after every grasp, and plans
    /// are checked from there.
    #[serde(default = "default_park_joints_rad")]
    pub park_joints_rad: [f64; 7],
}

/// The default park joints: elbow up, the palm about 0.48 m over the table, facing
/// down, clear of the camera's view of the table.
pub const DEFAULT_PARK_JOINTS_RAD: [f64; 7] = [0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0];

fn default_park_joints_rad() -> [f64; 7] {
    DEFAULT_PARK_JOINTS_RAD
}

/// The table: a horizontal plane with a rectangular extent.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableConfig {
    /// Height of the table top above the robot base (m).
    pub height_m: f64,
    /// Centre of the table top in the base frame, x y (m).
    pub center_xy_m: [f64; 2],
    /// Size of the table top along x and y (m).
    pub extent_xy_m: [f64; 2],
    /// Thickness of the table slab used for collision (m).
    pub thickness_m: f64,
    /// The palm must stay at least this far above the table (m; the paper used 0.05).
    pub palm_clearance_m: f64,
}

/// The fixed camera: intrinsics and the nominal mount.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Where snapshots come from: `sim`, `replay` or `kinect` (a Kinect v1 through
    /// libfreenect; needs the `kinect` cargo feature).
    pub backend: String,
    /// Nominal camera pose: robot base from camera optical frame (z forward, x right, y down).
    /// A calibration result in `calib/hand_eye.toml` overrides it.
    pub base_from_camera: PoseJson,
    /// Image width (px).
    pub width_px: u32,
    /// Image height (px).
    pub height_px: u32,
    /// Focal length along x (px).
    pub fx_px: f64,
    /// Focal length along y (px).
    pub fy_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
    /// Nearest valid depth (m).
    pub min_range_m: f64,
    /// Farthest valid depth (m).
    pub max_range_m: f64,
    /// Largest angle (deg) between the gravity the camera's accelerometer measures
    /// and the base's -z seen through the calibrated mount before a warning.
    #[serde(default = "default_gravity_check_max_deg")]
    pub gravity_check_max_deg: f64,
    /// Longest wait for a device camera's frame before the snapshot fails (s).
    #[serde(default = "default_frame_timeout_s")]
    pub frame_timeout_s: f64,
    /// libfreenect's index of the Kinect to use (`kinect` backend).
    #[serde(default)]
    pub kinect_index: u32,
    /// Stream the Kinect's colour camera too and keep each snapshot's colour
    /// image with the trial's raw frame (`kinect` backend).
    #[serde(default)]
    pub rgb: bool,
}

fn default_gravity_check_max_deg() -> f64 {
    2.0
}

fn default_frame_timeout_s() -> f64 {
    2.0
}

/// An axis-aligned box in the base frame.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkspaceConfig {
    /// Lower corner x y z (m).
    pub min_m: [f64; 3],
    /// Upper corner x y z (m).
    pub max_m: [f64; 3],
}

/// Speed limits applied on top of the URDF's joint limits.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsConfig {
    /// Fraction (0, 1] of each joint's URDF velocity limit that trajectories may use.
    pub joint_velocity_scale: f64,
    /// Joint acceleration limit used for trajectories (rad/s^2).
    pub joint_acceleration_rad_s2: f64,
    /// Cartesian speed limit of the palm during approach and lift (m/s).
    pub palm_speed_m_s: f64,
}

/// The KUKA FRI link.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FriConfig {
    /// `sim` (FRI robot simulator) or `hardware`.
    pub backend: String,
    /// Local UDP address the driver binds (FRI default port 49938).
    pub bind_addr: String,
    /// The robot controller (KRC): its IP address (any port) or address with port.
    /// The driver answers nobody else: datagrams from other senders are dropped,
    /// counted and never answered. Required; the shipped value is the simulator's
    /// host (127.0.0.1).
    pub robot_addr: String,
    /// Measurement period the KRL program requests (s).
    pub cycle_s: f64,
    /// A missing measurement for this long stops the executor (s).
    pub timeout_s: f64,
}

/// The hand's CAN bus.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    /// Interface: `can0`/`vcan0` (SocketCAN) or `virtual:NAME` (userspace bus).
    pub interface: String,
    /// Timeout for one request/reply exchange (s).
    pub reply_timeout_s: f64,
}

/// Approach to contact (GraspIt!'s rule, on the robot a guarded move): from the
/// pre-grasp (`robot.pregrasp_offset_m` back along the palm's -z) the palm moves
/// along its approach axis (+z) through the planned pose, at most
/// `max_overtravel_m` beyond it, and stops at first contact; then the hand closes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ApproachConfig {
    /// Farthest the palm goes beyond the planned pose (m).
    #[serde(default = "default_max_overtravel_m")]
    pub max_overtravel_m: f64,
    /// Estimated external force at the tool (FRI `estExtTcpFT`, magnitude of its
    /// force part, over its value when the approach began) that counts as contact (N).
    #[serde(default = "default_contact_force_n")]
    pub contact_force_n: f64,
    /// Peak palm speed of the guarded approach (m/s; at most `limits.palm_speed_m_s`).
    #[serde(default = "default_approach_speed_m_s")]
    pub speed_m_s: f64,
    /// Stiffness of the simulated contact (`cell-sim-arm`): the force is the hand's
    /// penetration into the object or the table times this (N/m).
    #[serde(default = "default_sim_contact_stiffness_n_per_m")]
    pub sim_contact_stiffness_n_per_m: f64,
}

fn default_max_overtravel_m() -> f64 {
    0.05
}

fn default_contact_force_n() -> f64 {
    10.0
}

fn default_approach_speed_m_s() -> f64 {
    0.05
}

fn default_sim_contact_stiffness_n_per_m() -> f64 {
    20_000.0
}

impl Default for ApproachConfig {
    fn default() -> Self {
        ApproachConfig {
            max_overtravel_m: default_max_overtravel_m(),
            contact_force_n: default_contact_force_n(),
            speed_m_s: default_approach_speed_m_s(),
            sim_contact_stiffness_n_per_m: default_sim_contact_stiffness_n_per_m(),
        }
    }
}

impl CellConfig {
    /// Loads and validates a configuration file; relative paths become relative to it.
    /// [`BUILTIN_CONFIG`] is the shipped configuration with the built-in URDF.
    pub fn load(path: &Path) -> Result<CellConfig, ConfigError> {
        let builtin = path == Path::new(BUILTIN_CONFIG);
        let text = if builtin {
            BUILTIN_CONFIG_TEXT.to_string()
        } else {
            crate::fsio::read_to_string(path).map_err(ConfigError::Read)?
        };
        Self::parse(&text, path)
    }

    /// Parses and validates configuration `text` read from `path` (which names it in
    /// errors; relative paths become relative to it).
    pub fn parse(text: &str, path: &Path) -> Result<CellConfig, ConfigError> {
        let builtin = path == Path::new(BUILTIN_CONFIG);
        let mut config: CellConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim().replace('\n', " "),
        })?;
        if builtin {
            config.robot.urdf = PathBuf::from(BUILTIN_URDF);
        } else if config.robot.urdf.is_relative() && config.robot.urdf != Path::new(BUILTIN_URDF) {
            let dir = path.parent().unwrap_or(Path::new("."));
            config.robot.urdf = dir.join(&config.robot.urdf);
        }
        config.validate(path)?;
        Ok(config)
    }

    /// The nominal `base_from_camera` pose.
    pub fn base_from_camera(&self) -> Pose {
        // Validated at load time.
        self.camera
            .base_from_camera
            .to_pose("camera.base_from_camera")
            .unwrap_or_else(|_| Pose::identity())
    }

    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let invalid = |field: &str, value: String, problem: &str| ConfigError::Invalid {
            path: path.to_path_buf(),
            field: field.to_string(),
            value,
            problem: problem.to_string(),
        };
        // TOML spells nan and inf: no number anywhere in the file may be either.
        if let Some((field, value)) = toml::Value::try_from(self)
            .ok()
            .and_then(|v| non_finite_number(&v, ""))
        {
            return Err(invalid(
                &field,
                value.to_string(),
                "must be a finite number",
            ));
        }
        let positive = [
            ("table.extent_xy_m[0]", self.table.extent_xy_m[0]),
            ("table.extent_xy_m[1]", self.table.extent_xy_m[1]),
            ("table.thickness_m", self.table.thickness_m),
            ("camera.fx_px", self.camera.fx_px),
            ("camera.fy_px", self.camera.fy_px),
            ("camera.min_range_m", self.camera.min_range_m),
            (
                "camera.gravity_check_max_deg",
                self.camera.gravity_check_max_deg,
            ),
            ("camera.frame_timeout_s", self.camera.frame_timeout_s),
            (
                "limits.joint_velocity_scale",
                self.limits.joint_velocity_scale,
            ),
            (
                "limits.joint_acceleration_rad_s2",
                self.limits.joint_acceleration_rad_s2,
            ),
            ("limits.palm_speed_m_s", self.limits.palm_speed_m_s),
            ("fri.cycle_s", self.fri.cycle_s),
            ("fri.timeout_s", self.fri.timeout_s),
            ("can.reply_timeout_s", self.can.reply_timeout_s),
            ("robot.pregrasp_offset_m", self.robot.pregrasp_offset_m),
            ("approach.contact_force_n", self.approach.contact_force_n),
            ("approach.speed_m_s", self.approach.speed_m_s),
            (
                "approach.sim_contact_stiffness_n_per_m",
                self.approach.sim_contact_stiffness_n_per_m,
            ),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(
                    field,
                    value.to_string(),
                    "must be a finite number > 0",
                ));
            }
        }
        let overtravel = self.approach.max_overtravel_m;
        if !(overtravel.is_finite() && overtravel >= 0.0) {
            return Err(invalid(
                "approach.max_overtravel_m",
                overtravel.to_string(),
                "must be a finite number >= 0",
            ));
        }
        if self.limits.joint_velocity_scale > 1.0 {
            return Err(invalid(
                "limits.joint_velocity_scale",
                self.limits.joint_velocity_scale.to_string(),
                "must be at most 1 (a fraction of the URDF limit)",
            ));
        }
        if self.camera.max_range_m <= self.camera.min_range_m {
            return Err(invalid(
                "camera.max_range_m",
                self.camera.max_range_m.to_string(),
                "must exceed camera.min_range_m",
            ));
        }
        if self.camera.width_px == 0 || self.camera.height_px == 0 {
            return Err(invalid(
                "camera.width_px/height_px",
                format!("{}x{}", self.camera.width_px, self.camera.height_px),
                "must be non-zero",
            ));
        }
        if self.robot.arm_joints.len() != 7 {
            return Err(invalid(
                "robot.arm_joints",
                format!("{} names", self.robot.arm_joints.len()),
                "the LBR4+ has exactly 7 joints",
            ));
        }
        for i in 0..3 {
            if self.workspace.min_m[i].partial_cmp(&self.workspace.max_m[i])
                != Some(std::cmp::Ordering::Less)
            {
                return Err(invalid(
                    "workspace.min_m/max_m",
                    format!("{:?} / {:?}", self.workspace.min_m, self.workspace.max_m),
                    "each min must be below its max",
                ));
            }
        }
        if !matches!(self.camera.backend.as_str(), "sim" | "replay" | "kinect") {
            return Err(invalid(
                "camera.backend",
                self.camera.backend.clone(),
                "use sim, replay or kinect",
            ));
        }
        if !matches!(self.fri.backend.as_str(), "sim" | "hardware") {
            return Err(invalid(
                "fri.backend",
                self.fri.backend.clone(),
                "use sim or hardware",
            ));
        }
        let robot_addr = self.fri.robot_addr.trim();
        if robot_addr.parse::<std::net::SocketAddr>().is_err()
            && robot_addr.parse::<std::net::IpAddr>().is_err()
        {
            return Err(invalid(
                "fri.robot_addr",
                self.fri.robot_addr.clone(),
                "must be the robot controller's IP address, or address:port (e.g. 192.168.0.10)",
            ));
        }
        self.camera
            .base_from_camera
            .to_pose("camera.base_from_camera")
            .map_err(|e| invalid("camera.base_from_camera", String::new(), &e.to_string()))?;
        Ok(())
    }
}

/// The first NaN or infinite number in `value` and its path (`table.height_m`,
/// `workspace.min_m[2]`).
fn non_finite_number(value: &toml::Value, path: &str) -> Option<(String, f64)> {
    match value {
        toml::Value::Float(f) if !f.is_finite() => Some((path.to_string(), *f)),
        toml::Value::Array(items) => items
            .iter()
            .enumerate()
            .find_map(|(i, v)| non_finite_number(v, &format!("{path}[{i}]"))),
        toml::Value::Table(table) => table.iter().find_map(|(key, v)| {
            let path = if path.is_empty() {
                key.clone()
            } else {
                format!("{path}.{key}")
            };
            non_finite_number(v, &path)
        }),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_CONFIG_PATH)
    }

    #[test]
    fn configuration_is_found_in_the_order_a_unix_tool_uses() {
        let dir = crate::fsio::TempDir::new("locate").unwrap();
        let local = dir.join("local.toml");
        let system = dir.join("system.toml");
        let env = dir.join("env.toml");
        let found = |env: Option<&Path>| locate_in(env.map(Path::to_path_buf), &local, &system);
        assert_eq!(found(None).path, PathBuf::from(BUILTIN_CONFIG));
        std::fs::write(&system, "").unwrap();
        assert_eq!(found(None).path, system);
        std::fs::write(&local, "").unwrap();
        assert_eq!(found(None).path, local);
        // The variable wins even over existing files, and even when its file is missing.
        assert_eq!(found(Some(&env)).path, env);
        assert_eq!(found(Some(Path::new(""))).path, local);
    }

    #[test]
    fn builtin_configuration_equals_the_shipped_file_with_the_builtin_urdf() {
        let builtin = CellConfig::load(Path::new(BUILTIN_CONFIG)).unwrap();
        let shipped = CellConfig::load(&shipped()).unwrap();
        assert_eq!(builtin.robot.urdf, PathBuf::from(BUILTIN_URDF));
        let without_urdf = |c: &CellConfig| {
            let mut c = c.clone();
            c.robot.urdf = PathBuf::new();
            toml::to_string(&c).unwrap()
        };
        assert_eq!(without_urdf(&builtin), without_urdf(&shipped));
        let shipped_urdf = std::fs::read_to_string(&shipped.robot.urdf).unwrap();
        assert_eq!(BUILTIN_URDF_TEXT, shipped_urdf);
    }

    #[test]
    fn shipped_config_loads_and_camera_sees_table() {
        let config = CellConfig::load(&shipped()).unwrap();
        assert!(config.robot.urdf.exists(), "{:?}", config.robot.urdf);
        // The camera's optical axis points down at the table.
        let z = config.base_from_camera().rotation * nalgebra::Vector3::z();
        assert!(z.z < -0.5, "camera looks along {z:?}");
    }

    #[test]
    fn unknown_field_and_bad_value_are_named() {
        let text = std::fs::read_to_string(shipped()).unwrap();
        let dir = crate::fsio::TempDir::new("config").unwrap();
        let typo = dir.join("typo.toml");
        std::fs::write(&typo, text.replace("height_m =", "heigth_m =")).unwrap();
        let err = CellConfig::load(&typo).unwrap_err().to_string();
        assert!(
            err.contains("heigth_m") && err.contains("typo.toml"),
            "{err}"
        );
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, text.replace("cycle_s = 0.002", "cycle_s = -1.0")).unwrap();
        let err = CellConfig::load(&bad).unwrap_err().to_string();
        assert!(err.contains("fri.cycle_s"), "{err}");
    }

    #[test]
    fn nan_and_infinity_are_refused_in_every_number() {
        // Issue 21 item 4: TOML spells nan and inf; none may reach the cell.
        let text = std::fs::read_to_string(shipped()).unwrap();
        let dir = crate::fsio::TempDir::new("nan").unwrap();
        let cases = [
            ("height_m = 0.0", "height_m = nan", "table.height_m", "NaN"),
            (
                "center_xy_m = [0.65, 0.0]",
                "center_xy_m = [0.65, -inf]",
                "table.center_xy_m[1]",
                "-inf",
            ),
            (
                "max_m = [1.10, 0.70, 1.00]",
                "max_m = [1.10, 0.70, inf]",
                "workspace.max_m[2]",
                "inf",
            ),
            (
                "pregrasp_offset_m = 0.10",
                "pregrasp_offset_m = +inf",
                "robot.pregrasp_offset_m",
                "inf",
            ),
            ("fx_px = 525.0", "fx_px = nan", "camera.fx_px", "NaN"),
        ];
        for (line, bad, field, shown) in cases {
            assert!(text.contains(line), "{line}");
            let path = dir.join("nan.toml");
            std::fs::write(&path, text.replace(line, bad)).unwrap();
            let err = CellConfig::load(&path).unwrap_err().to_string();
            assert!(
                err.contains(&format!("{field} = {shown}")) && err.contains("finite"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn the_robot_controller_address_is_required_and_checked() {
        let text = std::fs::read_to_string(shipped()).unwrap();
        assert!(CellConfig::load(&shipped()).unwrap().fri.robot_addr == "127.0.0.1");
        let dir = crate::fsio::TempDir::new("robot-addr").unwrap();
        let load = |name: &str, text: String| {
            let path = dir.join(name);
            std::fs::write(&path, text).unwrap();
            CellConfig::load(&path)
        };
        let line = "robot_addr = \"127.0.0.1\"";
        assert!(text.contains(line));
        let err = load("missing.toml", text.replace(line, "")).unwrap_err();
        assert!(err.to_string().contains("robot_addr"), "{err}");
        let err = load("bad.toml", text.replace(line, "robot_addr = \"krc\"")).unwrap_err();
        assert!(err.to_string().contains("fri.robot_addr = krc"), "{err}");
        for ok in ["192.168.0.10", "192.168.0.10:49938", "[::1]:49938"] {
            let config = load(
                "ok.toml",
                text.replace(line, &format!("robot_addr = \"{ok}\"")),
            );
            assert_eq!(config.unwrap().fri.robot_addr, ok);
        }
    }
}
