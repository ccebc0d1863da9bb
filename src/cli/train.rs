//! `cell train`: build a category database from a teach-in file, and
//! `cell train suggest-grasps`: propose a teach-in file for procedural models.

use crate::category::calibrate::{calibrate, LooSource, WeightCalibration};
use crate::category::suggest::{suggest_teach_file, SuggestModel, SuggestOptions};
use crate::category::teach::TeachFile;
use crate::category::train::{train, write_database, TrainOptions};
use crate::category::CategoryDb;
use crate::config::CellConfig;
use crate::eval::experiment::Registrar;
use crate::eval::registration::CategoryRegistrar;
use crate::eval::view::{partial_view, PlacementRegion};
use crate::mesh::procedural::{Category, Params};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
use crate::sim::camera::DepthCamera;
use crate::sim::scene::TableBox;
use anyhow::Context;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Options of `cell train`.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct TrainArgs {
    /// Category: mug, bottle, hammer or knife.
    #[arg(long, required = true)]
    pub category: Option<Category>,
    /// Directory of the model meshes the teach file names.
    #[arg(long, required = true)]
    pub models: Option<PathBuf>,
    /// Teach-in file (TOML): per model, task-labelled example grasps.
    #[arg(long, required = true)]
    pub grasps: Option<PathBuf>,
    /// Output directory of the database (category.json, models/).
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// Points of each model's cloud.
    #[arg(long, default_value_t = 2000)]
    pub cloud_points: usize,
    /// Seed of the cloud sampling.
    #[arg(long, default_value_t = 1)]
    pub cloud_seed: u64,
    /// Write the sampled clouds under clouds/ (else they are sampled when loaded).
    #[arg(long)]
    pub write_clouds: bool,
    /// Seed of the weight calibration's leave-one-out views (placement, camera noise,
    /// registration).
    #[arg(long, default_value_t = 1)]
    pub calibration_seed: u64,
    /// Do not calibrate the weights (the database then has none, and planners use
    /// the fixed defaults).
    #[arg(long)]
    pub no_calibrate: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Developer tools.
    #[command(subcommand)]
    pub command: Option<TrainCommand>,
}

/// `cell train` helpers.
#[derive(Debug, Subcommand)]
pub enum TrainCommand {
    /// Propose a teach-in file for procedural models (reads DIR/params.json of
    /// `cell objects generate`); the output is meant to be reviewed and edited.
    #[command(hide = true)]
    SuggestGrasps(SuggestArgs),
}

/// Options of `cell train suggest-grasps`.
#[derive(Debug, Args)]
pub struct SuggestArgs {
    /// Directory written by `cell objects generate` (meshes and params.json).
    #[arg(long)]
    pub models: PathBuf,
    /// Output teach file (TOML).
    #[arg(long)]
    pub out: PathBuf,
    /// Height of the table top in the models' frame (m); none = no table.
    #[arg(long, allow_hyphen_values = true)]
    pub table_z: Option<f64>,
    /// Seed of the random search.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// The part of `params.json` (from `cell objects generate`) read here.
#[derive(Debug, Deserialize)]
struct Listing {
    category: Category,
    seed: u64,
    count: usize,
    instances: Vec<ListedInstance>,
}

#[derive(Debug, Deserialize)]
struct ListedInstance {
    file: PathBuf,
    params: Params,
}

/// The report of `cell train`.
#[derive(Debug, Serialize)]
struct TrainReport {
    category: Category,
    out: PathBuf,
    models: usize,
    grasps: Vec<GraspLine>,
    /// The calibrated weights, when calibrated.
    weights: Option<WeightCalibration>,
}

#[derive(Debug, Serialize)]
struct GraspLine {
    name: String,
    task: String,
    q: f64,
    delta: [f64; 6],
}

fn progress_bar(message: &str) -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(message.to_string());
    bar
}

