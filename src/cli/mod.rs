//! Command-line definitions and dispatch.

mod bench;
mod body;
mod data;
mod evaluate;
mod garment;
mod learn;
mod pose_spec;
mod quickstart;
mod reproduce;
mod simulate;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

/// drape: cloth physics to training data to fast draping networks.
#[derive(Debug, Parser)]
#[command(name = "drape", version, about, long_about = None)]
pub struct Cli {
    /// Folder of the shipped assets (default: the `assets/` folder of this source tree).
    #[arg(long, global = true, value_name = "DIR")]
    pub assets: Option<PathBuf>,
    /// Pose library TOML to use instead of the built-in configs/poses/library.toml.
    #[arg(long, global = true, value_name = "FILE.toml")]
    pub pose_library: Option<PathBuf>,
    #[command(subcommand)]
    pub command: Command,
}

/// The jobs.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// The quick start: drape the T-shirt on one body with the simulator and with the
    /// committed GarNet-Local weights; print both times, the speed-up, Edist and Enorm;
    /// write OBJs and a side-by-side render.
    Quickstart(quickstart::QuickstartArgs),
    /// Build a shaped, posed MakeHuman body: OBJ and PNG; import the body asset; check the
    /// pose prior.
    Body(body::BodyArgs),
    /// Drape a garment on a shaped, posed body with the cloth simulator: OBJ, PNG and a
    /// quality report.
    Sim(Box<simulate::SimArgs>),
    /// Garment templates: build the built-in ones, import your own, list them, render them
    /// on sampled bodies and check their drapes against the quality bars.
    Garment(garment::GarmentArgs),
    /// Warp a garment template to a shaped, posed body with dual quaternion skinning (the
    /// network's input and the DQS baseline): OBJ and PNG.
    Warp(Box<garment::WarpArgs>),
    /// Scene benchmarks that print timings and quality figures.
    Bench(bench::BenchArgs),
    /// Generate a drape dataset (shards of bodies, DQS warps and simulated drapes) from a
    /// config, in parallel and resumably; `--shard I/N` makes one part of a cluster job.
    Gen(data::GenArgs),
    /// Inspect, verify, show and merge datasets made by `drape gen`; measure the
    /// simulator's scatter (sensitivity) and what more data would buy (curve).
    Data(data::DataArgs),
    /// Train a GarNet network (Naive, Global, Local, Global-Params) on a dataset; resumes;
    /// `--init` fine-tunes from another run.
    Train(learn::TrainArgs),
    /// Drape a garment with a trained network: the DQS warp onto a shaped, posed body, then
    /// the network (the run folder knows its garment).
    Predict(Box<learn::PredictArgs>),
    /// Evaluate a trained network and the DQS, mean-residual, nearest-neighbour, linear and
    /// kernel baselines on a dataset split: Edist, Enorm, curvature, physics, curves and renders
    /// in a report folder.
    Eval(evaluate::EvalArgs),
    /// Compare two evaluations of the same drapes sample by sample (two networks, or a
    /// network and a baseline): per figure the mean difference, its standard error, and
    /// on how many drapes each is lower.
    Compare(evaluate::CompareArgs),
    /// How much a trained network relies on each body input (permutation importance): the
    /// test drapes once as they are and once per input with that input taken from another
    /// drape of the batch; Edist and Enorm, and their paired rise.
    Importance(evaluate::ImportanceArgs),
    /// Reproduce the paper's tables on our data: generate the plan's datasets, train its
    /// networks and fine-tunes, evaluate them, time the speed-up, write
    /// docs/reproduction.md and .json. Resumable.
    Reproduce(reproduce::ReproduceArgs),
}

