//! `cell segment` and `cell register`: the perception stage from the command line
//! (`cell bench register` is in `bench::register`).

use crate::category::CategoryDb;
use crate::cloud::io::{read_cloud, write_cloud, CloudEncoding};
use crate::cloud::segment::{segment_object, SegmentParams};
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::geometry::{matrix_rows, parse_numbers, parse_pose};
use crate::register::icp::IcpMetric;
use crate::register::{
    register_all_timed, ModelRegistration, ModelSet, RegisterParams, RegistrationStatus,
};
use anyhow::{bail, Context};
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Options of `cell segment`.
#[derive(Debug, Args)]
pub struct SegmentArgs {
    /// The camera's snapshot (PLY/PCD, camera optical frame; organised or not, NaN = missing).
    #[arg(long)]
    pub cloud: PathBuf,
    /// Where to write the object's points (PLY/PCD, robot base frame).
    #[arg(long)]
    pub out: PathBuf,
    /// Camera pose `x,y,z,roll,pitch,yaw` (base_from_camera); default: the configuration's.
    #[arg(long)]
    pub camera_pose: Option<String>,
    /// Seed of the plane RANSAC.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `cell segment` reports.
#[derive(Debug, Serialize)]
struct SegmentReport {
    cloud: PathBuf,
    out: PathBuf,
    input_points: usize,
    valid_points: usize,
    object_points: usize,
    centroid_m: [f64; 3],
    extent_m: [f64; 3],
    time_ms: f64,
}

/// Runs `cell segment`.
pub fn segment(config_path: &Path, args: SegmentArgs) -> anyhow::Result<ExitCode> {
    let config = CellConfig::load(config_path)?;
    let base_from_camera = match &args.camera_pose {
        Some(text) => parse_pose(text).context("--camera-pose")?,
        None => config.base_from_camera(),
    };
    let cloud = read_cloud(&args.cloud)?;
    let params = SegmentParams {
        seed: args.seed,
        ..SegmentParams::for_cell(&config)
    };
    let started = Instant::now();
    let object = segment_object(&cloud, &base_from_camera, &params)
        .with_context(|| format!("{}", args.cloud.display()))?;
    let time_ms = started.elapsed().as_secs_f64() * 1e3;
    write_cloud(&args.out, &object, CloudEncoding::Binary)?;
    let (lo, hi) = bounds(&object);
    let n = object.len() as f64;
    let sum = object.points.iter().fold([0.0; 3], |s, p| {
        [s[0] + p.x as f64, s[1] + p.y as f64, s[2] + p.z as f64]
    });
    let report = SegmentReport {
        cloud: args.cloud.clone(),
        out: args.out.clone(),
        input_points: cloud.len(),
        valid_points: cloud.valid_points().count(),
        object_points: object.len(),
        centroid_m: sum.map(|v| v / n),
        extent_m: [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]],
        time_ms,
    };
    super::emit(args.json, &report, |r| {
        format!(
            "{}: {} object points of {} valid, centroid {:.3?} m, extent {:.3?} m ({:.0} ms)\n",
            r.out.display(),
            r.object_points,
            r.valid_points,
            r.centroid_m,
            r.extent_m,
            r.time_ms
        )
    })?;
    Ok(ExitCode::SUCCESS)
}

fn bounds(cloud: &PointCloud) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in cloud.valid_points() {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    (lo, hi)
}

/// Options of `cell register`.
#[derive(Debug, Args)]
pub struct RegisterArgs {
    /// The object's points (PLY/PCD), e.g. from `cell segment` (robot base frame).
    #[arg(long)]
    pub target: PathBuf,
    /// A model cloud (PLY/PCD, model frame); repeat for several. Named by file stem.
    #[arg(long = "model", conflicts_with = "models")]
    pub model: Vec<PathBuf>,
    /// A directory of models: a category database (`category.json`), or every
    /// `.ply`/`.pcd` cloud in it.
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Seed of RANSAC.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sensor position `x,y,z` in the target's frame, for normal orientation;
    /// default: the configured camera's position.
    #[arg(long)]
    pub viewpoint: Option<String>,
    /// ICP metric.
    #[arg(long, value_enum, default_value_t = IcpMetric::PointToPlane)]
    pub icp: IcpMetric,
    /// Print JSON: an array with one object per model.
    #[arg(long)]
    pub json: bool,
}

