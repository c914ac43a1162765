//! One layout for unit tests in every crate of the workspace: a module's
//! tests are its child module `tests`, written at the end of the file
//! (`#[cfg(test)] mod tests { ... }`) or, when they are long, in the file
//! `tests.rs` beside the module's own children (`foo.rs` ->
//! `foo/tests.rs`, `foo/mod.rs` -> `foo/tests.rs`) declared as
//! `#[cfg(test)] mod tests;`. No `#[path]` attributes and no other names
//! for test modules. Shared test helpers are `#[cfg(test)]` modules of
//! their own names and hold no `#[test]` (docs/architecture.md, "Tests").

use std::path::{Path, PathBuf};

#[path = "common/source_files.rs"]
mod source_files;

use source_files::rust_files;

fn workspace_sources() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for crate_src in ["src", "drivers/src", "calibration/src"] {
        files.extend(rust_files(&root.join(crate_src)));
    }
    assert!(files.len() > 100, "found only {} source files", files.len());
    files
}

/// Problems with the layout in `text`, the file at `path`.
fn layout_problems(path: &Path, text: &str) -> Vec<String> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let mut problems = Vec::new();
    if name.ends_with("_tests.rs") {
        problems.push("a file of tests not named tests.rs".to_string());
    }
    let mut tests_module_at = None;
    for (n, line) in text.lines().enumerate() {
        let code = line.trim_start();
        if code.starts_with("#[path") {
            problems.push(format!("line {}: #[path] attribute", n + 1));
        }
        if let Some(rest) = code.strip_prefix("mod ") {
            let module = rest.trim_end_matches([';', '{', ' ']).trim();
            if module.ends_with("_tests") || module.starts_with("tests_") {
                problems.push(format!("line {}: test module named `{module}`", n + 1));
            }
            if module == "tests" {
                if tests_module_at.is_some() {
                    problems.push(format!("line {}: a second `mod tests`", n + 1));
                }
                tests_module_at = Some(n);
            }
        }
        if code.starts_with("#[test]") && name != "tests.rs" {
            match tests_module_at {
                Some(m) if m < n && rest_is_inline(text, m) => {}
                _ => problems.push(format!("line {}: #[test] outside `mod tests`", n + 1)),
            }
        }
    }
    problems
}

/// Whether the `mod tests` line at index `m` opens an inline module.
fn rest_is_inline(text: &str, m: usize) -> bool {
    text.lines()
        .nth(m)
        .is_some_and(|l| l.trim_end().ends_with('{'))
}

#[test]
fn unit_tests_follow_one_layout() {
    let mut problems = Vec::new();
    for file in workspace_sources() {
        let text = std::fs::read_to_string(&file).expect("readable source");
        for p in layout_problems(&file, &text) {
            problems.push(format!("{}: {p}", file.display()));
        }
        // A tests.rs belongs to the module whose folder holds it.
        if file.file_name().is_some_and(|n| n == "tests.rs") {
            let folder = file.parent().expect("in a folder");
            let owners = [folder.join("mod.rs"), folder.with_extension("rs")];
            let declared = owners.iter().any(|owner| {
                std::fs::read_to_string(owner)
                    .is_ok_and(|t| t.lines().any(|l| l.trim() == "mod tests;"))
            });
            if !declared {
                problems.push(format!("{}: no `mod tests;` in its module", file.display()));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "unit-test layout:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_check_sees_each_kind_of_deviation() {
    let file = Path::new("src/x.rs");
    assert!(layout_problems(
        file,
        "fn a() {}\n#[cfg(test)]\nmod tests {\n    #[test]\n    fn t() {}\n}\n"
    )
    .is_empty());
    let loose = "#[cfg(test)]\n#[test]\nfn t() {}\n";
    assert_eq!(layout_problems(file, loose).len(), 1);
    let renamed = "#[cfg(test)]\nmod named_tests {\n    #[test]\n    fn t() {}\n}\n";
    assert_eq!(layout_problems(file, renamed).len(), 2);
    let path_attr = "#[cfg(test)]\n#[path = \"x_tests.rs\"]\nmod tests;\n";
    assert_eq!(layout_problems(file, path_attr).len(), 1);
    let two = "#[cfg(test)]\nmod tests {\n}\n#[cfg(test)]\nmod tests {\n}\n";
    assert_eq!(layout_problems(file, two).len(), 1);
    assert_eq!(layout_problems(Path::new("src/x_tests.rs"), "").len(), 1);
}
