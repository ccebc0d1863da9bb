//! The weights of eq. 2: grasp stability `psi(q)` (eq. 3) and model fit `phi` (eq. 4).

use serde::{Deserialize, Serialize};

/// Which fit weight of eq. 4 to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FitWeight {
    /// (4a) `phi(eps) = exp(-lambda_eps eps)`.
    Eps,
    /// (4b) `phi(eps, sigma) = exp(-lambda_eps (eps + sigma))`, more robust for
    /// partial clouds (it penalises a few large residuals).
    EpsSigma,
}

/// The parameters of the weights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Weights {
    /// `lambda_psi` of eq. 3, per unit of grasp quality (epsilon).
    pub lambda_psi: f64,
    /// `lambda_eps` of eq. 4 (1/m^2): the fitting error is a mean squared distance.
    pub lambda_eps_per_m2: f64,
    /// Fit weight variant.
    pub fit: FitWeight,
}

impl Default for Weights {
    /// `lambda_psi = 10` (psi(0.1) = 0.63), `lambda_eps = 1e4 / m^2` (a 1 cm rms fit
    /// weighs exp(-1) of a perfect one), (4b).
    fn default() -> Self {
        Weights {
            lambda_psi: 10.0,
            lambda_eps_per_m2: 1e4,
            fit: FitWeight::EpsSigma,
        }
    }
}

/// Stability weight (eq. 3): `psi(q) = 1 - exp(-lambda_psi q)`; 0 for `q = 0`.
pub fn psi(q: f64, lambda_psi: f64) -> f64 {
    -(-lambda_psi * q).exp_m1()
}

/// Fit weight (4a): `phi(eps) = exp(-lambda_eps eps)`.
pub fn phi(eps_m2: f64, lambda_eps_per_m2: f64) -> f64 {
    (-lambda_eps_per_m2 * eps_m2).exp()
}

/// Fit weight (4b): `phi(eps, sigma) = exp(-lambda_eps (eps + sigma))`.
pub fn phi_sigma(eps_m2: f64, sigma_m2: f64, lambda_eps_per_m2: f64) -> f64 {
    (-lambda_eps_per_m2 * (eps_m2 + sigma_m2)).exp()
}

impl Weights {
    /// `ln psi(q)` (`-inf` for `q = 0`).
    pub fn log_psi(&self, q: f64) -> f64 {
        psi(q, self.lambda_psi).ln()
    }

    /// `ln phi` of a fit by the configured variant (no underflow: it is linear).
    pub fn log_phi(&self, eps_m2: f64, sigma_m2: f64) -> f64 {
        match self.fit {
            FitWeight::Eps => -self.lambda_eps_per_m2 * eps_m2,
            FitWeight::EpsSigma => -self.lambda_eps_per_m2 * (eps_m2 + sigma_m2),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_match_their_equations() {
        assert_eq!(psi(0.0, 10.0), 0.0);
        assert!((psi(0.1, 10.0) - (1.0 - (-1.0f64).exp())).abs() < 1e-15);
        // Tiny q keeps its precision (1 - exp(-x) ~ x).
        assert!((psi(1e-12, 10.0) / 1e-11 - 1.0).abs() < 1e-10);
        assert!((phi(1e-4, 1e4) - (-1.0f64).exp()).abs() < 1e-15);
        assert!((phi_sigma(1e-4, 1e-4, 1e4) - (-2.0f64).exp()).abs() < 1e-15);
        let w = Weights::default();
        assert!((w.log_phi(1e-4, 1e-4) - phi_sigma(1e-4, 1e-4, 1e4).ln()).abs() < 1e-12);
        let w = Weights {
            fit: FitWeight::Eps,
            ..w
        };
        assert!((w.log_phi(1e-4, 1e-4) + 1.0).abs() < 1e-12);
        assert_eq!(w.log_psi(0.0), f64::NEG_INFINITY);
    }
}
