//! `cell camera render`: the simulated depth camera; `cell camera record` (any
//! backend into a fakenect recording). Their benchmarks are `bench::render` and
//! `bench::camera`.

use crate::cell::camera::{CameraBackend, Snapshot};
use crate::config::CellConfig;
use crate::geometry::{Pose, PoseJson};
use crate::hw::kinect::convert::cloud_to_raw;
use crate::hw::kinect::fakenect::{FakenectWriter, RawFrame};
use crate::hw::kinect::gravity::{expected_gravity_camera, AccelCounts};
use crate::hw::kinect::registration::{Registration, FRAME_HEIGHT, FRAME_WIDTH};
use crate::sim::camera::{DepthCamera, DepthFrame, Return, Surface};
use crate::sim::scene::{load_scene, Scene};
use anyhow::Context;
use clap::{Args, Subcommand};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Simulated camera commands.
#[derive(Debug, Subcommand)]
pub enum CameraCommand {
    /// Render a scene file to an organised point cloud (camera optical frame).
    Render(RenderArgs),
    /// Record frames of the configured camera (sim, replay or kinect) into a
    /// fakenect directory (INDEX.txt, d-*.pgm, r-*.ppm, a-*.dump, device.json),
    /// which the kinect backend plays through fakenect.
    Record(RecordArgs),
}

