//! `cell bench quality-metric`: epsilon and volume evaluations on 3-finger contact sets.

use crate::quality::{self, gws, wrench, Contact, QualityParams};
use crate::stats::median;
use clap::Args;
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell bench quality-metric`.
#[derive(Debug, Args)]
pub struct QualityMetricBenchArgs {
    /// Number of random contact sets per repeat.
    #[arg(long, default_value_t = 500)]
    pub sets: usize,
    /// Timed repeats over all sets (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the random contact sets.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
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
    crate::cli::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
