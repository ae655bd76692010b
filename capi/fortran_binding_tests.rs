//! The Fortran module (`gsenc.f90`) against the C header (`include/gsenc.h`),
//! read as text: the compilers check neither against the other. gfortran
//! lays out a `bind(c)` type as C lays out the struct of the same
//! components in the same order, and calls a `bind(c)` interface as C
//! calls the prototype of the same argument types; a component out of
//! order, a 64-bit integer bound as 32 bits, or an argument passed by value
//! that C takes by pointer compiles, links and then reads the wrong bytes.
//! The module's own test only checks `gsenc_config`'s size. So here:
//!
//! - every `bind(c)` type has the C struct's fields, in order, of the same
//!   size class and array length (a pointer as `type(c_ptr)`);
//! - every `bind(c, name=...)` interface has its C function's arguments, in
//!   order: by value as C's scalars, by reference as C's pointers to them,
//!   `type(c_ptr)` by value as any pointer and by reference as a pointer to
//!   one, `character(kind=c_char) :: s(*)` as `char *`; and its result;
//! - every `GSENC_*` constant of the header is a Fortran parameter of the
//!   same value, and every C function is bound but those the README names
//!   C only.

use crate::header_text::{c_header, CDecl, CHeader};
use std::collections::BTreeMap;

const MODULE: &str = include_str!("gsenc.f90");

/// C functions the Fortran module does not bind, and why.
const C_ONLY: [(&str, &str); 5] = [
    ("gsenc_encoder_model_bytes", "for shims that hand bytes on (README: C only)"),
    ("gsenc_model_read_buffer", "the same"),
    ("gsenc_model_field", "the same"),
    ("gsenc_status_string", "a static C string; gsenc_last_error_message() says more"),
    ("gsenc_version_string", "a static C string; gsenc_version() is bound"),
];
/// Header constants that are not values of the API.
const NOT_CONSTANTS: [&str; 4] = ["GSENC_H", "GSENC_VERSION_MAJOR", "GSENC_VERSION_MINOR", "GSENC_VERSION_PATCH"];

/// A Fortran kind's size class, named as [`crate::header_text::c_kind`]
/// names C's.
fn f_kind(kind: &str) -> String {
    match kind {
        "c_int" | "c_int32_t" => "i32",
        "c_int64_t" => "i64",
        "c_size_t" => "usize",
        "c_double" => "f64",
        "c_float" => "f32",
        "kind=c_char" => "char",
        "c_ptr" => "ptr",
        other => other,
    }
    .to_string()
}

/// Splits at commas outside parentheses.
fn top_level(text: &str) -> Vec<String> {
    let (mut parts, mut depth, mut part) = (vec![], 0, String::new());
    for c in text.chars() {
        match c {
            '(' => depth += 1,
            ')' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(std::mem::take(&mut part).trim().to_string());
                continue;
            }
            _ => {}
        }
        part.push(c);
    }
    parts.push(part.trim().to_string());
    parts
}

/// A Fortran declaration's entities: (name, kind, by value, array length;
/// 0 for an assumed size `(*)`).
#[derive(Debug)]
struct FDecl {
    name: String,
    kind: String,
    value: bool,
    len: usize,
}

fn f_decls(line: &str) -> Vec<FDecl> {
    let (spec, names) = line.split_once("::").unwrap_or_else(|| panic!("Fortran declaration '{line}'"));
    let spec = top_level(spec);
    let kind = spec[0].split_once('(').map(|(_, k)| k.trim_end_matches(')')).unwrap_or_else(|| panic!("kind of '{line}'"));
    let value = spec[1..].iter().any(|a| a == "value");
    top_level(names)
        .into_iter()
        .map(|entity| {
            let entity = entity.split('=').next().unwrap().trim();
            let (name, len) = match entity.split_once('(') {
                Some((n, d)) => (n, d.trim_end_matches(')').parse().unwrap_or(0)),
                None => (entity, 1),
            };
            FDecl { name: name.trim().to_string(), kind: f_kind(kind.trim()), value, len }
        })
        .collect()
}