/// Runs `cell train` (or its subcommand).
pub fn run(config: &Path, args: TrainArgs) -> anyhow::Result<ExitCode> {
    let cell = CellConfig::load(config)?;
    let hand = HandModel::load(&cell)?;
    if let Some(TrainCommand::SuggestGrasps(s)) = args.command {
        return suggest(&hand, s);
    }
    let (Some(category), Some(models), Some(grasps), Some(out)) =
        (args.category, args.models, args.grasps, args.out)
    else {
        anyhow::bail!("--category, --models, --grasps and --out are required");
    };
    let teach = TeachFile::load(&grasps)?;
    let options = TrainOptions {
        cloud_points: args.cloud_points,
        cloud_seed: args.cloud_seed,
        write_clouds: args.write_clouds,
        ..TrainOptions::default()
    };
    let bar = progress_bar(&format!("training {category}: stability ranges"));
    let mut db = train(&hand, category, &teach, &models, &out, &options, Some(&bar))
        .with_context(|| format!("training {category} from {}", grasps.display()))?;
    bar.finish_and_clear();
    if !args.no_calibrate {
        let weights = calibrate_weights(&cell, &db, args.calibration_seed)
            .with_context(|| format!("calibrating the weights of {}", out.display()))?;
        db.file.weights = Some(weights);
        write_database(&out, &db.file)?;
        db = CategoryDb::load(&out)?;
    }
    let report = report_of(&db);
    super::emit(args.json, &report, |r: &TrainReport| {
        let mut text = format!(
            "wrote {} ({} models, {} grasps) to {}\n",
            r.category,
            r.models,
            r.grasps.len(),
            r.out.display()
        );
        for g in &r.grasps {
            let d = g.delta;
            text += &format!(
                "  {:<24} {:<7} q {:.4}  Delta {:.1} {:.1} {:.1} mm  {:.1} {:.1} {:.1} deg\n",
                g.name,
                g.task,
                g.q,
                1e3 * d[0],
                1e3 * d[1],
                1e3 * d[2],
                d[3].to_degrees(),
                d[4].to_degrees(),
                d[5].to_degrees()
            );
        }
        if let Some(w) = &r.weights {
            text += &format!(
                "weights: lambda_psi {:.3} (median q {:.4}; psi {:.2}..{:.2} over q {:.4}..{:.4})\n\
                 \x20        lambda_eps {:.4e} /m^2 (median eps+sigma {:.3} mm^2 over {} leave-one-out fits; \
                 phi {:.2}..{:.2})\n",
                w.lambda_psi,
                w.q.median,
                w.psi_range[0],
                w.psi_range[1],
                w.q.min,
                w.q.max,
                w.lambda_eps_per_m2,
                w.fit_score_m2.median * 1e6,
                w.fit_score_m2.count,
                w.phi_range[1],
                w.phi_range[0]
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

fn report_of(db: &CategoryDb) -> TrainReport {
    TrainReport {
        category: db.file.category,
        out: db.dir.clone(),
        models: db.file.models.len(),
        grasps: db
            .file
            .grasps
            .iter()
            .map(|g| GraspLine {
                name: g.name.clone(),
                task: g.task.clone(),
                q: g.q,
                delta: g.delta,
            })
            .collect(),
        weights: db.file.weights.clone(),
    }
}

/// The weights of eq. 2 calibrated for `db` ([`crate::category::calibrate`]): each
/// model placed on the table (seeded), seen by the cell's sim camera, and the other
/// models registered to that partial view, as in `cell eval loo --views partial`.
fn calibrate_weights(
    cell: &CellConfig,
    db: &CategoryDb,
    seed: u64,
) -> anyhow::Result<WeightCalibration> {
    use rayon::prelude::*;
    let camera = DepthCamera::from_config(&cell.camera, cell.base_from_camera());
    let table = TableBox::from(&cell.table);
    let region = PlacementRegion::around([0.6, 0.0], cell.table.height_m);
    let eye = cell.base_from_camera().translation.vector;
    let registrar = CategoryRegistrar::new(db, Some([eye.x, eye.y, eye.z]))?;
    let models = db.file.models.len();
    anyhow::ensure!(
        models >= 2,
        "{}: leave-one-out needs at least 2 models (use --no-calibrate)",
        db.dir.display()
    );
    let per_view: Vec<anyhow::Result<(Vec<f64>, usize)>> = (0..models)
        .into_par_iter()
        .map(|i| {
            let name = &db.file.models[i].name;
            let mesh = &db.meshes[i];
            let view_seed = seed.wrapping_add(i as u64);
            let pose = region.place(mesh, view_seed);
            let view = partial_view(name, mesh, &pose, &camera, table, view_seed)?;
            Ok(match registrar.fits(&view, Some(name), view_seed) {
                Ok(fits) => {
                    let failed = models - 1 - fits.len();
                    (fits.iter().map(|f| f.eps_m2 + f.sigma_m2).collect(), failed)
                }
                Err(_) => (Vec::new(), models - 1),
            })
        })
        .collect();
    let mut scores = Vec::new();
    let mut failed = 0;
    for r in per_view {
        let (s, f) = r?;
        scores.extend(s);
        failed += f;
    }
    let q: Vec<f64> = db.file.grasps.iter().map(|g| g.q).collect();
    let source = LooSource {
        view: "partial".into(),
        seed,
        views: models,
        failed,
    };
    Ok(calibrate(&q, &scores, source)?)
}

fn suggest(hand: &HandModel, args: SuggestArgs) -> anyhow::Result<ExitCode> {
    let listing_path = args.models.join("params.json");
    let text = std::fs::read_to_string(&listing_path)
        .with_context(|| format!("cannot read {}", listing_path.display()))?;
    let listing: Listing =
        serde_json::from_str(&text).with_context(|| format!("{}", listing_path.display()))?;
    let models = listing
        .instances
        .into_iter()
        .map(|i| {
            let mesh = crate::mesh::load_mesh(&args.models.join(&i.file), 1.0)?;
            Ok(SuggestModel {
                file: i.file,
                mesh,
                params: i.params,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let bar = progress_bar(&format!("suggesting {} grasps", listing.category));
    bar.set_length(models.len() as u64);
    let options = SuggestOptions {
        seed: args.seed,
        ..SuggestOptions::default()
    };
    let (file, reports) = suggest_teach_file(
        hand,
        listing.category,
        &models,
        args.table_z,
        &QualityParams::default(),
        &options,
        &|| bar.inc(1),
    )?;
    bar.finish_and_clear();
    let table = args
        .table_z
        .map(|z| format!(" --table-z {z}"))
        .unwrap_or_default();
    let mut header = format!(
        "Teach-in grasps of {count} procedural {category} models: palm (bh_palm) pose in each\n\
         model's frame, spread of F1/F2. Models: `cell objects generate --category {category}\n\
         --count {count} --seed {seed} --out DIR`. Proposed by `cell train suggest-grasps\n\
         --models DIR --seed {search}{table}`; review and edit, then run `cell train`.\n\
         Epsilon of each proposal:\n",
        count = listing.count,
        category = listing.category,
        seed = listing.seed,
        search = args.seed,
    );
    for r in &reports {
        header += &match r.epsilon {
            Some(e) => format!("  {} ({}): {e:.4}\n", r.name, r.task),
            None => format!("  {} ({}): none found, add one by hand\n", r.name, r.task),
        };
    }
    crate::fsio::write_atomically(&args.out, file.to_toml(&header).as_bytes())
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    super::emit(args.json, &reports, |r: &Vec<_>| {
        let found = r
            .iter()
            .filter(|x: &&crate::category::suggest::SuggestReport| x.epsilon.is_some())
            .count();
        format!(
            "wrote {} ({found} of {} grasps found)\n{header}",
            args.out.display(),
            r.len()
        )
    })?;
    Ok(ExitCode::SUCCESS)
}
