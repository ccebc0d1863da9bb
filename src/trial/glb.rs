//! The trial's scene as binary glTF (`.glb`), for any glTF viewer.
//!
//! The same [`TrialScene`] the picture draws: one mesh per solid (flat normals, a
//! material per [`Part`]: the best model blue, the others faint and blended, the
//! hand orange, the table), the segmented cloud as points (grey) and each contact
//! as a small red ball. Everything is written in the robot base frame (z up) under
//! one root node that turns it into glTF's y-up convention. The document is built
//! with `gltf-json` and framed by the `gltf` crate's GLB writer.

use super::picture::{Part, Solid, TrialScene, CLOUD_COLOUR, CONTACT_COLOUR};
use super::TrialError;
use gltf::json;
use json::validation::Checked::Valid;
use json::validation::USize64;
use nalgebra::Point3;
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

/// Radius of the balls marking contacts (m).
const CONTACT_RADIUS_M: f64 = 0.004;

/// Builds the document and its binary buffer.
struct Builder {
    root: json::Root,
    bin: Vec<u8>,
    buffer: json::Index<json::Buffer>,
    materials: BTreeMap<&'static str, json::Index<json::Material>>,
    nodes: Vec<json::Index<json::Node>>,
}

fn rgba(colour: [u8; 3], alpha: f32) -> [f32; 4] {
    let c = colour.map(|v| v as f32 / 255.0);
    [c[0], c[1], c[2], alpha]
}

impl Builder {
    fn new() -> Builder {
        let mut root = json::Root::default();
        let buffer = root.push(json::Buffer {
            byte_length: USize64(0),
            extensions: None,
            extras: Default::default(),
            name: None,
            uri: None,
        });
        Builder {
            root,
            bin: Vec::new(),
            buffer,
            materials: BTreeMap::new(),
            nodes: Vec::new(),
        }
    }

    fn material(&mut self, name: &'static str, rgba: [f32; 4]) -> json::Index<json::Material> {
        if let Some(m) = self.materials.get(name) {
            return *m;
        }
        let blend = rgba[3] < 1.0;
        let m = self.root.push(json::Material {
            alpha_mode: Valid(if blend {
                json::material::AlphaMode::Blend
            } else {
                json::material::AlphaMode::Opaque
            }),
            double_sided: true,
            name: Some(name.to_string()),
            pbr_metallic_roughness: json::material::PbrMetallicRoughness {
                base_color_factor: json::material::PbrBaseColorFactor(rgba),
                metallic_factor: json::material::StrengthFactor(0.0),
                roughness_factor: json::material::StrengthFactor(0.8),
                ..Default::default()
            },
            ..Default::default()
        });
        self.materials.insert(name, m);
        m
    }

