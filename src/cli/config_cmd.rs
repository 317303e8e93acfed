//! `bench config`: the built-in bench description, and a check of a file.

use super::{bad_input, load_config, status};
use bench::config::BUILTIN_CONFIG_TOML;
use clap::Subcommand;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Subcommand)]
pub(super) enum ConfigCommand {
    /// Print the built-in bench (the Chapter 5 bench of the thesis, the
    /// shipped `bench-config/sr4dof-ch5.toml`) as a commented TOML file to
    /// start from: `bench config default > my.toml`, edit, then
    /// `bench chirp --config my.toml`.
    Default,
    /// Read and validate a bench description as `bench chirp --config FILE`
    /// does (syntax, unknown keys, every range), without running anything.
    Check {
        /// The TOML file.
        #[arg(value_name = "FILE")]
        file: PathBuf,
    },
}

pub(super) fn config_command(cmd: ConfigCommand) -> ExitCode {
    match cmd {
        ConfigCommand::Default => {
            let mut out = std::io::stdout().lock();
            match out
                .write_all(BUILTIN_CONFIG_TOML.as_bytes())
                .and_then(|()| out.flush())
            {
                Ok(()) => ExitCode::SUCCESS,
                // A closed pipe (`| head`) is the reader's choice.
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
                Err(e) => {
                    errln!("error: writing the config to stdout: {e}");
                    ExitCode::from(status::ERROR)
                }
            }
        }
        ConfigCommand::Check { file } => {
            match load_config(Some(&file)).and_then(|(c, p)| c.validate(&p)) {
                Ok(()) => {
                    outln!("{}: a valid bench description", file.display());
                    ExitCode::SUCCESS
                }
                Err(e) => bad_input(e),
            }
        }
    }
}
