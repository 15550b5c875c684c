//! `star calib import --merge CONFIG`: an existing star config with its
//! `[camera.intrinsics]` (and `.distortion`) values replaced by an imported
//! calibration. Everything else, comments and layout included, is kept
//! (through `toml_edit`); a missing section is added at the end.
//!
//! Takes in the config's text and the camera; gives out the new text. The
//! caller validates it as a star config before writing it.

use toml_edit::{DocumentMut, InlineTable, Item, TableLike, Value};

use crate::geometry::PinholeCamera;

/// Errors merging a calibration into a config's text.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// The config is not valid TOML.
    #[error("not valid TOML: {0}")]
    Parse(#[from] toml_edit::TomlError),
    /// A key on the path to the intrinsics holds a value, not a table.
    #[error("key `{key}` is not a table")]
    NotATable {
        /// The dotted key.
        key: String,
    },
}

/// `config_text` with `[camera.intrinsics]` set to `camera`.
pub fn merge_intrinsics(config_text: &str, camera: &PinholeCamera) -> Result<String, MergeError> {
    let mut doc: DocumentMut = config_text.parse()?;
    let camera_item = sub_table(doc.as_item_mut(), "camera", "camera")?;
    let intrinsics = sub_table(camera_item, "intrinsics", "camera.intrinsics")?;
    {
        let table = table_like(intrinsics, "camera.intrinsics")?;
        set(table, "width", i64::from(camera.width));
        set(table, "height", i64::from(camera.height));
        set(table, "fx", camera.fx);
        set(table, "fy", camera.fy);
        set(table, "cx", camera.cx);
        set(table, "cy", camera.cy);
    }
    let d = &camera.distortion;
    let dotted = "camera.intrinsics.distortion";
    let distortion = table_like(sub_table(intrinsics, "distortion", dotted)?, dotted)?;
    for (key, value) in [
        ("k1", d.k1),
        ("k2", d.k2),
        ("p1", d.p1),
        ("p2", d.p2),
        ("k3", d.k3),
    ] {
        set(distortion, key, value);
    }
    Ok(doc.to_string())
}

fn table_like<'a>(item: &'a mut Item, dotted: &str) -> Result<&'a mut dyn TableLike, MergeError> {
    item.as_table_like_mut()
        .ok_or_else(|| MergeError::NotATable {
            key: dotted.to_string(),
        })
}

/// The table `name` of table `parent` (whose dotted key is `dotted`'s
/// parent), created when absent: a `[header]` table below a header table,
/// an inline table inside an inline one.
fn sub_table<'a>(
    parent: &'a mut Item,
    name: &str,
    dotted: &str,
) -> Result<&'a mut Item, MergeError> {
    let inline = parent.is_inline_table();
    let parent_key = dotted.rsplit_once('.').map_or("(root)", |(p, _)| p);
    let table = table_like(parent, parent_key)?;
    if table.get(name).is_none() {
        let item = if inline {
            Item::Value(Value::InlineTable(InlineTable::new()))
        } else {
            let mut table = toml_edit::Table::new();
            // No empty `[camera]` header when only `[camera.intrinsics]` is new.
            table.set_implicit(true);
            Item::Table(table)
        };
        table.insert(name, item);
    }
    table.get_mut(name).ok_or_else(|| MergeError::NotATable {
        key: dotted.to_string(),
    })
}

/// Sets `key` to `value`, keeping the old value's surrounding whitespace
/// and trailing comment.
fn set(table: &mut dyn TableLike, key: &str, value: impl Into<Value>) {
    let mut value: Value = value.into();
    if let Some(old) = table.get(key).and_then(Item::as_value) {
        *value.decor_mut() = old.decor().clone();
    }
    table.insert(key, Item::Value(value));
}
