//! The layering of docs/architecture.md, checked on the source.
//!
//! - The core crate (`core/`) depends on no crate of the application and on nothing that does
//!   I/O: its `Cargo.toml` names only the listed libraries, so `crate::sim`, `infraloc::cli` or
//!   a capture backend cannot be imported from it (the compiler refuses).
//! - No file of the core names the file system, sockets, processes or a clock.
//! - No import cycle between modules of either crate, `localize/init/` never imports
//!   `localize/refine/`, and the service reaches the search and objective code only through the
//!   core's drift check (`.ci/module_cycles.py`).
//! - The integration tests are one binary (docs/architecture.md "Tests"): no test file directly
//!   in `tests/`, and every file of `tests/it/` a module of its `main.rs`.

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
        "crs-definitions",
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

/// The cycle check sees a cycle that only `super::` paths between two leaf files make (`a/b.rs`
/// and `a/c.rs` naming each other as `super::c` and `super::b`), and names both modules.
#[test]
fn the_cycle_check_finds_a_cycle_of_super_paths_between_leaf_files() {
    let dir = std::env::temp_dir().join(format!("infraloc-cycle-{}", std::process::id()));
    let write = |rel: &str, text: &str| {
        let p = dir.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    };
    write("core/src/lib.rs", "pub mod a;\n");
    write("core/src/a/mod.rs", "pub mod b;\npub mod c;\n");
    write("core/src/a/b.rs", "use super::c::C;\npub struct B;\n");
    write("core/src/a/c.rs", "use super::b::B;\npub struct C;\n");
    write("src/lib.rs", "\n");
    let out = Command::new("python3")
        .arg(root().join(".ci/module_cycles.py"))
        .arg("--root")
        .arg(&dir)
        .output()
        .expect("python3 runs .ci/module_cycles.py");
    std::fs::remove_dir_all(&dir).unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(
        text.contains("cycle: infraloc_core::a::b <-> infraloc_core::a::c"),
        "{text}"
    );
}

/// The longest a function may be: from its `fn` line to its closing brace.
const MAX_FN_LINES: usize = 150;
/// The longest a source file may be, its test code aside.
const MAX_FILE_LINES: usize = 1_200;

/// Every `.rs` file below `dir`, sorted.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The source with every comment, string and character literal blanked to spaces (newlines
/// kept), so that braces, `fn` and attributes are found only where they are code.
fn code_only(src: &str) -> Vec<char> {
    let c: Vec<char> = src.chars().collect();
    let mut out = c.clone();
    let blank = |out: &mut Vec<char>, from: usize, to: usize| {
        for ch in out.iter_mut().take(to.min(c.len())).skip(from) {
            if *ch != '\n' {
                *ch = ' ';
            }
        }
    };
    let ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let mut i = 0;
    while i < c.len() {
        let prev_ident = i > 0 && ident(c[i - 1]);
        match c[i] {
            '/' if c.get(i + 1) == Some(&'/') => {
                let end = (i..c.len()).find(|&j| c[j] == '\n').unwrap_or(c.len());
                blank(&mut out, i, end);
                i = end;
            }
            '/' if c.get(i + 1) == Some(&'*') => {
                // Block comments nest.
                let (mut j, mut depth) = (i + 2, 1);
                while j < c.len() && depth > 0 {
                    if c[j] == '/' && c.get(j + 1) == Some(&'*') {
                        depth += 1;
                        j += 2;
                    } else if c[j] == '*' && c.get(j + 1) == Some(&'/') {
                        depth -= 1;
                        j += 2;
                    } else {
                        j += 1;
                    }
                }
                blank(&mut out, i, j);
                i = j;
            }
            // Raw strings: r"…", r#"…"#, br"…", cr#"…"# (a raw identifier r#name is not one).
            'r' | 'b' | 'c' if !prev_ident => {
                let mut j = i;
                if c[j] != 'r' {
                    j += 1;
                }
                if c.get(j) == Some(&'r') {
                    let mut k = j + 1;
                    while c.get(k) == Some(&'#') {
                        k += 1;
                    }
                    if c.get(k) == Some(&'"') {
                        let hashes = k - j - 1;
                        let mut m = k + 1;
                        while m < c.len()
                            && !(c[m] == '"' && (1..=hashes).all(|h| c.get(m + h) == Some(&'#')))
                        {
                            m += 1;
                        }
                        let end = (m + 1 + hashes).min(c.len());
                        blank(&mut out, k + 1, m);
                        i = end;
                        continue;
                    }
                }
                i += 1;
            }
            '"' => {
                let mut j = i + 1;
                while j < c.len() && c[j] != '"' {
                    j += if c[j] == '\\' { 2 } else { 1 };
                }
                blank(&mut out, i + 1, j);
                i = j + 1;
            }
            // A character literal ('x', '\n', '\u{7f}'), not a lifetime or label ('a).
            '\'' => {
                if c.get(i + 1) == Some(&'\\') {
                    // Past the backslash and the escaped character ('\'' is one literal).
                    let mut j = i + 3;
                    while j < c.len() && c[j] != '\'' {
                        j += 1;
                    }
                    blank(&mut out, i + 1, j);
                    i = j + 1;
                } else if c.get(i + 2) == Some(&'\'') {
                    blank(&mut out, i + 1, i + 2);
                    i += 3;
                } else {
                    i += 1;
                }
            }
            _ => i += 1,
        }
    }
    out
}