/// Options every command shares.
#[derive(Debug)]
pub struct Context {
    /// The assets folder.
    pub assets: PathBuf,
    /// A pose library replacing the built-in one.
    pub pose_library: Option<PathBuf>,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let ctx = Context {
        assets: cli
            .assets
            .unwrap_or_else(sim::body::asset::default_assets_dir),
        pose_library: cli.pose_library,
    };
    match cli.command {
        Command::Body(args) => body::run(args, &ctx),
        Command::Sim(args) => simulate::run(*args, &ctx),
        Command::Garment(args) => garment::run(args, &ctx),
        Command::Warp(args) => garment::warp(*args, &ctx),
        Command::Bench(args) => bench::run(args, &ctx),
        Command::Gen(args) => data::gen_run(args, &ctx),
        Command::Data(args) => data::data_run(args, &ctx),
        Command::Train(args) => learn::run(args),
        Command::Predict(args) => learn::predict(*args, &ctx),
        Command::Eval(args) => evaluate::run(args),
        Command::Compare(args) => evaluate::compare(args),
        Command::Importance(args) => evaluate::importance(args),
        Command::Quickstart(args) => quickstart::run(args, &ctx),
        Command::Reproduce(args) => reproduce::run(args, &ctx),
    }
}

/// Checks, before any work, that each given output file can be written: its folder exists
/// and takes a new file. A long command with a mistyped output path then stops at once
/// instead of after its work.
pub(crate) fn check_outputs(paths: &[Option<&std::path::Path>]) -> anyhow::Result<()> {
    for path in paths.iter().flatten() {
        if path.is_dir() {
            anyhow::bail!("cannot write {}: it is a folder", path.display());
        }
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => std::path::Path::new("."),
        };
        if !dir.is_dir() {
            anyhow::bail!(
                "cannot write {}: no folder {}",
                path.display(),
                dir.display()
            );
        }
        let probe = dir.join(format!(".drape-write-check-{}", std::process::id()));
        std::fs::File::create(&probe)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        let _ = std::fs::remove_file(&probe);
    }
    Ok(())
}

/// A count given on the command line that must be at least 1 (`--samples`, `--batch`...).
pub(crate) fn at_least_one<T>(s: &str) -> Result<T, String>
where
    T: std::str::FromStr + PartialOrd + From<u8>,
{
    match s.parse::<T>() {
        Ok(n) if n >= T::from(1) => Ok(n),
        Ok(_) => Err("must be at least 1".to_string()),
        Err(_) => Err(format!("{s:?} is not a whole number")),
    }
}

#[cfg(test)]
mod doc_commands {
    //! Every `drape` command written out in the docs (README.md, ARCHITECTURE.md, docs/**/*.md
    //! in fenced shell blocks, docs/**/*.txt and scripts/*.sh line by line) parses with
    //! today's command line, and every usage synopsis and every command in running prose
    //! (inline code, often partial: `drape sim --strain-png`) names subcommands that exist
    //! and only options they take, so a renamed option or subcommand, or (in full commands)
    //! a new required argument, cannot leave a documented command broken.

    use super::Cli;
    use clap::Parser;
    use std::path::{Path, PathBuf};

    /// Splits a shell line into words, each with whether any of it was quoted: single and
    /// double quotes group, a backslash escapes the next character outside single quotes.
    fn tokens(line: &str) -> Vec<(String, bool)> {
        let mut out = Vec::new();
        let mut cur = String::new();
        let mut started = false;
        let mut quoted = false;
        let mut quote: Option<char> = None;
        let mut chars = line.chars();
        while let Some(c) = chars.next() {
            match (quote, c) {
                (Some(q), c) if c == q => quote = None,
                (Some('\''), c) => cur.push(c),
                (_, '\\') => {
                    if let Some(n) = chars.next() {
                        cur.push(n);
                        started = true;
                        quoted = true;
                    }
                }
                (None, '\'' | '"') => {
                    quote = Some(c);
                    started = true;
                    quoted = true;
                }
                (None, c) if c.is_whitespace() => {
                    if started {
                        out.push((std::mem::take(&mut cur), quoted));
                        started = false;
                        quoted = false;
                    }
                }
                (_, c) => {
                    cur.push(c);
                    started = true;
                }
            }
        }
        if started {
            out.push((cur, quoted));
        }
        out
    }

    fn words(line: &str) -> Vec<String> {
        tokens(line).into_iter().map(|(w, _)| w).collect()
    }

