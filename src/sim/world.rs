//! The simulated world the devices feel: the trial's objects and table, the
//! contact force the arm's FRI simulator reports, and the angles where the puck
//! emulator's fingers stall.
//!
//! - [`SimWorld`]: a scene ([`crate::sim::scene`]) with each object prepared for
//!   the grasp simulator, and the hand model.
//!   - [`SimWorld::tcp_wrench`]: the force and torque the object and the table
//!     exert on the hand at a palm pose and hand shape. Each link's deepest
//!     penetration (m) times `stiffness_n_per_m`, along the contact normal (out
//!     of the object, up out of the table), summed over links; about the palm
//!     origin, in the palm frame, in FRI's `estExtTcpFT` order (Fx Fy Fz Tz Ty
//!     Tx). The arm follows its position commands (the object does not push it
//!     back), so this is what a guarded move sees.
//!   - [`SimWorld::closing`]: where each finger stops when the hand closes at a
//!     palm pose: the grasp simulator's auto-grasp ([`close_hand`]) on the object
//!     nearest the palm, with the table. A finger that closes on air runs to its
//!     limit (`None`). Whether the object goes with the hand when the arm lifts
//!     is the physics observer's lift test at that palm pose
//!     ([`SimWorld::lift_holds`], on a thread of its own, for a world prepared
//!     [`SimWorld::with_physics`], as `cell-sim-hand`'s is): lifted and held or
//!     slipped, it comes up; not lifted, dropped or pushed away, it stays. A world
//!     without physics keeps the static rule (force closure holds).
//! - [`WorldLink`]: the two simulators' small shared state. The arm simulator
//!   writes the palm pose it measures (every cycle); the hand emulator writes the
//!   hand's joints and whether its fingers hold the object. In one process the
//!   state is shared memory ([`WorldLink::memory`]); between the `cell-sim-arm`
//!   and `cell-sim-hand` processes it is two small files in a directory
//!   ([`WorldLink::files`]), each written whole with a sequence number and a
//!   checksum and read again until the checksum holds.
//! - [`ArmContact`] plugs the world into the FRI simulator
//!   ([`crate::sim::fri::ExternalForce`]); [`HandContact`] into the puck
//!   emulator ([`crate::sim::puck::Feel`]). While the fingers hold the object it
//!   moves with the hand and exerts no force on it (its weight is not modelled).
//! - [`WorldWatch`]: the current world, reloaded from a scene file whenever the
//!   file changes (the harness writes one per trial), on a thread of its own so
//!   a device's cycle never waits for a mesh to load.

use crate::config::CellConfig;
use crate::fsio::{FileError, FileOp};
use crate::geometry::Pose;
use crate::quality::autograsp::{
    close_hand, evaluate_grasp, retreat_until_clear, AutoGraspOptions, FingerStop, GraspObject,
    GraspSimError,
};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::robot::{HandPose, Robot};
use crate::sim::physics::{lift_test, LiftRule, LiftScene, PhysicsObject, PhysicsOptions};
use crate::sim::scene::{load_scene, Scene, SceneError, TableBox};
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::query::{DefaultQueryDispatcher, QueryDispatcher};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

/// Errors of building the simulated world or its shared state.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    /// The scene file is unusable.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// An object cannot be grasped in simulation (e.g. an open mesh).
    #[error("scene object {name}: {source}")]
    Object {
        /// The object's name.
        name: String,
        /// Why.
        source: GraspSimError,
    },
    /// An object cannot be prepared for the physics lift test.
    #[error("scene object {name}: {source}")]
    Physics {
        /// The object's name.
        name: String,
        /// Why.
        source: crate::sim::physics::PhysicsError,
    },
    /// The stiffness is not a positive finite number.
    #[error("contact stiffness {value} N/m must be finite and > 0")]
    Stiffness {
        /// The offending value.
        value: f64,
    },
    /// A shared-state file or directory could not be opened or created.
    #[error("shared simulator state {}: {}", .0.path.display(), .0.source)]
    Io(crate::fsio::FileError),
}

/// One object of the world.
#[derive(Debug, Clone)]
struct WorldObject {
    name: String,
    base_from_object: Pose,
    object: GraspObject,
    /// Its mesh (object frame).
    mesh: Arc<crate::mesh::TriMesh>,
    /// The object for the lift test ([`SimWorld::with_physics`]).
    physics: Option<Arc<PhysicsObject>>,
}

/// The objects and the table the simulated devices feel; see the module doc.
#[derive(Debug, Clone)]
pub struct SimWorld {
    hand: Arc<HandModel>,
    objects: Vec<WorldObject>,
    table: Option<TableBox>,
    stiffness_n_per_m: f64,
    /// The lift test's settings, when the objects are prepared for it.
    physics: Option<PhysicsOptions>,
}

/// Where the fingers stop when the hand closes in the world.
#[derive(Debug, Clone, PartialEq)]
pub struct Closing {
    /// Flex angle (rad) where each finger F1, F2, F3 stalls on the object or the
    /// table; `None`: it closes on air to its limit.
    pub stall_rad: [Option<f64>; 3],
    /// Whether the closed hand holds the object in force closure.
    pub force_closure: bool,
    /// The object closed on, if any.
    pub object: Option<String>,
    /// Where the palm closed (base frame): the palm backed off along its axis until
    /// the open hand is clear, when it was pressed into the object.
    pub base_from_palm: Pose,
}

