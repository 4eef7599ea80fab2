//! OpenCV `FileStorage` YAML (`%YAML:1.0`), as `cv2.FileStorage` and EasyMocap's own writer produce it for
//! `intri.yml` / `extri.yml`: a top-level mapping of scalars, sequences (block `- "01"` or flow `[ … ]`),
//! nested mappings and `!!opencv-matrix` nodes (`rows`, `cols`, `dt`, `data`). Only this subset is read;
//! anything else (anchors, multi-line strings, other tags) is refused with the line it is on.

use std::path::{Path, PathBuf};

use crate::error::DataError;

/// A dense single-channel matrix, row-major, as stored (`dt` of any numeric kind, read as f64).
#[derive(Debug, Clone, PartialEq)]
pub struct Matrix {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f64>,
}

/// One value of the file.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// A scalar as written, quotes removed.
    Scalar(String),
    Seq(Vec<Node>),
    Map(Vec<(String, Node)>),
    Matrix(Matrix),
}

/// A parsed file: its top-level entries in file order, with the path for errors.
#[derive(Debug, Clone)]
pub struct FileStorage {
    path: PathBuf,
    entries: Vec<(String, Node)>,
}

/// Largest file [`FileStorage::read`] reads, in bytes; parsing takes time and memory linear in the size.
pub const MAX_BYTES: u64 = 8 << 20;

/// Deepest nesting of mappings and lists (blocks and flow lists together); OpenCV's calibration files
/// nest three levels.
pub const MAX_DEPTH: usize = 32;

/// One non-blank line with its indentation (spaces) and 1-based number.
struct Line<'a> {
    number: usize,
    indent: usize,
    text: &'a str,
}

impl FileStorage {
    /// Reads and parses `path` (at most [`MAX_BYTES`]).
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let bytes = super::read_bytes_at_most(
            path,
            MAX_BYTES,
            "an OpenCV calibration file (thousands of cameras take a few megabytes)",
        )?;
        let text = std::str::from_utf8(&bytes)
            .map_err(|e| DataError::invalid(path, format!("is not UTF-8 text: {e}")))?;
        Self::parse(text, path)
    }

    /// Parses `text` (`path` names the file in errors).
    pub fn parse(text: &str, path: &Path) -> Result<Self, DataError> {
        let mut lines = Vec::new();
        let mut header = false;
        for (i, raw) in text.lines().enumerate() {
            let line = strip_comment(raw.trim_end_matches('\r'));
            if line.trim().is_empty() {
                continue;
            }
            if !header {
                if !line.starts_with("%YAML") {
                    return Err(DataError::invalid(
                        path,
                        format!(
                            "line {}: expected the OpenCV header %YAML:1.0, found {:?}",
                            i + 1,
                            line.trim()
                        ),
                    ));
                }
                header = true;
                continue;
            }
            if line.trim() == "---" || line.trim() == "..." {
                continue;
            }
            if line.contains('\t') {
                return Err(DataError::invalid(
                    path,
                    format!("line {}: tabs are not allowed in YAML indentation", i + 1),
                ));
            }
            let indent = line.len() - line.trim_start().len();
            lines.push(Line {
                number: i + 1,
                indent,
                text: line.trim(),
            });
        }
        if !header {
            return Err(DataError::invalid(
                path,
                "is empty; expected OpenCV YAML starting with %YAML:1.0",
            ));
        }
        let mut parser = Parser {
            path,
            lines: &lines,
            at: 0,
            depth: 0,
        };
        let entries = match lines.first() {
            None => Vec::new(),
            Some(first) if first.indent != 0 => {
                return Err(parser.error(first.number, "top-level keys must not be indented"))
            }
            Some(_) => parser.mapping(0)?,
        };
        if let Some(extra) = lines.get(parser.at) {
            return Err(parser.error(
                extra.number,
                format!("unexpected {:?} after the top-level mapping", extra.text),
            ));
        }
        Ok(Self {
            path: path.to_path_buf(),
            entries,
        })
    }

    /// The file this was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The top-level keys in file order.
    pub fn keys(&self) -> impl Iterator<Item = &str> {
        self.entries.iter().map(|(k, _)| k.as_str())
    }

    /// The value of top-level `key`.
    pub fn get(&self, key: &str) -> Option<&Node> {
        self.entries.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    /// The matrix under `key`, `None` when the key is absent; a key holding something else is an error.
    pub fn matrix(&self, key: &str) -> Result<Option<&Matrix>, DataError> {
        match self.get(key) {
            None => Ok(None),
            Some(Node::Matrix(m)) => Ok(Some(m)),
            Some(other) => Err(DataError::invalid(
                &self.path,
                format!("'{key}' is {}, expected an !!opencv-matrix", other.kind()),
            )),
        }
    }

    /// The list of strings under `key` (numbers are taken as written), `None` when the key is absent.
    pub fn strings(&self, key: &str) -> Result<Option<Vec<String>>, DataError> {
        let Some(node) = self.get(key) else {
            return Ok(None);
        };
        let items = match node {
            Node::Seq(items) => items,
            other => {
                return Err(DataError::invalid(
                    &self.path,
                    format!("'{key}' is {}, expected a list of names", other.kind()),
                ))
            }
        };
        items
            .iter()
            .enumerate()
            .map(|(i, item)| match item {
                Node::Scalar(s) => Ok(s.clone()),
                other => Err(DataError::invalid(
                    &self.path,
                    format!("'{key}'[{i}] is {}, expected a name", other.kind()),
                )),
            })
            .collect::<Result<_, _>>()
            .map(Some)
    }
}

