//! `#import` for WGSL, in the manner of Vello's shader preprocessor: a line `#import name`
//! (alone on its line) brings in the module `name` once, before the importing file, with the
//! modules it imports in turn. Modules are plain WGSL; module-scope declarations may refer to
//! each other in any order (WGSL allows this), so a module may use a binding that the shader
//! importing it declares (`shaders/lib/grid.wgsl` reads `P` and `density`, which each stage
//! declares with its own binding numbers).
//!
//! Composition keeps every source line on its own line of the output (an import line becomes
//! a comment), so [`Composed::locate`] maps a line of the composed text back to the file and
//! line it came from; naga's errors are reported that way by [`Composed::parse`].
//!
//! Nothing is substituted inside a source: specialisation is by WGSL `override` constants set
//! when the pipeline is created, or by modules generated from Rust values (see
//! [`crate::consts`]).

use std::borrow::Cow;

/// One file's lines in the composed source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Segment {
    /// Module name (`rng`) or shader file name (`pt.wgsl`).
    pub file: String,
    /// First line of the segment in the composed source (0-based).
    pub start: usize,
    /// Number of lines.
    pub lines: usize,
}

/// A shader with its imports resolved.
#[derive(Debug, Clone)]
pub struct Composed {
    /// The WGSL handed to naga / wgpu.
    pub source: String,
    /// Where each line came from, in order.
    pub segments: Vec<Segment>,
}

/// Errors of composition (all are mistakes in the shader sources, found by the registry test).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ComposeError {
    #[error("{file}:{line}: `#import {name}`: no such WGSL module")]
    Unknown {
        file: String,
        line: usize,
        name: String,
    },
    #[error("{file}:{line}: malformed import `{text}` (expected `#import name`)")]
    Malformed {
        file: String,
        line: usize,
        text: String,
    },
    #[error("import cycle: {0}")]
    Cycle(String),
}

impl Composed {
    /// (file, 1-based line) of the 1-based `line` of the composed source.
    pub fn locate(&self, line: usize) -> Option<(&str, usize)> {
        let l = line.checked_sub(1)?;
        self.segments
            .iter()
            .find(|s| l >= s.start && l < s.start + s.lines)
            .map(|s| (s.file.as_str(), l - s.start + 1))
    }

    /// Parses the composed source with naga; an error names the original file and line.
    pub fn parse(&self) -> Result<naga::Module, String> {
        naga::front::wgsl::parse_str(&self.source).map_err(|e| {
            let at = e
                .location(&self.source)
                .and_then(|loc| self.locate(loc.line_number as usize))
                .map_or(String::new(), |(f, l)| format!("{f}:{l}: "));
            format!("{at}{}", e.emit_to_string(&self.source))
        })
    }

    /// Parses and validates (all validation flags and capabilities, as the registry test does).
    pub fn validate(&self) -> Result<naga::Module, String> {
        let module = self.parse()?;
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .map_err(|e| format!("{}: {e:?}", self.segments.last().map_or("", |s| &s.file)))?;
        Ok(module)
    }
}

/// The module name of an import line, `None` for any other line.
fn import_of(line: &str) -> Option<&str> {
    line.trim_start().strip_prefix("#import")
}

/// Composes `source` (called `name` in messages): every module it imports, recursively, once
/// each and depth first, then the file itself. `resolve` returns a module's source by name.
pub fn compose<'a>(
    name: &str,
    source: &str,
    resolve: &dyn Fn(&str) -> Option<Cow<'a, str>>,
) -> Result<Composed, ComposeError> {
    let mut out = Composed {
        source: String::new(),
        segments: Vec::new(),
    };
    let mut done: Vec<String> = Vec::new();
    let mut stack: Vec<String> = vec![name.to_string()];
    visit(name, source, resolve, &mut stack, &mut done, &mut out)?;
    Ok(out)
}