impl SimWorld {
    /// The world of `scene`, felt by `hand`, with contact stiffness
    /// `stiffness_n_per_m` (N/m).
    pub fn new(
        scene: &Scene,
        hand: Arc<HandModel>,
        stiffness_n_per_m: f64,
    ) -> Result<SimWorld, WorldError> {
        if !(stiffness_n_per_m.is_finite() && stiffness_n_per_m > 0.0) {
            return Err(WorldError::Stiffness {
                value: stiffness_n_per_m,
            });
        }
        let objects = scene
            .objects
            .iter()
            .map(|o| {
                let object = GraspObject::new(&o.mesh, Path::new(&o.name)).map_err(|source| {
                    WorldError::Object {
                        name: o.name.clone(),
                        source,
                    }
                })?;
                // The grasp simulator's table is a plane of the object frame: for
                // an upright object it is the table top; tilted objects close
                // without it.
                let up = o.base_from_object.rotation * Vector3::z();
                let table_height_m = scene
                    .table
                    .filter(|_| (up.z - 1.0).abs() < 1e-9)
                    .map(|t| t.height_m - o.base_from_object.translation.z);
                Ok(WorldObject {
                    name: o.name.clone(),
                    base_from_object: o.base_from_object,
                    object: object.with_table(table_height_m),
                    mesh: Arc::new(o.mesh.clone()),
                    physics: None,
                })
            })
            .collect::<Result<_, WorldError>>()?;
        Ok(SimWorld {
            hand,
            objects,
            table: scene.table,
            stiffness_n_per_m,
            physics: None,
        })
    }

    /// The world of a scene file (table and camera defaults from `config`), felt
    /// by the configured hand with the configured simulated stiffness.
    pub fn load(
        path: &Path,
        config: &CellConfig,
        hand: Arc<HandModel>,
    ) -> Result<SimWorld, WorldError> {
        let loaded = load_scene(path, config)?;
        SimWorld::new(
            &loaded.scene,
            hand,
            config.approach.sim_contact_stiffness_n_per_m,
        )
    }

    /// The same world with every object prepared for the physics lift test
    /// (its convex decomposition, the expensive part: build it off any device's
    /// cycle, as [`WorldWatch`] does).
    pub fn with_physics(mut self, options: PhysicsOptions) -> Result<SimWorld, WorldError> {
        for o in &mut self.objects {
            let body =
                PhysicsObject::new(&o.mesh, Path::new(&o.name), &options).map_err(|source| {
                    WorldError::Physics {
                        name: o.name.clone(),
                        source,
                    }
                })?;
            o.physics = Some(Arc::new(body));
        }
        self.physics = Some(options);
        Ok(self)
    }

    /// Whether the objects are prepared for the lift test ([`SimWorld::with_physics`]).
    pub fn has_physics(&self) -> bool {
        self.physics.is_some()
    }

    /// Whether the object nearest the palm comes up when the hand closes at
    /// `base_from_palm` from `start` (spread and pre-shape) and the arm lifts: the
    /// physics lift test
    /// lifts it (held, or slipped within the hand). `None` when the world has no
    /// physics ([`SimWorld::with_physics`]) or no object.
    pub fn lift_holds(&self, base_from_palm: &Pose, start: &HandPose) -> Option<bool> {
        let options = self.physics.as_ref()?;
        let o = self.nearest(base_from_palm)?;
        let body = o.physics.as_ref()?;
        let scene = LiftScene {
            base_from_object: o.base_from_object,
            base_from_palm: *base_from_palm,
            preshape: clamped(&self.hand, start),
            table_height_m: self.table.map(|t| t.height_m),
        };
        match lift_test(&self.hand, body, &scene, options) {
            Ok(lift) => Some(matches!(lift.rule, LiftRule::Held | LiftRule::Slipped)),
            Err(e) => {
                tracing::warn!("lift test of {}: {e}", o.name);
                None
            }
        }
    }

    /// The object whose origin is nearest the palm.
    fn nearest(&self, base_from_palm: &Pose) -> Option<&WorldObject> {
        self.objects.iter().min_by(|a, b| {
            let d = |o: &WorldObject| {
                (o.base_from_object.translation.vector - base_from_palm.translation.vector).norm()
            };
            d(a).total_cmp(&d(b))
        })
    }

    /// The hand model.
    pub fn hand(&self) -> &HandModel {
        &self.hand
    }

