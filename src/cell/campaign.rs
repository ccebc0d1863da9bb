//! Campaign planning: which trials a campaign runs (`cell campaign`).
//!
//! A campaign of one task runs every method on every novel object at every
//! placement. The trials of one object and placement are a *pair* (a tuple, with
//! more than two methods) for the report's sign tests: they share the placement,
//! the camera's noise and perception's seed, and the lab's errors, so that the
//! methods differ only in the method. Each task is its own campaign (its own
//! report), with an id that is stable across runs, so that a campaign already in the
//! trial log is resumed: its graded trials are not planned again.

use super::harness::{placement_rng, random_placement};
use super::log::verdict_grades;
use super::setup::{novel_object_in, ObjectSource, TrialSetup};
use crate::category::CategoryDb;
use crate::config::CellConfig;
use crate::eval::objects::UserObject;
use crate::ipc::Protocol;
use crate::mesh::procedural::held_apart::Family;
use crate::mesh::procedural::Category;
use crate::sim::lab::{LabDraw, LabErrors};
use crate::sim::observer::Agreement;
use crate::trial::report::latest_graded;
use crate::trial::{ObjectRef, Placement, Report, TrialRecord};
use serde::Serialize;
use std::collections::HashSet;

/// A novel object of a demo or campaign: its name, where its mesh comes from, and
/// the height (m) of its lowest point in its own frame (placements stand it on the
/// table).
#[derive(Debug, Clone, PartialEq)]
pub struct NovelObject {
    /// The object as the trial log names it.
    pub object: ObjectRef,
    /// Where its mesh comes from.
    pub source: ObjectSource,
    /// The lowest point's z in the object's frame (m).
    pub min_z_m: f64,
}

impl NovelObject {
    /// `count` procedural novel objects of `category` from `family`, the set `seed`
    /// (training-family instances are checked not to be one of `db`'s models).
    pub fn procedural(
        family: Family,
        category: Category,
        seed: u64,
        count: usize,
        db: &CategoryDb,
    ) -> Vec<NovelObject> {
        (0..count as u64)
            .map(|i| {
                let (object, source) = novel_object_in(family, category, seed, i, db);
                NovelObject {
                    object,
                    source,
                    min_z_m: 0.0,
                }
            })
            .collect()
    }

    /// A user's object (a mesh file of `objects.toml`).
    pub fn from_user(object: UserObject) -> NovelObject {
        let min_z_m = object
            .mesh
            .vertices
            .iter()
            .map(|v| v.z)
            .fold(f64::INFINITY, f64::min);
        NovelObject {
            object: ObjectRef {
                name: object.name,
                seed: None,
            },
            source: ObjectSource::File {
                path: object.path,
                scale: object.scale,
            },
            min_z_m,
        }
    }

    /// `placement` moved up or down so that the object's lowest point is on the table.
    pub fn on_table(&self, mut placement: Placement) -> Placement {
        placement.base_from_object.xyz[2] -= self.min_z_m;
        placement
    }
}

/// What a campaign runs: every method on every object at every placement, one
/// campaign per task.
#[derive(Debug, Clone)]
pub struct CampaignSpec {
    /// The category's name as given (and in the campaign ids).
    pub category: String,
    /// The tasks; each is its own campaign.
    pub tasks: Vec<String>,
    /// The novel objects, in order.
    pub objects: Vec<NovelObject>,
    /// Placements per object.
    pub placements: u32,
    /// The methods compared.
    pub methods: Vec<String>,
    /// The campaign id the user chose (with several tasks, `<id>-<task>`).
    pub campaign: Option<String>,
    /// Seed of objects, placements and noise.
    pub seed: u64,
    /// The paper's robot protocol (and campaign ids ending in `-paper`).
    pub paper: bool,
    /// The lab's errors (drawn per campaign and per trial).
    pub lab: LabErrors,
}

/// A trial of a campaign as the trial log knows it: graded ones are not run again.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct TrialKey {
    /// The campaign id.
    pub campaign_id: String,
    /// The object's name.
    pub object: String,
    /// The placement's index.
    pub placement: u32,
    /// The method.
    pub method: String,
}

