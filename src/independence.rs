//! The rule behind every referee's independence test: a referee may name
//! descriptions (scene parameter types, shared statistics) but never the
//! renderer stages it checks. Each `referee` module lists the project paths
//! it may use; [`foreign_paths`] returns every other path its source names.
//! Test-only.

/// The project paths (`crate::a::b`, `super::super::x`) named in the code of
/// `src` (comments and everything from the first `#[cfg(test)]` on are
/// skipped, so tests may compare against the renderer) that start with none
/// of `allowed` (e.g. `crate::stats`). One level of `{a, b}` groups is
/// expanded. A plain `super::` (a sibling referee file) is allowed.
pub fn foreign_paths(src: &str, allowed: &[&str]) -> Vec<String> {
    let code: String = src
        .split("#[cfg(test)]")
        .next()
        .unwrap_or("")
        .lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join(" ");
    let mut paths = vec![];
    for root in ["crate::", "super::super::"] {
        let mut at = 0;
        while let Some(i) = code[at..].find(root) {
            let start = at + i;
            let rest = &code[start..];
            let end = path_end(rest);
            paths.extend(expand(&rest[..end]));
            at = start + root.len();
        }
    }
    paths
        .into_iter()
        .filter(|p| {
            !allowed
                .iter()
                .any(|a| p == a || p.starts_with(&format!("{a}::")))
        })
        .collect()
}

/// Length of the path at the start of `s`, a `{...}` group included.
fn path_end(s: &str) -> usize {
    let mut depth = 0;
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth > 0 => {
                depth -= 1;
                if depth == 0 {
                    return i + 1;
                }
            }
            c if depth == 0 && !(c.is_alphanumeric() || c == '_' || c == ':') => return i,
            _ => {}
        }
    }
    s.len()
}

/// `a::{b, c::d}` -> `a::b`, `a::c::d`; a path without a group as is.
fn expand(p: &str) -> Vec<String> {
    match p.find('{') {
        None => vec![p.trim_end_matches(':').to_string()],
        Some(i) => {
            let head = &p[..i];
            p[i + 1..p.len() - 1]
                .split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(|s| format!("{head}{s}").replace("::self", ""))
                .collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_planted_renderer_import_is_reported() {
        let src = "use crate::stats::sidak;\nuse crate::pathtrace::{listed::HitList, shapes::intersect};\n// crate::pathtrace::packed in a comment\nfn f() { crate::pathtrace::packed::x(); }\n#[cfg(test)]\nuse crate::pathtrace::bsdf;";
        let allowed = ["crate::stats", "crate::pathtrace::listed"];
        assert_eq!(
            foreign_paths(src, &allowed),
            vec![
                "crate::pathtrace::shapes::intersect",
                "crate::pathtrace::packed::x"
            ]
        );
    }

    #[test]
    fn allowed_paths_and_siblings_pass() {
        let src = "use super::geometry::unit;\nuse crate::error::{Error, Result};";
        assert!(foreign_paths(src, &["crate::error"]).is_empty());
        assert_eq!(
            foreign_paths("use super::super::shapes;", &["crate::error"]),
            vec!["super::super::shapes"]
        );
    }
}