    /// The force and torque the world exerts on the hand at `base_from_palm`
    /// with `hand` (distal links coupled): about the palm origin, palm frame,
    /// FRI order Fx Fy Fz (N) Tz Ty Tx (N m).
    pub fn tcp_wrench(&self, base_from_palm: &Pose, hand: &HandPose) -> [f64; 6] {
        let k = self.stiffness_n_per_m;
        let links = self.hand.link_poses(hand);
        let origin = base_from_palm.translation.vector;
        let (mut force, mut torque) = (Vector3::zeros(), Vector3::zeros());
        let mut add = |point: Point3<f64>, f: Vector3<f64>| {
            force += f;
            torque += (point.coords - origin).cross(&f);
        };
        let dispatcher = DefaultQueryDispatcher;
        for (link, palm_from_link) in &links {
            for (local, shape) in &link.shapes {
                let base_from_shape = base_from_palm * palm_from_link * local;
                if let Some(t) = &self.table {
                    let aabb = shape.compute_aabb(&base_from_shape);
                    let (lo, hi) = t.corners();
                    let over = aabb.maxs.x >= lo[0]
                        && aabb.mins.x <= hi[0]
                        && aabb.maxs.y >= lo[1]
                        && aabb.mins.y <= hi[1];
                    let depth = t.height_m - aabb.mins.z;
                    if over && depth > 0.0 {
                        let c = aabb.center();
                        add(Point3::new(c.x, c.y, t.height_m), Vector3::z() * k * depth);
                    }
                }
                for o in &self.objects {
                    let object_from_shape = o.base_from_object.inverse() * base_from_shape;
                    let aabb = shape.compute_aabb(&object_from_shape);
                    let mesh = o.object.mesh();
                    let mut deepest: Option<(f64, Point3<f64>, Vector3<f64>)> = None;
                    for id in mesh.bvh().intersect_aabb(&aabb) {
                        let triangle = mesh.triangle(id);
                        let Ok(Some(c)) =
                            dispatcher.contact(&object_from_shape, &triangle, shape.as_ref(), 0.0)
                        else {
                            continue;
                        };
                        if c.dist < 0.0 && deepest.is_none_or(|d| -c.dist > d.0) {
                            deepest = Some((-c.dist, c.point1, c.normal1.into_inner()));
                        }
                    }
                    if let Some((depth, point, normal)) = deepest {
                        // normal1 points from the surface toward the link: the
                        // object pushes the link that way.
                        add(
                            o.base_from_object * point,
                            o.base_from_object.rotation * normal * (k * depth),
                        );
                    }
                }
            }
        }
        let palm_from_base = base_from_palm.rotation.inverse();
        let (f, t) = (palm_from_base * force, palm_from_base * torque);
        [f.x, f.y, f.z, t.z, t.y, t.x]
    }

    /// Where the fingers stop when the hand closes at `base_from_palm` from
    /// `start` (the spread, clamped to the joint's range, and each finger's flex
    /// now: open, or the grasp's pre-shape): auto-grasp on the object
    /// nearest the palm. A palm slightly inside the object (a guarded move stops
    /// a little past first contact) is first backed off along its approach axis
    /// until clear, by at most 20 mm; a hand jammed deeper stalls where it is.
    pub fn closing(&self, base_from_palm: &Pose, start: &HandPose) -> Closing {
        let hand = &self.hand;
        let start = clamped(hand, start);
        let nearest = self.nearest(base_from_palm);
        let free = Closing {
            stall_rad: [None; 3],
            force_closure: false,
            object: None,
            base_from_palm: *base_from_palm,
        };
        let Some(o) = nearest else {
            return free;
        };
        let object_from_palm = o.base_from_object.inverse() * base_from_palm;
        let Some(pose) = retreat_until_clear(hand, &o.object, &object_from_palm, &start, 0.02)
        else {
            return Closing {
                stall_rad: start.flex_rad.map(Some),
                force_closure: false,
                object: Some(o.name.clone()),
                base_from_palm: *base_from_palm,
            };
        };
        let options = AutoGraspOptions::default();
        let Ok(e) = evaluate_grasp(
            hand,
            &o.object,
            &pose,
            &start,
            &options,
            &QualityParams::default(),
            false,
        ) else {
            // Inputs are checked above; should closing fail, the hand feels air.
            return free;
        };
        let stall_rad = std::array::from_fn(|i| {
            (e.outcome.stops[i] != FingerStop::Limit).then_some(e.outcome.hand.flex_rad[i])
        });
        Closing {
            stall_rad,
            force_closure: e.force_closure,
            object: Some(o.name.clone()),
            base_from_palm: o.base_from_object * pose,
        }
    }

    /// [`close_hand`] of the object nearest the palm, for tests and tools that
    /// want the whole outcome (object frame).
    pub fn close_nearest(
        &self,
        base_from_palm: &Pose,
        spread_rad: f64,
    ) -> Option<crate::quality::autograsp::GraspOutcome> {
        let o = self.nearest(base_from_palm)?;
        let pose = o.base_from_object.inverse() * base_from_palm;
        close_hand(
            &self.hand,
            &o.object,
            &pose,
            &HandPose::open(spread_rad),
            &AutoGraspOptions::default(),
        )
        .ok()
    }
}

/// One shared record of numbers: in memory, or in a file written whole.
#[derive(Debug, Clone)]
enum Cell {
    Memory(Arc<Mutex<Option<Vec<f64>>>>),
    File(Arc<std::fs::File>),
}

impl Cell {
    fn file(path: &Path) -> Result<Cell, WorldError> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(|source| WorldError::Io(FileError::new(FileOp::Read, path, source)))?;
        Ok(Cell::File(Arc::new(file)))
    }

    fn store(&self, values: &[f64]) {
        match self {
            Cell::Memory(m) => *m.lock().unwrap_or_else(|e| e.into_inner()) = Some(values.to_vec()),
            Cell::File(f) => {
                use std::os::unix::fs::FileExt;
                let mut bytes = Vec::with_capacity(8 * values.len() + 16);
                bytes.extend_from_slice(&(values.len() as u64).to_le_bytes());
                for v in values {
                    bytes.extend_from_slice(&v.to_le_bytes());
                }
                let sum = crate::hash::fnv1a(&bytes);
                bytes.extend_from_slice(&sum.to_le_bytes());
                if let Err(e) = f.write_at(&bytes, 0) {
                    tracing::warn!("shared simulator state: write failed: {e}");
                }
            }
        }
    }

    fn load(&self, n: usize) -> Option<Vec<f64>> {
        match self {
            Cell::Memory(m) => m
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone()
                .filter(|v| v.len() == n),
            Cell::File(f) => {
                use std::os::unix::fs::FileExt;
                let mut bytes = vec![0u8; 8 * n + 16];
                // A write may be under way: read again until the checksum holds.
                for _ in 0..8 {
                    if f.read_exact_at(&mut bytes, 0).is_err() {
                        return None;
                    }
                    let (body, sum) = bytes.split_at(8 * n + 8);
                    let len = u64::from_le_bytes(body[..8].try_into().ok()?);
                    if len != n as u64 {
                        return None;
                    }
                    if crate::hash::fnv1a(body).to_le_bytes() == sum {
                        return Some(
                            body[8..]
                                .chunks_exact(8)
                                .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
                                .collect(),
                        );
                    }
                }
                None
            }
        }
    }
}