/// Execution errors (`ExecuteError::kind`) of the link between the PC and the robot
/// controller, not of the method: the robot dropped to monitor mode (FRI quality
/// fell: answers came late), or its measurements stopped coming.
pub const LINK_FAULTS: [&str; 2] = ["arm_dropped_to_monitor", "arm_measurement_late"];

/// Whether `trial` ended on a [`LINK_FAULTS`] error: the grasp was never tried to
/// the end, so a campaign runs the trial again (a lab resets the robot and repeats
/// it) and reports the latest (`trial::report`).
pub fn ended_on_link_fault(trial: &TrialRecord) -> bool {
    link_fault(trial).is_some()
}

/// The link fault ([`LINK_FAULTS`]) `trial` ended on, if any.
pub fn link_fault(trial: &TrialRecord) -> Option<&'static str> {
    let kind = trial
        .trial
        .outcome
        .as_ref()?
        .get("execution_error")?
        .as_str()?;
    LINK_FAULTS.iter().copied().find(|k| *k == kind)
}

/// The link fault the trial that the cell ran as `cell_trial_id` (the id of its
/// request, which the log stage records in the outcome) ended on, if it is in
/// `trials` and ended on one: `cell demo` runs such a trial again at once.
pub fn link_fault_of(trials: &[TrialRecord], cell_trial_id: u64) -> Option<&'static str> {
    trials
        .iter()
        .rev()
        .find(|t| {
            t.trial
                .outcome
                .as_ref()
                .and_then(|o| o.get("cell_trial_id")?.as_u64())
                == Some(cell_trial_id)
        })
        .and_then(link_fault)
}

/// The campaign trials in `trials` (of a trial log) that have a grade and did not
/// end on a link fault ([`ended_on_link_fault`]): the trials a resumed campaign
/// does not run again.
pub fn graded_trials(trials: &[TrialRecord]) -> HashSet<TrialKey> {
    trials
        .iter()
        .filter(|t| t.grading.is_some() && !ended_on_link_fault(t))
        .filter_map(|t| {
            Some(TrialKey {
                campaign_id: t.trial.campaign_id.clone()?,
                object: t.trial.object.name.clone(),
                placement: t.trial.placement.index,
                method: t.trial.method.clone(),
            })
        })
        .collect()
}

/// One trial a campaign plans to run.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedTrial {
    /// The campaign (of the task).
    pub campaign_id: String,
    /// The task.
    pub task: String,
    /// The object.
    pub object: ObjectRef,
    /// Where its mesh comes from.
    pub source: ObjectSource,
    /// Where it stands (on the table).
    pub placement: Placement,
    /// The method.
    pub method: String,
    /// The seed of the camera's noise and of perception (the same for every method
    /// of an object and placement).
    pub seed: u64,
    /// The lab's errors (the same for every method of an object and placement).
    pub lab: Option<LabDraw>,
}

impl PlannedTrial {
    /// The trial's setup for the simulated world, as trial `trial_id`.
    pub fn setup(&self, trial_id: u64, category: Category) -> TrialSetup {
        TrialSetup {
            trial_id,
            category,
            object: self.object.clone(),
            placement: self.placement,
            campaign_id: Some(self.campaign_id.clone()),
            noise_seed: self.seed,
            perception_seed: self.seed,
            source: self.source.clone(),
            lab: self.lab,
        }
    }
}

impl CampaignSpec {
    /// The campaign id of `task`: the user's id (`<id>-<task>` with several tasks),
    /// else `<category>-<task>-seed<seed>`, ending in `-paper` under the paper's
    /// protocol.
    pub fn campaign_id(&self, task: &str) -> String {
        match &self.campaign {
            Some(c) if self.tasks.len() == 1 => c.clone(),
            Some(c) => format!("{c}-{task}"),
            None => format!(
                "{}-{task}-seed{}{}",
                self.category,
                self.seed,
                if self.paper { "-paper" } else { "" }
            ),
        }
    }

    /// The campaign ids, one per task, in task order.
    pub fn campaign_ids(&self) -> Vec<String> {
        self.tasks.iter().map(|t| self.campaign_id(t)).collect()
    }

