//! Where a cell's iceoryx2 resources live: root directory, file prefix, instance.
//!
//! The system domain uses iceoryx2's defaults (root `/tmp/iceoryx2/`, prefix
//! `iox2_`) and does not read an iceoryx2 config file. An isolated domain has its own
//! root directory and prefix, so tests and benchmarks share nothing with a running
//! cell or with each other and can remove everything they created.

use super::services::Services;
use super::IpcError;
use crate::fsio::{FileError, FileOp};
use iceoryx2::config::Config;
use iceoryx2::node::{Node, NodeState};
use iceoryx2::prelude::{ipc, CallbackProgression, FileName, SemanticString};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Directory of POSIX shared memory objects on Linux.
const SHM_DIR: &str = "/dev/shm";

/// Suffix of iceoryx2's persistent global management segment (a node counter that
/// outlives every node by design).
const GLOBAL_MGMT_SUFFIX: &str = ".global_mgmt";

/// Longest file prefix of an isolated domain.
pub const MAX_PREFIX_LEN: usize = 32;

/// A domain as data, to hand to another process (e.g. as JSON on its command line).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomainSpec {
    /// Cell instance name.
    pub instance: String,
    /// Root directory of an isolated domain (`None`: the system domain).
    pub root: Option<PathBuf>,
    /// File prefix of an isolated domain (`None`: the system domain).
    pub prefix: Option<String>,
}

/// The iceoryx2 configuration and service names of one cell instance.
#[derive(Debug, Clone)]
pub struct Domain {
    services: Services,
    config: Config,
    isolated: bool,
}

impl Domain {
    /// The system domain of cell instance `instance` (iceoryx2 default root and prefix).
    pub fn system(instance: &str) -> Result<Domain, IpcError> {
        Ok(Domain {
            services: Services::new(instance)?,
            config: base_config(),
            isolated: false,
        })
    }

    /// An isolated domain: files under the absolute directory `root` and shared
    /// memory objects named `<prefix>...` (1 to 32 ASCII letters, digits or `_`).
    pub fn isolated(instance: &str, root: &Path, prefix: &str) -> Result<Domain, IpcError> {
        let services = Services::new(instance)?;
        let root_text = root.to_str().ok_or_else(|| IpcError::InvalidDomain {
            field: "root",
            value: root.display().to_string(),
            reason: "not UTF-8",
        })?;
        if !root.is_absolute() {
            return Err(IpcError::InvalidDomain {
                field: "root",
                value: root_text.to_string(),
                reason: "must be an absolute path",
            });
        }
        if prefix.is_empty()
            || prefix.len() > MAX_PREFIX_LEN
            || !prefix
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_')
        {
            return Err(IpcError::InvalidDomain {
                field: "prefix",
                value: prefix.to_string(),
                reason: "1 to 32 ASCII letters, digits or '_'",
            });
        }
        let mut root_with_slash = root_text.trim_end_matches('/').to_string();
        root_with_slash.push('/');
        let root_path = iceoryx2::prelude::Path::new(root_with_slash.as_bytes()).map_err(|e| {
            IpcError::InvalidDomain {
                field: "root",
                value: format!("{root_text} ({e:?})"),
                reason: "not accepted by iceoryx2",
            }
        })?;
        let prefix_name =
            FileName::new(prefix.as_bytes()).map_err(|e| IpcError::InvalidDomain {
                field: "prefix",
                value: format!("{prefix} ({e:?})"),
                reason: "not accepted by iceoryx2",
            })?;
        let mut config = base_config();
        config.global.set_root_path(&root_path);
        config.global.prefix = prefix_name;
        Ok(Domain {
            services,
            config,
            isolated: true,
        })
    }

