//! Kinect frames to organised clouds and back: the conversion the `kinect` camera
//! backend runs on every frame, and the projection `cell camera record` uses to
//! write any backend's cloud as a Kinect depth frame.

use super::registration::{KinectIntrinsics, Registration, DEPTH_NO_VALUE};
use crate::cloud::PointCloud;
use nalgebra::Point3;

/// How the values of a depth frame encode depth.
#[derive(Debug, Clone)]
pub enum DepthEncoding {
    /// Raw 11-bit disparity, converted with the device's table (m per raw value,
    /// [`Registration::depth_table_m`]).
    Disparity11 {
        /// Depth (m) of each raw value; NaN for none.
        table_m: Vec<f32>,
    },
    /// Millimetres, 0 for none (libfreenect's `FREENECT_DEPTH_REGISTERED`).
    Millimetres,
}

/// Back-projects a `width` x `height` depth frame into an organised cloud in the
/// camera optical frame (NaN where there is no depth or it lies outside
/// `[min_m, max_m]`).
pub fn depth_to_cloud(
    depth: &[u16],
    width: u32,
    encoding: &DepthEncoding,
    intrinsics: &KinectIntrinsics,
    range_m: [f32; 2],
) -> PointCloud {
    let w = width as usize;
    let height = depth.len().checked_div(w).unwrap_or(0);
    let inv_f = (1.0 / intrinsics.focal_px) as f32;
    let (cx, cy) = (intrinsics.cx_px as f32, intrinsics.cy_px as f32);
    let missing = Point3::new(f32::NAN, f32::NAN, f32::NAN);
    let depth_of = |raw: u16| -> f32 {
        match encoding {
            DepthEncoding::Disparity11 { table_m } => {
                table_m.get(raw as usize).copied().unwrap_or(f32::NAN)
            }
            DepthEncoding::Millimetres if raw == 0 => f32::NAN,
            DepthEncoding::Millimetres => f32::from(raw) * 1e-3,
        }
    };
    let mut points = Vec::with_capacity(w * height);
    for v in 0..height {
        let y_ray = (v as f32 - cy) * inv_f;
        for (u, &raw) in depth[v * w..(v + 1) * w].iter().enumerate() {
            let z = depth_of(raw);
            if z >= range_m[0] && z <= range_m[1] {
                let x_ray = (u as f32 - cx) * inv_f;
                points.push(Point3::new(x_ray * z, y_ray * z, z));
            } else {
                points.push(missing);
            }
        }
    }
    PointCloud {
        points,
        normals: None,
        width,
        height: height as u32,
    }
}

/// The raw 11-bit frame a Kinect with `registration` would see of `cloud` (camera
/// optical frame). An organised cloud of the image's size keeps its pixel grid
/// (each point's depth encoded in place); any other cloud has every valid point
/// projected into the `width` x `height` image with the registration's
/// intrinsics, the nearest kept where several fall on one pixel. Pixels without
/// a point get [`DEPTH_NO_VALUE`]. Also returns, per pixel, the index of the
/// point kept (`u32::MAX` for none).
pub fn cloud_to_raw(
    cloud: &PointCloud,
    registration: &Registration,
    width: u32,
    height: u32,
) -> (Vec<u16>, Vec<u32>) {
    let n = width as usize * height as usize;
    if cloud.width == width && cloud.height == height && cloud.points.len() == n {
        return cloud
            .points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let raw = registration.raw_from_depth_m(f64::from(p.z));
                (
                    raw,
                    if raw == DEPTH_NO_VALUE {
                        u32::MAX
                    } else {
                        i as u32
                    },
                )
            })
            .unzip();
    }
    let k = registration.intrinsics(width, height);
    let mut nearest = vec![f64::INFINITY; n];
    let mut source = vec![u32::MAX; n];
    for (i, p) in cloud.points.iter().enumerate() {
        let z = f64::from(p.z);
        if !(p.x.is_finite() && p.y.is_finite() && z.is_finite() && z > 0.0) {
            continue;
        }
        let u = (k.focal_px * f64::from(p.x) / z + k.cx_px).round();
        let v = (k.focal_px * f64::from(p.y) / z + k.cy_px).round();
        if !(u >= 0.0 && v >= 0.0 && u < f64::from(width) && v < f64::from(height)) {
            continue;
        }
        let pixel = v as usize * width as usize + u as usize;
        if z < nearest[pixel] {
            nearest[pixel] = z;
            source[pixel] = i as u32;
        }
    }
    let raw = nearest
        .iter()
        .map(|&z| {
            if z.is_finite() {
                registration.raw_from_depth_m(z)
            } else {
                DEPTH_NO_VALUE
            }
        })
        .collect();
    (raw, source)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_round_trips_through_raw_frames() {
        let reg = Registration::with_focal(525.0);
        let k = reg.intrinsics(64, 48);
        // A plane 1.0 m away seen by a 64 x 48 camera with these intrinsics.
        let mut points = Vec::new();
        for v in 0..48 {
            for u in 0..64 {
                let z = 1.0f32;
                points.push(Point3::new(
                    (u as f32 - k.cx_px as f32) / k.focal_px as f32 * z,
                    (v as f32 - k.cy_px as f32) / k.focal_px as f32 * z,
                    z,
                ));
            }
        }
        points[5] = Point3::new(f32::NAN, f32::NAN, f32::NAN);
        let cloud = PointCloud {
            points,
            normals: None,
            width: 64,
            height: 48,
        };
        let (raw, source) = cloud_to_raw(&cloud, &reg, 64, 48);
        assert_eq!(raw[5], DEPTH_NO_VALUE);
        assert_eq!(source[7], 7);
        // The same points unorganised are projected onto the same pixels.
        let loose = PointCloud::from_points(cloud.points.clone());
        assert_eq!(cloud_to_raw(&loose, &reg, 64, 48).0, raw);
        let back = depth_to_cloud(
            &raw,
            64,
            &DepthEncoding::Disparity11 {
                table_m: reg.depth_table_m(),
            },
            &k,
            [0.5, 4.0],
        );
        assert_eq!((back.width, back.height), (64, 48));
        assert!(back.points[5].z.is_nan());
        for (a, b) in cloud.points.iter().zip(&back.points).skip(6) {
            // Within half a raw step (about 1.4 mm at 1 m).
            assert!((a - b).norm() < 2e-3, "{a:?} {b:?}");
        }
        let mm: Vec<u16> = vec![0, 1000, 5000];
        let c = depth_to_cloud(&mm, 3, &DepthEncoding::Millimetres, &k, [0.5, 4.0]);
        assert!(c.points[0].z.is_nan() && c.points[2].z.is_nan());
        assert_eq!(c.points[1].z, 1.0);
    }
}