/// The hand as the emulator last reported it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandState {
    /// Joints (rad).
    pub pose: HandPose,
    /// The fingers hold the object (it moves with the hand).
    pub holding: bool,
}

/// The arm and hand simulators' shared state; see the module doc.
#[derive(Debug, Clone)]
pub struct WorldLink {
    palm: Cell,
    hand: Cell,
}

impl WorldLink {
    /// State shared between threads of one process.
    pub fn memory() -> WorldLink {
        WorldLink {
            palm: Cell::Memory(Arc::default()),
            hand: Cell::Memory(Arc::default()),
        }
    }

    /// State shared between processes: `palm.state` and `hand.state` in `dir`
    /// (created if missing).
    pub fn files(dir: &Path) -> Result<WorldLink, WorldError> {
        crate::fsio::create_dir_all(dir).map_err(WorldError::Io)?;
        Ok(WorldLink {
            palm: Cell::file(&dir.join("palm.state"))?,
            hand: Cell::file(&dir.join("hand.state"))?,
        })
    }

    /// Publishes the measured palm pose (base frame).
    pub fn set_palm(&self, base_from_palm: &Pose) {
        let t = base_from_palm.translation.vector;
        let q = base_from_palm.rotation.coords;
        self.palm.store(&[t.x, t.y, t.z, q.x, q.y, q.z, q.w]);
    }

    /// The palm pose last published, if any.
    pub fn palm(&self) -> Option<Pose> {
        let v = self.palm.load(7)?;
        let q = nalgebra::Quaternion::new(v[6], v[3], v[4], v[5]);
        (q.norm() > 0.5).then(|| {
            Pose::from_parts(
                Translation3::new(v[0], v[1], v[2]),
                UnitQuaternion::from_quaternion(q),
            )
        })
    }

    /// Publishes the hand's state.
    pub fn set_hand(&self, state: &HandState) {
        let p = &state.pose;
        self.hand.store(&[
            p.spread_rad,
            p.flex_rad[0],
            p.flex_rad[1],
            p.flex_rad[2],
            if state.holding { 1.0 } else { 0.0 },
        ]);
    }

    /// The hand's state last published; the open hand when none was.
    pub fn hand(&self) -> HandState {
        self.hand.load(5).map_or(
            HandState {
                pose: HandPose::OPEN,
                holding: false,
            },
            |v| HandState {
                pose: HandPose {
                    spread_rad: v[0],
                    flex_rad: [v[1], v[2], v[3]],
                },
                holding: v[4] != 0.0,
            },
        )
    }
}

/// The world now: fixed, or reloaded from a scene file when it changes.
#[derive(Clone)]
pub struct WorldWatch {
    current: Arc<Mutex<Option<Arc<SimWorld>>>>,
    stop: Arc<AtomicBool>,
}

impl std::fmt::Debug for WorldWatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorldWatch").finish_non_exhaustive()
    }
}

impl WorldWatch {
    /// A fixed world (`None`: empty, the hand feels only air).
    pub fn fixed(world: Option<SimWorld>) -> WorldWatch {
        WorldWatch {
            current: Arc::new(Mutex::new(world.map(Arc::new))),
            stop: Arc::new(AtomicBool::new(false)),
        }
    }

    /// What a simulator process (`cell-sim-arm`, `cell-sim-hand`) feels: scene file
    /// `scene` watched every 50 ms (its objects prepared for the lift test with
    /// `physics`), and the state shared with the other simulator in `state_dir`
    /// (default: the scene's directory), which is also returned.
    pub fn for_simulator(
        scene: &Path,
        state_dir: Option<&Path>,
        config: CellConfig,
        hand: Arc<HandModel>,
        physics: Option<PhysicsOptions>,
    ) -> Result<(WorldWatch, WorldLink, PathBuf), WorldError> {
        let dir = state_dir
            .or_else(|| scene.parent())
            .map(Path::to_path_buf)
            .unwrap_or_default();
        let link = WorldLink::files(&dir)?;
        let watch = WorldWatch::scene_file(
            scene.to_path_buf(),
            config,
            hand,
            physics,
            Duration::from_millis(50),
            Some(scene_loaded_path(&dir, std::process::id())),
        );
        Ok((watch, link, dir))
    }