/// One model's line of `cell register --json`.
#[derive(Debug, Serialize)]
pub struct RegistrationJson {
    model: String,
    status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    reason: Option<String>,
    /// 4x4, row-major.
    target_from_model: [[f64; 4]; 4],
    /// Mean squared nearest-neighbour distance (m^2).
    eps: Option<f64>,
    /// Standard deviation of the squared distances (m^2).
    sigma: Option<f64>,
    inlier_fraction: f64,
    /// Inlier RMS distance (m).
    rmse: Option<f64>,
    iterations: usize,
    time_ms: f64,
}

impl From<&ModelRegistration> for RegistrationJson {
    fn from(r: &ModelRegistration) -> Self {
        let finite = |v: f64| v.is_finite().then_some(v);
        let (status, reason) = match &r.status {
            RegistrationStatus::Ok => ("ok", None),
            RegistrationStatus::Failed(why) => ("failed", Some(why.clone())),
        };
        RegistrationJson {
            model: r.model.clone(),
            status,
            reason,
            target_from_model: matrix_rows(&r.target_from_model),
            eps: finite(r.eps_m2),
            sigma: finite(r.sigma_m2),
            inlier_fraction: r.inlier_fraction,
            rmse: finite(r.rmse_m),
            iterations: r.iterations,
            time_ms: r.time_ms,
        }
    }
}

/// Model clouds named by file stem: every `.ply`/`.pcd` in `dir`, sorted.
fn clouds_in(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot list the models directory", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            matches!(
                p.extension()
                    .and_then(|e| e.to_str())
                    .map(str::to_ascii_lowercase)
                    .as_deref(),
                Some("ply") | Some("pcd")
            )
        })
        .collect();
    files.sort();
    if files.is_empty() {
        bail!(
            "{}: no category.json and no .ply/.pcd model clouds",
            dir.display()
        );
    }
    Ok(files)
}

fn load_models(args: &RegisterArgs, params: &RegisterParams) -> anyhow::Result<ModelSet> {
    let files = match (&args.models, args.model.is_empty()) {
        (Some(dir), _) if dir.join("category.json").is_file() => {
            let db = CategoryDb::load(dir)?;
            return Ok(ModelSet::from_category(&db, params)?);
        }
        (Some(dir), _) => clouds_in(dir)?,
        (None, false) => args.model.clone(),
        (None, true) => bail!("give the models: --model a.ply [--model b.ply ...] or --models DIR"),
    };
    let mut clouds = Vec::new();
    for f in files {
        let name = f
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| f.display().to_string());
        clouds.push((name, read_cloud(&f)?));
    }
    Ok(ModelSet::from_clouds(clouds, params)?)
}

/// Runs `cell register`.
pub fn register(config_path: &Path, args: RegisterArgs) -> anyhow::Result<ExitCode> {
    let viewpoint = match &args.viewpoint {
        Some(text) => {
            let v = parse_numbers(text, 3, "--viewpoint")?;
            [v[0], v[1], v[2]]
        }
        None => {
            let eye = CellConfig::load(config_path)?
                .base_from_camera()
                .translation
                .vector;
            [eye.x, eye.y, eye.z]
        }
    };
    let params = RegisterParams {
        viewpoint_m: Some(viewpoint),
        icp_metric: args.icp,
        ..RegisterParams::default()
    };
    let target = read_cloud(&args.target)?;
    let models = load_models(&args, &params)?;
    let (results, timings) = register_all_timed(&target, &models, &params, args.seed)
        .with_context(|| format!("{}", args.target.display()))?;
    tracing::info!(?timings, "registration");
    let lines: Vec<RegistrationJson> = results.iter().map(RegistrationJson::from).collect();
    super::emit(args.json, &lines, |lines| {
        let mut text = format!(
            "{:<16} {:>7} {:>11} {:>11} {:>8} {:>8} {:>8}\n",
            "model", "status", "eps_mm2", "sigma_mm2", "inliers", "rmse_mm", "ms"
        );
        for l in lines {
            text += &format!(
                "{:<16} {:>7} {:>11.3} {:>11.3} {:>7.1}% {:>8.2} {:>8.1}{}\n",
                l.model,
                l.status,
                l.eps.unwrap_or(f64::NAN) * 1e6,
                l.sigma.unwrap_or(f64::NAN) * 1e6,
                l.inlier_fraction * 100.0,
                l.rmse.unwrap_or(f64::NAN) * 1e3,
                l.time_ms,
                l.reason
                    .as_deref()
                    .map(|r| format!("  ({r})"))
                    .unwrap_or_default()
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}
