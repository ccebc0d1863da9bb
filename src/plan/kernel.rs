//! Task-compatibility densities `P(X; theta_ik)` of eq. 5 over the pose difference
//! `d` between `T_i^-1 X` and `theta_ik`: the translation difference (m) and the
//! rotation vector `log(R_theta^T R_X)` about the grasp's own axes (rad), see
//! [`super::chart`].
//!
//! Translation and rotation have separate scales: the regulariser of Gaussian-R is
//! `s_translation_m2` (m^2) on x y z and `s_rotation_rad2` (rad^2) on the angles; the
//! Laplace scales are `b_translation_m` (m) and `b_rotation_rad` (rad).
//!
//! **The paper's scalar form.** Nikandrova & Kyrki used one `s` (or `b`) for all six
//! DOFs with positions in millimetres and angles in radians: s = b = 50 in simulation,
//! 700 on the robot. In SI units that is, for a scalar `s` (mm^2 and rad^2 mixed),
//! `s_translation_m2 = s * 1e-6` and `s_rotation_rad2 = s`; for a scalar `b` (mm and
//! rad mixed), `b_translation_m = b * 1e-3` and `b_rotation_rad = b`
//! ([`Kernel::paper_gaussian_r`], [`Kernel::paper_laplace`]). The densities then
//! differ from the paper's only by the constant factor of the unit change (1e9 for
//! Gaussian and Laplace), which moves no argmax. Note that 50 rad^2 (or 50 rad) makes
//! the paper's regularised densities almost flat in rotation.
//!
//! The Laplace density (5c) uses its scales only, not the grasp's `Sigma`: the paper's
//! `b` is one fixed "diversity" chosen by experiment.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The density family of eq. 5 and its parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Kernel {
    /// (5a) `N(d; 0, Sigma_ik)`.
    Gaussian,
    /// (5b) `N(d; 0, Sigma_ik + diag(s_t, s_t, s_t, s_r, s_r, s_r))`.
    GaussianR {
        /// Regulariser added to the translation variances (m^2).
        s_translation_m2: f64,
        /// Regulariser added to the rotation variances (rad^2).
        s_rotation_rad2: f64,
    },
    /// (5c) `prod_d exp(-|d_d| / b_d) / (2 b_d)`.
    Laplace {
        /// Scale of the translation DOFs (m).
        b_translation_m: f64,
        /// Scale of the rotation DOFs (rad).
        b_rotation_rad: f64,
    },
}

/// The pieces of one grasp's log density: `ln P(d) = log_norm - sum_d coef_d g(d_d)`
/// with `g(d) = d^2` (Gaussian) or `|d|` (Laplace).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KernelTerm {
    /// Logarithm of the normalising constant.
    pub log_norm: f64,
    /// Per-DOF coefficient: `1 / (2 var_d)` or `1 / b_d`.
    pub coef: [f64; 6],
    /// True for the Laplace form (`|d|`), false for the Gaussian (`d^2`).
    pub absolute: bool,
}

impl KernelTerm {
    /// `ln P(d)`.
    #[inline]
    pub fn log_density(&self, d: &[f64; 6]) -> f64 {
        let e: f64 = if self.absolute {
            self.coef.iter().zip(d).map(|(c, d)| c * d.abs()).sum()
        } else {
            self.coef.iter().zip(d).map(|(c, d)| c * d * d).sum()
        };
        self.log_norm - e
    }
}

impl Kernel {
    /// Gaussian-R with our default regulariser: the paper's 50 mm^2 on translation,
    /// 0.05 rad^2 (a 0.22 rad standard deviation) on rotation.
    pub const GAUSSIAN_R_DEFAULT: Kernel = Kernel::GaussianR {
        s_translation_m2: 50e-6,
        s_rotation_rad2: 0.05,
    };

    /// Laplace with our default scales: the paper's 50 mm on translation, 0.5 rad on
    /// rotation.
    pub const LAPLACE_DEFAULT: Kernel = Kernel::Laplace {
        b_translation_m: 0.05,
        b_rotation_rad: 0.5,
    };

    /// Gaussian-R with the paper's scalar regulariser `s` (mm^2 and rad^2 mixed).
    pub fn paper_gaussian_r(s: f64) -> Kernel {
        Kernel::GaussianR {
            s_translation_m2: s * 1e-6,
            s_rotation_rad2: s,
        }
    }

    /// Laplace with the paper's scalar diversity `b` (mm and rad mixed).
    pub fn paper_laplace(b: f64) -> Kernel {
        Kernel::Laplace {
            b_translation_m: b * 1e-3,
            b_rotation_rad: b,
        }
    }

