//! The layering of docs/architecture.md, checked on the source.
//!
//! - The core crate (`core/`) depends on no crate of the application and on nothing that does
//!   I/O: its `Cargo.toml` names only the listed libraries, so `crate::sim`, `infraloc::cli` or
//!   a capture backend cannot be imported from it (the compiler refuses).
//! - No file of the core names the file system, sockets, processes or a clock.
//! - No import cycle between modules of either crate, `localize/init/` never imports
//!   `localize/refine/`, and the service reaches the search and objective code only through the
//!   core's drift check (`.ci/module_cycles.py`).

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The `[dependencies]` table's keys of a manifest.
fn dependencies(manifest: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(manifest).unwrap();
    let doc: toml::Table = toml::from_str(&text).unwrap();
    doc.get("dependencies")
        .and_then(|d| d.as_table())
        .map(|t| t.keys().cloned().collect())
        .unwrap_or_default()
}

#[test]
fn the_core_depends_on_no_application_crate_and_no_io_library() {
    let deps = dependencies(&root().join("core/Cargo.toml"));
    let allowed = [
        "nalgebra",
        "rayon",
        "serde",
        "serde_json",
        "toml",
        "thiserror",
        "rand",
        "rand_chacha",
        "rustfft",
        "proj4rs",
        "yaml-rust2",
        "roxmltree",
        "chrono",
    ];
    assert!(!deps.is_empty(), "core/Cargo.toml lists no dependencies");
    for d in &deps {
        assert!(
            allowed.contains(&d.as_str()),
            "core/Cargo.toml depends on {d}: the core takes data in and gives data out \
             (docs/architecture.md); I/O and the application's crates belong to the root package"
        );
    }
    // The application depends on the core, never the other way round.
    assert!(dependencies(&root().join("Cargo.toml")).contains(&"infraloc-core".to_string()));
}

#[test]
fn no_core_file_touches_files_sockets_processes_or_clocks() {
    let forbidden = [
        "std::fs",
        "std::net",
        "std::process",
        "std::os::unix",
        "Instant::now",
        "SystemTime",
        "File::open",
        "File::create",
    ];
    let mut stack = vec![root().join("core/src")];
    let mut files = 0;
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            if p.extension().is_none_or(|x| x != "rs") {
                continue;
            }
            files += 1;
            let text = std::fs::read_to_string(&p).unwrap();
            // The unit tests at a file's end may write temporary files; the product code may not.
            let product = match text.find("#[cfg(test)]\nmod tests") {
                Some(i) => &text[..i],
                None => &text[..],
            };
            for (n, line) in product.lines().enumerate() {
                let code = line.split("//").next().unwrap_or("");
                for f in forbidden {
                    assert!(
                        !code.contains(f),
                        "{}:{}: the core names {f}: {line}",
                        p.display(),
                        n + 1
                    );
                }
            }
        }
    }
    assert!(files > 50, "only {files} core files found");
}

#[test]
fn no_import_cycle_and_the_rooms_keep_their_rules() {
    let out = Command::new("python3")
        .arg(root().join(".ci/module_cycles.py"))
        .output()
        .expect("python3 runs .ci/module_cycles.py");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("no import cycle"), "{text}");
}
