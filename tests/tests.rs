//! Integration and hardware-in-loop tests, built as one binary (one link step).

mod calib;
mod calib_collect;
mod camera;
mod can;
mod category;
mod cell;
mod cli_output;
mod common;
mod eval;
mod execute;
mod fri;
mod fuzz_regressions;
mod grasp;
mod ipc;
#[cfg(feature = "kinect")]
mod kinect;
mod layers;
mod objects;
mod perceive;
mod picture;
mod plan;
mod quality;
mod serve;
mod shipped_files;
mod trial;
