//! `cell objects generate`: procedural category models written as mesh files.

use super::eval::FamilyChoice;
use crate::mesh::procedural::held_apart::{generate_in, held_apart_instance, Family};
use crate::mesh::procedural::{instance_seed, Category, Params};
use crate::mesh::topology::{bounding_box, signed_volume};
use crate::mesh::{write_mesh, MeshFormat};
use anyhow::Context;
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::path::PathBuf;
use std::process::ExitCode;

/// Object model commands.
#[derive(Debug, Subcommand)]
pub enum ObjectsCommand {
    /// Write procedural instances of a category (one mesh each) and their parameters.
    Generate(GenerateArgs),
}

/// Options of `cell objects generate`.
#[derive(Debug, Args)]
pub struct GenerateArgs {
    /// Category: mug, bottle, hammer or knife.
    #[arg(long)]
    pub category: Category,
    /// Number of instances.
    #[arg(long, default_value_t = 7)]
    pub count: usize,
    /// Seed of the set; instance i uses a seed derived from (seed, i).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Which shapes: the databases' own generator (files `mug_000.obj`, ...), or
    /// the held-apart shapes of `cell eval novel` (files named as its trials name
    /// the objects, `squat-mug-1-0.obj` for set 1, instance 0), so that a trial's
    /// object can be closed on again with `cell quality --object`.
    #[arg(long, value_enum, default_value_t = FamilyChoice::Training)]
    pub family: FamilyChoice,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Mesh file format.
    #[arg(long, value_enum, default_value_t = MeshFormat::Obj)]
    pub format: MeshFormat,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// One generated instance, as listed in `params.json`.
#[derive(Debug, Serialize)]
struct Instance {
    index: usize,
    file: String,
    seed: u64,
    triangles: usize,
    volume_m3: f64,
    bounding_box_m: [[f64; 3]; 2],
    params: Params,
}

/// The content of `params.json`.
#[derive(Debug, Serialize)]
struct Listing {
    category: Category,
    family: &'static str,
    seed: u64,
    count: usize,
    instances: Vec<Instance>,
}

/// Runs an objects subcommand.
pub fn run(command: ObjectsCommand) -> anyhow::Result<ExitCode> {
    match command {
        ObjectsCommand::Generate(args) => generate_set(args),
    }
}

fn generate_set(args: GenerateArgs) -> anyhow::Result<ExitCode> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create output directory {}", args.out.display()))?;
    let progress = ProgressBar::new(args.count as u64);
    progress.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    progress.set_message(format!("generating {}", args.category));
    let mut instances = Vec::with_capacity(args.count);
    for index in 0..args.count {
        let family = Family::from(args.family);
        let (stem, seed) = match family {
            Family::Training => (
                format!("{}_{index:03}", args.category),
                instance_seed(args.seed, index as u64),
            ),
            Family::HeldApart => held_apart_instance(args.category, args.seed, index as u64),
        };
        let (mesh, params) = generate_in(family, args.category, seed);
        let file = format!("{stem}.{}", args.format.extension());
        write_mesh(&args.out.join(&file), &mesh)?;
        let (lo, hi) = bounding_box(&mesh).context("generated an empty mesh")?;
        tracing::info!(%file, seed, triangles = mesh.triangles.len(), "wrote instance");
        instances.push(Instance {
            index,
            file,
            seed,
            triangles: mesh.triangles.len(),
            volume_m3: signed_volume(&mesh),
            bounding_box_m: [lo.into(), hi.into()],
            params,
        });
        progress.inc(1);
    }
    progress.finish_and_clear();
    let listing = Listing {
        category: args.category,
        family: Family::from(args.family).name(),
        seed: args.seed,
        count: args.count,
        instances,
    };
    let params_path = args.out.join("params.json");
    crate::fsio::write_atomically(
        &params_path,
        serde_json::to_string_pretty(&listing)?.as_bytes(),
    )
    .with_context(|| format!("cannot write {}", params_path.display()))?;
    super::emit(args.json, &listing, |l| {
        let mut text = format!(
            "wrote {} {} instances (seed {}) and params.json to {}\n",
            l.count,
            l.category,
            l.seed,
            args.out.display()
        );
        for i in &l.instances {
            let size = [0, 1, 2].map(|k| 1e3 * (i.bounding_box_m[1][k] - i.bounding_box_m[0][k]));
            text += &format!(
                "  {}  seed {:>20}  {:>6} triangles  {:.0} x {:.0} x {:.0} mm\n",
                i.file, i.seed, i.triangles, size[0], size[1], size[2]
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}
