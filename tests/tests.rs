//! Integration and hardware-in-loop tests, built as one binary (one link step).

mod calib;
mod camera;
mod can;
mod fri;
mod ipc;
mod objects;
mod plan;
mod quality;
mod shipped_files;
mod trial;
