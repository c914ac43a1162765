//! YAML as OpenCV's `FileStorage` reads it (OpenVINS and VINS-Fusion load
//! their configs through it): the `%YAML:1.0` directive, mappings in block
//! style, every sequence in flow style (`[a, b, c]`, which OpenCV's parser
//! takes at any depth), and a matrix `{rows, cols, dt, data}` tagged
//! `!!opencv-matrix`. Values come from serde (`serde_json::Value`), so no
//! number or string is formatted by hand.

use serde::Serialize;
use serde_json::Value;

/// The document for `value` (a struct or map at the top).
pub fn to_string(value: &impl Serialize) -> String {
    let value = serde_json::to_value(value).expect("numbers, strings and maps serialise");
    let mut out = String::from("%YAML:1.0\n---\n");
    if let Value::Object(map) = &value {
        write_map(map, 0, &mut out);
    }
    out
}

fn is_matrix(map: &serde_json::Map<String, Value>) -> bool {
    map.len() == 4
        && ["rows", "cols", "dt", "data"]
            .iter()
            .all(|k| map.contains_key(*k))
}

fn write_map(map: &serde_json::Map<String, Value>, indent: usize, out: &mut String) {
    let pad = " ".repeat(indent);
    for (key, value) in map {
        match value {
            Value::Object(inner) => {
                let tag = if is_matrix(inner) {
                    " !!opencv-matrix"
                } else {
                    ""
                };
                out.push_str(&format!("{pad}{key}:{tag}\n"));
                write_map(inner, indent + 3, out);
            }
            // Scalars and sequences in JSON's flow syntax, which YAML shares.
            other => out.push_str(&format!("{pad}{key}: {other}\n")),
        }
    }
}

/// An OpenCV matrix of doubles, row-major.
#[derive(Debug, Clone, Serialize)]
pub struct Matrix {
    pub rows: usize,
    pub cols: usize,
    pub dt: &'static str,
    pub data: Vec<f64>,
}

impl Matrix {
    pub fn from_rows<const C: usize>(rows: &[[f64; C]]) -> Self {
        Self {
            rows: rows.len(),
            cols: C,
            dt: "d",
            data: rows.iter().flatten().copied().collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Doc {
        name: &'static str,
        rate: f64,
        list: Vec<Vec<f64>>,
        pose: Matrix,
    }

    #[test]
    fn flow_sequences_block_maps_and_tagged_matrices() {
        let text = to_string(&Doc {
            name: "cam0",
            rate: 20.0,
            list: vec![vec![1.0, 0.5], vec![0.0, 1.0]],
            pose: Matrix::from_rows(&[[1.0, 0.0], [0.0, 1.0]]),
        });
        assert!(text.starts_with("%YAML:1.0\n---\n"), "{text}");
        assert!(text.contains("list: [[1.0,0.5],[0.0,1.0]]"), "{text}");
        assert!(
            text.contains("pose: !!opencv-matrix\n   cols: 2\n"),
            "{text}"
        );
        assert!(text.contains("name: \"cam0\""), "{text}");
        // A YAML parser reads the same values back.
        let body: String = text.lines().skip(1).collect::<Vec<_>>().join("\n");
        let back: serde_yaml::Value = serde_yaml::from_str(&body).expect("YAML");
        assert_eq!(back["rate"].as_f64(), Some(20.0));
        assert_eq!(back["list"][0][1].as_f64(), Some(0.5));
    }
}
