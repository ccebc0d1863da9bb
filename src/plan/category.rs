//! The planner's example grasps from a category database, matched to the fits.
//!
//! Registration gives one fit per model that registered; the database holds every
//! model's task-labelled grasps. The planner wants, for one task, the grasps whose
//! model has a fit, indexed by that fit.

use super::{ExampleGrasp, FitWeight, ModelFit, PlanError, Weights};
use crate::category::CategoryDb;

/// The weights of eq. 2 for `db`: its calibrated `lambda_psi` and `lambda_eps` with
/// the fit weight (4b) when `cell train` stored them
/// ([`crate::category::calibrate`]), else [`Weights::default`].
pub fn weights(db: &CategoryDb) -> Weights {
    match &db.file.weights {
        Some(w) => Weights {
            lambda_psi: w.lambda_psi,
            lambda_eps_per_m2: w.lambda_eps_per_m2,
            fit: FitWeight::EpsSigma,
        },
        None => Weights::default(),
    }
}

/// The example grasps of `task` in `db`, each pointing at its model's entry in `fits`.
///
/// Grasps of models without a fit (their registration failed) are left out. Errors:
/// a fit that names no model of the database, a task the database has no grasp for,
/// or a task whose grasped models all lack a fit.
pub fn example_grasps(
    db: &CategoryDb,
    fits: &[ModelFit],
    task: &str,
) -> Result<Vec<ExampleGrasp>, PlanError> {
    if let Some(f) = fits.iter().find(|f| db.model_index(&f.name).is_none()) {
        return Err(PlanError::UnknownModel {
            model: f.name.clone(),
            database: db.dir.clone(),
        });
    }
    let of_task: Vec<_> = db.grasps_for(task).collect();
    if of_task.is_empty() {
        let mut tasks: Vec<&str> = db.file.grasps.iter().map(|g| g.task.as_str()).collect();
        tasks.sort_unstable();
        tasks.dedup();
        return Err(PlanError::NoGraspsForTask {
            task: task.to_string(),
            available: tasks.join(", "),
        });
    }
    let grasps: Vec<ExampleGrasp> = of_task
        .iter()
        .filter_map(|g| {
            let model = fits.iter().position(|f| f.name == g.model)?;
            Some(ExampleGrasp {
                model,
                task: g.task.clone(),
                model_from_palm: g.params(),
                spread_rad: g.spread_rad,
                preshape_rad: g.preshape_rad,
                max_overtravel_m: g.max_overtravel_m,
                q: g.q,
                sigma: g.sigma,
            })
        })
        .collect();
    if grasps.is_empty() {
        let mut models: Vec<&str> = of_task.iter().map(|g| g.model.as_str()).collect();
        models.dedup();
        return Err(PlanError::NoFitForTask {
            task: task.to_string(),
            models: models.join(", "),
        });
    }
    Ok(grasps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;
    use std::path::Path;

    fn mug_db() -> CategoryDb {
        CategoryDb::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("db/mug")).unwrap()
    }

    fn fit(name: &str) -> ModelFit {
        ModelFit {
            name: name.into(),
            base_from_model: Pose::identity(),
            eps_m2: 1e-6,
            sigma_m2: 1e-7,
        }
    }

    #[test]
    fn grasps_of_the_task_point_at_their_fits() {
        let db = mug_db();
        let names: Vec<String> = db.file.models.iter().map(|m| m.name.clone()).collect();
        // Fits in reverse order, without the first model: indices must follow the fits.
        let fits: Vec<ModelFit> = names[1..].iter().rev().map(|n| fit(n)).collect();
        let grasps = example_grasps(&db, &fits, "handle").unwrap();
        let expected = db
            .grasps_for("handle")
            .filter(|g| g.model != names[0])
            .count();
        assert!(expected > 0);
        assert_eq!(grasps.len(), expected);
        for g in &grasps {
            assert_eq!(g.task, "handle");
            let entry = db
                .grasps_for("handle")
                .find(|e| e.model == fits[g.model].name && e.params() == g.model_from_palm)
                .expect("grasp comes from the database under its fit's model");
            assert_eq!(entry.q, g.q);
            assert_eq!(entry.sigma, g.sigma);
        }
    }

    #[test]
    fn the_shipped_databases_carry_calibrated_weights_and_they_are_used() {
        for category in ["mug", "bottle", "hammer", "knife"] {
            let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("db")
                .join(category);
            let db = CategoryDb::load(&dir).unwrap();
            let stored = db.file.weights.as_ref().expect("calibrated by cell train");
            let w = weights(&db);
            assert_eq!(w.lambda_psi, stored.lambda_psi, "{category}");
            assert_eq!(w.lambda_eps_per_m2, stored.lambda_eps_per_m2, "{category}");
            assert_ne!(w, Weights::default(), "{category}");
            // The numbers they came from: the median fit weighs 1/e, the median q 1/2.
            assert!((w.lambda_eps_per_m2 * stored.fit_score_m2.median - 1.0).abs() < 1e-9);
            assert!((w.lambda_psi * stored.q.median - std::f64::consts::LN_2).abs() < 1e-9);
            assert!(stored.fit_score_m2.count > 0 && stored.loo.view == "partial");
        }
        // Without a calibration, the defaults.
        let mut db = mug_db();
        db.file.weights = None;
        assert_eq!(weights(&db), Weights::default());
    }

    #[test]
    fn unknown_task_and_unknown_model_are_named() {
        let db = mug_db();
        let fits = vec![fit(&db.file.models[0].name)];
        let e = example_grasps(&db, &fits, "pour").unwrap_err().to_string();
        assert!(e.contains("\"pour\"") && e.contains("handle"), "{e}");
        let e = example_grasps(&db, &[fit("teapot_9")], "top")
            .unwrap_err()
            .to_string();
        assert!(e.contains("teapot_9"), "{e}");
    }

    #[test]
    fn a_task_whose_models_all_lack_fits_is_an_error() {
        let db = mug_db();
        let grasped: Vec<&str> = db.grasps_for("top").map(|g| g.model.as_str()).collect();
        let others: Vec<ModelFit> = db
            .file
            .models
            .iter()
            .filter(|m| !grasped.contains(&m.name.as_str()))
            .map(|m| fit(&m.name))
            .collect();
        if others.is_empty() {
            // Every model has a top grasp: an empty fit list is the same case.
            assert!(example_grasps(&db, &[], "top").is_err());
        } else {
            let e = example_grasps(&db, &others, "top").unwrap_err().to_string();
            assert!(e.contains("top"), "{e}");
        }
    }
}
