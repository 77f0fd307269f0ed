//! Where a value sits in a scenario's text: every table, array and value of a TOML or JSON document with its
//! dotted path (`targets[1].brdf.roughness`) and byte span, so that a parse error (which the parsers report as a
//! position, or as a span of the enclosing table) and a validation error (which names a path) both become
//! `line:column` and a full field path.

/// What a node holds, as far as error messages need to know.
#[derive(Debug, Clone, PartialEq)]
pub enum NodeKind {
    /// A table (JSON object).
    Table,
    /// An array of this many items.
    Array(usize),
    /// A string with this content.
    Str(String),
    /// A boolean.
    Bool(bool),
    /// A number (or a TOML date), with its source text.
    Scalar(String),
}

/// One value of the document.
#[derive(Debug, Clone, PartialEq)]
pub struct Node {
    /// Dotted path, `""` for the root.
    pub path: String,
    /// Depth (the root is 0).
    pub depth: usize,
    /// Byte span of the value, `start..end`.
    pub span: (usize, usize),
    /// Byte offset of its key (the value's start for array items and the root).
    pub key_start: usize,
    /// What it holds.
    pub kind: NodeKind,
}

/// Every node of a document, in document order (parents before children).
#[derive(Debug, Clone, Default)]
pub struct Nodes(Vec<Node>);

fn child_path(parent: &str, key: &str) -> String {
    if parent.is_empty() { key.to_owned() } else { format!("{parent}.{key}") }
}

impl Nodes {
    /// The nodes of a TOML document (empty if it does not parse).
    pub fn toml(text: &str) -> Self {
        use toml::de::{DeTable, DeValue};
        fn walk(value: &toml::Spanned<DeValue<'_>>, path: String, depth: usize, key_start: usize, out: &mut Vec<Node>) {
            let span = value.span();
            let kind = match value.get_ref() {
                DeValue::Table(_) => NodeKind::Table,
                DeValue::Array(a) => NodeKind::Array(a.len()),
                DeValue::String(s) => NodeKind::Str(s.to_string()),
                DeValue::Boolean(b) => NodeKind::Bool(*b),
                DeValue::Integer(i) => NodeKind::Scalar(i.as_str().to_owned()),
                DeValue::Float(f) => NodeKind::Scalar(f.as_str().to_owned()),
                DeValue::Datetime(d) => NodeKind::Scalar(d.to_string()),
            };
            out.push(Node { path: path.clone(), depth, span: (span.start, span.end), key_start, kind });
            match value.get_ref() {
                DeValue::Table(t) => table(t, &path, depth, out),
                DeValue::Array(items) => {
                    for (i, item) in items.iter().enumerate() {
                        walk(item, format!("{path}[{i}]"), depth + 1, item.span().start, out);
                    }
                }
                _ => {}
            }
        }
        fn table(t: &DeTable<'_>, path: &str, depth: usize, out: &mut Vec<Node>) {
            for (k, v) in t {
                walk(v, child_path(path, k.get_ref()), depth + 1, k.span().start, out);
            }
        }
        let Ok(doc) = DeTable::parse(text) else { return Self::default() };
        let mut out =
            vec![Node { path: String::new(), depth: 0, span: (0, text.len()), key_start: 0, kind: NodeKind::Table }];
        table(doc.get_ref(), "", 0, &mut out);
        Self(out)
    }

    /// The nodes of a JSON document, as far as it is well formed.
    pub fn json(text: &str) -> Self {
        let mut scanner = JsonScanner { text: text.as_bytes(), at: 0, out: Vec::new() };
        scanner.skip_ws();
        let start = scanner.at;
        scanner.value(String::new(), 0, start);
        Self(scanner.out)
    }

    /// The node at exactly `path`.
    pub fn get(&self, path: &str) -> Option<&Node> {
        self.0.iter().find(|n| n.path == path)
    }

    /// The node at `path`, or at its deepest ancestor present in the document.
    pub fn nearest(&self, path: &str) -> Option<&Node> {
        let mut p = path;
        loop {
            if let Some(n) = self.get(p) {
                return Some(n);
            }
            let cut = p.rfind(['.', '['])?;
            p = &p[..cut];
        }
    }

