//! `cell-log`: follows every trial through the cell, has it graded, records it in
//! the SQLite trial log and publishes the result.
//!
//! A trial begins with its request and ends when the executor reports `Done` or
//! `Stopped`. While it runs, the log watches the stage whose answer is due (camera,
//! then perceive, plan, execute): when that stage's process is dead or gone, the
//! trial ends as a failure with the cause "a stage died" (recorded as `other`, the
//! note naming the stage); after `trial_timeout_s` it ends as timed out.
//!
//! Grading: the simulated observer ([`crate::sim::observer`]) with the trial's
//! setup file (the simulated world), or the person at the terminal
//! ([`crate::trial::prompt_grade`]). The trial row and its grade are committed before
//! the result is published, so a trial reported to the operator is on disk.

use super::execute::error_kind;
use super::notify::{self, Watchdog};
use super::setup::TrialSetup;
use super::{span_ms, stop_requested, CellError, TICK};
use crate::config::CellConfig;
use crate::geometry::{Pose, PoseJson};
use crate::ipc::{
    monotonic_now_ns, wait_any, CameraFault, CameraStatus, CloudTopic, Domain, ExecutionStatus,
    FailureCause as IpcCause, FitStatus, Fits, Grade as IpcGrade, GraspPlan, MessageSubscriber,
    Phase, Protocol, Stage, StageStatus, Timings, TrialRequest, TrialResult, Wakeable,
};
use crate::robot::Robot;
use crate::sim::observer::{Attempt, Observation, Observer, ObserverMode};
use crate::trial::{
    FailureCause, Grade, GradeSource, Grading, NewTrial, ObjectRef, Placement, TrialLog,
    UtcTimestamp,
};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Who grades the trials.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ObserverKind {
    /// The simulated observer grading by the physics lift test (`sim` is an alias);
    /// the static verdict is recorded beside it.
    #[default]
    #[value(alias = "sim")]
    Physics,
    /// The simulated observer grading by static epsilon (the earlier grading); the
    /// physics verdict is recorded beside it.
    Static,
    /// A person at the terminal (s / p / f, cause, note).
    Terminal,
}

impl ObserverKind {
    /// The simulated observer's mode, `None` for a person.
    pub fn mode(self) -> Option<ObserverMode> {
        match self {
            ObserverKind::Physics => Some(ObserverMode::Physics),
            ObserverKind::Static => Some(ObserverMode::Static),
            ObserverKind::Terminal => None,
        }
    }

    /// The command-line value (`physics`, `static`, `terminal`).
    pub fn arg(self) -> &'static str {
        match self {
            ObserverKind::Physics => "physics",
            ObserverKind::Static => "static",
            ObserverKind::Terminal => "terminal",
        }
    }
}

/// Options of the log stage besides the configuration.
#[derive(Debug, Clone)]
pub struct LogOptions {
    /// The trial log file.
    pub log_path: PathBuf,
    /// The directory of trial setup files.
    pub run_dir: PathBuf,
    /// Who grades.
    pub observer: ObserverKind,
    /// Longest a trial may take from request to the executor's end (s).
    pub trial_timeout_s: f64,
    /// The category databases (model meshes for the trial pictures).
    pub db_dir: PathBuf,
}

/// One trial being followed.
#[derive(Debug)]
struct Trial {
    request: TrialRequest,
    began: Instant,
    started_at: UtcTimestamp,
    cloud_ns: u64,
    /// The snapshot, until it is written to its file ([`Logger::bookkeeping`]).
    snapshot: Option<crate::cloud::PointCloud>,
    snapshot_path: Option<PathBuf>,
    camera: Option<CameraStatus>,
    fits: Option<Fits>,
    plan: Option<GraspPlan>,
    first_command_ns: u64,
    closing_joints: Option<[f64; 7]>,
    end: Option<ExecutionStatus>,
}

impl Trial {
    /// A trial just requested.
    fn new(request: TrialRequest, started_at: UtcTimestamp) -> Trial {
        Trial {
            request,
            began: Instant::now(),
            started_at,
            cloud_ns: 0,
            snapshot: None,
            snapshot_path: None,
            camera: None,
            fits: None,
            plan: None,
            first_command_ns: 0,
            closing_joints: None,
            end: None,
        }
    }

    /// Writes the snapshot to its file, once.
    fn save_snapshot(&mut self, run_dir: &Path) {
        if let Some(cloud) = self.snapshot.take() {
            self.snapshot_path = save_snapshot(run_dir, self.request.trial_id, &cloud);
        }
    }

