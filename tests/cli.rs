//! Command-line conventions on the real binary: exit codes (and their table in `--help` and the
//! README), `run --json`, `--fail-on-collision`, shell completions, the man page, and the
//! examples of `--help`.

mod common;
use common::*;

use std::collections::BTreeSet;
use std::process::Command;

use clap::Parser;

const COLLIDES: &str = "scenarios/bicycle_obstacle.toml";
const CLEAR: &str = "scenarios/bicycle_obstacle_gamma_m.toml";

fn code(args: &[&str]) -> (Option<i32>, String, String) {
    let o = mjsafe(args);
    (o.status.code(), stdout(&o), stderr(&o))
}

#[test]
fn exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    let log = |name: &str| dir.path().join(name).to_str().unwrap().to_string();

    // 0: a collision is a result.
    let (c, out, err) = code(&["run", COLLIDES, "--set", "duration=5.0", "--out", &log("a.mcap")]);
    assert_eq!(c, Some(0), "{err}");
    assert!(out.contains("COLLISION"), "{out}");
    // 4: the same run as a CI gate.
    let (c, out, err) = code(&[
        "run",
        COLLIDES,
        "--set",
        "duration=5.0",
        "--out",
        &log("b.mcap"),
        "--fail-on-collision",
    ]);
    assert_eq!(c, Some(4), "{out}{err}");
    assert!(out.contains("COLLISION"), "the summary is still printed: {out}");
    assert!(
        err.contains("--fail-on-collision") && err.contains("obstacle_0"),
        "{err}"
    );
    // 0 with the gate when the run is clear.
    let (c, out, err) = code(&[
        "run",
        CLEAR,
        "--set",
        "duration=5.0",
        "--out",
        &log("c.mcap"),
        "--fail-on-collision",
    ]);
    assert_eq!(c, Some(0), "{out}{err}");
    assert!(out.contains("no collision"), "{out}");
    // 1: bad input; 2: usage.
    let (c, _, err) = code(&["run", "scenarios/no-such-file.toml"]);
    assert_eq!(c, Some(1), "{err}");
    let (c, _, err) = code(&["run", COLLIDES, "--no-such-flag"]);
    assert_eq!(c, Some(2), "{err}");
    let (c, _, err) = code(&["frobnicate"]);
    assert_eq!(c, Some(2), "{err}");

    // Sweeps: 1 broken (before anything runs), 3 some runs failed, 4 some collided, 0 clear.
    let sweep = |out: &str, extra: &[&str]| {
        let mut args = vec!["sweep", COLLIDES, "--set", "duration=5.0", "--out", out];
        args.extend_from_slice(extra);
        code(&args)
    };
    let (c, _, err) = sweep(&log("s1"), &["--grid", "delays.steering=0.1,[0.2"]);
    assert_eq!(c, Some(1), "{err}");
    assert!(!dir.path().join("s1").exists(), "a broken sweep runs nothing");
    let (c, _, err) = sweep(
        &log("s3"),
        &["--grid", "delays.steering=0.1,-1.0", "--fail-on-collision"],
    );
    assert_eq!(c, Some(3), "failed runs take precedence over collisions: {err}");
    assert!(dir.path().join("s3/summary.json").exists());
    let (c, _, err) = sweep(
        &log("s4"),
        &["--grid", "delays.steering=0.1,0.2", "--fail-on-collision"],
    );
    assert_eq!(c, Some(4), "{err}");
    assert!(err.contains("2 of 2 runs collided: 0, 1"), "{err}");
    let (c, _, err) = sweep(&log("s0"), &["--grid", "delays.steering=0.1,0.2"]);
    assert_eq!(c, Some(0), "{err}");
    let gamma_m = "filter={kind='gamma_m', l0=4.0, l1=4.0, m=50.0}";
    let (c, _, err) = sweep(
        &log("s0g"),
        &[
            "--set",
            gamma_m,
            "--grid",
            "delays.steering=0.1,0.2",
            "--fail-on-collision",
        ],
    );
    assert_eq!(c, Some(0), "gamma-m clears the obstacle: {err}");
}

