//! Point-based calibration: Kabsch/Umeyama, and the solver for target points with
//! a known or unknown position on the flange.

use super::motions::check_motions;
use super::{refine, CalibError, HandEye, PointSample, Sample, Weights};
use crate::geometry::project_to_so3;
use crate::geometry::Pose;
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Point3, SymmetricEigen, Translation3, UnitQuaternion,
    Vector3,
};

/// Points must spread by at least this (m) across their thinnest needed direction:
/// two directions for Kabsch (not collinear), three for the unknown-offset solver
/// (not coplanar).
pub const MIN_POINT_SPREAD_M: f64 = 0.01;
/// The unknown-offset linear solve has 15 unknowns and 3 equations per sample.
const MIN_POINT_SAMPLES_UNKNOWN_OFFSET: usize = 5;

/// Standard deviations of a point set along its principal axes, largest first (m).
fn spreads(points: &[Point3<f64>]) -> [f64; 3] {
    let n = points.len().max(1) as f64;
    let mean = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let cov: Matrix3<f64> = points
        .iter()
        .map(|p| (p.coords - mean) * (p.coords - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let mut e: Vec<f64> = SymmetricEigen::new(cov)
        .eigenvalues
        .iter()
        .map(|v| v.max(0.0).sqrt())
        .collect();
    e.sort_by(|a, b| b.total_cmp(a));
    [e[0], e[1], e[2]]
}

/// The least-squares similarity `dst ≈ s R src + t` (Umeyama 1991); with
/// `with_scale == false`, `s = 1` and this is Kabsch. Returns the rigid part and `s`.
pub fn umeyama(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    with_scale: bool,
) -> Result<(Pose, f64), CalibError> {
    let n = src.len().min(dst.len());
    if n < 3 || src.len() != dst.len() {
        return Err(CalibError::TooFewSamples {
            got: n,
            need: 3,
            what: format!(
                "point pairs ({} source, {} target) for Kabsch/Umeyama",
                src.len(),
                dst.len()
            ),
        });
    }
    let spread = spreads(src)[1];
    if spread < MIN_POINT_SPREAD_M {
        return Err(CalibError::PointsDegenerate {
            shape: "collinear",
            spread_mm: spread * 1e3,
            need_mm: MIN_POINT_SPREAD_M * 1e3,
            fix: "move the target to positions spanning a plane or a volume, not a line",
        });
    }
    let nf = n as f64;
    let mu_s = src.iter().map(|p| p.coords).sum::<Vector3<f64>>() / nf;
    let mu_d = dst.iter().map(|p| p.coords).sum::<Vector3<f64>>() / nf;
    let cross: Matrix3<f64> = src
        .iter()
        .zip(dst)
        .map(|(s, d)| (d.coords - mu_d) * (s.coords - mu_s).transpose())
        .sum::<Matrix3<f64>>()
        / nf;
    let rotation = project_to_so3(&cross);
    let scale = if with_scale {
        let var_s = src
            .iter()
            .map(|p| (p.coords - mu_s).norm_squared())
            .sum::<f64>()
            / nf;
        (rotation.to_rotation_matrix().into_inner().transpose() * cross).trace() / var_s
    } else {
        1.0
    };
    let t = mu_d - scale * (rotation * mu_s);
    Ok((
        Isometry3::from_parts(Translation3::from(t), rotation),
        scale,
    ))
}

/// The least-squares rigid transform `dst ≈ R src + t` (Kabsch), e.g. `base_from_camera`
/// from target points in the camera (`src`) and in the base (`dst`).
pub fn kabsch(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Result<Pose, CalibError> {
    umeyama(src, dst, false).map(|(pose, _)| pose)
}

/// `base_from_camera` and the target position from target points.
///
/// With `known_target_point` (the target in the flange frame, m), the target's base
/// positions `F_i y` are known and this is [`kabsch`] from the camera points. Without
/// it: linear least squares of `R_F y − R_X p − t_X = −t_F` in the 15 unknowns
/// `(y, vec R_X, t_X)` (needs ≥ 5 samples and points not coplanar), `R_X` projected
/// onto SO(3), `y` and `t_X` re-solved with it, then [`refine`] on the point residuals.
/// The returned `flange_from_target` has the target position and no rotation.
pub fn point_solver(
    samples: &[PointSample],
    known_target_point: Option<Vector3<f64>>,
    weights: &Weights,
) -> Result<HandEye, CalibError> {
    let camera: Vec<Point3<f64>> = samples.iter().map(|s| s.target_point_camera_m).collect();
    if let Some(y) = known_target_point {
        let base: Vec<Point3<f64>> = samples
            .iter()
            .map(|s| s.base_from_flange * Point3::from(y))
            .collect();
        return Ok(HandEye {
            base_from_camera: kabsch(&camera, &base)?,
            flange_from_target: Isometry3::translation(y.x, y.y, y.z),
        });
    }
    if samples.len() < MIN_POINT_SAMPLES_UNKNOWN_OFFSET {
        return Err(CalibError::TooFewSamples {
            got: samples.len(),
            need: MIN_POINT_SAMPLES_UNKNOWN_OFFSET,
            what: "samples for the point solver with unknown target position".into(),
        });
    }
    let flanges: Vec<Pose> = samples.iter().map(|s| s.base_from_flange).collect();
    check_motions(&flanges)?;
    let spread = spreads(&camera)[2];
    if spread < MIN_POINT_SPREAD_M {
        return Err(CalibError::PointsDegenerate {
            shape: "coplanar",
            spread_mm: spread * 1e3,
            need_mm: MIN_POINT_SPREAD_M * 1e3,
            fix: "move the target to different heights and distances from the camera, not within one plane",
        });
    }
    // Unknowns z = (y, R_X columns 0..3, t_X); rows R_F y − Σ_k p_k R_X[:,k] − t_X = −t_F.
    let mut normal = DMatrix::<f64>::zeros(15, 15);
    let mut rhs = DVector::<f64>::zeros(15);
    for s in samples {
        let mut a = DMatrix::<f64>::zeros(3, 15);
        a.view_mut((0, 0), (3, 3))
            .copy_from(s.base_from_flange.rotation.to_rotation_matrix().matrix());
        for k in 0..3 {
            a.view_mut((0, 3 + 3 * k), (3, 3))
                .copy_from(&(Matrix3::identity() * -s.target_point_camera_m[k]));
        }
        a.view_mut((0, 12), (3, 3)).copy_from(&-Matrix3::identity());
        let b = -s.base_from_flange.translation.vector;
        normal += a.transpose() * &a;
        rhs += a.transpose() * b;
    }
    let z = solve_checked(normal, &rhs, "point solver (linear)")?;
    let r_lin = Matrix3::from_iterator(z.rows(3, 9).iter().copied());
    let rotation = project_to_so3(&r_lin);
    // With R_X fixed: R_F y − t_X = R_X p − t_F, six unknowns.
    let mut normal = DMatrix::<f64>::zeros(6, 6);
    let mut rhs = DVector::<f64>::zeros(6);
    for s in samples {
        let mut a = DMatrix::<f64>::zeros(3, 6);
        a.view_mut((0, 0), (3, 3))
            .copy_from(s.base_from_flange.rotation.to_rotation_matrix().matrix());
        a.view_mut((0, 3), (3, 3)).copy_from(&-Matrix3::identity());
        let b = rotation * s.target_point_camera_m.coords - s.base_from_flange.translation.vector;
        normal += a.transpose() * &a;
        rhs += a.transpose() * b;
    }
    let z = solve_checked(normal, &rhs, "point solver (translation)")?;
    let start = HandEye {
        base_from_camera: Isometry3::from_parts(Translation3::new(z[3], z[4], z[5]), rotation),
        flange_from_target: Isometry3::from_parts(
            Translation3::new(z[0], z[1], z[2]),
            UnitQuaternion::identity(),
        ),
    };
    let as_samples: Vec<Sample> = samples.iter().copied().map(Sample::Point).collect();
    Ok(refine(&as_samples, &start, None, weights).hand_eye)
}

/// Solves a symmetric positive semi-definite system, or reports it singular.
fn solve_checked(
    m: DMatrix<f64>,
    rhs: &DVector<f64>,
    what: &'static str,
) -> Result<DVector<f64>, CalibError> {
    let svd = m.svd(true, true);
    let max = svd.singular_values.max();
    let min = svd.singular_values.min();
    let condition = if max > 0.0 { min / max } else { 0.0 };
    if condition.is_nan() || condition <= 1e-12 {
        return Err(CalibError::Singular { what, condition });
    }
    svd.solve(rhs, 0.0)
        .map_err(|_| CalibError::Singular { what, condition })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{point_samples, Noise, SyntheticScene};
    use crate::geometry::{pose_error, pose_from_params};

    #[test]
    fn umeyama_recovers_a_similarity_and_kabsch_a_rigid_motion() {
        let truth = pose_from_params(&[0.3, -0.1, 0.8, 0.4, -1.2, 2.0]);
        let src: Vec<Point3<f64>> = [
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.0, 0.2, 0.0],
            [0.0, 0.0, 0.3],
            [0.1, 0.1, 0.1],
        ]
        .iter()
        .map(|p| Point3::from(*p))
        .collect();
        let scaled: Vec<Point3<f64>> = src
            .iter()
            .map(|p| truth * Point3::from(p.coords * 1.5))
            .collect();
        let (pose, s) = umeyama(&src, &scaled, true).unwrap();
        assert!((s - 1.5).abs() < 1e-12);
        let (dp, dr) = pose_error(&pose, &truth);
        assert!(dp < 1e-12 && dr < 1e-9);
        let rigid: Vec<Point3<f64>> = src.iter().map(|p| truth * p).collect();
        let (dp, dr) = pose_error(&kabsch(&src, &rigid).unwrap(), &truth);
        assert!(dp < 1e-12 && dr < 1e-9);
        // A mirrored point set still gives a proper rotation.
        let mirrored: Vec<Point3<f64>> = src.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let pose = kabsch(&src, &mirrored).unwrap();
        assert!((pose.rotation.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn collinear_and_too_few_points_are_rejected() {
        let line: Vec<Point3<f64>> = (0..5)
            .map(|i| Point3::new(0.1 * i as f64, 0.0, 1.0))
            .collect();
        let err = kabsch(&line, &line).unwrap_err();
        assert!(
            matches!(
                err,
                CalibError::PointsDegenerate {
                    shape: "collinear",
                    ..
                }
            ),
            "{err}"
        );
        assert!(matches!(
            kabsch(&line[..2], &line[..2]),
            Err(CalibError::TooFewSamples { got: 2, .. })
        ));
    }

    #[test]
    fn exact_points_give_the_exact_transform_with_and_without_offset() {
        let scene = SyntheticScene::nominal();
        let samples = point_samples(&scene, 8, &Noise::none(), 9);
        let y = scene.flange_from_target.translation.vector;
        for known in [Some(y), None] {
            let he = point_solver(&samples, known, &Weights::default()).unwrap();
            let (dp, dr) = pose_error(&he.base_from_camera, &scene.base_from_camera);
            assert!(dp < 1e-8 && dr < 1e-8, "{known:?}: {dp} m {dr} rad");
            assert!((he.flange_from_target.translation.vector - y).norm() < 1e-8);
        }
    }

    #[test]
    fn coplanar_points_are_rejected_with_the_fix() {
        let scene = SyntheticScene::nominal();
        let mut samples = point_samples(&scene, 8, &Noise::none(), 9);
        for s in &mut samples {
            s.target_point_camera_m.z = 1.0;
        }
        let err = point_solver(&samples, None, &Weights::default())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("coplanar") && err.contains("different heights"),
            "{err}"
        );
    }
}
