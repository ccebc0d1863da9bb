//! The module layers of ARCHITECTURE.md, enforced: every `crate::<module>` path in
//! the library's non-test code points to a module of the same layer or below.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::common::root;

/// Module name -> (layer number, layer name), from the table in ARCHITECTURE.md:
/// rows `| <n> <name> | \`module\`, ... | ... |`.
fn layer_table(markdown: &str) -> BTreeMap<String, (u32, String)> {
    let mut table = BTreeMap::new();
    for line in markdown.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 4 || !cells[0].is_empty() {
            continue;
        }
        let mut head = cells[1].split_whitespace();
        let (Some(Ok(number)), Some(name)) = (head.next().map(str::parse::<u32>), head.next())
        else {
            continue;
        };
        for module in cells[2].split(',') {
            let module = module.trim().trim_matches('`');
            if !module.is_empty() {
                table.insert(module.to_string(), (number, name.to_string()));
            }
        }
    }
    table
}

/// The code of a source file without comments and without its inline test modules
/// (`#[cfg(test)]` then `mod name {`, to its closing brace), and the names of
/// child modules declared test-only (`#[cfg(test)]` then `mod name;`).
fn non_test_code(text: &str) -> (String, Vec<String>) {
    let lines: Vec<&str> = text.lines().collect();
    let mut code = String::new();
    let mut test_children = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i].trim();
        if line == "#[cfg(test)]" {
            let next = lines.get(i + 1).map_or("", |l| l.trim());
            let declared = next.strip_prefix("mod ").or(next.strip_prefix("pub mod "));
            if let Some(rest) = declared {
                if let Some(name) = rest.strip_suffix(';') {
                    test_children.push(name.trim().to_string());
                    i += 2;
                    continue;
                }
                if rest.ends_with('{') {
                    // Skip the module's block: up to the line where its braces balance.
                    let mut depth = 0i64;
                    i += 1;
                    while i < lines.len() {
                        depth += lines[i].matches('{').count() as i64;
                        depth -= lines[i].matches('}').count() as i64;
                        i += 1;
                        if depth <= 0 {
                            break;
                        }
                    }
                    continue;
                }
            }
        }
        let without_comment = match line.find("//") {
            Some(at) => &line[..at],
            None => line,
        };
        code.push_str(without_comment);
        code.push('\n');
        i += 1;
    }
    (code, test_children)
}

/// The modules a piece of code names as `crate::<module>`.
fn named_modules(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(at) = rest.find("crate::") {
        let after = &rest[at + "crate::".len()..];
        let name: String = after
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        let preceded_by_ident = rest[..at]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_ascii_alphanumeric() || c == '_');
        if !name.is_empty() && !preceded_by_ident {
            out.push(name);
        }
        rest = after;
    }
    out
}

/// One import from a higher layer.
#[derive(Debug, Clone, PartialEq)]
struct UpwardImport {
    file: String,
    from: String,
    to: String,
}

/// The upward imports of one file of top-level module `module`; modules missing
/// from the table are errors too.
fn check_code(
    file: &str,
    module: &str,
    code: &str,
    table: &BTreeMap<String, (u32, String)>,
) -> Result<Vec<UpwardImport>, String> {
    let own = table
        .get(module)
        .ok_or_else(|| format!("{file}: module `{module}` is in no layer of ARCHITECTURE.md"))?;
    let mut upward = Vec::new();
    for target in named_modules(code) {
        if target == module {
            continue;
        }
        let theirs = table.get(&target).ok_or_else(|| {
            format!("{file}: `crate::{target}` is in no layer of ARCHITECTURE.md")
        })?;
        if theirs.0 > own.0 {
            upward.push(UpwardImport {
                file: file.to_string(),
                from: format!("{module} ({} {})", own.0, own.1),
                to: format!("{target} ({} {})", theirs.0, theirs.1),
            });
        }
    }
    Ok(upward)
}

/// Every `.rs` file below `dir`, skipping test-only child modules.
fn source_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            source_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn imports_only_point_down_the_layers_of_architecture_md() {
    let table = layer_table(&std::fs::read_to_string(root().join("ARCHITECTURE.md")).unwrap());
    assert!(table.len() > 20, "layer table not found: {table:?}");
    let src = root().join("src");
    let mut files = Vec::new();
    source_files(&src, &mut files);
    let texts: Vec<(PathBuf, String)> = files
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            (p, text)
        })
        .collect();
    // Files that are test-only child modules of another file.
    let mut test_only: Vec<PathBuf> = Vec::new();
    for (path, text) in &texts {
        let dir = match path.file_name().and_then(|n| n.to_str()) {
            Some("mod.rs") | Some("lib.rs") => path.parent().unwrap().to_path_buf(),
            _ => path.with_extension(""),
        };
        for child in non_test_code(text).1 {
            test_only.push(dir.join(format!("{child}.rs")));
            test_only.push(dir.join(&child));
        }
    }
    let mut upward = Vec::new();
    let mut problems = Vec::new();
    for (path, text) in &texts {
        let rel = path.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = top.trim_end_matches(".rs");
        if matches!(module, "bin" | "lib") || test_only.iter().any(|t| path.starts_with(t)) {
            continue;
        }
        let file = format!("src/{}", rel.display());
        match check_code(&file, module, &non_test_code(text).0, &table) {
            Ok(found) => upward.extend(found),
            Err(problem) => problems.push(problem),
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    let listing: Vec<String> = upward
        .iter()
        .map(|u| format!("{}: {} imports {}", u.file, u.from, u.to))
        .collect();
    assert!(
        upward.is_empty(),
        "imports from a higher layer (see ARCHITECTURE.md):\n{}",
        listing.join("\n")
    );
}

#[test]
fn an_upward_import_is_found_and_test_code_and_comments_are_not() {
    let table = layer_table(
        "| layer | modules | what |\n|---|---|---|\n| 2 system | `cell` | x |\n\
         | 1 pipeline | `plan`, `register` | y |\n| 0 core | `geometry` | z |\n",
    );
    assert_eq!(table.len(), 4);
    let code = |text: &str| non_test_code(text).0;
    let source = "use crate::geometry::Pose;\nuse crate::plan::x;\n\
                  // crate::cell::Cell in a comment\nfn f() { crate::cell::run(); }\n\
                  #[cfg(test)]\nmod tests {\n    use crate::cell::Cell;\n    fn f() {}\n}\n\
                  use crate::cell::Stage;\n";
    let found = check_code("src/register/a.rs", "register", &code(source), &table).unwrap();
    let upward = UpwardImport {
        file: "src/register/a.rs".into(),
        from: "register (1 pipeline)".into(),
        to: "cell (2 system)".into(),
    };
    // The call in `f` and the import after the test module; not the test module's.
    assert_eq!(found, vec![upward.clone(), upward]);
    let down_only = "use crate::geometry::Pose;\n#[cfg(test)]\nmod lockstep;\n";
    assert!(check_code("f", "cell", &code(down_only), &table)
        .unwrap()
        .is_empty());
    assert_eq!(non_test_code(down_only).1, vec!["lockstep".to_string()]);
    // A module missing from the table is an error, not a pass.
    assert!(check_code("f", "eval", "", &table).is_err());
    assert!(check_code("f", "plan", "crate::eval::x", &table).is_err());
    // `graspcell::crate` or `my_crate::` are not paths into this crate.
    assert!(named_modules("my_crate::cell x").is_empty());
}