    /// The program's arguments for each command of `line` that runs drape (`drape`,
    /// `target/release/drape`, a copy named `drape-*`, `$drape`, `cargo run --release --`),
    /// after any `VAR=value` prefixes and wrappers (`nice`, `time`, `nohup`, `env`), without
    /// redirections and comments. Commands joined by `&&`, `||`, `;`, `|` or `&` are taken
    /// one by one; usage synopses (`[--opt N]`, `...`, `<DIR>`) are left out.
    fn drape_commands(line: &str) -> Vec<Vec<String>> {
        let mut segments = vec![Vec::new()];
        let mut skip_next = false;
        for (w, quoted) in tokens(line) {
            if skip_next {
                skip_next = false;
                continue;
            }
            if !quoted {
                if w.starts_with('#') {
                    break;
                }
                if matches!(w.as_str(), "&&" | "||" | ";" | "|" | "&") {
                    segments.push(Vec::new());
                    continue;
                }
                if matches!(w.as_str(), ">" | ">>" | "2>" | "2>>" | "&>" | "<") {
                    skip_next = true;
                    continue;
                }
                if w.starts_with('>') || w.starts_with("2>") || w.starts_with("&>") {
                    continue;
                }
                if let Some(head) = w.strip_suffix(';') {
                    let last = segments.last_mut().expect("one segment at least");
                    last.push((head.to_string(), quoted));
                    segments.push(Vec::new());
                    continue;
                }
            }
            segments
                .last_mut()
                .expect("one segment at least")
                .push((w, quoted));
        }
        segments.into_iter().filter_map(drape_args).collect()
    }

    /// Whether the unquoted words read as a usage synopsis (`[--opt N]`, `DIR...`, `<DIR>`).
    fn is_synopsis(words: &[(String, bool)]) -> bool {
        words
            .iter()
            .any(|(w, q)| !q && (w.contains('[') || w.contains("...") || w.starts_with('<')))
    }

    fn drape_args(segment: Vec<(String, bool)>) -> Option<Vec<String>> {
        if is_synopsis(&segment) {
            return None;
        }
        program_args(segment)
    }

    /// The program's arguments of a usage synopsis line (`drape gen CONFIG -o DIR [--shard
    /// I/N]`), up to a comment; `None` for other lines.
    fn synopsis(line: &str) -> Option<Vec<String>> {
        let words: Vec<(String, bool)> = tokens(line)
            .into_iter()
            .take_while(|(w, q)| *q || !w.starts_with('#'))
            .collect();
        if !is_synopsis(&words) {
            return None;
        }
        program_args(words)
    }

    /// The subcommand a synopsis names and the options it writes (`--seed`, `-o`, each side
    /// of `--a|--b`), each checked against the command line: a command group must be
    /// followed by one of its subcommands, and every option must be one the subcommand
    /// named (or the program globally) takes. Errors name what is unknown.
    fn check_synopsis(args: &[String]) -> Result<(), String> {
        use clap::CommandFactory;
        let root = Cli::command();
        let mut cmd = &root;
        let mut path = vec!["drape".to_string()];
        let mut rest = args;
        while let Some((first, tail)) = rest.split_first() {
            match cmd.find_subcommand(first) {
                Some(sub) => {
                    cmd = sub;
                    path.push(first.clone());
                    rest = tail;
                }
                None => break,
            }
        }
        // A command that takes only subcommands (`drape`, `drape garment`) must be followed
        // by one of them, by nothing, or by `...` (any).
        if let Some(next) = rest.first()
            && cmd.is_subcommand_required_set()
            && next != "..."
        {
            return Err(format!("`{}` has no subcommand {next}", path.join(" ")));
        }
        let known = |c: &clap::Command, opt: &str| {
            c.get_arguments().any(|a| match opt.strip_prefix("--") {
                Some(long) => a.get_long() == Some(long),
                None => opt.chars().nth(1).is_some_and(|s| a.get_short() == Some(s)),
            })
        };
        for word in rest {
            for piece in word.split('|') {
                let piece = piece.trim_start_matches(['[', '(']);
                let piece = piece.trim_end_matches([']', ')', ',']);
                let piece = piece.split('=').next().unwrap_or(piece);
                let is_option = piece.starts_with("--") && piece.len() > 2
                    || piece.len() == 2
                        && piece.starts_with('-')
                        && piece[1..].chars().all(|c| c.is_ascii_alphabetic());
                if !is_option || matches!(piece, "--help" | "-h" | "--version" | "-V") {
                    continue;
                }
                if !known(cmd, piece) && !known(&root, piece) {
                    return Err(format!("`{}` has no option {piece}", path.join(" ")));
                }
            }
        }
        Ok(())
    }

