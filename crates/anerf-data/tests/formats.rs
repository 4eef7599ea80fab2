//! `.npy`, `.npz` and pickle readers against files written by real numpy and pickle
//! (`scripts/fixtures/datasets.py`).

use anerf_data::formats::{self, pickle::PickleError, Value};
use anerf_data::DataError;
use anerf_testing::Tolerance;
use anerf_testing::{fixture, floats, json};

#[test]
fn every_dtype_order_and_header_version_reads_like_numpy() {
    let index = json("formats/index.json");
    let arrays = index["arrays"].as_array().unwrap();
    assert!(arrays.len() >= 50, "{}", arrays.len());
    for case in arrays {
        let file = case["file"].as_str().unwrap();
        let a = formats::read_npy(&fixture(&format!("formats/{file}"))).unwrap();
        let shape: Vec<usize> = floats(&case["shape"]).iter().map(|&d| d as usize).collect();
        assert_eq!(a.shape(), &shape[..], "{file}");
        assert_close(&a.to_f64(), &floats(&case["values"]), file);
    }
}

/// Equal up to the last bits lost by JSON's decimal round trip.
fn assert_close(got: &[f64], want: &[f64], what: &str) {
    anerf_testing::assert_close(what, got, want, Tolerance::Relative(1e-12));
}

fn strings(v: &Value, key: &str) -> Vec<String> {
    let items = v.get(key).and_then(Value::as_seq).unwrap();
    items.iter().map(|s| s.as_str().unwrap()).collect()
}

fn check_expected(v: &Value, what: &str) {
    let index = json("formats/index.json");
    for (key, exp) in index["expected_arrays"].as_object().unwrap() {
        let a = v
            .get(key)
            .and_then(Value::as_array)
            .unwrap_or_else(|| panic!("{what}: {key} is not an array: {:?}", v.get(key)));
        let shape: Vec<usize> = floats(&exp["shape"]).iter().map(|&d| d as usize).collect();
        assert_eq!(a.shape(), &shape[..], "{what}: {key}");
        assert_close(
            &a.to_f64(),
            &floats(&exp["values"]),
            &format!("{what}: {key}"),
        );
    }
    assert_eq!(strings(v, "names"), ["Camera (1)/a b.jpg", "ü"], "{what}");
    assert_eq!(strings(v, "unicode_array"), ["abc", "de"], "{what}");
    assert_eq!(
        strings(v, "numpy_str_items"),
        ["Camera (2)/x.jpg", "y"],
        "{what}"
    );
    let nested = v.get("nested").unwrap();
    assert_eq!(
        nested.get("tuple"),
        Some(&Value::Tuple(vec![
            Value::Int(1),
            Value::Int(-2),
            Value::Float(3.5),
            Value::None,
            Value::Bool(true),
            Value::Bool(false)
        ])),
        "{what}"
    );
    assert_eq!(
        nested.get("raw"),
        Some(&Value::Bytes(vec![0, 255])),
        "{what}"
    );
    assert_eq!(nested.get("big"), Some(&Value::Int(1 << 40)), "{what}");
    let list = v.get("list_of_arrays").unwrap().as_seq().unwrap();
    assert_eq!(list[0].as_array().unwrap().shape(), &[3, 3]);
    assert_eq!(list[0].as_array().unwrap().to_f64()[4], 1.0);
    assert_eq!(list[1].as_array().unwrap().shape(), &[2, 1]);
    let objects = v.get("object_array").unwrap().as_seq().unwrap();
    let second = objects[1].get("ims").unwrap().as_seq().unwrap()[0].as_str();
    assert_eq!(second.as_deref(), Some("y.jpg"), "{what}");
}

#[test]
fn pickles_of_every_protocol_and_np_save_dicts_decode_fully() {
    let index = json("formats/index.json");
    for name in index["pickles"].as_array().unwrap() {
        let name = name.as_str().unwrap();
        let path = fixture(&format!("formats/{name}"));
        let v = if name.ends_with(".npy") {
            formats::read_npy_object(&path).unwrap()
        } else {
            formats::read_pickle(&path).unwrap()
        };
        check_expected(&v, name);
    }
}

#[test]
fn a_pickle_that_would_call_os_system_is_refused_by_name() {
    let index = json("formats/index.json");
    let global = index["evil_global"].as_str().unwrap();
    for name in index["evil"].as_array().unwrap() {
        let name = name.as_str().unwrap();
        let path = fixture(&format!("formats/{name}"));
        let err = if name.ends_with(".npy") {
            formats::read_npy_object(&path).unwrap_err()
        } else {
            formats::read_pickle(&path).unwrap_err()
        };
        let refused = match &err {
            DataError::Pickle { source, .. } => source.clone(),
            DataError::Npy {
                source: formats::npy::NpyError::Pickle(p),
                ..
            } => p.clone(),
            other => panic!("{name}: unexpected {other}"),
        };
        assert_eq!(refused, PickleError::Refused(global.into()), "{name}");
        let msg = err.to_string();
        assert!(msg.contains(name) && msg.contains(global), "{msg}");
    }
}

#[test]
fn body_model_archives_read_from_npz_and_pkl() {
    let index = json("body_model/index.json");
    let weights = floats(&index["weights"]);
    let faces = floats(&index["faces_list"]);
    for file in ["tiny_body.npz", "tiny_body_compressed.npz"] {
        let members =
            formats::npz::read_npz_arrays(&fixture(&format!("body_model/{file}"))).unwrap();
        assert_close(&members["weights"].to_f64(), &weights, file);
        let f: Vec<f64> = members["f"]
            .to_i64()
            .unwrap()
            .iter()
            .map(|&x| x as f64)
            .collect();
        assert_eq!(f, faces, "{file}");
    }
    let pkl = formats::read_pickle(&fixture("body_model/tiny_body.pkl")).unwrap();
    assert_close(
        &pkl.get("weights").unwrap().as_array().unwrap().to_f64(),
        &weights,
        "pkl",
    );
    assert_eq!(
        pkl.get("bs_style").unwrap().as_str().as_deref(),
        Some("lbs")
    );
}

#[test]
fn truncated_and_corrupt_files_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let src = std::fs::read(fixture("formats/arr_f4_le_C_v1.npy")).unwrap();
    let cut = dir.path().join("cut.npy");
    std::fs::write(&cut, &src[..src.len() - 3]).unwrap();
    let msg = formats::read_npy(&cut).unwrap_err().to_string();
    assert!(msg.contains("cut.npy") && msg.contains("needs 96"), "{msg}");
    let garbage = dir.path().join("garbage.npy");
    std::fs::write(&garbage, b"definitely not numpy").unwrap();
    let msg = formats::read_npy(&garbage).unwrap_err().to_string();
    assert!(
        msg.contains("garbage.npy") && msg.contains("magic"),
        "{msg}"
    );
    let missing = dir.path().join("absent.npy");
    let msg = formats::read_npy(&missing).unwrap_err().to_string();
    assert!(
        msg.contains("absent.npy") && msg.contains("missing"),
        "{msg}"
    );
    // A numeric file where an object is expected, and the other way round.
    let msg = formats::read_npy_object(&fixture("formats/arr_f4_le_C_v1.npy"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("expected a pickled object"), "{msg}");
    let msg = formats::read_npy(&fixture("formats/dict_npsave.npy"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("expected a numeric array"), "{msg}");
}
