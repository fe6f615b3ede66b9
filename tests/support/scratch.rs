//! A scratch place on disk for one test: `<temp dir>/<prefix>-<pid>-<name>/`, made fresh, is
//! removed when the guard drops after a passing test, and kept (its path printed on stderr)
//! after a failing one, so what the test wrote can be looked at. The guard derefs to the path
//! the test uses, `<that directory>/<name>`, which it does not create (a bag writer or a file
//! write does). Included with `#[path]` by the test crates that write files, so every crate
//! cleans up the same way (before it, each run of the suite left ~0.7 GB in /tmp).

use std::ops::Deref;
use std::path::{Path, PathBuf};

pub struct Scratch {
    root: PathBuf,
    path: PathBuf,
}

impl Scratch {
    /// A fresh, empty `<temp dir>/<prefix>-<pid>-<name>/`; the guard's path is `name` in it.
    pub fn new(prefix: &str, name: &str) -> Self {
        let root = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
        // A leftover of an earlier process with the same pid: start empty.
        let _ = std::fs::remove_dir_all(&root);
        if let Err(e) = std::fs::create_dir_all(&root) {
            panic!("cannot create the test's scratch directory {}: {e}", root.display());
        }
        let path = root.join(name);
        Scratch { root, path }
    }
}

impl Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("test failed: its files are kept in {}", self.root.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.root);
        }
    }
}
