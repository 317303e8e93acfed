//! `bench serve`, and `--daemon` (a job submitted to a running daemon).

use super::{bad_input, default_recordings, emit, load_config, run_failed, status};
use bench::daemon::client::ClientError;
use bench::daemon::ApiErrorKind;
use bench::jobs::request::{parse_fault, JobRequest};
use bench::rt::backend::BackendSpec;
use clap::Args;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Args)]
pub(super) struct ServeArgs {
    #[command(flatten)]
    config: super::ConfigFlag,
    /// Socket path [default: $XDG_RUNTIME_DIR/bench.sock when that is an
    /// absolute path, else /run/bench/bench.sock, /run/bench created if
    /// missing; the `--daemon` clients use the same rule]. Its directory
    /// must not be world-writable.
    #[arg(long, value_name = "PATH")]
    socket: Option<PathBuf>,
    /// Let this group use the socket (mode 0660; default owner-only 0600).
    #[arg(long, value_name = "GROUP")]
    socket_group: Option<String>,
    /// Directory for the job recordings and the rolling event log
    /// [default: ./recordings if it exists, else
    /// $XDG_DATA_HOME/bench/recordings, XDG_DATA_HOME defaulting to
    /// ~/.local/share].
    #[arg(long, value_name = "DIR")]
    recordings: Option<PathBuf>,
    /// Backend [default: [backend] of the config].
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    /// Simulator seed [default: sim.seed].
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Inject a simulator fault T_S seconds after start, between jobs (for
    /// testing supervision): KIND@T_S with KIND one of nan, frozen, drop,
    /// jump, out_of_range.
    #[arg(long, value_name = "KIND@T_S")]
    inject_fault: Option<String>,
    /// Serve Prometheus metrics at http://ADDR/metrics while the daemon
    /// runs (loop timing histograms, overruns, faults, supervisor state,
    /// jobs, recorder, link; off the loop's thread). ADDR: PORT or
    /// localhost:PORT (loopback), or IP:PORT to listen on another
    /// interface, which must be written out (0.0.0.0:9464: every
    /// interface); host names are refused. Without a value
    /// 127.0.0.1:9464. Port 0: the OS picks one (printed). An address in
    /// use stops the daemon before it opens the bench (exit 2).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = bench::daemon::metrics::DEFAULT_ADDR)]
    metrics: Option<String>,
    /// Copy each finished job's recording, with its FRF CSV, plots,
    /// summary (<stem>.summary.json) and catalogue row, to a store:
    /// s3://BUCKET[/PREFIX] (an S3-compatible store; endpoint, region and
    /// credentials from AWS_ENDPOINT, AWS_REGION, AWS_ACCESS_KEY_ID,
    /// AWS_SECRET_ACCESS_KEY, AWS_ALLOW_HTTP) or file:///DIRECTORY. Off
    /// the loop's thread; journalled in <recordings>/upload-journal.jsonl
    /// and retried with a backoff (1 s doubling to 60 s) across restarts
    /// until the store confirms each file by its SHA-256 read back; local
    /// copies are kept. A store that refuses (no such bucket, credentials
    /// refused) within 1 s of the start stops the daemon before it opens
    /// the bench (exit 2); one that does not answer only delays the
    /// uploads: the daemon opens its socket after at most 1 s, the store's
    /// probe goes on in the background, and `status` shows the store.
    #[arg(long, value_name = "URL")]
    upload: Option<String>,
    /// With --upload: how long the store has to take a connection, and to
    /// answer each request (from sending it to the answer's first byte,
    /// then between two reads), seconds (0.5 to 300).
    #[arg(
        long,
        value_name = "SECONDS",
        requires = "upload",
        default_value_t = bench::upload::store::DEFAULT_TIMEOUT_S,
        allow_negative_numbers = true
    )]
    store_timeout: f64,
    /// The pace of the daemon's jobs on the simulator when a request gives
    /// none: a factor of real time from 0.01 to 100 (1: real time, 10:
    /// ten times faster), or off (virtual time as fast as it goes)
    /// [default: real time, on the loop's deadlines]. A request's `pace`
    /// overrides it; between jobs the loop keeps real time. The simulator
    /// only (hardware always runs in real time): exit 2 otherwise.
    #[arg(long, value_name = "FACTOR|off", allow_hyphen_values = true, value_parser = bench::jobs::request::parse_pace)]
    pace: Option<bench::jobs::request::Pace>,
    #[command(flatten)]
    live: super::LiveArgs,
}

/// Submits a job to the daemon, shows its progress on stderr and prints the
/// summary as the local run does.
pub(super) fn via_daemon<
    T: serde::de::DeserializeOwned + serde::Serialize + schemars::JsonSchema,
>(
    socket: &str,
    job: &JobRequest,
    json: bool,
    human: fn(&T),
) -> ExitCode {
    via_daemon_then(socket, job, json, human, |_| None)
}

/// [`via_daemon`], the exit status of a summary that printed decided by
/// `status_of` (`None`: success), as the local run decides it (`bench
/// control --verify`'s disagreement).
pub(super) fn via_daemon_then<
    T: serde::de::DeserializeOwned + serde::Serialize + schemars::JsonSchema,
