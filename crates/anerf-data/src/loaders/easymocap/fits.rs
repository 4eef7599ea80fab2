//! EasyMocap's SMPL fits: `output-smpl-3d/smpl/<frame>.json` (or `output/smpl/`), a list of people, each
//! `{"id", "Rh", "Th", "poses", "shapes"}` (and `"expression"` for SMPL-X), every value a list of numbers or
//! a list holding one such list (`[[…]]`, as EasyMocap writes them). `Rh` is axis-angle, `Th` metres, the
//! body's world placement `R(Rh) x + Th`.

use std::path::Path;

use glam::DVec3;
use serde_json::Value;

use crate::error::DataError;
use crate::smpl::SmplParams;

/// One person's fit in one frame, as written (before it is matched to a body model).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PersonFit {
    pub id: i64,
    pub rh: DVec3,
    pub th: DVec3,
    pub poses: Vec<f64>,
    pub shapes: Vec<f64>,
    pub expression: Vec<f64>,
}

/// Every person of a fit file; each value checked for its length and finiteness.
pub(crate) fn read_fit_file(path: &Path) -> Result<Vec<PersonFit>, DataError> {
    let bytes = crate::formats::read_bytes(path)?;
    let value: Value = serde_json::from_slice(&bytes).map_err(|e| {
        DataError::invalid(
            path,
            format!("is not valid JSON (EasyMocap writes plain numbers; NaN is not JSON): {e}"),
        )
    })?;
    let people = match &value {
        Value::Array(people) => people,
        Value::Object(o) => match o.get("annots") {
            Some(Value::Array(people)) => people,
            _ => {
                return Err(DataError::invalid(
                    path,
                    "holds an object without an 'annots' list; expected a list of people",
                ))
            }
        },
        _ => return Err(DataError::invalid(path, "expected a list of people")),
    };
    people
        .iter()
        .enumerate()
        .map(|(i, person)| person_fit(person, path, i))
        .collect()
}

fn person_fit(person: &Value, path: &Path, i: usize) -> Result<PersonFit, DataError> {
    let invalid = |detail: String| DataError::invalid(path, format!("person {i}: {detail}"));
    let Value::Object(fields) = person else {
        return Err(invalid(
            "is not an object with id, Rh, Th, poses and shapes".into(),
        ));
    };
    let id = match fields.get("id") {
        None => 0, // single-person fits of older EasyMocap versions carry no id
        Some(v) => v
            .as_i64()
            .ok_or_else(|| invalid(format!("'id' is {v}, expected a whole number")))?,
    };
    let numbers = |key: &str, required: bool| -> Result<Vec<f64>, DataError> {
        let Some(v) = fields.get(key) else {
            return if required {
                Err(invalid(format!(
                    "has no '{key}' (keys: {})",
                    fields.keys().cloned().collect::<Vec<_>>().join(", ")
                )))
            } else {
                Ok(Vec::new())
            };
        };
        let row = match v {
            Value::Array(items) if items.len() == 1 && items[0].is_array() => &items[0],
            other => other,
        };
        let items = row
            .as_array()
            .ok_or_else(|| invalid(format!("'{key}' is {v}, expected a list of numbers")))?;
        items
            .iter()
            .enumerate()
            .map(|(j, x)| match x.as_f64() {
                Some(x) if x.is_finite() => Ok(x),
                _ => Err(invalid(format!(
                    "'{key}'[{j}] is {x}, expected a finite number"
                ))),
            })
            .collect()
    };
    let vec3 = |key: &str| -> Result<DVec3, DataError> {
        let v = numbers(key, true)?;
        match v[..] {
            [x, y, z] => Ok(DVec3::new(x, y, z)),
            _ => Err(invalid(format!(
                "'{key}' has {} numbers, expected 3",
                v.len()
            ))),
        }
    };
    let poses = numbers("poses", true)?;
    if poses.is_empty() || !poses.len().is_multiple_of(3) {
        return Err(invalid(format!(
            "'poses' has {} numbers, expected 3 per joint (72 for SMPL)",
            poses.len()
        )));
    }
    Ok(PersonFit {
        id,
        rh: vec3("Rh")?,
        th: vec3("Th")?,
        poses,
        shapes: numbers("shapes", true)?,
        expression: numbers("expression", false)?,
    })
}

impl PersonFit {
    /// The model parameters: `shapes` as the first betas and, for SMPL-X, `expression` at the model's
    /// expression columns (`expression_at`, from the model's coefficient count).
    pub fn params(&self, expression_at: Option<usize>) -> SmplParams {
        let mut betas = self.shapes.clone();
        if let (Some(at), false) = (expression_at, self.expression.is_empty()) {
            betas.resize(at, 0.0);
            betas.extend_from_slice(&self.expression);
        }
        SmplParams {
            betas,
            poses: self.poses.clone(),
            rh: self.rh,
            th: self.th,
        }
    }
}
