//! Skinned glTF 2.0 binaries (`.glb`): a mesh in its bind pose with vertex colours and four joint weights
//! per vertex, the skeleton as a node hierarchy with inverse bind matrices, and a keyframe animation, so
//! that Blender, three.js, Unity and Unreal play the avatar.
//!
//! Frames: the mesh is in the skeleton's bind space (anerf's canonical T-pose, metres); joint nodes hold
//! each joint's local transform (joint 0: the frame's global placement composed with the root rotation),
//! under one static `capture` node whose rotation turns the capture's world into glTF's Y-up world.
//! Skinning then gives `capture · Σ_k w_k A_k x` with `A_k` anerf's bone transforms.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

use glam::{Quat, Vec3};
use gltf::json;
use json::validation::Checked::Valid;
use json::validation::USize64;

use crate::error::EvalError;

/// Joint weights kept per vertex (glTF's `JOINTS_0` / `WEIGHTS_0`).
pub const WEIGHTS_PER_VERTEX: usize = 4;

/// A mesh in its bind pose with what skinning it needs.
#[derive(Debug, Clone, Copy)]
pub struct SkinnedMesh<'a> {
    /// Bind-pose (canonical) positions, metres.
    pub positions: &'a [Vec3],
    pub faces: &'a [[u32; 3]],
    /// Per-vertex colour in `[0, 1]`, sRGB-encoded like the images it was learned from; the file stores
    /// it linear, as glTF's `COLOR_0` is defined.
    pub colors: &'a [[f32; 3]],
    /// Per vertex, [`WEIGHTS_PER_VERTEX`] joints and their weights (summing to 1).
    pub joints: &'a [[u16; WEIGHTS_PER_VERTEX]],
    pub weights: &'a [[f32; WEIGHTS_PER_VERTEX]],
    /// Rest positions of the joints in bind space (metres) and each joint's parent (parents precede
    /// their children).
    pub rest_joints: &'a [Vec3],
    pub parents: &'a [Option<usize>],
}

/// One animation frame: every joint's local rotation, and joint 0's translation (its parent is the
/// capture node: world placement of the root joint).
#[derive(Debug, Clone, PartialEq)]
pub struct JointFrame {
    pub root_translation: Vec3,
    pub rotations: Vec<Quat>,
}

/// Keyframes at `fps` frames per second.
#[derive(Debug, Clone, PartialEq)]
pub struct JointAnimation {
    pub name: String,
    pub fps: f32,
    pub frames: Vec<JointFrame>,
}

/// The four largest weights of each row of `weights` (`V × k`, rows summing to 1), renormalised: the
/// joints and weights glTF stores. Unused slots get joint 0 with weight 0.
pub fn top_weights(
    weights: &[f32],
    k: usize,
) -> (
    Vec<[u16; WEIGHTS_PER_VERTEX]>,
    Vec<[f32; WEIGHTS_PER_VERTEX]>,
) {
    weights
        .chunks_exact(k)
        .map(|row| {
            let mut order: Vec<usize> = (0..k).collect();
            order.sort_by(|&a, &b| row[b].total_cmp(&row[a]));
            let mut joints = [0u16; WEIGHTS_PER_VERTEX];
            let mut w = [0f32; WEIGHTS_PER_VERTEX];
            for (slot, &j) in order.iter().take(WEIGHTS_PER_VERTEX).enumerate() {
                if row[j] > 0.0 {
                    joints[slot] = j as u16;
                    w[slot] = row[j];
                }
            }
            let sum: f32 = w.iter().sum();
            if sum > 0.0 {
                w.iter_mut().for_each(|x| *x /= sum);
            } else {
                w[0] = 1.0;
            }
            (joints, w)
        })
        .unzip()
}

