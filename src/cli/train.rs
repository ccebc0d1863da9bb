//! `cell train`: build a category database from a teach-in file, and
//! `cell train suggest-grasps`: propose a teach-in file for procedural models.

use crate::category::suggest::{suggest_teach_file, SuggestModel, SuggestOptions};
use crate::category::teach::TeachFile;
use crate::category::train::{train, TrainOptions};
use crate::category::CategoryDb;
use crate::config::CellConfig;
use crate::mesh::procedural::{Category, Params};
use crate::quality::QualityParams;
use crate::robot::hand::HandModel;
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
    let hand = HandModel::load(&CellConfig::load(config)?)?;
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
    let db = train(&hand, category, &teach, &models, &out, &options, Some(&bar))
        .with_context(|| format!("training {category} from {}", grasps.display()))?;
    bar.finish_and_clear();
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
    }
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