impl Node {
    /// What the node is, for messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Node::Scalar(_) => "a scalar",
            Node::Seq(_) => "a list",
            Node::Map(_) => "a mapping",
            Node::Matrix(_) => "a matrix",
        }
    }
}

struct Parser<'a> {
    path: &'a Path,
    lines: &'a [Line<'a>],
    at: usize,
    /// Blocks open around the current line.
    depth: usize,
}

impl Parser<'_> {
    fn error(&self, line: usize, detail: impl std::fmt::Display) -> DataError {
        DataError::invalid(self.path, format!("line {line}: {detail}"))
    }

    /// `key: value` lines at exactly `indent`, each value inline or as a block below it.
    fn mapping(&mut self, indent: usize) -> Result<Vec<(String, Node)>, DataError> {
        let mut entries = Vec::new();
        let mut seen = std::collections::HashSet::new();
        while let Some(line) = self.lines.get(self.at) {
            if line.indent < indent {
                break;
            }
            if line.indent > indent {
                return Err(self.error(line.number, "indented more than the keys before it"));
            }
            if line.text.starts_with('-') {
                return Err(self.error(line.number, "a list item where a key was expected"));
            }
            let (key, rest) = split_key(line.text).ok_or_else(|| {
                self.error(
                    line.number,
                    format!("expected `key: value`, found {:?}", line.text),
                )
            })?;
            count_work(1);
            if !seen.insert(key.clone()) {
                return Err(self.error(line.number, format!("key '{key}' appears twice")));
            }
            let number = line.number;
            self.at += 1;
            let value = self.value(rest, indent, number, &key)?;
            entries.push((key, value));
        }
        Ok(entries)
    }

    /// The value after `key:` on line `number`: inline, a flow list (possibly over several lines), a
    /// matrix, or a block (mapping or list) indented below.
    fn value(
        &mut self,
        rest: &str,
        indent: usize,
        number: usize,
        key: &str,
    ) -> Result<Node, DataError> {
        if let Some(tag) = rest.strip_prefix("!!") {
            let (tag, after) = tag.split_once(char::is_whitespace).unwrap_or((tag, ""));
            if tag != "opencv-matrix" {
                return Err(self.error(number, format!("'{key}': unsupported tag !!{tag}")));
            }
            if !after.trim().is_empty() {
                return Err(self.error(
                    number,
                    format!("'{key}': the matrix's fields must follow on their own lines"),
                ));
            }
            let fields = self.block(indent, number, key)?;
            return match fields {
                Node::Map(fields) => matrix(&fields, key)
                    .map(Node::Matrix)
                    .map_err(|e| self.error(number, e)),
                other => Err(self.error(
                    number,
                    format!(
                        "'{key}': !!opencv-matrix holds {}, expected rows, cols, dt and data",
                        other.kind()
                    ),
                )),
            };
        }
        if rest.starts_with('!') || rest.starts_with('&') || rest.starts_with('*') {
            return Err(self.error(
                number,
                format!("'{key}': tags, anchors and aliases are not supported"),
            ));
        }
        if rest.starts_with('[') {
            let mut text = rest.to_string();
            let mut brackets = Brackets::default();
            brackets.scan(rest);
            while !brackets.closed() {
                let Some(next) = self.lines.get(self.at) else {
                    return Err(self.error(
                        number,
                        format!("'{key}': the list opened here is never closed"),
                    ));
                };
                text.push(' ');
                text.push_str(next.text);
                brackets.scan(next.text);
                self.at += 1;
            }
            return flow_list(&text, self.depth)
                .map_err(|e| self.error(number, format!("'{key}': {e}")));
        }
        if rest.starts_with('{') || rest.starts_with('|') || rest.starts_with('>') {
            return Err(self.error(
                number,
                format!("'{key}': flow mappings and block strings are not supported"),
            ));
        }
        if rest.is_empty() {
            return self.block(indent, number, key);
        }
        scalar(rest)
            .map(Node::Scalar)
            .map_err(|e| self.error(number, format!("'{key}': {e}")))
    }

    /// The block under a key at `indent`: a mapping or a list indented further (a list may also sit at the
    /// key's own indentation, as YAML allows).
    fn block(&mut self, indent: usize, number: usize, key: &str) -> Result<Node, DataError> {
        if self.depth >= MAX_DEPTH {
            return Err(self.error(
                number,
                format!("'{key}' nests deeper than {MAX_DEPTH} levels"),
            ));
        }
        self.depth += 1;
        let node = self.block_below(indent, number, key);
        self.depth -= 1;
        node
    }

    fn block_below(&mut self, indent: usize, number: usize, key: &str) -> Result<Node, DataError> {
        match self.lines.get(self.at) {
            Some(next) if next.text.starts_with('-') && next.indent >= indent => {
                let at = next.indent;
                self.list(at).map(Node::Seq)
            }
            Some(next) if next.indent > indent => {
                let at = next.indent;
                self.mapping(at).map(Node::Map)
            }
            _ => Err(self.error(number, format!("'{key}' has no value"))),
        }
    }

    /// `- item` lines at exactly `indent`; items are scalars or flow lists.
    fn list(&mut self, indent: usize) -> Result<Vec<Node>, DataError> {
        let mut items = Vec::new();
        while let Some(line) = self.lines.get(self.at) {
            if line.indent != indent || !line.text.starts_with('-') {
                break;
            }
            let item = line.text[1..].trim();
            let number = line.number;
            if !line.text[1..].is_empty() && !line.text[1..].starts_with(' ') {
                return Err(self.error(number, format!("expected `- item`, found {:?}", line.text)));
            }
            self.at += 1;
            items.push(if item.starts_with('[') {
                flow_list(item, self.depth).map_err(|e| self.error(number, e))?
            } else {
                Node::Scalar(scalar(item).map_err(|e| self.error(number, e))?)
            });
        }
        Ok(items)
    }
}

