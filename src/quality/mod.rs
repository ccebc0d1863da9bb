//! Grasp quality from contacts: Ferrari–Canny epsilon and the volume of the grasp
//! wrench space.
//!
//! Contacts become friction-cone edge wrenches ([`wrench`]); their convex hull is the
//! L1 grasp wrench space ([`gws`], qhull). Epsilon, the radius of the largest ball about
//! the origin inside it (0 without force closure), comes from [`epsilon`], which grows
//! the hull only toward the origin and is exact; qhull gives the volume (and is the
//! fallback for epsilon should the expansion fail numerically).

pub mod approach;
pub mod autograsp;
pub mod epsilon;
pub mod gws;
pub mod stability;
pub mod wrench;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};
pub use wrench::{Contact, Wrench};

/// Errors in grasp-quality inputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum QualityError {
    /// A coordinate of a contact is NaN or infinite.
    #[error("contact {index}: {field} has the non-finite value {value}")]
    NotFinite {
        /// Zero-based contact index.
        index: usize,
        /// `point` or `normal`.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A contact normal of (nearly) zero length.
    #[error("contact {index}: normal {normal:?} has zero length")]
    ZeroNormal {
        /// Zero-based contact index.
        index: usize,
        /// The offending normal.
        normal: [f64; 3],
    },
    /// The friction coefficient is negative or not finite.
    #[error("friction coefficient mu = {mu} must be finite and >= 0")]
    Friction {
        /// The offending coefficient.
        mu: f64,
    },
    /// Too few friction-cone edges for a pyramid.
    #[error("cone_edges = {edges} must be at least 3")]
    ConeEdges {
        /// The offending count.
        edges: usize,
    },
    /// The torque scale is not a positive finite length.
    #[error("torque_scale = {torque_scale_m} m must be finite and > 0")]
    TorqueScale {
        /// The offending scale (m).
        torque_scale_m: f64,
    },
    /// The reference point is not finite.
    #[error("centroid {centroid:?} is not finite")]
    Centroid {
        /// The offending point (m).
        centroid: [f64; 3],
    },
}

/// Parameters of the quality metric.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityParams {
    /// Coulomb friction coefficient (0.5 by default; 0 = frictionless).
    pub mu: f64,
    /// Edges of the friction pyramid (8 by default).
    pub cone_edges: usize,
    /// Torque scale r (m): torques are divided by it. GraspIt! uses the largest distance
    /// from the object's centroid to its surface; None = the largest distance of a
    /// contact from the reference point (for contacts given without an object).
    pub torque_scale_m: Option<f64>,
    /// Reference point for torques: the object's centroid; None = the mean of the
    /// contact points.
    pub centroid: Option<Point3<f64>>,
}

impl Default for QualityParams {
    fn default() -> Self {
        QualityParams {
            mu: 0.5,
            cone_edges: 8,
            torque_scale_m: None,
            centroid: None,
        }
    }
}

impl QualityParams {
    /// Checks the ranges of the parameters.
    pub fn validate(&self) -> Result<(), QualityError> {
        if !(self.mu.is_finite() && self.mu >= 0.0) {
            return Err(QualityError::Friction { mu: self.mu });
        }
        if self.cone_edges < 3 {
            return Err(QualityError::ConeEdges {
                edges: self.cone_edges,
            });
        }
        if let Some(r) = self.torque_scale_m {
            if !(r.is_finite() && r > 0.0) {
                return Err(QualityError::TorqueScale { torque_scale_m: r });
            }
        }
        if let Some(c) = self.centroid {
            if c.iter().any(|x| !x.is_finite()) {
                return Err(QualityError::Centroid {
                    centroid: [c.x, c.y, c.z],
                });
            }
        }
        Ok(())
    }
}

/// The quality of a grasp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GraspQuality {
    /// Ferrari–Canny epsilon: distance from the origin to the nearest facet of the grasp
    /// wrench space when the origin is strictly inside, else 0.
    pub epsilon: f64,
    /// 6-D volume of the grasp wrench space (0 when it has no interior).
    pub volume: f64,
    /// Whether the grasp is force closure (epsilon > 0).
    pub force_closure: bool,
}

/// Epsilon, volume and force closure of a grasp with `contacts`.
pub fn evaluate(
    contacts: &[Contact],
    params: &QualityParams,
) -> Result<GraspQuality, QualityError> {
    let wrenches = wrench::contact_wrenches(contacts, params)?;
    let volume = match gws::hull_measures(&wrenches) {
        Ok(m) => m.volume,
        Err(e) => {
            tracing::debug!("{e}; volume taken as 0");
            0.0
        }
    };
    let epsilon = epsilon_of_wrenches(&wrenches);
    Ok(GraspQuality {
        epsilon,
        volume,
        force_closure: epsilon > 0.0,
    })
}

/// Epsilon alone (no volume): the fast path for grasp search.
pub fn epsilon(contacts: &[Contact], params: &QualityParams) -> Result<f64, QualityError> {
    Ok(epsilon_of_wrenches(&wrench::contact_wrenches(
        contacts, params,
    )?))
}

/// Epsilon of the hull of `wrenches` (0 without force closure): the best-first
/// expansion, or qhull should it fail numerically (0 if qhull fails too).
pub fn epsilon_of_wrenches(wrenches: &[Wrench]) -> f64 {
    match epsilon::origin_depth(wrenches) {
        Ok(epsilon::OriginDepth::Inside { epsilon, .. }) => epsilon,
        Ok(_) => 0.0,
        Err(e) => {
            tracing::debug!("{e}; falling back to qhull");
            gws::hull_measures(wrenches).map_or(0.0, |m| m.epsilon)
        }
    }
}
