//! Every command the documents show runs as written, so they cannot drift
//! from the tools. The commands are read from the code spans and code
//! blocks of README.md, docs/*.md, firmware/PROTOCOL.md and
//! host-tests/RECORDING.md:
//! - `cargo flatland ...` runs (the built `flatland`, from the repository
//!   root) and exits 0. Placeholders are filled: RECORDING / REC with a
//!   scratch copy of a bundled recording, DIR and FILE with scratch paths,
//!   FILE.yaml with a ROS camera_info, SPEC, X, N, H, A..B, SECS with
//!   sample values; a command that needs ../shared (OPENCV_CYCLE) is not
//!   run. A synopsis (`[--opt VALUE]` groups, `a|b` choices) runs
//!   bare and once with each group and each choice. A bare `cargo flatland
//!   SUB` names a subcommand: `flatland SUB --help` must know it.
//! - `cargo X ...`: X is a cargo command or an alias of .cargo/config.toml,
//!   and every `--option` shown for the `fw` aliases is one `fw --help`
//!   lists (running them needs QEMU: `.ci/test` runs `cargo fw`,
//!   `cargo fw-test` and `cargo fw-bench`).
//! - `.ci/NAME` is an executable script.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

mod common;
use common::TempRecording;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// The documents users read, relative to the repository root.
fn documents() -> Vec<PathBuf> {
    let mut files = vec![PathBuf::from("README.md"), PathBuf::from("firmware/PROTOCOL.md"), PathBuf::from("host-tests/RECORDING.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .map(|p| p.strip_prefix(root()).unwrap().to_path_buf())
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

/// Every command in a document: code spans (which may wrap across lines)
/// and code-block lines that start with `cargo ` or `.ci/`, comments cut,
/// markdown table escapes undone.
fn commands(text: &str) -> Vec<String> {
    let (mut prose, mut found, mut in_block) = (String::new(), Vec::new(), false);
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
        } else if in_block {
            found.push(line.split('#').next().unwrap().trim().to_string());
        } else {
            prose.push_str(line);
            prose.push(' ');
        }
    }
    found.extend(prose.split('`').skip(1).step_by(2).map(|span| span.split_whitespace().collect::<Vec<_>>().join(" ")));
    found.into_iter().map(|c| c.replace("\\|", "|")).filter(|c| c.starts_with("cargo ") || c.starts_with(".ci/")).collect()
}

/// A synopsis's parts: words, and `[...]` optional groups (which may nest).
#[derive(Clone, Debug)]
enum Part {
    Word(String),
    Optional(String),
}

fn parts(synopsis: &str) -> Vec<Part> {
    let mut parts = Vec::new();
    let mut rest = synopsis.trim();
    while !rest.is_empty() {
        if let Some(inner) = rest.strip_prefix('[') {
            let mut depth = 1;
            let end = inner
                .char_indices()
                .find(|&(_, c)| {
                    depth += match c {
                        '[' => 1,
                        ']' => -1,
                        _ => 0,
                    };
                    depth == 0
                })
                .unwrap_or_else(|| panic!("unclosed [ in `{synopsis}`"))
                .0;
            parts.push(Part::Optional(inner[..end].to_string()));
            rest = inner[end + 1..].trim_start();
        } else {
            let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
            parts.push(Part::Word(rest[..end].to_string()));
            rest = rest[end..].trim_start();
        }
    }
    parts
}

/// Each way to run a synopsis: bare, then with each optional group in turn
/// (a nested group once without and once with its own groups), each `a|b`
/// word taken once per choice.
fn variants(synopsis: &str) -> Vec<Vec<String>> {
    let parts = parts(synopsis);
    let with = |group: Option<(usize, &Vec<String>)>| -> Vec<String> {
        parts
            .iter()
            .enumerate()
            .flat_map(|(i, part)| match (part, group) {
                (Part::Word(word), _) => vec![word.clone()],
                (Part::Optional(_), Some((g, words))) if g == i => words.clone(),
                (Part::Optional(_), _) => vec![],
            })
            .collect()
    };
    let mut runs = vec![with(None)];
    for (i, part) in parts.iter().enumerate() {
        if let Part::Optional(inner) = part {
            runs.extend(variants(inner).iter().map(|inner| with(Some((i, inner)))));
        }
    }
    // One run per choice of every `a|b` word (choices of different words
    // are taken together: the first with the first, and so on).
    runs.into_iter()
        .flat_map(|words| {
            let choices = words.iter().map(|w| w.split('|').count()).max().unwrap_or(1);
            (0..choices)
                .map(|c| {
                    words
                        .iter()
                        .map(|w| {
                            let options: Vec<&str> = w.split('|').collect();
                            options[c.min(options.len() - 1)].to_string()
                        })
                        .collect()
                })
                .collect::<Vec<Vec<String>>>()
        })
        .collect()
}

/// flat_marks' camera as a ROS camera_info.
const CAMERA_INFO: &str = "image_width: 256
image_height: 256
camera_matrix:
  rows: 3
  cols: 3
  data: [240.0, 0.0, 127.5, 0.0, 240.0, 127.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.0, 0.0, 0.0, 0.0, 0.0]
";

/// Scratch inputs and outputs for the placeholders.
struct Scratch {
    recording: TempRecording,
    dir: PathBuf,
    runs: usize,
}

impl Scratch {
    fn new() -> Scratch {
        let recording = TempRecording::copy_of("flat_marks", "documented");
        let dir = recording.dir.with_extension("out");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("camera_info.yaml"), CAMERA_INFO).unwrap();
        Scratch { recording, dir, runs: 0 }
    }

    /// `word` with its placeholder filled (None: no value for it here).
    fn fill(&mut self, word: &str) -> Option<String> {
        self.runs += 1;
        let scratch = |name: String| self.dir.join(name).display().to_string();
        Some(match word {
            "RECORDING" | "REC" => self.recording.dir.display().to_string(),
            "DIR" => scratch(format!("out-{}", self.runs)),
            // An input (an empty capture) or an output, a file of its own.
            "FILE" => {
                let path = scratch(format!("file-{}", self.runs));
                std::fs::write(&path, b"").unwrap();
                path
            }
            w if w.ends_with(".yaml") => scratch("camera_info.yaml".into()),
            w if w.starts_with("FILE.") => scratch(format!("out-{}.{}", self.runs, &w[5..])),
            // A picture the docs show, made as written but not over the committed one.
            w if w.starts_with("host-tests/doc/") => scratch(format!("out-{}-{}", self.runs, &w[15..])),
            "SPEC" => "noise=2".into(),
            "X" => "5".into(),
            "N" => "2".into(),
            "H" => "400".into(),
            "A..B" => "1..3".into(),
            "SECS" => "60".into(),
            "..." | "NAME" => return None,
            // The OpenCV reference lives outside the repository (../shared).
            w if w.contains("../shared") || w == "OPENCV_CYCLE" => return None,
            w => w.to_string(),
        })
    }
}

