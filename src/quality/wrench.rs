//! Contacts to friction-cone edge wrenches.
//!
//! A contact is a point on the object's surface and the inward unit normal there (the
//! direction in which the finger pushes). Coulomb friction with coefficient `mu` is
//! linearised as an `m`-edge pyramid: edge `k` is the force
//! `f_k = n + mu (cos(2 pi k / m) t1 + sin(2 pi k / m) t2)`, i.e. a unit *normal*
//! component, as in Ferrari & Canny's L1 grasp wrench space and GraspIt! (the sum of
//! the normal force magnitudes is bounded by 1). Its wrench about the reference point
//! `c` is `[f; (p - c) x f / r]`, where the torque scale `r` (m) makes torques
//! commensurable with forces; GraspIt! uses the largest distance from the object's
//! centroid to its surface. A frictionless contact (`mu = 0`) has the single edge `n`.

use super::{QualityError, QualityParams};
use nalgebra::{Point3, Vector3, Vector6};
use serde::{Deserialize, Serialize};

/// A 6-D wrench `[force; torque / r]` (N, N).
pub type Wrench = Vector6<f64>;

/// A contact between a finger and the object.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Contact {
    /// The contact point (m), in the object's frame (or any frame the reference point shares).
    pub point: Point3<f64>,
    /// The inward surface normal (into the object); normalised before use.
    pub normal: Vector3<f64>,
}

/// A unit tangent `t1` perpendicular to a unit `normal`; `(t1, normal x t1)` spans the
/// tangent plane. `t1` lies in the plane spanned by `normal` and the world axis least
/// aligned with it, so it depends on the frame: the pyramid's orientation about the
/// normal is a discretisation choice, not a physical quantity.
pub fn tangent_of(normal: &Vector3<f64>) -> Vector3<f64> {
    let a = normal.abs();
    let axis = if a.x <= a.y && a.x <= a.z {
        Vector3::x()
    } else if a.y <= a.z {
        Vector3::y()
    } else {
        Vector3::z()
    };
    normal.cross(&axis).normalize()
}

/// The `edges` force vectors of the friction pyramid about the unit `normal`, starting at
/// the unit tangent `t1`: unit normal component, tangential component `mu`. One edge
/// (the normal) when `mu == 0`.
pub fn cone_edge_forces(
    normal: &Vector3<f64>,
    t1: &Vector3<f64>,
    mu: f64,
    edges: usize,
) -> Vec<Vector3<f64>> {
    if mu == 0.0 {
        return vec![*normal];
    }
    let t2 = normal.cross(t1);
    (0..edges)
        .map(|k| {
            let angle = std::f64::consts::TAU * k as f64 / edges as f64;
            normal + (t1 * angle.cos() + t2 * angle.sin()) * mu
        })
        .collect()
}

/// The wrench `[f; (p - c) x f / r]` of force `force` applied at `point`.
pub fn wrench_of(
    point: &Point3<f64>,
    force: &Vector3<f64>,
    reference: &Point3<f64>,
    torque_scale_m: f64,
) -> Wrench {
    let torque = (point - reference).cross(force) / torque_scale_m;
    Wrench::new(force.x, force.y, force.z, torque.x, torque.y, torque.z)
}

/// The reference point and torque scale used for `contacts`: the given ones, else the
/// mean of the contact points and the largest distance of a contact from it (1 m when
/// all contacts coincide with it, where every torque is zero anyway).
pub fn reference_and_scale(contacts: &[Contact], params: &QualityParams) -> (Point3<f64>, f64) {
    let reference = params.centroid.unwrap_or_else(|| {
        let sum = contacts
            .iter()
            .fold(Vector3::zeros(), |acc, c| acc + c.point.coords);
        Point3::from(sum / contacts.len().max(1) as f64)
    });
    let scale = params.torque_scale_m.unwrap_or_else(|| {
        let r = contacts
            .iter()
            .map(|c| (c.point - reference).norm())
            .fold(0.0, f64::max);
        if r > 0.0 {
            r
        } else {
            1.0
        }
    });
    (reference, scale)
}

