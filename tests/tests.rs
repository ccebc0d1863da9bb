//! Integration and hardware-in-loop tests, built as one binary (one link step).

mod calib;
mod camera;
mod can;
mod category;
mod fri;
mod grasp;
mod ipc;
mod objects;
mod quality;
mod shipped_files;
mod trial;
