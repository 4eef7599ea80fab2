//! The app's commands only parse, call a job and print: the work lives in `anerf-run` (and the viewer) where
//! tests call it. This reads the commands' sources and fails on a function that has grown past
//! `MAX_LINES` lines, the size of "turn flags into a job's arguments, call it, print what it returns".

use std::path::Path;

/// The longest function a command file may hold, signature and closing brace included.
const MAX_LINES: usize = 60;

/// Each function's name and length in lines: from a line opening it (`fn` or `pub fn`, at any
/// indentation) to the first line after it that is `}` at the same indentation.
fn functions(source: &str) -> Vec<(String, usize)> {
    let lines: Vec<&str> = source.lines().collect();
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let body = line.trim_start();
        let indent = &line[..line.len() - body.len()];
        let Some(rest) = body
            .strip_prefix("pub fn ")
            .or_else(|| body.strip_prefix("pub(crate) fn "))
            .or_else(|| body.strip_prefix("fn "))
        else {
            continue;
        };
        let name: String = rest
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let close = format!("{indent}}}");
        let end = lines[i..]
            .iter()
            .position(|l| *l == close)
            .unwrap_or_else(|| panic!("fn {name}: no closing brace at its indentation"));
        found.push((name, end + 1));
    }
    found
}

#[test]
fn the_line_counter_measures_functions_as_written() {
    let source = "pub fn run(a: &A) -> Result<()> {\n    call(a)?;\n    Ok(())\n}\n\nfn print(x: &X) {\n    println!(\"{x}\");\n}\n";
    assert_eq!(
        functions(source),
        vec![("run".to_string(), 4), ("print".to_string(), 3)]
    );
}

#[test]
fn every_command_function_is_short() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/commands");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "rs"))
        .collect();
    files.sort();
    assert!(files.len() >= 16, "the commands' sources: {files:?}");
    let mut too_long = Vec::new();
    let mut runs = 0;
    for file in &files {
        let source = std::fs::read_to_string(file).unwrap();
        for (name, lines) in functions(&source) {
            runs += usize::from(name == "run");
            if lines > MAX_LINES {
                too_long.push(format!("{}: fn {name}, {lines} lines", file.display()));
            }
        }
    }
    assert!(runs >= 15, "found only {runs} `run` functions");
    assert!(
        too_long.is_empty(),
        "command functions over {MAX_LINES} lines (move the work into a job of anerf-run):\n{}",
        too_long.join("\n")
    );
}