/// `rows`, `cols`, `dt` and `data` of an `!!opencv-matrix`, with `data` holding `rows × cols` numbers.
fn matrix(fields: &[(String, Node)], key: &str) -> Result<Matrix, String> {
    let field = |name: &str| {
        fields
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v)
            .ok_or_else(|| format!("'{key}': !!opencv-matrix has no '{name}'"))
    };
    let count = |name: &str| -> Result<usize, String> {
        match field(name)? {
            Node::Scalar(s) => s
                .parse()
                .map_err(|_| format!("'{key}': {name} is {s:?}, expected a whole number")),
            other => Err(format!(
                "'{key}': {name} is {}, expected a number",
                other.kind()
            )),
        }
    };
    let (rows, cols) = (count("rows")?, count("cols")?);
    let single = match field("dt")? {
        Node::Scalar(dt) if ["d", "f", "i", "u", "s", "w", "c"].contains(&dt.as_str()) => dt == "f",
        Node::Scalar(dt) => {
            return Err(format!(
                "'{key}': dt {dt:?} is not a single-channel type (expected d, f, i, u, s, w or c)"
            ))
        }
        other => {
            return Err(format!(
                "'{key}': dt is {}, expected a type letter",
                other.kind()
            ))
        }
    };
    let data = match field("data")? {
        Node::Seq(items) => items
            .iter()
            .enumerate()
            .map(|(i, item)| match item {
                // A float32 matrix holds the nearest f32 of each printed value, as OpenCV reads it.
                Node::Scalar(s) => number(s)
                    .map(|x| if single { f64::from(x as f32) } else { x })
                    .ok_or_else(|| format!("'{key}': data[{i}] is {s:?}, not a number")),
                other => Err(format!(
                    "'{key}': data[{i}] is {}, expected a number",
                    other.kind()
                )),
            })
            .collect::<Result<Vec<f64>, String>>()?,
        other => {
            return Err(format!(
                "'{key}': data is {}, expected a list of numbers",
                other.kind()
            ))
        }
    };
    if data.len() != rows * cols {
        return Err(format!(
            "'{key}': !!opencv-matrix of {rows} rows × {cols} cols has {} data values, expected {}",
            data.len(),
            rows * cols
        ));
    }
    Ok(Matrix { rows, cols, data })
}

