//! Running the solvers on a sample set, refining, and comparing the methods.

use super::{
    check_frames, check_motions, daniilidis, evaluate, fit_target, measure_motions, park_martin,
    point_solver, refine, tsai_lenz, CalibError, Conditioning, Evaluation, HandEye, PointSample,
    PoseSample, Sample, Weights,
};
use crate::geometry::{pose_error, Pose};
use nalgebra::Vector3;
use serde::Serialize;

/// Below this axis spread or largest rotation (deg) the result is computed but a
/// warning suggests better poses.
const WARN_BELOW_DEG: f64 = 30.0;
/// Above either RMS residual the best solution is rejected as wrong (mm), with a
/// diagnosis of inverted poses.
pub const GROSS_RMS_MM: f64 = 20.0;
/// See [`GROSS_RMS_MM`] (deg).
pub const GROSS_RMS_DEG: f64 = 3.0;
/// Above these RMS residuals a warning suggests checking the data.
const WARN_RMS_MM: f64 = 5.0;
/// See [`WARN_RMS_MM`] (deg).
const WARN_RMS_DEG: f64 = 1.0;
/// Closed forms further than this from the selected result get a warning (mm, deg).
const WARN_SPREAD: (f64, f64) = (5.0, 0.5);

/// Which closed-form solver(s) to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Tsai–Lenz (pose samples).
    Tsai,
    /// Park–Martin (pose samples).
    Park,
    /// Daniilidis, dual quaternions (pose samples).
    Daniilidis,
    /// Target points (point samples, or the origins of pose samples).
    Points,
    /// Every method the samples allow.
    All,
}

impl Method {
    /// The method's name as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Tsai => "tsai",
            Method::Park => "park",
            Method::Daniilidis => "daniilidis",
            Method::Points => "points",
            Method::All => "all",
        }
    }
}

/// Options of [`solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// The closed-form solver(s) to run.
    pub method: Method,
    /// Refine the best closed form over all samples ([`refine`]).
    pub refine: bool,
    /// The target's position in the flange frame (m), if known (e.g. a sphere on a
    /// measured mount); otherwise it is estimated.
    pub known_target_point: Option<Vector3<f64>>,
    /// Residual weighting of the refinement and of the comparison.
    pub weights: Weights,
}

impl Default for SolveOptions {
    /// All methods, refined, target position unknown, default weights.
    fn default() -> Self {
        SolveOptions {
            method: Method::All,
            refine: true,
            known_target_point: None,
            weights: Weights::default(),
        }
    }
}

/// One method's solution evaluated on all samples.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodResult {
    /// The method, e.g. `tsai` or `daniilidis+refine`.
    pub name: String,
    /// Its solution and residuals.
    pub evaluation: Evaluation,
    /// Distance of its `base_from_camera` from the selected one (mm, deg).
    pub from_selected: (f64, f64),
}

/// The outcome of [`solve`]: every method's result and the selected one.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// The methods' results, closed forms first, the refinement last.
    pub results: Vec<MethodResult>,
    /// Index of the selected result (the refinement, or the lowest-cost closed form).
    pub selected: usize,
    /// How well the flange motions determine the calibration.
    pub conditioning: Conditioning,
    /// Things worth knowing that did not prevent a result.
    pub warnings: Vec<String>,
}

impl Solution {
    /// The selected result.
    pub fn best(&self) -> &MethodResult {
        &self.results[self.selected]
    }
}