    /// The protocol the trial requests name.
    pub fn protocol(&self) -> Protocol {
        if self.paper {
            Protocol::PaperRobot
        } else {
            Protocol::Cell
        }
    }

    /// Every trial of the campaigns, graded or not.
    pub fn total(&self) -> usize {
        self.tasks.len() * self.objects.len() * self.placements as usize * self.methods.len()
    }

    /// The seed of object `object`'s placement `placement` (camera noise,
    /// perception, the lab's joint errors), shared by every method.
    pub fn trial_seed(&self, object: usize, placement: u32) -> u64 {
        self.seed.wrapping_mul(1_000_003) ^ ((object as u64) << 16 | u64::from(placement))
    }

    /// The trials to run, task by task, object by object, placement by placement,
    /// method by method; those in `graded` are left out.
    pub fn plan(&self, config: &CellConfig, graded: &HashSet<TrialKey>) -> Vec<PlannedTrial> {
        let mut plan = Vec::new();
        for task in &self.tasks {
            let id = self.campaign_id(task);
            for (o, novel) in self.objects.iter().enumerate() {
                let mut rng = placement_rng(self.seed, o as u64);
                for p in 0..self.placements {
                    let placement = novel.on_table(random_placement(config, &mut rng, p));
                    let seed = self.trial_seed(o, p);
                    for method in &self.methods {
                        let key = TrialKey {
                            campaign_id: id.clone(),
                            object: novel.object.name.clone(),
                            placement: p,
                            method: method.clone(),
                        };
                        if graded.contains(&key) {
                            continue;
                        }
                        plan.push(PlannedTrial {
                            campaign_id: id.clone(),
                            task: task.clone(),
                            object: novel.object.clone(),
                            source: novel.source.clone(),
                            placement,
                            method: method.clone(),
                            seed,
                            lab: self.lab.trial_draw(self.seed, seed),
                        });
                    }
                }
            }
        }
        plan
    }
}

/// The report of one task's campaign over the trial log.
#[derive(Debug, Clone, Serialize)]
pub struct TaskReport {
    /// The task.
    pub task: String,
    /// Its campaign.
    pub campaign_id: String,
    /// Rates, causes and the paired sign tests of the campaign's graded trials.
    pub report: Report,
    /// Both observers' verdicts of the campaign's trials, side by side.
    pub verdicts: Agreement,
}

/// How often the physics and the static observer agree on the trials of
/// `campaign_id`: of each trial (method, object, placement) its latest graded run,
/// the one the report counts (a link-fault repeat supersedes the run it repeats).
pub fn agreement(trials: &[TrialRecord], campaign_id: &str) -> Agreement {
    let in_campaign = trials
        .iter()
        .filter(|t| t.trial.campaign_id.as_deref() == Some(campaign_id));
    let mut verdicts = Agreement::default();
    for t in latest_graded(in_campaign).values() {
        if let Some((physics, statics)) = t.trial.outcome.as_ref().and_then(verdict_grades) {
            verdicts.add(physics, statics);
        }
    }
    verdicts
}