/// A number as OpenCV writes it (`1.5e-01`, `3.`, `-.Inf`, `.Nan`).
pub fn number(s: &str) -> Option<f64> {
    match s.to_ascii_lowercase().as_str() {
        ".nan" => Some(f64::NAN),
        ".inf" | "+.inf" => Some(f64::INFINITY),
        "-.inf" => Some(f64::NEG_INFINITY),
        _ => s.parse().ok(),
    }
}

/// The line without a `#` comment (a `#` inside quotes is kept).
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), c) if c == q => quote = None,
            (None, '#') if i == 0 || line[..i].ends_with(char::is_whitespace) => return &line[..i],
            _ => {}
        }
    }
    line
}

/// `key: rest` (the key possibly quoted), or `None` when the line has no `:` separator outside quotes.
fn split_key(text: &str) -> Option<(String, &str)> {
    let (key, rest) = if let Some(quoted) = text.strip_prefix('"') {
        let end = quoted.find('"')?;
        (
            quoted[..end].to_string(),
            quoted[end + 1..].trim_start().strip_prefix(':')?,
        )
    } else {
        let at = text
            .find(": ")
            .or_else(|| text.strip_suffix(':').map(|k| k.len()))?;
        (text[..at].trim().to_string(), &text[at + 1..])
    };
    (!key.is_empty()).then(|| (key, rest.trim()))
}

/// A plain or quoted scalar, quotes removed (`\"` and `\\` unescaped in double quotes).
fn scalar(text: &str) -> Result<String, String> {
    let text = text.trim();
    for q in ['"', '\''] {
        if let Some(inner) = text.strip_prefix(q) {
            let inner = inner
                .strip_suffix(q)
                .ok_or_else(|| format!("unterminated quoted string {text}"))?;
            return Ok(if q == '"' {
                inner.replace("\\\"", "\"").replace("\\\\", "\\")
            } else {
                inner.replace("''", "'")
            });
        }
    }
    Ok(text.to_string())
}

/// The `[`/`]` balance of a flow list read line by line: each line is scanned once, so a list over many
/// lines is read in linear time.
#[derive(Default)]
struct Brackets {
    depth: i64,
    quote: Option<char>,
}

impl Brackets {
    fn scan(&mut self, text: &str) {
        count_work(text.len());
        for c in text.chars() {
            match (self.quote, c) {
                (None, '"' | '\'') => self.quote = Some(c),
                (Some(q), c) if c == q => self.quote = None,
                (None, '[') => self.depth += 1,
                (None, ']') => self.depth -= 1,
                _ => {}
            }
        }
    }

    /// Whether every `[` opened outside quotes is closed.
    fn closed(&self) -> bool {
        self.depth <= 0
    }
}

/// `[ a, b, [c, d] ]`: a flow list of scalars and nested lists, inside `depth` blocks.
fn flow_list(text: &str, depth: usize) -> Result<Node, String> {
    let chars: Vec<char> = text.trim().chars().collect();
    count_work(chars.len());
    let mut at = 0;
    let node = flow_item(&chars, &mut at, depth)?;
    if chars[at..].iter().any(|c| !c.is_whitespace()) {
        return Err(format!(
            "unexpected text after the list: {:?}",
            chars[at..].iter().collect::<String>()
        ));
    }
    Ok(node)
}