/// Index of the brace that closes the one at `open`, in code-only text.
fn closing_brace(code: &[char], open: usize) -> Option<usize> {
    let mut depth = 0usize;
    for (j, ch) in code.iter().enumerate().skip(open) {
        match ch {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return Some(j);
                }
            }
            _ => {}
        }
    }
    None
}

/// Where an item's body or end is: the first `{` or `;` from `from` outside parentheses and
/// brackets (`[u8; 4]` in a signature is not the end).
fn item_end(code: &[char], from: usize) -> Option<(usize, char)> {
    let mut depth = 0i32;
    for (j, &ch) in code.iter().enumerate().skip(from) {
        match ch {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            '{' | ';' if depth == 0 => return Some((j, ch)),
            _ => {}
        }
    }
    None
}

/// Whether code-only `code` has the word `w` at `i` (not part of a longer identifier).
fn word_at(code: &[char], i: usize, w: &str) -> bool {
    let ident = |ch: &char| ch.is_alphanumeric() || *ch == '_';
    w.chars()
        .enumerate()
        .all(|(k, ch)| code.get(i + k) == Some(&ch))
        && !(i > 0 && ident(&code[i - 1]))
        && !code.get(i + w.len()).is_some_and(ident)
}

/// The character ranges of test code: items under `#[test]` or a `#[cfg(…test…)]` attribute
/// (not `cfg(not(test))`), from the attribute to the item's end.
fn test_ranges(code: &[char]) -> Vec<(usize, usize)> {
    let mut ranges = Vec::new();
    let mut i = 0;
    while i + 1 < code.len() {
        if !(code[i] == '#' && code[i + 1] == '[') {
            i += 1;
            continue;
        }
        let Some(close) = (i..code.len()).find(|&j| code[j] == ']') else {
            break;
        };
        let attr: String = code[i + 2..close]
            .iter()
            .filter(|c| !c.is_whitespace())
            .collect();
        let is_test = attr == "test"
            || (attr.starts_with("cfg(") && attr.contains("test") && !attr.contains("not(test"));
        if is_test {
            if let Some((at, ch)) = item_end(code, close + 1) {
                let end = if ch == '{' {
                    closing_brace(code, at).unwrap_or(code.len() - 1)
                } else {
                    at
                };
                ranges.push((i, end));
                i = end + 1;
                continue;
            }
        }
        i = close + 1;
    }
    ranges
}

/// Each function of a file outside its test code: (name, line of `fn`, lines to its closing
/// brace). Functions without a body (trait declarations) and `fn` pointer types are not counted.
fn functions(code: &[char], tests: &[(usize, usize)]) -> Vec<(String, usize, usize)> {
    let line_of = |at: usize| 1 + code[..at].iter().filter(|c| **c == '\n').count();
    let mut out = Vec::new();
    for i in 0..code.len() {
        if !word_at(code, i, "fn") || tests.iter().any(|(a, b)| (*a..=*b).contains(&i)) {
            continue;
        }
        let mut j = i + 2;
        while code.get(j).is_some_and(|c| c.is_whitespace()) {
            j += 1;
        }
        let name: String = code[j..]
            .iter()
            .take_while(|c| c.is_alphanumeric() || **c == '_')
            .collect();
        if name.is_empty() {
            continue;
        }
        if let Some((open, '{')) = item_end(code, j) {
            if let Some(close) = closing_brace(code, open) {
                out.push((name, line_of(i), line_of(close) - line_of(i) + 1));
            }
        }
    }
    out
}

