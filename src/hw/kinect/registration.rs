//! The Kinect v1's depth model: raw 11-bit disparity to depth, and the pinhole
//! intrinsics of the depth image, both from the device's registration data (its
//! "zero plane" parameters and constant shift), with libfreenect's formulas.
//!
//! libfreenect (`registration.c`) converts a raw value `r` to depth as
//! `x = (r - 4 c) / 4 - 0.375`, `m = x p`, `z_mm = 10 (m D / (b - m) + D)` with the
//! constant shift `c`, the reference pixel size `p`, the reference distance `D` and
//! the emitter-to-IR-camera distance `b`; and projects a pixel `(u, v)` at depth
//! `z` to `x = (u - W/2) 2 p z / D` (`freenect_camera_to_world`), so the focal
//! length is `D / (2 p)` px and the principal point the image centre. Here the
//! same formulas run in `f64` without rounding to whole millimetres.

use serde::{Deserialize, Serialize};

/// Raw value of a pixel without depth (11-bit modes).
pub const DEPTH_NO_VALUE: u16 = 2047;

/// Number of raw 11-bit values.
pub const RAW_VALUES: usize = 2048;

/// Width of the medium-resolution (VGA) depth and colour images (px).
pub const FRAME_WIDTH: u32 = 640;

/// Height of the medium-resolution (VGA) depth and colour images (px).
pub const FRAME_HEIGHT: u32 = 480;

/// libfreenect's `parameter_coefficient` (raw values per disparity pixel step).
const PARAMETER_COEFFICIENT: f64 = 4.0;
/// libfreenect's `S2D_CONST_OFFSET`.
const CONST_OFFSET: f64 = 0.375;
/// libfreenect's `shift_scale` (the zero-plane lengths are in tenths of the result).
const SHIFT_SCALE: f64 = 10.0;

/// The device's zero-plane data (`freenect_zero_plane_info`), in the device's units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZeroPlane {
    /// Distance between the IR camera and the IR emitter (cm; the baseline).
    pub dcmos_emitter_dist: f64,
    /// Distance between the IR camera and the RGB camera (cm).
    pub dcmos_rcmos_dist: f64,
    /// The reference plane's distance (libfreenect's units: tenths of the depth
    /// unit, so 120 means a 1.2 m reference plane).
    pub reference_distance: f64,
    /// Size of one pixel on the reference plane (same units as the distance).
    pub reference_pixel_size: f64,
}

/// What converts a raw frame to metric depth and back-projects it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Registration {
    /// The zero-plane data.
    pub zero_plane: ZeroPlane,
    /// The constant shift of the raw values.
    pub const_shift: f64,
}

/// Pinhole intrinsics of a Kinect depth image (px).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct KinectIntrinsics {
    /// Focal length (px), the same along x and y.
    pub focal_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
}

/// A registration value that describes no usable sensor.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{field} = {value}: {problem}")]
pub struct BadRegistration {
    /// The field (`zero_plane.reference_pixel_size`, `const_shift`, ...).
    pub field: &'static str,
    /// Its value.
    pub value: f64,
    /// What is wrong with it.
    pub problem: &'static str,
}

impl Registration {
    /// The values libfreenect's sources and OpenNI give for a typical Kinect v1:
    /// a 7.5 cm baseline, 2.3 cm to the RGB camera, a 1.2 m reference plane with
    /// 0.1042 pixel size (focal length 575.8 px) and a constant shift of 200.
    pub fn nominal() -> Registration {
        Registration {
            zero_plane: ZeroPlane {
                dcmos_emitter_dist: 7.5,
                dcmos_rcmos_dist: 2.3,
                reference_distance: 120.0,
                reference_pixel_size: 0.1042,
            },
            const_shift: 200.0,
        }
    }

    /// The nominal registration with the reference pixel size chosen so that the
    /// focal length is `focal_px` (how a recording of another camera describes it).
    pub fn with_focal(focal_px: f64) -> Registration {
        let mut r = Registration::nominal();
        r.zero_plane.reference_pixel_size = r.zero_plane.reference_distance / (2.0 * focal_px);
        r
    }

