//! `bench serve --metrics [ADDR]`: the daemon's Prometheus metrics (README,
//! *Metrics: `--metrics`*), in the text formats of the official Rust
//! client (`prometheus-client`): OpenMetrics for a scraper that asks for it
//! (Prometheus does), else the Prometheus text format 0.0.4.
//!
//! Nothing here runs on the loop's thread. The loop counts its real-time
//! ticks into fixed buckets and hands them off wait-free
//! ([`crate::rt::tap`]); this module adds them up on the metrics thread
//! (every 0.1 s, and at each scrape). The owner thread reports jobs and
//! faults as they end or latch ([`Metrics::job_finished`],
//! [`Metrics::fault`]); the writer thread of a job leaves its queue fill and
//! file size in the job's [`QueueRoom`]. A scrape takes short locks that
//! only these non-real-time threads share, encodes into a string, then
//! writes it: a slow scraper waits on its own socket, never on a lock.
//!
//! The HTTP side ([`MetricsServer`]) is `hyper` on a single-threaded tokio
//! runtime of its own (`bench-metrics`, nice 10, off the loop's CPU), apart
//! from the socket side's: `/metrics` only (GET, HEAD), at most
//! [`MAX_SCRAPERS`] connections, each for at most [`CONNECTION_LIMIT_S`].

use super::lock;
use super::protocol::Status;
use crate::record::queue::QueueRoom;
use crate::rt::backend::LinkCounters;
use crate::rt::tap::{Buckets, LoopCounts, BOUNDS_NS};
use crate::vocab::{FaultKind, SupervisorState};
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeLabelSet, EncodeMetric, NoLabelSet};
use prometheus_client::metrics::counter::{ConstCounter, Counter};
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::info::Info;
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::{Registry, Unit};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::Path;
use std::sync::{Arc, Mutex};

/// `--metrics` without a value: loopback only, the port of the
/// OpenTelemetry Prometheus exporter.
pub const DEFAULT_ADDR: &str = "127.0.0.1:9464";

/// Scrapers connected at once; one more is closed at once.
pub const MAX_SCRAPERS: usize = 16;

/// How long one scraper's connection may last, s (keep-alive requests
/// included; Prometheus opens a new one). A scraper that stops reading is
/// cut off after this.
pub const CONNECTION_LIMIT_S: u64 = 60;

/// How long a request's header may take to arrive, s.
pub const HEADER_TIMEOUT_S: u64 = 10;

/// What `--metrics` accepts, for messages.
const FORMS: &str = "expected PORT, localhost:PORT or IP:PORT (e.g. 9464 or \
     localhost:9464 for this machine only, 0.0.0.0:9464 for every interface; \
     port 0: the OS picks one)";

/// Parses `--metrics`'s value into the address to listen on:
///
/// - `PORT` and `localhost:PORT`: loopback, 127.0.0.1 (`localhost` is not
///   looked up);
/// - `IP:PORT`, `[IPv6]:PORT`: that address, loopback or not. Another
///   interface is exposed only when its address is written out;
/// - a host name (`bench.lab:9464`) is refused, whatever it resolves to:
///   which interfaces it means depends on the resolver, at start-up;
/// - port 0 lets the OS choose (the daemon prints the address it listens
///   on).
///
/// # Errors
/// The reason (the caller names the flag and the value).
pub fn parse_addr(given: &str) -> Result<SocketAddr, String> {
    let loopback = |port| SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port);
    let port = |p: &str| -> Result<u16, String> {
        if p.is_empty() {
            return Err(format!("no port: {FORMS}"));
        }
        if !p.bytes().all(|b| b.is_ascii_digit()) {
            return Err(format!("port {p:?} is not a number: {FORMS}"));
        }
        p.parse::<u16>()
            .map_err(|_| format!("port {p} is outside 0 … 65535"))
    };
    if given.is_empty() {
        return Err(format!("empty: {FORMS}"));
    }
    if given.bytes().all(|b| b.is_ascii_digit()) {
        return port(given).map(loopback);
    }
    if let Ok(a) = given.parse::<SocketAddr>() {
        return Ok(a);
    }
    let bare = given.trim_start_matches('[').trim_end_matches(']');
    if given == "localhost" || bare.parse::<IpAddr>().is_ok() {
        return Err(format!("no port: {FORMS}"));
    }
    let Some((host, p)) = given.rsplit_once(':') else {
        return Err(format!("not an address: {FORMS}"));
    };
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() {
        return Err(format!("no address before the port: {FORMS}"));
    }
    if host == "localhost" {
        return port(p).map(loopback);
    }
    if let Ok(ip) = bare.parse::<IpAddr>() {
        return port(p).map(|p| SocketAddr::new(ip, p));
    }
    let hostname = host
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'.')
        && host.bytes().any(|b| b.is_ascii_alphabetic());
    if hostname {
        return Err(format!(
            "host name {host:?} refused (it could resolve to any interface): give the IP \
             address to listen on, e.g. 127.0.0.1:{p} for this machine only or \
             0.0.0.0:{p} for every interface"
        ));
    }
    Err(format!("{host:?} is not an IP address: {FORMS}"))
}