impl CampaignSpec {
    /// One report per task, from the trial log's `trials`.
    pub fn reports(&self, trials: &[TrialRecord]) -> Vec<TaskReport> {
        self.tasks
            .iter()
            .map(|task| {
                let id = self.campaign_id(task);
                TaskReport {
                    task: task.clone(),
                    report: Report::from_trials(trials, crate::trial::Scope::campaign(&id)),
                    verdicts: agreement(trials, &id),
                    campaign_id: id,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::BUILTIN_CONFIG;
    use std::collections::HashMap;
    use std::path::Path;

    fn config() -> CellConfig {
        CellConfig::load(Path::new(BUILTIN_CONFIG)).unwrap()
    }

    fn object(name: &str, seed: u64) -> NovelObject {
        NovelObject {
            object: ObjectRef {
                name: name.into(),
                seed: Some(seed),
            },
            source: ObjectSource::Training,
            min_z_m: 0.0,
        }
    }

    fn spec() -> CampaignSpec {
        CampaignSpec {
            category: "mug".into(),
            tasks: vec!["top".into(), "handle".into()],
            objects: vec![object("mug-novel-1-0", 11), object("mug-novel-1-1", 12)],
            placements: 3,
            methods: vec!["best-single".into(), "gaussian-r".into(), "laplace".into()],
            campaign: None,
            seed: 1,
            paper: false,
            lab: LabErrors::NONE,
        }
    }

    #[test]
    fn plans_every_method_on_every_object_placement_and_task() {
        let spec = spec();
        let plan = spec.plan(&config(), &HashSet::new());
        assert_eq!(spec.total(), 2 * 2 * 3 * 3);
        assert_eq!(plan.len(), spec.total());
        let distinct: HashSet<_> = plan
            .iter()
            .map(|t| (&t.campaign_id, &t.object.name, t.placement.index, &t.method))
            .collect();
        assert_eq!(distinct.len(), plan.len(), "no trial planned twice");
        assert_eq!(spec.protocol(), Protocol::Cell);
    }

    #[test]
    fn every_pair_is_complete_and_differs_only_in_the_method() {
        let spec = CampaignSpec {
            lab: LabErrors {
                hand_eye_translation_m: 0.003,
                hand_eye_rotation_rad: 0.01,
                joint_noise_rad: 1e-4,
            },
            ..spec()
        };
        let plan = spec.plan(&config(), &HashSet::new());
        let mut pairs: HashMap<(String, String, u32), Vec<&PlannedTrial>> = HashMap::new();
        for t in &plan {
            pairs
                .entry((
                    t.campaign_id.clone(),
                    t.object.name.clone(),
                    t.placement.index,
                ))
                .or_default()
                .push(t);
        }
        assert_eq!(pairs.len(), 2 * 2 * 3);
        let mut seeds = HashSet::new();
        for trials in pairs.values() {
            let methods: Vec<&str> = trials.iter().map(|t| t.method.as_str()).collect();
            assert_eq!(methods, ["best-single", "gaussian-r", "laplace"]);
            let first = trials[0];
            assert!(first.lab.is_some());
            for t in trials {
                assert_eq!(t.placement, first.placement);
                assert_eq!(t.seed, first.seed);
                assert_eq!(t.lab, first.lab);
                assert_eq!(t.source, first.source);
            }
            seeds.insert((first.campaign_id.clone(), first.seed));
        }
        // Each object and placement has its own seed within a campaign.
        assert_eq!(seeds.len(), pairs.len());
        // The same object and placement stands in the same place for every task.
        let top = plan.iter().find(|t| t.task == "top").unwrap();
        let handle = plan
            .iter()
            .find(|t| t.task == "handle" && t.object == top.object)
            .unwrap();
        assert_eq!(top.placement, handle.placement);
    }

    #[test]
    fn ids_and_plans_are_stable() {
        let spec = spec();
        assert_eq!(spec.campaign_ids(), ["mug-top-seed1", "mug-handle-seed1"]);
        let a = spec.plan(&config(), &HashSet::new());
        let b = spec.plan(&config(), &HashSet::new());
        assert_eq!(a, b);
        // The seed formula of the logged campaigns (issue 16 moved it, unchanged).
        assert_eq!(spec.trial_seed(1, 2), 1_000_003 ^ (1 << 16 | 2));
        let mine = CampaignSpec {
            campaign: Some("lab-a".into()),
            ..spec.clone()
        };
        assert_eq!(mine.campaign_ids(), ["lab-a-top", "lab-a-handle"]);
        let one = CampaignSpec {
            tasks: vec!["side".into()],
            ..mine
        };
        assert_eq!(one.campaign_ids(), ["lab-a"]);
    }

    #[test]
    fn the_paper_protocol_has_its_own_ids() {
        let paper = CampaignSpec {
            paper: true,
            ..spec()
        };
        for id in paper.campaign_ids() {
            assert!(id.ends_with("-paper"), "{id}");
        }
        assert_eq!(paper.campaign_id("top"), "mug-top-seed1-paper");
        assert_eq!(paper.protocol(), Protocol::PaperRobot);
    }

    #[test]
    fn graded_trials_are_not_planned_again() {
        let spec = spec();
        let all = spec.plan(&config(), &HashSet::new());
        let graded: HashSet<TrialKey> = all[..5]
            .iter()
            .map(|t| TrialKey {
                campaign_id: t.campaign_id.clone(),
                object: t.object.name.clone(),
                placement: t.placement.index,
                method: t.method.clone(),
            })
            .collect();
        let rest = spec.plan(&config(), &graded);
        assert_eq!(rest, all[5..]);
    }

    #[test]
    fn a_trial_that_ended_on_a_link_fault_is_run_again() {
        use crate::trial::report::tests::record;
        let failed = |id, placement, kind: &str| {
            let mut t = record(
                id,
                "laplace",
                "m1",
                placement,
                Some(("failure", Some("execution"))),
            );
            t.trial.outcome = Some(serde_json::json!({ "execution_error": kind }));
            t
        };
        let dropped = failed(1, 0, "arm_dropped_to_monitor");
        let late = failed(2, 1, "arm_measurement_late");
        let refused = failed(3, 2, "unsafe_motion");
        assert!(ended_on_link_fault(&dropped) && ended_on_link_fault(&late));
        assert!(!ended_on_link_fault(&refused));
        // The demo finds a trial by the id the cell ran it under.
        let mut ran = vec![dropped.clone(), refused.clone()];
        for (t, cell_id) in ran.iter_mut().zip([70, 71]) {
            let outcome = t.trial.outcome.as_mut().unwrap();
            outcome["cell_trial_id"] = serde_json::json!(cell_id);
        }
        assert_eq!(link_fault_of(&ran, 70), Some("arm_dropped_to_monitor"));
        assert_eq!(link_fault_of(&ran, 71), None);
        assert_eq!(link_fault_of(&ran, 72), None);
        let key = |placement| TrialKey {
            campaign_id: "c1".into(),
            object: "m1".into(),
            placement,
            method: "laplace".into(),
        };
        let mut trials = vec![dropped, late, refused];
        assert_eq!(graded_trials(&trials), HashSet::from([key(2)]));
        // The repeat of placement 0 is graded: that trial is done.
        trials.push(record(4, "laplace", "m1", 0, Some(("success", None))));
        assert_eq!(graded_trials(&trials), HashSet::from([key(0), key(2)]));
    }

    #[test]
    fn verdicts_agree_over_the_latest_run_of_each_trial() {
        use crate::trial::report::tests::record;
        let run = |id, method, placement, physics: &str, statics: &str| {
            let cause = (physics == "failure").then_some("registration");
            let mut t = record(id, method, "m1", placement, Some((physics, cause)));
            t.trial.outcome = Some(serde_json::json!({ "verdicts": {
                "physics": { "grade": physics }, "static": { "grade": statics } } }));
            t
        };
        let trials = vec![
            // Placement 0 by laplace ran twice: the repeat (id 3) supersedes id 1.
            run(1, "laplace", 0, "failure", "success"),
            run(2, "best-single", 0, "success", "success"),
            run(3, "laplace", 0, "success", "success"),
            run(4, "laplace", 1, "partial", "failure"),
        ];
        let a = agreement(&trials, "c1");
        assert_eq!((a.total, a.agree), (3, 2));
        assert_eq!(a.counts[0][0], 2);
        assert_eq!(a.counts[1][2], 1);
        assert_eq!(a.counts[2][0], 0, "the superseded run is not counted");
        assert_eq!(agreement(&trials, "c2").total, 0);
    }

    #[test]
    fn objects_stand_on_the_table() {
        let mut spec = spec();
        spec.objects[0].min_z_m = -0.02;
        let plan = spec.plan(&config(), &HashSet::new());
        let sunk = plan
            .iter()
            .find(|t| t.object == spec.objects[0].object)
            .unwrap();
        let level = plan
            .iter()
            .find(|t| t.object == spec.objects[1].object)
            .unwrap();
        let z = |t: &PlannedTrial| t.placement.base_from_object.xyz[2];
        assert!((z(sunk) - z(level) - 0.02).abs() < 1e-12);
        let setup = sunk.setup(7, Category::Mug);
        assert_eq!(setup.campaign_id.as_deref(), Some("mug-top-seed1"));
        assert_eq!(
            (setup.noise_seed, setup.perception_seed),
            (sunk.seed, sunk.seed)
        );
    }
}
