//! Helpers shared by the conformance and fuzz-smoke tests: where the samples are, what
//! each must produce, and how to run the `dnr` binary.
//!
//! Test-only (`publish = false`): it depends on `dnr-format` and `dnr-bake`, and no product
//! crate may depend on it.
#![forbid(unsafe_code)]

pub mod fuzz_targets;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The repository root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// `samples/` in the repository.
pub fn samples_dir() -> PathBuf {
    repo_root().join("samples")
}

/// `samples/expected.json`: sample path (relative to `samples/`) -> expected codes.
pub fn expected() -> BTreeMap<String, Vec<String>> {
    let path = samples_dir().join("expected.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The `dnr` binary, built once per test process with the same profile as the tests
/// (a binary of another package has no `CARGO_BIN_EXE_*` variable here).
pub fn dnr_exe() -> &'static Path {
    static EXE: OnceLock<PathBuf> = OnceLock::new();
    EXE.get_or_init(|| {
        let test_exe = std::env::current_exe().expect("current exe");
        // target/<profile>/deps/<test>-<hash>
        let profile_dir = test_exe
            .parent()
            .and_then(Path::parent)
            .expect("test binary lives in target/<profile>/deps");
        let release = profile_dir.file_name().is_some_and(|n| n == "release");
        let mut cmd = Command::new(env!("CARGO"));
        cmd.current_dir(repo_root())
            .args(["build", "--quiet", "-p", "dnr-cli", "--bin", "dnr"]);
        if release {
            cmd.arg("--release");
        }
        let status = cmd.status().expect("run cargo build for the dnr binary");
        assert!(status.success(), "cargo build -p dnr-cli failed");
        let exe = profile_dir.join(format!("dnr{}", std::env::consts::EXE_SUFFIX));
        assert!(exe.exists(), "{} was not built", exe.display());
        exe
    })
}