    /// The deepest node whose span is exactly `span`, else the smallest one holding it.
    pub fn at_span(&self, span: (usize, usize)) -> Option<&Node> {
        if let Some(n) = self.0.iter().filter(|n| n.span == span).max_by_key(|n| n.depth) {
            return Some(n);
        }
        self.0
            .iter()
            .filter(|n| n.span.0 <= span.0 && span.1 <= n.span.1.max(n.span.0 + 1))
            .min_by_key(|n| (n.span.1 - n.span.0, usize::MAX - n.depth))
    }

    /// The smallest node holding byte `offset` (end inclusive: parsers report the position after a value).
    pub fn at_offset(&self, offset: usize) -> Option<&Node> {
        self.0
            .iter()
            .filter(|n| n.span.0 <= offset && offset <= n.span.1)
            .min_by_key(|n| (n.span.1 - n.span.0, usize::MAX - n.depth))
    }

    /// The field a deserializer's `message` is about, given the node it was reported at: the missing field
    /// below a table, or the value inside it whose type, content, length or key the message names.
    pub fn refine<'a>(&'a self, node: &'a Node, message: &str) -> (String, Option<&'a Node>) {
        self.refine_with(node, message, &|_| true)
    }

    /// [`Nodes::refine`], where `culprit` settles between several values that fit the message (two `true`s in
    /// one table, where only one should be a number): the first for which it returns true, else the first.
    pub fn refine_with<'a>(
        &'a self,
        node: &'a Node,
        message: &str,
        culprit: &dyn Fn(&Node) -> bool,
    ) -> (String, Option<&'a Node>) {
        let quoted = |after: &str| -> Option<String> {
            let rest = &message[message.find(after)? + after.len()..];
            let (open, close) = match rest.chars().next()? {
                '`' => ('`', '`'),
                '"' => ('"', '"'),
                _ => return None,
            };
            let body = &rest[open.len_utf8()..];
            Some(body[..body.find(close)?].to_owned())
        };
        if let Some(missing) = quoted("missing field ") {
            // the table it is missing from: the node, or the nearest table above it (JSON positions may fall
            // on the last value before the closing brace)
            let mut table = Some(node);
            while let Some(t) = table
                && !matches!(t.kind, NodeKind::Table)
            {
                let cut = t.path.rfind(['.', '[']).unwrap_or(0);
                table = self.get(&t.path[..cut]);
            }
            if let Some(t) = table {
                return (child_path(&t.path, &missing), Some(t));
            }
            return (node.path.clone(), Some(node));
        }
        let mut node = node;
        if !matches!(node.kind, NodeKind::Table | NodeKind::Array(_)) {
            // a parser may point at the wrong value of a table it buffered: then look through the table
            let parent = node.path.rfind(['.', '[']).and_then(|cut| self.get(&node.path[..cut]));
            match parent {
                Some(p) if !culprit(node) => node = p,
                _ => return (node.path.clone(), Some(node)),
            }
        }
        let inside = |pred: &dyn Fn(&Node) -> bool| {
            let fits: Vec<&Node> = self
                .0
                .iter()
                .filter(|n| {
                    // by path, not span: a TOML table's span is its header only
                    n.depth > node.depth
                        && (node.path.is_empty()
                            || n.path.starts_with(&node.path) && n.path[node.path.len()..].starts_with(['.', '[']))
                        && pred(n)
                })
                .collect();
            match fits.len() {
                0 | 1 => fits.first().copied(),
                _ => fits.iter().copied().find(|n| culprit(n)).or(fits.first().copied()),
            }
        };
        let found = if let Some(key) = quoted("unknown field ") {
            inside(&|n| n.path.rsplit('.').next() == Some(key.as_str()))
        } else if let Some(s) = quoted("invalid type: string ").or_else(|| quoted("unknown variant ")) {
            inside(&|n| n.kind == NodeKind::Str(s.clone()))
        } else if message == "expected value" {
            // JSON's word for a number where a name (an enum's variant) belongs
            inside(&|n| matches!(n.kind, NodeKind::Scalar(_)))
        } else if message == "wanted string or table" {
            // TOML's word for a number or boolean where a name (an enum's variant) belongs
            inside(&|n| matches!(n.kind, NodeKind::Scalar(_) | NodeKind::Bool(_)))
        } else if let Some(b) = quoted("invalid type: boolean ") {
            inside(&|n| n.kind == NodeKind::Bool(b == "true"))
        } else if message.contains("invalid type: sequence") {
            // the innermost: a list where a number belongs sits inside the list that holds it
            let arrays: Vec<&Node> = self
                .0
                .iter()
                .filter(|n| {
                    matches!(n.kind, NodeKind::Array(_))
                        && n.depth > node.depth
                        && (node.path.is_empty()
                            || n.path.starts_with(&node.path) && n.path[node.path.len()..].starts_with(['.', '[']))
                })
                .collect();
            arrays
                .iter()
                .copied()
                .find(|n| n.path.ends_with(']') && n.kind == NodeKind::Array(0))
                .or_else(|| arrays.iter().copied().find(|n| n.kind == NodeKind::Array(0)))
                .or(arrays.first().copied())
        } else if message.contains("invalid type: map") {
            // prefer a table with nothing in it (`{}` where a number belongs) over the tables that hold fields
            let has_children = |n: &Node| {
                self.0
                    .iter()
                    .any(|c| c.path.len() > n.path.len() && c.path.starts_with(&n.path) && c.depth == n.depth + 1)
            };
            inside(&|n| matches!(n.kind, NodeKind::Table) && !has_children(n))
                .or_else(|| inside(&|n| matches!(n.kind, NodeKind::Table)))
        } else if let Some(v) = quoted("invalid type: integer ").or_else(|| quoted("invalid type: floating point ")) {
            let v: Option<f64> = v.parse().ok();
            inside(&|n| match &n.kind {
                NodeKind::Scalar(s) => s.replace('_', "").parse::<f64>().ok() == v,
                _ => false,
            })
        } else if let Some(len) = message
            .strip_prefix("invalid length ")
            .and_then(|r| r.split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|d| d.parse::<usize>().ok())
        {
            inside(&|n| n.kind == NodeKind::Array(len))
        } else {
            None
        };
        match found {
            Some(n) => (n.path.clone(), Some(n)),
            None => (node.path.clone(), Some(node)),
        }
    }
}