/// Options of `cell camera record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Output directory (created; must not already hold a recording).
    pub dir: PathBuf,
    /// Number of frames (each: accelerometer, depth, colour; 30 frames/s).
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// Scene file (TOML) the simulated camera renders (camera.backend = "sim").
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Seed of the first frame's sensor noise (sim); frame i uses seed + i.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Take frames from this backend instead of the configured camera.backend.
    #[arg(long)]
    pub backend: Option<String>,
    /// Run directory of the replay backend (it reads `<run dir>/replay/`).
    #[arg(long, default_value = "run")]
    pub run_dir: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Options of `cell camera render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Scene file (TOML): camera pose, table and objects with their poses.
    #[arg(long)]
    pub scene: PathBuf,
    /// Output cloud (PLY): organised, camera optical frame, NaN where no return.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Also write a colour-mapped depth image here (PNG; black = no return).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Pixel counts of one object in a frame.
#[derive(Debug, Serialize)]
struct ObjectPixels {
    name: String,
    hit_pixels: usize,
    valid_pixels: usize,
}

/// What `cell camera render` reports.
#[derive(Debug, Serialize)]
struct RenderReport {
    scene: PathBuf,
    cloud: PathBuf,
    png: Option<PathBuf>,
    seed: u64,
    width_px: u32,
    height_px: u32,
    base_from_camera: PoseJson,
    valid_fraction: f64,
    missing: MissingCounts,
    depth_range_m: Option<[f32; 2]>,
    objects: Vec<ObjectPixels>,
}

/// Pixels without a return, by cause.
#[derive(Debug, Serialize)]
struct MissingCounts {
    no_surface: usize,
    out_of_range: usize,
    grazing: usize,
    edge: usize,
}

/// Runs a camera subcommand.
pub fn run(config: &Path, command: CameraCommand) -> anyhow::Result<ExitCode> {
    match command {
        CameraCommand::Render(args) => render(config, args),
        CameraCommand::Record(args) => record(config, args),
    }
}

fn render(config_path: &Path, args: RenderArgs) -> anyhow::Result<ExitCode> {
    let config = CellConfig::load(config_path)?;
    let loaded = load_scene(&args.scene, &config)?;
    let camera = DepthCamera::from_config(&config.camera, loaded.base_from_camera);
    let frame = camera.render(&loaded.scene, args.seed);
    tracing::info!(seed = args.seed, valid = frame.valid_fraction(), "rendered");
    crate::cloud::io::write_cloud(
        &args.out,
        &frame.to_cloud(),
        crate::cloud::io::CloudEncoding::Binary,
    )?;
    let depth_range_m = valid_depth_range(&frame);
    if let Some(png) = &args.png {
        write_depth_png(png, &frame)?;
        match depth_range_m {
            Some([near, far]) => eprintln!(
                "{}: turbo colour map, dark blue = {near:.3} m (near) .. dark red = {far:.3} m (far), \
                 black = no return; bar at the bottom: near to far, ticks every 0.1 m",
                png.display()
            ),
            None => eprintln!("{}: no valid depth; the image is black", png.display()),
        }
    }
    let report = RenderReport {
        scene: args.scene.clone(),
        cloud: args.out.clone(),
        png: args.png.clone(),
        seed: args.seed,
        width_px: frame.intrinsics.width_px,
        height_px: frame.intrinsics.height_px,
        base_from_camera: PoseJson::from(&loaded.base_from_camera),
        valid_fraction: frame.valid_fraction(),
        missing: MissingCounts {
            no_surface: frame.count(|r, _| r == Return::NoSurface),
            out_of_range: frame.count(|r, _| r == Return::OutOfRange),
            grazing: frame.count(|r, _| r == Return::Grazing),
            edge: frame.count(|r, _| r == Return::Edge),
        },
        depth_range_m,
        objects: object_pixels(&frame, &loaded.scene),
    };
    super::emit(args.json, &report, |r| {
        let mut text = format!(
            "{}: {}x{} cloud, {:.1} % valid (seed {})\n",
            r.cloud.display(),
            r.width_px,
            r.height_px,
            100.0 * r.valid_fraction,
            r.seed
        );
        for o in &r.objects {
            text += &format!(
                "  {}: {} pixels hit, {} valid\n",
                o.name, o.hit_pixels, o.valid_pixels
            );
        }
        text
    })?;
    Ok(ExitCode::SUCCESS)
}

fn object_pixels(frame: &DepthFrame, scene: &Scene) -> Vec<ObjectPixels> {
    scene
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let this = Surface::Object(i as u16);
            ObjectPixels {
                name: o.name.clone(),
                hit_pixels: frame.count(|_, s| s == this),
                valid_pixels: frame.count(|r, s| s == this && r == Return::Valid),
            }
        })
        .collect()
}

fn valid_depth_range(frame: &DepthFrame) -> Option<[f32; 2]> {
    frame
        .depth_m
        .iter()
        .filter(|z| z.is_finite())
        .fold(None, |range, &z| match range {
            None => Some([z, z]),
            Some([lo, hi]) => Some([lo.min(z), hi.max(z)]),
        })
}

/// The turbo colour map (polynomial approximation) at `t` in `[0, 1]`.
fn turbo(t: f64) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let poly = |c: [f64; 6]| {
        let v = c[0] + t * (c[1] + t * (c[2] + t * (c[3] + t * (c[4] + t * c[5]))));
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    };
    [
        poly([
            0.13572138,
            4.61539260,
            -42.66032258,
            132.13108234,
            -152.94239396,
            59.28637943,
        ]),
        poly([
            0.09140261,
            2.19418839,
            4.84296658,
            -14.18503333,
            4.27729857,
            2.82956604,
        ]),
        poly([
            0.10667330,
            12.64194608,
            -60.58204836,
            110.36276771,
            -89.90310912,
            27.34824973,
        ]),
    ]
}

/// Height (px) of the colour bar under the depth image.
const LEGEND_PX: u32 = 14;

/// Writes the frame's depth as a turbo-coloured PNG (black = no return) with a
/// near-to-far colour bar underneath, ticked every 0.1 m.
fn write_depth_png(path: &Path, frame: &DepthFrame) -> anyhow::Result<()> {
    let (width, height) = (frame.intrinsics.width_px, frame.intrinsics.height_px);
    let [near, far] = valid_depth_range(frame)
        .unwrap_or([0.0, 1.0])
        .map(f64::from);
    let span = (far - near).max(1e-6);
    let mut rgb = Vec::with_capacity(3 * (width * (height + LEGEND_PX)) as usize);
    for &z in &frame.depth_m {
        rgb.extend(if z.is_finite() {
            turbo((z as f64 - near) / span)
        } else {
            [0, 0, 0]
        });
    }
    for row in 0..LEGEND_PX {
        for u in 0..width {
            let depth = near + span * u as f64 / (width - 1).max(1) as f64;
            let next = near + span * (u + 1) as f64 / (width - 1).max(1) as f64;
            let tick = (depth * 10.0).floor() != (next * 10.0).floor() && row < LEGEND_PX / 2;
            rgb.extend(if row < 2 {
                [0, 0, 0]
            } else if tick {
                [255, 255, 255]
            } else {
                turbo(u as f64 / (width - 1).max(1) as f64)
            });
        }
    }
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height + LEGEND_PX);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(&rgb)?;
    }
    crate::fsio::write_atomically(path, &bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// What `cell camera record` reports.
#[derive(Debug, Serialize)]
struct RecordReport {
    dir: PathBuf,
    backend: String,
    frames: usize,
    records: usize,
    focal_px: f64,
    cx_px: f64,
    cy_px: f64,
    registration: Registration,
    /// Accelerometer counts of the first frame (x, y, z), when there is one.
    accel_counts: Option<[i16; 3]>,
    /// Fraction of pixels with depth in the first frame.
    valid_fraction: f64,
}

/// Colour of a simulated pixel: the table grey, objects in distinct colours.
fn surface_rgb(surface: Surface) -> [u8; 3] {
    const OBJECTS: [[u8; 3]; 4] = [[200, 40, 40], [40, 160, 60], [40, 80, 200], [220, 180, 40]];
    match surface {
        Surface::None => [0, 0, 0],
        Surface::Table => [150, 140, 120],
        Surface::Object(i) => OBJECTS[i as usize % OBJECTS.len()],
    }
}

/// A grey image of a cloud's depth (near bright), for backends without colour.
fn depth_grey(cloud: &crate::cloud::PointCloud) -> Vec<u8> {
    cloud
        .points
        .iter()
        .flat_map(|p| {
            let v = if p.z.is_finite() {
                (255.0 - 50.0 * p.z).clamp(0.0, 255.0) as u8
            } else {
                0
            };
            [v, v, v]
        })
        .collect()
}

/// The simulated camera's frames of `scene` as a Kinect with the configured focal
/// length sees them: rendered with the Kinect's image centre as principal point,
/// the depth encoded as raw 11-bit values, the accelerometer at rest under the
/// scene's mount, colour by surface.
pub(super) fn sim_frames(
    config: &CellConfig,
    scene: &Scene,
    base_from_camera: &Pose,
    frames: usize,
    seed: u64,
) -> Vec<RawFrame> {
    let (w, h) = (config.camera.width_px, config.camera.height_px);
    let registration = Registration::with_focal(config.camera.fx_px);
    let k = registration.intrinsics(w, h);
    let mut camera = DepthCamera::from_config(&config.camera, *base_from_camera);
    camera.intrinsics.fx_px = k.focal_px;
    camera.intrinsics.fy_px = k.focal_px;
    camera.intrinsics.cx_px = k.cx_px;
    camera.intrinsics.cy_px = k.cy_px;
    let accel = AccelCounts::at_rest(&expected_gravity_camera(base_from_camera));
    let progress = indicatif::ProgressBar::new(frames as u64);
    let out = (0..frames as u64)
        .map(|i| {
            let frame = camera.render(scene, seed + i);
            let (depth_raw, _) = cloud_to_raw(&frame.to_cloud(), &registration, w, h);
            progress.inc(1);
            RawFrame {
                depth_raw,
                rgb: Some(frame.surface.iter().flat_map(|&s| surface_rgb(s)).collect()),
                accel: Some(accel),
                registration,
                width: w,
                height: h,
            }
        })
        .collect();
    progress.finish_and_clear();
    out
}

/// The frame a Kinect would give of a backend's snapshot: its own raw frame, or
/// its cloud encoded with the snapshot's focal length.
fn snapshot_frame(config: &CellConfig, snapshot: Snapshot) -> RawFrame {
    if let Some(raw) = snapshot.raw {
        return raw;
    }
    let (w, h) = (config.camera.width_px, config.camera.height_px);
    let registration = Registration::with_focal(snapshot.intrinsics.fx);
    let (depth_raw, _) = cloud_to_raw(&snapshot.cloud, &registration, w, h);
    let rgb =
        (snapshot.cloud.len() == w as usize * h as usize).then(|| depth_grey(&snapshot.cloud));
    RawFrame {
        depth_raw,
        rgb,
        accel: snapshot
            .gravity_camera_m_s2
            .map(|g| AccelCounts::at_rest(&g)),
        registration,
        width: w,
        height: h,
    }
}

fn record(config_path: &Path, args: RecordArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.frames > 0, "--frames must be at least 1");
    let mut config = CellConfig::load(config_path)?;
    if let Some(b) = &args.backend {
        config.camera.backend = b.clone();
    }
    let (w, h) = (config.camera.width_px, config.camera.height_px);
    anyhow::ensure!(
        (w, h) == (FRAME_WIDTH, FRAME_HEIGHT),
        "camera.width_px/height_px = {w}x{h}: fakenect plays {FRAME_WIDTH}x{FRAME_HEIGHT} frames only"
    );
    let frames: Vec<RawFrame> = match config.camera.backend.as_str() {
        "sim" => {
            let scene = args.scene.as_deref().context(
                "--scene: the simulated camera needs a scene file to record (see cell camera render)",
            )?;
            let loaded = load_scene(scene, &config)?;
            sim_frames(
                &config,
                &loaded.scene,
                &loaded.base_from_camera,
                args.frames,
                args.seed,
            )
        }
        _ => {
            let mut backend = CameraBackend::from_config(&config, &args.run_dir)?;
            (0..args.frames as u64)
                .map(|i| {
                    backend
                        .snapshot(&config, &args.run_dir, i + 1)
                        .map(|s| snapshot_frame(&config, s))
                        .with_context(|| format!("frame {i}"))
                })
                .collect::<anyhow::Result<_>>()?
        }
    };
    let mut writer = FakenectWriter::create(&args.dir)?;
    writer.registration(&frames[0].registration)?;
    for (i, frame) in frames.iter().enumerate() {
        frame.append(&mut writer, 1.0 + i as f64 / 30.0, i as u32 * 2_000_000)?;
    }
    let first = &frames[0];
    let k = first.registration.intrinsics(w, h);
    let valid = first
        .depth_raw
        .iter()
        .filter(|&&r| r != crate::hw::kinect::registration::DEPTH_NO_VALUE)
        .count();
    let report = RecordReport {
        dir: args.dir.clone(),
        backend: config.camera.backend.clone(),
        frames: frames.len(),
        records: writer.records(),
        focal_px: k.focal_px,
        cx_px: k.cx_px,
        cy_px: k.cy_px,
        registration: first.registration,
        accel_counts: first.accel.map(|a| [a.x, a.y, a.z]),
        valid_fraction: valid as f64 / first.depth_raw.len().max(1) as f64,
    };
    super::emit(args.json, &report, |r| {
        format!(
            "{}: {} frames ({} records) from the {} camera, focal {:.1} px, {:.1} % valid depth\n\
             play it: LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/fakenect FAKENECT_PATH={} <program>\n",
            r.dir.display(),
            r.frames,
            r.records,
            r.backend,
            r.focal_px,
            100.0 * r.valid_fraction,
            r.dir.display()
        )
    })?;
    Ok(ExitCode::SUCCESS)
}