/// Binds `addr` for the metrics server (before anything else starts, so
/// an address in use stops the daemon before it opens the bench).
///
/// # Errors
/// The OS's reason (address in use, not an address of this machine, a
/// privileged port).
pub fn bind(addr: SocketAddr) -> Result<std::net::TcpListener, String> {
    let l = std::net::TcpListener::bind(addr).map_err(|e| format!("cannot listen there: {e}"))?;
    l.set_nonblocking(true)
        .map_err(|e| format!("cannot listen there: {e}"))?;
    Ok(l)
}

/// `bench_faults_total`'s label.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FaultLabels {
    kind: &'static str,
}

/// `bench_jobs_total`'s labels.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct JobLabels {
    kind: &'static str,
    outcome: &'static str,
}

/// The recorder's figures of the jobs that drive the bench.
#[derive(Debug, Default)]
struct RecorderState {
    /// Bytes of the finished jobs' recordings (each as finished on disk).
    done_bytes: u64,
    /// The queue of the job in the loop now.
    current: Option<Arc<QueueRoom>>,
    /// Records the loop dropped on a full queue, over every job.
    dropped_records: u64,
}

/// The loop's counts, added up.
struct LoopState {
    total: LoopCounts,
    rx: rtrb::Consumer<LoopCounts>,
}

impl LoopState {
    fn drain(&mut self) {
        while let Ok(c) = self.rx.pop() {
            self.total.add(&c);
        }
    }
}

/// Everything a scrape reads, shared by the owner thread (jobs, faults),
/// the metrics thread (the loop's counts) and the scrapes.
pub(super) struct Metrics {
    registry: Registry,
    faults: Family<FaultLabels, Counter>,
    jobs: Family<JobLabels, Counter>,
    state: Arc<Shared>,
}

struct Shared {
    status: Arc<Mutex<Status>>,
    /// `--upload`'s counts, if the daemon uploads.
    uploads: Option<Arc<crate::upload::worker::UploadCounts>>,
    recorder: Mutex<RecorderState>,
    loop_: Mutex<LoopState>,
}

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Shared").finish_non_exhaustive()
    }
}

/// What the daemon is, for `bench_build_info`.
pub(super) struct BuildInfo {
    /// The crate's version.
    pub(super) version: &'static str,
    /// SHA-256 of the resolved config ([`crate::config::BenchConfig::sha256_hex`]).
    pub(super) config_hash: String,
    /// The backend (`sim`, `serial:/dev/ttyACM0`, …).
    pub(super) backend: String,
}

impl Metrics {
    /// The metrics of a daemon whose loop hands its counts to `rx` and
    /// whose state is `status`.
    pub(super) fn new(
        status: Arc<Mutex<Status>>,
        rx: rtrb::Consumer<LoopCounts>,
        build: BuildInfo,
        uploads: Option<Arc<crate::upload::worker::UploadCounts>>,
    ) -> Self {
        let mut registry = Registry::with_prefix("bench");
        registry.register(
            "build",
            "The daemon: bench's version, the SHA-256 of its resolved config \
             (as recordings hold it, bench.config sha256) and its backend",
            Info::new(vec![
                ("version".to_string(), build.version.to_string()),
                ("config_hash".to_string(), build.config_hash),
                ("backend".to_string(), build.backend),
            ]),
        );
        let faults = Family::<FaultLabels, Counter>::default();
        for k in FaultKind::ALL {
            // Every kind from 0: rate() sees the first one.
            let _ = faults.get_or_create(&FaultLabels { kind: k.as_str() });
        }
        registry.register(
            "faults",
            "Faults latched by the supervisor, by kind (in a job or between jobs; \
             the owner thread counts each as it reports it)",
            faults.clone(),
        );
        let jobs = Family::<JobLabels, Counter>::default();
        registry.register(
            "jobs",
            "Jobs that ended, by kind and outcome (ok, or the error kind of the \
             answer: fault, hal, interrupted, refused, bad_params, error)",
            jobs.clone(),
        );
        let state = Arc::new(Shared {
            status,
            uploads,
            recorder: Mutex::new(RecorderState::default()),
            loop_: Mutex::new(LoopState {
                total: LoopCounts::default(),
                rx,
            }),
        });
        registry.register_collector(Box::new(Scrape(Arc::clone(&state))));
        Self {
            registry,
            faults,
            jobs,
            state,
        }
    }