/// Writes `mesh` with `animation` as a binary glTF at `path` (atomically); `capture_to_gltf` turns the
/// capture's world into glTF's Y-up one.
pub fn write_glb(
    path: &Path,
    mesh: &SkinnedMesh,
    animation: &JointAnimation,
    capture_to_gltf: Quat,
) -> Result<(), EvalError> {
    let bytes =
        glb_bytes(mesh, animation, capture_to_gltf).map_err(|detail| EvalError::InvalidInput {
            what: "glTF export",
            detail,
        })?;
    Ok(anerf_data::atomic::write_bytes(path, &bytes)?)
}

/// The binary buffer under construction and the accessors into it.
struct Builder {
    root: json::Root,
    bin: Vec<u8>,
    buffer: json::Index<json::Buffer>,
}

impl Builder {
    fn new() -> Self {
        let mut root = json::Root {
            asset: json::Asset {
                generator: Some(format!("anerf {}", env!("CARGO_PKG_VERSION"))),
                ..Default::default()
            },
            ..Default::default()
        };
        let buffer = root.push(json::Buffer {
            byte_length: USize64(0),
            extensions: None,
            extras: Default::default(),
            name: None,
            uri: None,
        });
        Self {
            root,
            bin: Vec::new(),
            buffer,
        }
    }

    /// Appends `bytes` as a buffer view (4-byte aligned) and an accessor of `count` elements over it.
    #[allow(clippy::too_many_arguments)]
    fn accessor(
        &mut self,
        bytes: &[u8],
        count: usize,
        component: json::accessor::ComponentType,
        kind: json::accessor::Type,
        target: Option<json::buffer::Target>,
        bounds: Option<(Vec<f32>, Vec<f32>)>,
    ) -> json::Index<json::Accessor> {
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let view = self.root.push(json::buffer::View {
            buffer: self.buffer,
            byte_length: USize64::from(bytes.len()),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            extensions: None,
            extras: Default::default(),
            name: None,
            target: target.map(Valid),
        });
        let (min, max) = match bounds {
            Some((min, max)) => (Some(json::Value::from(min)), Some(json::Value::from(max))),
            None => (None, None),
        };
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(json::accessor::GenericComponentType(component)),
            extensions: None,
            extras: Default::default(),
            type_: Valid(kind),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    fn floats(
        &mut self,
        values: &[f32],
        count: usize,
        kind: json::accessor::Type,
        target: Option<json::buffer::Target>,
        bounds: Option<(Vec<f32>, Vec<f32>)>,
    ) -> json::Index<json::Accessor> {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.accessor(
            &bytes,
            count,
            json::accessor::ComponentType::F32,
            kind,
            target,
            bounds,
        )
    }
}

/// The IEC 61966-2-1 sRGB decoding of one channel in `[0, 1]` (glTF vertex colours are linear).
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn glb_bytes(
    mesh: &SkinnedMesh,
    animation: &JointAnimation,
    capture_to_gltf: Quat,
) -> Result<Vec<u8>, String> {
    use json::accessor::{ComponentType, Type};
    use json::buffer::Target;
    let (v, k) = (mesh.positions.len(), mesh.rest_joints.len());
    if v == 0 || mesh.faces.is_empty() {
        return Err("the mesh has no triangles".into());
    }
    if [mesh.colors.len(), mesh.joints.len(), mesh.weights.len()] != [v, v, v] {
        return Err(format!(
            "{v} positions but {} colours, {} joint rows, {} weight rows",
            mesh.colors.len(),
            mesh.joints.len(),
            mesh.weights.len()
        ));
    }
    if mesh.parents.len() != k || k == 0 || k > u16::MAX as usize {
        return Err(format!("{k} joints with {} parents", mesh.parents.len()));
    }
    if animation.frames.is_empty() || !(animation.fps.is_finite() && animation.fps > 0.0) {
        return Err(format!(
            "an animation needs frames and a positive rate ({} frames at {} fps)",
            animation.frames.len(),
            animation.fps
        ));
    }
    if let Some(f) = animation.frames.iter().position(|f| f.rotations.len() != k) {
        return Err(format!(
            "animation frame {f} has {} rotations for {k} joints",
            animation.frames[f].rotations.len()
        ));
    }
    let mut b = Builder::new();
    let flat3 = |p: &[Vec3]| -> Vec<f32> { p.iter().flat_map(|x| x.to_array()).collect() };
    let (lo, hi) = mesh.positions.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    );
    let positions = b.floats(
        &flat3(mesh.positions),
        v,
        Type::Vec3,
        Some(Target::ArrayBuffer),
        Some((lo.to_array().to_vec(), hi.to_array().to_vec())),
    );
    let colors: Vec<f32> = mesh
        .colors
        .iter()
        .flat_map(|c| c.map(|x| srgb_to_linear(x.clamp(0.0, 1.0))))
        .collect();
    let colors = b.floats(&colors, v, Type::Vec3, Some(Target::ArrayBuffer), None);
    let joint_bytes: Vec<u8> = mesh
        .joints
        .iter()
        .flatten()
        .flat_map(|j| j.to_le_bytes())
        .collect();
    let joints = b.accessor(
        &joint_bytes,
        v,
        ComponentType::U16,
        Type::Vec4,
        Some(Target::ArrayBuffer),
        None,
    );
    let weights: Vec<f32> = mesh.weights.iter().flatten().copied().collect();
    let weights = b.floats(&weights, v, Type::Vec4, Some(Target::ArrayBuffer), None);
    let index_bytes: Vec<u8> = mesh
        .faces
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let indices = b.accessor(
        &index_bytes,
        3 * mesh.faces.len(),
        ComponentType::U32,
        Type::Scalar,
        Some(Target::ElementArrayBuffer),
        None,
    );
    // A_k = G_k · T(−J_k): the inverse bind matrix of joint k is the translation by −J_k.
    let ibm: Vec<f32> = mesh
        .rest_joints
        .iter()
        .flat_map(|j| glam::Mat4::from_translation(-*j).to_cols_array())
        .collect();
    let ibm = b.floats(&ibm, k, Type::Mat4, None, None);

