//! The `.npy` and pickle writers against numpy itself: every file must read back exactly.

mod common;

use anerf_data::formats::{write_npy, write_object_npy, ArrayData, NdArray, PyValue};
use serde_json::{json, Value};

/// The checker's JSON form of a value: arrays as `{"__array__": …}`, the rest as plain JSON.
fn expected(v: &PyValue) -> Value {
    match v {
        PyValue::None => Value::Null,
        PyValue::Bool(b) => json!(b),
        PyValue::Int(i) => json!(i),
        PyValue::Float(f) => json!(f),
        PyValue::Str(s) => json!(s),
        PyValue::List(items) => Value::Array(items.iter().map(expected).collect()),
        PyValue::Dict(items) => {
            json!({"__dict__": items.iter().map(|(k, v)| json!([k, expected(v)])).collect::<Vec<_>>()})
        }
        PyValue::Array(a) => expected_array(a),
    }
}

fn expected_array(a: &NdArray) -> Value {
    let data = match a.data() {
        ArrayData::F32(v) => json!(v),
        ArrayData::F64(v) => json!(v),
        ArrayData::I32(v) => json!(v),
        ArrayData::I64(v) => json!(v),
        ArrayData::U32(v) => json!(v),
        ArrayData::U8(v) => json!(v),
        ArrayData::Bool(v) => json!(v),
    };
    json!({"__array__": {"dtype": a.dtype().descr(), "shape": a.shape(), "data": data}})
}

fn arrays() -> Vec<(&'static str, NdArray)> {
    let a = |shape: Vec<usize>, data| NdArray::new(shape, data).unwrap();
    vec![
        (
            "f32_2d",
            a(
                vec![3, 2],
                ArrayData::F32(vec![1.5, -0.0, 1e-38, f32::MAX, -3.25, 7.0]),
            ),
        ),
        (
            "f64_3d",
            a(
                vec![2, 1, 2],
                ArrayData::F64(vec![0.1, -2.0, 1e300, 5e-324]),
            ),
        ),
        (
            "i64_sentinel",
            a(vec![4], ArrayData::I64(vec![4294967295, 0, -1, i64::MIN])),
        ),
        ("i32_scalar", a(vec![], ArrayData::I32(vec![-7]))),
        ("u32_empty", a(vec![0, 3], ArrayData::U32(vec![]))),
        (
            "u8_long",
            a(
                vec![300],
                ArrayData::U8((0..300).map(|i| (i * 7 % 256) as u8).collect()),
            ),
        ),
        (
            "bool_mask",
            a(vec![2, 2], ArrayData::Bool(vec![true, false, false, true])),
        ),
        // 40 dimensions: a header longer than 128 bytes, padded to the next multiple of 64.
        ("many_dims", a(vec![1; 40], ArrayData::F32(vec![2.0]))),
    ]
}

#[test]
fn numpy_reads_plain_and_pickled_arrays_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("files");
    std::fs::create_dir(&folder).unwrap();
    let mut files = Vec::new();
    for (name, array) in arrays() {
        let path = format!("{name}.npy");
        write_npy(&folder.join(&path), &array).unwrap();
        files.push(json!({"path": path, "kind": "npy", "expected": expected_array(&array)}));
    }
    // A dict like annots.npy: nested dicts and lists, arrays of every dtype, strings past 255 bytes and
    // with non-ASCII characters, ints of every pickle width, floats, bools and None.
    let dict = PyValue::dict([
        (
            "arrays",
            PyValue::List(
                arrays()
                    .into_iter()
                    .map(|(_, a)| PyValue::Array(a))
                    .collect(),
            ),
        ),
        (
            "ims",
            PyValue::List(vec![PyValue::dict([(
                "ims",
                PyValue::List(vec![
                    PyValue::Str("Camera (1)/0001.jpg".into()),
                    PyValue::Str("é".repeat(200)),
                ]),
            )])]),
        ),
        (
            "ints",
            PyValue::List(
                [
                    0,
                    255,
                    256,
                    -1,
                    65536,
                    i32::MAX as i64,
                    -(1 << 40),
                    i64::MAX,
                ]
                .map(PyValue::Int)
                .to_vec(),
            ),
        ),
        (
            "floats",
            PyValue::List(vec![PyValue::Float(0.1), PyValue::Float(-1e300)]),
        ),
        (
            "flags",
            PyValue::List(vec![
                PyValue::Bool(true),
                PyValue::Bool(false),
                PyValue::None,
            ]),
        ),
        ("empty", PyValue::dict::<&str>([])),
        ("empty_list", PyValue::List(vec![])),
    ]);
    write_object_npy(&folder.join("annots.npy"), &dict).unwrap();
    files.push(json!({"path": "annots.npy", "kind": "object", "expected": expected(&dict)}));
    let list = PyValue::List(vec![PyValue::Int(1), PyValue::Str("two".into())]);
    write_object_npy(&folder.join("list.npy"), &list).unwrap();
    files.push(json!({"path": "list.npy", "kind": "object", "expected": expected(&list)}));
    common::numpy_check(&folder, &json!({ "files": files }));
}

#[test]
fn the_checker_catches_a_wrong_value() {
    // The check must be able to fail: one element off is reported.
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("files");
    std::fs::create_dir(&folder).unwrap();
    let array = NdArray::new(vec![2], ArrayData::F32(vec![1.0, 2.0])).unwrap();
    write_npy(&folder.join("a.npy"), &array).unwrap();
    let wrong = NdArray::new(vec![2], ArrayData::F32(vec![1.0, 2.5])).unwrap();
    let manifest =
        json!({"files": [{"path": "a.npy", "kind": "npy", "expected": expected_array(&wrong)}]});
    let result = std::panic::catch_unwind(|| common::numpy_check(&folder, &manifest));
    assert!(result.is_err(), "the checker accepted a wrong value");
}
