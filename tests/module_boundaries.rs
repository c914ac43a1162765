//! The library's module graph has no cycles between sibling modules: in
//! every folder of `src/`, the files and sub-folders depend on each other
//! one way only, so each can be read (and tested) with what it depends on
//! and nothing above it. References are read from the source as `super::`,
//! `self::` and `crate::` paths outside comments, string literals and test
//! code (`#[cfg(test)]` items and `tests.rs` files: a test may exercise
//! two modules together).
//!
//! A cycle that has to stay for a while goes in `ALLOWED` with its
//! reason; an allowed one that disappears fails the test too, so the list
//! stays true. It is empty.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Sibling pairs allowed to depend on each other, `(folder, a, b)`.
const ALLOWED: &[(&str, &str, &str)] = &[];

/// Module path of a source file: `src/relative/window/mod.rs` ->
/// `[relative, window]`, `src/relative/odometry.rs` -> `[relative,
/// odometry]`; the crate roots give `[]`.
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).expect("under src");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().expect("a file name");
    let stem = last.trim_end_matches(".rs");
    if !matches!(stem, "mod" | "lib" | "main") {
        parts.push(stem.to_string());
    }
    parts
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable source folder") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            // The binaries are crates of their own.
            if path.file_name().is_some_and(|n| n == "bin") {
                continue;
            }
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs")
            && path.file_name().is_some_and(|n| n != "tests.rs")
        {
            out.push(path);
        }
    }
}

/// The code of a file without its comments (line comments, doc comments
/// and block comments), so that doc links are not counted as uses.
fn code_only(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("//") {
            rest = r.find('\n').map_or("", |i| &r[i..]);
        } else if let Some(r) = rest.strip_prefix("/*") {
            rest = r.find("*/").map_or("", |i| &r[i + 2..]);
        } else if let Some(len) = char_literal(rest) {
            rest = &rest[len..];
            out.push_str("' '");
        } else if rest.starts_with('"') {
            // Skip string literals ("crate::..." in a message is no use).
            let bytes = rest.as_bytes();
            let mut i = 1;
            while i < bytes.len() && bytes[i] != b'"' {
                i += if bytes[i] == b'\\' { 2 } else { 1 };
            }
            rest = &rest[(i + 1).min(rest.len())..];
            out.push_str("\"\"");
        } else {
            let c = rest.chars().next().expect("not empty");
            out.push(c);
            rest = &rest[c.len_utf8()..];
        }
    }
    without_test_items(&out)
}

/// The length of a char literal at the start of `text` (`'{'`, `'\n'`),
/// if there is one (a lifetime `'a` is not).
fn char_literal(text: &str) -> Option<usize> {
    let mut chars = text.char_indices();
    if chars.next()?.1 != '\'' {
        return None;
    }
    let (_, c) = chars.next()?;
    if c == '\\' {
        chars.next()?;
    }
    let (i, close) = chars.next()?;
    (close == '\'').then_some(i + 1)
}

/// `code` without its `#[cfg(test)]` items (a `mod tests { ... }`, a
/// helper function, a `mod x;` declaration).
fn without_test_items(code: &str) -> String {
    const MARK: &str = "#[cfg(test)]";
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = rest.find(MARK) {
        out.push_str(&rest[..at]);
        let item = &rest[at + MARK.len()..];
        let brace = item.find('{');
        let semi = item.find(';');
        let end = match (brace, semi) {
            (Some(b), Some(s)) if s < b => s + 1,
            (None, Some(s)) => s + 1,
            (Some(b), _) => {
                let mut depth = 0usize;
                let mut end = item.len();
                for (i, c) in item[b..].char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                end = b + i + 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                }
                end
            }
            (None, None) => item.len(),
        };
        rest = &item[end..];
    }
    out.push_str(rest);
    out
}

/// The module paths a file refers to, as absolute segment lists (the item
/// name may be the last segment; only prefixes are compared). A use group
/// (`super::{a::X, b}`) gives one path per member.
fn references(code: &str, here: &[String]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for start in ["crate::", "super::", "self::"] {
        let mut from = 0;
        while let Some(pos) = code[from..].find(start) {
            let at = from + pos;
            from = at + start.len();
            if at > 0 && code[..at].chars().next_back().is_some_and(ident) {
                continue;
            }
            let (segments, rest) = path_at(&code[at..]);
            // `self` is this module, `super` its parent (the module path
            // of a leaf file ends with its own name, of a `mod.rs` with its
            // folder's), each further `super` one more up.
            let mut iter = segments.iter().peekable();
            let mut path: Vec<String> = match *iter.next().expect("a prefix") {
                "crate" => Vec::new(),
                "self" => here.to_vec(),
                _ => {
                    let mut up = here.to_vec();
                    up.pop();
                    while iter.peek() == Some(&&"super") {
                        iter.next();
                        up.pop();
                    }
                    up
                }
            };
            path.extend(iter.map(|s| s.to_string()));
            expand_group(path, rest, &mut out);
        }
    }
    out
}

