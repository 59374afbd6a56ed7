//! The documentation against the code: the README stays short and its picture exists, every
//! relative link of README.md and docs/ leads to a file (and heading) that exists, every flag the
//! command line takes is documented in the guide or a method page, every method has its page
//! with its generated table, and no text tells the story of how the work was organised.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use defocus::methods::registry::METHODS;

use crate::cli::defocus;

/// The README's length limit: a page a newcomer reads in five minutes.
const README_MAX_LINES: usize = 250;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every Markdown file under `dir`, recursively, sorted.
fn markdown_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "md") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// README.md and every Markdown file of docs/.
fn documents() -> Vec<PathBuf> {
    let mut docs = vec![root().join("README.md")];
    docs.extend(markdown_under(&root().join("docs")));
    docs
}

/// The text outside fenced code blocks (links inside code are examples, not links).
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            out.push('\n');
            continue;
        }
        if !fenced {
            out.push_str(line);
        }
        out.push('\n');
    }
    out
}

/// The targets of the Markdown links and images of `text`: `[..](target)` and `![..](target)`,
/// outside code spans.
fn link_targets(text: &str) -> Vec<String> {
    let mut targets = Vec::new();
    for line in prose(text).lines() {
        // Drop inline code spans: `[a](b)` inside backticks is not a link.
        let mut plain = String::new();
        let mut in_code = false;
        for ch in line.chars() {
            if ch == '`' {
                in_code = !in_code;
            } else if !in_code {
                plain.push(ch);
            }
        }
        let bytes = plain.as_bytes();
        let mut i = 0;
        while let Some(off) = plain[i..].find("](") {
            let start = i + off + 2;
            let mut depth = 1;
            let mut end = start;
            while end < bytes.len() {
                match bytes[end] {
                    b'(' => depth += 1,
                    b')' => {
                        depth -= 1;
                        if depth == 0 {
                            break;
                        }
                    }
                    _ => {}
                }
                end += 1;
            }
            let target = plain[start..end.min(plain.len())].trim();
            // A title after the address: `(file.md "Title")`.
            let target = target.split_whitespace().next().unwrap_or("");
            targets.push(target.to_string());
            i = end.min(plain.len());
        }
    }
    targets
}

/// The anchors of the headings of a Markdown text, as GitHub and mdBook make them: lower case,
/// spaces to hyphens, punctuation other than hyphens and underscores dropped.
fn anchors(text: &str) -> BTreeSet<String> {
    let mut set = BTreeSet::new();
    for line in prose(text).lines() {
        let t = line.trim_start();
        if !t.starts_with('#') {
            continue;
        }
        let title = t.trim_start_matches('#').trim();
        let slug: String = title
            .to_lowercase()
            .chars()
            .filter_map(|c| {
                if c == ' ' {
                    Some('-')
                } else if c.is_alphanumeric() || c == '-' || c == '_' {
                    Some(c)
                } else {
                    None
                }
            })
            .collect();
        set.insert(slug);
    }
    set
}

#[test]
fn readme_is_short_and_shows_its_picture() {
    let text = std::fs::read_to_string(root().join("README.md")).expect("README.md");
    let lines = text.lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines; at most {README_MAX_LINES}: move the rest into docs/"
    );
    let pictures: Vec<String> = link_targets(&text)
        .into_iter()
        .filter(|t| t.ends_with(".png"))
        .collect();
    assert!(!pictures.is_empty(), "README.md shows no picture");
    // Its first lines give the two commands a newcomer needs.
    let head: String = text.lines().take(12).collect::<Vec<_>>().join("\n");
    assert!(head.contains("cargo run --release -- render"), "{head}");
    assert!(head.contains("scripts/test"), "{head}");
}

#[test]
fn every_relative_link_of_the_docs_leads_somewhere() {
    let mut broken = Vec::new();
    let mut checked = 0;
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).unwrap();
        for target in link_targets(&text) {
            if target.is_empty()
                || target.contains("://")
                || target.starts_with("mailto:")
                || target.starts_with('<')
            {
                continue;
            }
            checked += 1;
            let (file, anchor) = match target.split_once('#') {
                Some((f, a)) => (f, Some(a)),
                None => (target.as_str(), None),
            };
            let path = if file.is_empty() {
                doc.clone()
            } else {
                doc.parent().unwrap().join(file)
            };
            if !path.exists() {
                broken.push(format!("{}: {target} (no such file)", doc.display()));
                continue;
            }
            if let Some(anchor) = anchor {
                if path.extension().is_some_and(|x| x == "md") {
                    let there = std::fs::read_to_string(&path).unwrap();
                    if !anchors(&there).contains(anchor) {
                        broken.push(format!("{}: {target} (no such heading)", doc.display()));
                    }
                }
            }
        }
    }
    assert!(
        checked > 20,
        "only {checked} links found: is the parser right?"
    );
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

