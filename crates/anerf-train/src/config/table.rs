//! The raw TOML tables a config is layered from, before it is typed: deep merging and setting a key path.

use toml::{Table, Value};

/// Deep-merges `over` into `base`: tables merge key by key, anything else replaces.
pub fn merge(base: &mut Table, over: Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(Value::Table(b)), Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Sets the value at a key path, making the sections on the way; the error is the first key on the way
/// that holds a value instead of a section.
pub(super) fn set_value(table: &mut Table, path: &[&str], value: Value) -> Result<(), String> {
    let (last, sections) = path.split_last().expect("a key path has a key");
    let mut node = table;
    for p in sections {
        node = match node
            .entry(p.to_string())
            .or_insert_with(|| Value::Table(Table::new()))
        {
            Value::Table(t) => t,
            _ => return Err(p.to_string()),
        };
    }
    node.insert(last.to_string(), value);
    Ok(())
}
