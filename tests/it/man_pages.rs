//! The manual pages cannot drift: `man/man1/infraloc.1` is exactly what `infraloc man` generates
//! from the clap definitions (every command in it), `man/man5/infraloc.toml.5` has an entry for
//! every key of the config structs and of the shipped config (and no entry for a key that does
//! not exist), and `man -l` renders both without a warning.

use clap::CommandFactory;
use infraloc::camera::Camera;
use infraloc::config::Config;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `infraloc man --out DIR` into a fresh directory.
fn generated() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["man", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "infraloc man: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}

#[test]
fn repository_pages_are_the_generated_ones() {
    let dir = generated();
    for page in ["man1/infraloc.1", "man5/infraloc.toml.5"] {
        let want = std::fs::read_to_string(dir.path().join(page)).unwrap();
        let have = std::fs::read_to_string(root().join("man").join(page)).unwrap_or_default();
        assert!(
            want == have,
            "man/{page} is stale: regenerate with `cargo run --release -- man --out man`"
        );
    }
}

#[test]
fn infraloc_1_has_every_command_and_option() {
    let page = infraloc::cli::man::infraloc_1().unwrap();
    let mut cmd = infraloc::cli::Cli::command();
    cmd.build();
    let leaves = infraloc::cli::man::leaf_commands(&cmd);
    assert!(leaves.len() >= 18, "{} commands", leaves.len());
    for sub in cmd
        .get_subcommands()
        .filter(|s| !s.is_hide_set() && s.get_name() != "help")
    {
        let heading = format!(".SS \"{}", sub.get_bin_name().unwrap());
        assert!(page.contains(&heading), "{} missing", sub.get_name());
    }
    let sections: Vec<&str> = page.split("\n.SS ").collect();
    for sub in leaves {
        let name = sub.get_bin_name().unwrap();
        let section = sections
            .iter()
            .find(|s| s.starts_with(&format!("\"{name}\"\n")))
            .unwrap_or_else(|| panic!("no section for {name}"));
        for arg in sub.get_arguments().filter(|a| !a.is_hide_set()) {
            if let Some(long) = arg.get_long() {
                let flag = format!("\\-\\-{}", long.replace('-', "\\-"));
                assert!(section.contains(&flag), "{name}: {flag} missing");
            }
        }
    }
    assert!(
        !page.contains("\"infraloc man\""),
        "the hidden command is listed"
    );
}

/// `(section, key)` of every key a config can hold: the structs serialised with every optional
/// table and key present (both camera models), so a new field shows up here by itself.
fn struct_keys() -> BTreeSet<(String, String)> {
    let mut keys = BTreeSet::new();
    let mut add = |v: serde_json::Value| {
        for (section, table) in v.as_object().unwrap() {
            for (key, value) in table.as_object().unwrap() {
                if key == "intrinsics" {
                    for k in value.as_object().unwrap().keys() {
                        keys.insert(("camera.intrinsics".to_string(), k.clone()));
                    }
                } else {
                    keys.insert((section.clone(), key.clone()));
                }
            }
        }
    };
    let mut c = Config::default();
    // The required parameters only: those with defaults appear when serialised back.
    for model in ["mei", "equidistant"] {
        let mut v = serde_json::json!({
            "model": model, "width": 640, "height": 480, "fx": 300.0, "fy": 300.0,
            "cx": 320.0, "cy": 240.0, "fov-deg": 185.0,
        });
        if model == "mei" {
            v["xi"] = 1.0.into();
        }
        let cam: Camera = serde_json::from_value(v).unwrap();
        c.camera.intrinsics = Some(cam);
        add(serde_json::to_value(&c).unwrap());
    }
    keys
}

/// `(section, key)` of the shipped config, commented-out examples included.
fn shipped_keys() -> BTreeSet<(String, String)> {
    let text = std::fs::read_to_string(root().join("config/infraloc.toml")).unwrap();
    let mut keys = BTreeSet::new();
    // A commented-out table header (`# [camera.intrinsics]`) holds only for the commented lines
    // after it; the next live key belongs to the last live header again.
    let (mut section, mut commented_section) = (String::new(), None::<String>);
    for line in text.lines() {
        let commented = line.trim_start().starts_with('#');
        let l = line.trim_start_matches('#').trim();
        if let Some(s) = l.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            if commented {
                commented_section = Some(s.to_string());
            } else {
                (section, commented_section) = (s.to_string(), None);
            }
        } else if let Some((k, _)) = l.split_once(" = ") {
            let k = k.trim();
            let is_key = k
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-');
            if !commented {
                commented_section = None;
            }
            let s = commented_section.as_ref().unwrap_or(&section);
            if !s.is_empty() && !k.is_empty() && is_key {
                keys.insert((s.clone(), k.to_string()));
            }
        }
    }
    keys
}