fn flow_item(chars: &[char], at: &mut usize, depth: usize) -> Result<Node, String> {
    while chars.get(*at).is_some_and(|c| c.is_whitespace()) {
        *at += 1;
    }
    if chars.get(*at) != Some(&'[') {
        let start = *at;
        let mut quote = None;
        while let Some(&c) = chars.get(*at) {
            match (quote, c) {
                (None, '"' | '\'') => quote = Some(c),
                (Some(q), c) if c == q => quote = None,
                (None, ',' | ']') => break,
                _ => {}
            }
            *at += 1;
        }
        return scalar(&chars[start..*at].iter().collect::<String>()).map(Node::Scalar);
    }
    if depth >= MAX_DEPTH {
        return Err(format!("lists nest deeper than {MAX_DEPTH} levels"));
    }
    *at += 1;
    let mut items = Vec::new();
    loop {
        while chars.get(*at).is_some_and(|c| c.is_whitespace()) {
            *at += 1;
        }
        match chars.get(*at) {
            None => return Err("unclosed list".into()),
            Some(']') => {
                *at += 1;
                return Ok(Node::Seq(items));
            }
            _ => {}
        }
        items.push(flow_item(chars, at, depth + 1)?);
        while chars.get(*at).is_some_and(|c| c.is_whitespace()) {
            *at += 1;
        }
        match chars.get(*at) {
            Some(',') => *at += 1,
            Some(']') => {}
            Some(c) => return Err(format!("expected ',' or ']' in a list, found {c:?}")),
            None => return Err("unclosed list".into()),
        }
    }
}