    /// The world of scene file `path`, reloaded (on a thread of its own, every
    /// `poll` at most) whenever the file's modification time changes; empty
    /// while there is no file. A file that fails to load is logged and the
    /// world emptied (the devices feel nothing rather than a stale object). With
    /// `physics` each loaded world is prepared for the lift test
    /// ([`SimWorld::with_physics`]) before it replaces the last one. After each
    /// load (or failure) the file's modification time is written to `loaded`
    /// ([`scene_modified_ns`]), so that whoever wrote the scene can wait until the
    /// devices feel it ([`wait_until_scene_loaded`]).
    pub fn scene_file(
        path: PathBuf,
        config: CellConfig,
        hand: Arc<HandModel>,
        physics: Option<PhysicsOptions>,
        poll: Duration,
        loaded: Option<PathBuf>,
    ) -> WorldWatch {
        let watch = WorldWatch::fixed(None);
        let (current, stop) = (Arc::clone(&watch.current), Arc::clone(&watch.stop));
        let spawned = std::thread::Builder::new()
            .name("world-watch".into())
            .spawn(move || {
                // Loading (a convex decomposition with physics) is background work.
                crate::hw::realtime::lower_thread_priority();
                let mut seen: Option<SystemTime> = None;
                while !stop.load(Ordering::Relaxed) {
                    let modified = modified_at(&path);
                    if modified != seen {
                        seen = modified;
                        let world = match modified {
                            None => None,
                            Some(_) => match SimWorld::load(&path, &config, Arc::clone(&hand))
                                .and_then(|w| match physics {
                                    Some(options) => w.with_physics(options),
                                    None => Ok(w),
                                }) {
                                Ok(w) => {
                                    tracing::info!(scene = %path.display(), objects = w.objects.len(), "simulated world loaded");
                                    Some(Arc::new(w))
                                }
                                Err(e) => {
                                    tracing::error!("simulated world: {e}");
                                    None
                                }
                            },
                        };
                        *current.lock().unwrap_or_else(|e| e.into_inner()) = world;
                        if let (Some(ack), Some(ns)) = (&loaded, modified.and_then(since_epoch_ns)) {
                            if let Err(e) = crate::fsio::write_atomically(ack, ns.to_string().as_bytes()) {
                                tracing::warn!("cannot acknowledge the scene in {}: {e}", ack.display());
                            }
                        }
                    }
                    std::thread::sleep(poll);
                }
            });
        if let Err(e) = spawned {
            tracing::error!("cannot start the scene watcher: {e}");
        }
        watch
    }

    /// The world now.
    pub fn get(&self) -> Option<Arc<SimWorld>> {
        self.current
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }
}

/// Where a simulator process `pid` with state directory `state_dir` acknowledges
/// the scene it loaded last ([`WorldWatch::scene_file`]).
pub fn scene_loaded_path(state_dir: &Path, pid: u32) -> PathBuf {
    state_dir.join(format!("scene-loaded.{pid}"))
}

/// A time as nanoseconds since the Unix epoch (`None` before it).
fn since_epoch_ns(t: SystemTime) -> Option<u64> {
    t.duration_since(SystemTime::UNIX_EPOCH)
        .ok()
        .map(|d| d.as_nanos() as u64)
}

