//! `bench completions SHELL` and `bench man`: shell completion scripts and
//! man pages generated from the command's clap definitions
//! (`clap_complete`, `clap_mangen`), so they never drift from the flags.

use super::{bad_input, status, Cli};
use clap::{Args, CommandFactory};
use clap_complete::Shell;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Debug, Args)]
pub(super) struct CompletionsArgs {
    /// The shell: bash, zsh, fish, elvish or powershell.
    #[arg(value_name = "SHELL")]
    shell: Shell,
}

#[derive(Debug, Args)]
pub(super) struct ManArgs {
    /// Print the page of this command only (e.g. `chirp`, `emulate
    /// serial`) [default: the whole of `bench`, each command a section].
    #[arg(value_name = "COMMAND")]
    command: Vec<String>,
    /// Write one page per command into DIR (bench.1, bench-chirp.1, …)
    /// instead of printing.
    #[arg(long, value_name = "DIR", conflicts_with = "command")]
    out: Option<PathBuf>,
}

/// The command tree as the pages and scripts see it (built, so that
/// subcommands carry their full names, `bench chirp`).
fn command() -> clap::Command {
    let mut cmd = Cli::command().disable_help_subcommand(true);
    cmd.build();
    cmd
}

/// Writes `bytes` to stdout; a closed pipe (`| head`) is not an error.
fn print(bytes: &[u8], what: &str) -> ExitCode {
    let mut out = std::io::stdout().lock();
    match out.write_all(bytes).and_then(|()| out.flush()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => {
            errln!("error: writing the {what} to stdout: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}

pub(super) fn completions(args: &CompletionsArgs) -> ExitCode {
    let mut cmd = command();
    let mut script = Vec::new();
    clap_complete::generate(args.shell, &mut cmd, "bench", &mut script);
    print(&script, "completion script")
}

pub(super) fn man(args: &ManArgs) -> ExitCode {
    let root = command();
    if let Some(dir) = &args.out {
        return match write_pages(&root, dir) {
            Ok(n) => {
                errln!("wrote {n} man pages to {}", dir.display());
                ExitCode::SUCCESS
            }
            Err(e) => {
                errln!("error: --out {}: {e}", dir.display());
                ExitCode::from(status::ERROR)
            }
        };
    }
    let mut page = Vec::new();
    let rendered = if args.command.is_empty() {
        render_whole(&root, &mut page)
    } else {
        let mut cmd = &root;
        for name in &args.command {
            match cmd.find_subcommand(name) {
                Some(sub) => cmd = sub,
                None => {
                    let known: Vec<&str> = cmd.get_subcommands().map(|s| s.get_name()).collect();
                    return bad_input(format!(
                        "man {}: no command {name:?} (known: {})",
                        args.command.join(" "),
                        known.join(", ")
                    ));
                }
            }
        }
        page_of(cmd).render(&mut page)
    };
    match rendered {
        Ok(()) => print(&page, "man page"),
        Err(e) => {
            errln!("error: rendering the man page: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}

/// The page of one (built) command, titled by its full name.
fn page_of(cmd: &clap::Command) -> clap_mangen::Man {
    clap_mangen::Man::new(cmd.clone()).manual("bench manual")
}

/// The page of `bench`, then for each command (depth first) a section
/// `BENCH CHIRP` with its synopsis, description and options (their headings
/// as subsections).
fn render_whole(root: &clap::Command, w: &mut Vec<u8>) -> std::io::Result<()> {
    page_of(root).render(w)?;
    fn sections(cmd: &clap::Command, w: &mut Vec<u8>) -> std::io::Result<()> {
        for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
            let name = sub.get_display_name().unwrap_or_else(|| sub.get_name());
            writeln!(w, ".SH \"{}\"", name.replace('-', " ").to_uppercase())?;
            let man = page_of(sub);
            let mut body = Vec::new();
            man.render_synopsis_section(&mut body)?;
            man.render_description_section(&mut body)?;
            if sub.get_arguments().any(|a| !a.is_hide_set()) {
                man.render_options_section(&mut body)?;
            }
            if sub.has_subcommands() {
                man.render_subcommands_section(&mut body)?;
            }
            // Inside this section, each of the page's own sections is a
            // subsection.
            for line in String::from_utf8_lossy(&body).lines() {
                match line.strip_prefix(".SH ") {
                    Some(heading) => writeln!(w, ".SS {heading}")?,
                    None => writeln!(w, "{line}")?,
                }
            }
            sections(sub, w)?;
        }
        Ok(())
    }
    sections(root, w)
}

/// Writes `bench.1` and one page per command (`bench-chirp.1`,
/// `bench-emulate-serial.1`, …) into `dir` (created if missing); returns
/// how many.
fn write_pages(root: &clap::Command, dir: &Path) -> std::io::Result<usize> {
    std::fs::create_dir_all(dir)?;
    fn write(cmd: &clap::Command, dir: &Path, n: &mut usize) -> std::io::Result<()> {
        page_of(cmd).generate_to(dir)?;
        *n += 1;
        for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
            write(sub, dir, n)?;
        }
        Ok(())
    }
    let mut n = 0;
    write(root, dir, &mut n)?;
    Ok(n)
}
