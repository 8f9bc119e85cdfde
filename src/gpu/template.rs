//! Unrolling for WGSL kernels whose tiling must be straight-line code.
//!
//! Some drivers (Mesa's lavapipe among them) do not unroll loops, so an array of
//! accumulators indexed by loop counters lives in memory instead of registers, even when
//! every trip count is a constant. A kernel that needs registers declares *template
//! parameters* and writes its unrolled blocks once; the registry expands them per
//! [`Specialisation`](super::Specialisation) before compiling (values of other names stay
//! WGSL `override` constants). The syntax, in WGSL line comments so that tools see plain
//! WGSL around it:
//!
//! - `//#param NAME DEFAULT`: a template parameter (an integer) and its default, the value
//!   naga validation and limit checks use unless told otherwise;
//! - `//#repeat VAR COUNT` ... `//#end`: the lines between, repeated for `VAR` = 0 ..
//!   COUNT-1, where COUNT is an expression (below); blocks nest;
//! - `{EXPR}` anywhere in a line: the value of EXPR (no spaces), a `+`-separated sum of integers,
//!   template parameters and enclosing `repeat` variables (`{q+tx}`, `{N_IN+1}`).

use std::collections::BTreeMap;

use crate::error::{Error, Result};

/// The template parameters a WGSL source declares, with their defaults, in order.
pub fn params(source: &str) -> Vec<(&str, u32)> {
    source
        .lines()
        .filter_map(|l| {
            let rest = l.trim().strip_prefix("//#param ")?;
            let mut it = rest.split_whitespace();
            let name = it.next()?;
            let default = it.next()?.parse().ok()?;
            Some((name, default))
        })
        .collect()
}

fn err(kernel: &str, line: usize, message: impl std::fmt::Display) -> Error {
    Error::Kernel {
        kernel: kernel.to_string(),
        message: format!("template line {}: {message}", line + 1),
    }
}

/// Evaluates a `+`-separated sum of integers and names bound in `vars`.
fn eval(expr: &str, vars: &BTreeMap<String, u32>) -> std::result::Result<u32, String> {
    let mut sum = 0u32;
    for term in expr.split('+') {
        let term = term.trim();
        let v = match term.parse::<u32>() {
            Ok(v) => v,
            Err(_) => *vars.get(term).ok_or_else(|| {
                format!("'{term}' is neither a number nor a template parameter or repeat variable")
            })?,
        };
        sum = sum.checked_add(v).ok_or_else(|| format!("'{expr}' overflows"))?;
    }
    Ok(sum)
}

