//! Synthetic planning problems for benchmarks and tests: a category of models
//! registered to one object on the table, each with task-labelled top grasps.

use super::{ExampleGrasp, ModelFit};
use crate::geometry::pose_from_params;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

/// What to generate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticSpec {
    /// Number of models.
    pub models: usize,
    /// `top` grasps per model (each model also gets one `side` grasp).
    pub grasps_per_model: usize,
    /// Where the object stands on the table (world x, y; m).
    pub object_xy_m: [f64; 2],
    /// Seed of everything random.
    pub seed: u64,
}

/// Fits and grasps: each model registered to the object with a few millimetres and
/// degrees of error and a random yaw; `top` grasps 12-18 cm above the model origin
/// within 2 cm of its axis, palm down within 0.1 rad, any yaw; quality 0.02-0.3;
/// per-DOF sigma 0.5-2 cm and 0.05-0.2 rad; fitting errors (1.4-7 mm rms)^2.
pub fn synthetic_problem(spec: &SyntheticSpec) -> (Vec<ModelFit>, Vec<ExampleGrasp>) {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut fits = Vec::with_capacity(spec.models);
    let mut grasps = Vec::new();
    for m in 0..spec.models {
        let noise = |rng: &mut ChaCha8Rng, s: f64| rng.gen_range(-s..s);
        let base_from_model = pose_from_params(&[
            spec.object_xy_m[0] + noise(&mut rng, 0.005),
            spec.object_xy_m[1] + noise(&mut rng, 0.005),
            noise(&mut rng, 0.003),
            noise(&mut rng, 0.05),
            noise(&mut rng, 0.05),
            rng.gen_range(-PI..PI),
        ]);
        let eps_m2 = rng.gen_range(2e-6..5e-5);
        fits.push(ModelFit {
            name: format!("model_{m:03}"),
            base_from_model,
            eps_m2,
            sigma_m2: 0.3 * eps_m2,
        });
        let sigma = |rng: &mut ChaCha8Rng| -> [f64; 6] {
            std::array::from_fn(|d| {
                if d < 3 {
                    rng.gen_range(0.005..0.02)
                } else {
                    rng.gen_range(0.05..0.2)
                }
            })
        };
        for _ in 0..spec.grasps_per_model {
            let theta = [
                noise(&mut rng, 0.02),
                noise(&mut rng, 0.02),
                rng.gen_range(0.12..0.18),
                PI + noise(&mut rng, 0.1),
                noise(&mut rng, 0.1),
                rng.gen_range(-PI..PI),
            ];
            grasps.push(ExampleGrasp {
                model: m,
                task: "top".into(),
                model_from_palm: theta,
                spread_rad: rng.gen_range(0.0..PI / 2.0),
                preshape_rad: crate::robot::PreshapeRad::OPEN,
                max_overtravel_m: None,
                q: rng.gen_range(0.02..0.3),
                sigma: sigma(&mut rng),
            });
        }
        grasps.push(ExampleGrasp {
            model: m,
            task: "side".into(),
            model_from_palm: [0.0, 0.09, 0.06, PI / 2.0, 0.0, 0.0],
            spread_rad: 0.0,
            preshape_rad: crate::robot::PreshapeRad::OPEN,
            max_overtravel_m: None,
            q: rng.gen_range(0.02..0.3),
            sigma: sigma(&mut rng),
        });
    }
    (fits, grasps)
}
