//! Editing a scene file's text in place (toml_edit): a table's entries, a
//! value set with its comment kept, and relative mesh paths rewritten for
//! the folder the edited file goes to.
//!
//! Why one room: every calibration that writes a scene back (pose, occluder,
//! geometry) and the daemon's posted scenes edit the user's file by the same
//! rules, so comments, order and mesh paths survive each alike.

use std::path::{Component, Path, PathBuf};

/// A relative mesh path that cannot be written for another folder.
#[derive(Debug, thiserror::Error)]
pub enum MeshPathError {
    /// The folder of one of the two scene files cannot be found.
    #[error("occluder[{index}].mesh = {path:?}: cannot find the folder {}: {source}", folder.display())]
    Folder {
        /// Occluder index.
        index: usize,
        /// The path as the scene file gives it.
        path: String,
        /// The folder looked for.
        folder: PathBuf,
        /// Why it was not found.
        #[source]
        source: std::io::Error,
    },
    /// The mesh the path names cannot be found from the scene file's folder.
    #[error("occluder[{index}].mesh = {path:?}: cannot find {}: {source}", file.display())]
    Mesh {
        /// Occluder index.
        index: usize,
        /// The path as the scene file gives it.
        path: String,
        /// The file looked for.
        file: PathBuf,
        /// Why it was not found.
        #[source]
        source: std::io::Error,
    },
    /// The rewritten path is not UTF-8, which TOML cannot hold.
    #[error("occluder[{index}].mesh = {path:?}: {} is not UTF-8 and cannot be written in TOML", file.display())]
    NotUtf8 {
        /// Occluder index.
        index: usize,
        /// The path as the scene file gives it.
        path: String,
        /// The rewritten path.
        file: PathBuf,
    },
}

/// A folder as an absolute path without links (`""`: the current one).
fn absolute(dir: &Path) -> std::io::Result<PathBuf> {
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    dir.canonicalize()
}

/// The mesh path `path` of occluder `index`, written in a file in
/// `from_dir`, as a file in `to_dir` must write it: an absolute path as it
/// is, a relative one relative to `to_dir`, or absolute when no relative
/// path leads there (another drive).
pub(crate) fn rebase(
    index: usize,
    path: &str,
    from_dir: &Path,
    to_dir: &Path,
) -> Result<String, MeshPathError> {
    if Path::new(path).is_absolute() {
        return Ok(path.to_string());
    }
    let folder = |dir: &Path| {
        absolute(dir).map_err(|source| MeshPathError::Folder {
            index,
            path: path.to_string(),
            folder: dir.to_path_buf(),
            source,
        })
    };
    let (from, to) = (folder(from_dir)?, folder(to_dir)?);
    let file = from.join(path);
    let target = file.canonicalize().map_err(|source| MeshPathError::Mesh {
        index,
        path: path.to_string(),
        file: file.clone(),
        source,
    })?;
    let new = relative_to(&target, &to).unwrap_or(target);
    match new.to_str() {
        Some(text) => Ok(text.to_string()),
        None => Err(MeshPathError::NotUtf8 {
            index,
            path: path.to_string(),
            file: new,
        }),
    }
}

/// The tables of the array `key` of `doc` (`[[key]]` or `key = [{...}]`),
/// in file order, for editing in place.
pub(crate) fn entries<'a>(
    doc: &'a mut toml_edit::DocumentMut,
    key: &str,
) -> Vec<&'a mut dyn toml_edit::TableLike> {
    match doc.get_mut(key) {
        Some(toml_edit::Item::ArrayOfTables(a)) => a
            .iter_mut()
            .map(|t| t as &mut dyn toml_edit::TableLike)
            .collect(),
        Some(toml_edit::Item::Value(toml_edit::Value::Array(a))) => a
            .iter_mut()
            .filter_map(|v| v.as_inline_table_mut())
            .map(|t| t as &mut dyn toml_edit::TableLike)
            .collect(),
        _ => Vec::new(),
    }
}

/// Sets `key` of `entry` to `value`, keeping the comment that followed
/// the value it replaces (the key's own comments stay with the key).
pub(crate) fn set_value(
    entry: &mut dyn toml_edit::TableLike,
    key: &str,
    mut value: toml_edit::Value,
) {
    if let Some(old) = entry.get(key).and_then(toml_edit::Item::as_value) {
        *value.decor_mut() = old.decor().clone();
    }
    entry.insert(key, toml_edit::Item::Value(value));
}

/// Every relative `mesh` path of `doc`'s `[[occluder]]` entries (a file
/// in `from_dir`) rewritten for a file in `to_dir` ([`rebase`]), the rest
/// of the file as it is: the edited file reads the same meshes.
pub(crate) fn rebase_mesh_paths(
    doc: &mut toml_edit::DocumentMut,
    from_dir: &Path,
    to_dir: &Path,
) -> Result<(), MeshPathError> {
    for (index, entry) in entries(doc, "occluder").into_iter().enumerate() {
        let Some(path) = entry
            .get("mesh")
            .and_then(|m| m.as_str())
            .map(str::to_string)
        else {
            continue;
        };
        let new = rebase(index, &path, from_dir, to_dir)?;
        if new != path {
            set_value(entry, "mesh", toml_edit::Value::from(new));
        }
    }
    Ok(())
}

/// `target` relative to the folder `base`, both absolute; `None` when they
/// have different roots (another drive).
fn relative_to(target: &Path, base: &Path) -> Option<PathBuf> {
    let t: Vec<Component> = target.components().collect();
    let b: Vec<Component> = base.components().collect();
    let is_root = |c: &&Component| matches!(c, Component::Prefix(_) | Component::RootDir);
    let (tr, br) = (
        t.iter().take_while(is_root).count(),
        b.iter().take_while(is_root).count(),
    );
    if t[..tr] != b[..br] {
        return None;
    }
    let common = t.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..b.len() {
        out.push("..");
    }
    for c in &t[common..] {
        out.push(c);
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_relative_to_another_folder_climbs_to_their_common_root() {
        assert_eq!(
            relative_to(Path::new("/x/y/z.obj"), Path::new("/x/w/v")),
            Some(PathBuf::from("../../y/z.obj"))
        );
    }
}