/// The module's lines, without comments, continuations joined.
fn module_lines() -> Vec<String> {
    let mut lines = vec![];
    let mut pending = String::new();
    for line in MODULE.lines() {
        let line = line.split('!').next().unwrap().trim();
        let line = line.strip_prefix('&').unwrap_or(line).trim();
        match line.strip_suffix('&') {
            Some(head) => pending.push_str(head),
            None => {
                pending.push_str(line);
                if !pending.is_empty() {
                    lines.push(std::mem::take(&mut pending));
                }
            }
        }
    }
    lines
}

/// What the module declares, as [`crate::header_text::CHeader`] holds
/// the header's.
struct FModule {
    /// Each `bind(c)` type's components in order.
    types: BTreeMap<String, Vec<FDecl>>,
    /// Each `bind(c, name=...)` interface by its C name: result kind (or
    /// "void") and arguments in order.
    interfaces: BTreeMap<String, (String, Vec<FDecl>)>,
    /// `GSENC_*` parameters.
    parameters: BTreeMap<String, i64>,
}

/// The module's `bind(c)` types, interfaces and parameters.
fn fortran_api() -> FModule {
    let lines = module_lines();
    let (mut types, mut interfaces, mut parameters) = (BTreeMap::new(), BTreeMap::new(), BTreeMap::new());
    let mut i = 0;
    while i < lines.len() {
        let line = &lines[i];
        if let Some(name) = line.strip_prefix("type, bind(c), public ::") {
            let mut fields = vec![];
            i += 1;
            while lines[i] != "end type" {
                fields.extend(f_decls(&lines[i]));
                i += 1;
            }
            types.insert(name.trim().to_string(), fields);
        } else if let Some(at) = line.find("bind(c, name=\"") {
            let cname = line[at + 14..].split('"').next().unwrap().to_string();
            // `[kind] function name(args)` or `subroutine name(args)`.
            let (result, rest) = match line[..at].split_once(" function ") {
                Some((kind, rest)) => (f_kind(kind.split_once('(').unwrap().1.trim_end_matches(')')), rest),
                None => ("void".to_string(), line[..at].strip_prefix("subroutine ").unwrap_or_else(|| panic!("'{line}'"))),
            };
            let args = rest.split_once('(').unwrap().1;
            let order: Vec<String> = args.trim().trim_end_matches(')').split(',').map(|a| a.trim().to_string()).filter(|a| !a.is_empty()).collect();
            let mut declared = BTreeMap::new();
            i += 1;
            while !lines[i].starts_with("end function") && !lines[i].starts_with("end subroutine") {
                if !lines[i].starts_with("import") {
                    declared.extend(f_decls(&lines[i]).into_iter().map(|d| (d.name.clone(), d)));
                }
                i += 1;
            }
            let args = order.iter().map(|a| declared.remove(a).unwrap_or_else(|| panic!("{cname}: argument {a} undeclared"))).collect();
            interfaces.insert(cname, (result, args));
        } else if line.contains(", parameter, public ::") {
            for p in top_level(line.split_once("::").unwrap().1) {
                let (k, v) = p.split_once('=').unwrap();
                parameters.insert(k.trim().to_string(), v.trim().parse().unwrap_or_else(|_| panic!("parameter '{p}'")));
            }
        }
        i += 1;
    }
    FModule { types, interfaces, parameters }
}

/// Whether Fortran's `f` passes what C's `c` takes.
fn same_argument(f: &FDecl, c: &CDecl) -> bool {
    match (f.kind.as_str(), f.value) {
        // A handle or an address by value: any one pointer; by reference: a pointer to one.
        ("ptr", true) => c.stars == 1,
        ("ptr", false) => c.stars == 2,
        (kind, true) => c.stars == 0 && c.kind == kind && f.len == 1,
        (kind, false) => c.stars == 1 && c.kind == kind,
    }
}