/// Checks the samples, runs the chosen solvers, refines the best (lowest weighted
/// cost) closed form, and compares them all on every sample. A best solution whose
/// RMS residual exceeds [`GROSS_RMS_MM`] or [`GROSS_RMS_DEG`] is an error, which
/// says whether the samples fit with the robot poses or the observations inverted.
pub fn solve(samples: &[Sample], options: &SolveOptions) -> Result<Solution, CalibError> {
    let solution = solve_unchecked(samples, options)?;
    let best = solution.best();
    let stats = best.evaluation.stats;
    if stats.rms_mm <= GROSS_RMS_MM && stats.rms_deg.is_none_or(|d| d <= GROSS_RMS_DEG) {
        return Ok(solution);
    }
    let fits = |variant: Vec<Sample>| {
        solve_unchecked(&variant, options).ok().and_then(|s| {
            let st = s.best().evaluation.stats;
            (st.rms_mm <= WARN_RMS_MM && st.rms_deg.is_none_or(|d| d <= WARN_RMS_DEG))
                .then_some(st.rms_mm)
        })
    };
    let flange_inverted: Vec<Sample> = samples
        .iter()
        .map(|s| match *s {
            Sample::Pose(p) => Sample::Pose(PoseSample {
                base_from_flange: p.base_from_flange.inverse(),
                ..p
            }),
            Sample::Point(p) => Sample::Point(PointSample {
                base_from_flange: p.base_from_flange.inverse(),
                ..p
            }),
        })
        .collect();
    // Inverting every robot pose fits equally when instead every observation is
    // inverted (inverting both swaps X and Y), so the hint names both.
    let has_poses = samples.iter().any(|s| matches!(s, Sample::Pose(_)));
    let hint = match fits(flange_inverted) {
        Some(mm) if has_poses => format!("the samples fit ({mm:.1} mm RMS) with one side of each sample inverted: the robot poses are probably flange_from_base (not base_from_flange), or the observations target_from_camera (not camera_from_target), or the camera is on the hand (eye-in-hand; this tool is for a fixed camera)"),
        Some(mm) => format!("the samples fit ({mm:.1} mm RMS) with every robot pose inverted: the robot poses are probably flange_from_base (not base_from_flange), or the camera is on the hand (eye-in-hand; this tool is for a fixed camera)"),
        None => "check that each robot pose and observation were captured at the same moment, units are metres, the target is rigid on the flange, and frames are as documented (base_from_flange, camera_from_target)".to_string(),
    };
    Err(CalibError::ResidualsTooLarge {
        method: best.name.clone(),
        rms_mm: stats.rms_mm,
        rms_deg: stats.rms_deg,
        hint,
    })
}

