//! `cell-camera`: the camera stage of the cell (see `graspcell::cell::camera`).

use clap::Parser;
use graspcell::cell::{camera, stage_main, StageArgs};
use graspcell::config::CellConfig;

/// Publishes a depth snapshot (point cloud in shared memory) for every trial request;
/// the backend (`sim`, `replay` or `kinect`) comes from `camera.backend` in the configuration.
#[derive(Debug, Parser)]
#[command(name = "cell-camera", version)]
struct Args {
    #[command(flatten)]
    stage: StageArgs,
    /// Hand–eye calibration result the gravity check compares the camera's
    /// accelerometer with (the configured mount when missing or invalid).
    #[arg(long, default_value = graspcell::calib::DEFAULT_RESULT_PATH)]
    hand_eye: std::path::PathBuf,
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    stage_main("camera", || {
        let config = CellConfig::load(&args.stage.config)?;
        camera::run(
            &config,
            &args.stage.domain()?,
            &args.stage.run_dir,
            &args.hand_eye,
        )
    })
}