    /// A fault latched (its supervisor name). Owner thread.
    pub(super) fn fault(&self, kind: &'static str) {
        self.faults.get_or_create(&FaultLabels { kind }).inc();
    }

    /// A job went into the loop, recording through the queue `room`.
    /// Owner thread.
    /// A job of several runs (a track job's trials) goes in once per run:
    /// the run before's bytes are counted as done then.
    pub(super) fn job_in_loop(&self, room: Arc<QueueRoom>) {
        let mut r = lock(&self.state.recorder);
        if let Some(before) = r.current.replace(room) {
            r.done_bytes += before.file_bytes();
        }
    }

    /// The loop gave the job back, having dropped `dropped` records on a
    /// full queue. Owner thread.
    pub(super) fn job_out_of_loop(&self, dropped: u64) {
        lock(&self.state.recorder).dropped_records += dropped;
    }

    /// A job ended with `outcome` (`ok` or the answer's error kind); its
    /// recording, if it made one, is at `recording` (finished). Owner
    /// thread.
    pub(super) fn job_finished(
        &self,
        kind: &'static str,
        outcome: &'static str,
        recording: Option<&Path>,
    ) {
        self.jobs.get_or_create(&JobLabels { kind, outcome }).inc();
        let mut r = lock(&self.state.recorder);
        if let Some(room) = r.current.take() {
            // The finished file (footer and summary included), or what
            // was on disk at the last flush if it is gone: never less
            // than the live figure showed.
            let finished = recording
                .and_then(|p| std::fs::metadata(p).ok())
                .filter(std::fs::Metadata::is_file)
                .map_or(0, |m| m.len());
            r.done_bytes += finished.max(room.file_bytes());
        }
    }

    /// Takes the loop's counts handed off since the last call (the
    /// metrics thread, every 0.1 s).
    pub(super) fn drain(&self) {
        lock(&self.state.loop_).drain();
    }

    /// The exposition: OpenMetrics text when `openmetrics`, else the
    /// Prometheus text format 0.0.4.
    pub(super) fn encode(&self, openmetrics: bool) -> String {
        let mut out = String::with_capacity(16 * 1024);
        let r = if openmetrics {
            prometheus_client::encoding::text::encode(&mut out, &self.registry)
        } else {
            prometheus_client::encoding::prometheus_text::encode(&mut out, &self.registry)
        };
        if let Err(e) = r {
            tracing::error!("metrics: encoding failed: {e}");
        }
        out
    }
}

/// The metrics read at each scrape: the loop's, the supervisor state, the
/// recorder's and the link's.
#[derive(Debug)]
struct Scrape(Arc<Shared>);

/// Cumulative-ready `(upper bound s, count)` pairs of `b`, `+Inf` last.
fn histogram_buckets(b: &Buckets) -> Vec<(f64, u64)> {
    BOUNDS_NS
        .iter()
        .map(|&ns| ns as f64 / 1e9)
        .chain([f64::INFINITY])
        .zip(b.counts)
        .collect()
}

fn histogram(
    enc: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    b: &Buckets,
) -> Result<(), std::fmt::Error> {
    let mut m = enc.encode_descriptor(name, help, Some(&Unit::Seconds), MetricType::Histogram)?;
    m.encode_histogram::<NoLabelSet>(
        b.sum_ns as f64 / 1e9,
        b.count(),
        &histogram_buckets(b),
        None,
    )
}

fn counter(
    enc: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    unit: Option<&Unit>,
    v: u64,
) -> Result<(), std::fmt::Error> {
    ConstCounter::new(v).encode(enc.encode_descriptor(name, help, unit, MetricType::Counter)?)
}