    /// A fresh isolated domain for a test or benchmark named `tag`: instance
    /// `<tag>-<pid>-<n>`, root `<temp dir>/graspcell-ipc-<pid>-<n>/`, prefix
    /// `gc<pid>x<n>_`, unique within the machine while this process lives. Its
    /// files are removed when the returned guard is dropped (or by
    /// [`Domain::remove`] earlier, to see errors).
    pub fn temporary(tag: &str) -> Result<TemporaryDomain, IpcError> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let pid = std::process::id();
        let tag: String = tag
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '-'
                }
            })
            .take(32)
            .collect();
        let root = std::env::temp_dir().join(format!("graspcell-ipc-{pid}-{n}"));
        Domain::isolated(&format!("{tag}-{pid}-{n}"), &root, &format!("gc{pid}x{n}_"))
            .map(TemporaryDomain)
    }

    /// The domain described by `spec`: isolated when it names both root and prefix,
    /// the system domain when it names neither.
    pub fn from_spec(spec: &DomainSpec) -> Result<Domain, IpcError> {
        match (&spec.root, &spec.prefix) {
            (Some(root), Some(prefix)) => Domain::isolated(&spec.instance, root, prefix),
            (None, None) => Domain::system(&spec.instance),
            _ => Err(IpcError::InvalidDomain {
                field: "root",
                value: format!("{:?} with prefix {:?}", spec.root, spec.prefix),
                reason: "give both root and prefix, or neither",
            }),
        }
    }

    /// This domain as data ([`Domain::from_spec`] makes it again).
    pub fn spec(&self) -> DomainSpec {
        DomainSpec {
            instance: self.services.instance().to_string(),
            root: self.isolated.then(|| self.root()),
            prefix: self.isolated.then(|| self.prefix()),
        }
    }

    /// The service names of the instance.
    pub fn services(&self) -> &Services {
        &self.services
    }

    /// The iceoryx2 configuration every node of the domain uses.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// True for a domain made by [`Domain::isolated`].
    pub fn is_isolated(&self) -> bool {
        self.isolated
    }

    /// Root directory of the domain's files.
    pub fn root(&self) -> PathBuf {
        PathBuf::from(self.config.global.root_path().to_string())
    }

    /// Prefix of the domain's file and shared memory names.
    pub fn prefix(&self) -> String {
        self.config.global.prefix.to_string()
    }

    /// Number of nodes of the domain whose process is alive (any instance).
    pub fn alive_nodes(&self) -> Result<usize, IpcError> {
        let mut alive = 0;
        Node::<ipc::Service>::list(&self.config, |state| {
            if matches!(state, NodeState::Alive(_)) {
                alive += 1;
            }
            CallbackProgression::Continue
        })
        .map_err(|e| IpcError::iceoryx("list nodes", self.root().display().to_string(), e))?;
        Ok(alive)
    }

    /// The domain's files: everything under the root directory whose name starts
    /// with the prefix, and the shared memory objects with the prefix.
    pub fn files(&self) -> Result<Vec<PathBuf>, IpcError> {
        let prefix = self.prefix();
        let mut out = Vec::new();
        collect_prefixed(&self.root(), &prefix, &mut out)?;
        collect_prefixed_flat(Path::new(SHM_DIR), &prefix, &mut out)?;
        out.sort();
        Ok(out)
    }

    /// The domain's files except iceoryx2's persistent node counter: the resources
    /// of nodes and services. Empty once every process of the domain has ended
    /// cleanly or been cleaned up after.
    pub fn leftover_files(&self) -> Result<Vec<PathBuf>, IpcError> {
        let mut files = self.files()?;
        files.retain(|f| !f.to_string_lossy().ends_with(GLOBAL_MGMT_SUFFIX));
        Ok(files)
    }

    /// Removes an isolated domain: its shared memory objects and its root directory.
    /// Refuses while a node of the domain is alive, and for the system domain.
    /// Returns the number of files removed.
    pub fn remove(&self) -> Result<usize, IpcError> {
        if !self.isolated {
            return Err(IpcError::InvalidDomain {
                field: "root",
                value: self.root().display().to_string(),
                reason: "only an isolated domain can be removed",
            });
        }
        let root = self.root();
        if root.exists() {
            let alive = self.alive_nodes()?;
            if alive > 0 {
                return Err(IpcError::DomainInUse { root, alive });
            }
        }
        let files = self.files()?;
        for file in files.iter().filter(|f| f.starts_with(SHM_DIR)) {
            remove_file_if_present(file)?;
        }
        match std::fs::remove_dir_all(&root) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(source) => return Err(FileError::new(FileOp::Remove, &root, source).into()),
        }
        Ok(files.len())
    }
}