#[test]
fn run_json_is_the_summary_as_one_object() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    let (c, out, err) = code(&[
        "run",
        COLLIDES,
        "--set",
        "duration=5.0",
        "--out",
        log.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(c, Some(0), "{err}");
    assert_eq!(out.lines().count(), 1, "one line: {out}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("run --json prints JSON");
    println!("{v}");
    let m = analyze_json(&log);
    assert_eq!(v["scenario"], "bicycle_obstacle");
    assert_eq!(v["log"], log.to_str().unwrap());
    assert_eq!(v["min_h"], m["min_h"]);
    assert_eq!(v["min_h_by_barrier"], m["min_h_by_barrier"]);
    assert_eq!(v["collision"], m["collision"]);
    assert!(v["collision"]["time"].as_f64().unwrap() > 3.0, "{v}");
    assert_eq!(v["steps"], m["steps"]);
    assert_eq!(v["simulated_time"], m["simulated_time"]);
    assert_eq!(v["complete"], true);
    assert!(v["error"].is_null());
    assert!(v["real_time_factor"].as_f64().unwrap() > 0.0);

    // A clear run: collision null.
    let log = dir.path().join("clear.mcap");
    let (c, out, _) = code(&[
        "run",
        CLEAR,
        "--set",
        "duration=5.0",
        "--out",
        log.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(c, Some(0));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["collision"].is_null(), "{v}");
    assert!(v["min_h"].as_f64().unwrap() > 0.0, "{v}");
}

/// The codes of a table whose rows start with the code: `  3    …` (help) or `| 3 | …` (README).
fn codes(text: &str, after: &str) -> BTreeSet<u32> {
    let start = text.find(after).unwrap_or_else(|| panic!("no `{after}` in:\n{text}"));
    text[start + after.len()..]
        .lines()
        .skip(1)
        .skip_while(|l| l.trim().is_empty())
        .take_while(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .filter_map(|l| {
            l.trim_start_matches(|c: char| c == '|' || c.is_whitespace())
                .split(|c: char| !c.is_ascii_digit())
                .next()
                .and_then(|n| n.parse().ok())
        })
        .collect()
}

#[test]
fn exit_code_tables_agree() {
    let help = stdout(&mjsafe(&["--help"]));
    let in_help = codes(&help, "Exit codes:");
    assert_eq!(in_help, BTreeSet::from([0, 1, 2, 3, 4, 5, 6, 130, 141]), "{help}");
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    assert_eq!(codes(&readme, "## Exit codes"), in_help, "README's table vs --help");
    // The constants the code uses are the table's.
    use mjsafe::cli::exit;
    let constants = [
        exit::DONE,
        exit::ERROR,
        exit::USAGE,
        exit::RUNS_FAILED,
        exit::COLLISION,
        exit::VIOLATION,
        exit::BELOW,
        exit::INTERRUPTED,
        exit::BROKEN_PIPE,
    ];
    assert_eq!(
        constants.iter().map(|&c| u32::from(c)).collect::<BTreeSet<_>>(),
        in_help
    );
}

/// Splits a shell command line into words (single and double quotes, no expansion); cuts it
/// at an unquoted `|`, `>` or `#`.
fn words(line: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut word: Option<String> = None;
    let mut quote = None;
    for c in line.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.get_or_insert_with(String::new).push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                word.get_or_insert_with(String::new);
            }
            (None, '|' | '>' | '#') => break,
            (None, c) if c.is_whitespace() => words.extend(word.take()),
            (None, c) => word.get_or_insert_with(String::new).push(c),
        }
    }
    words.extend(word);
    words
}

#[test]
fn help_examples_parse_and_name_real_files() {
    let mut seen = 0;
    for sub in [&[][..], &["run"], &["sweep"], &["analyze"]] {
        let help = stdout(&mjsafe(&[sub, &["--help"]].concat()));
        let examples = &help[help
            .find("Examples:")
            .unwrap_or_else(|| panic!("no examples in {sub:?} --help"))..];
        for line in examples.lines().skip(1).take_while(|l| l.starts_with("  mjsafe ")) {
            let argv = words(line.trim());
            if let Err(e) = mjsafe::cli::Cli::try_parse_from(&argv) {
                panic!("`{}` in {sub:?} --help does not parse: {e}", line.trim());
            }
            // Scenario and sweep files named by an example exist.
            for w in argv.iter().filter(|w| w.starts_with("scenarios/")) {
                assert!(root().join(w).exists(), "`{}` names a missing file {w}", line.trim());
            }
            seen += 1;
        }
    }
    assert!(seen >= 15, "only {seen} examples");
    // The parser is the binary's: an example with a typo would be caught.
    assert!(mjsafe::cli::Cli::try_parse_from(words("mjsafe run x.toml --fail-on-colision")).is_err());
}

#[test]
fn completions_name_the_subcommands() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let (c, out, err) = code(&["completions", shell]);
        assert_eq!(c, Some(0), "{shell}: {err}");
        for word in [
            "run",
            "sweep",
            "analyze",
            "info",
            "bench",
            "completions",
            "fail-on-collision", // fish: `-l fail-on-collision`
            "shard",
        ] {
            assert!(out.contains(word), "{shell} completions lack {word}");
        }
    }
    let (c, _, _) = code(&["completions", "tcsh"]);
    assert_eq!(c, Some(2), "an unknown shell is a usage error");

    // bash loads the script and completes a subcommand from it.
    let (_, script, _) = code(&["completions", "bash"]);
    let dir = tempfile::tempdir().unwrap();
    let file = write(dir.path(), "mjsafe.bash", &script);
    let probe = format!(
        "source {}; COMP_WORDS=(mjsafe sw); COMP_CWORD=1; COMP_LINE='mjsafe sw'; COMP_POINT=9; \
         _mjsafe mjsafe sw mjsafe; printf '%s\\n' \"${{COMPREPLY[@]}}\"",
        file.display()
    );
    let o = Command::new("bash").args(["-c", &probe]).output().unwrap();
    assert_eq!(
        stdout(&o).trim(),
        "sweep",
        "bash completion of `mjsafe sw`: {}",
        text(&o)
    );
}

