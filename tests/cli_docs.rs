//! `docs/cli.md` is the `--help` text of every command and subcommand of both binaries, taken
//! from the binaries themselves; this test fails when the file no longer matches them.
//! Subcommands are found in each help text's `Commands:` section, so a new one is picked up
//! without touching this file. Regenerate with `PGSER_BLESS=1 cargo test --release --test cli_docs`.

use std::path::{Path, PathBuf};
use std::process::Command;

const BINARIES: [(&str, &str); 2] =
    [("pgser-etl", env!("CARGO_BIN_EXE_pgser-etl")), ("pgser-train", env!("CARGO_BIN_EXE_pgser-train"))];

const REGENERATE: &str = "PGSER_BLESS=1 cargo test --release --test cli_docs";

fn docs_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/cli.md")
}

/// `EXE ARGS.. --help`, at a fixed width and without colour whatever the terminal and
/// environment (clap wraps at `COLUMNS` when its `wrap_help` feature is on), trailing spaces
/// trimmed from each line.
fn help(exe: &str, args: &[&str]) -> String {
    let out = Command::new(exe)
        .args(args)
        .arg("--help")
        .env("COLUMNS", "100")
        .env("NO_COLOR", "1")
        .env("TERM", "dumb")
        .env_remove("CLICOLOR_FORCE")
        .output()
        .unwrap_or_else(|e| panic!("{exe}: cannot run: {e}"));
    assert!(out.status.success(), "{exe} {} --help: exit {}", args.join(" "), out.status);
    let text = String::from_utf8(out.stdout).expect("help is UTF-8");
    let lines: Vec<&str> = text.lines().map(str::trim_end).collect();
    lines.join("\n").trim_end().to_string()
}

/// The subcommand names listed in a help text's `Commands:` section, but `help`. A command's
/// line starts with two spaces and its name; a wrapped description is indented further.
fn subcommands(help: &str) -> Vec<String> {
    let Some(start) = help.lines().position(|l| l == "Commands:") else { return Vec::new() };
    help.lines()
        .skip(start + 1)
        .take_while(|l| l.starts_with("  "))
        .filter(|l| !l[2..].starts_with(' '))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|name| *name != "help")
        .map(str::to_string)
        .collect()
}

/// (command path, help text) of `path` and of all its subcommands, depth first, in the order
/// the help texts list them.
fn walk(exe: &str, path: &mut Vec<String>, out: &mut Vec<(String, String)>) {
    let args: Vec<&str> = path[1..].iter().map(String::as_str).collect();
    let text = help(exe, &args);
    let children = subcommands(&text);
    out.push((path.join(" "), text));
    for child in children {
        path.push(child);
        walk(exe, path, out);
        path.pop();
    }
}

/// GitHub's anchor of a heading made of a command path (`pgser-etl pipeline run`).
fn anchor(title: &str) -> String {
    title.replace(' ', "-")
}

fn render() -> String {
    let mut pages = Vec::new();
    for (name, exe) in BINARIES {
        walk(exe, &mut vec![name.to_string()], &mut pages);
    }
    let mut md = String::new();
    md.push_str("# Command-line reference\n\n");
    md.push_str(
        "The `--help` text of every command of `pgser-etl` and `pgser-train`, generated from the binaries by\n\
         `tests/cli_docs.rs`, which fails when this file is out of date. Do not edit it by hand; after changing\n\
         a command, a flag or a help text, regenerate it with\n\n",
    );
    md.push_str(&format!("```sh\n{REGENERATE}\n```\n\n"));
    md.push_str(
        "Every command also answers `-h` (the same text, shorter) and `help SUBCOMMAND`. What the files the\n\
         commands write hold: [tables.md](tables.md) and [checkpoint.md](checkpoint.md); pipeline files:\n\
         [pipelines.md](pipelines.md).\n\n",
    );
    for (title, _) in &pages {
        let depth = title.matches(' ').count();
        md.push_str(&format!("{}- [`{title}`](#{})\n", "  ".repeat(depth), anchor(title)));
    }
    for (title, text) in &pages {
        assert!(!text.contains("```"), "{title}: the help text holds a code fence");
        md.push_str(&format!("\n## {title}\n\n```text\n{text}\n```\n"));
    }
    md
}

#[test]
fn cli_reference_is_up_to_date() {
    let want = render();
    let path = docs_file();
    if std::env::var_os("PGSER_BLESS").is_some_and(|v| !v.is_empty() && v != "0") {
        std::fs::write(&path, &want).unwrap_or_else(|e| panic!("{}: cannot write: {e}", path.display()));
        return;
    }
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    if have != want {
        let line = have
            .lines()
            .zip(want.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(have.lines().count().min(want.lines().count()))
            + 1;
        panic!(
            "docs/cli.md is out of date with the binaries' --help (first difference at line {line}); regenerate it with `{REGENERATE}`"
        );
    }
}

#[test]
fn subcommands_are_read_from_the_commands_section() {
    let text = "About\n\nUsage: x <COMMAND>\n\nCommands:\n  run   Run it\n        and more\n  bench-sampler\n          Time\n  help  Print this message\n\nOptions:\n  -h, --help  Print help";
    assert_eq!(subcommands(text), ["run", "bench-sampler"]);
    assert!(subcommands("Usage: x [OPTIONS]\n\nOptions:\n  -h, --help  Print help").is_empty());
}
