//! The core's module layering, read from its own source: every `use` and every path through
//! `crate::`, `super::`, `self::` or a child module in `rust/core/src/**/*.rs` is an arrow from
//! the file it is written in to the file that defines what it names. Two rules hold:
//!
//! (a) the top-level modules obey one layer order ([`LAYERS`]): an arrow only goes to a lower
//!     rank, never up and never between two modules of the same rank;
//! (b) the file-level graph has no circle (Tarjan's strongly connected components).
//!
//! What counts as an arrow:
//! - code paths count for both rules; comments and string literals are skipped;
//! - intra-doc links (`[..](crate::x)`, `` [`crate::x`] ``, `[..]: crate::x`) count for rule (a)
//!   only: a lower layer's documentation does not send the reader up (say it in words
//!   instead), but a file's docs may point to a sibling that uses it;
//! - a `pub use` re-export is a module's face, not an arrow: a path through it is followed to
//!   the file that defines the item; `mod x;` declarations are structure, not arrows; `lib.rs`
//!   is the crate's face and outside the layers.
//!

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The layer order, lowest first; modules in one entry share a rank and may not use each other.
const LAYERS: &[&[&str]] = &[
    &["error", "math"],
    &["model"],
    &["metrics"],
    &["calibrate", "derive"],
    &["format", "synth"],
    &["renoise"],
    &["resolve"],
];

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    PathSep,
    Punct(char),
}

/// One file's tokens (comments and literals dropped) and its doc-comment text.
struct Lexed {
    toks: Vec<Tok>,
    docs: String,
}

fn lex(src: &str) -> Lexed {
    let b = src.as_bytes();
    let (mut i, mut toks, mut docs) = (0, Vec::new(), String::new());
    while i < b.len() {
        let c = b[i];
        if c == b'/' && b.get(i + 1) == Some(&b'/') {
            let end = src[i..].find('\n').map_or(b.len(), |e| i + e);
            let line = &src[i..end];
            if line.starts_with("///") || line.starts_with("//!") {
                docs.push_str(&line[3..]);
                docs.push('\n');
            }
            i = end;
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            let (mut depth, mut j) = (1, i + 2);
            while j < b.len() && depth > 0 {
                if b[j] == b'/' && b.get(j + 1) == Some(&b'*') {
                    depth += 1;
                    j += 2;
                } else if b[j] == b'*' && b.get(j + 1) == Some(&b'/') {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            if src[i..].starts_with("/**") || src[i..].starts_with("/*!") {
                docs.push_str(&src[i + 3..j.saturating_sub(2).max(i + 3)]);
                docs.push('\n');
            }
            i = j;
        } else if c == b'"' || ((c == b'r' || c == b'b') && raw_or_byte_string_start(b, i).is_some()) {
            i = skip_string(b, i);
        } else if c == b'\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a): skip the former only.
            if b.get(i + 1) == Some(&b'\\') {
                let close = src[i + 2..].find('\'').expect("unterminated char literal");
                i = i + 2 + close + 1;
            } else if b.get(i + 2) == Some(&b'\'') {
                i += 3;
            } else if let Some(ch) = src[i + 1..].chars().next().filter(|ch| !ch.is_ascii())
                && src[i + 1 + ch.len_utf8()..].starts_with('\'')
            {
                i += 2 + ch.len_utf8();
            } else {
                i += 1;
            }
        } else if c.is_ascii_alphabetic() || c == b'_' {
            let start = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            toks.push(Tok::Ident(src[start..i].to_string()));
        } else if c.is_ascii_digit() {
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_' || b[i] == b'.') {
                if b[i] == b'.' && !b.get(i + 1).is_some_and(u8::is_ascii_digit) {
                    break;
                }
                i += 1;
            }
        } else if c == b':' && b.get(i + 1) == Some(&b':') {
            toks.push(Tok::PathSep);
            i += 2;
        } else if c.is_ascii() {
            if !c.is_ascii_whitespace() {
                toks.push(Tok::Punct(c as char));
            }
            i += 1;
        } else {
            i += src[i..].chars().next().map_or(1, char::len_utf8);
        }
    }
    Lexed { toks, docs }
}

