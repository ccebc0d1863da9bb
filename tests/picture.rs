//! Trial pictures and the 3-D export (issue 23): a campaign trial in the simulated
//! cell gets its picture named in its log row; `cell trial show` writes a PNG and a
//! GLB, and the GLB is read back and validated by the `gltf` crate.

use crate::common::cell;
use graspcell::fsio::TempDir;
use graspcell::trial::TrialLog;
use std::path::Path;

/// Decodes a PNG: (width, height, RGB bytes).
fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// Pixels of a colour class in an RGB image.
fn count(rgb: &[u8], pred: impl Fn([u8; 3]) -> bool) -> usize {
    rgb.chunks_exact(3)
        .filter(|c| pred([c[0], c[1], c[2]]))
        .count()
}

#[test]
fn a_campaign_trial_has_a_picture_and_trial_show_writes_png_and_a_valid_glb() {
    let dir = TempDir::new("picture-campaign").unwrap();
    let log_path = dir.join("campaign.sqlite");
    let run_dir = dir.join("run");
    let (ok, out, err) = cell(&[
        "campaign",
        "--instances",
        "1",
        "--task",
        "top",
        "--placements",
        "1",
        "--methods",
        "laplace",
        "--log",
        log_path.to_str().unwrap(),
        "--run-dir",
        run_dir.to_str().unwrap(),
    ]);
    assert!(ok, "campaign failed:\n{out}\n{err}");
    let log = TrialLog::open_existing(&log_path).unwrap();
    let rows = log.trials().unwrap();
    // One trial, and one more row for each run again after a link fault (a
    // loaded host can drop the FRI link); the last row is the counted one.
    let repeats = rows.len() - 1;
    assert!(
        repeats == 0 || out.contains(&format!("{repeats} trial(s) run again after a link fault")),
        "{} rows for one trial:\n{out}",
        rows.len()
    );
    let row = rows.last().expect("the trial's row");
    let id = row.id;
    assert!(row.trial.campaign_id.is_some());

    // The log stage drew the picture and named it in the row.
    let named = log
        .picture_path(id)
        .unwrap()
        .expect("picture named in the row");
    let (w, h, rgb) = read_png(&named);
    assert!(w >= 960 && h >= 360, "{w}x{h}");
    let blue = count(&rgb, |c| c[2] > 150 && c[2] as i32 > c[0] as i32 + 80);
    let orange = count(&rgb, |c| {
        c[0] > 150 && c[0] as i32 > c[2] as i32 + 100 && c[1] > 60
    });
    assert!(blue > 1000, "best model drawn: {blue} blue pixels");
    assert!(orange > 1000, "hand drawn: {orange} orange pixels");

    // `cell trial show` draws the same trial and exports it.
    let png_path = dir.join("show.png");
    let glb_path = dir.join("show.glb");
    let (ok, out, err) = cell(&[
        "trial",
        "show",
        &id.to_string(),
        "--log",
        log_path.to_str().unwrap(),
        "--png",
        png_path.to_str().unwrap(),
        "--glb",
        glb_path.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "trial show failed:\n{out}\n{err}");
    let shown: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(shown["trial_id"], id);
    assert!(shown["cloud_points"].as_u64().unwrap() > 100, "{shown}");
    let (sw, sh, shown_rgb) = read_png(&png_path);
    assert_eq!((sw, sh), (w, h));
    assert_eq!(shown_rgb, rgb, "show draws what the cell drew");

    // The GLB parses and validates with the gltf reader, and holds the scene.
    let bytes = std::fs::read(&glb_path).unwrap();
    let gltf = gltf::Gltf::from_slice(&bytes).expect("a valid glTF 2.0 binary");
    let names: Vec<String> = gltf
        .nodes()
        .filter_map(|n| n.name().map(str::to_string))
        .collect();
    for want in ["table", "segmented-cloud", "bh_palm", "robot_base"] {
        assert!(
            names.iter().any(|n| n == want),
            "no node {want} in {names:?}"
        );
    }
    let contacts = names.iter().filter(|n| n.starts_with("contact-")).count();
    assert_eq!(contacts as u64, shown["contacts"].as_u64().unwrap());
    let materials: Vec<String> = gltf
        .materials()
        .filter_map(|m| m.name().map(str::to_string))
        .collect();
    for want in ["best-model", "hand", "table", "cloud"] {
        assert!(materials.iter().any(|m| m == want), "{materials:?}");
    }
    let blob = gltf.blob.as_ref().expect("binary chunk");
    for mesh in gltf.meshes() {
        for prim in mesh.primitives() {
            let pos = prim.get(&gltf::Semantic::Positions).expect("positions");
            let view = pos.view().unwrap();
            assert!(view.offset() + view.length() <= blob.len());
            assert!(pos.count() > 0);
        }
    }

    // Bad input: an unknown trial and a missing output are clear errors.
    let (ok, _, err) = cell(&[
        "trial",
        "show",
        "999",
        "--log",
        log_path.to_str().unwrap(),
        "--png",
        png_path.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("no trial with id 999"), "{err}");
    let (ok, _, err) = cell(&[
        "trial",
        "show",
        &id.to_string(),
        "--log",
        log_path.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("--png"), "{err}");

    // Without `show`, `cell trial` still takes a trial request (checked before it
    // looks for a running cell).
    let (ok, _, err) = cell(&[
        "trial",
        "--category",
        "mug",
        "--task",
        "top",
        "--timeout-s",
        "0",
    ]);
    assert!(!ok && err.contains("--timeout-s 0"), "{err}");

    // The static report carries the charts and the trial's picture.
    let html_dir = dir.join("html");
    let (ok, out, err) = cell(&[
        "report",
        "--log",
        log_path.to_str().unwrap(),
        "--html",
        html_dir.to_str().unwrap(),
    ]);
    assert!(ok, "report --html failed:\n{out}\n{err}");
    let index = std::fs::read_to_string(html_dir.join("index.html")).unwrap();
    let picture = format!("pictures/{id}.png");
    assert!(
        index.contains(&picture) && index.contains("outcomes.png"),
        "{index}"
    );
    assert!(index.contains("id=\"table2\""));
    assert_eq!(read_png(&html_dir.join(&picture)).2, rgb);
    read_png(&html_dir.join("failure_causes.png"));
}