#[test]
fn the_fortran_types_are_the_c_structs() {
    let structs = c_header().structs;
    let types = fortran_api().types;
    assert_eq!(types.keys().collect::<Vec<_>>(), structs.keys().collect::<Vec<_>>(), "the bind(c) types and the header's structs");
    for (name, fields) in &types {
        let c = &structs[name];
        let f: Vec<(&str, String, usize)> = fields.iter().map(|f| (f.name.as_str(), f.kind.clone(), f.len)).collect();
        let want: Vec<(&str, String, usize)> =
            c.iter().map(|c| (c.name.as_str(), if c.stars == 1 { "ptr".to_string() } else { c.kind.clone() }, c.len)).collect();
        assert_eq!(f, want, "{name}: Fortran's components (name, size class, length) against C's fields");
        assert!(c.iter().all(|c| c.stars <= 1), "{name}: a field the test cannot compare");
    }
}

#[test]
fn the_fortran_interfaces_are_the_c_prototypes() {
    let functions = c_header().functions;
    let interfaces = fortran_api().interfaces;
    assert!(interfaces.len() >= 20, "the interfaces were not found: {:?}", interfaces.keys());
    for (name, (result, args)) in &interfaces {
        let c = functions.get(name).unwrap_or_else(|| panic!("{name} is bound but not in the header"));
        let (c_result, c_args) = (if c.result.stars > 0 { "ptr".to_string() } else { c.result.kind.clone() }, &c.args);
        assert_eq!(*result, c_result, "{name}: result");
        assert_eq!(args.len(), c_args.len(), "{name}: {args:?} against {c_args:?}");
        for (f, c) in args.iter().zip(c_args) {
            assert!(same_argument(f, c), "{name}: Fortran's {f:?} does not pass C's {c:?}");
        }
    }
    let unbound: Vec<&str> = functions.keys().map(String::as_str).filter(|f| !interfaces.contains_key(*f)).collect();
    let mut c_only = C_ONLY.map(|(f, _)| f);
    c_only.sort_unstable();
    assert_eq!(unbound, c_only, "C functions the module does not bind");
}

#[test]
fn the_fortran_parameters_are_the_c_constants() {
    let constants = c_header().constants;
    let parameters = fortran_api().parameters;
    let constants: BTreeMap<&String, &i64> = constants.iter().filter(|(k, _)| !NOT_CONSTANTS.contains(&k.as_str())).collect();
    assert!(constants.len() > 40, "the header's constants were not found: {constants:?}");
    assert_eq!(parameters.iter().collect::<BTreeMap<_, _>>(), constants, "Fortran's parameters against C's constants");
}

/// The comparisons can fail: one field, argument or value changed in the
/// module's text is found.
#[test]
fn a_changed_binding_is_found() {
    let CHeader { structs, constants, functions } = c_header();
    // gsenc_job's `error` (int32) bound as 64 bits.
    let fields = f_decls("integer(c_int64_t) :: state = 0, iteration = 0, iterations = 0, error = 0");
    assert_ne!(fields.iter().map(|f| f.kind.clone()).collect::<Vec<_>>(), structs["gsenc_job"][1..5].iter().map(|c| c.kind.clone()).collect::<Vec<_>>());
    // gsenc_push_grid's step by reference.
    let args = &functions["gsenc_push_grid"].args;
    assert!(same_argument(&f_decls("integer(c_int64_t), value :: step")[0], &args[2]));
    assert!(!same_argument(&f_decls("integer(c_int64_t), intent(in) :: step")[0], &args[2]));
    assert!(!same_argument(&f_decls("integer(c_int32_t), value :: step")[0], &args[2]));
    // An out handle by value, a string as a handle by reference.
    let args = &functions["gsenc_model_read"].args;
    assert!(!same_argument(&f_decls("type(c_ptr), value :: out")[0], &args[1]));
    assert!(!same_argument(&f_decls("type(c_ptr), intent(in) :: path")[0], &args[0]));
    assert!(same_argument(&f_decls("character(kind=c_char), intent(in) :: path(*)")[0], &args[0]));
    assert_eq!(constants["GSENC_STATUS_DEVICE"], 14);
}
