//! The floors of the house (DESIGN.md, "The house"), checked: no module imports a module on
//! a higher floor. Reads every `rust/src/**/*.rs`, collects the top-level module of each
//! `crate::…` path in its code (`use crate::…`, `use crate::{…}`, inline `crate::…::` paths
//! and `super::` chains that climb out of their top-level module), and fails naming the
//! file and the import where one runs up a floor.
//!
//! Only library code counts: `tests.rs` files, files under a `tests/` folder and items
//! under `#[cfg(test)]` are skipped (a test may build a scene from `scenes` to exercise a
//! lower floor). Comments and string literals are skipped too.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The floors, bottom up: a module may import its own floor and the floors below it. The
/// order is DESIGN.md's listing with what it leaves out filled in and one departure:
/// - Floor 0 holds the small shared modules DESIGN names (`math`, `error`, `simd`) and the
///   others like them (`alloc`, `files`, `image`, `moments`, `parallel`, `stop`).
/// - `camera` sits above `geometry`, not beside `bsdf` as DESIGN lists it: its G-buffer
///   traces the camera's rays through the scene's BVH.
/// - `testing` (ray sets and helpers shared by benches, peer scripts and tests) builds
///   scenes and records, so it sits above `visibility`; below `py`, which exposes it.
/// - `py` is the top floor and may import anything.
const FLOORS: &[&[&str]] = &[
    &[
        "alloc", "error", "math", "simd", "files", "image", "moments", "parallel", "stop",
    ],
    &["spatial"],
    &["sampling"],
    &["bsdf"],
    &["lights"],
    &["geometry"],
    &["camera"],
    &["scenes"],
    &["visibility"],
    &["estimators"],
    &["render"],
    &["testing"],
    &["py"],
];

/// What the crate root re-exports, by the module that defines it (`crate::Result` is
/// `error`'s).
const ROOT_ITEMS: &[(&str, &str)] = &[("Error", "error"), ("Result", "error")];

/// Imports that run up a floor today, each with the reason it is allowed for now: `(file
/// under rust/src, imported top-level module)`. The test fails on any other upward import,
/// and on an entry here that no longer occurs (remove it then).
const KNOWN_UPWARD: &[(&str, &str)] = &[];

/// Files skipped whole: test-only code (this file is compiled only for tests).
fn is_test_file(rel: &Path) -> bool {
    rel.file_name()
        .is_some_and(|n| n == "tests.rs" || n == "floors.rs")
        || rel.components().any(|c| c.as_os_str() == "tests")
}

fn floor_of(module: &str) -> Option<usize> {
    FLOORS.iter().position(|floor| floor.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .expect("a readable source folder")
        .map(|e| e.expect("a directory entry").path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Whether `rest`, the text after a quote, continues a character literal (`x'` or `\…'`)
/// rather than a lifetime or a label.
fn is_char_literal(rest: &str) -> bool {
    let mut chars = rest.chars();
    match chars.next() {
        Some('\\') => true,
        Some(_) => chars.next() == Some('\''),
        None => false,
    }
}

/// `text` with comments and string and character literals replaced by spaces (a lifetime's
/// quote is kept: it opens no literal).
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            out.push(b' ');
        } else if b[i] == b'r'
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'))
            && (b[i + 1..].starts_with(b"\"") || b[i + 1..].starts_with(b"#"))
        {
            // A raw string r"…" or r#"…"#, else an identifier starting with r.
            let hashes = b[i + 1..].iter().take_while(|&&c| c == b'#').count();
            if b.get(i + 1 + hashes) == Some(&b'"') {
                let close: Vec<u8> = std::iter::once(b'"')
                    .chain(std::iter::repeat_n(b'#', hashes))
                    .collect();
                i += 2 + hashes;
                while i < b.len() && !b[i..].starts_with(&close) {
                    i += 1;
                }
                i += close.len();
                out.push(b' ');
            } else {
                out.push(b[i]);
                i += 1;
            }
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push(b' ');
        } else if b[i] == b'\'' && is_char_literal(&text[i + 1..]) {
            // A character literal: 'x' or '\…'.
            i += 1;
            while i < b.len() && b[i] != b'\'' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push(b' ');
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).expect("ASCII edits of UTF-8 text")
}

/// `code` without the items under `#[cfg(test)]` (an item ends at its first `;` or at the
/// brace that closes its first `{`).
fn without_test_items(code: &str) -> String {
    const ATTR: &str = "#[cfg(test)]";
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = rest.find(ATTR) {
        out.push_str(&rest[..at]);
        let item = &rest[at + ATTR.len()..];
        let b = item.as_bytes();
        let mut i = 0;
        // Further attributes of the item.
        loop {
            while i < b.len() && b[i].is_ascii_whitespace() {
                i += 1;
            }
            if b[i..].starts_with(b"#[") {
                let mut depth = 0;
                while i < b.len() {
                    match b[i] {
                        b'[' => depth += 1,
                        b']' => {
                            depth -= 1;
                            if depth == 0 {
                                i += 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                    i += 1;
                }
            } else {
                break;
            }
        }
        while i < b.len() && b[i] != b';' && b[i] != b'{' {
            i += 1;
        }
        if i < b.len() && b[i] == b'{' {
            let mut depth = 0;
            while i < b.len() {
                match b[i] {
                    b'{' => depth += 1,
                    b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            break;
                        }
                    }
                    _ => {}
                }
                i += 1;
            }
        }
        rest = &item[(i + 1).min(item.len())..];
    }
    out.push_str(rest);
    out
}

/// The identifiers at the head of each path a `crate::` (or a `super::` chain out of the
/// file's top-level module) at byte `at` of `code` starts: one for `crate::a::…`, one per
/// entry for `crate::{a::…, b}`.
fn heads_after(code: &str, at: usize) -> Vec<String> {
    let rest = code[at..].trim_start();
    let ident = |s: &str| -> String {
        s.trim_start()
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    if let Some(group) = rest.strip_prefix('{') {
        let mut heads = Vec::new();
        let mut depth = 0;
        let mut start = 0;
        for (i, c) in group.char_indices() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => {
                    heads.push(ident(&group[start..i]));
                    break;
                }
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    heads.push(ident(&group[start..i]));
                    start = i + 1;
                }
                _ => {}
            }
        }
        heads.retain(|h| !h.is_empty() && h != "self");
        heads
    } else {
        let h = ident(rest);
        if h.is_empty() {
            Vec::new()
        } else {
            vec![h]
        }
    }
}