/// iceoryx2's defaults, except that creating a node does not clean up dead nodes by
/// itself: [`Stage::start`](super::Stage::start) does it explicitly, to report it.
fn base_config() -> Config {
    let mut config = Config::default();
    config.global.node.cleanup_dead_nodes_on_creation = false;
    config
}

/// A domain made by [`Domain::temporary`]; dropping it removes its files (after the
/// stages and peer processes using it are gone; errors are ignored then).
#[derive(Debug)]
pub struct TemporaryDomain(Domain);

impl std::ops::Deref for TemporaryDomain {
    type Target = Domain;

    fn deref(&self) -> &Domain {
        &self.0
    }
}

impl Drop for TemporaryDomain {
    fn drop(&mut self) {
        if let Err(e) = self.0.remove() {
            tracing::warn!("temporary ipc domain not removed: {e}");
        }
    }
}

fn remove_file_if_present(path: &Path) -> Result<(), IpcError> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(source) => Err(FileError::new(FileOp::Remove, path, source).into()),
    }
}

fn read_dir_if_present(dir: &Path) -> Result<Option<std::fs::ReadDir>, IpcError> {
    match std::fs::read_dir(dir) {
        Ok(entries) => Ok(Some(entries)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(FileError::new(FileOp::ListDir, dir, source).into()),
    }
}

fn collect_prefixed_flat(dir: &Path, prefix: &str, out: &mut Vec<PathBuf>) -> Result<(), IpcError> {
    let Some(entries) = read_dir_if_present(dir)? else {
        return Ok(());
    };
    for entry in entries.flatten() {
        if entry.file_name().to_string_lossy().starts_with(prefix) {
            out.push(entry.path());
        }
    }
    Ok(())
}

fn collect_prefixed(dir: &Path, prefix: &str, out: &mut Vec<PathBuf>) -> Result<(), IpcError> {
    let Some(entries) = read_dir_if_present(dir)? else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if entry.file_type().map(|t| t.is_dir()).unwrap_or(false) {
            collect_prefixed(&path, prefix, out)?;
        } else if entry.file_name().to_string_lossy().starts_with(prefix) {
            out.push(path);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isolated_domain_settings_are_checked() {
        let d = Domain::isolated("t", Path::new("/tmp/gc-x"), "gc_1").unwrap();
        assert_eq!(d.root(), PathBuf::from("/tmp/gc-x/"));
        assert_eq!(d.prefix(), "gc_1");
        assert!(d.is_isolated());
        assert!(Domain::isolated("t", Path::new("rel/dir"), "p").is_err());
        assert!(Domain::isolated("t", Path::new("/tmp/x"), "").is_err());
        assert!(Domain::isolated("t", Path::new("/tmp/x"), "a-b").is_err());
        assert!(Domain::isolated("t/u", Path::new("/tmp/x"), "p").is_err());
        assert_eq!(Domain::from_spec(&d.spec()).unwrap().spec(), d.spec());
        let system = Domain::system("cell").unwrap();
        assert_eq!(system.spec().root, None);
        assert!(!Domain::from_spec(&system.spec()).unwrap().is_isolated());
        let mut half = d.spec();
        half.prefix = None;
        assert!(Domain::from_spec(&half).is_err());
        assert!(!system.is_isolated());
        assert!(matches!(
            system.remove(),
            Err(IpcError::InvalidDomain { .. })
        ));
    }
}