/// The long flags a `--help` text lists (`--flag` at the start of an option line).
fn flags_of(help: &str) -> BTreeSet<String> {
    let mut set = BTreeSet::new();
    for line in help.lines() {
        let t = line.trim_start();
        let t = t.strip_prefix("-").map_or(t, |_| {
            // `-q, --quiet`: the long form after the short one.
            t.split_once(", ").map_or(t, |(_, rest)| rest)
        });
        if let Some(rest) = t.strip_prefix("--") {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                .collect();
            if !name.is_empty() && name != "help" && name != "version" {
                set.insert(format!("--{name}"));
            }
        }
    }
    set
}

#[test]
fn every_flag_of_the_command_line_is_in_the_guide_or_a_method_page() {
    let mut docs = String::new();
    for dir in ["docs/guide", "docs/methods"] {
        for p in markdown_under(&root().join(dir)) {
            docs.push_str(&std::fs::read_to_string(p).unwrap());
        }
    }
    let mut missing = Vec::new();
    let mut total = 0;
    for command in [
        vec!["--help"],
        vec!["render", "--help"],
        vec!["blur", "--help"],
        vec!["compare", "--help"],
        vec!["kernel", "--help"],
        vec!["devices", "--help"],
    ] {
        let out = defocus(&command);
        assert!(out.status.success(), "{command:?}");
        let help = String::from_utf8_lossy(&out.stdout);
        for flag in flags_of(&help) {
            total += 1;
            // As a whole word: `--layers` is not documented by `--layers-out`.
            let found = docs.match_indices(&flag).any(|(i, _)| {
                let next = docs[i + flag.len()..].chars().next();
                !next.is_some_and(|c| c.is_ascii_alphanumeric() || c == '-')
            });
            if !found {
                missing.push(format!("{} {flag}", command[0]));
            }
        }
    }
    assert!(total > 50, "only {total} flags found: is the parser right?");
    assert!(
        missing.is_empty(),
        "flags in --help but not in docs/guide or docs/methods:\n{}",
        missing.join("\n")
    );
}

#[test]
fn every_method_has_its_page_with_its_generated_table() {
    for m in METHODS {
        let path = root().join("docs/methods").join(format!("{}.md", m.id));
        let text =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let begin = text
            .find("<!-- tables:begin -->")
            .unwrap_or_else(|| panic!("{}: no <!-- tables:begin --> marker", path.display()));
        let end = text
            .find("<!-- tables:end -->")
            .unwrap_or_else(|| panic!("{}: no <!-- tables:end --> marker", path.display()));
        let table = &text[begin..end];
        let rows = table.lines().filter(|l| l.starts_with('|')).count();
        assert!(
            rows >= 4,
            "{}: the generated table is empty; run scripts/tables",
            path.display()
        );
        assert!(
            table.contains(m.id) || table.contains("dB"),
            "{}",
            path.display()
        );
    }
}

/// Words that tell how the work was organised rather than what the project does.
fn story_in(text: &str, markdown: bool) -> Vec<String> {
    let mut found = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let lower = line.to_lowercase();
        for word in ["session", "sitting"] {
            if lower
                .match_indices(word)
                .any(|(i, _)| i == 0 || !lower.as_bytes()[i - 1].is_ascii_alphabetic())
            {
                found.push(format!("line {}: {}", n + 1, line.trim()));
            }
        }
        // Issue numbers: `#26` in prose, `issue 26` anywhere.
        let bytes = lower.as_bytes();
        let issue_ref = lower.match_indices('#').any(|(i, _)| {
            let digits = bytes[i + 1..]
                .iter()
                .take_while(|b| b.is_ascii_digit())
                .count();
            let after = bytes.get(i + 1 + digits);
            let before = i.checked_sub(1).map(|j| bytes[j]);
            markdown
                && digits > 0
                && !after.is_some_and(|b| b.is_ascii_alphanumeric())
                && !before.is_some_and(|b| b.is_ascii_alphanumeric() || b == b'&')
        }) || lower.contains("issue #")
            || lower
                .match_indices("issue ")
                .any(|(i, _)| bytes.get(i + 6).is_some_and(|b| b.is_ascii_digit()));
        if issue_ref {
            found.push(format!("line {}: {}", n + 1, line.trim()));
        }
    }
    found
}