fn ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The `::`-joined segments at the start of `text` and what follows them.
fn path_at(text: &str) -> (Vec<&str>, &str) {
    let end = text
        .find(|c: char| !(ident(c) || c == ':'))
        .unwrap_or(text.len());
    let segments = text[..end].split("::").filter(|s| !s.is_empty()).collect();
    (segments, &text[end..])
}

/// Pushes `prefix` and, when `rest` opens a use group, `prefix` joined
/// with each of its members (nested groups too).
fn expand_group(prefix: Vec<String>, rest: &str, out: &mut Vec<Vec<String>>) {
    if let Some(group) = rest.strip_prefix('{') {
        let mut depth = 0usize;
        let mut member_start = 0;
        for (i, c) in group.char_indices() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => {
                    member(&prefix, &group[member_start..i], out);
                    break;
                }
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    member(&prefix, &group[member_start..i], out);
                    member_start = i + 1;
                }
                _ => {}
            }
        }
    }
    out.push(prefix);
}

fn member(prefix: &[String], text: &str, out: &mut Vec<Vec<String>>) {
    let text = text.trim_start();
    let (segments, rest) = path_at(text);
    if segments.is_empty() || segments[0] == "self" {
        return;
    }
    let mut path = prefix.to_vec();
    path.extend(segments.iter().map(|s| s.to_string()));
    expand_group(path, rest, out);
}

#[test]
fn sibling_modules_do_not_depend_on_each_other_both_ways() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    assert!(files.len() > 50, "{} source files found", files.len());
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_path(&src, f)).collect();

    // (folder, from child, to child) for siblings in the same folder.
    let mut edges: BTreeSet<(Vec<String>, String, String)> = BTreeSet::new();
    for file in &files {
        let here = module_path(&src, file);
        let code = code_only(&std::fs::read_to_string(file).expect("readable"));
        for mut t in references(&code, &here) {
            // The deepest module the reference names.
            while !t.is_empty() && !modules.contains(&t) {
                t.pop();
            }
            // The folder shared by both and the children of it they sit in.
            let common = here.iter().zip(&t).take_while(|(a, b)| a == b).count();
            if common >= here.len() || common >= t.len() {
                // One contains the other (a module and its own children or
                // parents): not a sibling dependency.
                continue;
            }
            edges.insert((
                here[..common].to_vec(),
                here[common].clone(),
                t[common].clone(),
            ));
        }
    }
    assert!(
        edges
            .iter()
            .any(|(f, a, b)| f.is_empty() && a == "daemon" && b == "relative"),
        "the scan sees the daemon use the relative stage"
    );

    // Cycles within each folder: strongly connected pairs through paths.
    let mut by_folder: BTreeMap<Vec<String>, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for (folder, a, b) in &edges {
        by_folder
            .entry(folder.clone())
            .or_default()
            .entry(a.clone())
            .or_default()
            .insert(b.clone());
    }
    let reaches = |graph: &BTreeMap<String, BTreeSet<String>>, from: &str, to: &str| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.to_string()];
        while let Some(n) = stack.pop() {
            if n == to {
                return true;
            }
            if seen.insert(n.clone()) {
                if let Some(next) = graph.get(&n) {
                    stack.extend(next.iter().cloned());
                }
            }
        }
        false
    };
    // Every edge on a cycle, as the sorted pair it joins.
    let mut cycles = Vec::new();
    for (folder, graph) in &by_folder {
        for (a, next) in graph {
            for b in next {
                if reaches(graph, b, a) {
                    let (x, y) = if a < b { (a, b) } else { (b, a) };
                    cycles.push((folder.join("::"), x.clone(), y.clone()));
                }
            }
        }
    }
    cycles.sort();
    cycles.dedup();
    let allowed: Vec<(String, String, String)> = ALLOWED
        .iter()
        .map(|(f, a, b)| (f.to_string(), a.to_string(), b.to_string()))
        .collect();
    let unexpected: Vec<_> = cycles.iter().filter(|c| !allowed.contains(c)).collect();
    assert!(
        unexpected.is_empty(),
        "modules that depend on each other (folder, a, b): {unexpected:?}"
    );
    for a in &allowed {
        assert!(
            cycles.contains(a),
            "{a:?} no longer depend on each other: remove them from ALLOWED"
        );
    }
}
