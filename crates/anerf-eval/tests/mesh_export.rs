//! PLY and OBJ export: byte-identical to plyfile's output (`scripts/fixtures/mesh_io.py`), read back by our
//! reader, OBJ parsed back from text, and invalid meshes rejected without writing anything.

use anerf_eval::mesh_io::{read_ply, write_obj, write_ply, MeshView, PlyMesh, VertexAttribute};
use anerf_eval::EvalError;
use glam::Vec3;
use serde_json::Value;

mod support;

fn floats(v: &Value) -> Vec<f32> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

/// The content of one fixture case, owned.
struct Case {
    name: String,
    file: String,
    positions: Vec<Vec3>,
    faces: Vec<[u32; 3]>,
    colors: Option<Vec<[f32; 3]>>,
    attributes: Vec<(String, Vec<f32>)>,
}

fn cases() -> Vec<Case> {
    let fixture = support::load_json("mesh_io", "meshes.json");
    fixture["cases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|case| Case {
            name: case["name"].as_str().unwrap().into(),
            file: case["file"].as_str().unwrap().into(),
            positions: case["positions"]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| Vec3::from_slice(&floats(p)))
                .collect(),
            faces: case["faces"]
                .as_array()
                .unwrap()
                .iter()
                .map(|f| {
                    let v: Vec<u32> = f
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|i| i.as_u64().unwrap() as u32)
                        .collect();
                    [v[0], v[1], v[2]]
                })
                .collect(),
            colors: case["colors"].as_array().map(|rows| {
                rows.iter()
                    .map(|c| {
                        floats(c)
                            .iter()
                            .map(|v| v / 255.0)
                            .collect::<Vec<_>>()
                            .try_into()
                            .unwrap()
                    })
                    .collect()
            }),
            attributes: case["attributes"]
                .as_array()
                .unwrap()
                .iter()
                .map(|a| {
                    (
                        a["name"].as_str().unwrap().to_string(),
                        floats(&a["values"]),
                    )
                })
                .collect(),
        })
        .collect()
}

#[test]
fn ply_output_is_byte_identical_to_plyfile_and_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let cases = cases();
    assert_eq!(cases.len(), 2, "expected the coloured and the plain mesh");
    for case in cases {
        let attributes: Vec<VertexAttribute> = case
            .attributes
            .iter()
            .map(|(name, values)| VertexAttribute { name, values })
            .collect();
        let mut mesh = MeshView::new(&case.positions, &case.faces).with_attributes(&attributes);
        if let Some(colors) = &case.colors {
            mesh = mesh.with_colors(colors);
        }
        let ours = dir.path().join(&case.file);
        write_ply(&ours, &mesh).unwrap();
        let reference = support::fixture_path("mesh_io", &case.file);
        let expected = std::fs::read(&reference).unwrap_or_else(|e| {
            panic!(
                "{}: {e}; run scripts/fixtures/generate.py",
                reference.display()
            )
        });
        assert_eq!(
            std::fs::read(&ours).unwrap(),
            expected,
            "{}: bytes differ from plyfile's",
            case.name
        );

        let read = read_ply(&reference).unwrap();
        let expected_mesh = PlyMesh {
            positions: case.positions.clone(),
            faces: case.faces.clone(),
            colors: case.colors.clone(),
            attributes: case.attributes.clone(),
        };
        assert_eq!(read, expected_mesh, "{}", case.name);
    }
}

#[test]
fn obj_lists_vertices_with_colours_and_one_based_faces() {
    let dir = tempfile::tempdir().unwrap();
    let case = cases().into_iter().find(|c| c.colors.is_some()).unwrap();
    let colors = case.colors.clone().unwrap();
    let path = dir.path().join("mesh.obj");
    write_obj(
        &path,
        &MeshView::new(&case.positions, &case.faces).with_colors(&colors),
    )
    .unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let mut vertices: Vec<Vec<f32>> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => vertices.push(words.map(|w| w.parse().unwrap()).collect()),
            Some("f") => {
                let v: Vec<u32> = words.map(|w| w.parse::<u32>().unwrap() - 1).collect();
                faces.push([v[0], v[1], v[2]]);
            }
            Some("#") | None => {}
            Some(other) => panic!("unexpected OBJ line kind {other}"),
        }
    }
    assert_eq!(faces, case.faces);
    assert_eq!(vertices.len(), case.positions.len());
    for ((v, p), c) in vertices.iter().zip(&case.positions).zip(&colors) {
        assert_eq!(
            v[..3],
            p.to_array(),
            "positions round-trip exactly through the shortest decimal form"
        );
        assert_eq!(v[3..], c[..]);
    }
}