    /// Appends `values` (f32 triples) to the buffer as one view and accessor.
    fn vec3_accessor(&mut self, values: &[[f32; 3]], bounds: bool) -> json::Index<json::Accessor> {
        let offset = self.bin.len();
        for v in values {
            for x in v {
                self.bin.extend_from_slice(&x.to_le_bytes());
            }
        }
        let length = self.bin.len() - offset;
        let view = self.root.push(json::buffer::View {
            buffer: self.buffer,
            byte_length: USize64::from(length),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            extensions: None,
            extras: Default::default(),
            name: None,
            target: Some(Valid(json::buffer::Target::ArrayBuffer)),
        });
        let (min, max) = if bounds {
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for v in values {
                for k in 0..3 {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
            (
                Some(json::Value::from(lo.to_vec())),
                Some(json::Value::from(hi.to_vec())),
            )
        } else {
            (None, None)
        };
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: Some(USize64(0)),
            count: USize64::from(values.len()),
            component_type: Valid(json::accessor::GenericComponentType(
                json::accessor::ComponentType::F32,
            )),
            extensions: None,
            extras: Default::default(),
            type_: Valid(json::accessor::Type::Vec3),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    /// One node with one mesh of one primitive.
    fn node(
        &mut self,
        name: &str,
        positions: &[[f32; 3]],
        normals: Option<&[[f32; 3]]>,
        mode: json::mesh::Mode,
        material: json::Index<json::Material>,
    ) {
        if positions.is_empty() {
            return;
        }
        let mut attributes = BTreeMap::new();
        attributes.insert(
            Valid(json::mesh::Semantic::Positions),
            self.vec3_accessor(positions, true),
        );
        if let Some(normals) = normals {
            attributes.insert(
                Valid(json::mesh::Semantic::Normals),
                self.vec3_accessor(normals, false),
            );
        }
        let mesh = self.root.push(json::Mesh {
            extensions: None,
            extras: Default::default(),
            name: Some(name.to_string()),
            primitives: vec![json::mesh::Primitive {
                attributes,
                extensions: None,
                extras: Default::default(),
                indices: None,
                material: Some(material),
                mode: Valid(mode),
                targets: None,
            }],
            weights: None,
        });
        let node = self.root.push(json::Node {
            mesh: Some(mesh),
            name: Some(name.to_string()),
            ..Default::default()
        });
        self.nodes.push(node);
    }

    fn solid(&mut self, solid: &Solid) {
        let (name, alpha) = match solid.part {
            Part::Table => ("table", 1.0),
            Part::BestModel => ("best-model", 1.0),
            Part::OtherModel => ("other-model", solid.part.opacity() as f32),
            Part::Hand => ("hand", 1.0),
        };
        let material = self.material(name, rgba(solid.part.colour(), alpha));
        let mut positions = Vec::with_capacity(3 * solid.triangles.len());
        let mut normals = Vec::with_capacity(3 * solid.triangles.len());
        for [a, b, c] in &solid.triangles {
            let n = (b - a).cross(&(c - a));
            let Some(n) = n.try_normalize(0.0) else {
                continue;
            };
            for p in [a, b, c] {
                positions.push(f32x3(p));
                normals.push([n.x as f32, n.y as f32, n.z as f32]);
            }
        }
        self.node(
            &solid.name,
            &positions,
            Some(&normals),
            json::mesh::Mode::Triangles,
            material,
        );
    }

    fn finish(mut self) -> Result<Vec<u8>, String> {
        // Base frame (z up) to glTF (y up): -90 degrees about x.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let root_node = self.root.push(json::Node {
            children: Some(self.nodes.clone()),
            name: Some("robot_base".to_string()),
            rotation: Some(json::scene::UnitQuaternion([-h, 0.0, 0.0, h])),
            ..Default::default()
        });
        let scene = self.root.push(json::Scene {
            extensions: None,
            extras: Default::default(),
            name: Some("trial".to_string()),
            nodes: vec![root_node],
        });
        self.root.scene = Some(scene);
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        self.root.buffers[0].byte_length = USize64::from(self.bin.len());
        let text = json::serialize::to_string(&self.root).map_err(|e| e.to_string())?;
        let glb = gltf::binary::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                // `to_writer` computes the length itself.
                length: 0,
            },
            json: Cow::Owned(text.into_bytes()),
            bin: (!self.bin.is_empty()).then_some(Cow::Owned(self.bin)),
        };
        glb.to_vec().map_err(|e| e.to_string())
    }
}

fn f32x3(p: &Point3<f64>) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// The scene as GLB bytes.
pub fn to_glb(scene: &TrialScene, path_for_errors: &Path) -> Result<Vec<u8>, TrialError> {
    let mut b = Builder::new();
    for solid in &scene.solids {
        b.solid(solid);
    }
    let cloud: Vec<[f32; 3]> = scene.cloud_m.iter().map(f32x3).collect();
    let grey = b.material("cloud", rgba(CLOUD_COLOUR, 1.0));
    b.node(
        "segmented-cloud",
        &cloud,
        None,
        json::mesh::Mode::Points,
        grey,
    );
    let ball = parry3d_f64::shape::SharedShape::ball(CONTACT_RADIUS_M);
    for (i, c) in scene.contacts_m.iter().enumerate() {
        let pose = crate::geometry::Pose::translation(c.x, c.y, c.z);
        if let Some(mut solid) =
            Solid::from_shape(&format!("contact-{i}"), Part::Hand, &ball, &pose)
        {
            solid.name = format!("contact-{i}");
            let red = b.material("contact", rgba(CONTACT_COLOUR, 1.0));
            let (positions, normals): (Vec<_>, Vec<_>) = solid
                .triangles
                .iter()
                .flat_map(|t| {
                    let n = (t[1] - t[0]).cross(&(t[2] - t[0])).normalize();
                    t.iter()
                        .map(move |p| (f32x3(p), [n.x as f32, n.y as f32, n.z as f32]))
                })
                .unzip();
            b.node(
                &solid.name,
                &positions,
                Some(&normals),
                json::mesh::Mode::Triangles,
                red,
            );
        }
    }
    b.finish().map_err(|detail| TrialError::Glb {
        path: path_for_errors.to_path_buf(),
        detail,
    })
}

/// Writes the scene as GLB to `path` (atomically).
pub fn write_glb(scene: &TrialScene, path: &Path) -> Result<(), TrialError> {
    let bytes = to_glb(scene, path)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        crate::fsio::create_dir_all(dir)?;
    }
    Ok(crate::fsio::write(path, &bytes)?)
}