/// Lines of a file outside its test code.
fn product_lines(code: &[char], tests: &[(usize, usize)]) -> usize {
    let lines = |a: usize, b: usize| code[a..=b].iter().filter(|c| **c == '\n').count();
    let total = code.iter().filter(|c| **c == '\n').count();
    total - tests.iter().map(|&(a, b)| lines(a, b)).sum::<usize>()
}

#[test]
fn the_counter_skips_strings_chars_comments_and_tests() {
    let src = r##"
fn one() {
    let s = "}{ fn fake() {";
    let r = r#"}"#;
    let c = ('{', '\'', b'}');
    /* } /* nested } */ fn no() {} */
    // fn nor() {
    let f: fn(u8) -> [u8; 2] = |x| [x; 2];
    'outer: loop { break 'outer; }
}
trait T { fn decl(&self) -> [u8; 3]; }
#[cfg(test)]
mod tests {
    fn in_tests() {
    }
}
fn two<'a>(x: &'a str) -> &'a str {
    x
}
"##;
    let code = code_only(src);
    let tests = test_ranges(&code);
    let fns = functions(&code, &tests);
    assert_eq!(
        fns,
        [("one".to_string(), 2, 9), ("two".to_string(), 17, 3)],
        "{}",
        code.iter().collect::<String>()
    );
    assert_eq!(product_lines(&code, &tests), 19 - 4);
}

#[test]
fn no_function_over_150_lines_and_no_file_over_1200() {
    let mut long = Vec::new();
    let mut files = 0;
    for dir in ["src", "core/src", "examples", "benches"] {
        for p in rust_files(&root().join(dir)) {
            let rel = p.strip_prefix(root()).unwrap().display().to_string();
            let is_test_file = p.file_name().is_some_and(|n| n == "tests.rs")
                || p.components().any(|c| c.as_os_str() == "tests");
            if is_test_file {
                continue;
            }
            files += 1;
            let code = code_only(&std::fs::read_to_string(&p).unwrap());
            let tests = test_ranges(&code);
            for (name, line, n) in functions(&code, &tests) {
                if n > MAX_FN_LINES {
                    long.push(format!("{rel}:{line}: fn {name} is {n} lines"));
                }
            }
            let n = product_lines(&code, &tests);
            if n > MAX_FILE_LINES {
                long.push(format!("{rel}: {n} lines outside its tests"));
            }
        }
    }
    assert!(files > 100, "only {files} source files found");
    assert!(
        long.is_empty(),
        "over {MAX_FN_LINES} lines a function or {MAX_FILE_LINES} a file (cut it into named steps):\n{}",
        long.join("\n")
    );
}

/// A file directly in `tests/` would be a test binary of its own, linking the whole crate again
/// (`SEPARATE` says which may, and why); a file in `tests/it/` without its `mod` line would not
/// be compiled at all, its tests lost.
/// Test binaries that stay apart from `tests/it`, with the reason.
const SEPARATE: [(&str, &str); 1] = [(
    "pose_store_crash.rs",
    "its soak kills a child within milliseconds of its ready line: no other test may compete for the CPU",
)];

#[test]
fn every_test_file_is_a_module_of_the_one_binary() {
    let tests = root().join("tests");
    let mut stray = Vec::new();
    for e in std::fs::read_dir(&tests).unwrap() {
        let p = e.unwrap().path();
        let separate = p
            .file_name()
            .is_some_and(|n| SEPARATE.iter().any(|(f, _)| n == *f));
        if p.extension().is_some_and(|x| x == "rs") && !separate {
            stray.push(p.display().to_string());
        }
    }
    assert!(
        stray.is_empty(),
        "move into tests/it/ as modules: {stray:?}"
    );
    let main = std::fs::read_to_string(tests.join("it/main.rs")).unwrap();
    let declared: Vec<&str> = main
        .lines()
        .filter_map(|l| l.strip_prefix("mod ")?.strip_suffix(';'))
        .collect();
    let mut missing = Vec::new();
    for e in std::fs::read_dir(tests.join("it")).unwrap() {
        let p = e.unwrap().path();
        let name = if p.is_dir() {
            p.file_name().unwrap().to_string_lossy().into_owned()
        } else if p.extension().is_some_and(|x| x == "rs") {
            p.file_stem().unwrap().to_string_lossy().into_owned()
        } else {
            continue;
        };
        if name != "main" && !declared.contains(&name.as_str()) {
            missing.push(name);
        }
    }
    assert!(
        missing.is_empty(),
        "no `mod` line in tests/it/main.rs: {missing:?}"
    );
    assert!(declared.len() > 39, "{} modules declared", declared.len());
}