#[test]
fn our_own_output_round_trips_through_the_reader() {
    let dir = tempfile::tempdir().unwrap();
    // A strip of 40 triangles with colours and 24 blend-weight attributes, as a reposable mesh carries.
    let positions: Vec<Vec3> = (0..42)
        .map(|i| Vec3::new(i as f32 * 0.01, (i % 2) as f32 * 0.02, -1.5))
        .collect();
    let faces: Vec<[u32; 3]> = (0..40).map(|i| [i, i + 1, i + 2]).collect();
    let colors: Vec<[f32; 3]> = (0..42)
        .map(|i| [i as f32 / 41.0, 0.5, 1.0 - i as f32 / 41.0])
        .collect();
    let weights: Vec<Vec<f32>> = (0..24)
        .map(|k| (0..42).map(|i| ((i + k) % 24) as f32 / 23.0).collect())
        .collect();
    let names: Vec<String> = (0..24).map(|k| format!("w{k}")).collect();
    let attributes: Vec<VertexAttribute> = names
        .iter()
        .zip(&weights)
        .map(|(name, values)| VertexAttribute { name, values })
        .collect();
    let path = dir.path().join("meshes").join("canonical.ply");
    write_ply(
        &path,
        &MeshView::new(&positions, &faces)
            .with_colors(&colors)
            .with_attributes(&attributes),
    )
    .unwrap();
    let read = read_ply(&path).unwrap();
    assert_eq!(read.positions, positions);
    assert_eq!(read.faces, faces);
    let quantised: Vec<[f32; 3]> = colors
        .iter()
        .map(|c| c.map(|v| (v * 255.0).round() / 255.0))
        .collect();
    assert_eq!(read.colors.unwrap(), quantised);
    assert_eq!(read.attributes.len(), 24);
    for ((name, values), (expected_name, expected)) in
        read.attributes.iter().zip(names.iter().zip(&weights))
    {
        assert_eq!((name, values), (expected_name, expected));
    }
}

#[test]
fn invalid_meshes_and_files_are_rejected_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let positions = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let path = dir.path().join("bad.ply");
    let out_of_range = write_ply(&path, &MeshView::new(&positions, &[[0, 1, 3]])).unwrap_err();
    assert!(
        out_of_range.to_string().contains("face 0"),
        "{out_of_range}"
    );
    let colors = [[0.0; 3]; 2];
    let short = write_obj(
        &path,
        &MeshView::new(&positions, &[[0, 1, 2]]).with_colors(&colors),
    )
    .unwrap_err();
    assert!(
        short.to_string().contains("2 colours for 3 vertices"),
        "{short}"
    );
    let values = [0.0; 3];
    for name in ["x", "has space", ""] {
        let attributes = [VertexAttribute {
            name,
            values: &values,
        }];
        let err = write_ply(
            &path,
            &MeshView::new(&positions, &[[0, 1, 2]]).with_attributes(&attributes),
        )
        .unwrap_err();
        assert!(
            matches!(err, EvalError::InvalidInput { .. }),
            "{name:?}: {err}"
        );
    }
    let nan = [Vec3::ZERO, Vec3::X, Vec3::NAN];
    assert!(write_ply(&path, &MeshView::new(&nan, &[[0, 1, 2]])).is_err());
    assert!(!path.exists(), "nothing may be written for an invalid mesh");

    let good = dir.path().join("good.ply");
    write_ply(&good, &MeshView::new(&positions, &[[0, 1, 2]])).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let truncated = dir.path().join("truncated.ply");
    std::fs::write(&truncated, &bytes[..bytes.len() - 5]).unwrap();
    let err = read_ply(&truncated).unwrap_err();
    assert!(
        matches!(err, EvalError::Format { .. }) && err.to_string().contains("truncated.ply"),
        "{err}"
    );
    let ascii = dir.path().join("ascii.ply");
    std::fs::write(
        &ascii,
        String::from_utf8_lossy(&bytes).replace("binary_little_endian", "ascii"),
    )
    .unwrap();
    assert!(read_ply(&ascii)
        .unwrap_err()
        .to_string()
        .contains("expected binary_little_endian"));
    let missing = read_ply(&dir.path().join("none.ply")).unwrap_err();
    assert!(
        matches!(missing, EvalError::MissingFile { .. }),
        "{missing}"
    );
}