/// [`solve`] without the final residual check.
fn solve_unchecked(samples: &[Sample], options: &SolveOptions) -> Result<Solution, CalibError> {
    for (index, s) in samples.iter().enumerate() {
        s.check_finite(index)?;
    }
    let flanges: Vec<Pose> = samples.iter().map(|s| *s.base_from_flange()).collect();
    // Kabsch with a known target position needs non-collinear points, not rotations.
    let kabsch_only = options.method == Method::Points && options.known_target_point.is_some();
    let conditioning = if kabsch_only {
        measure_motions(&flanges)?
    } else {
        check_motions(&flanges)?
    };
    let poses: Vec<PoseSample> = samples
        .iter()
        .filter_map(|s| match s {
            Sample::Pose(p) => Some(*p),
            Sample::Point(_) => None,
        })
        .collect();
    let points: Vec<PointSample> = samples.iter().map(Sample::as_point_sample).collect();
    let need_poses = |method: Method| -> Result<(), CalibError> {
        if poses.is_empty() {
            return Err(CalibError::NeedsPoseSamples {
                method: method.name().into(),
                points: samples.len(),
                poses: 0,
            });
        }
        if poses.len() < super::samples::MIN_SAMPLES {
            return Err(CalibError::TooFewSamples {
                got: poses.len(),
                need: super::samples::MIN_SAMPLES,
                what: format!("pose samples (camera_from_target) for {}", method.name()),
            });
        }
        Ok(())
    };
    let methods: Vec<Method> = match options.method {
        Method::All => {
            let mut m = Vec::new();
            if poses.len() >= super::samples::MIN_SAMPLES {
                m.extend([Method::Tsai, Method::Park, Method::Daniilidis]);
            }
            m.push(Method::Points);
            m
        }
        Method::Points => vec![Method::Points],
        pose_method => {
            need_poses(pose_method)?;
            vec![pose_method]
        }
    };
    if methods.iter().any(|m| *m != Method::Points) {
        check_frames(&poses)?;
    }
    let known = options.known_target_point;
    let mut warnings = Vec::new();
    let mut results: Vec<MethodResult> = Vec::new();
    let mut first_error = None;
    for method in methods {
        let x = match method {
            Method::Tsai => tsai_lenz(&poses),
            Method::Park => park_martin(&poses),
            Method::Daniilidis => daniilidis(&poses),
            Method::Points | Method::All => {
                point_solver(&points, known, &options.weights).map(|he| he.base_from_camera)
            }
        };
        match x {
            Ok(x) => {
                let he = HandEye {
                    base_from_camera: x,
                    flange_from_target: fit_target(samples, &x, known),
                };
                results.push(MethodResult {
                    name: method.name().into(),
                    evaluation: evaluate(samples, &he, &options.weights),
                    from_selected: (0.0, 0.0),
                });
            }
            // With several methods, one failing (e.g. too few points for the point
            // solver) is a warning; the error is returned only if none succeeds.
            Err(e) if options.method == Method::All => {
                warnings.push(format!("{} skipped: {e}", method.name()));
                first_error.get_or_insert(e);
            }
            Err(e) => return Err(e),
        }
    }
    let Some(best) = results
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.evaluation.cost.total_cmp(&b.1.evaluation.cost))
        .map(|(i, _)| i)
    else {
        return Err(first_error.unwrap_or(CalibError::TooFewSamples {
            got: samples.len(),
            need: super::samples::MIN_SAMPLES,
            what: "samples".into(),
        }));
    };
    let mut selected = best;
    if options.refine {
        let start = &results[best];
        let refined = refine(samples, &start.evaluation.hand_eye, known, &options.weights);
        let name = format!("{}+refine", start.name);
        results.push(MethodResult {
            name,
            evaluation: evaluate(samples, &refined.hand_eye, &options.weights),
            from_selected: (0.0, 0.0),
        });
        selected = results.len() - 1;
    }
    let chosen = results[selected].evaluation.hand_eye.base_from_camera;
    for r in &mut results {
        let (dp, dr) = pose_error(&r.evaluation.hand_eye.base_from_camera, &chosen);
        r.from_selected = (dp * 1e3, dr.to_degrees());
        if r.from_selected.0 > WARN_SPREAD.0 || r.from_selected.1 > WARN_SPREAD.1 {
            warnings.push(format!(
                "{} is {:.1} mm / {:.2}° from the selected result: the samples constrain the camera poorly; add more varied poses",
                r.name, r.from_selected.0, r.from_selected.1
            ));
        }
    }
    if conditioning.axis_spread_deg < WARN_BELOW_DEG && !kabsch_only {
        warnings.push(format!(
            "rotation axes spread only {:.1}°: add poses rotating about other axes",
            conditioning.axis_spread_deg
        ));
    }
    if conditioning.max_pair_rotation_deg < WARN_BELOW_DEG && !kabsch_only {
        warnings.push(format!(
            "the flange turns at most {:.1}° between samples: larger rotations (30°+) calibrate better",
            conditioning.max_pair_rotation_deg
        ));
    }
    let stats = results[selected].evaluation.stats;
    if stats.rms_mm > WARN_RMS_MM || stats.rms_deg.is_some_and(|d| d > WARN_RMS_DEG) {
        warnings.push(format!(
            "large residuals (RMS {:.1} mm{}): check that each robot pose and observation were captured at the same moment, units are metres, and the target is rigid",
            stats.rms_mm,
            stats.rms_deg.map(|d| format!(", {d:.2}°")).unwrap_or_default()
        ));
    }
    Ok(Solution {
        results,
        selected,
        conditioning,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{point_samples, pose_samples, Noise, SyntheticScene};

    fn pose_set(n: usize, noise: &Noise, seed: u64) -> Vec<Sample> {
        pose_samples(&SyntheticScene::nominal(), n, noise, seed)
            .into_iter()
            .map(Sample::Pose)
            .collect()
    }

    #[test]
    fn all_methods_run_and_the_refinement_is_selected() {
        let s = solve(
            &pose_set(12, &Noise::typical(), 3),
            &SolveOptions::default(),
        )
        .unwrap();
        let names: Vec<&str> = s.results.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(&names[..4], &["tsai", "park", "daniilidis", "points"]);
        assert!(names[4].ends_with("+refine"));
        assert_eq!(s.selected, 4);
        assert!(s.best().from_selected.0 < 1e-9 && s.best().from_selected.1 < 1e-9);
        let start = s
            .results
            .iter()
            .find(|r| names[4].starts_with(&r.name))
            .unwrap();
        assert!(s.best().evaluation.cost <= start.evaluation.cost);
    }

    #[test]
    fn pose_methods_refuse_point_samples_and_points_accept_them() {
        let points: Vec<Sample> =
            point_samples(&SyntheticScene::nominal(), 8, &Noise::typical(), 1)
                .into_iter()
                .map(Sample::Point)
                .collect();
        let options = SolveOptions {
            method: Method::Tsai,
            ..SolveOptions::default()
        };
        let err = solve(&points, &options).unwrap_err().to_string();
        assert!(
            err.contains("needs pose samples") && err.contains("--method points"),
            "{err}"
        );
        let s = solve(&points, &SolveOptions::default()).unwrap();
        let names: Vec<&str> = s.results.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(names, ["points", "points+refine"]);
        assert!(s.best().evaluation.stats.rms_deg.is_none());
    }

    #[test]
    fn nan_sample_is_named() {
        let mut samples = pose_set(6, &Noise::none(), 1);
        if let Sample::Pose(p) = &mut samples[4] {
            p.camera_from_target.translation.vector.y = f64::NAN;
        }
        let err = solve(&samples, &SolveOptions::default()).unwrap_err();
        assert!(
            matches!(
                err,
                CalibError::NotFinite {
                    index: 4,
                    field: "camera_from_target",
                    ..
                }
            ),
            "{err}"
        );
    }
}