/// The modification time of `path` (`None` without a file).
fn modified_at(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// The modification time of `path` (ns since the epoch), as a watcher acknowledges it.
pub fn scene_modified_ns(path: &Path) -> Option<u64> {
    modified_at(path).and_then(since_epoch_ns)
}

/// Waits until every acknowledgement file in `acks` names the scene file `scene`
/// as it is now (its modification time): the simulated devices feel the scene
/// just written. Polls every 5 ms; false when `timeout` passed first.
pub fn wait_until_scene_loaded(scene: &Path, acks: &[PathBuf], timeout: Duration) -> bool {
    let Some(want) = scene_modified_ns(scene) else {
        return false;
    };
    let started = std::time::Instant::now();
    loop {
        let loaded = acks.iter().all(|ack| {
            std::fs::read_to_string(ack)
                .ok()
                .and_then(|t| t.trim().parse::<u64>().ok())
                == Some(want)
        });
        if loaded {
            return true;
        }
        if started.elapsed() > timeout {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

impl Drop for WorldWatch {
    fn drop(&mut self) {
        // The last handle stops the watcher thread.
        if Arc::strong_count(&self.current) <= 2 {
            self.stop.store(true, Ordering::Relaxed);
        }
    }
}

/// The arm simulator's side: publishes the palm pose and reports the world's
/// force on the hand ([`crate::sim::fri::ExternalForce`]).
pub struct ArmContact {
    robot: Arc<Robot>,
    world: WorldWatch,
    link: WorldLink,
}

impl ArmContact {
    /// The arm `robot` in `world`, sharing `link` with the hand.
    pub fn new(robot: Arc<Robot>, world: WorldWatch, link: WorldLink) -> ArmContact {
        ArmContact { robot, world, link }
    }
}

impl crate::sim::fri::ExternalForce for ArmContact {
    fn tcp_ft(&mut self, measured_rad: &[f64; crate::hw::fri::JOINTS]) -> [f64; 6] {
        let palm = self.robot.arm().palm(measured_rad);
        self.link.set_palm(&palm);
        let hand = self.link.hand();
        match self.world.get() {
            Some(world) if !hand.holding => world.tcp_wrench(&palm, &hand.pose),
            _ => [0.0; 6],
        }
    }
}

/// The hand emulator's side: stall angles from the world at the palm pose the
/// arm publishes; an object the hand does not hold ([`SimWorld::lift_holds`], or
/// without physics force closure) stays behind when the palm moves more than
/// [`HandContact::DROP_DISTANCE_M`] from where the hand closed
/// ([`crate::sim::puck::Feel`]).
pub struct HandContact {
    world: WorldWatch,
    link: WorldLink,
    /// Where the hand last closed, whether that grasp holds, and its spread.
    closed: Option<(Pose, Hold, f64)>,
}

/// `start` within the hand's joint ranges (spread and each finger's flex).
fn clamped(hand: &HandModel, start: &HandPose) -> HandPose {
    let (lo, hi) = hand.spread_limits_rad;
    HandPose {
        spread_rad: start.spread_rad.clamp(lo, hi),
        flex_rad: std::array::from_fn(|i| {
            let (lo, hi) = hand.fingers[i].flex_limits_rad;
            start.flex_rad[i].clamp(lo, hi)
        }),
    }
}

/// Whether a closed grasp holds the object: known, or the lift test still running
/// on its own thread (the static rule stands in should it fail to answer).
enum Hold {
    Known(bool),
    Pending {
        answer: std::sync::mpsc::Receiver<Option<bool>>,
        static_rule: bool,
    },
}

impl Hold {
    /// Whether the grasp closed at `closed_at` holds: by the lift test when `world`
    /// has physics, else (or should the test not start) by `static_rule` at once.
    /// The lift test takes tens of milliseconds, longer than a CAN reply may: it
    /// runs beside the emulator, at the lowest priority.
    fn start(world: Arc<SimWorld>, closed_at: Pose, from: HandPose, static_rule: bool) -> Hold {
        if !world.has_physics() {
            return Hold::Known(static_rule);
        }
        let (send, answer) = std::sync::mpsc::channel();
        let test = std::thread::Builder::new()
            .name("lift-test".into())
            .spawn(move || {
                crate::hw::realtime::lower_thread_priority();
                send.send(world.lift_holds(&closed_at, &from))
            });
        match test {
            Ok(_) => Hold::Pending {
                answer,
                static_rule,
            },
            Err(_) => Hold::Known(static_rule),
        }
    }

    /// Whether the grasp holds, as far as known now: the emulator never waits for
    /// the lift test (a CAN reply must not), and until it answers (tens of
    /// milliseconds after closing, long before the arm lifts) the object stays.
    fn holds(&mut self) -> bool {
        if let Hold::Pending {
            answer,
            static_rule,
        } = self
        {
            match answer.try_recv() {
                Ok(Some(held)) => *self = Hold::Known(held),
                Ok(None) | Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                    *self = Hold::Known(*static_rule)
                }
                Err(std::sync::mpsc::TryRecvError::Empty) => return true,
            }
        }
        matches!(self, Hold::Known(true))
    }
}

impl HandContact {
    /// The distance the palm may move from where the hand closed before an
    /// object the hand does not hold slips out.
    pub const DROP_DISTANCE_M: f64 = 0.005;

    /// The hand in `world`, sharing `link` with the arm.
    pub fn new(world: WorldWatch, link: WorldLink) -> HandContact {
        HandContact {
            world,
            link,
            closed: None,
        }
    }
}

impl crate::sim::puck::Feel for HandContact {
    fn contacts(&mut self, start: &HandPose) -> [Option<f64>; 3] {
        let (Some(world), Some(palm)) = (self.world.get(), self.link.palm()) else {
            self.closed = None;
            return [None; 3];
        };
        let spread_rad = start.spread_rad;
        let c = world.closing(&palm, start);
        tracing::debug!(?c, "hand closes in the simulated world");
        // Each finger's close command asks again: one lift test per closing.
        let same_closing = self.closed.as_ref().is_some_and(|(at, _, spread)| {
            *spread == spread_rad && crate::geometry::pose_error(at, &palm).0 < 1e-4
        });
        if !same_closing {
            let hold = Hold::start(world, c.base_from_palm, *start, c.force_closure);
            self.closed = Some((palm, hold, spread_rad));
        }
        c.stall_rad
    }

    fn still_held(&mut self) -> bool {
        match (&mut self.closed, self.link.palm()) {
            (Some((at, hold, _)), Some(palm)) => {
                (palm.translation.vector - at.translation.vector).norm() <= Self::DROP_DISTANCE_M
                    || hold.holds()
            }
            _ => true,
        }
    }

    fn hand_moved(&mut self, pose: &HandPose, holding: bool) {
        self.link.set_hand(&HandState {
            pose: *pose,
            holding,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::hw::can::{CanBus, VirtualBus};
    use crate::hw::hand::{Hand, HandPositions, HandTiming, Puck};
    use crate::mesh::procedural::{generate, Category};
    use crate::quality::approach::{approach_to_contact, ApproachOptions};
    use crate::quality::autograsp::tests::{cuboid, hand_of};
    use crate::robot::shipped_robot;
    use crate::sim::puck::{HandEmulator, HandEmulatorConfig};
    use crate::sim::scene::TableBox;
    use std::f64::consts::PI;

    fn hand() -> Arc<HandModel> {
        Arc::new(hand_of(&shipped_robot()))
    }

    fn table() -> TableBox {
        TableBox {
            height_m: 0.0,
            center_xy_m: [0.65, 0.0],
            extent_xy_m: [0.8, 1.2],
            thickness_m: 0.05,
        }
    }

    /// A mug standing on the table at (0.6, 0, 0), and its mesh.
    fn mug_world() -> (SimWorld, TriMesh) {
        let mesh = generate(Category::Mug, 5).0;
        let mut scene = Scene::new(Some(table()));
        scene
            .add("mug", mesh.clone(), Pose::translation(0.6, 0.0, 0.0))
            .unwrap();
        (SimWorld::new(&scene, hand(), 2e4).unwrap(), mesh)
    }

    use crate::mesh::TriMesh;

    /// Whoever writes a scene can wait until a watching device has loaded it: the
    /// watcher acknowledges each load (a failed one too) with the file's
    /// modification time, and a stale acknowledgement is not taken for it.
    #[test]
    fn a_watched_scene_is_acknowledged_once_loaded() {
        let dir = crate::fsio::TempDir::new("scene-ack").unwrap();
        let scene = dir.join("scene.toml");
        let ack = scene_loaded_path(&dir, 7);
        std::fs::write(&scene, "objects = [").unwrap();
        let config = CellConfig::load(Path::new(crate::config::BUILTIN_CONFIG)).unwrap();
        let watch = WorldWatch::scene_file(
            scene.clone(),
            config,
            hand(),
            None,
            Duration::from_millis(5),
            Some(ack.clone()),
        );
        assert!(wait_until_scene_loaded(
            &scene,
            std::slice::from_ref(&ack),
            Duration::from_secs(10)
        ));
        assert!(watch.get().is_none(), "a scene that fails to load is empty");
        std::fs::write(&ack, "12").unwrap();
        drop(watch);
        std::thread::sleep(Duration::from_millis(20));
        assert!(!wait_until_scene_loaded(
            &scene,
            &[ack],
            Duration::from_millis(30)
        ));
        assert!(!wait_until_scene_loaded(
            &dir.join("missing.toml"),
            &[],
            Duration::from_millis(1)
        ));
    }

    #[test]
    fn the_contact_force_is_penetration_times_stiffness_along_the_normal() {
        // A box whose top is at z = 0.3 under a palm facing down: the fingertips
        // (open hand) press 2 mm into it.
        let hand = hand();
        let open = HandPose::OPEN;
        let reach = hand
            .link_poses(&open)
            .iter()
            .flat_map(|(link, pose)| {
                link.shapes
                    .iter()
                    .map(move |(local, shape)| shape.compute_aabb(&(pose * local)).maxs.z)
            })
            .fold(f64::MIN, f64::max);
        let mut scene = Scene::new(None);
        scene
            .add(
                "box",
                cuboid([0.0, 0.0, 0.0], [0.4, 0.4, 0.1]),
                Pose::translation(0.6, 0.0, 0.25),
            )
            .unwrap();
        let world = SimWorld::new(&scene, Arc::clone(&hand), 2e4).unwrap();
        let down = |z: f64| {
            Pose::from_parts(
                Translation3::new(0.6, 0.0, z),
                UnitQuaternion::from_euler_angles(PI, 0.0, 0.0),
            )
        };
        let free = world.tcp_wrench(&down(0.3 + reach + 0.001), &open);
        assert_eq!(free, [0.0; 6]);
        let ft = world.tcp_wrench(&down(0.3 + reach - 0.002), &open);
        // In the palm frame the push is along -z (back against the approach),
        // one link's 2 mm at least, at most every link's.
        let links = hand.link_poses(&open).len() as f64;
        assert!(ft[0].abs() < 1e-6 && ft[1].abs() < 1e-6, "{ft:?}");
        assert!(
            ft[2] < -40.0 + 1e-6 && ft[2] > -40.0 * links - 1e-6,
            "{ft:?}"
        );
        // A table under the hand pushes up too.
        let mut on_table = Scene::new(Some(table()));
        on_table
            .add(
                "far",
                cuboid([0.0; 3], [0.01; 3]),
                Pose::translation(2.0, 0.0, 0.0),
            )
            .unwrap();
        let world = SimWorld::new(&on_table, hand, 2e4).unwrap();
        let ft = world.tcp_wrench(&down(reach - 0.001), &open);
        assert!(ft[2] < -20.0 + 1e-6, "{ft:?}");
        assert!(SimWorld::new(&Scene::new(None), hand_arc(), 0.0)
            .unwrap_err()
            .to_string()
            .contains("stiffness"));
    }

    fn hand_arc() -> Arc<HandModel> {
        hand()
    }

    /// The hand driver on a virtual bus with an emulator feeling `world` at the
    /// palm pose published on `link`.
    fn hand_in(
        world: SimWorld,
        link: &WorldLink,
        name: &str,
    ) -> (Hand<Box<dyn CanBus>>, crate::sim::puck::EmulatorThread) {
        let bus = VirtualBus::new(name);
        let node = bus.endpoint();
        let probe = node.idle_probe();
        let clock: Arc<dyn crate::clock::Clock> =
            Arc::new(ManualClock::new().with_settle(move || {
                probe.wait_idle(Duration::from_secs(5));
            }));
        let feel = HandContact::new(WorldWatch::fixed(Some(world)), link.clone());
        let emulator = HandEmulator::new(HandEmulatorConfig::default(), Arc::clone(&clock))
            .unwrap()
            .with_feel(Box::new(feel))
            .spawn(node);
        let mut hand = Hand::new(
            Box::new(bus.endpoint()) as Box<dyn CanBus>,
            clock,
            HandTiming::default(),
        );
        let t = Duration::from_secs(30);
        hand.wake(t).unwrap();
        hand.identify(t).unwrap();
        hand.initialise(t).unwrap();
        (hand, emulator)
    }

    fn preshape(hand: &mut Hand<Box<dyn CanBus>>, spread_rad: f64) -> [i32; 3] {
        let t = Duration::from_secs(10);
        hand.move_to(
            &HandPositions {
                fingers_rad: [0.0; 3],
                spread_rad,
            },
            t,
        )
        .unwrap();
        hand.strain(t).unwrap()
    }

    #[test]
    fn a_grasp_on_a_mug_stops_the_fingers_at_the_grasp_simulators_contact_angles() {
        let (world, mesh) = mug_world();
        let hand_model = hand();
        // A side grasp at mid-height: approach along +x from well outside.
        let (lo, hi) = mesh
            .vertices
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), v| {
                (lo.min(v.z), hi.max(v.z))
            });
        let side =
            nalgebra::Rotation3::from_basis_unchecked(&[Vector3::z(), -Vector3::y(), Vector3::x()]);
        let planned = Pose::from_parts(
            Translation3::new(-0.12, 0.0, (hi - 0.02).max(0.5 * (lo + hi))),
            UnitQuaternion::from_rotation_matrix(&side),
        );
        let object = GraspObject::new(&mesh, Path::new("mug"))
            .unwrap()
            .with_table(Some(0.0));
        let spread = 0.0;
        let stop = approach_to_contact(
            &hand_model,
            &object,
            &planned,
            &HandPose::open(spread),
            &ApproachOptions::default(),
        )
        .unwrap();
        assert!(stop.contact.is_some(), "{stop:?}");
        // The grasp simulator, independently of the emulator.
        let expected = close_hand(
            &hand_model,
            &object,
            &stop.object_from_palm,
            &HandPose::open(spread),
            &AutoGraspOptions::default(),
        )
        .unwrap();
        let touching: Vec<usize> = (0..3)
            .filter(|&i| expected.stops[i] != FingerStop::Limit)
            .collect();
        assert!(touching.len() >= 2, "{expected:?}");

        let link = WorldLink::memory();
        let base_from_palm = Pose::translation(0.6, 0.0, 0.0) * stop.object_from_palm;
        link.set_palm(&base_from_palm);
        let (mut hand, _emulator) = hand_in(world, &link, "world-mug");
        let baseline = preshape(&mut hand, spread);
        let t = Duration::from_secs(10);
        let outcomes = hand.close(t).unwrap();
        let positions = hand.positions(t).unwrap();
        let strain = hand.strain(t).unwrap();
        for i in 0..3 {
            let o = outcomes
                .iter()
                .find(|o| o.puck == Puck::FINGERS[i])
                .unwrap();
            if touching.contains(&i) {
                assert!(!o.reached_target, "F{}: {o:?}", i + 1);
                assert!(
                    (positions.fingers_rad[i] - expected.hand.flex_rad[i]).abs() < 2e-3,
                    "F{}: driver {} rad, grasp simulator {} rad",
                    i + 1,
                    positions.fingers_rad[i],
                    expected.hand.flex_rad[i]
                );
                assert!(strain[i] - baseline[i] >= 300, "{strain:?} {baseline:?}");
            } else {
                assert!(o.reached_target, "F{}: {o:?}", i + 1);
            }
        }
        // The hand told the arm's side that it holds the object.
        assert!(link.hand().holding);
        assert!(
            (link.hand().pose.flex_rad[touching[0]] - positions.fingers_rad[touching[0]]).abs()
                < 2e-3
        );
    }

    #[test]
    fn a_grasp_on_air_reports_no_contact_through_the_hand_driver() {
        let (world, _) = mug_world();
        let link = WorldLink::memory();
        // The palm 0.3 m above the mug, facing down: nothing within reach.
        link.set_palm(&Pose::from_parts(
            Translation3::new(0.6, 0.0, 0.6),
            UnitQuaternion::from_euler_angles(PI, 0.0, 0.0),
        ));
        let (mut hand, _emulator) = hand_in(world, &link, "world-air");
        let baseline = preshape(&mut hand, 0.3);
        let t = Duration::from_secs(10);
        let outcomes = hand.close(t).unwrap();
        let strain = hand.strain(t).unwrap();
        for o in outcomes.iter().filter(|o| o.puck.is_finger()) {
            assert!(o.reached_target, "{o:?}");
        }
        assert_eq!(strain, baseline);
        assert!(!link.hand().holding);
    }

    /// The hold decision is the physics lift test's: a side grasp of a 35 mm
    /// cylinder (the physics tests' case) lifts it, the same grasp 0.3 m beside it
    /// lifts nothing; a world without physics does not decide.
    #[test]
    fn the_object_comes_up_only_when_the_lift_test_lifts_it() {
        let (_, lift) = crate::sim::physics::tests::side_grasp();
        let mut scene = Scene::new(Some(table()));
        let mesh = crate::quality::autograsp::tests::cylinder(0.035, 0.12, 32);
        scene.add("cylinder", mesh, lift.base_from_object).unwrap();
        let world = SimWorld::new(&scene, hand(), 2e4).unwrap();
        let palm = lift.base_from_palm;
        assert_eq!(world.lift_holds(&palm, &HandPose::open(0.0)), None);
        let world = world.with_physics(PhysicsOptions::default()).unwrap();
        assert_eq!(world.lift_holds(&palm, &HandPose::open(0.0)), Some(true));
        let beside = Pose::translation(0.0, 0.3, 0.0) * palm;
        assert_eq!(world.lift_holds(&beside, &HandPose::open(0.0)), Some(false));
    }

    #[test]
    fn shared_state_files_round_trip_between_handles() {
        let dir = crate::fsio::TempDir::new("world-link").unwrap();
        let a = WorldLink::files(&dir).unwrap();
        let b = WorldLink::files(&dir).unwrap();
        assert_eq!(b.palm(), None);
        let pose = Pose::from_parts(
            Translation3::new(0.5, -0.1, 0.3),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        );
        a.set_palm(&pose);
        let got = b.palm().unwrap();
        assert!((got.translation.vector - pose.translation.vector).norm() < 1e-12);
        assert!(got.rotation.angle_to(&pose.rotation) < 1e-9);
        let state = HandState {
            pose: HandPose {
                spread_rad: 0.4,
                flex_rad: [1.0, 1.1, 1.2],
            },
            holding: true,
        };
        b.set_hand(&state);
        assert_eq!(a.hand(), state);
    }
}