    /// Checks that the values describe a usable sensor (positive, finite).
    pub fn validate(&self) -> Result<(), BadRegistration> {
        let z = &self.zero_plane;
        for (field, value) in [
            ("zero_plane.dcmos_emitter_dist", z.dcmos_emitter_dist),
            ("zero_plane.reference_distance", z.reference_distance),
            ("zero_plane.reference_pixel_size", z.reference_pixel_size),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(BadRegistration {
                    field,
                    value,
                    problem: "must be finite and > 0",
                });
            }
        }
        if !self.const_shift.is_finite() {
            return Err(BadRegistration {
                field: "const_shift",
                value: self.const_shift,
                problem: "not finite",
            });
        }
        Ok(())
    }

    /// The depth image's intrinsics for a `width` x `height` image (as
    /// `freenect_camera_to_world`: focal `D / (2 p)`, centre `(W/2, H/2)`).
    pub fn intrinsics(&self, width: u32, height: u32) -> KinectIntrinsics {
        KinectIntrinsics {
            focal_px: self.zero_plane.reference_distance
                / (2.0 * self.zero_plane.reference_pixel_size),
            cx_px: f64::from(width / 2),
            cy_px: f64::from(height / 2),
        }
    }

    /// Depth (m) of raw value `raw`; NaN for [`DEPTH_NO_VALUE`] and for values that
    /// do not give a positive depth.
    pub fn depth_m(&self, raw: u16) -> f64 {
        if raw >= DEPTH_NO_VALUE {
            return f64::NAN;
        }
        let z = &self.zero_plane;
        let x = (f64::from(raw) - PARAMETER_COEFFICIENT * self.const_shift) / PARAMETER_COEFFICIENT
            - CONST_OFFSET;
        let metric = x * z.reference_pixel_size;
        let denominator = z.dcmos_emitter_dist - metric;
        if denominator <= 0.0 {
            return f64::NAN;
        }
        let mm = SHIFT_SCALE * (metric * z.reference_distance / denominator + z.reference_distance);
        if mm > 0.0 {
            mm * 1e-3
        } else {
            f64::NAN
        }
    }

    /// The table of [`Registration::depth_m`] for every raw value (m, `f32`).
    pub fn depth_table_m(&self) -> Vec<f32> {
        (0..RAW_VALUES as u16)
            .map(|raw| self.depth_m(raw) as f32)
            .collect()
    }

    /// The raw value whose depth is nearest `depth_m` (the inverse of
    /// [`Registration::depth_m`]); [`DEPTH_NO_VALUE`] when the depth is not finite,
    /// not positive or outside what 11 bits encode.
    pub fn raw_from_depth_m(&self, depth_m: f64) -> u16 {
        if !(depth_m.is_finite() && depth_m > 0.0) {
            return DEPTH_NO_VALUE;
        }
        let z = &self.zero_plane;
        // z_mm = 10 D b / (b - m)  =>  m = b (1 - 10 D / z_mm).
        let metric =
            z.dcmos_emitter_dist * (1.0 - SHIFT_SCALE * z.reference_distance / (depth_m * 1e3));
        let x = metric / z.reference_pixel_size;
        let raw =
            PARAMETER_COEFFICIENT * (x + CONST_OFFSET) + PARAMETER_COEFFICIENT * self.const_shift;
        let raw = raw.round();
        if (0.0..f64::from(DEPTH_NO_VALUE)).contains(&raw) {
            raw as u16
        } else {
            DEPTH_NO_VALUE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_focal_length_and_reference_plane_match_libfreenect() {
        let r = Registration::nominal();
        let k = r.intrinsics(640, 480);
        assert!((k.focal_px - 575.816).abs() < 1e-2, "{k:?}");
        assert_eq!((k.cx_px, k.cy_px), (320.0, 240.0));
        // The raw value of zero metric offset lies on the 1.2 m reference plane.
        let raw_ref = (4.0 * (0.375 + 200.0)) as u16; // 801.5 -> between 801 and 802
        let z = r.depth_m(raw_ref);
        assert!((z - 1.2).abs() < 0.005, "{z}");
        assert!(r.depth_m(DEPTH_NO_VALUE).is_nan());
    }

    #[test]
    fn depth_round_trips_through_raw_within_half_a_step() {
        let r = Registration::with_focal(525.0);
        assert!((r.intrinsics(640, 480).focal_px - 525.0).abs() < 1e-9);
        for mm in (500..4000).step_by(37) {
            let z = f64::from(mm) * 1e-3;
            let raw = r.raw_from_depth_m(z);
            assert_ne!(raw, DEPTH_NO_VALUE, "{z}");
            let back = r.depth_m(raw);
            let step = r.depth_m(raw + 1) - r.depth_m(raw);
            assert!(
                step > 0.0 && (back - z).abs() <= 0.5 * step + 1e-9,
                "{z} {back} {step}"
            );
        }
        assert_eq!(r.raw_from_depth_m(f64::NAN), DEPTH_NO_VALUE);
        assert_eq!(r.raw_from_depth_m(-1.0), DEPTH_NO_VALUE);
        // Nearer than the 11 bits reach.
        assert_eq!(r.raw_from_depth_m(0.1), DEPTH_NO_VALUE);
    }

    #[test]
    fn bad_registration_is_named() {
        let mut r = Registration::nominal();
        r.zero_plane.reference_pixel_size = 0.0;
        let e = r.validate().unwrap_err();
        assert_eq!(e.field, "zero_plane.reference_pixel_size");
        assert!(e.to_string().contains("reference_pixel_size"), "{e}");
    }
}
