//! `bench daemon status|reset|enable|disable|stop|shutdown`: the socket's
//! commands of the same names, from the command line, so that an operator
//! answers a latched fault without writing JSON. Each sends one request
//! through [`bench::daemon::client::request`] and prints the answer as
//! aligned `key  value` lines (`--json`: the daemon's JSON unchanged).

use super::serve::answer_status;
use super::status;
use bench::daemon::client::{request, ClientError};
use clap::{Args, Subcommand};
use serde::Deserialize;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// How long `stop` waits for the job to end, and `shutdown` for the
/// daemon to remove its socket (the daemon gives a stopping job 10 s to
/// answer, then finishes its recording).
const WAIT_LIMIT: Duration = Duration::from_secs(30);

/// How often `stop` and `shutdown` look while they wait.
const WAIT_POLL: Duration = Duration::from_millis(50);

/// The exit statuses of every `bench daemon` command but `status` (their
/// --help); `$refused`: this command's refusals (status 5) and `$other`:
/// its status 1 beyond a broken connection.
macro_rules! exit_status {
    ($refused:literal, $other:literal) => {
        concat!(
            "Exit status: 0 done; 2 --socket is not a socket (a directory, another kind of file, \
             a path too long for a socket address); ",
            $refused,
            "6 no daemon answers at the socket (no socket there, a stale one, or permission \
             denied); 1 ",
            $other,
            "the daemon closed the connection before answering."
        )
    };
}

/// The exit statuses of `bench daemon status` (its --help).
const STATUS_EXIT_STATUS: &str = "Exit status: 0 healthy (disabled, enabled or running); 3 a \
fault is latched (so `bench daemon status || bench daemon reset` answers it); 2 --socket is \
not a socket; 6 no daemon answers at the socket (no socket there, a stale one, or permission \
denied); 1 the daemon closed the connection before answering.";

#[derive(Debug, Args)]
pub(super) struct DaemonArgs {
    /// The daemon's socket [default: $XDG_RUNTIME_DIR/bench.sock when that
    /// is an absolute path, else /run/bench/bench.sock: the rule of
    /// `bench serve` and the `--daemon` clients].
    #[arg(long, value_name = "PATH", global = true)]
    socket: Option<PathBuf>,
    /// Print the daemon's answer (its JSON `result`) unchanged, one line.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: DaemonCommand,
}

/// The commands, named as the socket's: `stop` stops the running job,
/// `shutdown` stops the job and then the daemon.
#[derive(Debug, Clone, Copy, Subcommand)]
enum DaemonCommand {
    /// Show the daemon's state; exit 3 when a fault is latched.
    ///
    /// The supervisor state (disabled: amplifier disabled at 0 A; enabled;
    /// running a job; faulted), the latched fault
    /// with its kind and cause, the running job and its progress, the
    /// backend and loop rate, the last position (µm) and current (A), what
    /// holds the stage between jobs, the jobs run and the last recording.
    #[command(after_help = STATUS_EXIT_STATUS)]
    Status,
    /// Clear a latched fault (back to `disabled`).
    ///
    /// Prints the new state. Refused while a job runs (`stop` it first). A cause still present
    /// (a probe that still reads NaN) latches again at once: check with
    /// `status`.
    #[command(after_help = exit_status!("5 refused: busy (a job is running: `bench daemon stop` it first); ", ""))]
    Reset,
    /// Enable the amplifier between jobs.
    ///
    /// At 0 A, or holding the position with `[daemon] hold_controller`.
    /// Refused while faulted or while a job runs.
    #[command(after_help = exit_status!("5 refused: busy (a job is running), or faulted (`bench daemon reset` first); ", ""))]
    Enable,
    /// Disable the amplifier between jobs (0 A).
    ///
    /// Refused while a job runs.
    #[command(after_help = exit_status!("5 refused: busy (a job is running: `bench daemon stop` it first); ", ""))]
    Disable,
    /// Stop the running job safely; the daemon keeps running.
    ///
    /// 0 A, amplifier disabled, recording finished; waits until the job has
    /// ended. With no job running there is nothing to do (exit 0).
    #[command(after_help = exit_status!("", "the job still runs 30 s after the stop, or "))]
    Stop,
    /// Shut the daemon down (the running job stops safely first).
    ///
    /// The daemon exits and removes its socket; this waits until the
    /// socket is gone, so a new `bench serve` can take the path.
    #[command(after_help = exit_status!("", "the socket is still there 30 s after the shutdown, or "))]
    Shutdown,
}

