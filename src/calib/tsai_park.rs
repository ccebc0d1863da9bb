//! Tsai–Lenz and Park–Martin: rotation of `X` first, then its translation.

use super::motions::{motion_pairs, solve_3x3, solve_translation, MotionPair};
use super::{CalibError, PoseSample};
use crate::geometry::project_to_so3;
use crate::geometry::Pose;
use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// `P = 2 sin(θ/2) n`: twice the vector part of the quaternion with `w ≥ 0`.
fn modified_rodrigues(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let v = q.vector().into_owned();
    if q.w < 0.0 {
        -2.0 * v
    } else {
        2.0 * v
    }
}

fn usable_pairs(samples: &[PoseSample], method: &str) -> Result<Vec<MotionPair>, CalibError> {
    let pairs = motion_pairs(samples);
    if pairs.len() < 2 {
        return Err(CalibError::TooFewSamples {
            got: pairs.len(),
            need: 2,
            what: format!(
                "sample pairs rotating by ≥ {}° for {method}",
                super::MIN_PAIR_ROTATION_DEG
            ),
        });
    }
    Ok(pairs)
}

/// `base_from_camera` by Tsai & Lenz (1989), eye-to-hand (see the module doc).
///
/// Rotation: least squares of `[P_A + P_B]× r = P_B − P_A` over all usable pairs,
/// where `r = tan(θ_X/2) n_X` (so `R_X P_B = P_A` by the Cayley formula).
pub fn tsai_lenz(samples: &[PoseSample]) -> Result<Pose, CalibError> {
    let pairs = usable_pairs(samples, "tsai")?;
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for p in &pairs {
        let pa = modified_rodrigues(&p.a.rotation);
        let pb = modified_rodrigues(&p.b.rotation);
        let k = (pa + pb).cross_matrix();
        ata += k.transpose() * k;
        atb += k.transpose() * (pb - pa);
    }
    let r = solve_3x3(&ata, &atb, "tsai rotation")?;
    // (1, r) is proportional to (cos θ/2, sin θ/2 n).
    let rotation = UnitQuaternion::from_quaternion(Quaternion::new(1.0, r.x, r.y, r.z));
    let t = solve_translation(&pairs, &rotation)?;
    Ok(Isometry3::from_parts(Translation3::from(t), rotation))
}

/// `base_from_camera` by Park & Martin (1994), eye-to-hand (see the module doc).
///
/// Rotation: `α = log R_A = R_X log R_B = R_X β` for every pair; the least-squares
/// `R_X` is the orthogonal polar factor of `Σ α βᵀ` (Park–Martin's
/// `(MᵀM)^(-1/2) Mᵀ` with `M = Σ β αᵀ`, computed by SVD with det = +1).
pub fn park_martin(samples: &[PoseSample]) -> Result<Pose, CalibError> {
    let pairs = usable_pairs(samples, "park")?;
    let m: Matrix3<f64> = pairs
        .iter()
        .map(|p| p.a.rotation.scaled_axis() * p.b.rotation.scaled_axis().transpose())
        .sum();
    let rotation = project_to_so3(&m);
    let t = solve_translation(&pairs, &rotation)?;
    Ok(Isometry3::from_parts(Translation3::from(t), rotation))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::synthetic::{pose_samples, Noise, SyntheticScene};
    use crate::geometry::pose_error;

    #[test]
    fn exact_samples_give_the_exact_transform() {
        let scene = SyntheticScene::nominal();
        let samples = pose_samples(&scene, 8, &Noise::none(), 3);
        for (name, solve) in [
            ("tsai", tsai_lenz as fn(&[PoseSample]) -> _),
            ("park", park_martin),
        ] {
            let x = solve(&samples).unwrap();
            let (dp, dr) = pose_error(&x, &scene.base_from_camera);
            assert!(dp < 1e-9 && dr < 1e-9, "{name}: {dp} m {dr} rad");
        }
    }

    #[test]
    fn modified_rodrigues_ignores_quaternion_sign() {
        let q = UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.2, 0.1));
        let neg = UnitQuaternion::new_unchecked(-q.into_inner());
        assert!((modified_rodrigues(&q) - modified_rodrigues(&neg)).norm() < 1e-15);
        let angle = q.angle();
        assert!((modified_rodrigues(&q).norm() - 2.0 * (angle / 2.0).sin()).abs() < 1e-15);
    }
}
