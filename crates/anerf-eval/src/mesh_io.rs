//! Triangle-mesh export to binary little-endian PLY and to OBJ (atomically), and a PLY reader for the files
//! this module writes (and other binary little-endian PLYs of the same shape).
//!
//! Meshes come as plain slices so any mesh type can be exported: positions in metres (in whatever frame the
//! caller extracted them: canonical or world), triangles as vertex-index triples, optional per-vertex
//! colours and optional named per-vertex scalars (blend weights, distances).

use std::path::Path;

use glam::Vec3;

use crate::error::EvalError;
use anerf_data::atomic::write_with;

/// Header comment of every PLY written here.
const PLY_COMMENT: &str = "anerf mesh, lengths in metres";

/// A named per-vertex scalar, written as a PLY `float` property (OBJ cannot hold it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VertexAttribute<'a> {
    pub name: &'a str,
    pub values: &'a [f32],
}

/// A borrowed triangle mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshView<'a> {
    /// Vertex positions in metres.
    pub positions: &'a [Vec3],
    /// Triangles as indices into `positions`, counter-clockwise seen from outside.
    pub faces: &'a [[u32; 3]],
    /// Per-vertex RGB in [0, 1] (clamped; 8 bits per channel in PLY).
    pub colors: Option<&'a [[f32; 3]]>,
    pub attributes: &'a [VertexAttribute<'a>],
}

impl<'a> MeshView<'a> {
    /// A mesh without colours or attributes.
    pub fn new(positions: &'a [Vec3], faces: &'a [[u32; 3]]) -> Self {
        Self {
            positions,
            faces,
            colors: None,
            attributes: &[],
        }
    }

    pub fn with_colors(self, colors: &'a [[f32; 3]]) -> Self {
        Self {
            colors: Some(colors),
            ..self
        }
    }

    pub fn with_attributes(self, attributes: &'a [VertexAttribute<'a>]) -> Self {
        Self { attributes, ..self }
    }

    /// Checks counts, indices, finiteness and attribute names, naming the offending item.
    pub fn validate(&self) -> Result<(), EvalError> {
        let invalid = |detail: String| {
            Err(EvalError::InvalidInput {
                what: "mesh",
                detail,
            })
        };
        let n = self.positions.len();
        if n > i32::MAX as usize || self.faces.len() > i32::MAX as usize {
            return invalid(format!(
                "{n} vertices and {} faces; PLY int indices allow 2^31 - 1",
                self.faces.len()
            ));
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return invalid(format!("vertex {i} is not finite: {}", self.positions[i]));
        }
        if let Some((f, face)) = self
            .faces
            .iter()
            .enumerate()
            .find(|(_, f)| f.iter().any(|&v| v as usize >= n))
        {
            return invalid(format!(
                "face {f} is {face:?}, expected indices below the {n} vertices"
            ));
        }
        if let Some(colors) = self.colors {
            if colors.len() != n {
                return invalid(format!("{} colours for {n} vertices", colors.len()));
            }
            if let Some(i) = colors.iter().position(|c| c.iter().any(|v| !v.is_finite())) {
                return invalid(format!("colour {i} is not finite: {:?}", colors[i]));
            }
        }
        for (k, attribute) in self.attributes.iter().enumerate() {
            let name = attribute.name;
            let reserved = ["x", "y", "z", "red", "green", "blue"].contains(&name)
                || self.attributes[..k].iter().any(|a| a.name == name);
            if name.is_empty()
                || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                || reserved
            {
                return invalid(format!(
                    "attribute name {name:?}: expected a unique word of letters, digits and '_', not x/y/z/red/green/blue"
                ));
            }
            if attribute.values.len() != n {
                return invalid(format!(
                    "attribute {name:?} has {} values for {n} vertices",
                    attribute.values.len()
                ));
            }
            if let Some(i) = attribute.values.iter().position(|v| !v.is_finite()) {
                return invalid(format!(
                    "attribute {name:?} of vertex {i} is not finite: {}",
                    attribute.values[i]
                ));
            }
        }
        Ok(())
    }
}

