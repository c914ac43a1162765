//! The SLAM core builds without the command-line, plotting and
//! progress-bar crates: in Cargo.toml they are optional, switched on by the
//! `cli`, `plot` and `progress` features, and the library's code names
//! them only where those features gate it (the binaries, `src/plot/`, the
//! rendering progress bar, and `cfg_attr` derives of the settings enums).
//! A program that wants poses depends on `rigslam` with
//! `default-features = false` and gets none of them. The maths modules
//! read no files either.

use std::path::Path;

/// Optional crate, its feature, and the only library files that may name it
/// outside a `#[cfg_attr(feature = ...)]` line.
const GATED: &[(&str, &str, &[&str])] = &[
    ("clap", "cli", &[]),
    ("plotters", "plot", &["src/plot/"]),
    ("indicatif", "progress", &["src/simulate/progress.rs"]),
];

#[path = "common/source_files.rs"]
mod source_files;

use source_files::rust_files;

#[test]
fn optional_crates_are_optional_in_the_manifest() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest: toml::Table = std::fs::read_to_string(root.join("Cargo.toml"))
        .expect("Cargo.toml")
        .parse()
        .expect("Cargo.toml is TOML");
    let deps = manifest["dependencies"].as_table().expect("[dependencies]");
    let features = manifest["features"].as_table().expect("[features]");
    for (krate, feature, _) in GATED {
        let optional = deps[*krate]
            .get("optional")
            .and_then(|v| v.as_bool())
            .unwrap_or(false);
        assert!(optional, "{krate} must be `optional = true`");
        let enables = features[*feature].as_array().expect("feature list");
        assert!(
            enables
                .iter()
                .any(|v| v.as_str() == Some(&format!("dep:{krate}"))),
            "feature {feature} must enable dep:{krate}"
        );
    }
}

#[test]
fn the_library_names_optional_crates_only_behind_their_feature() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let files = rust_files(&root.join("src"));
    let mut offenders = Vec::new();
    for file in &files {
        let rel = file
            .strip_prefix(root)
            .expect("under the crate")
            .to_string_lossy()
            .replace('\\', "/");
        if rel.starts_with("src/bin/") {
            continue; // the binaries require every feature they use
        }
        let text = std::fs::read_to_string(file).expect("readable source");
        for (krate, feature, allowed) in GATED {
            if allowed.iter().any(|a| rel.starts_with(a)) {
                continue;
            }
            for (n, line) in text.lines().enumerate() {
                let code = line.split("//").next().unwrap_or("");
                let names_it =
                    code.contains(&format!("{krate}::")) || code.contains(&format!("use {krate}"));
                let gated = code.contains(&format!("cfg_attr(feature = \"{feature}\""));
                if names_it && !gated {
                    offenders.push(format!("{rel}:{}: {}", n + 1, line.trim()));
                }
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "optional crates named outside their feature:\n{}",
        offenders.join("\n")
    );
}

#[test]
fn the_plot_module_is_gated_in_lib_rs() {
    let lib = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs"))
        .expect("src/lib.rs");
    assert!(
        lib.contains("#[cfg(feature = \"plot\")]\npub mod plot;"),
        "src/lib.rs must declare `pub mod plot` behind #[cfg(feature = \"plot\")]"
    );
}

/// The maths modules read no files: formats and I/O live in `dataset`,
/// `rig`, `recording` and `text_file`, which hand the maths plain values.
#[test]
fn the_maths_modules_read_no_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let test_only = [
        "tests.rs",
        "test_scenes.rs",
        "finite_difference.rs",
        "synthetic.rs",
    ];
    let mut offenders = Vec::new();
    for module in ["camera", "imu", "two_view", "features"] {
        let files = rust_files(&root.join("src").join(module));
        for file in files {
            let name = file.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if test_only.contains(&name) {
                continue;
            }
            let text = std::fs::read_to_string(&file).expect("readable source");
            // Unit tests sit at the end of the file; they may read fixtures.
            let code = text.split("#[cfg(test)]").next().unwrap_or("");
            for (n, line) in code.lines().enumerate() {
                let line = line.split("//").next().unwrap_or("");
                if ["crate::text_file", "std::fs", "File::", "matches_file"]
                    .iter()
                    .any(|io| line.contains(io))
                {
                    offenders.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
                }
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "file I/O in the maths modules:\n{}",
        offenders.join("\n")
    );
}