/// The friction-cone edge wrenches of all contacts (`edges` per contact, 1 when
/// frictionless), after validating the contacts and parameters.
pub fn contact_wrenches(
    contacts: &[Contact],
    params: &QualityParams,
) -> Result<Vec<Wrench>, QualityError> {
    params.validate()?;
    for (index, c) in contacts.iter().enumerate() {
        check_vector(index, "point", c.point.coords.as_slice())?;
        check_vector(index, "normal", c.normal.as_slice())?;
        if c.normal.norm() < 1e-12 {
            return Err(QualityError::ZeroNormal {
                index,
                normal: [c.normal.x, c.normal.y, c.normal.z],
            });
        }
    }
    let (reference, scale) = reference_and_scale(contacts, params);
    let mut wrenches = Vec::with_capacity(contacts.len() * params.cone_edges);
    for c in contacts {
        let n = c.normal.normalize();
        for f in cone_edge_forces(&n, &tangent_of(&n), params.mu, params.cone_edges) {
            wrenches.push(wrench_of(&c.point, &f, &reference, scale));
        }
    }
    Ok(wrenches)
}

fn check_vector(index: usize, field: &'static str, values: &[f64]) -> Result<(), QualityError> {
    match values.iter().find(|v| !v.is_finite()) {
        Some(&value) => Err(QualityError::NotFinite {
            index,
            field,
            value,
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangent_is_unit_and_perpendicular() {
        for n in [
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(1.0, 2.0, -3.0).normalize(),
            Vector3::new(-1.0, 0.0, 0.0),
        ] {
            let t = tangent_of(&n);
            assert!((t.norm() - 1.0).abs() < 1e-12);
            assert!(t.dot(&n).abs() < 1e-12);
        }
    }

    #[test]
    fn cone_edges_have_unit_normal_part_and_friction_angle() {
        let n = Vector3::new(0.0, 0.0, -1.0);
        let edges = cone_edge_forces(&n, &tangent_of(&n), 0.5, 8);
        assert_eq!(edges.len(), 8);
        for f in &edges {
            assert!((f.dot(&n) - 1.0).abs() < 1e-12);
            assert!(((f - n).norm() - 0.5).abs() < 1e-12);
        }
        // The edges of a pyramid sum to m times the normal.
        let sum: Vector3<f64> = edges.iter().sum();
        assert!((sum - n * 8.0).norm() < 1e-12);
        assert_eq!(cone_edge_forces(&n, &tangent_of(&n), 0.0, 8), vec![n]);
    }

    #[test]
    fn wrench_torque_is_moment_over_scale() {
        // Force +y at (1, 0, 0) about the origin: torque +z of 1 N m, scaled by 1/2.
        let w = wrench_of(
            &Point3::new(1.0, 0.0, 0.0),
            &Vector3::y(),
            &Point3::origin(),
            2.0,
        );
        assert_eq!(w, Wrench::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.5));
    }

    #[test]
    fn default_reference_is_mean_and_scale_is_farthest_contact() {
        let contacts = [
            Contact {
                point: Point3::new(1.0, 0.0, 0.0),
                normal: -Vector3::x(),
            },
            Contact {
                point: Point3::new(-1.0, 0.0, 0.0),
                normal: Vector3::x(),
            },
            Contact {
                point: Point3::new(0.0, 3.0, 0.0),
                normal: -Vector3::y(),
            },
        ];
        let (c, r) = reference_and_scale(&contacts, &QualityParams::default());
        assert!((c - Point3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
        assert!((r - 2.0).abs() < 1e-12);
    }

    #[test]
    fn bad_contacts_are_rejected_by_index() {
        let bad = [Contact {
            point: Point3::new(0.0, f64::NAN, 0.0),
            normal: Vector3::z(),
        }];
        let err = contact_wrenches(&bad, &QualityParams::default()).unwrap_err();
        assert!(err.to_string().contains("contact 0"), "{err}");
        let zero = [Contact {
            point: Point3::origin(),
            normal: Vector3::zeros(),
        }];
        assert!(matches!(
            contact_wrenches(&zero, &QualityParams::default()),
            Err(QualityError::ZeroNormal { index: 0, .. })
        ));
    }
}