/// Writes `mesh` as binary little-endian PLY: `float x y z`, `uchar red green blue` when coloured, one
/// `float` per attribute, and faces as `list uchar int vertex_indices`.
pub fn write_ply(path: &Path, mesh: &MeshView) -> Result<(), EvalError> {
    mesh.validate()?;
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {PLY_COMMENT}\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n",
        mesh.positions.len()
    );
    if mesh.colors.is_some() {
        header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    for attribute in mesh.attributes {
        header += &format!("property float {}\n", attribute.name);
    }
    header += &format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.faces.len()
    );

    let mut bytes = header.into_bytes();
    for (i, p) in mesh.positions.iter().enumerate() {
        for v in p.to_array() {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        if let Some(colors) = mesh.colors {
            bytes.extend(colors[i].map(anerf_data::formats::images::channel_byte));
        }
        for attribute in mesh.attributes {
            bytes.extend_from_slice(&attribute.values[i].to_le_bytes());
        }
    }
    for face in mesh.faces {
        bytes.push(3);
        for &v in face {
            bytes.extend_from_slice(&(v as i32).to_le_bytes());
        }
    }
    write_with(path, |w| {
        w.write_all(&bytes).map_err(|source| EvalError::Io {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Writes `mesh` as OBJ: `v x y z` (with `r g b` in [0, 1] appended when coloured, the common extension
/// read by MeshLab and others) and 1-based `f a b c`; attributes have no OBJ form and are left out.
pub fn write_obj(path: &Path, mesh: &MeshView) -> Result<(), EvalError> {
    mesh.validate()?;
    let mut text = format!(
        "# anerf mesh: {} vertices, {} triangles, lengths in metres\n",
        mesh.positions.len(),
        mesh.faces.len()
    );
    for (i, p) in mesh.positions.iter().enumerate() {
        text += &format!("v {} {} {}", p.x, p.y, p.z);
        if let Some(colors) = mesh.colors {
            let [r, g, b] = colors[i].map(|v| v.clamp(0.0, 1.0));
            text += &format!(" {r} {g} {b}");
        }
        text.push('\n');
    }
    for [a, b, c] in mesh.faces {
        text += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    write_with(path, |w| {
        w.write_all(text.as_bytes())
            .map_err(|source| EvalError::Io {
                path: path.to_path_buf(),
                source,
            })
    })
}

/// A mesh read from a PLY file.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyMesh {
    /// Metres.
    pub positions: Vec<Vec3>,
    pub faces: Vec<[u32; 3]>,
    /// Per-vertex RGB as `byte / 255`.
    pub colors: Option<Vec<[f32; 3]>>,
    /// Named per-vertex `float` properties other than x, y, z, in file order.
    pub attributes: Vec<(String, Vec<f32>)>,
}

/// Scalar types of the PLY properties this reader accepts.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    Float,
    UChar,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        match name {
            "float" | "float32" => Some(Scalar::Float),
            "uchar" | "uint8" => Some(Scalar::UChar),
            _ => None,
        }
    }

    fn size(self) -> usize {
        match self {
            Scalar::Float => 4,
            Scalar::UChar => 1,
        }
    }
}

/// Reads a binary little-endian PLY with a `vertex` element of `float`/`uchar` properties (x, y, z
/// required; red, green, blue optional) followed by a `face` element of triangles
/// (`list uchar int|uint vertex_indices`), such as [`write_ply`] writes.
pub fn read_ply(path: &Path) -> Result<PlyMesh, EvalError> {
    let bytes = std::fs::read(path).map_err(|e| EvalError::io(path, "a binary PLY mesh", e))?;
    let bad = |detail: String| EvalError::Format {
        path: path.to_path_buf(),
        detail,
    };
    let end = b"end_header\n";
    let header_len = bytes
        .windows(end.len())
        .position(|w| w == end)
        .map(|p| p + end.len())
        .ok_or_else(|| bad("no end_header line; expected a PLY header".into()))?;
    let header =
        std::str::from_utf8(&bytes[..header_len]).map_err(|_| bad("header is not text".into()))?;

    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err(bad("does not start with 'ply'".into()));
    }
    let (mut vertices, mut faces) = (None::<usize>, None::<usize>);
    let mut properties: Vec<(String, Scalar)> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", "binary_little_endian", "1.0"]
            | ["comment", ..]
            | ["obj_info", ..]
            | ["end_header"] => {}
            ["format", other, ..] => {
                return Err(bad(format!(
                    "format {other}; expected binary_little_endian"
                )))
            }
            ["element", "vertex", n] if vertices.is_none() => {
                vertices = Some(n.parse().map_err(|_| bad(format!("vertex count {n:?}")))?)
            }
            ["element", "face", n] if vertices.is_some() && faces.is_none() => {
                faces = Some(n.parse().map_err(|_| bad(format!("face count {n:?}")))?)
            }
            ["property", ty, name] if faces.is_none() && vertices.is_some() => {
                let scalar = Scalar::parse(ty).ok_or_else(|| {
                    bad(format!(
                        "vertex property {name} of type {ty}; expected float or uchar"
                    ))
                })?;
                properties.push((name.to_string(), scalar));
            }
            ["property", "list", "uchar" | "uint8", "int" | "uint" | "int32" | "uint32", "vertex_indices"]
                if faces.is_some() => {}
            _ => return Err(bad(format!("unsupported header line {line:?}"))),
        }
    }
    let vertices = vertices.ok_or_else(|| bad("no vertex element".into()))?;
    let faces = faces.ok_or_else(|| bad("no face element after the vertex element".into()))?;

    let position_of = |name: &str| properties.iter().position(|(n, _)| n == name);
    let float_of = |name: &str| {
        position_of(name)
            .filter(|&i| properties[i].1 == Scalar::Float)
            .ok_or_else(|| bad(format!("no float vertex property {name}")))
    };
    let xyz = [float_of("x")?, float_of("y")?, float_of("z")?];
    let rgb = ["red", "green", "blue"].map(position_of);
    let colored = match rgb {
        [Some(_), Some(_), Some(_)]
            if rgb
                .iter()
                .flatten()
                .all(|&i| properties[i].1 == Scalar::UChar) =>
        {
            true
        }
        [None, None, None] => false,
        _ => {
            return Err(bad(
                "expected all of uchar red, green, blue or none of them".into(),
            ))
        }
    };
    if let Some((name, _)) = properties
        .iter()
        .find(|(n, s)| *s == Scalar::UChar && !["red", "green", "blue"].contains(&n.as_str()))
    {
        return Err(bad(format!(
            "uchar vertex property {name}; only red, green and blue may be uchar"
        )));
    }
    let offsets: Vec<usize> = properties
        .iter()
        .scan(0, |offset, (_, s)| {
            Some(std::mem::replace(offset, *offset + s.size()))
        })
        .collect();
    let stride: usize = properties.iter().map(|(_, s)| s.size()).sum();

    let body = &bytes[header_len..];
    let vertex_bytes = vertices
        .checked_mul(stride)
        .filter(|&n| n <= body.len())
        .ok_or_else(|| {
            bad(format!(
                "file ends inside the {vertices} vertices ({} bytes after the header)",
                body.len()
            ))
        })?;
    let float_at = |v: usize, p: usize| {
        let at = v * stride + offsets[p];
        f32::from_le_bytes(body[at..at + 4].try_into().expect("4 bytes"))
    };
    let byte_at = |v: usize, p: usize| body[v * stride + offsets[p]];
    let positions = (0..vertices)
        .map(|v| Vec3::from_array(xyz.map(|p| float_at(v, p))))
        .collect();
    let colors = colored.then(|| {
        (0..vertices)
            .map(|v| rgb.map(|p| f32::from(byte_at(v, p.expect("checked above"))) / 255.0))
            .collect()
    });
    let attributes = properties
        .iter()
        .enumerate()
        .filter(|(_, (name, s))| *s == Scalar::Float && !["x", "y", "z"].contains(&name.as_str()))
        .map(|(p, (name, _))| {
            (
                name.clone(),
                (0..vertices).map(|v| float_at(v, p)).collect(),
            )
        })
        .collect();

    let face_bytes = &body[vertex_bytes..];
    if face_bytes.len() != faces * 13 {
        return Err(bad(format!(
            "{} bytes of faces, expected {} for {faces} triangles (count byte + 3 int indices each)",
            face_bytes.len(),
            faces * 13
        )));
    }
    let mut triangles = Vec::with_capacity(faces);
    for (f, record) in face_bytes.chunks_exact(13).enumerate() {
        if record[0] != 3 {
            return Err(bad(format!(
                "face {f} has {} vertices; expected triangles",
                record[0]
            )));
        }
        let index = |k: usize| {
            u32::from_le_bytes(record[1 + 4 * k..5 + 4 * k].try_into().expect("4 bytes"))
        };
        let triangle = [index(0), index(1), index(2)];
        if triangle.iter().any(|&i| i as usize >= vertices) {
            return Err(bad(format!(
                "face {f} is {triangle:?}, expected indices below {vertices}"
            )));
        }
        triangles.push(triangle);
    }
    Ok(PlyMesh {
        positions,
        faces: triangles,
        colors,
        attributes,
    })
}
