//! The file paths a scene file names, and how they move when a scene is saved elsewhere.
//!
//! A scene file's relative paths are relative to the scene file's folder
//! ([`crate::scene::Scene::load`]). A scene saved into another folder (the viewer's `save-scene`,
//! the Python bindings) must therefore rewrite them, or the copy reads another folder's files:
//! [`rebase_paths`] does so for every field of [`PATH_FIELDS`].

use std::path::{Component, Path, PathBuf};

use crate::error::{Error, Result};

/// Every field of the scene format that names a file, as `section.key` (dotted as in errors).
/// A unit test probes the format's deserialisation and fails when a path field is missing here.
pub const PATH_FIELDS: &[&str] = &["volume.file", "sky.envmap"];

/// Rewrites the path fields ([`PATH_FIELDS`]) of a parsed scene `doc`, read from a scene file in
/// `from_dir`, for a copy saved as `to_path`, so that the copy names the same files by the
/// loader's rule (relative to the scene file):
/// - a file under `to_path`'s folder is written relative to it (`sky.exr`, `maps/sky.exr`: the
///   folder can be moved with the scene);
/// - any other file is written absolute.
///
/// Relative `from_dir` and `to_path` are taken from the current folder; symbolic links are not
/// resolved in the paths written (a file is also found under `to_path`'s folder through them
/// when both exist). Absent fields, and values that are not strings or are empty (which the
/// loader reports), are left as they are. A path that is not UTF-8 (TOML cannot hold it) is an
/// error naming `to_path` and the field.
pub fn rebase_paths(doc: &mut toml::Table, from_dir: &Path, to_path: &Path) -> Result<()> {
    let absolute = |p: &Path| -> Result<PathBuf> {
        let p = if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        };
        std::path::absolute(p).map_err(|e| Error::io(p, e))
    };
    let from = absolute(from_dir)?;
    let to_dir = absolute(to_path.parent().unwrap_or(Path::new("")))?;
    for field in PATH_FIELDS {
        let Some(value) = string_at(doc, field) else {
            continue;
        };
        if value.is_empty() {
            continue;
        }
        let target = absolute(&from.join(value.as_str()))?;
        let new = relative_under(&target, &to_dir).unwrap_or(target);
        *value = new
            .to_str()
            .ok_or_else(|| {
                Error::invalid(
                    to_path,
                    *field,
                    format!(
                        "{} is not UTF-8 text, which a scene file cannot hold",
                        new.display()
                    ),
                )
            })?
            .to_string();
    }
    Ok(())
}

/// The string at a dotted `field` of `doc`, if there is one.
fn string_at<'a>(doc: &'a mut toml::Table, field: &str) -> Option<&'a mut String> {
    let (sections, key) = field.rsplit_once('.').unwrap_or(("", field));
    let mut table = doc;
    for section in sections.split('.').filter(|s| !s.is_empty()) {
        match table.get_mut(section)? {
            toml::Value::Table(t) => table = t,
            _ => return None,
        }
    }
    match table.get_mut(key)? {
        toml::Value::String(s) => Some(s),
        _ => None,
    }
}