/// The top-level modules `code` (of the file at `module`, its module path under the crate
/// root) imports, each with the text of the import's start.
fn imports(code: &str, module: &[String]) -> Vec<(String, String)> {
    let bytes = code.as_bytes();
    let is_ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut out = Vec::new();
    let mut i = 0;
    while i < code.len() {
        let boundary = i == 0 || !(is_ident(bytes[i - 1]) || matches!(bytes[i - 1], b':' | b'$'));
        if boundary && code[i..].starts_with("crate::") {
            let at = i + "crate::".len();
            for head in heads_after(code, at) {
                let shown: String = code[i..].chars().take(60).collect();
                out.push((head, shown.lines().next().unwrap_or("").to_string()));
            }
            i = at;
        } else if boundary && code[i..].starts_with("super::") {
            // A chain of `super::` that climbs to the crate root names a top-level module.
            let mut j = i;
            let mut ups = 0;
            while code[j..].starts_with("super::") {
                ups += 1;
                j += "super::".len();
            }
            if ups >= module.len() {
                for head in heads_after(code, j) {
                    let shown: String = code[i..].chars().take(60).collect();
                    out.push((head, shown.lines().next().unwrap_or("").to_string()));
                }
            }
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn no_module_imports_a_higher_floor() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("rust/src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    assert!(files.len() > 50, "found only {} files", files.len());
    let mut wrong = Vec::new();
    let mut known_seen = BTreeSet::new();
    for path in &files {
        let rel = path.strip_prefix(&src).expect("a file under rust/src");
        if rel == Path::new("lib.rs") || is_test_file(rel) {
            continue;
        }
        let rel_name = rel.to_string_lossy().replace('\\', "/");
        // The module path: `a/b/c.rs` is a::b::c, `a/b/mod.rs` is a::b.
        let mut module: Vec<String> = rel
            .with_extension("")
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        if module.last().is_some_and(|m| m == "mod") {
            module.pop();
        }
        let top = module[0].clone();
        let Some(own) = floor_of(&top) else {
            wrong.push(format!("{rel_name}: module `{top}` has no floor in FLOORS"));
            continue;
        };
        let text = std::fs::read_to_string(path).expect("a readable source file");
        let code = without_test_items(&code_only(&text));
        for (head, shown) in imports(&code, &module) {
            let head = ROOT_ITEMS
                .iter()
                .find(|(item, _)| *item == head)
                .map_or(head, |(_, defined)| defined.to_string());
            if head == top {
                continue;
            }
            let Some(theirs) = floor_of(&head) else {
                wrong.push(format!(
                    "{rel_name}: `{shown}`: `{head}` has no floor in FLOORS"
                ));
                continue;
            };
            if theirs <= own {
                continue;
            }
            if KNOWN_UPWARD.contains(&(rel_name.as_str(), head.as_str())) {
                known_seen.insert((rel_name.clone(), head.clone()));
                continue;
            }
            wrong.push(format!(
                "{rel_name}: `{shown}` imports `{head}` (floor {theirs}) from `{top}` (floor {own})"
            ));
        }
    }
    for &(file, module) in KNOWN_UPWARD {
        if !known_seen.contains(&(file.to_string(), module.to_string())) {
            wrong.push(format!(
                "KNOWN_UPWARD lists {file} -> {module}, which no longer occurs: remove it"
            ));
        }
    }
    assert!(
        wrong.is_empty(),
        "imports that run up a floor:\n{}",
        wrong.join("\n")
    );
}

/// The scanner itself: each form of import is found, comments, strings and test items are
/// not.
#[test]
fn the_scanner_finds_each_form_of_import() {
    let module = ["lights".to_string(), "envmap".to_string()];
    let code = r#"
use crate::sampling::octahedral::texel_of;
use crate::{bsdf::Material, geometry::{Scene, Hits}};
// use crate::commented::Out;
/// [`crate::docs::Link`]
fn f() -> u32 { let s = "crate::quoted::Str"; crate::render::run(); 1 }
use super::super::camera::Camera;
use super::EnvMap;
#[cfg(test)]
mod tests { use crate::scenes::cornell; }
#[cfg(test)]
use crate::testing::to_world;
"#;
    let found: Vec<String> = imports(&without_test_items(&code_only(code)), &module)
        .into_iter()
        .map(|(head, _)| head)
        .collect();
    assert_eq!(
        found,
        ["sampling", "bsdf", "geometry", "render", "camera"],
        "{found:?}"
    );
}