>(
    socket: &str,
    job: &JobRequest,
    json: bool,
    human: fn(&T),
    status_of: fn(&T) -> Option<ExitCode>,
) -> ExitCode {
    let cmd = job.kind();
    let socket = if socket.is_empty() {
        bench::daemon::default_socket_path()
    } else {
        PathBuf::from(socket)
    };
    let show = std::io::stderr().is_terminal();
    let mut progressed = false;
    let result = bench::daemon::client::submit(&socket, job, |ev| {
        if !show {
            return;
        }
        match ev["event"].as_str() {
            // A job without progress (fit, analyze, map) has no total.
            Some("progress") if ev["total_ticks"].as_f64().unwrap_or(0.0) > 0.0 => {
                let (t, n) = (
                    ev["ticks"].as_f64().unwrap_or(0.0),
                    ev["total_ticks"].as_f64().unwrap_or(1.0),
                );
                progressed = true;
                {
                    use std::io::Write as _;
                    let _ = write!(
                        std::io::stderr(),
                        "\r{cmd} on the daemon: {:5.1} %",
                        100.0 * t / n.max(1.0)
                    );
                }
            }
            Some("job_started") => match ev["recording"].as_str() {
                Some(r) => errln!("{cmd} job {} started: {r}", ev["job"]),
                None => errln!("{cmd} job {} started", ev["job"]),
            },
            // Ends the progress line, if there was one.
            Some("job_finished") if progressed => errln!(),
            _ => {}
        }
    });
    match result {
        Ok(v) => match serde_json::from_value::<T>(v.clone()) {
            Ok(summary) => {
                if let Some(r) = v.get("recording").and_then(|r| r.as_str()) {
                    if !json {
                        outln!("recording (daemon) {r}");
                    }
                }
                match emit(&summary, json, human) {
                    Ok(()) => status_of(&summary).unwrap_or(ExitCode::SUCCESS),
                    Err(code) => code,
                }
            }
            Err(e) => {
                errln!("error: the daemon's summary does not parse: {e}");
                ExitCode::from(status::ERROR)
            }
        },
        Err(e) => {
            if let (
                true,
                ClientError::Api {
                    kind,
                    message,
                    summary,
                },
            ) = (json, &e)
            {
                // A job that ended without its summary (fault, HAL error,
                // interrupted): its outcome on stdout, as a local run's
                // (the daemon's `error.summary`: recording and catalogue
                // row included).
                if matches!(
                    kind,
                    ApiErrorKind::Fault | ApiErrorKind::Hal | ApiErrorKind::Interrupted
                ) {
                    let v = summary.clone().unwrap_or_else(|| {
                        serde_json::json!({
                            "outcome": kind,
                            "error": message,
                        })
                    });
                    outln!("{v}");
                }
            }
            errln!("error: {}", bench::error::error_chain(&e));
            ExitCode::from(match &e {
                ClientError::Connect { .. } | ClientError::NotASocket { .. } => status::BAD_INPUT,
                ClientError::Io(_) => status::ERROR,
                ClientError::Api { kind, .. } => answer_status(*kind),
            })
        }
    }
}

/// The exit status of the daemon's error answer `kind`, for every client
/// (`--daemon`, `bench daemon`): 5 for a refusal (`busy`, `faulted`), the
/// status of the local run's outcome for a job's end (fault 3, HAL 4,
/// interrupted 130), 2 for what the client sent, 1 for anything else.
pub(super) fn answer_status(kind: ApiErrorKind) -> u8 {
    use ApiErrorKind as K;
    match kind {
        K::BadParams | K::BadRequest | K::UnknownCommand | K::Refused => status::BAD_INPUT,
        K::Busy | K::Faulted => status::DAEMON_REFUSED,
        K::Fault => status::FAULT,
        K::Hal => status::HAL,
        K::Interrupted => status::INTERRUPTED,
        K::Error => status::ERROR,
    }
}

pub(super) fn serve(args: ServeArgs) -> ExitCode {
    let (cfg, config_path) = match load_config(args.config.config.as_deref())
        .and_then(|(c, p)| c.validate(&p).map(|_| (c, p)))
    {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let recordings = match args.recordings {
        Some(dir) => dir,
        None => match default_recordings(true, "--recordings DIR") {
            Ok(dir) => dir,
            Err(e) => return bad_input(format!("--recordings: {e}")),
        },
    };
    let inject = match args.inject_fault.as_deref().map(parse_fault).transpose() {
        Ok(f) => f,
        Err(e) => return bad_input(format!("--inject-fault: {e}")),
    };
    let metrics = match args
        .metrics
        .as_deref()
        .map(|a| bench::daemon::metrics::parse_addr(a).map_err(|e| format!("--metrics {a:?}: {e}")))
        .transpose()
    {
        Ok(m) => m,
        Err(e) => return bad_input(e),
    };
    let upload = match args
        .upload
        .as_deref()
        .map(|u| bench::upload::StoreUrl::parse(u).map_err(|e| format!("--upload {u:?}: {e}")))
        .transpose()
    {
        Ok(u) => u,
        Err(e) => return bad_input(e),
    };
    if let Err(reason) = bench::upload::store::check_timeout_s(args.store_timeout) {
        return bad_input(format!("--store-timeout: {reason}"));
    }
    // On while the daemon runs: every job's channels, as they are written.
    let _live = match args.live.start(cfg.loop_.cpu) {
        Ok(l) => l,
        Err(code) => return code,
    };
    let opts = bench::daemon::ServeOptions {
        inject,
        seed: args.seed.unwrap_or(cfg.sim.seed),
        config: cfg,
        config_path,
        socket: args
            .socket
            .unwrap_or_else(bench::daemon::default_socket_path),
        socket_group: args.socket_group,
        recordings,
        backend: args.backend,
        metrics,
        upload,
        store_timeout_s: args.store_timeout,
        default_pace: args.pace,
    };
    match bench::daemon::serve(opts) {
        Ok(()) => ExitCode::SUCCESS,
        Err(bench::daemon::ServeError::Input(e)) => run_failed(&e),
        Err(e) => {
            errln!("error: {}", bench::error::error_chain(&e));
            ExitCode::from(status::ERROR)
        }
    }
}