/// Where a raw or byte string literal starts at `i` (`r"`, `r#"`, `b"`, `br#"`): the index of
/// its opening quote and the number of `#`.
fn raw_or_byte_string_start(b: &[u8], i: usize) -> Option<(usize, usize, bool)> {
    if i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_') {
        return None;
    }
    let mut j = i;
    if b[j] == b'b' {
        j += 1;
    }
    let raw = b.get(j) == Some(&b'r');
    if raw {
        j += 1;
    }
    let mut hashes = 0;
    while raw && b.get(j) == Some(&b'#') {
        hashes += 1;
        j += 1;
    }
    (j > i && b.get(j) == Some(&b'"')).then_some((j, hashes, raw))
}

fn skip_string(b: &[u8], i: usize) -> usize {
    let (q, hashes, raw) = raw_or_byte_string_start(b, i).unwrap_or((i, 0, false));
    let mut j = q + 1;
    while j < b.len() {
        if !raw && b[j] == b'\\' {
            j += 2;
            continue;
        }
        if b[j] == b'"' && b[j + 1..].iter().take(hashes).filter(|&&h| h == b'#').count() == hashes {
            return j + 1 + hashes;
        }
        j += 1;
    }
    panic!("unterminated string literal");
}

/// A module path from the crate root, e.g. `["calibrate", "estimate", "clip"]`.
type ModPath = Vec<String>;

struct SourceFile {
    rel: String,
    module: ModPath,
    lexed: Lexed,
}

fn module_of(rel: &str) -> ModPath {
    let mut parts: Vec<String> = rel.trim_end_matches(".rs").split('/').map(str::to_string).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    parts
}

fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("the source folder reads") {
        let p = entry.expect("a folder entry reads").path();
        if p.is_dir() {
            collect(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// Expands the use tree starting at `toks[i]` (after `use`) into its paths; returns them and
/// the index after the closing `;`.
fn use_tree(toks: &[Tok], mut i: usize) -> (Vec<Vec<String>>, usize) {
    fn tree(toks: &[Tok], i: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
        let mut path = prefix.to_vec();
        loop {
            match toks.get(*i) {
                Some(Tok::PathSep) => *i += 1,
                Some(Tok::Ident(s)) if s == "as" => {
                    *i += 2;
                }
                Some(Tok::Ident(s)) => {
                    if s != "self" || path.is_empty() {
                        path.push(s.clone());
                    }
                    *i += 1;
                }
                Some(Tok::Punct('*')) => *i += 1,
                Some(Tok::Punct('{')) => {
                    *i += 1;
                    loop {
                        match toks.get(*i) {
                            Some(Tok::Punct('}')) => {
                                *i += 1;
                                return;
                            }
                            Some(Tok::Punct(',')) => *i += 1,
                            _ => tree(toks, i, &path, out),
                        }
                    }
                }
                _ => {
                    if !path.is_empty() {
                        out.push(path);
                    }
                    return;
                }
            }
        }
    }
    let mut out = Vec::new();
    tree(toks, &mut i, &[], &mut out);
    assert_eq!(toks.get(i), Some(&Tok::Punct(';')), "use statement not closed by ';'");
    (out, i + 1)
}

/// One arrow as written: the path (already made absolute) and whether it is a doc link.
struct Written {
    path: ModPath,
    doc: bool,
}

struct Crate {
    files: Vec<SourceFile>,
    /// Module path → index in `files`.
    by_module: BTreeMap<ModPath, usize>,
    /// Per file, `pub use` re-exports: exported name → absolute path of the original.
    reexports: Vec<BTreeMap<String, ModPath>>,
}

impl Crate {
    fn load() -> Crate {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut paths = Vec::new();
        collect(&root, &mut paths);
        paths.sort();
        let files: Vec<SourceFile> = paths
            .iter()
            .map(|p| {
                let rel = p.strip_prefix(&root).expect("under src").to_string_lossy().replace('\\', "/");
                let lexed = lex(&std::fs::read_to_string(p).expect("a source file reads"));
                SourceFile { module: module_of(&rel), rel, lexed }
            })
            .collect();
        let by_module = files.iter().enumerate().map(|(i, f)| (f.module.clone(), i)).collect();
        let mut krate = Crate { files, by_module, reexports: Vec::new() };
        krate.reexports = (0..krate.files.len()).map(|i| krate.reexports_of(i)).collect();
        krate
    }

    /// Makes a written path absolute from `module`, or `None` for an outside crate's path.
    fn absolute(&self, module: &[String], path: &[String]) -> Option<ModPath> {
        let first = path.first()?;
        let mut base: ModPath = module.to_vec();
        let mut rest = path;
        match first.as_str() {
            "crate" => {
                base.clear();
                rest = &path[1..];
            }
            "self" => rest = &path[1..],
            "super" => {
                while rest.first().is_some_and(|s| s == "super") {
                    base.pop()?;
                    rest = &rest[1..];
                }
            }
            child => {
                let mut m = module.to_vec();
                m.push(child.to_string());
                if !self.by_module.contains_key(&m) {
                    return None;
                }
            }
        }
        base.extend(rest.iter().cloned());
        Some(base)
    }

    fn reexports_of(&self, i: usize) -> BTreeMap<String, ModPath> {
        let f = &self.files[i];
        let toks = &f.lexed.toks;
        let mut out = BTreeMap::new();
        for k in 0..toks.len() {
            let is_pub_use = toks[k] == Tok::Ident("use".into())
                && k > 0
                && (toks[k - 1] == Tok::Ident("pub".into()) || toks[k - 1] == Tok::Punct(')'));
            if is_pub_use {
                for p in use_tree(toks, k + 1).0 {
                    if let Some(abs) = self.absolute(&f.module, &p) {
                        out.insert(abs.last().expect("a non-empty path").clone(), abs);
                    }
                }
            }
        }
        out
    }

    /// The file that defines what an absolute path names, following re-exports.
    fn resolve(&self, path: &[String]) -> Option<usize> {
        let mut path = path.to_vec();
        for _ in 0..8 {
            let (len, &file) = (0..=path.len()).rev().find_map(|n| self.by_module.get(&path[..n]).map(|f| (n, f)))?;
            match path.get(len).and_then(|name| self.reexports[file].get(name)) {
                Some(target) if target.as_slice() != path.as_slice() => {
                    let mut next = target.clone();
                    next.extend(path[len + 1..].iter().cloned());
                    path = next;
                }
                _ => return Some(file),
            }
        }
        panic!("re-export chain too long at {path:?}");
    }

    /// Every path written in file `i` that names something in this crate.
    fn written(&self, i: usize) -> Vec<Written> {
        let f = &self.files[i];
        let toks = &f.lexed.toks;
        let mut out = Vec::new();
        // Inline modules (`mod tests { .. }`) shift what `self` and `super` mean.
        let mut inline: Vec<(String, usize)> = Vec::new();
        let mut depth = 0usize;
        let mut k = 0;
        while k < toks.len() {
            let mut module = f.module.clone();
            module.extend(inline.iter().map(|(m, _)| m.clone()));
            match &toks[k] {
                Tok::Punct('{') => depth += 1,
                Tok::Punct('}') => {
                    depth -= 1;
                    if inline.last().is_some_and(|&(_, d)| d == depth) {
                        inline.pop();
                    }
                }
                Tok::Ident(s) if s == "mod" => {
                    if let (Some(Tok::Ident(name)), Some(Tok::Punct('{'))) = (toks.get(k + 1), toks.get(k + 2)) {
                        inline.push((name.clone(), depth));
                        depth += 1;
                        k += 3;
                        continue;
                    }
                }
                Tok::Ident(s) if s == "use" => {
                    let public = k > 0 && (toks[k - 1] == Tok::Ident("pub".into()) || toks[k - 1] == Tok::Punct(')'));
                    let (paths, next) = use_tree(toks, k + 1);
                    if !public {
                        out.extend(
                            paths.iter().filter_map(|p| Some(Written { path: self.absolute(&module, p)?, doc: false })),
                        );
                    }
                    k = next;
                    continue;
                }
                Tok::Ident(first)
                    if toks.get(k + 1) == Some(&Tok::PathSep) && (k == 0 || toks[k - 1] != Tok::PathSep) =>
                {
                    let mut p = vec![first.clone()];
                    let mut j = k + 1;
                    while let (Some(Tok::PathSep), Some(Tok::Ident(s))) = (toks.get(j), toks.get(j + 1)) {
                        p.push(s.clone());
                        j += 2;
                    }
                    if let Some(abs) = self.absolute(&module, &p) {
                        out.push(Written { path: abs, doc: false });
                    }
                    k = j;
                    continue;
                }
                _ => {}
            }
            k += 1;
        }
        for link in doc_links(&f.lexed.docs) {
            if let Some(abs) = self.absolute(&f.module, &link) {
                out.push(Written { path: abs, doc: true });
            }
        }
        out
    }

    /// Arrows between distinct files: (from, to, doc-only).
    fn arrows(&self) -> BTreeMap<(usize, usize), bool> {
        let mut arrows: BTreeMap<(usize, usize), bool> = BTreeMap::new();
        for i in 0..self.files.len() {
            for w in self.written(i) {
                let Some(j) = self.resolve(&w.path) else { continue };
                if j != i {
                    let doc_only = arrows.entry((i, j)).or_insert(true);
                    *doc_only &= w.doc;
                }
            }
        }
        arrows
    }

    fn top(&self, i: usize) -> Option<&str> {
        self.files[i].module.first().map(String::as_str)
    }
}

/// Paths in doc links that start with `crate::`, `super::` or `self::`.
fn doc_links(docs: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for start in ["crate::", "super::", "self::"] {
        for (at, _) in docs.match_indices(start) {
            let before = docs[..at].chars().next_back();
            if !matches!(before, Some('(' | '[' | '`' | ' ')) {
                continue;
            }
            if before == Some(' ') && !docs[..at].trim_end().ends_with("]:") {
                continue;
            }
            let end = docs[at..]
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'))
                .map_or(docs.len(), |e| at + e);
            let path: Vec<String> = docs[at..end].split("::").filter(|s| !s.is_empty()).map(str::to_string).collect();
            out.push(path);
        }
    }
    out
}

fn rank(module: &str) -> usize {
    LAYERS.iter().position(|rank| rank.contains(&module)).unwrap_or_else(|| {
        panic!("top-level module `{module}` is in no layer: add it to LAYERS (and to docs/method.md's code map)")
    })
}

/// Arrows against the layer order: (file, target module) → one example target file.
fn layer_violations(k: &Crate) -> BTreeMap<(String, String), (String, bool)> {
    let mut out = BTreeMap::new();
    for (&(i, j), &doc_only) in &k.arrows() {
        let (Some(from), Some(to)) = (k.top(i), k.top(j)) else { continue };
        if from != to && rank(to) >= rank(from) {
            let e = out.entry((k.files[i].rel.clone(), to.to_string())).or_insert((k.files[j].rel.clone(), true));
            e.1 &= doc_only;
        }
    }
    out
}

/// Strongly connected components with more than one file (Tarjan).
fn circles(n: usize, edges: &BTreeSet<(usize, usize)>) -> Vec<Vec<usize>> {
    struct State<'a> {
        adj: Vec<Vec<usize>>,
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: &'a mut Vec<Vec<usize>>,
    }
    fn visit(s: &mut State<'_>, v: usize) {
        s.index[v] = Some(s.next);
        s.low[v] = s.next;
        s.next += 1;
        s.stack.push(v);
        s.on_stack[v] = true;
        for w in s.adj[v].clone() {
            match s.index[w] {
                None => {
                    visit(s, w);
                    s.low[v] = s.low[v].min(s.low[w]);
                }
                Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                _ => {}
            }
        }
        if Some(s.low[v]) == s.index[v] {
            let mut comp = Vec::new();
            loop {
                let w = s.stack.pop().expect("v is on the stack");
                s.on_stack[w] = false;
                comp.push(w);
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                s.out.push(comp);
            }
        }
    }
    let mut adj = vec![Vec::new(); n];
    for &(a, b) in edges {
        adj[a].push(b);
    }
    let mut out = Vec::new();
    let mut s = State {
        adj,
        index: vec![None; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        next: 0,
        out: &mut out,
    };
    for v in 0..n {
        if s.index[v].is_none() {
            visit(&mut s, v);
        }
    }
    out
}

fn code_edges(k: &Crate) -> BTreeSet<(usize, usize)> {
    k.arrows().into_iter().filter(|&(_, doc_only)| !doc_only).map(|(e, _)| e).collect()
}

#[test]
fn top_level_modules_obey_the_layer_order() {
    let k = Crate::load();
    let violations = layer_violations(&k);
    let unexpected: Vec<String> = violations
        .iter()
        .map(|((f, t), (example, doc))| {
            let kind = if *doc { "doc link" } else { "code" };
            format!(
                "{f} → {t} ({kind}, e.g. {example}; rank {} → rank {})",
                rank(&k.files[k.by_module[&module_of(f)]].module[0]),
                rank(t)
            )
        })
        .collect();
    assert!(unexpected.is_empty(), "arrows up or across the layer order {LAYERS:?}:\n{}", unexpected.join("\n"));
}

#[test]
fn no_circle_between_files() {
    let k = Crate::load();
    let edges = code_edges(&k);
    let found: Vec<String> = circles(k.files.len(), &edges)
        .iter()
        .map(|c| {
            let inside: Vec<String> = edges
                .iter()
                .filter(|(a, b)| c.contains(a) && c.contains(b))
                .map(|&(a, b)| format!("  {} → {}", k.files[a].rel, k.files[b].rel))
                .collect();
            inside.join("\n")
        })
        .collect();
    assert!(found.is_empty(), "circles between files (the arrows inside each):\n{}", found.join("\n\n"));
}

/// The reader itself: it must see the arrows it is there to forbid.
#[test]
fn the_reader_sees_known_arrows_and_skips_comments() {
    let k = Crate::load();
    let arrows = k.arrows();
    let file = |rel: &str| k.files.iter().position(|f| f.rel == rel).unwrap();
    // A grouped `use` through a re-export, a child-module path and a `super::` path.
    assert_eq!(arrows.get(&(file("calibrate/session.rs"), file("model/layout.rs"))), Some(&false));
    assert!(arrows.contains_key(&(file("calibrate/estimate/mod.rs"), file("calibrate/estimate/pool.rs"))));
    assert!(arrows.contains_key(&(file("metrics/spatial.rs"), file("metrics/mod.rs"))));
    // Re-exports are followed: `crate::Error` is error.rs, not lib.rs.
    assert!(!arrows.keys().any(|&(_, j)| j == file("lib.rs")));

    let lexed =
        lex("// use crate::a;\n/// [`crate::b`]\nlet s = \"crate::c\"; let c = '\"'; crate::d::e(r#\"crate::f\"#);");
    let idents: Vec<&Tok> = lexed.toks.iter().filter(|t| matches!(t, Tok::Ident(_))).collect();
    assert_eq!(
        idents,
        ["let", "s", "let", "c", "crate", "d", "e"].map(|s| Tok::Ident(s.into())).iter().collect::<Vec<_>>()
    );
    assert_eq!(doc_links(&lexed.docs), vec![vec!["crate".to_string(), "b".to_string()]]);

    // Tarjan finds a circle and only that one.
    let edges: BTreeSet<(usize, usize)> = [(0, 1), (1, 2), (2, 0), (2, 3), (3, 4)].into();
    assert_eq!(circles(5, &edges), vec![vec![0, 1, 2]]);
}