/// A lenient JSON reader that records every value's path and span; it stops at the first malformed token.
struct JsonScanner<'t> {
    text: &'t [u8],
    at: usize,
    out: Vec<Node>,
}

impl JsonScanner<'_> {
    fn skip_ws(&mut self) {
        while self.at < self.text.len() && self.text[self.at].is_ascii_whitespace() {
            self.at += 1;
        }
    }

    fn peek(&self) -> Option<u8> {
        self.text.get(self.at).copied()
    }

    /// A string's content, the scanner left after its closing quote.
    fn string(&mut self) -> Option<String> {
        if self.peek() != Some(b'"') {
            return None;
        }
        let start = self.at + 1;
        self.at += 1;
        while self.at < self.text.len() {
            match self.text[self.at] {
                b'\\' => self.at += 2,
                b'"' => {
                    let raw = std::str::from_utf8(&self.text[start..self.at]).ok()?;
                    self.at += 1;
                    return Some(serde_json::from_str::<String>(&format!("\"{raw}\"")).unwrap_or_else(|_| raw.into()));
                }
                _ => self.at += 1,
            }
        }
        None
    }

    /// Reads one value (the scanner at its first byte); false if the text is malformed there.
    fn value(&mut self, path: String, depth: usize, key_start: usize) -> bool {
        let start = self.at;
        let index = self.out.len();
        self.out.push(Node {
            path: path.clone(),
            depth,
            span: (start, self.text.len()),
            key_start,
            kind: NodeKind::Scalar(String::new()),
        });
        let ok = match self.peek() {
            Some(b'{') => {
                self.out[index].kind = NodeKind::Table;
                self.at += 1;
                self.members(&path, depth)
            }
            Some(b'[') => {
                self.at += 1;
                let (ok, n) = self.items(&path, depth);
                self.out[index].kind = NodeKind::Array(n);
                ok
            }
            Some(b'"') => match self.string() {
                Some(s) => {
                    self.out[index].kind = NodeKind::Str(s);
                    true
                }
                None => false,
            },
            Some(_) => {
                while self.at < self.text.len() && !b",]} \t\r\n".contains(&self.text[self.at]) {
                    self.at += 1;
                }
                let raw = String::from_utf8_lossy(&self.text[start..self.at]).into_owned();
                self.out[index].kind = match raw.as_str() {
                    "true" => NodeKind::Bool(true),
                    "false" => NodeKind::Bool(false),
                    _ => NodeKind::Scalar(raw),
                };
                self.at > start
            }
            None => false,
        };
        if ok {
            self.out[index].span.1 = self.at;
        }
        ok
    }

    fn members(&mut self, path: &str, depth: usize) -> bool {
        loop {
            self.skip_ws();
            match self.peek() {
                Some(b'}') => {
                    self.at += 1;
                    return true;
                }
                Some(b',') => self.at += 1,
                Some(b'"') => {
                    let key_start = self.at;
                    let Some(key) = self.string() else { return false };
                    self.skip_ws();
                    if self.peek() != Some(b':') {
                        return false;
                    }
                    self.at += 1;
                    self.skip_ws();
                    if !self.value(child_path(path, &key), depth + 1, key_start) {
                        return false;
                    }
                }
                _ => return false,
            }
        }
    }

    fn items(&mut self, path: &str, depth: usize) -> (bool, usize) {
        let mut n = 0;
        loop {
            self.skip_ws();
            match self.peek() {
                Some(b']') => {
                    self.at += 1;
                    return (true, n);
                }
                Some(b',') => self.at += 1,
                Some(_) => {
                    let start = self.at;
                    if !self.value(format!("{path}[{n}]"), depth + 1, start) {
                        return (false, n + 1);
                    }
                    n += 1;
                }
                None => return (false, n),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOML: &str = r#"
[sensor]
band_um = [8, 12]
gray = { v_low = 0.0, v_high = "x" }

[[targets]]
name = "a"
[[targets]]
name = "b"
brdf = { roughness = 0.3 }
"#;

    #[test]
    fn toml_paths_and_spans() {
        let n = Nodes::toml(TOML);
        let v = n.get("sensor.gray.v_high").unwrap();
        assert_eq!(&TOML[v.span.0..v.span.1], "\"x\"");
        assert!(n.get("targets[1].brdf.roughness").is_some());
        assert_eq!(n.get("sensor.band_um").unwrap().kind, NodeKind::Array(2));
        assert_eq!(n.nearest("targets[1].brdf.f0").unwrap().path, "targets[1].brdf");
    }

    #[test]
    fn refine_finds_the_value_a_message_names() {
        let n = Nodes::toml(TOML);
        let gray = n.get("sensor.gray").unwrap();
        assert_eq!(n.refine(gray, "invalid type: string \"x\", expected f64").0, "sensor.gray.v_high");
        assert_eq!(n.refine(gray, "missing field `v_mid`").0, "sensor.gray.v_mid");
        let root = n.get("").unwrap();
        assert_eq!(n.refine(root, "missing field `observer`").0, "observer");
    }

    #[test]
    fn json_paths_and_spans() {
        let text = r#"{"sensor": {"band_um": [8, 12], "gray": {"v_high": "x"}}, "targets": [{"name": "a"}, {"brdf": {"roughness": true}}]}"#;
        let n = Nodes::json(text);
        let v = n.get("targets[1].brdf.roughness").unwrap();
        assert_eq!(&text[v.span.0..v.span.1], "true");
        let end = n.get("sensor.gray.v_high").unwrap().span.1;
        assert_eq!(n.at_offset(end).unwrap().path, "sensor.gray.v_high");
    }
}
