//! The C header (`include/gsenc.h`) read as text, for the tests that hold
//! other text to it: the Fortran module (`fortran_binding_tests.rs`) and
//! the pinned prototypes (`lib.rs`). Reads what cbindgen writes: block
//! comments, `#define NAME value`, `typedef struct { fields } name;`,
//! `typedef enum { NAME = value, } name;` and one prototype a statement.

use std::collections::BTreeMap;

const HEADER: &str = include_str!("../include/gsenc.h");

/// A scalar's size class: C's and Fortran's names of the same bits.
pub(crate) fn c_kind(base: &str) -> String {
    match base {
        "int32_t" | "uint32_t" | "int" | "gsenc_status" => "i32",
        "int64_t" | "uint64_t" => "i64",
        "size_t" => "usize",
        "double" => "f64",
        "float" => "f32",
        "char" => "char",
        other => other,
    }
    .to_string()
}

/// A C declaration (`const gsenc_config *config`, `uint32_t dims[3]`).
#[derive(Debug, PartialEq)]
pub(crate) struct CDecl {
    pub name: String,
    /// Its size class ([`c_kind`]) or type name.
    pub kind: String,
    /// Levels of pointer.
    pub stars: usize,
    /// Array length (1 for a scalar).
    pub len: usize,
}

/// A prototype: its result (named as the function), its arguments, and
/// its text with the white space made single spaces.
#[derive(Debug)]
pub(crate) struct CFunction {
    pub result: CDecl,
    pub args: Vec<CDecl>,
    pub text: String,
}

/// What the header declares.
pub(crate) struct CHeader {
    /// Each struct's fields in order.
    pub structs: BTreeMap<String, Vec<CDecl>>,
    /// `#define`s with an integer value and enum entries.
    pub constants: BTreeMap<String, i64>,
    pub functions: BTreeMap<String, CFunction>,
}

pub(crate) fn c_decl(text: &str) -> CDecl {
    let text = text.trim();
    let (text, len) = match text.strip_suffix(']') {
        Some(t) => {
            let (t, n) = t.split_once('[').unwrap_or_else(|| panic!("C declaration '{text}'"));
            (t, n.trim().parse().unwrap_or_else(|_| panic!("C array length in '{text}'")))
        }
        None => (text, 1),
    };
    let stars = text.matches('*').count();
    let words: Vec<&str> = text.split(|c: char| c.is_whitespace() || c == '*').filter(|w| !w.is_empty() && *w != "const").collect();
    let [base @ .., name] = words.as_slice() else { panic!("C declaration '{text}'") };
    assert_eq!(base.len(), 1, "C declaration '{text}'");
    CDecl { name: name.to_string(), kind: c_kind(base[0]), stars, len }
}

/// The header without comments and preprocessor lines, and its `#define`s.
fn header() -> (String, BTreeMap<String, i64>) {
    let mut text = String::new();
    let mut rest = HEADER;
    while let Some(at) = rest.find("/*") {
        text.push_str(&rest[..at]);
        rest = &rest[at + rest[at..].find("*/").expect("an open comment") + 2..];
    }
    text.push_str(rest);
    let mut defines = BTreeMap::new();
    let mut code = String::new();
    for line in text.lines() {
        let line = line.split("//").next().unwrap();
        if let Some(d) = line.trim().strip_prefix("#define ") {
            let mut it = d.split_whitespace();
            if let (Some(name), Some(Ok(v))) = (it.next(), it.next().map(str::parse::<i64>)) {
                defines.insert(name.to_string(), v);
            }
        } else if !line.trim_start().starts_with('#') {
            code.push_str(line);
            code.push('\n');
        }
    }
    (code.replace("extern \"C\" {", ""), defines)
}

/// The header's structs, constants and functions.
pub(crate) fn c_header() -> CHeader {
    let (mut code, mut constants) = header();
    let mut structs = BTreeMap::new();
    // `typedef struct|enum { ... } name;`, taken out of the code.
    while let Some(at) = code.find("typedef struct {").or_else(|| code.find("typedef enum {")) {
        let open = at + code[at..].find('{').unwrap();
        let close = open + code[open..].find('}').expect("a closed typedef");
        let semi = close + code[close..].find(';').unwrap();
        let name = code[close + 1..semi].trim().to_string();
        let body = code[open + 1..close].to_string();
        if code[at..open].contains("enum") {
            for entry in body.split(',').map(str::trim).filter(|e| !e.is_empty()) {
                let (k, v) = entry.split_once('=').unwrap_or_else(|| panic!("enum entry '{entry}' without its value"));
                constants.insert(k.trim().to_string(), v.trim().parse().unwrap());
            }
        } else {
            structs.insert(name, body.split(';').map(str::trim).filter(|f| !f.is_empty()).map(c_decl).collect());
        }
        code.replace_range(at..=semi, "");
    }
    let mut functions = BTreeMap::new();
    for text in code.split(';').map(|s| s.split_whitespace().collect::<Vec<_>>().join(" ")) {
        let Some(open) = text.find('(') else { continue };
        if text.starts_with("typedef") {
            continue;
        }
        let result = c_decl(&text[..open]);
        let args = &text[open + 1..text.rfind(')').unwrap()];
        let args = if args.trim() == "void" { vec![] } else { args.split(',').map(c_decl).collect() };
        functions.insert(result.name.clone(), CFunction { result, args, text: text.replace("( ", "(").replace(" )", ")") });
    }
    CHeader { structs, constants, functions }
}
