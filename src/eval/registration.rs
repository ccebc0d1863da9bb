//! The category's registration ([`crate::register`]) as the experiments'
//! [`Registrar`]: the models are prepared once, and leave-one-out drops the held-out
//! model from the set for its own target.

use super::experiment::{Registrar, RegistrationFailure};
use crate::category::CategoryDb;
use crate::cloud::PointCloud;
use crate::plan::input::fits_input;
use crate::plan::ModelFit;
use crate::register::{register_all, ModelSet, RegisterError, RegisterParams};

/// Registration against the models of one category database.
#[derive(Debug, Clone)]
pub struct CategoryRegistrar {
    set: ModelSet,
    params: RegisterParams,
}

impl CategoryRegistrar {
    /// Prepares the models of `db` with the default registration parameters; with
    /// `viewpoint_m` (the camera's position, base frame) target normals are oriented
    /// towards it, as for a partial view.
    pub fn new(
        db: &CategoryDb,
        viewpoint_m: Option<[f64; 3]>,
    ) -> Result<CategoryRegistrar, RegisterError> {
        let params = RegisterParams {
            viewpoint_m,
            ..RegisterParams::default()
        };
        let set = ModelSet::from_category(db, &params)?;
        Ok(CategoryRegistrar { set, params })
    }

    /// Scores fits for `view`: a complete view's two-sided score compares every
    /// model point with the target ([`RegisterParams::complete_view`]).
    pub fn for_view(mut self, view: super::ViewKind) -> CategoryRegistrar {
        self.params.complete_view = view == super::ViewKind::Complete;
        self
    }

    /// With `paper`, scores fits as the paper did ([`RegisterParams::paper`]:
    /// one-sided, poor registrations kept).
    pub fn paper(mut self, paper: bool) -> CategoryRegistrar {
        if paper {
            self.params = self.params.paper();
        }
        self
    }
}

impl Registrar for CategoryRegistrar {
    fn fits(
        &self,
        target_base: &PointCloud,
        exclude: Option<&str>,
        seed: u64,
    ) -> Result<Vec<ModelFit>, RegistrationFailure> {
        let without;
        let set = match exclude {
            Some(name) => {
                without = self.set.without(name);
                &without
            }
            None => &self.set,
        };
        let registrations = register_all(target_base, set, &self.params, seed)?;
        let input = fits_input(&registrations);
        if input.fits.is_empty() {
            return Err(RegistrationFailure::NoneRegistered {
                reasons: input.unregistered_text(),
            });
        }
        Ok(input.fits)
    }
}