impl DaemonCommand {
    /// The socket command.
    fn cmd(self) -> &'static str {
        match self {
            Self::Status => "status",
            Self::Reset => "reset",
            Self::Enable => "enable",
            Self::Disable => "disable",
            Self::Stop => "stop",
            Self::Shutdown => "shutdown",
        }
    }
}

/// `status` as the daemon answers it (`bench::daemon`'s `Status`; the
/// fields shown).
#[derive(Debug, Deserialize)]
struct StatusView {
    state: String,
    fault: Option<FaultView>,
    job: Option<JobView>,
    backend: String,
    rate_hz: f64,
    /// `null` before the first reading (JSON has no NaN).
    position_m: Option<f64>,
    command_a: Option<f64>,
    hold: String,
    jobs_run: u64,
    last_recording: Option<String>,
    /// The store of `--upload` (absent or `null` without it).
    #[serde(default)]
    store: Option<StoreView>,
}

#[derive(Debug, Deserialize)]
struct StoreView {
    url: String,
    state: String,
    reason: Option<String>,
}

#[derive(Debug, Deserialize)]
struct FaultView {
    kind: String,
    message: String,
}

#[derive(Debug, Deserialize)]
struct JobView {
    id: u64,
    kind: String,
    ticks: u64,
    total_ticks: u64,
    /// `null` for the jobs that do not drive the bench.
    recording: Option<String>,
    detach: bool,
}

impl StatusView {
    fn faulted(&self) -> bool {
        self.state == "faulted" || self.fault.is_some()
    }

    /// The `key  value` lines.
    fn lines(&self) -> Vec<(&'static str, String)> {
        let number = |v: Option<f64>, scale: f64, unit: &str, digits: usize| match v {
            Some(x) if x.is_finite() => format!("{:.digits$} {unit}", x * scale),
            _ => "no reading yet".to_string(),
        };
        let mut lines = vec![("state", self.state.clone())];
        lines.push((
            "fault",
            self.fault
                .as_ref()
                .map_or("none".into(), |f| format!("{}: {}", f.kind, f.message)),
        ));
        match &self.job {
            None => lines.push(("job", "none".into())),
            Some(j) => {
                lines.push((
                    "job",
                    format!(
                        "{} (job {}{})",
                        j.kind,
                        j.id,
                        if j.detach { ", detached" } else { "" }
                    ),
                ));
                let unit = if j.kind == "campaign" {
                    "cells"
                } else {
                    "ticks"
                };
                if j.total_ticks > 0 {
                    lines.push((
                        "progress",
                        format!(
                            "{:.1} % ({} of {} {unit})",
                            100.0 * j.ticks as f64 / j.total_ticks.max(1) as f64,
                            j.ticks,
                            j.total_ticks
                        ),
                    ));
                }
                lines.push(("recording", j.recording.clone().unwrap_or("none".into())));
            }
        }
        lines.extend([
            ("backend", self.backend.clone()),
            ("loop rate", format!("{} Hz", self.rate_hz)),
            ("position", number(self.position_m, 1e6, "µm", 3)),
            ("command", number(self.command_a, 1.0, "A", 4)),
            ("hold", self.hold.clone()),
            ("jobs run", self.jobs_run.to_string()),
            (
                "last recording",
                self.last_recording.clone().unwrap_or_else(|| "none".into()),
            ),
        ]);
        if let Some(s) = &self.store {
            lines.push((
                "upload store",
                match &s.reason {
                    Some(r) => format!("{} {} ({r})", s.url, s.state),
                    None => format!("{} {}", s.url, s.state),
                },
            ));
        }
        lines
    }
}

/// Prints `lines` as `key  value`, the values aligned.
fn print_lines(lines: &[(&str, String)]) {
    let width = lines
        .iter()
        .map(|(k, _)| k.chars().count())
        .max()
        .unwrap_or(0);
    for (k, v) in lines {
        outln!("{k:<width$}  {v}");
    }
}