/// `target` relative to `dir` when it lies under it (plain names only, no `..`): lexically, or
/// else with both paths' links resolved (when both exist).
fn relative_under(target: &Path, dir: &Path) -> Option<PathBuf> {
    let plain = |rel: &Path| {
        !rel.as_os_str().is_empty() && rel.components().all(|c| matches!(c, Component::Normal(_)))
    };
    if let Ok(rel) = target.strip_prefix(dir)
        && plain(rel)
    {
        return Some(rel.to_path_buf());
    }
    // `dir` resolves to its canonical form and the rest of the canonical target holds no link,
    // so `dir/rel` resolves to the target.
    let (t, d) = (target.canonicalize().ok()?, dir.canonicalize().ok()?);
    let rel = t.strip_prefix(&d).ok()?;
    plain(rel).then(|| rel.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The path fields of the format, found by asking the deserialiser itself: every section's
    /// keys come from the unknown-field error of a probe key, and a key set to a number is a
    /// path when serde expected a `path string` (a `PathBuf`), a section when it expected a
    /// struct. A new `PathBuf` field anywhere in the format shows up here without a change.
    fn probed_path_fields() -> Vec<String> {
        fn error_of(prefix: &[String], key: &str, value: toml::Value) -> String {
            let mut doc = toml::Table::new();
            doc.insert(key.into(), value);
            for section in prefix.iter().rev() {
                let mut outer = toml::Table::new();
                outer.insert(section.clone(), toml::Value::Table(doc));
                doc = outer;
            }
            let text = toml::to_string(&doc).unwrap();
            match crate::Scene::from_toml_str(&text, Path::new("/nonexistent"), Path::new("p")) {
                Ok(_) => panic!("{text} was accepted"),
                Err(e) => e.to_string(),
            }
        }
        fn walk(prefix: Vec<String>, out: &mut Vec<String>) {
            let e = error_of(&prefix, "no_such_key_probe", toml::Value::Integer(1));
            let (_, expected) = e
                .split_once("expected")
                .unwrap_or_else(|| panic!("no field list for {prefix:?}: {e}"));
            let keys: Vec<&str> = expected.split('`').skip(1).step_by(2).collect();
            assert!(!keys.is_empty(), "{e}");
            for key in keys {
                let e = error_of(&prefix, key, toml::Value::Integer(1));
                let mut field = prefix.clone();
                field.push(key.to_string());
                if e.contains("expected path string") {
                    out.push(field.join("."));
                } else if e.contains("expected struct") {
                    walk(field, out);
                }
            }
        }
        let mut out = Vec::new();
        walk(Vec::new(), &mut out);
        out.sort();
        out
    }

    #[test]
    fn the_list_holds_every_path_field_of_the_format() {
        let mut listed: Vec<String> = PATH_FIELDS.iter().map(|s| s.to_string()).collect();
        listed.sort();
        let probed = probed_path_fields();
        assert_eq!(probed, listed, "PATH_FIELDS must list every path field");
    }

    fn doc(volume: &str, envmap: &str) -> toml::Table {
        format!("[volume]\nfile = {volume:?}\n[sky]\nenvmap = {envmap:?}\nscale = 2.0\n")
            .parse()
            .unwrap()
    }

    fn field<'a>(doc: &'a toml::Table, section: &str, key: &str) -> &'a str {
        doc[section][key].as_str().unwrap()
    }

    #[test]
    fn paths_become_relative_under_the_new_folder_and_absolute_elsewhere() {
        // Lexical cases: nothing here needs to exist.
        let a = Path::new("/data/a");
        let mut d = doc("cloud.vol", "sky/sky.exr");
        rebase_paths(&mut d, a, Path::new("/data/a/sky/saved.toml")).unwrap();
        assert_eq!(field(&d, "volume", "file"), "/data/a/cloud.vol");
        assert_eq!(field(&d, "sky", "envmap"), "sky.exr");
        assert_eq!(d["sky"]["scale"].as_float(), Some(2.0));

        let mut d = doc("cloud.vol", "/maps/sky.exr");
        rebase_paths(&mut d, a, Path::new("/elsewhere/b/saved.toml")).unwrap();
        assert_eq!(field(&d, "volume", "file"), "/data/a/cloud.vol");
        assert_eq!(field(&d, "sky", "envmap"), "/maps/sky.exr");

        // Saved beside the original: the same relative paths; `.` components dropped.
        let mut d = doc("./cloud.vol", "sky/./sky.exr");
        rebase_paths(&mut d, a, Path::new("/data/a/copy.toml")).unwrap();
        assert_eq!(field(&d, "volume", "file"), "cloud.vol");
        assert_eq!(field(&d, "sky", "envmap"), "sky/sky.exr");

        // `..` is never resolved lexically (a link may sit before it): kept in an absolute path
        // that the system resolves as the original did.
        let mut d = doc("../shared/cloud.vol", "sky.exr");
        rebase_paths(&mut d, a, Path::new("/data/saved.toml")).unwrap();
        assert_eq!(field(&d, "volume", "file"), "/data/a/../shared/cloud.vol");
        assert_eq!(field(&d, "sky", "envmap"), "a/sky.exr");

        // Absent sections and fields, and non-path values, are left alone.
        let mut d: toml::Table = "[volume]\ngenerator = { kind = \"cumulus\", seed = 1, \
                                  resolution = [8, 8, 8] }\n[sky]\nradiance = 0.5\n"
            .parse()
            .unwrap();
        let before = d.clone();
        rebase_paths(&mut d, a, Path::new("/x/y.toml")).unwrap();
        assert_eq!(d, before);
    }

    #[test]
    fn relative_folders_are_taken_from_the_current_folder() {
        let cwd = std::env::current_dir().unwrap();
        let mut d = doc("cloud.vol", "in/sky.exr");
        rebase_paths(&mut d, Path::new(""), Path::new("out.toml")).unwrap();
        assert_eq!(field(&d, "volume", "file"), "cloud.vol");
        assert_eq!(field(&d, "sky", "envmap"), "in/sky.exr");
        let mut d = doc("cloud.vol", "in/sky.exr");
        rebase_paths(&mut d, Path::new("scenes"), Path::new("out/s.toml")).unwrap();
        assert_eq!(
            Path::new(field(&d, "volume", "file")),
            cwd.join("scenes/cloud.vol")
        );
    }

    #[cfg(unix)]
    #[test]
    fn a_file_under_the_new_folder_through_a_link_is_written_relative() {
        let root = std::env::temp_dir().join(format!("nimbus-rebase-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(root.join("real/sub")).unwrap();
        std::fs::write(root.join("real/sub/sky.exr"), "x").unwrap();
        std::os::unix::fs::symlink(root.join("real"), root.join("link")).unwrap();
        let mut d = doc("cloud.vol", "sub/sky.exr");
        // Read through the link, saved into the real folder.
        rebase_paths(&mut d, &root.join("link"), &root.join("real/saved.toml")).unwrap();
        assert_eq!(field(&d, "sky", "envmap"), "sub/sky.exr");
        // cloud.vol does not exist: only the lexical rule applies, so it is absolute.
        assert_eq!(
            Path::new(field(&d, "volume", "file")),
            root.join("link/cloud.vol")
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_path_toml_cannot_hold_is_an_error_naming_the_file_and_field() {
        use std::os::unix::ffi::OsStrExt;
        let bad = Path::new(std::ffi::OsStr::from_bytes(b"/data/\xff"));
        let mut d = doc("cloud.vol", "sky.exr");
        let e = rebase_paths(&mut d, bad, Path::new("/x/saved.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/x/saved.toml") && e.contains("volume.file") && e.contains("UTF-8"),
            "{e}"
        );
    }
}