/// `(section, key)` of the page's entries: `.B key` lines under `.SH "[section]"`.
fn page_keys() -> BTreeSet<(String, String)> {
    let page = std::fs::read_to_string(root().join("man/man5/infraloc.toml.5")).unwrap();
    let mut keys = BTreeSet::new();
    let mut section: Option<String> = None;
    let mut after_tp = false;
    for line in page.lines() {
        if let Some(h) = line.strip_prefix(".SH ") {
            section = h
                .trim_matches('"')
                .strip_prefix('[')
                .and_then(|s| s.strip_suffix(']'))
                .map(str::to_string);
        } else if line == ".TP" {
            after_tp = true;
            continue;
        } else if let (true, Some(s), Some(k)) = (after_tp, &section, line.strip_prefix(".B ")) {
            keys.insert((s.clone(), k.replace("\\-", "-")));
        }
        after_tp = false;
    }
    keys
}

#[test]
fn infraloc_toml_5_has_every_config_key() {
    let page = page_keys();
    let structs = struct_keys();
    let shipped = shipped_keys();
    assert!(structs.len() >= 60, "{} keys", structs.len());
    let missing: Vec<_> = structs
        .union(&shipped)
        .filter(|k| !page.contains(k))
        .collect();
    assert!(
        missing.is_empty(),
        "keys without an entry in man/man5/infraloc.toml.5 (add a .TP/.B entry under its \
         table, then `cargo run --release -- man --out man`): {missing:?}"
    );
    let unknown: Vec<_> = page.difference(&structs).collect();
    assert!(
        unknown.is_empty(),
        "entries for keys that do not exist: {unknown:?}"
    );
    let not_in_structs: Vec<_> = shipped.difference(&structs).collect();
    assert!(
        not_in_structs.is_empty(),
        "shipped config keys the structs lack: {not_in_structs:?}"
    );
}

/// `man -l` renders `page` (a path) with no warning; its text.
fn render(page: &Path) -> String {
    let out = Command::new("man")
        .args(["-l", "--warnings", "-E", "UTF-8"])
        .arg(page)
        .env("MANWIDTH", "100")
        .output()
        .expect("man: .ci/setup installs man-db");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.trim().is_empty(),
        "man -l {}: {err}",
        page.display()
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn man_renders_both_pages() {
    let dir = generated();
    let one = render(&dir.path().join("man1/infraloc.1"));
    for heading in ["NAME", "SYNOPSIS", "COMMANDS", "EXIT STATUS", "SEE ALSO"] {
        assert!(
            one.contains(&format!("\n{heading}\n")),
            "infraloc(1) lacks {heading}:\n{one}"
        );
    }
    assert!(one.contains("infraloc plot mi-surface"), "{one}");
    let five = render(&dir.path().join("man5/infraloc.toml.5"));
    for heading in [
        "NAME",
        "[camera]",
        "[camera.intrinsics]",
        "[quality]",
        "SEE ALSO",
    ] {
        assert!(
            five.contains(&format!("\n{heading}\n")),
            "infraloc.toml(5) lacks {heading}"
        );
    }
    assert!(five.contains("drift-threshold-deg"), "{five}");
}
