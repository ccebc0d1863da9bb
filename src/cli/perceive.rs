//! `cell segment`, `cell register` and `cell bench register`: the perception stage
//! from the command line.

use super::bench::median;
use crate::category::CategoryDb;
use crate::cloud::io::{read_cloud, write_cloud, CloudEncoding};
use crate::cloud::sample::sample_surface;
use crate::cloud::segment::{segment_object, SegmentParams};
use crate::cloud::PointCloud;
use crate::config::CellConfig;
use crate::geometry::{matrix_rows, parse_numbers, parse_pose, pose_error, pose_from_params, Pose};
use crate::mesh::procedural::{generate, instance_seed, Category};
use crate::register::icp::IcpMetric;
use crate::register::{
    register_all_timed, ModelRegistration, ModelSet, RegisterParams, RegisterTimings,
    RegistrationStatus,
};
use crate::sim::camera::DepthCamera;
use crate::sim::scene::{Scene, TableBox};
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

/// Options of `cell bench register`.
#[derive(Debug, Args)]
pub struct RegisterBenchArgs {
    /// Number of procedural mug models (the view shows the first that has a handle,
    /// so that its pose is unique).
    #[arg(long, default_value_t = 11)]
    pub models: usize,
    /// Timed runs per view (medians are reported).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the models, the view's noise and RANSAC.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the exact clouds used (views in the base frame, model clouds in their
    /// frames, `truth.json`) to this directory, to run other tools on the same input.
    #[arg(long)]
    pub write_clouds: Option<PathBuf>,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Per-stage medians of one view.
#[derive(Debug, Serialize)]
struct ViewBench {
    view: &'static str,
    target_points: usize,
    /// Target stages run once per call; model stages are CPU time summed over models.
    median_ms: StageMedians,
    /// Median CPU time of the process per call (ms), all threads: with `threads`
    /// cores to itself a call's wall time is about this over the threads; a total
    /// well above that means the machine was busy with other work.
    median_cpu_ms: f64,
    /// Own model's pose error (mm, deg) and its rank by eps among all models (1 = best), per run.
    own_error_mm: f64,
    own_error_deg: f64,
    own_rank: usize,
    models_ok: usize,
}

#[derive(Debug, Serialize)]
struct StageMedians {
    downsample: f64,
    normals: f64,
    fpfh: f64,
    matching: f64,
    ransac: f64,
    coarse: f64,
    icp: f64,
    scoring: f64,
    total: f64,
}

#[derive(Debug, Serialize)]
struct RegisterBench {
    models: usize,
    model_points: usize,
    threads: usize,
    repeats: usize,
    seed: u64,
    /// The model the views show.
    view_shows: String,
    model_preparation_ms: f64,
    views: Vec<ViewBench>,
}

/// CPU time (user and system) of this process so far (ms).
fn process_cpu_ms() -> f64 {
    crate::sys::resource_usage().map_or(f64::NAN, |u| u.cpu_ms)
}

/// The mug `index` of the bench's set.
fn bench_mug(seed: u64, index: usize) -> crate::mesh::TriMesh {
    generate(Category::Mug, instance_seed(seed, index as u64)).0
}

/// Whether mug `index` of the bench's set has a handle.
fn bench_mug_has_handle(seed: u64, index: usize) -> bool {
    matches!(
        generate(Category::Mug, instance_seed(seed, index as u64)).1,
        crate::mesh::procedural::Params::Mug(crate::mesh::procedural::MugParams {
            handle: Some(_),
            ..
        })
    )
}

/// Renders mug `index` on the table at `truth` with the configured camera, its
/// resolution scaled by `scale`, and segments it.
fn bench_view(
    config: &CellConfig,
    index: usize,
    truth: &Pose,
    scale: f64,
    seed: u64,
) -> anyhow::Result<PointCloud> {
    let mut camera = DepthCamera::from_config(&config.camera, config.base_from_camera());
    let i = &mut camera.intrinsics;
    i.width_px = (i.width_px as f64 * scale).round() as u32;
    i.height_px = (i.height_px as f64 * scale).round() as u32;
    i.fx_px *= scale;
    i.fy_px *= scale;
    i.cx_px = (i.cx_px + 0.5) * scale - 0.5;
    i.cy_px = (i.cy_px + 0.5) * scale - 0.5;
    let mut scene = Scene::new(Some(TableBox::from(&config.table)));
    scene.add("shown", bench_mug(seed, index), *truth)?;
    let cloud = camera.render(&scene, seed).to_cloud();
    Ok(segment_object(
        &cloud,
        &camera.base_from_camera,
        &SegmentParams::for_cell(config),
    )?)
}

/// Runs `cell bench register`.
pub fn bench(config_path: &Path, args: RegisterBenchArgs) -> anyhow::Result<ExitCode> {
    if args.models == 0 || args.repeats == 0 {
        bail!("--models and --repeats must be at least 1");
    }
    let config = CellConfig::load(config_path)?;
    let eye = config.base_from_camera().translation.vector;
    let params = RegisterParams {
        viewpoint_m: Some([eye.x, eye.y, eye.z]),
        ..RegisterParams::default()
    };
    let clouds: Vec<(String, PointCloud)> = (0..args.models)
        .map(|i| {
            let cloud = sample_surface(&bench_mug(args.seed, i), params.model_points, args.seed)?;
            Ok((format!("mug_{i:02}"), cloud))
        })
        .collect::<anyhow::Result<_>>()?;
    let shown = (0..args.models)
        .find(|&i| bench_mug_has_handle(args.seed, i))
        .unwrap_or(0);
    let started = Instant::now();
    let models = ModelSet::from_clouds(clouds.clone(), &params)?;
    let model_preparation_ms = started.elapsed().as_secs_f64() * 1e3;
    // Handle visible: yaw 50 deg turns it towards the camera's side.
    let truth = pose_from_params(&[0.6, 0.03, config.table.height_m, 0.0, 0.0, 0.87]);
    // The configured camera's 640 x 480 sees a few thousand points of a mug; the
    // views are rendered at the resolutions that give about 6k and 28k.
    let native = bench_view(&config, shown, &truth, 1.0, args.seed)?
        .len()
        .max(1) as f64;
    let views = [
        (
            "6k",
            bench_view(&config, shown, &truth, (6e3 / native).sqrt(), args.seed)?,
        ),
        (
            "28k",
            bench_view(&config, shown, &truth, (28e3 / native).sqrt(), args.seed)?,
        ),
    ];
    if let Some(dir) = &args.write_clouds {
        std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
        for (name, view) in &views {
            write_cloud(
                &dir.join(format!("view_{name}.ply")),
                view,
                CloudEncoding::Ascii,
            )?;
        }
        for (name, cloud) in &clouds {
            write_cloud(
                &dir.join(format!("{name}.ply")),
                cloud,
                CloudEncoding::Ascii,
            )?;
        }
        let truth_json = serde_json::json!({
            "frame": "views in the robot base frame, models in their own frames",
            "view_shows": clouds[shown].0,
            "base_from_shown": matrix_rows(&truth),
            "camera_position_m": [eye.x, eye.y, eye.z],
        });
        crate::fsio::write_atomically(
            &dir.join("truth.json"),
            serde_json::to_string_pretty(&truth_json)?.as_bytes(),
        )
        .with_context(|| format!("{}", dir.display()))?;
    }
    let mut out = Vec::new();
    for (name, view) in &views {
        let mut runs: Vec<(Vec<ModelRegistration>, RegisterTimings)> = Vec::new();
        let mut cpu = Vec::new();
        for r in 0..args.repeats {
            let before = process_cpu_ms();
            runs.push(register_all_timed(
                view,
                &models,
                &params,
                args.seed + r as u64,
            )?);
            cpu.push(process_cpu_ms() - before);
        }
        let stage = |f: fn(&RegisterTimings) -> f64| {
            median(&mut runs.iter().map(|(_, t)| f(t)).collect::<Vec<_>>())
        };
        let (results, _) = &runs[0];
        let own = &results[shown];
        let (dp, dr) = pose_error(&own.target_from_model, &truth);
        let rank = 1 + results
            .iter()
            .filter(|r| r.status == RegistrationStatus::Ok && r.eps_m2 < own.eps_m2)
            .count();
        out.push(ViewBench {
            view: name,
            target_points: view.len(),
            median_ms: StageMedians {
                downsample: stage(|t| t.downsample_ms),
                normals: stage(|t| t.normals_ms),
                fpfh: stage(|t| t.fpfh_ms),
                matching: stage(|t| t.matching_ms),
                ransac: stage(|t| t.ransac_ms),
                coarse: stage(|t| t.coarse_ms),
                icp: stage(|t| t.icp_ms),
                scoring: stage(|t| t.scoring_ms),
                total: stage(|t| t.total_ms),
            },
            median_cpu_ms: median(&mut cpu),
            own_error_mm: dp * 1e3,
            own_error_deg: dr.to_degrees(),
            own_rank: rank,
            models_ok: results
                .iter()
                .filter(|r| r.status == RegistrationStatus::Ok)
                .count(),
        });
    }
    let report = RegisterBench {
        models: args.models,
        model_points: params.model_points,
        threads: rayon::current_num_threads(),
        repeats: args.repeats,
        seed: args.seed,
        view_shows: clouds[shown].0.clone(),
        model_preparation_ms,
        views: out,
    };
    super::emit(true, &report, |_| String::new())?;
    Ok(ExitCode::SUCCESS)
}