#[test]
fn man_page_renders() {
    let (c, roff, err) = code(&["man"]);
    assert_eq!(c, Some(0), "{err}");
    assert!(roff.starts_with(".ie") || roff.contains(".TH mjsafe 1"), "{roff}");
    // groff (Debian's groff-base) renders it without a warning.
    let dir = tempfile::tempdir().unwrap();
    let page = write(dir.path(), "mjsafe.1", &roff);
    let o = Command::new("groff")
        .args(["-k", "-man", "-Tutf8", "-ww"])
        .arg(&page)
        .env("LANG", "C.UTF-8")
        .output()
        .expect("groff runs (Debian's groff-base; scripts/setup.sh --test installs it)");
    assert!(o.status.success() && stderr(&o).is_empty(), "groff: {}", stderr(&o));
    // Formatted text: strip the overstriking (bold/underline) of -Tutf8.
    let shown: String = {
        let raw = stdout(&o);
        let mut s = String::new();
        for c in raw.chars() {
            if c == '\u{8}' {
                s.pop();
            } else if matches!(c, '\u{2010}' | '\u{2212}') {
                // groff's hyphen and minus for `-` and `\-`.
                s.push('-');
            } else {
                s.push(c);
            }
        }
        s
    };
    for needle in [
        "NAME",
        "SYNOPSIS",
        "SUBCOMMANDS",
        "mjsafe-sweep(1)",
        "Exit codes:",
        "--fail-on-collision",
    ] {
        assert!(shown.contains(needle), "the rendered page lacks {needle}:\n{shown}");
    }

    // --dir: one page per subcommand.
    let pages = dir.path().join("man1");
    let (c, _, err) = code(&["man", "--dir", pages.to_str().unwrap()]);
    assert_eq!(c, Some(0), "{err}");
    let names = listing(&pages);
    for name in ["mjsafe.1", "mjsafe-run.1", "mjsafe-sweep.1", "mjsafe-analyze.1"] {
        assert!(names.iter().any(|n| n == name), "{name} not in {names:?}");
    }
    let run_page = std::fs::read_to_string(pages.join("mjsafe-run.1")).unwrap();
    assert!(run_page.contains("fail\\-on\\-collision"), "{run_page}");
    // Every page the top page lists is written (`mjsafe help` has none, and is not listed).
    let top = std::fs::read_to_string(pages.join("mjsafe.1")).unwrap();
    for listed in top.split("mjsafe\\-").skip(1).filter_map(|rest| rest.split_once("(1)")) {
        let page = format!("mjsafe-{}.1", listed.0.replace("\\-", "-"));
        assert!(names.contains(&page), "{page} is listed but not written: {names:?}");
    }
    assert!(!top.contains("mjsafe\\-help(1)"), "{top}");
    // Written again: the earlier pages are replaced.
    let (c, _, err) = code(&["man", "--dir", pages.to_str().unwrap()]);
    assert_eq!(c, Some(0), "{err}");
    // A file that is not a man page, a link or a directory under a page's name: refused
    // before any page is written, and left as it was.
    let notes = dir.path().join("notes.txt");
    std::fs::write(&notes, "precious\n").unwrap();
    for (name, make) in [
        ("mjsafe.1", "file"),
        ("mjsafe-run.1", "link"),
        ("mjsafe-info.1", "directory"),
    ] {
        let other = dir.path().join(format!("man-{make}"));
        std::fs::create_dir_all(&other).unwrap();
        let target = other.join(name);
        match make {
            "file" => std::fs::write(&target, "precious\n").unwrap(),
            "link" => std::os::unix::fs::symlink(&notes, &target).unwrap(),
            _ => std::fs::create_dir(&target).unwrap(),
        }
        let (c, _, err) = code(&["man", "--dir", other.to_str().unwrap()]);
        assert_eq!(c, Some(1), "{make}: {err}");
        assert!(err.contains(name), "{make}: {err}");
        assert_eq!(listing(&other), [name], "{make}: nothing written");
    }
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "precious\n");
}