    let attributes = BTreeMap::from([
        (Valid(json::mesh::Semantic::Positions), positions),
        (Valid(json::mesh::Semantic::Colors(0)), colors),
        (Valid(json::mesh::Semantic::Joints(0)), joints),
        (Valid(json::mesh::Semantic::Weights(0)), weights),
    ]);
    let material = b.root.push(json::Material {
        pbr_metallic_roughness: json::material::PbrMetallicRoughness {
            metallic_factor: json::material::StrengthFactor(0.0),
            roughness_factor: json::material::StrengthFactor(1.0),
            ..Default::default()
        },
        name: Some("vertex colours".into()),
        ..Default::default()
    });
    let gltf_mesh = b.root.push(json::Mesh {
        extensions: None,
        extras: Default::default(),
        name: Some("avatar".into()),
        primitives: vec![json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: Default::default(),
            indices: Some(indices),
            material: Some(material),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }],
        weights: None,
    });

    // Joint nodes first (index j = joint j), then the capture node and the mesh node.
    let first = &animation.frames[0];
    let mut children: Vec<Vec<json::Index<json::Node>>> = vec![Vec::new(); k];
    for (j, p) in mesh.parents.iter().enumerate() {
        if let Some(p) = *p {
            children[p].push(json::Index::new(j as u32));
        }
    }
    for (j, kids) in children.into_iter().enumerate() {
        let translation = match mesh.parents[j] {
            Some(p) => mesh.rest_joints[j] - mesh.rest_joints[p],
            None => first.root_translation,
        };
        b.root.push(json::Node {
            name: Some(format!("joint_{j:02}")),
            translation: Some(translation.to_array()),
            rotation: Some(json::scene::UnitQuaternion(
                first.rotations[j].normalize().to_array(),
            )),
            children: (!kids.is_empty()).then_some(kids),
            ..Default::default()
        });
    }
    let roots: Vec<json::Index<json::Node>> = (0..k)
        .filter(|&j| mesh.parents[j].is_none())
        .map(|j| json::Index::new(j as u32))
        .collect();
    let capture = b.root.push(json::Node {
        name: Some("capture".into()),
        rotation: Some(json::scene::UnitQuaternion(
            capture_to_gltf.normalize().to_array(),
        )),
        children: Some(roots),
        ..Default::default()
    });
    let skin = b.root.push(json::Skin {
        extensions: None,
        extras: Default::default(),
        inverse_bind_matrices: Some(ibm),
        joints: (0..k).map(|j| json::Index::new(j as u32)).collect(),
        name: Some("skeleton".into()),
        skeleton: Some(capture),
    });
    let body = b.root.push(json::Node {
        name: Some("avatar".into()),
        mesh: Some(gltf_mesh),
        skin: Some(skin),
        ..Default::default()
    });

    // The animation: one time accessor, a rotation channel per joint and joint 0's translation.
    let n = animation.frames.len();
    let times: Vec<f32> = (0..n).map(|i| i as f32 / animation.fps).collect();
    let last = times[n - 1];
    let input = b.floats(&times, n, Type::Scalar, None, Some((vec![0.0], vec![last])));
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    let mut channel = |b: &mut Builder,
                       node: usize,
                       path: json::animation::Property,
                       values: Vec<f32>,
                       kind: Type| {
        let output = b.floats(&values, n, kind, None, None);
        samplers.push(json::animation::Sampler {
            extensions: None,
            extras: Default::default(),
            input,
            interpolation: Valid(json::animation::Interpolation::Linear),
            output,
        });
        channels.push(json::animation::Channel {
            sampler: json::Index::new(samplers.len() as u32 - 1),
            target: json::animation::Target {
                extensions: None,
                extras: Default::default(),
                node: json::Index::new(node as u32),
                path: Valid(path),
            },
            extensions: None,
            extras: Default::default(),
        });
    };
    let root_joint = roots_first(mesh.parents);
    let translations: Vec<f32> = animation
        .frames
        .iter()
        .flat_map(|f| f.root_translation.to_array())
        .collect();
    channel(
        &mut b,
        root_joint,
        json::animation::Property::Translation,
        translations,
        Type::Vec3,
    );
    for j in 0..k {
        let rotations: Vec<f32> = animation
            .frames
            .iter()
            .flat_map(|f| f.rotations[j].normalize().to_array())
            .collect();
        channel(
            &mut b,
            j,
            json::animation::Property::Rotation,
            rotations,
            Type::Vec4,
        );
    }
    b.root.push(json::Animation {
        extensions: None,
        extras: Default::default(),
        channels,
        name: Some(animation.name.clone()),
        samplers,
    });
    let scene = b.root.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some("anerf".into()),
        nodes: vec![capture, body],
    });
    b.root.scene = Some(scene);
    b.root.buffers[0].byte_length = USize64::from(b.bin.len());

    let json_text = json::serialize::to_string(&b.root).map_err(|e| e.to_string())?;
    let mut json_bytes = json_text.into_bytes();
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    let length = 12 + 8 + json_bytes.len() + 8 + b.bin.len();
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: u32::try_from(length)
                .map_err(|_| format!("{length} bytes: a .glb holds at most 4 GiB"))?,
        },
        json: Cow::Owned(json_bytes),
        bin: Some(Cow::Owned(b.bin)),
    };
    glb.to_vec().map_err(|e| e.to_string())
}

/// The joint without a parent (joint 0 in SMPL-family skeletons).
fn roots_first(parents: &[Option<usize>]) -> usize {
    parents.iter().position(Option::is_none).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::srgb_to_linear;

    #[test]
    fn vertex_colours_are_decoded_from_srgb_as_the_standard_defines() {
        // IEC 61966-2-1: the linear segment's end 0.04045 ↦ 0.04045/12.92, mid-grey 0.5 ↦ 0.21404, ends fixed.
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(0.04045) - 0.003_130_8).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        let samples: Vec<f32> = (0..=100)
            .map(|i| srgb_to_linear(i as f32 / 100.0))
            .collect();
        assert!(samples.windows(2).all(|w| w[1] > w[0]));
    }
}