    /// Short name: `gaussian`, `gaussian-r` or `laplace`.
    pub fn name(&self) -> &'static str {
        match self {
            Kernel::Gaussian => "gaussian",
            Kernel::GaussianR { .. } => "gaussian-r",
            Kernel::Laplace { .. } => "laplace",
        }
    }

    /// The parameters by name, for validation and messages.
    pub fn parameters(&self) -> Vec<(&'static str, f64)> {
        match *self {
            Kernel::Gaussian => Vec::new(),
            Kernel::GaussianR {
                s_translation_m2,
                s_rotation_rad2,
            } => vec![
                ("s_translation_m2", s_translation_m2),
                ("s_rotation_rad2", s_rotation_rad2),
            ],
            Kernel::Laplace {
                b_translation_m,
                b_rotation_rad,
            } => vec![
                ("b_translation_m", b_translation_m),
                ("b_rotation_rad", b_rotation_rad),
            ],
        }
    }

    /// The log-density pieces for a grasp with per-DOF standard deviations `sigma`
    /// (m, m, m, rad, rad, rad; `Sigma = diag(sigma^2)`).
    pub fn term(&self, sigma: &[f64; 6]) -> KernelTerm {
        match *self {
            Kernel::Gaussian => gaussian_term(std::array::from_fn(|i| sigma[i] * sigma[i])),
            Kernel::GaussianR {
                s_translation_m2,
                s_rotation_rad2,
            } => gaussian_term(std::array::from_fn(|i| {
                sigma[i] * sigma[i]
                    + if i < 3 {
                        s_translation_m2
                    } else {
                        s_rotation_rad2
                    }
            })),
            Kernel::Laplace {
                b_translation_m,
                b_rotation_rad,
            } => {
                let b: [f64; 6] = std::array::from_fn(|i| {
                    if i < 3 {
                        b_translation_m
                    } else {
                        b_rotation_rad
                    }
                });
                KernelTerm {
                    log_norm: -b.iter().map(|b| (2.0 * b).ln()).sum::<f64>(),
                    coef: std::array::from_fn(|i| 1.0 / b[i]),
                    absolute: true,
                }
            }
        }
    }
}

fn gaussian_term(var: [f64; 6]) -> KernelTerm {
    KernelTerm {
        log_norm: -3.0 * (2.0 * PI).ln() - 0.5 * var.iter().map(|v| v.ln()).sum::<f64>(),
        coef: std::array::from_fn(|i| 0.5 / var[i]),
        absolute: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix6, Vector6};

    /// The multivariate normal density written out with a full matrix.
    fn normal_pdf(d: &[f64; 6], cov: &Matrix6<f64>) -> f64 {
        let d = Vector6::from_column_slice(d);
        let inv = cov.try_inverse().unwrap();
        let q = (d.transpose() * inv * d)[0];
        (-0.5 * q).exp() / ((2.0 * PI).powi(6) * cov.determinant()).sqrt()
    }

    const SIGMA: [f64; 6] = [0.01, 0.02, 0.005, 0.1, 0.2, 0.3];
    const D: [f64; 6] = [0.004, -0.01, 0.002, 0.05, -0.3, 0.2];

    #[test]
    fn gaussians_match_the_full_matrix_density() {
        let cov = Matrix6::from_diagonal(&Vector6::from_fn(|i, _| SIGMA[i] * SIGMA[i]));
        let got = Kernel::Gaussian.term(&SIGMA).log_density(&D).exp();
        let want = normal_pdf(&D, &cov);
        assert!((got / want - 1.0).abs() < 1e-12, "{got} vs {want}");
        let k = Kernel::GaussianR {
            s_translation_m2: 1e-4,
            s_rotation_rad2: 0.5,
        };
        let reg = Vector6::new(1e-4, 1e-4, 1e-4, 0.5, 0.5, 0.5);
        let want = normal_pdf(&D, &(cov + Matrix6::from_diagonal(&reg)));
        let got = k.term(&SIGMA).log_density(&D).exp();
        assert!((got / want - 1.0).abs() < 1e-12, "{got} vs {want}");
    }

    #[test]
    fn laplace_is_a_product_of_double_exponentials() {
        let k = Kernel::Laplace {
            b_translation_m: 0.03,
            b_rotation_rad: 0.4,
        };
        let want: f64 = (0..6)
            .map(|i| {
                let b = if i < 3 { 0.03 } else { 0.4 };
                (-D[i].abs() / b).exp() / (2.0 * b)
            })
            .product();
        let got = k.term(&SIGMA).log_density(&D).exp();
        assert!((got / want - 1.0).abs() < 1e-12);
    }

    #[test]
    fn paper_scalar_converts_millimetres() {
        // The paper's density over [mm, mm, mm, rad, rad, rad] with s = 50 equals ours
        // over metres times 1e-9 (the Jacobian of mm -> m on three axes).
        let sigma_mm: [f64; 6] = std::array::from_fn(|i| SIGMA[i] * if i < 3 { 1e3 } else { 1.0 });
        let d_mm: [f64; 6] = std::array::from_fn(|i| D[i] * if i < 3 { 1e3 } else { 1.0 });
        let paper = normal_pdf(
            &d_mm,
            &(Matrix6::from_diagonal(&Vector6::from_fn(|i, _| sigma_mm[i].powi(2)))
                + Matrix6::identity() * 50.0),
        );
        let ours = Kernel::paper_gaussian_r(50.0)
            .term(&SIGMA)
            .log_density(&D)
            .exp();
        assert!((ours * 1e-9 / paper - 1.0).abs() < 1e-9, "{ours} {paper}");
        let paper: f64 = (0..6)
            .map(|i| (-d_mm[i].abs() / 50.0).exp() / 100.0)
            .product();
        let ours = Kernel::paper_laplace(50.0)
            .term(&SIGMA)
            .log_density(&D)
            .exp();
        assert!((ours * 1e-9 / paper - 1.0).abs() < 1e-9, "{ours} {paper}");
    }
}
