//! Packaging stays consistent with the repository: every asset `cargo deb` would ship exists (a
//! renamed unit or doc cannot silently break the .deb), the maintainer scripts are valid `sh`, and
//! the GigE Vision drop-in example verifies cleanly on top of the service with its exposure recorded
//! in docs/install.md.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn deb_metadata() -> toml::Table {
    let text = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let manifest: toml::Table = toml::from_str(&text).unwrap();
    manifest["package"]["metadata"]["deb"]
        .as_table()
        .expect("[package.metadata.deb] in Cargo.toml")
        .clone()
}

/// (source, destination, mode) of each `assets` entry.
fn assets() -> Vec<(String, String, String)> {
    deb_metadata()["assets"]
        .as_array()
        .expect("assets array")
        .iter()
        .map(|a| {
            let a = a.as_array().expect("asset = [source, dest, mode]");
            assert_eq!(a.len(), 3, "asset {a:?} is not [source, dest, mode]");
            let s = |i: usize| a[i].as_str().unwrap().to_string();
            (s(0), s(1), s(2))
        })
        .collect()
}

/// Where an asset lands: a destination ending in `/` is a directory.
fn installed_path(src: &str, dest: &str) -> String {
    let name = Path::new(src).file_name().unwrap().to_str().unwrap();
    if dest.ends_with('/') {
        format!("/{dest}{name}")
    } else {
        format!("/{dest}")
    }
}

#[test]
fn deb_assets_exist() {
    let mut missing = Vec::new();
    for (src, dest, mode) in assets() {
        assert!(
            u32::from_str_radix(&mode, 8).is_ok_and(|m| m <= 0o777),
            "{src}: mode {mode:?} is not octal"
        );
        assert!(
            !dest.starts_with('/'),
            "{src}: dest {dest:?} must be relative"
        );
        if let Some(bin) = src.strip_prefix("target/release/") {
            // Built by cargo deb; must be one of our binaries.
            assert_eq!(bin, env!("CARGO_PKG_NAME"), "unknown binary asset {src}");
            continue;
        }
        if !root().join(&src).is_file() {
            missing.push(src);
        }
    }
    assert!(
        missing.is_empty(),
        "deb assets missing from the repo: {missing:?}"
    );
}

#[test]
fn deb_ships_what_the_units_reference() {
    let installed: Vec<String> = assets()
        .iter()
        .map(|(s, d, _)| installed_path(s, d))
        .collect();
    let has = |p: &str| installed.iter().any(|i| i == p);
    // The binary the units run, every unit, the preset, the config the service requires
    // (ConditionPathExists) and the README its Documentation= names.
    for p in [
        "/usr/bin/infraloc",
        "/lib/systemd/system/infraloc.service",
        "/lib/systemd/system/infraloc-relocalize.service",
        "/lib/systemd/system/infraloc-relocalize.timer",
        "/lib/systemd/system-preset/90-infraloc.preset",
        "/etc/infraloc/infraloc.toml",
        "/usr/share/doc/infraloc/README.md",
    ] {
        assert!(has(p), "{p} is not in the .deb assets: {installed:?}");
    }
    // Every unit in systemd/ is shipped, and so is every page its Documentation= names
    // (`man:NAME(N)` → /usr/share/man/manN/NAME.N; cargo-deb gzips it there).
    let mut man_links = 0;
    for e in std::fs::read_dir(root().join("systemd")).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".service") || name.ends_with(".timer") {
            assert!(
                has(&format!("/lib/systemd/system/{name}")),
                "systemd/{name} is not shipped"
            );
            let unit = std::fs::read_to_string(root().join("systemd").join(&name)).unwrap();
            let docs = unit
                .lines()
                .filter_map(|l| l.strip_prefix("Documentation="))
                .flat_map(str::split_whitespace);
            for page in docs.filter_map(|d| d.strip_prefix("man:")) {
                let (page, sect) = page.trim_end_matches(')').split_once('(').unwrap();
                let path = format!("/usr/share/man/man{sect}/{page}.{sect}");
                assert!(
                    has(&path),
                    "{name}: {page}({sect}) is not shipped as {path}"
                );
                man_links += 1;
            }
        }
    }
    assert!(man_links >= 3, "{man_links} man: links in the units");
    // conf-files are shipped files under /etc.
    let meta = deb_metadata();
    for c in meta["conf-files"].as_array().unwrap() {
        let c = c.as_str().unwrap();
        assert!(
            c.starts_with("/etc/") && has(c),
            "conf-file {c} is not an /etc asset"
        );
    }
}

