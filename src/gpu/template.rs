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
//! - `//#if EXPR` ... (`//#else` ...) `//#end`: the first lines when EXPR is not 0, else
//!   those after `//#else` (e.g. a binding's element type, `f32` or `f16`);
//! - in a directive's argument, `{EXPR}` is replaced first, so names can be built from
//!   repeat variables (`//#if F16_IN{k}`);
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
        let what = if lines[end].trim() == "//#else" {
            "'//#else' without '//#if'"
        } else {
            "'//#end' without '//#repeat' or '//#if'"
        };
        return Err(err(kernel, end, what));
    }
    Ok(out)
}

/// Where the block opened just before `start` ends: its `//#else` at the same depth, if
/// any, and the line of its closing `//#end`.
fn block_end(lines: &[&str], start: usize) -> Option<(Option<usize>, usize)> {
    let mut depth = 0usize;
    let mut otherwise = None;
    for (i, l) in lines.iter().enumerate().skip(start) {
        let t = l.trim();
        if t.starts_with("//#repeat ") || t.starts_with("//#if ") {
            depth += 1;
        } else if t == "//#else" && depth == 0 && otherwise.is_none() {
            otherwise = Some(i);
        } else if t == "//#end" {
            if depth == 0 {
                return Some((otherwise, i));
            }
            depth -= 1;
        }
    }
    None
}

/// Emits lines from `start` until an unmatched `//#end` or `//#else`, or the end of the
/// source, and returns where it stopped.
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
        if t == "//#end" || t == "//#else" {
            // The caller's block (or branch) ends here; at top level, reported.
            return Ok(i);
        }
        let arg = |prefix: &str| -> Result<Option<String>> {
            match t.strip_prefix(prefix) {
                None => Ok(None),
                Some(rest) => substitute(rest.trim(), vars)
                    .map(Some)
                    .map_err(|m| err(kernel, i, m)),
            }
        };
        if let Some(rest) = arg("//#repeat ")? {
            let (var, count) = rest
                .split_once(' ')
                .ok_or_else(|| err(kernel, i, "expected '//#repeat VAR COUNT'"))?;
            let count = eval(count, vars).map_err(|m| err(kernel, i, m))?;
            if vars.contains_key(var) {
                return Err(err(kernel, i, format!("'{var}' is already bound")));
            }
            let (otherwise, close) =
                block_end(lines, i + 1).ok_or_else(|| err(kernel, i, "'//#repeat' without '//#end'"))?;
            if let Some(e) = otherwise {
                return Err(err(
                    kernel,
                    e,
                    "'//#else' inside '//#repeat' (only '//#if' has one)",
                ));
            }
            for v in 0..count {
                vars.insert(var.to_string(), v);
                emit(kernel, lines, i + 1, vars, out)?;
            }
            vars.remove(var);
            i = close + 1;
            continue;
        }
        if let Some(cond) = arg("//#if ")? {
            let value = eval(&cond, vars).map_err(|m| err(kernel, i, m))?;
            let (otherwise, close) =
                block_end(lines, i + 1).ok_or_else(|| err(kernel, i, "'//#if' without '//#end'"))?;
            if value != 0 {
                emit(kernel, lines, i + 1, vars, out)?;
            } else if let Some(e) = otherwise {
                emit(kernel, lines, e + 1, vars, out)?;
            }
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
    fn conditionals_pick_a_branch_and_directives_substitute_names() {
        let src = "//#param N 2\n//#param F_0 0\n//#param F_1 1\n//#repeat k N\n//#if F_{k}\nh{k}\n//#else\nf{k}\n//#if 1\ninner{k}\n//#end\n//#end\n//#end\n//#if F_0\nnever\n//#end\ntail\n";
        let out = expand("t", src, &[]).unwrap();
        let body: Vec<&str> = out.lines().filter(|l| !l.starts_with("//#param")).collect();
        assert_eq!(body, ["f0", "inner0", "h1", "tail"]);
        let out = expand("t", src, &[("F_0", 1)]).unwrap();
        let body: Vec<&str> = out.lines().filter(|l| !l.starts_with("//#param")).collect();
        assert_eq!(body, ["h0", "h1", "never", "tail"]);
    }

    #[test]
    fn mistakes_are_named_errors() {
        for (src, values, want) in [
            (SRC, vec![("Q", 1)], "'Q' is not one of"),
            ("fn f() {}\n", vec![("Q", 1)], "declares none"),
            ("//#param N 1\n//#repeat i N\nx\n", vec![], "without '//#end'"),
            ("//#param N 1\nx\n//#end\n", vec![], "without '//#repeat'"),
            ("//#param N 1\nx = {K};\n", vec![], "'K' is neither"),
            ("//#param N 1\n//#if N\nx\n", vec![], "'//#if' without '//#end'"),
            ("//#param N 1\nx\n//#else\n", vec![], "'//#else' without '//#if'"),
            (
                "//#param N 1\n//#repeat i N\nx\n//#else\ny\n//#end\n",
                vec![],
                "inside '//#repeat'",
            ),
        ] {
            let e = expand("nn/t", src, &values).unwrap_err().to_string();
            assert!(e.contains("nn/t") && e.contains(want), "{e}");
        }
    }
}