/// Runs `flatland ARGS` from the repository root; the failure if any.
fn run_flatland(args: &[String]) -> Result<(), String> {
    let start = std::time::Instant::now();
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(args).current_dir(root()).stdin(Stdio::null()).output().unwrap();
    println!("{:6.2} s  flatland {}", start.elapsed().as_secs_f64(), args.join(" "));
    if output.status.success() {
        Ok(())
    } else {
        Err(format!("flatland {}: {}\n{}", args.join(" "), output.status, String::from_utf8_lossy(&output.stderr)))
    }
}

fn cargo_aliases() -> BTreeSet<String> {
    let config = std::fs::read_to_string(root().join(".cargo/config.toml")).unwrap();
    let aliases = config.split("[alias]").nth(1).expect("an [alias] table");
    aliases
        .lines()
        .take_while(|l| !l.starts_with('['))
        .filter_map(|l| l.split_once('=').map(|(name, _)| name.trim().to_string()))
        .filter(|name| !name.is_empty() && !name.starts_with('#') && !name.starts_with('"'))
        .collect()
}

#[test]
fn every_documented_command_runs_as_written() {
    let aliases = cargo_aliases();
    let builtins = ["build", "check", "clippy", "doc", "install", "run", "test", "fuzz", "+nightly"];
    let fw_help = Command::new(env!("CARGO_BIN_EXE_fw")).arg("--help").output().unwrap();
    let fw_help = format!("{}{}", String::from_utf8_lossy(&fw_help.stdout), String::from_utf8_lossy(&fw_help.stderr));
    let mut scratch = Scratch::new();
    let (mut failures, mut runs, mut seen) = (Vec::new(), Vec::new(), BTreeSet::new());
    for document in documents() {
        let text = std::fs::read_to_string(root().join(&document)).unwrap();
        for command in commands(&text) {
            if !seen.insert(command.clone()) {
                continue;
            }
            let place = format!("{}: `{command}`", document.display());
            if let Some(script) = command.strip_prefix(".ci/") {
                // `.ci/` alone names the folder.
                let Some(name) = script.split_whitespace().next() else { continue };
                let path = root().join(".ci").join(name);
                let executable = std::fs::metadata(&path).is_ok_and(|m| {
                    use std::os::unix::fs::PermissionsExt;
                    m.permissions().mode() & 0o111 != 0
                });
                if !executable {
                    failures.push(format!("{place}: no executable .ci/{name}"));
                }
                continue;
            }
            let words: Vec<&str> = command.split_whitespace().collect();
            let Some(&sub) = words.get(1) else { continue };
            // `cargo fw*` names the fw aliases together.
            let known = builtins.contains(&sub)
                || aliases.contains(sub)
                || sub.strip_suffix('*').is_some_and(|stem| aliases.iter().any(|a| a.starts_with(stem)));
            if !known {
                failures.push(format!("{place}: `cargo {sub}` is neither a cargo command nor an alias"));
                continue;
            }
            if sub.starts_with("fw") {
                for option in words.iter().map(|w| w.trim_start_matches('[').trim_end_matches(']')).filter(|w| w.starts_with("--")) {
                    if !fw_help.contains(option) {
                        failures.push(format!("{place}: `fw --help` does not list {option}"));
                    }
                }
                continue;
            }
            if sub != "flatland" {
                continue;
            }
            if words.len() <= 3 && words.get(2).is_none_or(|w| !w.starts_with('-')) {
                // The tool or a subcommand, named in prose.
                runs.push((place, words[2..].iter().map(|w| w.to_string()).chain(["--help".to_string()]).collect()));
                continue;
            }
            for variant in variants(&words[2..].join(" ")) {
                if let Some(args) = variant.iter().map(|w| scratch.fill(w)).collect::<Option<Vec<String>>>() {
                    runs.push((place.clone(), args));
                }
            }
        }
    }
    // The runs in parallel: calibrate takes seconds.
    let next = std::sync::atomic::AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get());
    let outcomes: Vec<Vec<(usize, Result<(), String>)>> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some((_, args)) = runs.get(i) else { return done };
                        done.push((i, run_flatland(args)));
                    }
                })
            })
            .collect();
        workers.into_iter().map(|w| w.join().unwrap()).collect()
    });
    for (i, outcome) in outcomes.into_iter().flatten() {
        if let Err(e) = outcome {
            failures.push(format!("{}: {e}", runs[i].0));
        }
    }
    println!("{} flatland runs from {} documented commands", runs.len(), seen.len());
    assert!(failures.is_empty(), "{} documented commands fail:\n{}", failures.len(), failures.join("\n"));
    assert!(runs.len() > 30, "the documents show flatland commands: {} runs", runs.len());
    let _ = std::fs::remove_dir_all(&scratch.dir);
}

#[test]
fn synopses_expand_into_runs() {
    let runs = variants("detect RECORDING [--format csv|json] [--png DIR]");
    assert_eq!(
        runs,
        [vec!["detect", "RECORDING"], vec!["detect", "RECORDING", "--format", "csv"], vec!["detect", "RECORDING", "--format", "json"], vec![
            "detect",
            "RECORDING",
            "--png",
            "DIR"
        ]]
        .map(|r| r.into_iter().map(String::from).collect::<Vec<_>>())
    );
    assert_eq!(commands("run `cargo flatland scan REC` and\n```sh\ncargo fw   # main\n```\n`x|y`"), ["cargo fw", "cargo flatland scan REC"]);
}