#[test]
fn maintainer_scripts_are_valid_sh() {
    let dir = root().join(deb_metadata()["maintainer-scripts"].as_str().unwrap());
    for s in ["postinst", "prerm", "postrm"] {
        let p = dir.join(s);
        let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert!(text.starts_with("#!/bin/sh\n"), "{s}: not a /bin/sh script");
        assert!(text.contains("\nset -e\n"), "{s}: no `set -e`");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode();
            assert!(mode & 0o111 != 0, "{s} is not executable");
        }
        let out = Command::new("sh").arg("-n").arg(&p).output().unwrap();
        assert!(
            out.status.success(),
            "sh -n {s}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // The user the units run as is the one postinst creates.
    let postinst = std::fs::read_to_string(dir.join("postinst")).unwrap();
    let unit = std::fs::read_to_string(root().join("systemd/infraloc.service")).unwrap();
    assert!(unit.contains("\nUser=infraloc\n") && postinst.contains("USER=infraloc\n"));
    for g in ["video", "dialout"] {
        assert!(unit.contains(g) && postinst.contains(g), "group {g}");
    }
}

/// Exposure of infraloc.service with the GigE Vision drop-in (docs/install.md quotes it).
const MAX_GIGE_EXPOSURE: f64 = 2.0;

#[test]
fn gige_dropin_verifies() {
    if Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        common::skip_unless_ci(
            "packaging::gige_dropin_verifies",
            "systemd-analyze not installed (apt-get install systemd; .ci/setup installs it)",
        );
        return;
    }
    // The unit plus its drop-in directory, as on the box (systemd-analyze also reads drop-ins from
    // beside the unit file given).
    let dir = tempfile::tempdir().unwrap();
    let src = root().join("systemd");
    let unit = std::fs::read_to_string(src.join("infraloc.service"))
        .unwrap()
        .replace("/usr/bin/infraloc", env!("CARGO_BIN_EXE_infraloc"));
    std::fs::write(dir.path().join("infraloc.service"), unit).unwrap();
    std::fs::create_dir(dir.path().join("infraloc.service.d")).unwrap();
    std::fs::copy(
        src.join("infraloc.service.d/gige.conf.example"),
        dir.path().join("infraloc.service.d/gige.conf"),
    )
    .unwrap();

    // The man check on: the pages the .deb installs, on MANPATH.
    let man = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["man", "--out"])
        .arg(dir.path().join("man"))
        .status()
        .unwrap();
    assert!(man.success());
    let out = Command::new("systemd-analyze")
        .args(["verify", "./infraloc.service"])
        .current_dir(dir.path())
        .env("MANPATH", dir.path().join("man"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.trim().is_empty(),
        "systemd-analyze verify with gige.conf:\n{err}"
    );

    let out = Command::new("systemd-analyze")
        .args(["security", "--offline=true", "./infraloc.service"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    // The drop-in took effect: the host network is reachable, the allow list is there.
    assert!(
        text.lines().any(|l| l.contains("PrivateNetwork=")
            && l.contains("access to the host's network")
            && !l.contains("no access")),
        "drop-in not applied:\n{text}"
    );
    let line = text
        .lines()
        .find(|l| l.contains("Overall exposure level"))
        .unwrap_or_else(|| panic!("no exposure line in:\n{text}"));
    let score: f64 = line
        .split(':')
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("cannot parse {line:?}"));
    eprintln!("exposure with gige.conf: {score}");
    assert!(
        score <= MAX_GIGE_EXPOSURE,
        "exposure with the GigE drop-in {score} > {MAX_GIGE_EXPOSURE}: {line}"
    );
}

/// The crates of the dependency graph (normal and build edges) for `features` (none: the
/// default build), as `name` per line.
fn graph_crates(features: &[&str]) -> Vec<String> {
    let mut cmd = Command::new(env!("CARGO"));
    cmd.current_dir(root())
        .args([
            "tree",
            "--offline",
            "-e",
            "normal,build",
            "--prefix",
            "none",
        ])
        .args(["--format", "{p}"]);
    if !features.is_empty() {
        cmd.args(["--features", &features.join(",")]);
    }
    let out = cmd.output().expect("cargo tree");
    assert!(
        out.status.success(),
        "cargo tree: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .collect()
}

/// The default build (`cargo run --release -- demo`) needs nothing but a Rust toolchain: no
/// bindgen (libclang), no C compiler driver, no pkg-config/cmake probing for a system library.
/// The `v4l` graph is the control: it must show bindgen, or this check could not fail.
#[test]
fn default_build_needs_no_libclang_or_system_library() {
    const NATIVE: [&str; 5] = ["bindgen", "cc", "pkg-config", "cmake", "system-deps"];
    let default = graph_crates(&[]);
    assert!(default.iter().any(|c| c == "nalgebra"), "{default:?}");
    let native: Vec<&String> = default
        .iter()
        .filter(|c| NATIVE.contains(&c.as_str()))
        .collect();
    assert!(
        native.is_empty(),
        "the default build needs native tooling through {native:?}"
    );
    assert!(graph_crates(&["v4l"]).iter().any(|c| c == "bindgen"));
}

/// The package and the node's cross build have the V4L2 backend the node's camera needs; the
/// default build has none (docs/architecture.md, "Capture backends are cargo features").
#[test]
fn package_and_cross_builds_enable_v4l() {
    let text = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let manifest: toml::Table = toml::from_str(&text).unwrap();
    let default = manifest["features"]["default"].as_array().unwrap();
    assert!(
        !default.iter().any(|f| f.as_str() == Some("v4l")),
        "v4l is a default feature again: the default build would need libclang"
    );
    let meta = deb_metadata();
    let deb_features: Vec<&str> = meta["features"]
        .as_array()
        .expect("[package.metadata.deb] features")
        .iter()
        .filter_map(|f| f.as_str())
        .collect();
    assert!(deb_features.contains(&"v4l"), "{deb_features:?}");
    let cross = std::fs::read_to_string(root().join("cross/build.sh")).unwrap();
    assert!(
        cross.contains("FEATURES=(-p infraloc --features v4l)")
            && cross.contains(r#"build --release --target "$TARGET" "${FEATURES[@]}""#),
        "cross/build.sh no longer builds with --features v4l"
    );
}
