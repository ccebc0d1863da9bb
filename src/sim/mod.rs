//! The simulated world: scenes of a table and object meshes, and a depth camera
//! that renders them with a Kinect-like error model.

pub mod camera;
pub mod scene;
