//! `cell bench picture`: rendering and encoding one logged trial's picture.

use crate::trial::{TrialId, TrialLog};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

/// Options of `cell bench picture`.
#[derive(Debug, Args)]
pub struct PictureBenchArgs {
    /// Trial log holding the trial (e.g. a `cell campaign` log).
    #[arg(long)]
    pub log: PathBuf,
    /// The trial's id.
    #[arg(long, default_value_t = 1)]
    pub trial: TrialId,
    /// Directory of the category databases.
    #[arg(long, default_value = "db")]
    pub db_dir: PathBuf,
    /// Timed repeats (medians are reported).
    #[arg(long, default_value_t = 20)]
    pub repeats: usize,
    /// Print JSON (always JSON; accepted for uniformity).
    #[arg(long)]
    pub json: bool,
}

/// Runs `cell bench picture`.
pub fn bench_picture(
    config_path: &std::path::Path,
    args: PictureBenchArgs,
) -> anyhow::Result<ExitCode> {
    use std::time::Instant;
    anyhow::ensure!(args.repeats > 0, "--repeats must be at least 1");
    let config = crate::config::CellConfig::load(config_path)?;
    let log = TrialLog::open_existing(&args.log)?;
    let record = log.trial(args.trial)?;
    let robot = crate::robot::Robot::load(&config)?;
    let hand = crate::robot::hand::HandModel::load(&config)?;
    let db = crate::cell::load_category(&args.db_dir, &record.trial.category).ok();
    let inputs = crate::trial::scene::SceneInputs {
        config: &config,
        robot: &robot,
        hand: &hand,
        db: db.as_ref(),
        base_from_camera: config.base_from_camera(),
    };
    let mut scene_ms = Vec::new();
    let mut scene = None;
    for _ in 0..args.repeats.min(5) {
        let t = Instant::now();
        scene = Some(crate::trial::scene::trial_scene(&record, &inputs));
        scene_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let scene = scene.expect("at least one repeat");
    let (mut render_ms, mut encode_ms) = (Vec::new(), Vec::new());
    let mut size = (0, 0);
    for _ in 0..args.repeats {
        let t = Instant::now();
        let canvas = crate::trial::picture::render(&scene);
        render_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let png = canvas.to_png(std::path::Path::new("bench.png"))?;
        encode_ms.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(png);
        size = (canvas.width, canvas.height);
    }
    let triangles: usize = scene.solids.iter().map(|s| s.triangles.len()).sum();
    let render = crate::stats::median(&mut render_ms);
    let encode = crate::stats::median(&mut encode_ms);
    let out = serde_json::json!({
        "benchmark": "picture",
        "trial_id": args.trial,
        "repeats": args.repeats,
        "image_px": [size.0, size.1],
        "triangles": triangles,
        "cloud_points": scene.cloud_m.len(),
        "contacts": scene.contacts_m.len(),
        "render_median_ms": render,
        "png_encode_median_ms": encode,
        "render_and_encode_median_ms": render + encode,
        "scene_assembly_median_ms": crate::stats::median(&mut scene_ms),
        "goal_ms": 100.0,
        "load_average": super::load_average(),
    });
    crate::cli::write_stdout(&format!("{}\n", serde_json::to_string_pretty(&out)?))?;
    Ok(ExitCode::SUCCESS)
}