#[cfg(test)]
thread_local! {
    /// Characters scanned and keys checked by the parser on this thread: what the tests count to show
    /// that reading is linear in the file's size.
    static WORK: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Counts `n` units of the parser's work (in tests; nothing otherwise).
fn count_work(_n: usize) {
    #[cfg(test)]
    WORK.with(|w| w.set(w.get() + _n));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parser's work for `text` (characters scanned, keys checked).
    fn work_for(text: &str) -> usize {
        let before = WORK.with(std::cell::Cell::get);
        let _ = FileStorage::parse(text, Path::new("w.yml"));
        WORK.with(std::cell::Cell::get) - before
    }

    /// A flow list over many lines and a mapping of many keys are read in time linear in their size:
    /// doubling the file doubles the work (the quadratic reader's grew fourfold).
    #[test]
    fn large_flat_files_are_read_in_linear_work() {
        let flow = |n: usize| {
            let mut t = String::from("%YAML:1.0\nnames: [\n");
            for i in 0..n {
                t.push_str(&format!("  \"{i:06}\",\n"));
            }
            t.push_str("  \"end\" ]\n");
            t
        };
        let keys = |n: usize| {
            let mut t = String::from("%YAML:1.0\n");
            for i in 0..n {
                t.push_str(&format!("key_{i:06}: {i}\n"));
            }
            t
        };
        for (name, make) in [
            ("flow list", &flow as &dyn Fn(usize) -> String),
            ("keys", &keys),
        ] {
            let (small, large) = (work_for(&make(20_000)), work_for(&make(40_000)));
            let ratio = large as f64 / small as f64;
            assert!(
                (1.8..=2.2).contains(&ratio),
                "{name}: work {small} then {large}, ratio {ratio:.2}"
            );
        }
        assert!(FileStorage::parse(&flow(20_000), Path::new("w.yml")).is_ok());
        assert!(FileStorage::parse(&keys(20_000), Path::new("w.yml")).is_ok());
    }

    /// 50,000 nested brackets (a 100 KB file) or 5,000 nested mappings are refused at the depth limit,
    /// naming it, instead of overflowing the stack.
    #[test]
    fn deep_nesting_is_refused_at_the_limit() {
        let brackets = format!(
            "%YAML:1.0\nk: {}{}\n",
            "[".repeat(50_000),
            "]".repeat(50_000)
        );
        let err = FileStorage::parse(&brackets, Path::new("deep.yml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("deep.yml") && err.contains("deeper than 32"),
            "{err}"
        );
        let mut nested = String::from("%YAML:1.0\n");
        for level in 0..5_000 {
            nested.push_str(&format!("{}k{level}:\n", " ".repeat(level)));
        }
        nested.push_str(&format!("{}leaf: 1\n", " ".repeat(5_000)));
        let err = FileStorage::parse(&nested, Path::new("deep.yml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("deeper than 32"), "{err}");
        // 32 levels are read.
        let ok = format!("%YAML:1.0\nk: {}1{}\n", "[".repeat(31), "]".repeat(31));
        assert!(FileStorage::parse(&ok, Path::new("ok.yml")).is_ok());
    }

    fn parse(text: &str) -> Result<FileStorage, DataError> {
        FileStorage::parse(text, Path::new("test.yml"))
    }

    #[test]
    fn reads_opencv_and_easymocap_writers_output() {
        // cv2.FileStorage's wrapped data and block list, then EasyMocap's own writer (CRLF, quoted names).
        let cv = "%YAML:1.0\n---\nnames:\n   - \"01\"\n   - \"02\"\nK_01: !!opencv-matrix\n   rows: 2\n   cols: 3\n   dt: d\n   data: [ 1.5e+03, 0., -2.,\n       .Nan, 3, -.Inf ]\n";
        let fs = parse(cv).unwrap();
        assert_eq!(fs.strings("names").unwrap().unwrap(), ["01", "02"]);
        let k = fs.matrix("K_01").unwrap().unwrap();
        assert_eq!((k.rows, k.cols), (2, 3));
        assert_eq!(&k.data[..3], &[1500.0, 0.0, -2.0]);
        assert!(k.data[3].is_nan() && k.data[5] == f64::NEG_INFINITY);
        let emc = "%YAML:1.0\r\n---\r\nnames:\r\n  - \"1\"\r\nT_1: !!opencv-matrix\r\n  rows: 3\r\n  cols: 1\r\n  dt: d\r\n  data: [0.100, -0.200, 3.000] # metres\r\n";
        let fs = parse(emc).unwrap();
        assert_eq!(fs.strings("names").unwrap().unwrap(), ["1"]);
        assert_eq!(fs.matrix("T_1").unwrap().unwrap().data, [0.1, -0.2, 3.0]);
        assert_eq!(fs.matrix("absent").unwrap(), None);
        let flow = parse("%YAML:1.0\nnames: [ \"a\", b ]\n").unwrap();
        assert_eq!(flow.strings("names").unwrap().unwrap(), ["a", "b"]);
    }

    #[test]
    fn malformed_files_name_the_line_and_key() {
        let cases = [
            ("K: 1\n", "%YAML:1.0"),
            (
                "%YAML:1.0\nK: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [1, 2]\n",
                "3 rows × 3 cols has 2 data values",
            ),
            (
                "%YAML:1.0\nK: !!opencv-matrix\n  rows: 3\n  dt: d\n  data: [1]\n",
                "has no 'cols'",
            ),
            (
                "%YAML:1.0\nK: !!opencv-matrix\n  rows: 1\n  cols: 1\n  dt: 3d\n  data: [1]\n",
                "single-channel",
            ),
            (
                "%YAML:1.0\nK: !!opencv-matrix\n  rows: 1\n  cols: 2\n  dt: d\n  data: [1, x]\n",
                "data[1]",
            ),
            ("%YAML:1.0\nK: [1, 2\n", "never closed"),
            ("%YAML:1.0\nK: 1\nK: 2\n", "line 3: key 'K' appears twice"),
            ("%YAML:1.0\nK: !!binary abc\n", "unsupported tag"),
            ("%YAML:1.0\nK: &a 1\n", "anchors"),
            ("%YAML:1.0\nK:\n", "'K' has no value"),
            ("%YAML:1.0\n  K: 1\n", "must not be indented"),
        ];
        for (text, expected) in cases {
            let err = parse(text).unwrap_err().to_string();
            assert!(
                err.contains("test.yml") && err.contains(expected),
                "{text:?}: {err}"
            );
        }
        let fs = parse("%YAML:1.0\nK: 1\nnames: 2\n").unwrap();
        assert!(fs
            .matrix("K")
            .unwrap_err()
            .to_string()
            .contains("'K' is a scalar"));
        assert!(fs
            .strings("names")
            .unwrap_err()
            .to_string()
            .contains("expected a list"));
    }
}