/// Replaces every `{EXPR}` of `line` by its value.
fn substitute(line: &str, vars: &BTreeMap<String, u32>) -> std::result::Result<String, String> {
    let mut out = String::with_capacity(line.len());
    let mut rest = line;
    while let Some(open) = rest.find('{') {
        let Some(len) = rest[open..].find('}') else {
            break;
        };
        let inner = &rest[open + 1..open + len];
        // Only template expressions (no spaces): WGSL braces enclose statements or fields.
        let is_expr = !inner.is_empty()
            && inner
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '+');
        out.push_str(&rest[..open]);
        if is_expr {
            out.push_str(&eval(inner, vars)?.to_string());
        } else {
            out.push_str(&rest[open..open + len + 1]);
        }
        rest = &rest[open + len + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// Expands `source` with `values` for its template parameters (defaults for the others).
/// A source without parameters comes back unchanged. Errors name `kernel` and the line.
pub fn expand(kernel: &str, source: &str, values: &[(&str, u32)]) -> Result<String> {
    let declared = params(source);
    if declared.is_empty() {
        if let Some((n, _)) = values.first() {
            return Err(Error::Kernel {
                kernel: kernel.to_string(),
                message: format!("'{n}' is not a template parameter (the kernel declares none)"),
            });
        }
        return Ok(source.to_string());
    }
    let mut vars = BTreeMap::new();
    for (n, d) in &declared {
        vars.insert(n.to_string(), *d);
    }
    for (n, v) in values {
        if !vars.contains_key(*n) {
            return Err(Error::Kernel {
                kernel: kernel.to_string(),
                message: format!("'{n}' is not one of its template parameters"),
            });
        }
        vars.insert(n.to_string(), *v);
    }
    let lines: Vec<&str> = source.lines().collect();
    let mut out = String::with_capacity(source.len() * 2);
    let end = emit(kernel, &lines, 0, &mut vars, &mut out)?;
    if end != lines.len() {
        return Err(err(kernel, end, "'//#end' without '//#repeat'"));
    }
    Ok(out)
}

/// The line of the `//#end` that closes a block opened just before `start`.
fn block_end(lines: &[&str], start: usize) -> Option<usize> {
    let mut depth = 0usize;
    for (i, l) in lines.iter().enumerate().skip(start) {
        let t = l.trim();
        if t.starts_with("//#repeat ") {
            depth += 1;
        } else if t == "//#end" {
            if depth == 0 {
                return Some(i);
            }
            depth -= 1;
        }
    }
    None
}

/// Emits lines from `start` until an unmatched `//#end` or the end of the source, and
/// returns where it stopped.
fn emit(
    kernel: &str,
    lines: &[&str],
    start: usize,
    vars: &mut BTreeMap<String, u32>,
    out: &mut String,
) -> Result<usize> {
    let mut i = start;
    while i < lines.len() {
        let t = lines[i].trim();
        if t == "//#end" {
            // The caller's block ends here (at top level: an unmatched end, reported).
            return Ok(i);
        }
        if let Some(rest) = t.strip_prefix("//#repeat ") {
            let (var, count) = rest
                .trim()
                .split_once(' ')
                .ok_or_else(|| err(kernel, i, "expected '//#repeat VAR COUNT'"))?;
            let count = eval(count, vars).map_err(|m| err(kernel, i, m))?;
            if vars.contains_key(var) {
                return Err(err(kernel, i, format!("'{var}' is already bound")));
            }
            let close =
                block_end(lines, i + 1).ok_or_else(|| err(kernel, i, "'//#repeat' without '//#end'"))?;
            for v in 0..count {
                vars.insert(var.to_string(), v);
                emit(kernel, lines, i + 1, vars, out)?;
            }
            vars.remove(var);
            i = close + 1;
            continue;
        }
        out.push_str(&substitute(lines[i], vars).map_err(|m| err(kernel, i, m))?);
        out.push('\n');
        i += 1;
    }
    Ok(i)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SRC: &str = "//#param N 2\n//#param M 1\nlet a = {N+1};\n//#repeat i N\n//#repeat j M+1\nx_{i}_{j} = v[{i+j}];\n//#end\n//#end\nstruct S { a: u32 }\n";

    #[test]
    fn expands_nested_blocks_and_sums() {
        let out = expand("t", SRC, &[("M", 0)]).unwrap();
        assert_eq!(
            out,
            "//#param N 2\n//#param M 1\nlet a = 3;\nx_0_0 = v[0];\nx_1_0 = v[1];\nstruct S { a: u32 }\n"
        );
        let out = expand("t", SRC, &[("N", 1)]).unwrap();
        assert!(
            out.contains("x_0_0 = v[0];\nx_0_1 = v[1];\n") && !out.contains("x_1"),
            "{out}"
        );
        assert_eq!(params(SRC), vec![("N", 2), ("M", 1)]);
    }

    #[test]
    fn zero_repeats_and_plain_sources() {
        let out = expand("t", SRC, &[("N", 0)]).unwrap();
        assert!(!out.contains("x_"), "{out}");
        assert_eq!(expand("t", "fn f() {}\n", &[]).unwrap(), "fn f() {}\n");
    }

    #[test]
    fn mistakes_are_named_errors() {
        for (src, values, want) in [
            (SRC, vec![("Q", 1)], "'Q' is not one of"),
            ("fn f() {}\n", vec![("Q", 1)], "declares none"),
            ("//#param N 1\n//#repeat i N\nx\n", vec![], "without '//#end'"),
            ("//#param N 1\nx\n//#end\n", vec![], "without '//#repeat'"),
            ("//#param N 1\nx = {K};\n", vec![], "'K' is neither"),
        ] {
            let e = expand("nn/t", src, &values).unwrap_err().to_string();
            assert!(e.contains("nn/t") && e.contains(want), "{e}");
        }
    }
}