    /// The stage whose answer is due.
    fn waiting_for(&self) -> &'static str {
        if self.plan.is_some() {
            "execute"
        } else if self.fits.is_some() {
            "plan"
        } else if self.cloud_ns != 0 {
            "perceive"
        } else {
            "camera"
        }
    }

    fn timings(&self) -> Timings {
        let request_ns = self.request.stamp_ns;
        let fits_ns = self.fits.map_or(0, |f| f.stamp_ns);
        let plan_ns = self.plan.map_or(0, |p| p.stamp_ns);
        let end_ns = self.end.map_or(0, |e| e.stamp_ns);
        let s = |a, b| span_ms(a, b) * 1e-3;
        Timings {
            capture_s: s(request_ns, self.cloud_ns),
            perceive_s: s(self.cloud_ns, fits_ns),
            plan_s: s(fits_ns, plan_ns),
            execute_s: s(plan_ns, end_ns),
            snapshot_to_grasp_command_s: s(self.cloud_ns, self.first_command_ns),
            total_s: s(request_ns, monotonic_now_ns()),
        }
    }
}

/// How a trial ended, before grading.
#[derive(Debug, Clone, PartialEq)]
enum Ending {
    /// The executor reported the end (or the plan's failure).
    Reported,
    /// The stage whose answer was due died.
    StageDied(&'static str),
    /// No end within the timeout.
    TimedOut(&'static str),
    /// The camera reported that it has no snapshot.
    Camera(CameraFault),
}

/// The trial log's note on a camera fault.
fn camera_note(fault: CameraFault) -> String {
    let what = match fault {
        CameraFault::NoDevice => "no device (check USB, power and the udev rule)",
        CameraFault::Vanished => "the device vanished mid-run",
        CameraFault::Stalled => "frames stalled beyond the frame timeout",
        CameraFault::Failed | CameraFault::None => "the backend failed",
    };
    format!("camera: {what}")
}

/// The fits as JSON for the trial log.
fn fits_json(fits: Option<&Fits>) -> serde_json::Value {
    let Some(fits) = fits else {
        return json!([]);
    };
    let list = fits.fits().unwrap_or(&[]);
    serde_json::Value::Array(
        list.iter()
            .map(|f| {
                let pose = f
                    .base_from_model
                    .to_pose("fit")
                    .map(|p| PoseJson::from(&p))
                    .ok();
                json!({
                    "model_id": f.model_id,
                    "status": f.status().map(|s| format!("{s:?}")).unwrap_or_default(),
                    "base_from_model": pose,
                    "eps_m2": f.eps,
                    "sigma_m2": f.sigma,
                })
            })
            .collect(),
    )
}

/// The pose of the best fit (lowest eps among usable fits).
fn best_fit(fits: Option<&Fits>) -> Option<Pose> {
    fits?
        .fits()
        .ok()?
        .iter()
        .filter(|f| f.status().is_ok_and(|s| s != FitStatus::Failed) && f.eps.is_finite())
        .min_by(|a, b| a.eps.total_cmp(&b.eps))
        .and_then(|f| f.base_from_model.to_pose("fit").ok())
}

/// How long without a result, and with no trial in flight, before the slow
/// bookkeeping runs ([`Logger::may_do_bookkeeping`]).
const QUIET: Duration = Duration::from_secs(1);

/// [`Logger::may_do_bookkeeping`] for the trials followed, `since_result` after
/// the last result.
fn bookkeeping_may_run(trials: &BTreeMap<u64, Trial>, since_result: Duration) -> bool {
    let in_flight = trials.values().any(|t| t.end.is_none());
    !in_flight && since_result > QUIET
}

/// The log stage's state: the trials being followed and what grades them.
struct Logger {
    options: LogOptions,
    log: TrialLog,
    observer: Option<Observer>,
    robot: Robot,
    followed: Followed,
    /// The grasp simulator's hand (the pictures close its fingers).
    hand: crate::robot::hand::HandModel,
    /// Category databases loaded for the pictures (`None`: could not be loaded).
    dbs: BTreeMap<String, Option<crate::category::CategoryDb>>,
    /// Recorded trials whose picture is still to be drawn.
    pictures_due: Vec<crate::trial::TrialId>,
    /// When the last result was answered.
    last_result: Instant,
    /// Graded trials the file refused (a full disk), oldest first: written, and
    /// only then answered, as soon as it takes them.
    unrecorded: Vec<Concluded>,
    config: CellConfig,
}

/// The trials being followed, and their journal ([`journal_dir`]): followed and not
/// yet recorded.
struct Followed {
    trials: BTreeMap<u64, Trial>,
    journal: PathBuf,
}

impl Followed {
    /// Starts following every trial requested since the last call.
    fn admit(&mut self, requests: &MessageSubscriber<TrialRequest>) -> Result<(), CellError> {
        while let Some(request) = requests.try_receive()? {
            if let Err(e) = request.check() {
                tracing::warn!("ignoring a malformed trial request: {e}");
                continue;
            }
            let trial = Trial::new(request, UtcTimestamp::now());
            journal_trial(&self.journal, &trial);
            self.trials.insert(request.trial_id, trial);
        }
        Ok(())
    }

    /// The followed trial a stage's message belongs to. A message can be read before
    /// the request that caused it (they travel on different services): on a miss the
    /// requests are read again, and only then is the message someone else's.
    fn trial(
        &mut self,
        requests: &MessageSubscriber<TrialRequest>,
        trial_id: u64,
    ) -> Result<Option<&mut Trial>, CellError> {
        if !self.trials.contains_key(&trial_id) {
            self.admit(requests)?;
        }
        Ok(self.trials.get_mut(&trial_id))
    }
}

/// A finished, graded trial and the result the operator gets once it is recorded.
struct Concluded {
    row: NewTrial,
    grading: Grading,
    source: GradeSource,
    graded_at: UtcTimestamp,
    result: TrialResult,
}

impl Logger {
    fn attempt(&self, trial: &Trial) -> Result<Attempt, CellError> {
        let Some(plan) = &trial.plan else {
            // The executor stopped before the log saw a plan (it refused one the
            // log missed, e.g. sent before the request reached the log).
            return match &trial.end {
                Some(end) => Ok(Attempt::Stopped {
                    kind: error_kind(end.error_code).to_string(),
                }),
                None => Err(CellError::Invalid("no plan".into())),
            };
        };
        let failure = plan.failure().unwrap_or(IpcCause::Other);
        if failure != IpcCause::None {
            let detail = match failure {
                IpcCause::RegistrationFailure => "no model registered to the object",
                IpcCause::Reachability => "no reachable grasp",
                _ => "the planner failed",
            };
            return Ok(Attempt::NotPlanned {
                cause: failure.into(),
                detail: detail.to_string(),
            });
        }
        let Some(end) = &trial.end else {
            return Err(CellError::Invalid("no execution end".into()));
        };
        let stopped_after_closing = match end.phase() {
            Ok(Phase::Done) => None,
            _ => {
                let kind = error_kind(end.error_code);
                // The hand closed and felt too little, or the object did not stay
                // in it: the executor stopped because of the grasp, not of the
                // devices. The trial failed; the observer judges that grasp for why.
                let grasp_failed = matches!(kind, "no_contact" | "grasp_lost");
                if !(grasp_failed && trial.closing_joints.is_some()) {
                    return Ok(Attempt::Stopped {
                        kind: kind.to_string(),
                    });
                }
                Some(kind.to_string())
            }
        };
        let base_from_palm = match trial.closing_joints {
            Some(q) => self.robot.arm().palm(&q),
            None => plan.base_from_palm.to_pose("plan palm")?,
        };
        Ok(Attempt::Executed {
            base_from_palm,
            spread_rad: plan.spread_rad,
            preshape_rad: crate::robot::PreshapeRad(plan.preshape_rad),
            best_fit: best_fit(trial.fits.as_ref()),
            stopped_after_closing,
        })
    }

    fn observe(
        &self,
        trial: &Trial,
        ending: &Ending,
        setup: Option<&TrialSetup>,
    ) -> Result<(Grading, GradeSource, Option<Observation>), CellError> {
        type Graded = (Grading, GradeSource, Option<Observation>);
        let died = |note: String| -> Result<Graded, CellError> {
            Ok((
                Grading::new(Grade::Failure, Some(FailureCause::Other), Some(note))?,
                GradeSource::Simulated,
                None,
            ))
        };
        match ending {
            Ending::StageDied(stage) => {
                return died(format!("stage {stage} died during the trial"))
            }
            Ending::TimedOut(stage) => {
                return died(format!(
                    "no answer from stage {stage} within {} s",
                    self.options.trial_timeout_s
                ))
            }
            Ending::Camera(fault) => return died(camera_note(*fault)),
            Ending::Reported => {}
        }
        let mut attempt = self.attempt(trial)?;
        match self.options.observer {
            ObserverKind::Terminal => {
                eprintln!("trial {}: {:?}; grade it", trial.request.trial_id, attempt);
                let grading =
                    crate::trial::prompt_grade(std::io::stdin().lock(), std::io::stderr().lock())?;
                Ok((grading, GradeSource::Observer, None))
            }
            ObserverKind::Physics | ObserverKind::Static => {
                let (Some(observer), Some(setup)) = (&self.observer, setup) else {
                    return died(
                        "no trial setup: the simulated observer cannot grade it".to_string(),
                    );
                };
                let base_from_object = setup.base_from_object().map_err(|e| CellError::Setup {
                    path: TrialSetup::path(&self.options.run_dir, setup.trial_id),
                    problem: e.to_string(),
                })?;
                // The lab's execution error: the arm stands at the closing joints
                // plus the trial's joint errors.
                if let (Attempt::Executed { base_from_palm, .. }, Some(lab), Some(q)) =
                    (&mut attempt, setup.lab, trial.closing_joints)
                {
                    *base_from_palm = self.robot.arm().palm(&lab.executed_joints(&q));
                }
                let seen = observer
                    .grade(
                        &setup.object.name,
                        &setup.mesh()?,
                        &base_from_object,
                        &attempt,
                    )
                    .map_err(|e| CellError::Invalid(e.to_string()))?;
                // The lab's errors go into the trial's record with its grade.
                let note = match &setup.lab {
                    Some(lab) => format!("{} [lab: {}]", seen.note, lab.text()),
                    None => seen.note.clone(),
                };
                let grading = Grading::new(seen.grade, seen.cause, Some(note))?;
                Ok((grading, GradeSource::Simulated, Some(seen)))
            }
        }
    }

    /// Whether the slow bookkeeping (snapshot files, pictures) may run now: never
    /// while a followed trial waits for its camera, perception or plan (it would
    /// take a core from them) or executes (the arm's real-time link runs beside
    /// it), and not just after a result, when the next request may be on its way;
    /// only after [`QUIET`] without a result and with no trial in flight.
    fn may_do_bookkeeping(&self) -> bool {
        bookkeeping_may_run(&self.followed.trials, self.last_result.elapsed())
    }

    /// Writes the snapshots taken and draws the pictures of the trials recorded.
    fn bookkeeping(&mut self) {
        let run_dir = self.options.run_dir.clone();
        for trial in self.followed.trials.values_mut() {
            trial.save_snapshot(&run_dir);
        }
        self.draw_pictures();
    }

    /// Draws the picture of every recorded trial that has none yet, writes it to
    /// `<run dir>/pictures/<id>.png` and names it in the trial's row. A picture
    /// that cannot be drawn is logged; the trial stays recorded.
    fn draw_pictures(&mut self) {
        for id in std::mem::take(&mut self.pictures_due) {
            if let Err(e) = self.draw_picture(id) {
                tracing::error!(log_id = id, "trial picture not written: {e}");
            }
        }
    }

    fn draw_picture(&mut self, id: crate::trial::TrialId) -> Result<(), CellError> {
        let record = self.log.trial(id)?;
        let category = record.trial.category.clone();
        let db_dir = self.options.db_dir.clone();
        let db = self
            .dbs
            .entry(category.clone())
            .or_insert_with(|| {
                super::load_category(&db_dir, &category)
                    .map_err(|e| tracing::warn!("trial pictures without models: {e}"))
                    .ok()
            })
            .as_ref();
        let inputs = crate::trial::scene::SceneInputs {
            config: &self.config,
            robot: &self.robot,
            hand: &self.hand,
            db,
            base_from_camera: self.config.base_from_camera(),
        };
        let scene = crate::trial::scene::trial_scene(&record, &inputs);
        let path = picture_path(&self.options.run_dir, id);
        crate::trial::picture::write_png(&scene, &path)?;
        self.log.set_picture(id, &path)?;
        Ok(())
    }

    /// Grades a finished trial: its row, grade and result, to be recorded.
    fn finish(&mut self, mut trial: Trial, ending: Ending) -> Result<Concluded, CellError> {
        let trial_id = trial.request.trial_id;
        // Its row names the snapshot's file.
        trial.save_snapshot(&self.options.run_dir);
        let setup = TrialSetup::read(&self.options.run_dir, trial_id).unwrap_or_else(|e| {
            tracing::error!(trial_id, "{e}");
            None
        });
        // A trial that cannot be graded is still recorded, as failed, saying why.
        let (grading, source, seen) = match self.observe(&trial, &ending, setup.as_ref()) {
            Ok(graded) => graded,
            Err(e) => (
                Grading::new(
                    Grade::Failure,
                    Some(FailureCause::Other),
                    Some(format!("not graded: {e}")),
                )?,
                GradeSource::Simulated,
                None,
            ),
        };
        let timings = trial.timings();
        let (object, placement, campaign_id, seeds) = match &setup {
            Some(s) => (
                s.object.clone(),
                s.placement,
                s.campaign_id.clone(),
                BTreeMap::from([
                    ("trial".to_string(), trial_id),
                    ("noise".to_string(), s.noise_seed),
                    ("perception".to_string(), s.perception_seed),
                ]),
            ),
            None => (
                ObjectRef {
                    name: "unknown".into(),
                    seed: None,
                },
                Placement {
                    index: 0,
                    base_from_object: PoseJson::from(&Pose::identity()),
                },
                None,
                BTreeMap::from([("trial".to_string(), trial_id)]),
            ),
        };
        let raw_frame = super::camera::raw_frame_dir(&self.options.run_dir, trial_id);
        let gravity = trial
            .camera
            .filter(|c| c.gravity_angle_rad.is_finite())
            .map(|c| {
                json!({
                    "camera_m_s2": c.gravity_camera_m_s2,
                    "angle_deg": c.gravity_angle_rad.to_degrees(),
                    "warning": c.gravity_warning != 0,
                })
            });
        let planned = trial
            .plan
            .filter(|p| matches!(p.failure(), Ok(IpcCause::None)))
            .and_then(|p| {
                p.base_from_palm
                    .to_pose("plan")
                    .ok()
                    .map(|pose| (PoseJson::from(&pose), p.joints_rad.to_vec()))
            });
        let new = NewTrial {
            started_at: trial.started_at,
            category: trial.request.category()?.to_string(),
            task: trial.request.task()?.to_string(),
            method: trial.request.method()?.to_string(),
            object,
            placement,
            campaign_id,
            snapshot_path: trial.snapshot_path.clone(),
            fits: fits_json(trial.fits.as_ref()),
            planned_pose: planned.as_ref().map(|p| p.0),
            planned_joints: planned.map(|p| p.1),
            outcome: Some(json!({
                "cell_trial_id": trial_id,
                "ending": format!("{ending:?}"),
                "execution_phase": trial.end.and_then(|e| e.phase().ok()).map(|p| format!("{p:?}")),
                "execution_error": trial.end.map(|e| error_kind(e.error_code)),
                "epsilon": seen.as_ref().map(|s| s.epsilon),
                "contacts": seen.as_ref().map(|s| s.contacts),
                "registration_error_m": seen.as_ref().and_then(|s| s.registration_error_m),
                "closing_joints_rad": trial.closing_joints,
                "spread_rad": trial.plan.map(|p| p.spread_rad),
                "observer": seen.as_ref().map(|s| s.mode),
                "verdicts": seen.as_ref().map(|s| json!({
                    "physics": s.physics,
                    "static": s.static_epsilon,
                })),
                "lift": seen.as_ref().and_then(|s| s.lift.as_ref()),
                "registration": seen.as_ref().and_then(|s| s.registration),
                "timings_s": timings,
                "gravity": gravity,
                "raw_frame": raw_frame.join(crate::hw::kinect::fakenect::INDEX_FILE).is_file().then_some(raw_frame),
            })),
            seeds,
        };
        let cause = match ending {
            Ending::StageDied(_) => IpcCause::StageDied,
            Ending::TimedOut(_) => IpcCause::Timeout,
            Ending::Camera(_) => IpcCause::Camera,
            Ending::Reported => grading.cause.into(),
        };
        let result = TrialResult::new(
            trial_id,
            monotonic_now_ns(),
            grading.grade.into(),
            cause,
            timings,
        );
        Ok(Concluded {
            row: new,
            grading,
            source,
            graded_at: UtcTimestamp::now(),
            result,
        })
    }

    /// Grades a finished trial and queues it to be written; false (logged, and
    /// taken out of the journal) when it cannot be recorded at all.
    fn conclude(&mut self, trial: Trial, ending: Ending) -> bool {
        let id = trial.request.trial_id;
        match self.finish(trial, ending) {
            Ok(concluded) => {
                self.unrecorded.push(concluded);
                true
            }
            Err(e) => {
                tracing::error!(trial_id = id, "trial not recorded: {e}");
                unjournal(&self.followed.journal, id);
                false
            }
        }
    }

    /// Writes the oldest waiting trial with its grade (one transaction); on success
    /// returns the result to answer.
    fn record_oldest(&mut self) -> Option<Result<TrialResult, CellError>> {
        let c = self.unrecorded.first()?;
        let written = self
            .log
            .record_graded_trial(&c.row, &c.grading, c.source, c.graded_at);
        Some(match written {
            Ok(id) => {
                let c = self.unrecorded.remove(0);
                unjournal(&self.followed.journal, c.result.trial_id);
                self.pictures_due.push(id);
                tracing::info!(trial_id = c.result.trial_id, log_id = id, grading = %c.grading, "trial graded");
                Ok(c.result)
            }
            Err(e) => Err(e.into()),
        })
    }
}

/// Where the log stage keeps one small file per trial it follows, from the request
/// until the trial's row is written: a log stage that restarts (after a crash or
/// SIGKILL) records each trial its predecessor was following as failed, "stage log
/// died during the trial", so no requested trial is missing from the log.
pub fn journal_dir(log_path: &Path) -> PathBuf {
    let mut name = log_path.as_os_str().to_owned();
    name.push(".inflight");
    PathBuf::from(name)
}

/// A followed trial's request, as journaled.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
struct Journaled {
    trial_id: u64,
    stamp_ns: u64,
    category: String,
    task: String,
    method: String,
    protocol: u32,
    started_at: String,
}

fn journal_file(dir: &Path, trial_id: u64) -> PathBuf {
    dir.join(format!("{trial_id}.json"))
}

/// Journals a trial now followed; a trial that cannot be journaled (a full disk)
/// is still followed.
fn journal_trial(dir: &Path, trial: &Trial) {
    let r = &trial.request;
    let (Ok(category), Ok(task), Ok(method)) = (r.category(), r.task(), r.method()) else {
        return;
    };
    let entry = Journaled {
        trial_id: r.trial_id,
        stamp_ns: r.stamp_ns,
        category: category.into(),
        task: task.into(),
        method: method.into(),
        protocol: r.protocol().map_or(0, |p| p.code()),
        started_at: trial.started_at.to_string(),
    };
    let written = serde_json::to_vec(&entry)
        .map_err(std::io::Error::other)
        .and_then(|bytes| {
            std::fs::create_dir_all(dir)?;
            crate::fsio::write_atomically(&journal_file(dir, r.trial_id), &bytes)
        });
    if let Err(e) = written {
        tracing::warn!(
            trial_id = r.trial_id,
            "trial not journaled ({}): {e}",
            dir.display()
        );
    }
}

fn unjournal(dir: &Path, trial_id: u64) {
    let _ = std::fs::remove_file(journal_file(dir, trial_id));
}

/// The trials a previous log stage was following when it died.
fn journaled(dir: &Path) -> Vec<Trial> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut trials: Vec<Trial> = Vec::new();
    for path in entries.flatten().map(|e| e.path()) {
        let read = std::fs::read(&path)
            .map_err(|e| e.to_string())
            .and_then(|b| serde_json::from_slice::<Journaled>(&b).map_err(|e| e.to_string()))
            .and_then(|j| {
                let protocol = Protocol::from_code(j.protocol).map_err(|e| e.to_string())?;
                let request =
                    TrialRequest::new(j.trial_id, j.stamp_ns, &j.category, &j.task, &j.method)
                        .map_err(|e| e.to_string())?
                        .with_protocol(protocol);
                let started_at = j
                    .started_at
                    .parse()
                    .map_err(|e: crate::trial::TrialError| e.to_string())?;
                Ok(Trial::new(request, started_at))
            });
        match read {
            Ok(trial) => trials.push(trial),
            Err(e) => {
                tracing::error!("journal entry {} unreadable, removed: {e}", path.display());
                let _ = std::fs::remove_file(&path);
            }
        }
    }
    trials.sort_by_key(|t| t.request.trial_id);
    trials
}

/// Where the picture of the trial logged as `log_id` is kept.
pub fn picture_path(run_dir: &Path, log_id: crate::trial::TrialId) -> PathBuf {
    run_dir.join("pictures").join(format!("{log_id}.png"))
}

/// The physics and static grades in a trial's logged outcome (as this stage writes
/// them under `verdicts`), when both are there.
pub fn verdict_grades(outcome: &serde_json::Value) -> Option<(Grade, Grade)> {
    let grade = |which: &str| {
        serde_json::from_value::<Grade>(outcome.get("verdicts")?.get(which)?.get("grade")?.clone())
            .ok()
    };
    Some((grade("physics")?, grade("static")?))
}

/// Where the snapshot of trial `trial_id` is kept: a binary PCD in the camera's
/// optical frame, which the camera's `replay` backend reads back.
pub fn snapshot_path(run_dir: &Path, trial_id: u64) -> PathBuf {
    run_dir.join("snapshots").join(format!("{trial_id}.pcd"))
}

/// Writes trial `trial_id`'s snapshot (atomically); its path, or `None` (logged)
/// when it could not be written — the trial is still recorded.
fn save_snapshot(
    run_dir: &Path,
    trial_id: u64,
    cloud: &crate::cloud::PointCloud,
) -> Option<PathBuf> {
    let path = snapshot_path(run_dir, trial_id);
    let written = path
        .parent()
        .map_or(Ok(()), std::fs::create_dir_all)
        .map_err(|e| e.to_string())
        .and_then(|()| {
            crate::cloud::io::write_cloud(&path, cloud, crate::cloud::io::CloudEncoding::Binary)
                .map_err(|e| e.to_string())
        });
    match written {
        Ok(()) => Some(path),
        Err(e) => {
            tracing::error!(trial_id, "snapshot not saved: {e}");
            None
        }
    }
}

/// Runs the log stage until SIGTERM/SIGINT.
pub fn run(config: &CellConfig, domain: &Domain, options: LogOptions) -> Result<(), CellError> {
    if !(options.trial_timeout_s.is_finite() && options.trial_timeout_s > 0.0) {
        return Err(CellError::Invalid(format!(
            "--trial-timeout-s {}: must be a finite number > 0",
            options.trial_timeout_s
        )));
    }
    if let Some(dir) = options
        .log_path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
    {
        crate::fsio::create_dir_all(dir)?;
    }
    let log = TrialLog::open(&options.log_path)?;
    let observer = match options.observer.mode() {
        Some(mode) => Some(
            Observer::new(config)
                .map_err(|e| CellError::Invalid(e.to_string()))?
                .with_mode(mode),
        ),
        None => None,
    };
    let journal = journal_dir(&options.log_path);
    let mut logger = Logger {
        robot: Robot::load(config)?,
        hand: crate::robot::hand::HandModel::load(config)?,
        dbs: BTreeMap::new(),
        pictures_due: Vec::new(),
        last_result: Instant::now(),
        unrecorded: Vec::new(),
        followed: Followed {
            trials: BTreeMap::new(),
            journal,
        },
        config: config.clone(),
        options,
        log,
        observer,
    };
    // The trials a killed predecessor was following: recorded as failed.
    for trial in journaled(&logger.followed.journal) {
        let id = trial.request.trial_id;
        tracing::warn!(
            trial_id = id,
            "recording a trial the previous log stage was following"
        );
        logger.conclude(trial, Ending::StageDied("log"));
    }
    let stage = Stage::start(domain, "log")?;
    let results = stage.publisher::<TrialResult>()?;
    let clouds = stage.cloud_subscriber(CloudTopic::Camera)?;
    let fits = stage.subscriber::<Fits>()?;
    let plans = stage.subscriber::<GraspPlan>()?;
    let statuses = stage.subscriber::<ExecutionStatus>()?;
    let requests = stage.subscriber::<TrialRequest>()?;
    let camera_statuses = stage.subscriber::<CameraStatus>()?;
    notify::ready("log following trials");
    let mut watchdog = Watchdog::from_env();
    let timeout = Duration::from_secs_f64(logger.options.trial_timeout_s);
    let mut write_failing = false;
    while !stop_requested() {
        watchdog.ping();
        let inputs: [&dyn Wakeable; 6] = [
            &requests,
            &clouds,
            &fits,
            &plans,
            &statuses,
            &camera_statuses,
        ];
        match wait_any(&inputs, TICK) {
            Ok(_) => {}
            Err(_) if stop_requested() => break,
            Err(e) => return Err(e.into()),
        }
        logger.followed.admit(&requests)?;
        while let Some(cloud) = clouds.try_receive()? {
            let h = *cloud.header();
            if let Some(t) = logger.followed.trial(&requests, h.trial_id)? {
                t.cloud_ns = h.stamp_ns;
                t.snapshot = Some(cloud.to_cloud());
            }
        }
        while let Some(c) = camera_statuses.try_receive()? {
            if let Some(t) = logger.followed.trial(&requests, c.trial_id)? {
                t.camera = Some(c);
            }
        }
        while let Some(f) = fits.try_receive()? {
            if let Some(t) = logger.followed.trial(&requests, f.trial_id)? {
                t.fits = Some(f);
            }
        }
        while let Some(p) = plans.try_receive()? {
            if let Err(e) = p.check() {
                tracing::warn!(trial_id = p.trial_id, "ignoring a malformed plan: {e}");
                continue;
            }
            if let Some(t) = logger.followed.trial(&requests, p.trial_id)? {
                t.plan = Some(p);
            }
        }
        while let Some(s) = statuses.try_receive()? {
            let Some(t) = logger.followed.trial(&requests, s.trial_id)? else {
                continue;
            };
            match s.phase() {
                Ok(Phase::MovingToPregrasp) if t.first_command_ns == 0 => {
                    t.first_command_ns = s.stamp_ns
                }
                Ok(Phase::Closing) => t.closing_joints = Some(s.joints.arm_rad),
                Ok(Phase::Done | Phase::Stopped) => t.end = Some(s),
                _ => {}
            }
        }
        let mut finished = Vec::new();
        for (id, trial) in &logger.followed.trials {
            if trial.end.is_some() {
                finished.push((*id, Ending::Reported));
                continue;
            }
            if let Some(fault) = trial
                .camera
                .and_then(|c| c.fault().ok())
                .filter(|f| *f != CameraFault::None)
            {
                finished.push((*id, Ending::Camera(fault)));
                continue;
            }
            let due = trial.waiting_for();
            if matches!(
                stage.stage_status(due)?,
                StageStatus::Dead | StageStatus::Missing
            ) {
                finished.push((*id, Ending::StageDied(due)));
            } else if trial.began.elapsed() > timeout {
                finished.push((*id, Ending::TimedOut(due)));
            }
        }
        for (id, ending) in finished {
            let Some(trial) = logger.followed.trials.remove(&id) else {
                continue;
            };
            if !logger.conclude(trial, ending) {
                results.send(&TrialResult::new(
                    id,
                    monotonic_now_ns(),
                    IpcGrade::Failure,
                    IpcCause::Other,
                    Timings::default(),
                ))?;
            }
        }
        // Oldest first; what the file refuses (a full disk) waits for the next tick,
        // unanswered, so that no answered trial is missing from the log.
        while let Some(written) = logger.record_oldest() {
            match written {
                Ok(result) => {
                    results.send(&result)?;
                    logger.last_result = Instant::now();
                    write_failing = false;
                }
                Err(e) => {
                    if !write_failing {
                        tracing::error!(
                            waiting = logger.unrecorded.len(),
                            "trials wait to be recorded: {e}"
                        );
                    }
                    write_failing = true;
                    break;
                }
            }
        }
        if logger.may_do_bookkeeping() {
            logger.bookkeeping();
        }
    }
    logger.bookkeeping();
    notify::stopping();
    Ok(())
}

/// Where the log stage keeps trials by default, under the run directory.
pub fn default_log_path(run_dir: &Path) -> PathBuf {
    run_dir.join("trials.sqlite")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A killed log stage's successor finds the trials it was following.
    #[test]
    fn followed_trials_are_journaled_until_recorded() {
        let dir = crate::fsio::TempDir::new("journal").unwrap();
        let journal = journal_dir(&dir.join("trials.sqlite"));
        assert!(journal.ends_with("trials.sqlite.inflight"));
        let request = TrialRequest::new(41, 7, "mug", "handle", "laplace")
            .unwrap()
            .with_protocol(Protocol::PaperRobot);
        let started: UtcTimestamp = "2026-11-27T03:00:00Z".parse().unwrap();
        journal_trial(&journal, &Trial::new(request, started));
        std::fs::write(journal.join("garbage.json"), b"{").unwrap();
        let found = journaled(&journal);
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].request, request);
        assert_eq!(found[0].started_at, started);
        assert!(
            !journal.join("garbage.json").exists(),
            "unreadable entry removed"
        );
        unjournal(&journal, 41);
        assert!(journaled(&journal).is_empty());
    }

    /// A stage's answer read before its request (two services, no order between
    /// them) still finds its trial: the camera's "vanished" once went unseen and the
    /// trial timed out instead of failing on the camera.
    #[test]
    fn an_answer_read_before_its_request_finds_its_trial() {
        let dir = crate::fsio::TempDir::new("followed").unwrap();
        let domain = crate::ipc::Domain::temporary("log-followed").unwrap();
        let operator = Stage::start(&domain, "operator").unwrap();
        let log = Stage::start(&domain, "log").unwrap();
        let requests = log.subscriber::<TrialRequest>().unwrap();
        let publisher = operator.publisher::<TrialRequest>().unwrap();
        let mut followed = Followed {
            trials: BTreeMap::new(),
            journal: journal_dir(&dir.join("trials.sqlite")),
        };
        followed.admit(&requests).unwrap();
        let request = TrialRequest::new(2, 0, "mug", "top", "laplace").unwrap();
        publisher.send(&request).unwrap();
        // The camera's status for trial 2 is read now, before the next admit.
        let trial = followed.trial(&requests, 2).unwrap().expect("trial 2");
        assert_eq!(trial.request, request);
        assert!(followed.trial(&requests, 3).unwrap().is_none());
        assert_eq!(journaled(&followed.journal).len(), 1);
    }

    /// Snapshot files and pictures wait while a trial is between its request and
    /// its end, and just after a result (the next request is on its way); they
    /// are written once the cell is quiet.
    #[test]
    fn bookkeeping_waits_for_perception_and_planning() {
        let request = TrialRequest::new(5, 0, "mug", "side", "laplace-sim").unwrap();
        let started: UtcTimestamp = "2026-12-06T20:00:00Z".parse().unwrap();
        let mut trials = BTreeMap::new();
        let just = Duration::from_millis(10);
        let quiet = QUIET + Duration::from_millis(1);
        assert!(!bookkeeping_may_run(&trials, just), "just after a result");
        assert!(bookkeeping_may_run(&trials, quiet), "a quiet cell");
        trials.insert(5, Trial::new(request, started));
        assert!(!bookkeeping_may_run(&trials, quiet), "perceiving");
        trials.get_mut(&5).unwrap().plan = Some(GraspPlan::default());
        assert!(!bookkeeping_may_run(&trials, quiet), "executing");
        trials.insert(6, Trial::new(request, started));
        assert!(
            !bookkeeping_may_run(&trials, quiet),
            "one executes, one plans"
        );
        trials.remove(&6);
        trials.get_mut(&5).unwrap().end = Some(ExecutionStatus::default());
        assert!(
            !bookkeeping_may_run(&trials, just),
            "ended, next on its way"
        );
        assert!(bookkeeping_may_run(&trials, quiet));
    }

    #[test]
    fn no_fits_have_no_best_fit() {
        assert!(best_fit(None).is_none());
    }

    #[test]
    fn both_verdicts_are_read_back_from_the_outcome() {
        let outcome = json!({"verdicts": {
            "physics": {"grade": "success", "cause": null},
            "static": {"grade": "failure", "cause": "shape_dissimilarity"},
        }});
        assert_eq!(
            verdict_grades(&outcome),
            Some((Grade::Success, Grade::Failure))
        );
        assert_eq!(verdict_grades(&json!({"epsilon": 0.1})), None);
    }
}