    fn program_args(segment: Vec<(String, bool)>) -> Option<Vec<String>> {
        // A word that is only a shell variable stands for a value the docs cannot know.
        let w: Vec<String> = segment
            .into_iter()
            .map(|(w, _)| match w.as_str() {
                "$drape" | "${drape}" => "drape".to_string(), // scripts/render-docs.sh
                _ if is_variable(&w) => "1".to_string(),
                _ => w,
            })
            .collect();
        let mut i = 0;
        loop {
            while i < w.len() && is_assignment(&w[i]) {
                i += 1;
            }
            match w.get(i).map(String::as_str) {
                Some("time" | "nohup" | "env") => i += 1,
                Some("nice") => {
                    i += 1;
                    if w.get(i).is_some_and(|s| s == "-n") {
                        i += 2;
                    }
                }
                _ => break,
            }
        }
        let first = w.get(i)?;
        let name = first.rsplit('/').next().unwrap_or(first);
        if name == "drape" || name.starts_with("drape-") {
            return Some(w[i + 1..].to_vec());
        }
        let cargo: Vec<&str> = w[i..].iter().map(String::as_str).collect();
        if let Some(k) = cargo.iter().position(|s| *s == "--")
            && cargo.first() == Some(&"cargo")
            && cargo.get(1) == Some(&"run")
            && !cargo[..k]
                .iter()
                .any(|s| matches!(*s, "-p" | "--package" | "--example"))
            && cargo[..k]
                .iter()
                .position(|s| *s == "--bin")
                .is_none_or(|b| cargo.get(b + 1) == Some(&"drape"))
        {
            return Some(w[i + k + 1..].to_vec());
        }
        None
    }

    fn is_name(k: &str) -> bool {
        k.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    }

    fn is_assignment(w: &str) -> bool {
        w.split_once('=').is_some_and(|(k, _)| is_name(k))
    }

    /// `$X` or `${X}`.
    fn is_variable(w: &str) -> bool {
        w.strip_prefix('$').is_some_and(|v| {
            is_name(
                v.strip_prefix('{')
                    .and_then(|v| v.strip_suffix('}'))
                    .unwrap_or(v),
            )
        })
    }

    /// Lines of `text` that are commands: joined across trailing backslashes, and an
    /// indented line of options (`[--a N]`, `-o FILE`) joined to the synopsis line above it;
    /// in Markdown
    /// only those inside fenced shell blocks (```sh, bash, shell, console).
    fn command_lines(text: &str, markdown: bool) -> Vec<(usize, String)> {
        let mut out: Vec<(usize, String)> = Vec::new();
        let mut fenced = false;
        let mut shell = false;
        let mut pending: Option<(usize, String)> = None;
        // The raw line the last command ended on.
        let mut last_end = usize::MAX;
        for (n, raw) in text.lines().enumerate() {
            let t = raw.trim();
            if pending.is_none()
                && raw.starts_with([' ', '\t'])
                && t.starts_with(['[', '-'])
                && last_end.checked_add(1) == Some(n)
                && let Some((_, prev)) = out.last_mut()
                && synopsis(prev).is_some()
            {
                // Options after a comment would not be read: the test cannot check them.
                assert!(
                    !prev.contains(" #"),
                    "a synopsis continued after a comment: {prev}"
                );
                prev.push(' ');
                prev.push_str(t);
                last_end = n;
                continue;
            }
            if markdown && let Some(tag) = t.strip_prefix("```") {
                fenced = !fenced;
                shell = fenced && matches!(tag.trim(), "sh" | "bash" | "shell" | "console");
                pending = None;
                continue;
            }
            if markdown && !shell {
                continue;
            }
            let (start, mut joined) = pending.take().unwrap_or((n + 1, String::new()));
            if let Some(head) = t.strip_suffix('\\') {
                joined.push_str(head.trim_end());
                joined.push(' ');
                pending = Some((start, joined));
                continue;
            }
            joined.push_str(t);
            out.push((start, joined));
            last_end = n;
        }
        out
    }

