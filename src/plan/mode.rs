//! The paper's settings beside the cell's own, for a fair reproduction (issue 19).
//!
//! [`PlanMode::Cell`] is the shipped behaviour: our kernel scales, the category's
//! calibrated weights, and the **same reachability repair for every method** (an
//! unreachable optimum, or an unreachable best-single grasp, is replaced by the best
//! reachable pose the constrained search finds near it).
//!
//! [`PlanMode::Paper`] is Nikandrova & Kyrki's setting: the scalar kernel scale
//! `s = b = 50` in simulation and 700 on the robot protocol (positions in mm, angles
//! in rad, [`Kernel::paper_gaussian_r`], [`Kernel::paper_laplace`]), the fixed
//! weights `lambda_psi = 10`, `lambda_eps = 1e4 / m^2` ([`Weights::default`]), and
//! **no repair** for any method: an unreachable grasp stays the answer, marked
//! unreachable, so that reachability failures are counted apart, as in the paper's
//! Table 2. Other commands (`cell eval`, `cell campaign`) pass a mode and call
//! [`PlanMode::apply`] on their options.

use super::{Kernel, PlanOptions, Weights};
use serde::Serialize;

/// Which of the paper's experiments sets the kernel scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum PaperProtocol {
    /// The simulation experiments (Figs. 5-6, Table 1): s = b = 50.
    Simulation,
    /// The robot experiment (Table 2): s = b = 700.
    Robot,
}

impl PaperProtocol {
    /// The paper's scalar `s` (Gaussian-R) and `b` (Laplace), mm and rad mixed.
    pub fn scale(self) -> f64 {
        match self {
            PaperProtocol::Simulation => 50.0,
            PaperProtocol::Robot => 700.0,
        }
    }
}

/// The cell's own planning settings, or the paper's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(tag = "mode", rename_all = "kebab-case")]
pub enum PlanMode {
    /// Our defaults, with the reachability repair for every method.
    Cell,
    /// The paper's kernel scale and weights, no repair.
    Paper {
        /// Which experiment's scale.
        protocol: PaperProtocol,
    },
}

impl PlanMode {
    /// The kernel of this mode for the family of `kernel` (the cell's mode keeps
    /// `kernel` as given).
    pub fn kernel(&self, kernel: Kernel) -> Kernel {
        match (self, kernel) {
            (PlanMode::Cell, k) | (PlanMode::Paper { .. }, k @ Kernel::Gaussian) => k,
            (PlanMode::Paper { protocol }, Kernel::GaussianR { .. }) => {
                Kernel::paper_gaussian_r(protocol.scale())
            }
            (PlanMode::Paper { protocol }, Kernel::Laplace { .. }) => {
                Kernel::paper_laplace(protocol.scale())
            }
        }
    }

    /// Sets `options` for this mode: in the paper's, its kernel scale, its weights
    /// and no repair; the cell's mode leaves them as they are.
    pub fn apply(&self, options: &mut PlanOptions) {
        if let PlanMode::Paper { .. } = self {
            options.kernel = self.kernel(options.kernel);
            options.weights = Weights::default();
            options.repair = false;
        }
    }

    /// Whether unreachable grasps are repaired.
    pub fn repairs(&self) -> bool {
        matches!(self, PlanMode::Cell)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_mode_sets_its_scales_weights_and_no_repair() {
        let mut options = PlanOptions::with_kernel(Kernel::LAPLACE_DEFAULT);
        options.weights.lambda_psi = 3.0;
        let mode = PlanMode::Paper {
            protocol: PaperProtocol::Robot,
        };
        mode.apply(&mut options);
        assert_eq!(options.kernel, Kernel::paper_laplace(700.0));
        assert_eq!(options.weights, Weights::default());
        assert!(!options.repair && !mode.repairs());
        let sim = PlanMode::Paper {
            protocol: PaperProtocol::Simulation,
        };
        assert_eq!(
            sim.kernel(Kernel::GAUSSIAN_R_DEFAULT),
            Kernel::paper_gaussian_r(50.0)
        );
        assert_eq!(sim.kernel(Kernel::Gaussian), Kernel::Gaussian);
        let mut cell = PlanOptions::with_kernel(Kernel::GAUSSIAN_R_DEFAULT);
        let before = cell;
        PlanMode::Cell.apply(&mut cell);
        assert_eq!(cell, before);
        assert!(cell.repair);
    }
}