#[test]
fn no_text_tells_the_story_of_the_work() {
    let mut files: Vec<PathBuf> = documents();
    let mut stack = vec![root().join("src"), root().join("python")];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            if p.is_dir() {
                if name != "target" && !name.starts_with('.') && name != "__pycache__" {
                    stack.push(p);
                }
            } else if ["rs", "py", "pyi", "md", "toml", "wgsl"]
                .iter()
                .any(|x| name.ends_with(&format!(".{x}")))
            {
                files.push(p);
            }
        }
    }
    let mut found = Vec::new();
    for f in &files {
        let Ok(text) = std::fs::read_to_string(f) else {
            continue;
        };
        let markdown = f.extension().is_some_and(|x| x == "md");
        for hit in story_in(&text, markdown) {
            found.push(format!("{}: {hit}", f.display()));
        }
    }
    assert!(
        found.is_empty(),
        "text that tells how the work was organised (say what the code does, date measurements):\n{}",
        found.join("\n")
    );
}

#[test]
fn the_story_check_finds_what_it_looks_for() {
    assert_eq!(story_in("measured in the tenth session", true).len(), 1);
    assert_eq!(story_in("### Trace (#26 item 2)", true).len(), 1);
    assert_eq!(story_in("an early test (issue #15)", false).len(), 1);
    assert!(story_in("colour #333 and `#[test]`", false).is_empty());
    assert!(story_in("## Measured 2026-12-06 on 2 cores", true).is_empty());
}

/// The `defocus SUBCOMMAND ...` lines of the shell blocks of `text`, continuation lines joined.
fn command_lines(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_shell = false;
    let mut pending = String::new();
    for line in text.lines() {
        let t = line.trim();
        if t.starts_with("```") {
            in_shell = matches!(t, "```sh" | "```bash" | "```shell" | "```console");
            pending.clear();
            continue;
        }
        if !in_shell {
            continue;
        }
        let t = t.strip_prefix("$ ").unwrap_or(t);
        if pending.is_empty() && !t.starts_with("defocus ") {
            continue;
        }
        // A comment ends the command.
        let code = t.split(" #").next().unwrap_or(t);
        pending.push_str(code.trim_end_matches('\\'));
        pending.push(' ');
        if !code.trim_end().ends_with('\\') {
            // `a; defocus b` holds two commands.
            for part in pending.split(';') {
                let part = part.trim();
                if part.starts_with("defocus ") {
                    out.push(part.to_string());
                }
            }
            pending.clear();
        }
    }
    out
}

#[test]
fn every_flag_the_docs_show_exists() {
    let mut known: std::collections::HashMap<&str, BTreeSet<String>> = Default::default();
    let global = flags_of(&String::from_utf8_lossy(&defocus(&["--help"]).stdout));
    for sub in ["render", "blur", "compare", "kernel"] {
        let help = String::from_utf8_lossy(&defocus(&[sub, "--help"]).stdout).into_owned();
        let mut flags = flags_of(&help);
        flags.extend(global.iter().cloned());
        known.insert(sub, flags);
    }
    let mut unknown = Vec::new();
    let mut commands = 0;
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).unwrap();
        for cmd in command_lines(&text) {
            let words: Vec<&str> = cmd.split_whitespace().collect();
            // `defocus [global flags] SUBCOMMAND ...`
            let Some(sub) = words
                .iter()
                .skip(1)
                .find(|w| !w.starts_with('-') && known.contains_key(**w))
            else {
                continue;
            };
            commands += 1;
            for w in &words {
                if let Some(name) = w.strip_prefix("--") {
                    let name: String = name
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                        .collect();
                    let flag = format!("--{name}");
                    if name.is_empty() || name == "help" || name == "version" {
                        continue;
                    }
                    if !known[*sub].contains(&flag) {
                        unknown.push(format!("{}: defocus {sub} {flag}", doc.display()));
                    }
                }
            }
        }
    }
    assert!(
        commands > 30,
        "only {commands} commands found: is the parser right?"
    );
    assert!(
        unknown.is_empty(),
        "flags shown in the docs that the command does not take:\n{}",
        unknown.join("\n")
    );
}

#[test]
fn every_page_of_the_docs_is_in_the_book() {
    let summary = std::fs::read_to_string(root().join("docs/SUMMARY.md")).expect("docs/SUMMARY.md");
    let listed: BTreeSet<String> = link_targets(&summary).into_iter().collect();
    let mut missing = Vec::new();
    for page in markdown_under(&root().join("docs")) {
        let rel = page
            .strip_prefix(root().join("docs"))
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        if rel != "SUMMARY.md" && !listed.contains(&rel) {
            missing.push(rel);
        }
    }
    assert!(
        missing.is_empty(),
        "pages of docs/ that docs/SUMMARY.md does not list (the book leaves them out): {missing:?}"
    );
}
