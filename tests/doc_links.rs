//! Every relative link in the user-facing documents points at a file of the
//! repository: the README, docs/, bench/ and the publish README are read
//! by people who follow them.

use std::path::{Path, PathBuf};

/// Targets of the Markdown links `[text](target)` in `text`.
fn link_targets(text: &str) -> Vec<String> {
    let mut targets = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        if let Some(end) = rest.find(')') {
            targets.push(rest[..end].to_string());
            rest = &rest[end..];
        }
    }
    targets
}

fn documents(root: &Path) -> Vec<PathBuf> {
    let mut files = vec![root.join("README.md"), root.join("src/publish/README.md")];
    for dir in ["docs", "docs/results", "bench", "bench/accuracy"] {
        for entry in std::fs::read_dir(root.join(dir)).expect(dir).flatten() {
            if entry.path().extension().is_some_and(|e| e == "md") {
                files.push(entry.path());
            }
        }
    }
    files
}

#[test]
fn relative_links_point_at_files_that_exist() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut broken = Vec::new();
    let mut checked = 0;
    for doc in documents(root) {
        let text = std::fs::read_to_string(&doc).expect("readable document");
        for target in link_targets(&text) {
            let path = target.split('#').next().unwrap_or("");
            if path.is_empty() || path.contains("://") || path.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let resolved = doc.parent().expect("in a folder").join(path);
            if !resolved.exists() {
                broken.push(format!(
                    "{}: {target}",
                    doc.strip_prefix(root).unwrap_or(&doc).display()
                ));
            }
            // The repository speaks of itself alone.
            if resolved
                .canonicalize()
                .is_ok_and(|p| !p.starts_with(root.canonicalize().expect("root")))
            {
                broken.push(format!("{}: {target} leaves the repository", doc.display()));
            }
        }
    }
    assert!(
        checked > 30,
        "only {checked} links found: is the parser broken?"
    );
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn link_targets_are_found() {
    assert_eq!(
        link_targets("see [a](x.md) and [b](y/z.md#s)."),
        ["x.md", "y/z.md#s"]
    );
}
