//! `cell quality` and `cell bench quality-metric`.

use super::bench::{cpu_ms, median, QualityMetricBenchArgs};
use crate::config::CellConfig;
use crate::geometry::PoseJson;
use crate::geometry::{params_from_pose, parse_pose};
use crate::mesh::load_mesh;
use crate::quality::approach::{ApproachOptions, ApproachStop};
use crate::quality::autograsp::{
    evaluate_approached_grasp, evaluate_grasp, AutoGraspOptions, FingerStop, GraspApproach,
    GraspObject, Obstacle, StartCollision,
};
use crate::quality::stability::{stability_range, StabilityOptions, StabilityRange};
use crate::quality::{self, gws, wrench, Contact, GraspQuality, QualityParams};
use crate::robot::hand::HandModel;
use crate::sim::physics::{lift_test, LiftOutcome, LiftScene, PhysicsObject, PhysicsOptions};
use anyhow::Context;
use clap::Args;
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell quality`.
#[derive(Debug, Args)]
pub struct QualityArgs {
    /// Contacts file (JSON): {"mu": 0.5, "torque_scale": 0.05, "contacts": [{"point":
    /// [x,y,z], "normal": [nx,ny,nz]}], "centroid": [x,y,z], "cone_edges": 8}; metres,
    /// inward normals. Optional: mu (0.5), cone_edges (8), centroid (mean of the contact
    /// points), torque_scale (largest distance of a contact from the centroid).
    #[arg(long, required_unless_present = "object", conflicts_with = "object")]
    pub contacts: Option<PathBuf>,
    /// Object mesh (OBJ, STL or PLY; metres, closed and outward) to close the hand
    /// around (auto-grasp); needs --pose.
    #[arg(long, requires = "pose")]
    pub object: Option<PathBuf>,
    /// Palm pose (bh_palm) in the object's frame: x,y,z,roll,pitch,yaw (m, rad, URDF rpy).
    #[arg(long, requires = "object", allow_hyphen_values = true)]
    pub pose: Option<String>,
    /// Spread of F1 and F2 about the palm normal (rad, 0..pi).
    #[arg(
        long,
        default_value_t = 0.0,
        requires = "object",
        allow_hyphen_values = true
    )]
    pub spread: f64,
    /// Height of a table top in the object's frame (m): the table becomes an obstacle.
    #[arg(long, requires = "object", allow_hyphen_values = true)]
    pub table_z: Option<f64>,
    /// Friction coefficient for --object.
    #[arg(long, default_value_t = 0.5, requires = "object")]
    pub mu: f64,
    /// Also compute the stability ranges (Delta, sigma per DOF) for --object.
    #[arg(long, requires = "object")]
    pub stability: bool,
    /// Approach to contact before closing (as the executor does): from the
    /// pre-grasp (robot.pregrasp_offset_m back along the palm's -z) the open hand
    /// moves along +z through --pose, at most approach.max_overtravel_m beyond it,
    /// and stops at first contact. Without it the hand closes at --pose (the
    /// paper's setting).
    #[arg(long, requires = "object")]
    pub approach_to_contact: bool,
    /// Also run the physics lift test (rapier3d) for --object: close, lift 0.10 m,
    /// hold 2 s, with the object free on the table (--table-z) and friction --mu.
    /// The object frame must be upright (z up). Prints the verdict, lift height,
    /// slip and the hand parts touching.
    #[arg(long, requires = "object")]
    pub lift: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// The contacts file of `cell quality --contacts`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactsFile {
    /// Friction coefficient.
    #[serde(default = "default_mu")]
    pub mu: f64,
    /// Torque scale (m).
    #[serde(default)]
    pub torque_scale: Option<f64>,
    /// The contacts.
    pub contacts: Vec<Contact>,
    /// Reference point for torques (m).
    #[serde(default)]
    pub centroid: Option<Point3<f64>>,
    /// Edges of the friction pyramid.
    #[serde(default = "default_cone_edges")]
    pub cone_edges: usize,
}

fn default_mu() -> f64 {
    QualityParams::default().mu
}

fn default_cone_edges() -> usize {
    QualityParams::default().cone_edges
}

impl ContactsFile {
    /// The metric parameters the file asks for.
    pub fn params(&self) -> QualityParams {
        QualityParams {
            mu: self.mu,
            cone_edges: self.cone_edges,
            torque_scale_m: self.torque_scale,
            centroid: self.centroid,
        }
    }
}

/// Runs `cell quality`.
pub fn run(config: &Path, args: QualityArgs) -> anyhow::Result<ExitCode> {
    if let Some(object) = &args.object {
        return run_object(config, object, &args);
    }
    let path = args
        .contacts
        .as_deref()
        .context("--contacts or --object is required")?;
    let q = evaluate_file(path)?;
    super::emit(args.json, &q, |q: &GraspQuality| {
        format!(
            "epsilon {:.6}, volume {:.6e}, force closure: {}\n",
            q.epsilon,
            q.volume,
            if q.force_closure { "yes" } else { "no" }
        )
    })?;
    Ok(ExitCode::SUCCESS)
}

/// A contact in the output of `cell quality --object`.
#[derive(Debug, Serialize)]
struct ContactJson {
    link: String,
    point: [f64; 3],
    normal: [f64; 3],
}

/// The output of `cell quality --object`.
#[derive(Debug, Serialize)]
struct AutoGraspReport {
    epsilon: f64,
    volume: f64,
    force_closure: bool,
    collision_at_start: bool,
    /// Which link collides with what, when collision_at_start.
    start_collision: Option<StartCollision>,
    contacts: Vec<ContactJson>,
    spread_rad: f64,
    flex_rad: [f64; 3],
    distal_rad: [f64; 3],
    stops: [FingerStop; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    stability: Option<StabilityRange>,
    /// Where the palm stopped, with --approach-to-contact.
    #[serde(skip_serializing_if = "Option::is_none")]
    approach: Option<ApproachStop>,
    /// The physics lift test, with --lift.
    #[serde(skip_serializing_if = "Option::is_none")]
    lift: Option<LiftOutcome>,
}

fn run_object(config: &Path, object: &Path, args: &QualityArgs) -> anyhow::Result<ExitCode> {
    let text = args.pose.as_deref().context("--object needs --pose")?;
    let pose = parse_pose(text).with_context(|| format!("--pose {text}"))?;
    let config = CellConfig::load(config)?;
    let hand = HandModel::load(&config)?;
    let mesh = load_mesh(object, 1.0)?;
    let grasp_object = GraspObject::new(&mesh, object)?.with_table(args.table_z);
    let options = AutoGraspOptions::default();
    let params = QualityParams {
        mu: args.mu,
        ..QualityParams::default()
    };
    let approach = if args.approach_to_contact {
        GraspApproach::ToContact(ApproachOptions::from_cell(&config))
    } else {
        GraspApproach::AtPose
    };
    let e = evaluate_approached_grasp(
        &hand,
        &grasp_object,
        &pose,
        args.spread,
        &approach,
        &options,
        &params,
        true,
    )
    .with_context(|| format!("grasp of {}", object.display()))?;
    let stability = if args.stability {
        Some(stability_range(
            &hand,
            &grasp_object,
            &params_from_pose(&pose),
            args.spread,
            &options,
            &params,
            &StabilityOptions::default(),
        )?)
    } else {
        None
    };
    let lift = if args.lift {
        let options = PhysicsOptions {
            friction: args.mu,
            ..PhysicsOptions::default()
        };
        let body = PhysicsObject::new(&mesh, object, &options)?;
        let scene = LiftScene {
            base_from_object: crate::geometry::Pose::identity(),
            base_from_palm: pose,
            spread_rad: args.spread,
            table_height_m: args.table_z,
        };
        Some(
            lift_test(&hand, &body, &scene, &options)
                .with_context(|| format!("lift test of {}", object.display()))?,
        )
    } else {
        None
    };
    let o = e.outcome;
    let report = AutoGraspReport {
        epsilon: e.epsilon,
        volume: e.volume.unwrap_or(0.0),
        force_closure: e.force_closure,
        collision_at_start: o.collision_at_start.is_some(),
        start_collision: o.collision_at_start,
        contacts: o
            .contacts
            .iter()
            .map(|c| ContactJson {
                link: c.link.clone(),
                point: c.point.into(),
                normal: c.normal.into(),
            })
            .collect(),
        spread_rad: o.hand.spread_rad,
        flex_rad: o.hand.flex_rad,
        distal_rad: o.distal_rad,
        stops: o.stops,
        stability,
        approach: e.approach,
        lift,
    };
    super::emit(args.json, &report, |r: &AutoGraspReport| {
        let mut text = match &r.approach {
            Some(a) => {
                let p = PoseJson::from(&a.object_from_palm);
                format!(
                    "approach: palm stopped at {:.4},{:.4},{:.4} m ({:+.1} mm beyond --pose, {:.1} mm from the pre-grasp): {}\n",
                    p.xyz[0],
                    p.xyz[1],
                    p.xyz[2],
                    1e3 * a.beyond_plan_m,
                    1e3 * a.travel_m,
                    match (&a.start_collision, &a.contact) {
                        (Some(c), _) => format!("the pre-grasp collides: {c}"),
                        (None, Some(c)) => format!("first contact: link {} with the {}", c.link, match c.with {
                            Obstacle::Table => "table",
                            _ => "object",
                        }),
                        (None, None) => "no contact within the overtravel".to_string(),
                    }
                )
            }
            None => String::new(),
        };
        text += &match &r.start_collision {
            Some(c) => format!("invalid start: {c}\n"),
            None => format!(
                "epsilon {:.6}, volume {:.6e}, force closure: {}, {} contacts\n",
                r.epsilon,
                r.volume,
                if r.force_closure { "yes" } else { "no" },
                r.contacts.len()
            ),
        };
        for c in &r.contacts {
            text += &format!(
                "  {:<16} point {:>7.1} {:>7.1} {:>7.1} mm  normal {:>6.3} {:>6.3} {:>6.3}\n",
                c.link,
                1e3 * c.point[0],
                1e3 * c.point[1],
                1e3 * c.point[2],
                c.normal[0],
                c.normal[1],
                c.normal[2]
            );
        }
        if let Some(l) = &r.lift {
            text += &format!(
                "physics: {:?} ({:?}): rose {:.1} mm, slip {:.1} mm, turn {:.1} deg, touching {}; \
                 mass {:.3} kg, closed in {:.2} s, {} steps\n",
                l.grade,
                l.rule,
                1e3 * l.lift_height_m,
                1e3 * l.slip_m,
                l.turn_rad.to_degrees(),
                if l.contacts.is_empty() {
                    "nothing".to_string()
                } else {
                    l.contacts.join(" ")
                },
                l.mass_kg,
                l.close_s,
                l.steps
            );
            if let Some(c) = &l.start_collision {
                text += &format!("  invalid start: {c}\n");
            }
        }
        if let Some(s) = &r.stability {
            text += &format!(
                "  Delta x y z {:.1} {:.1} {:.1} mm, ax ay az {:.1} {:.1} {:.1} deg\n",
                1e3 * s.delta[0],
                1e3 * s.delta[1],
                1e3 * s.delta[2],
                s.delta[3].to_degrees(),
                s.delta[4].to_degrees(),
                s.delta[5].to_degrees()
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

/// A contact set such as the BH8-282 makes on a mug-sized cylinder (radius 35 mm,
/// height 100 mm, centroid at the origin): the thumb on one side, the two fingers on the
/// other, 1 or 2 contacts per finger (proximal and distal link), normals radial (inward)
/// tilted by up to ~6 degrees as mesh facets do. Returns the contacts and the torque
/// scale (the largest centroid-to-surface distance, as GraspIt! takes).
pub fn sample_three_finger_contacts(rng: &mut ChaCha8Rng) -> (Vec<Contact>, f64) {
    const RADIUS_M: f64 = 0.035;
    const HALF_HEIGHT_M: f64 = 0.05;
    let base = rng.gen_range(0.0..std::f64::consts::TAU);
    let spread = rng.gen_range(0.3..1.2);
    let height = rng.gen_range(-0.03..0.03);
    let mut contacts = Vec::with_capacity(6);
    for finger_angle in [base + std::f64::consts::PI, base + spread, base - spread] {
        let links = rng.gen_range(1..=2);
        for link in 0..links {
            let angle = finger_angle + rng.gen_range(-0.15..0.15) + 0.25 * link as f64;
            let z = height + rng.gen_range(-0.01..0.01);
            let outward = Vector3::new(angle.cos(), angle.sin(), 0.0);
            let tilt = Vector3::new(
                rng.gen_range(-0.1..0.1),
                rng.gen_range(-0.1..0.1),
                rng.gen_range(-0.1..0.1),
            );
            contacts.push(Contact {
                point: Point3::from(outward * RADIUS_M + Vector3::z() * z),
                normal: (-outward + tilt).normalize(),
            });
        }
    }
    (contacts, RADIUS_M.hypot(HALF_HEIGHT_M))
}

/// The result of `cell bench quality-metric`.
#[derive(Debug, Serialize)]
struct QualityMetricBench {
    workload: String,
    seed: u64,
    sets: usize,
    repeats: usize,
    mean_contacts: f64,
    mean_wrenches: f64,
    force_closure_fraction: f64,
    mean_qhull_facets: f64,
    max_epsilon_difference_vs_qhull: f64,
    /// Best-first exact epsilon (no volume): the grasp-search path.
    epsilon_per_s: f64,
    /// `quality::evaluate`: epsilon plus the qhull hull for the volume.
    evaluate_per_s: f64,
    /// qhull hull alone (epsilon and volume from its facets): the baseline.
    qhull_per_s: f64,
    epsilon_speedup_vs_qhull: f64,
    /// Median time of one best-first epsilon evaluation (us).
    epsilon_us: f64,
    /// Best-first epsilon with 4-edge pyramids (a cheaper discretisation, for comparison).
    epsilon_4_edges_per_s: f64,
}

/// Runs `cell bench quality-metric`.
pub fn bench_metric(args: QualityMetricBenchArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        args.sets > 0 && args.repeats > 0,
        "--sets and --repeats must be > 0"
    );
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let sets: Vec<(Vec<Contact>, QualityParams)> = (0..args.sets)
        .map(|_| {
            let (contacts, r) = sample_three_finger_contacts(&mut rng);
            let params = QualityParams {
                torque_scale_m: Some(r),
                centroid: Some(Point3::origin()),
                ..QualityParams::default()
            };
            (contacts, params)
        })
        .collect();
    let wrenches: Vec<_> = sets
        .iter()
        .map(|(c, p)| wrench::contact_wrenches(c, p))
        .collect::<Result<_, _>>()?;
    let mut closure = 0usize;
    let mut facets = 0usize;
    let mut max_diff: f64 = 0.0;
    for w in &wrenches {
        let fast = quality::epsilon_of_wrenches(w);
        let hull = gws::hull_measures(w)?;
        closure += usize::from(fast > 0.0);
        facets += hull.facets;
        max_diff = max_diff.max((fast - hull.epsilon).abs());
    }
    // The methods timed, interleaved within each repeat so that load from other
    // processes falls on all of them alike.
    type Method<'a> = Box<dyn Fn(&(Vec<Contact>, QualityParams)) -> f64 + 'a>;
    let methods: [Method; 4] = [
        Box::new(|(c, p)| quality::epsilon(c, p).unwrap_or(0.0)),
        Box::new(|(c, p)| quality::evaluate(c, p).map_or(0.0, |q| q.volume)),
        Box::new(|(c, p)| {
            wrench::contact_wrenches(c, p)
                .ok()
                .and_then(|w| gws::hull_measures(&w).ok())
                .map_or(0.0, |m| m.epsilon)
        }),
        Box::new(|(c, p)| {
            let p4 = QualityParams {
                cone_edges: 4,
                ..*p
            };
            quality::epsilon(c, &p4).unwrap_or(0.0)
        }),
    ];
    let progress = indicatif::ProgressBar::new((args.repeats * methods.len()) as u64);
    let mut rates = vec![Vec::with_capacity(args.repeats); methods.len()];
    for _ in 0..args.repeats {
        for (method, samples) in methods.iter().zip(&mut rates) {
            let start = Instant::now();
            let mut sink = 0.0;
            for set in &sets {
                sink += method(set);
            }
            std::hint::black_box(sink);
            samples.push(args.sets as f64 / start.elapsed().as_secs_f64());
            progress.inc(1);
        }
    }
    progress.finish_and_clear();
    let [epsilon_per_s, evaluate_per_s, qhull_per_s, epsilon_4_edges_per_s] =
        [0, 1, 2, 3].map(|i| median(&mut rates[i]));
    let n = args.sets as f64;
    let report = QualityMetricBench {
        workload: "BH8-282-like contact sets on a 35 mm cylinder: 3-6 contacts, mu 0.5, \
                   8-edge pyramids, one thread"
            .into(),
        seed: args.seed,
        sets: args.sets,
        repeats: args.repeats,
        mean_contacts: sets.iter().map(|s| s.0.len()).sum::<usize>() as f64 / n,
        mean_wrenches: wrenches.iter().map(Vec::len).sum::<usize>() as f64 / n,
        force_closure_fraction: closure as f64 / n,
        mean_qhull_facets: facets as f64 / n,
        max_epsilon_difference_vs_qhull: max_diff,
        epsilon_per_s,
        evaluate_per_s,
        qhull_per_s,
        epsilon_speedup_vs_qhull: epsilon_per_s / qhull_per_s,
        epsilon_us: 1e6 / epsilon_per_s,
        epsilon_4_edges_per_s,
    };
    super::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}

/// Reads and evaluates a contacts file.
fn evaluate_file(path: &Path) -> anyhow::Result<GraspQuality> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read contacts file {}", path.display()))?;
    let file: ContactsFile =
        serde_json::from_str(&text).with_context(|| format!("contacts file {}", path.display()))?;
    quality::evaluate(&file.contacts, &file.params())
        .with_context(|| format!("contacts file {}", path.display()))
}

/// Options of `cell bench quality`.
#[derive(Debug, Args)]
pub struct QualityBenchArgs {
    /// Grasp poses per repeat (around the mug's top, side and handle grasps).
    #[arg(long, default_value_t = 1500)]
    pub grasps: usize,
    /// Timed repeats over all poses (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the mug and the pose perturbations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads for the parallel run (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Physics lift tests per repeat (the first poses of --grasps; 0 skips them).
    #[arg(long, default_value_t = 40)]
    pub lifts: usize,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// The physics part of `cell bench quality`: the observer's lift test.
#[derive(Debug, Serialize)]
struct LiftBench {
    workload: String,
    lifts: usize,
    /// Convex parts of the mug's decomposition.
    convex_parts: usize,
    /// Time of the decomposition, done once per mesh (s).
    decomposition_s: f64,
    success_fraction: f64,
    partial_fraction: f64,
    start_collision_fraction: f64,
    mean_steps: f64,
    /// Lift tests per second, parallel over all threads (the figure the goal is about).
    lift_tests_per_s: f64,
    lift_tests_per_s_one_thread: f64,
    /// CPU time of one lift test on one thread (ms, median over repeats): its cost
    /// whatever else the machine is doing.
    lift_cpu_ms_one_thread: f64,
    /// Lift tests per CPU-second of one thread times the threads of the parallel
    /// run: the rate the cores give when the machine is otherwise idle.
    lift_tests_per_s_cpu_bound: f64,
    goal_per_s: f64,
    meets_goal: bool,
}

/// The result of `cell bench quality`.
#[derive(Debug, Serialize)]
struct GraspBench {
    workload: String,
    seed: u64,
    mug_seed: u64,
    mug_triangles: usize,
    grasps: usize,
    repeats: usize,
    threads: usize,
    force_closure_fraction: f64,
    collision_at_start_fraction: f64,
    mean_contacts: f64,
    /// Auto-grasp + epsilon, parallel over all threads (the figure the goal is about).
    grasps_per_s: f64,
    /// Auto-grasp + epsilon on one thread: the baseline.
    grasps_per_s_one_thread: f64,
    parallel_speedup: f64,
    /// Auto-grasp alone on one thread.
    auto_grasp_per_s_one_thread: f64,
    /// Median time of one auto-grasp + epsilon on one thread (us).
    grasp_us_one_thread: f64,
    /// CPU time of one auto-grasp + epsilon on one thread (us, median over
    /// repeats): its cost whatever else the machine is doing.
    grasp_cpu_us_one_thread: f64,
    /// Evaluations per CPU-second of one thread times the threads of the
    /// parallel run: the rate the cores give when the machine is otherwise idle.
    grasps_per_s_cpu_bound: f64,
    goal_per_s: f64,
    meets_goal: bool,
    /// The physics lift tests (absent with --lifts 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    physics: Option<LiftBench>,
    /// 1, 5 and 15 minute load averages at the end of the run.
    load_average: Option<[f64; 3]>,
}

/// Times the physics lift test at the first `count` of `poses` (object frame, table
/// at z = 0, the mug upright).
fn bench_lifts(
    hand: &HandModel,
    mesh: &crate::mesh::TriMesh,
    poses: &[(crate::geometry::Pose, f64)],
    count: usize,
    repeats: usize,
    pool: &rayon::ThreadPool,
) -> anyhow::Result<LiftBench> {
    use rayon::prelude::*;
    let options = PhysicsOptions::default();
    let start = Instant::now();
    let body = PhysicsObject::new(mesh, Path::new("<bench mug>"), &options)?;
    let decomposition_s = start.elapsed().as_secs_f64();
    let poses = &poses[..count.min(poses.len())];
    let lift = |(pose, spread): &(crate::geometry::Pose, f64)| {
        let scene = LiftScene {
            base_from_object: crate::geometry::Pose::identity(),
            base_from_palm: *pose,
            spread_rad: *spread,
            table_height_m: Some(0.0),
        };
        lift_test(hand, &body, &scene, &options)
    };
    let outcomes: Vec<LiftOutcome> =
        pool.install(|| poses.par_iter().map(lift).collect::<Result<_, _>>())?;
    let n = poses.len() as f64;
    let share =
        |f: &dyn Fn(&LiftOutcome) -> bool| outcomes.iter().filter(|o| f(o)).count() as f64 / n;
    let (mut parallel, mut single, mut cpu) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..repeats {
        let start = Instant::now();
        let steps: usize = pool.install(|| {
            poses
                .par_iter()
                .map(|p| lift(p).map_or(0, |o| o.steps))
                .sum()
        });
        std::hint::black_box(steps);
        parallel.push(n / start.elapsed().as_secs_f64());
        let (start, cpu_start) = (Instant::now(), cpu_ms(true));
        let steps: usize = poses.iter().map(|p| lift(p).map_or(0, |o| o.steps)).sum();
        std::hint::black_box(steps);
        single.push(n / start.elapsed().as_secs_f64());
        cpu.push((cpu_ms(true) - cpu_start) / n);
    }
    let lift_tests_per_s = median(&mut parallel);
    let lift_cpu_ms = median(&mut cpu);
    Ok(LiftBench {
        workload: format!(
            "physics lift test (rapier3d, {:.0} Hz step, {} solver iterations): close, lift {} m, \
             hold {} s, at the first poses of the auto-grasp figures on the same mug",
            1.0 / options.step_s,
            options.solver_iterations,
            options.lift_m,
            options.hold_s
        ),
        lifts: poses.len(),
        convex_parts: body.parts(),
        decomposition_s,
        success_fraction: share(&|o| o.grade == crate::trial::Grade::Success),
        partial_fraction: share(&|o| o.grade == crate::trial::Grade::Partial),
        start_collision_fraction: share(&|o| o.start_collision.is_some()),
        mean_steps: outcomes.iter().map(|o| o.steps).sum::<usize>() as f64 / n,
        lift_tests_per_s,
        lift_tests_per_s_one_thread: median(&mut single),
        lift_cpu_ms_one_thread: lift_cpu_ms,
        lift_tests_per_s_cpu_bound: pool.current_num_threads() as f64 * 1e3 / lift_cpu_ms,
        goal_per_s: 20.0,
        meets_goal: lift_tests_per_s >= 20.0,
    })
}

/// Runs `cell bench quality`.
pub fn bench_grasp(config: &Path, args: QualityBenchArgs) -> anyhow::Result<ExitCode> {
    use crate::category::suggest::{standoff_m, templates};
    use crate::mesh::procedural::{generate, instance_seed, Category, Params};
    use crate::quality::autograsp::close_hand;
    use rayon::prelude::*;
    anyhow::ensure!(
        args.grasps > 0 && args.repeats > 0,
        "--grasps and --repeats must be > 0"
    );
    let hand = HandModel::load(&CellConfig::load(config)?)?;
    // The first mug of the seed's set that has a handle.
    let (mug_seed, mesh, params) = (0..)
        .map(|i| {
            let s = instance_seed(args.seed, i);
            let (mesh, params) = generate(Category::Mug, s);
            (s, mesh, params)
        })
        .find(|(_, _, p)| matches!(p, Params::Mug(m) if m.handle.is_some()))
        .expect("some mug has a handle");
    let object = GraspObject::new(&mesh, Path::new("<bench mug>"))?.with_table(Some(0.0));
    let options = AutoGraspOptions::default();
    let quality = QualityParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let templates = templates(&hand, &params, &mesh);
    let mut poses = Vec::with_capacity(args.grasps);
    let mut attempts = 0;
    while poses.len() < args.grasps {
        attempts += 1;
        anyhow::ensure!(attempts < 100 * args.grasps, "cannot place bench grasps");
        let t = &templates[rng.gen_range(0..templates.len())];
        let u = t.sample(&mut rng);
        if let Some(p) = t.place(&hand, &object, &u, standoff_m(&object)) {
            poses.push(p);
        }
    }
    let evaluate = |(pose, spread): &(crate::geometry::Pose, f64)| {
        evaluate_grasp(&hand, &object, pose, *spread, &options, &quality, false)
    };
    let results: Vec<_> = poses.iter().map(evaluate).collect::<Result<_, _>>()?;
    let n = args.grasps as f64;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()?;
    let threads = pool.current_num_threads();
    let progress = indicatif::ProgressBar::new(3 * args.repeats as u64);
    let (mut parallel, mut single, mut closing) = (Vec::new(), Vec::new(), Vec::new());
    let mut single_cpu = Vec::new();
    for _ in 0..args.repeats {
        let start = Instant::now();
        let sum: f64 = pool.install(|| {
            poses
                .par_iter()
                .map(|p| evaluate(p).map_or(0.0, |e| e.epsilon))
                .sum()
        });
        std::hint::black_box(sum);
        parallel.push(n / start.elapsed().as_secs_f64());
        progress.inc(1);
        let (start, cpu) = (Instant::now(), cpu_ms(true));
        let sum: f64 = poses
            .iter()
            .map(|p| evaluate(p).map_or(0.0, |e| e.epsilon))
            .sum();
        std::hint::black_box(sum);
        single.push(n / start.elapsed().as_secs_f64());
        single_cpu.push((cpu_ms(true) - cpu) * 1e3 / n);
        progress.inc(1);
        let start = Instant::now();
        let count: usize = poses
            .iter()
            .map(|(pose, spread)| {
                close_hand(&hand, &object, pose, *spread, &options).map_or(0, |o| o.contacts.len())
            })
            .sum();
        std::hint::black_box(count);
        closing.push(n / start.elapsed().as_secs_f64());
        progress.inc(1);
    }
    progress.finish_and_clear();
    let physics = if args.lifts > 0 {
        Some(bench_lifts(
            &hand,
            &mesh,
            &poses,
            args.lifts,
            args.repeats,
            &pool,
        )?)
    } else {
        None
    };
    let grasps_per_s = median(&mut parallel);
    let one = median(&mut single);
    let grasp_cpu_us = median(&mut single_cpu);
    let report = GraspBench {
        workload: "auto-grasp (BH8-282, 0.04 rad steps, bisection to 1e-4 rad) + fast epsilon \
                   (mu 0.5, 8 edges) at seeded poses around a procedural mug's top, side and \
                   handle grasps (approached to contact, table at z = 0)"
            .into(),
        seed: args.seed,
        mug_seed,
        mug_triangles: mesh.triangles.len(),
        grasps: args.grasps,
        repeats: args.repeats,
        threads,
        force_closure_fraction: results.iter().filter(|e| e.force_closure).count() as f64 / n,
        collision_at_start_fraction: results
            .iter()
            .filter(|e| e.outcome.collision_at_start.is_some())
            .count() as f64
            / n,
        mean_contacts: results
            .iter()
            .map(|e| e.outcome.contacts.len())
            .sum::<usize>() as f64
            / n,
        grasps_per_s,
        grasps_per_s_one_thread: one,
        parallel_speedup: grasps_per_s / one,
        auto_grasp_per_s_one_thread: median(&mut closing),
        grasp_us_one_thread: 1e6 / one,
        grasp_cpu_us_one_thread: grasp_cpu_us,
        grasps_per_s_cpu_bound: threads as f64 * 1e6 / grasp_cpu_us,
        goal_per_s: 1000.0,
        meets_goal: grasps_per_s >= 1000.0,
        physics,
        load_average: super::bench::load_average(),
    };
    super::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