fn visit<'a>(
    name: &str,
    source: &str,
    resolve: &dyn Fn(&str) -> Option<Cow<'a, str>>,
    stack: &mut Vec<String>,
    done: &mut Vec<String>,
    out: &mut Composed,
) -> Result<(), ComposeError> {
    for (i, line) in source.lines().enumerate() {
        let Some(rest) = import_of(line) else {
            continue;
        };
        let module = rest.trim();
        let valid = rest.starts_with(char::is_whitespace)
            && !module.is_empty()
            && module
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !valid {
            return Err(ComposeError::Malformed {
                file: name.into(),
                line: i + 1,
                text: line.trim().into(),
            });
        }
        if done.iter().any(|d| d == module) {
            continue;
        }
        if stack.iter().any(|s| s == module) {
            stack.push(module.into());
            return Err(ComposeError::Cycle(stack.join(" → ")));
        }
        let text = resolve(module).ok_or_else(|| ComposeError::Unknown {
            file: name.into(),
            line: i + 1,
            name: module.into(),
        })?;
        stack.push(module.into());
        visit(module, &text, resolve, stack, done, out)?;
        stack.pop();
    }
    let start = out.segments.last().map_or(0, |s| s.start + s.lines);
    let mut lines = 0;
    for line in source.lines() {
        match import_of(line) {
            Some(rest) => {
                out.source.push_str("// (imported above:");
                out.source.push_str(rest);
                out.source.push_str(")\n");
            }
            None => {
                out.source.push_str(line);
                out.source.push('\n');
            }
        }
        lines += 1;
    }
    out.segments.push(Segment {
        file: name.into(),
        start,
        lines,
    });
    done.push(name.into());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lib(name: &str) -> Option<Cow<'static, str>> {
        match name {
            "a" => Some("#import b\nfn a() -> f32 { return b(); }".into()),
            "b" => Some("fn b() -> f32 { return 1.0; }".into()),
            "loop1" => Some("#import loop2\n".into()),
            "loop2" => Some("#import loop1\n".into()),
            _ => None,
        }
    }

    /// Depth-first, each module once, line numbers kept.
    #[test]
    fn imports_once_in_dependency_order_and_locates_lines() {
        let main = "#import a\n#import b\nfn main_fn() -> f32 {\n  return a() + b();\n}";
        let c = compose("main.wgsl", main, &lib).unwrap();
        let names: Vec<&str> = c.segments.iter().map(|s| s.file.as_str()).collect();
        assert_eq!(names, ["b", "a", "main.wgsl"]);
        assert_eq!(c.source.matches("fn b()").count(), 1);
        // b: line 1; a: lines 2–3; main: lines 4–8 ("return a() + b()" is main's line 4).
        assert_eq!(c.locate(1), Some(("b", 1)));
        assert_eq!(c.locate(3), Some(("a", 2)));
        assert_eq!(c.locate(7), Some(("main.wgsl", 4)));
        assert_eq!(c.locate(9), None);
        assert_eq!(c.source.lines().nth(6), Some("  return a() + b();"));
        c.validate().unwrap();
    }

    /// A naga error points at the file and line that holds the mistake, not the composed text.
    #[test]
    fn parse_errors_name_the_original_file_and_line() {
        let main = "#import a\nfn f() -> f32 {\n  return undefined_name;\n}";
        let err = compose("main.wgsl", main, &lib)
            .unwrap()
            .parse()
            .unwrap_err();
        assert!(err.starts_with("main.wgsl:3: "), "{err}");
    }

    #[test]
    fn unknown_malformed_and_cyclic_imports_are_errors() {
        let e = compose("m.wgsl", "\n#import nope\n", &lib).unwrap_err();
        assert_eq!(
            e.to_string(),
            "m.wgsl:2: `#import nope`: no such WGSL module"
        );
        let e = compose("m.wgsl", "#importa\n", &lib).unwrap_err();
        assert!(matches!(e, ComposeError::Malformed { line: 1, .. }), "{e}");
        let e = compose("m.wgsl", "#import a.wgsl\n", &lib).unwrap_err();
        assert!(matches!(e, ComposeError::Malformed { .. }), "{e}");
        let e = compose("m.wgsl", "#import loop1\n", &lib).unwrap_err();
        assert_eq!(
            e.to_string(),
            "import cycle: m.wgsl → loop1 → loop2 → loop1"
        );
    }
}