    /// Inline code spans of Markdown prose (outside fenced blocks) that start with `drape `,
    /// with the line their paragraph starts on; a span may run over a line break.
    fn inline_commands(text: &str) -> Vec<(usize, String)> {
        let mut out = Vec::new();
        let mut fenced = false;
        let mut paragraph: Option<(usize, String)> = None;
        let flush = |p: Option<(usize, String)>, out: &mut Vec<(usize, String)>| {
            if let Some((n, text)) = p {
                for (k, span) in text.split('`').enumerate() {
                    if k % 2 == 1 && span.trim_start().starts_with("drape ") {
                        out.push((n, span.trim().to_string()));
                    }
                }
            }
        };
        for (n, raw) in text.lines().enumerate() {
            let t = raw.trim();
            if t.starts_with("```") {
                fenced = !fenced;
                flush(paragraph.take(), &mut out);
                continue;
            }
            if fenced {
                continue;
            }
            if t.is_empty() {
                flush(paragraph.take(), &mut out);
                continue;
            }
            let p = paragraph.get_or_insert_with(|| (n + 1, String::new()));
            p.1.push(' ');
            p.1.push_str(t);
        }
        flush(paragraph.take(), &mut out);
        out
    }

    fn files(root: &Path) -> Vec<PathBuf> {
        fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
            let Ok(entries) = std::fs::read_dir(dir) else {
                return;
            };
            for e in entries.flatten() {
                let p = e.path();
                if p.is_dir() {
                    walk(&p, out);
                } else if matches!(
                    p.extension().and_then(|e| e.to_str()),
                    Some("md" | "txt" | "sh")
                ) {
                    out.push(p);
                }
            }
        }
        let mut out = vec![root.join("README.md"), root.join("ARCHITECTURE.md")];
        walk(&root.join("docs"), &mut out);
        walk(&root.join("scripts"), &mut out);
        out.sort();
        out
    }

    #[test]
    fn the_shell_words_and_the_command_are_found() {
        assert_eq!(
            words(r#"a 'b c' "d e" f\ g"#),
            ["a", "b c", "d e", "f g"].map(String::from)
        );
        let args = |l: &str| {
            let c = drape_commands(l);
            assert!(c.len() <= 1, "{l}: {c:?}");
            c.first().map(|v| v.join(" "))
        };
        let cases = [
            (
                "RAYON_NUM_THREADS=1 drape train c.toml -o r  # note",
                Some("train c.toml -o r"),
            ),
            (
                "cargo run --release -- quickstart --seed 3 > log 2>&1",
                Some("quickstart --seed 3"),
            ),
            (
                "nice -n 19 runs/bin/drape-x gen small -o d",
                Some("gen small -o d"),
            ),
            ("drape garment check NAME [--samples 50]", None),
            ("cargo test --release", None),
            ("cargo run --release -p learn --example stages -- DIR", None),
            ("drape=target/release/drape", None),
            ("  $drape body -o b.obj", Some("body -o b.obj")),
            (
                r#"drape gen c.toml -o "$D/x" --threads "$N""#,
                Some("gen c.toml -o $D/x --threads 1"),
            ),
            (
                r#"drape sim -o "a | b.obj" --png '#1.png'"#,
                Some("sim -o a | b.obj --png #1.png"),
            ),
            (
                "cargo run --release --bin drape -- body -o b.obj",
                Some("body -o b.obj"),
            ),
            (
                "nohup env X=1 nice -n 19 drape gen c -o d",
                Some("gen c -o d"),
            ),
        ];
        for (line, want) in cases {
            assert_eq!(args(line).as_deref(), want, "{line}");
        }
        assert_eq!(synopsis("drape warp --garment jeans -o w.obj"), None);
        let no = |what: &str| Err(what.to_string());
        let synopses = [
            (
                "drape garment check NAME [--samples 50 [--seed 0] | --corners] # note",
                Ok(()),
            ),
            ("drape data merge DIR... -o OUT [--assets A]", Ok(())),
            ("drape ... [--assets DIR]", Ok(())),
            (
                "drape garment check NAME [--sample 50]",
                no("`drape garment check` has no option --sample"),
            ),
            (
                "drape warp [--pose SPEC|-q]",
                no("`drape warp` has no option -q"),
            ),
            (
                "drape garment chek NAME [--samples 50]",
                no("`drape garment` has no subcommand chek"),
            ),
            (
                "drape simulate [--pose P]",
                no("`drape` has no subcommand simulate"),
            ),
        ];
        for (line, want) in synopses {
            let args = synopsis(line).expect("a synopsis");
            assert_eq!(check_synopsis(&args), want, "{line}");
        }
        let prose = "See `drape sim\n--png p.png` and `cargo run`.\n\n```sh\n`drape x`\n```\nthen `drape warp`";
        assert_eq!(
            inline_commands(prose),
            [
                (1, "drape sim --png p.png".to_string()),
                (7, "drape warp".to_string())
            ]
        );
        assert_eq!(
            drape_commands("drape a -o x && RAYON_NUM_THREADS=1 drape b 2>&1 | tee log; drape c"),
            [vec!["a", "-o", "x"], vec!["b"], vec!["c"]]
        );
        let lines = command_lines(
            "text drape x\n```sh\ndrape a \\\n  --b 1\n```\n```\ndrape out\n```\n",
            true,
        );
        assert_eq!(lines, vec![(3, "drape a --b 1".to_string())]);
        // A synopsis's indented lines of options are part of it; an indented line
        // after a command that is not a synopsis, or after a blank line, is not.
        let lines = command_lines(
            "```sh\ndrape a X [--b N]\n        [--c M]\n\t-o F\n\n   [--d]\ndrape e\n   [--f]\n```\n",
            true,
        );
        assert_eq!(
            lines,
            vec![
                (2, "drape a X [--b N] [--c M] -o F".to_string()),
                (5, String::new()),
                (6, "[--d]".to_string()),
                (7, "drape e".to_string()),
                (8, "[--f]".to_string()),
            ]
        );
    }

    #[test]
    fn every_documented_command_parses() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut checked = 0;
        let mut synopses = 0;
        let mut inline = 0;
        let mut broken = Vec::new();
        for path in files(root) {
            let text = std::fs::read_to_string(&path).unwrap();
            let markdown = path.extension().is_some_and(|e| e == "md");
            // Commands in prose are often partial (`drape sim --strain-png`): their
            // subcommand and option names are checked, as a synopsis's.
            let prose = if markdown {
                inline_commands(&text)
            } else {
                Vec::new()
            };
            for (n, span) in prose {
                inline += 1;
                let args: Vec<String> = words(&span).into_iter().skip(1).collect();
                if let Err(e) = check_synopsis(&args) {
                    let rel = path.strip_prefix(root).unwrap_or(&path);
                    broken.push(format!("{}:{n}: `{span}`\n    {e}", rel.display()));
                }
            }
            for (n, line) in command_lines(&text, markdown) {
                if let Some(args) = synopsis(&line) {
                    synopses += 1;
                    if let Err(e) = check_synopsis(&args) {
                        let rel = path.strip_prefix(root).unwrap_or(&path);
                        broken.push(format!("{}:{n}: {line}\n    {e}", rel.display()));
                    }
                }
                for args in drape_commands(&line) {
                    checked += 1;
                    let argv = std::iter::once("drape".to_string()).chain(args);
                    if let Err(e) = Cli::try_parse_from(argv) {
                        use clap::error::ErrorKind::*;
                        if !matches!(e.kind(), DisplayHelp | DisplayVersion) {
                            let first = e.to_string().lines().next().unwrap_or("").to_string();
                            let rel = path.strip_prefix(root).unwrap_or(&path);
                            broken.push(format!("{}:{n}: {line}\n    {first}", rel.display()));
                        }
                    }
                }
            }
        }
        println!(
            "{checked} documented commands parsed; {synopses} usage synopses and {inline} \
             commands in prose checked for their subcommand and options"
        );
        assert!(checked > 100, "only {checked} documented commands found");
        assert!(synopses > 20, "only {synopses} usage synopses found");
        assert!(inline > 100, "only {inline} commands in prose found");
        assert!(
            broken.is_empty(),
            "{} of the documented commands, synopses and commands in prose do not parse:\n{}",
            broken.len(),
            broken.join("\n")
        );
    }
}