/// A counter with one label, one sample per `(value, count)`.
fn labelled_counter(
    enc: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    label: &'static str,
    samples: &[(&'static str, u64)],
) -> Result<(), std::fmt::Error> {
    let mut m = enc.encode_descriptor(name, help, None, MetricType::Counter)?;
    for (value, n) in samples {
        ConstCounter::new(*n).encode(m.encode_family(&[(label, *value)])?)?;
    }
    Ok(())
}

/// The link's counters by name: bad frames by reason, timeouts, missed
/// samples.
fn link_figures(l: LinkCounters) -> (Vec<(&'static str, u64)>, u64, u64) {
    match l {
        LinkCounters::Serial(s) => (
            vec![("crc", s.crc_errors), ("framing", s.frame_errors)],
            s.timeouts,
            s.missed_samples,
        ),
        LinkCounters::Can(c) => (
            vec![("size", c.bad_frames), ("error_frame", c.error_frames)],
            c.timeouts,
            c.lost_samples,
        ),
        LinkCounters::Ethercat(e) => (
            vec![
                ("working_counter", e.wkc_errors),
                ("al_state", e.state_errors),
            ],
            e.lost_frames,
            e.lost_frames,
        ),
    }
}

impl Collector for Scrape {
    fn encode(&self, mut enc: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let total = {
            let mut l = lock(&self.0.loop_);
            l.drain();
            l.total
        };
        histogram(
            &mut enc,
            "loop_wakeup_latency",
            "Wake-up latency of the real-time loop's ticks (wake - deadline; 0 on a \
             device-clocked backend), from the loop's own clock reads; jobs and the hold \
             between them, not jobs run in virtual time.",
            &total.wake,
        )?;
        histogram(
            &mut enc,
            "loop_compute",
            "Compute time of the real-time loop's ticks (wake to command written, less \
             one clock read).",
            &total.compute,
        )?;
        counter(
            &mut enc,
            "loop_overruns",
            "Real-time ticks that ended after the next deadline.",
            None,
            total.overruns,
        )?;
        labelled_counter(
            &mut enc,
            "loop_ticks",
            "Ticks the loop ran in real time, in jobs or in the hold between jobs.",
            "phase",
            &[("job", total.job_ticks), ("hold", total.hold_ticks)],
        )?;
        {
            let state = lock(&self.0.status).state;
            let mut m = enc.encode_descriptor(
                "supervisor_state",
                "The daemon's state as `status` reports it: 1 for the current one.",
                None,
                MetricType::Gauge,
            )?;
            for s in SupervisorState::ALL {
                let v = i64::from(s.as_str() == state);
                ConstGauge::new(v).encode(m.encode_family(&[("state", s.as_str())])?)?;
            }
        }
        let (bytes, fill, dropped) = {
            let r = lock(&self.0.recorder);
            let live = r.current.as_ref();
            (
                r.done_bytes + live.map_or(0, |q| q.file_bytes()),
                live.map_or(0.0, |q| q.fill_ratio()),
                r.dropped_records,
            )
        };
        counter(
            &mut enc,
            "recorder",
            "Bytes of the MCAP recordings of the jobs that drive the bench (chirp, \
             control): the file on disk at each chunk flush, the finished file at the \
             job's end.",
            Some(&Unit::Bytes),
            bytes,
        )?;
        ConstGauge::new(fill).encode(enc.encode_descriptor(
            "recorder_queue_fill_ratio",
            "How full the running job's record queue (loop to writer thread) was when \
             the writer last came for a batch, 0 to 1; 0 between jobs.",
            None,
            MetricType::Gauge,
        )?)?;
        counter(
            &mut enc,
            "recorder_dropped_records",
            "Records the real-time loop dropped because its job's queue was full.",
            None,
            dropped,
        )?;
        if let Some(u) = &self.0.uploads {
            use std::sync::atomic::Ordering::Relaxed;
            labelled_counter(
                &mut enc,
                "uploads",
                "`--upload`: files the store confirmed (SHA-256 read back), failed tries \
                 (each retried after a backoff) and files dropped (another object of the \
                 name in the store, the local file gone).",
                "outcome",
                &[
                    ("confirmed", u.confirmed.load(Relaxed)),
                    ("failed", u.failed.load(Relaxed)),
                    ("dropped", u.dropped.load(Relaxed)),
                ],
            )?;
            ConstGauge::new(u.pending.load(Relaxed) as i64).encode(enc.encode_descriptor(
                "upload_pending",
                "`--upload`: files queued (in the journal) and not yet confirmed or dropped.",
                None,
                MetricType::Gauge,
            )?)?;
        }
        if let Some(link) = total.link {
            let (bad, timeouts, missed) = link_figures(link);
            labelled_counter(
                &mut enc,
                "link_bad_frames",
                "Frames the hardware backend refused since the device was opened, by \
                 reason (serial: crc, framing; CAN: size, error_frame).",
                "reason",
                &bad,
            )?;
            counter(
                &mut enc,
                "link_timeouts",
                "Sample reads that timed out, since the device was opened.",
                None,
                timeouts,
            )?;
            counter(
                &mut enc,
                "link_missed_samples",
                "Samples the device sent that never reached the loop (sequence gaps), \
                 since the device was opened.",
                None,
                missed,
            )?;
            counter(
                &mut enc,
                "link_late_commands",
                "Samples the device flagged command_late: the command in force had not \
                 answered the previous sample (the link's round trip took longer than a \
                 period).",
                None,
                total.late_commands,
            )?;
        }
        Ok(())
    }
}

/// The metrics server: its thread and the address it listens on. Stops
/// (and joins its thread) when dropped.
pub(super) struct MetricsServer {
    addr: SocketAddr,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl MetricsServer {
    /// Serves `metrics` on `listener` ([`bind`]) from a thread of its own,
    /// kept off `loop_cpu`.
    ///
    /// # Errors
    /// When the thread or its runtime cannot start.
    pub(super) fn start(
        listener: std::net::TcpListener,
        metrics: Arc<Metrics>,
        loop_cpu: Option<usize>,
    ) -> Result<Self, String> {
        let addr = listener.local_addr().map_err(|e| e.to_string())?;
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| format!("tokio: {e}"))?;
        let (stop, stopped) = tokio::sync::oneshot::channel();
        let thread = std::thread::Builder::new()
            .name("bench-metrics".into())
            .spawn(move || {
                bench_hal::os::keep_off_cpu(loop_cpu);
                rt.block_on(serve(listener, metrics, stopped));
            })
            .map_err(|e| format!("cannot start the metrics thread: {e}"))?;
        Ok(Self {
            addr,
            stop: Some(stop),
            thread: Some(thread),
        })
    }

    /// `http://ADDR/metrics` (with the port the OS chose for port 0).
    pub(super) fn url(&self) -> String {
        format!("http://{}/metrics", self.addr)
    }
}

impl Drop for MetricsServer {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The server's loop: accepts scrapers (at most [`MAX_SCRAPERS`]) and
/// takes the loop's counts every 0.1 s, until `stopped`.
async fn serve(
    listener: std::net::TcpListener,
    metrics: Arc<Metrics>,
    mut stopped: tokio::sync::oneshot::Receiver<()>,
) {
    let listener = match tokio::net::TcpListener::from_std(listener) {
        Ok(l) => l,
        Err(e) => {
            tracing::error!("metrics: cannot serve: {e}");
            return;
        }
    };
    let slots = Arc::new(tokio::sync::Semaphore::new(MAX_SCRAPERS));
    let mut drain = tokio::time::interval(std::time::Duration::from_millis(100));
    drain.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = &mut stopped => break,
            _ = drain.tick() => metrics.drain(),
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => {
                    let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
                        // Too many scrapers: this one is closed at once.
                        drop(stream);
                        continue;
                    };
                    let m = Arc::clone(&metrics);
                    tokio::spawn(async move {
                        let _slot = slot;
                        connection(stream, m).await;
                    });
                }
                Err(e) => {
                    // Out of file descriptors, most likely: pause instead
                    // of spinning.
                    tracing::warn!("metrics: accept failed: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
            },
        }
    }
}

/// Serves one scraper's connection (HTTP/1.1, keep-alive) for at most
/// [`CONNECTION_LIMIT_S`].
async fn connection(stream: tokio::net::TcpStream, metrics: Arc<Metrics>) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    let svc = hyper::service::service_fn(move |req| {
        let m = Arc::clone(&metrics);
        async move { Ok::<_, std::convert::Infallible>(respond(&m, &req)) }
    });
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(std::time::Duration::from_secs(HEADER_TIMEOUT_S))
        .serve_connection(TokioIo::new(stream), svc);
    let limit = std::time::Duration::from_secs(CONNECTION_LIMIT_S);
    let _ = tokio::time::timeout(limit, conn).await;
}

type Body = http_body_util::Full<hyper::body::Bytes>;

/// The answer to one request: the exposition for `GET /metrics` (and its
/// headers for `HEAD`), 405 for another method there, 404 elsewhere.
fn respond<B>(metrics: &Metrics, req: &hyper::Request<B>) -> hyper::Response<Body> {
    use hyper::{header, Method, StatusCode};
    let plain = |status: StatusCode, text: &str| {
        let mut r = hyper::Response::new(Body::from(text.to_string()));
        *r.status_mut() = status;
        r.headers_mut().insert(
            header::CONTENT_TYPE,
            header::HeaderValue::from_static("text/plain; charset=utf-8"),
        );
        r
    };
    if req.uri().path() != "/metrics" {
        return plain(
            StatusCode::NOT_FOUND,
            "not found: bench serves its metrics at /metrics only\n",
        );
    }
    if req.method() != Method::GET && req.method() != Method::HEAD {
        let mut r = plain(
            StatusCode::METHOD_NOT_ALLOWED,
            "method not allowed: GET or HEAD /metrics\n",
        );
        r.headers_mut()
            .insert(header::ALLOW, header::HeaderValue::from_static("GET, HEAD"));
        return r;
    }
    let openmetrics = req
        .headers()
        .get_all(header::ACCEPT)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .any(|v| v.contains("application/openmetrics-text"));
    let (text, content_type) = if openmetrics {
        (
            metrics.encode(true),
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )
    } else {
        (
            metrics.encode(false),
            prometheus_client::encoding::prometheus_text::CONTENT_TYPE,
        )
    };
    let len = text.len();
    let body = if req.method() == Method::HEAD {
        Body::default()
    } else {
        Body::from(text)
    };
    let mut r = hyper::Response::new(body);
    r.headers_mut().insert(
        header::CONTENT_TYPE,
        header::HeaderValue::from_static(content_type),
    );
    if req.method() == Method::HEAD {
        r.headers_mut()
            .insert(header::CONTENT_LENGTH, header::HeaderValue::from(len));
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_unless_an_address_is_written_out() {
        let lo = |p| SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), p);
        assert_eq!(parse_addr("9464"), Ok(lo(9464)));
        assert_eq!(parse_addr("0"), Ok(lo(0)));
        assert_eq!(parse_addr("localhost:9464"), Ok(lo(9464)));
        assert_eq!(parse_addr("127.0.0.1:9464"), Ok(lo(9464)));
        assert_eq!(
            parse_addr("0.0.0.0:9464"),
            Ok("0.0.0.0:9464".parse().unwrap())
        );
        assert_eq!(
            parse_addr("192.0.2.5:9464"),
            Ok("192.0.2.5:9464".parse().unwrap())
        );
        assert_eq!(parse_addr("[::1]:9464"), Ok("[::1]:9464".parse().unwrap()));
        assert_eq!(parse_addr("[::]:9464"), Ok("[::]:9464".parse().unwrap()));
        assert_eq!(parse_addr(DEFAULT_ADDR), Ok(lo(9464)));
    }

    #[test]
    fn every_refusal_says_why() {
        for (given, why) in [
            ("", "empty"),
            ("127.0.0.1", "no port"),
            ("::1", "no port"),
            ("[::1]", "no port"),
            ("localhost", "no port"),
            ("localhost:", "no port"),
            ("127.0.0.1:", "no port"),
            ("70000", "outside 0 … 65535"),
            ("127.0.0.1:65536", "outside 0 … 65535"),
            ("127.0.0.1:http", "not a number"),
            ("127.0.0.1:-1", "not a number"),
            (":9464", "no address before the port"),
            ("bench.lab:9464", "host name \"bench.lab\" refused"),
            ("example.org:9464", "host name"),
            ("1.2.3.4.5:9464", "not an IP address"),
            ("garbage", "not an address"),
            ("a b:1", "not an IP address"),
        ] {
            let e = parse_addr(given).expect_err(given);
            assert!(e.contains(why), "{given:?}: {e}");
        }
    }

    #[test]
    fn histogram_buckets_end_with_inf_and_keep_every_count() {
        let mut b = Buckets::default();
        for ns in [100, 30_000, 200_000_000] {
            b.record(ns);
        }
        let h = histogram_buckets(&b);
        assert_eq!(h.len(), BOUNDS_NS.len() + 1);
        assert_eq!(h.last().unwrap().0, f64::INFINITY);
        assert_eq!(h.iter().map(|x| x.1).sum::<u64>(), 3);
        assert_eq!(h[0], (250e-9, 1));
    }
}