pub(super) fn daemon(args: DaemonArgs) -> ExitCode {
    let given = args.socket.is_some();
    let socket = args
        .socket
        .unwrap_or_else(bench::daemon::default_socket_path);
    if socket.as_os_str().is_empty() {
        return super::bad_input("--socket: empty path; give the socket `bench serve` listens on");
    }
    let cmd = args.command;
    let answer = match request(&socket, cmd.cmd(), json!({})) {
        Ok(v) => v,
        Err(e) => return failed(&e, &socket, given),
    };
    match cmd {
        DaemonCommand::Status => show_status(&answer, args.json),
        DaemonCommand::Stop => stop(&socket, given, &answer, args.json),
        DaemonCommand::Shutdown => shutdown(&socket, &answer, args.json),
        DaemonCommand::Reset | DaemonCommand::Enable | DaemonCommand::Disable => {
            if args.json {
                outln!("{answer}");
            } else {
                print_lines(&[("state", answer["state"].as_str().unwrap_or("?").into())]);
            }
            ExitCode::SUCCESS
        }
    }
}

/// Prints why the request failed and returns the exit status: 2 for a
/// path that is not a socket (naming `--socket`, or saying the default
/// was used), 6 when no daemon answers, the answer's status when the
/// daemon refused ([`answer_status`]).
fn failed(e: &ClientError, socket: &Path, given: bool) -> ExitCode {
    match e {
        ClientError::NotASocket { reason, .. } => {
            if given {
                errln!("error: --socket {}: {reason}", socket.display());
            } else {
                errln!(
                    "error: the default socket {}: {reason}; give --socket",
                    socket.display()
                );
            }
            ExitCode::from(status::BAD_INPUT)
        }
        ClientError::Connect { .. } => {
            errln!("error: {e}");
            ExitCode::from(status::NO_DAEMON)
        }
        ClientError::Api { kind, .. } => {
            errln!("error: {e}");
            ExitCode::from(answer_status(*kind))
        }
        ClientError::Io(_) => {
            errln!("error: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}

/// `status`: 0 healthy, 3 when a fault is latched.
fn show_status(answer: &Value, json: bool) -> ExitCode {
    let view: StatusView = match serde_json::from_value(answer.clone()) {
        Ok(v) => v,
        Err(e) => {
            errln!("error: the daemon's status does not parse: {e}: {answer}");
            return ExitCode::from(status::ERROR);
        }
    };
    if json {
        outln!("{answer}");
    } else {
        print_lines(&view.lines());
    }
    if view.faulted() {
        ExitCode::from(status::FAULT)
    } else {
        ExitCode::SUCCESS
    }
}

/// `stop`: waits until the job the daemon is stopping has ended (it is no
/// longer `status`'s job), then prints how it ended.
fn stop(socket: &Path, given: bool, answer: &Value, json: bool) -> ExitCode {
    let Some(id) = answer["stopping"].as_u64() else {
        if json {
            outln!("{answer}");
        } else {
            print_lines(&[("job", "none running; nothing to stop".into())]);
        }
        return ExitCode::SUCCESS;
    };
    let t0 = Instant::now();
    let state = loop {
        let s = match request(socket, "status", json!({})) {
            Ok(s) => s,
            Err(e) => return failed(&e, socket, given),
        };
        if s["job"]["id"].as_u64() != Some(id) {
            break s["state"].as_str().unwrap_or("?").to_string();
        }
        if t0.elapsed() > WAIT_LIMIT {
            errln!(
                "error: job {id} is still running {} s after `stop`",
                WAIT_LIMIT.as_secs()
            );
            return ExitCode::from(status::ERROR);
        }
        std::thread::sleep(WAIT_POLL);
    };
    if json {
        outln!("{answer}");
    } else {
        print_lines(&[("stopped", format!("job {id}")), ("state", state)]);
    }
    ExitCode::SUCCESS
}

/// `shutdown`: waits until the daemon has removed its socket (its last
/// act), so that a new `bench serve` can take the path.
fn shutdown(socket: &Path, answer: &Value, json: bool) -> ExitCode {
    let t0 = Instant::now();
    while std::fs::symlink_metadata(socket).is_ok() {
        if t0.elapsed() > WAIT_LIMIT {
            errln!(
                "error: the daemon accepted `shutdown` but {} is still there after {} s",
                socket.display(),
                WAIT_LIMIT.as_secs()
            );
            return ExitCode::from(status::ERROR);
        }
        std::thread::sleep(WAIT_POLL);
    }
    if json {
        outln!("{answer}");
    } else {
        print_lines(&[("daemon", format!("shut down; {} removed", socket.display()))]);
    }
    ExitCode::SUCCESS
}
